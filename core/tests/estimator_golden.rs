//! The whole estimator, core alone, on real data: EuRoC V1_01's first 30 s (IMU and a real front
//! end's tracks, `tests/data`), started at rest by the estimator's own initializer, fed through the
//! public push/update interface. Two configurations: the default pose-only window, and the same
//! with the camera-IMU extrinsic estimated online (the delay is estimated in both).
//!
//! Each run is made twice in the process and must agree bit for bit; then one FNV-1a 64 hash of
//! every IMU-rate state's bit patterns and every keyframe report (its `Debug` form, which prints
//! each `f64` exactly, timings zeroed) is compared with a constant blessed on x86-64 and printed as
//! `POVINS_ESTIMATOR_HASH_*`. `scripts/cross-check.sh` runs this test on aarch64 under qemu:
//! it needs only `povins-core`, so the cross build stays small (the facade's golden replays,
//! `tests/estimator_determinism.rs`, feed the same core through the host tools' runner and run
//! on x86-64).
//!
//! After an intended change of the estimator's numbers, run with `POVINS_BLESS=1` and
//! `-- --nocapture`, and copy the printed hashes here.

mod vision_common;

use nalgebra::Vector3;
use povins_core::camera::{FeatureObs, PinholeCamera};
use povins_core::estimator::{EstimatorConfig, KeyframeReport, PoVins};
use povins_core::inertial::{ImuNoise, ImuSample, NavState};
use vision_common::{data_dir, euroc_extrinsic};

/// Blessed on x86-64 (see the module docs).
const GOLDEN_DEFAULT: u64 = 0x041a_bf47_033a_ef63;
const GOLDEN_EXTRINSIC: u64 = 0xd3af_391e_2f47_8925;

struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn f64s<'a>(&mut self, v: impl IntoIterator<Item = &'a f64>) {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
    }
}

fn hash_state(h: &mut Fnv, s: &NavState) {
    h.bytes(&s.t_ns.to_le_bytes());
    h.f64s(s.p_wb.iter());
    h.f64s(s.q_wb.coords.iter());
    h.f64s(s.v_wb.iter());
    h.f64s(s.bg.iter());
    h.f64s(s.ba.iter());
}

fn hash_report(h: &mut Fnv, r: &KeyframeReport) {
    let untimed = KeyframeReport {
        solve_ns: 0,
        marginalization_ns: 0,
        total_ns: 0,
        ..*r
    };
    h.bytes(format!("{untimed:?}").as_bytes());
}

fn csv_rows(path: &std::path::Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split(',').map(|f| f.trim().to_string()).collect())
        .collect()
}

fn num<T: std::str::FromStr>(s: &str) -> T {
    s.parse()
        .unwrap_or_else(|_| panic!("not a number in the EuRoC csv: {s:?}"))
}

struct Input {
    imu: Vec<ImuSample>,
    /// (camera stamp, the frame's observations), in time order.
    frames: Vec<(i64, Vec<FeatureObs>)>,
}

fn load() -> Input {
    let dir = data_dir().join("euroc-v101-30s-features/mav0");
    let imu = csv_rows(&dir.join("imu0/data.csv"))
        .iter()
        .map(|f| ImuSample {
            t_ns: num(&f[0]),
            gyro_rps: Vector3::new(num(&f[1]), num(&f[2]), num(&f[3])),
            accel_mps2: Vector3::new(num(&f[4]), num(&f[5]), num(&f[6])),
        })
        .collect();
    let mut frames: Vec<(i64, Vec<FeatureObs>)> = Vec::new();
    for f in csv_rows(&dir.join("features0/data.csv")) {
        let t: i64 = num(&f[0]);
        let obs = FeatureObs {
            id: num(&f[1]),
            u_px: num(&f[2]),
            v_px: num(&f[3]),
        };
        match frames.last_mut() {
            Some((tl, v)) if *tl == t => v.push(obs),
            _ => frames.push((t, vec![obs])),
        }
    }
    Input { imu, frames }
}

struct Run {
    states: Vec<NavState>,
    reports: Vec<KeyframeReport>,
}

impl Run {
    fn hash(&self) -> u64 {
        let mut h = Fnv::new();
        self.states.iter().for_each(|s| hash_state(&mut h, s));
        self.reports.iter().for_each(|r| hash_report(&mut h, r));
        h.0
    }
}

/// Every frame whose stamp the IMU has reached is pushed before the sample, then the sample;
/// the queue is drained after each sample (as the host tools' runner does).
fn replay(input: &Input, cfg: EstimatorConfig) -> Run {
    let mut est = PoVins::new(cfg).expect("a valid configuration");
    let mut run = Run {
        states: Vec::new(),
        reports: Vec::new(),
    };
    let mut fi = 0;
    for s in &input.imu {
        while let Some((t, obs)) = input.frames.get(fi).filter(|f| f.0 <= s.t_ns) {
            let _ = est.push_frame(*t, obs);
            fi += 1;
        }
        let _ = est.push_imu(s);
        loop {
            match est.update() {
                Ok(Some(o)) => {
                    run.states.extend(o.nav);
                    run.reports.extend(o.keyframe);
                }
                Ok(None) => break,
                Err(_) => continue,
            }
        }
    }
    run
}

fn euroc_config() -> EstimatorConfig {
    EstimatorConfig::new(
        PinholeCamera::EUROC_CAM0,
        euroc_extrinsic(),
        ImuNoise::EUROC_ADIS16448,
    )
}

/// Two replays agree bit for bit, the run is a real one, and its hash is the golden one.
fn check(name: &str, cfg: EstimatorConfig, golden: u64) {
    // The estimator (several MB) lives on this thread's stack.
    let name = name.to_string();
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(move || {
            let input = load();
            let a = replay(&input, cfg);
            let b = replay(&input, cfg);
            assert_eq!(
                a.states.len(),
                b.states.len(),
                "{name}: state counts differ"
            );
            if let Some(i) = (0..a.states.len()).find(|&i| {
                let (mut x, mut y) = (Fnv::new(), Fnv::new());
                hash_state(&mut x, &a.states[i]);
                hash_state(&mut y, &b.states[i]);
                x.0 != y.0
            }) {
                panic!(
                    "{name}: run 2 differs from run 1 at state #{i}: {:?} vs {:?}",
                    a.states[i], b.states[i]
                );
            }
            assert_eq!(
                a.hash(),
                b.hash(),
                "{name}: keyframe reports differ between runs"
            );
            assert!(
                a.reports.len() > 40 && a.states.len() > 4000,
                "{name}: only {} keyframes and {} states",
                a.reports.len(),
                a.states.len()
            );
            let last = a.states.last().expect("states");
            assert!(
                last.p_wb.iter().all(|x| x.is_finite()),
                "{name}: non-finite state"
            );
            let h = a.hash();
            println!("POVINS_ESTIMATOR_HASH_{name}={h:016x}");
            println!(
                "{name}: {} keyframes, {} states, last p_wb {:?}, td {:.4} ms",
                a.reports.len(),
                a.states.len(),
                last.p_wb,
                a.reports.last().map_or(0.0, |r| r.td_s * 1e3)
            );
            if std::env::var_os("POVINS_BLESS").is_none() {
                assert_eq!(
                    h, golden,
                    "{name}: the output moved from the golden hash {golden:016x} (now {h:016x}); \
                     bless an intended change as the module docs say"
                );
            }
        })
        .expect("spawn")
        .join()
        .expect("the run panicked");
}

#[test]
fn euroc_default_is_deterministic_and_golden() {
    check("DEFAULT", euroc_config(), GOLDEN_DEFAULT);
}

#[test]
fn euroc_online_extrinsic_is_deterministic_and_golden() {
    let mut cfg = euroc_config();
    cfg.estimate_extrinsic = true;
    check("EXTRINSIC", cfg, GOLDEN_EXTRINSIC);
}

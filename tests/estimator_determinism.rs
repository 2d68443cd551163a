//! Golden-file replay (PX4 style): the same input gives bit-identical output, and that output
//! has not changed since the golden files were blessed.
//!
//! Each run is replayed twice and the IMU-rate states must match bit for bit. The output is then
//! hashed (FNV-1a 64 over the bit patterns of `t, p, q, v, bg, ba` of every IMU-rate state,
//! then every keyframe report's numbers except the `*_ns` timings) and compared with
//! `tests/golden/<name>.hash`. Besides the total, the file keeps one hash per state and per
//! report so a mismatch can say where the output first changed.
//!
//! After an intended change of the estimator's numbers, re-bless with
//! `POVINS_BLESS=1 cargo test --test estimator_determinism` and commit the files.

mod common;

use common::*;
use povins::core::estimator::{KeyframeReport, VisualMode};
use povins::core::inertial::NavState;
use povins::host_tools::runner::{config_for, replay, InitMode, RunOutput};
use povins::platform::dataset::Dataset;
use std::fmt::Write as _;
use std::path::PathBuf;

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a 64.
#[derive(Clone, Copy)]
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(FNV_OFFSET)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(FNV_PRIME);
        }
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn f64s<'a>(&mut self, vs: impl IntoIterator<Item = &'a f64>) {
        for v in vs {
            self.f64(*v);
        }
    }
}

fn hash_state(h: &mut Fnv, s: &NavState) {
    h.u64(s.t_ns as u64);
    h.f64s(s.p_wb.iter());
    h.f64s(s.q_wb.coords.iter());
    h.f64s(s.v_wb.iter());
    h.f64s(s.bg.iter());
    h.f64s(s.ba.iter());
}

/// Every number of the report except the timings (`*_ns`), which depend on the machine's load.
fn hash_report(h: &mut Fnv, r: &KeyframeReport) {
    let KeyframeReport {
        t_ns,
        t_cam_ns,
        decision,
        window_len,
        landmarks_total,
        landmarks_used,
        observations_used,
        residual_rms_px,
        iterations,
        cost,
        termination,
        culled_chi2,
        culled_observations,
        culled_landmarks,
        disabled_landmarks,
        marginalized_rank_deficiency,
        prior_rank_deficiency,
        solve_ns: _,
        marginalization_ns: _,
        total_ns: _,
        lidar_points,
        depths_associated,
        depths_rejected,
        ldm_count,
        association_ns: _,
        rejection_ns: _,
        depth_opt_ns: _,
        admission,
        td_s,
        imu_noise_scale,
        multi_view_tracks,
        multi_view_observations,
        landmarks_promoted,
        landmarks_evicted,
        breakdown,
    } = r;
    h.u64(*t_ns as u64);
    h.u64(*t_cam_ns as u64);
    h.bytes(format!("{decision:?}").as_bytes());
    for n in [
        window_len,
        landmarks_total,
        landmarks_used,
        observations_used,
        iterations,
        culled_chi2,
        culled_observations,
        culled_landmarks,
        disabled_landmarks,
        marginalized_rank_deficiency,
        prior_rank_deficiency,
        lidar_points,
        depths_associated,
        depths_rejected,
        ldm_count,
        &admission.admitted,
        &admission.single_view,
        &admission.low_parallax,
        &admission.bad_depth,
        &admission.uncertain_depth,
        multi_view_tracks,
        multi_view_observations,
        landmarks_promoted,
        landmarks_evicted,
    ] {
        h.u64(u64::from(*n));
    }
    h.f64s([residual_rms_px, &cost.0, &cost.1, td_s, imu_noise_scale]);
    h.bytes(format!("{termination:?} {breakdown:?}").as_bytes());
}

/// The hashes of a run: the total and one per state and per report (each over that item only).
#[derive(Debug, PartialEq)]
struct Hashes {
    total: u64,
    states: Vec<u64>,
    reports: Vec<u64>,
}

fn hashes(out: &RunOutput) -> Hashes {
    let mut total = Fnv::new();
    let mut one = |f: &dyn Fn(&mut Fnv)| {
        f(&mut total);
        let mut h = Fnv::new();
        f(&mut h);
        h.0
    };
    let states = out
        .imu_rate
        .iter()
        .map(|s| one(&|h| hash_state(h, s)))
        .collect();
    let no_events = Vec::new();
    let reports = out
        .reports
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let ev = out.lidar_events.get(i).map_or(&no_events, |e| &e.events);
            one(&|h| {
                hash_report(h, r);
                // Empty for runs without LiDAR, so their hashes are unchanged.
                for e in ev {
                    h.u64(e.id);
                    h.bytes(format!("{:?}", e.kind).as_bytes());
                    h.f64s([&e.depth_m]);
                }
            })
        })
        .collect();
    Hashes {
        total: total.0,
        states,
        reports,
    }
}

const BLESS: &str = "POVINS_BLESS=1 cargo test --test estimator_determinism";

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden")).join(format!("{name}.hash"))
}

fn render(name: &str, h: &Hashes) -> String {
    let mut s = format!(
        "# povins golden replay '{name}': FNV-1a 64 of the IMU-rate states and keyframe reports\n\
         # (timings excluded). Re-bless after an intended change: {BLESS}\n"
    );
    let _ = writeln!(s, "total {:016x}", h.total);
    let _ = writeln!(s, "states {}", h.states.len());
    let _ = writeln!(s, "reports {}", h.reports.len());
    for v in h.states.iter().chain(&h.reports) {
        let _ = writeln!(s, "{v:016x}");
    }
    s
}

fn parse(text: &str) -> Option<Hashes> {
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let mut field = |key: &str| -> Option<String> {
        let l = lines.next()?;
        l.strip_prefix(key)?.strip_prefix(' ').map(str::to_string)
    };
    let total = u64::from_str_radix(&field("total")?, 16).ok()?;
    let n_states: usize = field("states")?.parse().ok()?;
    let n_reports: usize = field("reports")?.parse().ok()?;
    let vals: Vec<u64> = lines
        .map(|l| u64::from_str_radix(l.trim(), 16).ok())
        .collect::<Option<_>>()?;
    if vals.len() != n_states + n_reports {
        return None;
    }
    Some(Hashes {
        total,
        states: vals[..n_states].to_vec(),
        reports: vals[n_states..].to_vec(),
    })
}

/// Where two hash lists first differ (an index past the shorter one when one is a prefix).
fn first_difference(a: &[u64], b: &[u64]) -> Option<usize> {
    (0..a.len().max(b.len())).find(|&i| a.get(i) != b.get(i))
}

fn check_golden(name: &str, out: &RunOutput) {
    let now = hashes(out);
    let path = golden_path(name);
    if std::env::var_os("POVINS_BLESS").is_some_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().expect("a parent folder"))
            .expect("create tests/golden");
        std::fs::write(&path, render(name, &now))
            .unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
        println!("blessed {} (total {:016x})", path.display(), now.total);
        return;
    }
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "golden file {} is missing ({e}); create it with `{BLESS}`",
            path.display()
        )
    });
    let golden = parse(&text).unwrap_or_else(|| {
        panic!(
            "golden file {} is malformed; re-bless with `{BLESS}`",
            path.display()
        )
    });
    if golden == now {
        println!("{name}: matches golden total {:016x}", now.total);
        return;
    }
    let t_s = |t_ns: i64| (t_ns - out.imu_rate.first().map_or(0, |s| s.t_ns)) as f64 * 1e-9;
    let mut msg = format!(
        "{name}: output differs from the golden file {}\n  states: {} now, {} golden; \
         keyframe reports: {} now, {} golden; total {:016x} now, {:016x} golden\n",
        path.display(),
        now.states.len(),
        golden.states.len(),
        now.reports.len(),
        golden.reports.len(),
        now.total,
        golden.total
    );
    if let Some(i) = first_difference(&now.states, &golden.states) {
        let at = match out.imu_rate.get(i) {
            Some(s) => format!(
                "t = {} ns ({:.3} s after the first state)",
                s.t_ns,
                t_s(s.t_ns)
            ),
            None => "past the last state of this run".to_string(),
        };
        let _ = writeln!(msg, "  first differing state: #{i}, {at}");
    } else if let Some(i) = first_difference(&now.reports, &golden.reports) {
        let at = match out.reports.get(i) {
            Some(r) => format!(
                "t = {} ns ({:.3} s after the first state)",
                r.t_ns,
                t_s(r.t_ns)
            ),
            None => "past the last report of this run".to_string(),
        };
        let _ = writeln!(
            msg,
            "  all states match; first differing keyframe report: #{i}, {at}"
        );
    }
    let _ = write!(
        msg,
        "  if the change is intended, re-bless with `{BLESS}` and commit tests/golden/"
    );
    panic!("{msg}");
}

fn state_bits(s: &NavState) -> [u64; 17] {
    let mut b = [0u64; 17];
    b[0] = s.t_ns as u64;
    let vals = s
        .p_wb
        .iter()
        .chain(s.q_wb.coords.iter())
        .chain(s.v_wb.iter())
        .chain(s.bg.iter())
        .chain(s.ba.iter());
    for (d, v) in b[1..].iter_mut().zip(vals) {
        *d = v.to_bits();
    }
    b
}

/// Two replays of the same input must agree bit for bit, state by state.
fn assert_runs_identical(a: &RunOutput, b: &RunOutput) {
    assert_eq!(a.imu_rate.len(), b.imu_rate.len(), "state counts differ");
    if let Some(i) =
        (0..a.imu_rate.len()).find(|&i| state_bits(&a.imu_rate[i]) != state_bits(&b.imu_rate[i]))
    {
        panic!(
            "run 2 differs from run 1 at state #{i} (t = {} ns): {:?} vs {:?}",
            a.imu_rate[i].t_ns, a.imu_rate[i], b.imu_rate[i]
        );
    }
    assert_eq!(a.reports.len(), b.reports.len(), "keyframe counts differ");
    // The reports' timings differ between the runs; everything else must not.
    assert_eq!(hashes(a), hashes(b), "keyframe reports differ between runs");
    assert_eq!(a.counters, b.counters);
}

fn run_twice(
    ds: &Dataset,
    cfg: povins::core::estimator::EstimatorConfig,
    init: InitMode,
) -> RunOutput {
    let a = replay(ds, cfg, init, &quiet()).expect("replay 1");
    let b = replay(ds, cfg, init, &quiet()).expect("replay 2");
    assert_runs_identical(&a, &b);
    assert!(a.reports.len() > 40, "only {} keyframes", a.reports.len());
    a
}

#[test]
fn euroc_30s_static_init_is_deterministic_and_golden() {
    big_stack(|| {
        let ds = load(EUROC_30S);
        let out = run_twice(
            &ds,
            euroc_config(&ds, VisualMode::PoseOnly),
            InitMode::Static,
        );
        check_golden("euroc-v101-30s-static", &out);
    });
}

#[test]
fn simulated_robot_20s_gt_init_is_deterministic_and_golden() {
    big_stack(|| {
        let ds = simulate_robot(2, 20.0);
        let out = run_twice(&ds, config_for(&ds), InitMode::Groundtruth);
        check_golden("sim-robot-seed2-20s-gt", &out);
    });
}

/// LiDAR on (sweep de-skew, association, rejection, MSC LDM, depth-only optimization): the
/// same bits run after run, and against the golden file. The LiDAR events are part of the hash.
#[test]
fn simulated_robot_20s_with_lidar_is_deterministic_and_golden() {
    big_stack(|| {
        let ds = simulate_with_lidar(povins::host_tools::sim::Scenario::Robot, 2, 20.0);
        let cfg = config_for(&ds);
        assert!(
            cfg.lidar.enabled,
            "config_for enables LiDAR for a data set with sweeps"
        );
        let out = run_twice(&ds, cfg, InitMode::Groundtruth);
        let ldm: u32 = out.reports.iter().map(|r| r.ldm_count).sum();
        assert!(ldm > 1000, "LiDAR depths were not used ({ldm})");
        let a = replay(&ds, cfg, InitMode::Groundtruth, &quiet()).expect("replay");
        assert_eq!(
            a.lidar_events, out.lidar_events,
            "LiDAR events differ between runs"
        );
        check_golden("sim-robot-seed2-20s-gt-lidar", &out);
    });
}

/// The hash covers every reported number but none of the timings.
#[test]
fn report_hash_ignores_timings_only() {
    big_stack(|| {
        let ds = load(EUROC_30S);
        let out = replay(
            &ds,
            euroc_config(&ds, VisualMode::PoseOnly),
            InitMode::Static,
            &quiet(),
        )
        .expect("replay");
        let r = *out.reports.last().expect("a keyframe report");
        let h = |r: &KeyframeReport| {
            let mut f = Fnv::new();
            hash_report(&mut f, r);
            f.0
        };
        let timed = KeyframeReport {
            solve_ns: r.solve_ns + 1,
            marginalization_ns: r.marginalization_ns + 1,
            total_ns: r.total_ns + 1,
            ..r
        };
        assert_eq!(h(&r), h(&timed));
        let changed = KeyframeReport {
            residual_rms_px: r.residual_rms_px + 1e-12,
            ..r
        };
        assert_ne!(h(&r), h(&changed));
        let changed = KeyframeReport {
            culled_chi2: r.culled_chi2 + 1,
            ..r
        };
        assert_ne!(h(&r), h(&changed));
        // And the state hash sees the last bit of a coordinate.
        let s = out.imu_rate[out.imu_rate.len() / 2];
        let mut t = s;
        t.ba.z = f64::from_bits(s.ba.z.to_bits() ^ 1);
        let hs = |s: &NavState| {
            let mut f = Fnv::new();
            hash_state(&mut f, s);
            f.0
        };
        assert_ne!(hs(&s), hs(&t));
    });
}

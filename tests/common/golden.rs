//! Golden files of a run (shared by the tests that compare with `tests/golden/`): the exact
//! hashes (`<name>.hash`, the authority) and the decimated states to read (`<name>.csv`,
//! [`table`]), which say how far a run moved when the hashes differ.
//!
//! FNV-1a 64 over the bit patterns of `t, p, q, v, bg, ba` of every IMU-rate state, then every
//! keyframe report's numbers except the `*_ns` timings (and its LiDAR events). Besides the total,
//! a golden file keeps one hash per state and per report so a mismatch can say where the output
//! first changed. The API sees a run only through [`RunView`]; [`RunView::of`] is the one
//! adapter from the replay's output.

pub mod table;

use povins::core::estimator::{DepthEvent, KeyframeReport};
use povins::core::inertial::NavState;
use povins::host_tools::runner::RunOutput;
use std::fmt::Write as _;
use std::path::PathBuf;

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a 64.
#[derive(Clone, Copy)]
pub struct Fnv(pub u64);

impl Fnv {
    pub fn new() -> Self {
        Fnv(FNV_OFFSET)
    }
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(FNV_PRIME);
        }
    }
    pub fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub fn f64s<'a>(&mut self, vs: impl IntoIterator<Item = &'a f64>) {
        for v in vs {
            self.f64(*v);
        }
    }
}

pub fn hash_state(h: &mut Fnv, s: &NavState) {
    h.u64(s.t_ns as u64);
    h.f64s(s.p_wb.iter());
    h.f64s(s.q_wb.coords.iter());
    h.f64s(s.v_wb.iter());
    h.f64s(s.bg.iter());
    h.f64s(s.ba.iter());
}

/// Every number of the report except the timings (`*_ns`), which depend on the machine's load.
pub fn hash_report(h: &mut Fnv, r: &KeyframeReport) {
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
        // Always false without a budget (the golden runs have none).
        budget_hit: _,
        solve_work: _,
        cost,
        termination,
        culled_chi2,
        culled_observations,
        culled_landmarks,
        disabled_landmarks,
        marginalized_rank_deficiency,
        prior_rank_deficiency,
        prior_gauge_std: _,
        window_correction_m: _,
        at_rest: _,
        td_info_per_s2: _,
        solve_ns: _,
        marginalization_ns: _,
        total_ns: _,
        lidar_points,
        // Running counters, outside the goldens (hashed before they were reported).
        lidar_points_cropped_total: _,
        lidar_points_lost_total: _,
        lidar_points_thinned_total: _,
        depths_associated,
        depths_rejected,
        ldm_count,
        association_ns: _,
        rejection_ns: _,
        depth_opt_ns: _,
        admission,
        td_s,
        // The configured extrinsic unless estimated (off in the golden runs).
        extrinsic: _,
        // Estimated extrinsic only (off in the golden runs).
        extrinsic_sd: _,
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
pub struct Hashes {
    pub total: u64,
    pub states: Vec<u64>,
    pub reports: Vec<u64>,
}

/// What the golden files cover of a run: the IMU-rate states, the keyframe reports with each
/// report's LiDAR-depth events (same order; missing entries count as no events), and every
/// keyframe's final state (for the readable states only).
#[derive(Clone)]
pub struct RunView<'a> {
    pub imu_rate: &'a [NavState],
    pub reports: &'a [KeyframeReport],
    pub lidar_events: Vec<&'a [DepthEvent]>,
    pub keyframe_states: &'a [NavState],
}

impl<'a> RunView<'a> {
    /// The parts of a replay's output.
    pub fn of(out: &'a RunOutput) -> Self {
        RunView {
            imu_rate: &out.imu_rate,
            reports: &out.reports,
            lidar_events: out
                .lidar_events
                .iter()
                .map(|e| e.events.as_slice())
                .collect(),
            keyframe_states: &out.keyframe_states,
        }
    }
}

/// The hashes of a run.
pub fn hashes_of(out: &RunView<'_>) -> Hashes {
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
    let reports = out
        .reports
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let ev: &[DepthEvent] = out.lidar_events.get(i).copied().unwrap_or_default();
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

pub const BLESS: &str = "POVINS_BLESS=1 cargo test --test estimator_determinism";

/// `tests/golden/<name>.hash`.
pub fn golden_path(name: &str) -> PathBuf {
    golden_dir().join(format!("{name}.hash"))
}

/// `tests/golden/<name>.csv`: the decimated states ([`table`]).
pub fn states_path(name: &str) -> PathBuf {
    golden_dir().join(format!("{name}.csv"))
}

fn golden_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden"))
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

/// Compares a run with `tests/golden/<name>.hash`, panicking with where it first differs and,
/// from `tests/golden/<name>.csv`, how far each state column moved. With `may_bless` and
/// `POVINS_BLESS=1` it writes both files instead (only the determinism test blesses: other tests
/// compare with what it blessed). A run matching the hashes must reproduce the states file byte
/// for byte too (what the cross-target check relies on).
pub fn check_golden_of(name: &str, out: &RunView<'_>, may_bless: bool) {
    let now = hashes_of(out);
    let states = table::render(name, &table::table_of(out), BLESS);
    let path = golden_path(name);
    let csv = states_path(name);
    if may_bless && std::env::var_os("POVINS_BLESS").is_some_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().expect("a parent folder"))
            .expect("create tests/golden");
        for (p, text) in [(&path, render(name, &now)), (&csv, states)] {
            std::fs::write(p, text).unwrap_or_else(|e| panic!("cannot write {}: {e}", p.display()));
        }
        println!(
            "blessed {} (total {:016x}) and {}",
            path.display(),
            now.total,
            csv.display()
        );
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
    let golden_states = std::fs::read_to_string(&csv).ok();
    if golden == now {
        assert!(
            golden_states.as_deref() == Some(states.as_str()),
            "{name}: the output matches the golden hashes but {} is missing or differs from \
             this run's states (edited by hand, or stale): re-bless with `{BLESS}`",
            csv.display()
        );
        println!("{name}: matches golden total {:016x}", now.total);
        return;
    }
    panic!(
        "{}",
        mismatch_message(name, out, &now, &golden, golden_states.as_deref(), &states)
    );
}

/// What a failing comparison prints: counts and totals, where the hashes first differ, and how
/// far the states moved (from the states files, when the golden one is readable).
pub fn mismatch_message(
    name: &str,
    out: &RunView<'_>,
    now: &Hashes,
    golden: &Hashes,
    golden_states: Option<&str>,
    states: &str,
) -> String {
    let t_s = |t_ns: i64| (t_ns - out.imu_rate.first().map_or(0, |s| s.t_ns)) as f64 * 1e-9;
    let mut msg = format!(
        "{name}: output differs from the golden file {}\n  states: {} now, {} golden; \
         keyframe reports: {} now, {} golden; total {:016x} now, {:016x} golden\n",
        golden_path(name).display(),
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
    let csv = states_path(name);
    match (golden_states.and_then(table::parse), table::parse(states)) {
        (Some(g), Some(n)) => {
            let c = table::compare(&g, &n);
            let _ = writeln!(msg, "  how much, from {}:", csv.display());
            if c.is_equal() {
                let _ = writeln!(
                    msg,
                    "    every decimated state agrees to the printed digits: the change is \
                     below their resolution, between the rows, or in the reports only"
                );
            } else {
                msg.push_str(&c.describe());
            }
        }
        _ => {
            let _ = writeln!(msg, "  (no readable {} to say how much)", csv.display());
        }
    }
    let _ = write!(
        msg,
        "  if the change is intended, re-bless with `{BLESS}` and commit tests/golden/"
    );
    msg
}

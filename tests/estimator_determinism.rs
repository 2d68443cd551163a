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

use common::golden::{check_golden, hash_report, hash_state, hashes, Fnv};
use common::*;
use povins::core::estimator::{KeyframeReport, VisualMode};
use povins::core::inertial::NavState;
use povins::host_tools::runner::{config_for, replay, InitMode, RunOutput};
use povins::platform::dataset::Dataset;

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
    small_stack(|| {
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
    small_stack(|| {
        let ds = simulate_robot(2, 20.0);
        let out = run_twice(&ds, config_for(&ds), InitMode::Groundtruth);
        check_golden("sim-robot-seed2-20s-gt", &out);
    });
}

/// LiDAR on (sweep de-skew, association, rejection, MSC LDM, depth-only optimization): the
/// same bits run after run, and against the golden file. The LiDAR events are part of the hash.
#[test]
fn simulated_robot_20s_with_lidar_is_deterministic_and_golden() {
    small_stack(|| {
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
    small_stack(|| {
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

//! Golden-file replay (PX4 style): the same input gives bit-identical output, and that output
//! has not changed since the golden files were blessed.
//!
//! Each run is replayed twice and the IMU-rate states must match bit for bit. The output is then
//! hashed (FNV-1a 64 over the bit patterns of `t, p, q, v, bg, ba` of every IMU-rate state,
//! then every keyframe report's numbers except the `*_ns` timings) and compared with
//! `tests/golden/<name>.hash`. Besides the total, the file keeps one hash per state and per
//! report so a mismatch can say where the output first changed. Beside it,
//! `tests/golden/<name>.csv` keeps the states decimated to 0.1 s and every keyframe's state with
//! its td, printed to a few digits: a mismatch also prints how far each column moved.
//!
//! After an intended change of the estimator's numbers, re-bless with
//! `POVINS_BLESS=1 cargo test --test estimator_determinism` and commit the files.

mod common;

use common::golden::table::{self, Kind};
use common::golden::{
    check_golden_of, hash_report, hash_state, hashes_of, mismatch_message, Fnv, RunView, BLESS,
};
use common::*;
use nalgebra::{UnitQuaternion, Vector3};
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
    assert_eq!(
        hashes_of(&RunView::of(a)),
        hashes_of(&RunView::of(b)),
        "keyframe reports differ between runs"
    );
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
        check_golden_of("euroc-v101-30s-static", &RunView::of(&out), true);
    });
}

#[test]
fn simulated_robot_20s_gt_init_is_deterministic_and_golden() {
    small_stack(|| {
        let ds = simulate_robot(2, 20.0);
        let out = run_twice(&ds, config_for(&ds), InitMode::Groundtruth);
        check_golden_of("sim-robot-seed2-20s-gt", &RunView::of(&out), true);
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
        check_golden_of("sim-robot-seed2-20s-gt-lidar", &RunView::of(&out), true);
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

/// The readable half of the golden files: a run perturbed on purpose (position y +3.2 mm from
/// 10 s on, yaw +0.01 deg from 15 s on, td +0.05 ms at the keyframes from 12 s on) is reported
/// column by column with the right magnitude and time, every other column unmoved, and a failing
/// golden check prints it.
#[test]
fn golden_mismatch_says_which_column_moved_and_how_much() {
    small_stack(|| {
        let ds = simulate_robot(2, 20.0);
        let out = replay(&ds, config_for(&ds), InitMode::Groundtruth, &quiet()).expect("replay");
        let view = RunView::of(&out);
        let t0 = out.imu_rate[0].t_ns;
        let after = |t_ns: i64, s: f64| t_ns - t0 >= (s * 1e9) as i64;
        let dyaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.01_f64.to_radians());
        let perturb = |s: &NavState| {
            let mut p = *s;
            if after(s.t_ns, 10.0) {
                p.p_wb.y += 3.2e-3;
            }
            if after(s.t_ns, 15.0) {
                p.q_wb = dyaw * p.q_wb;
            }
            p
        };
        let imu: Vec<NavState> = out.imu_rate.iter().map(perturb).collect();
        let kfs: Vec<NavState> = out.keyframe_states.iter().map(perturb).collect();
        let reports: Vec<KeyframeReport> = out
            .reports
            .iter()
            .map(|r| KeyframeReport {
                td_s: r.td_s + if after(r.t_ns, 12.0) { 5e-5 } else { 0.0 },
                ..*r
            })
            .collect();
        let moved = RunView {
            imu_rate: &imu,
            reports: &reports,
            keyframe_states: &kfs,
            ..view.clone()
        };
        let printed = |v: &RunView<'_>| {
            table::parse(&table::render("t", &table::table_of(v), BLESS)).expect("parses back")
        };
        let same = table::compare(&printed(&view), &printed(&view));
        assert!(same.is_equal());
        let c = table::compare(&printed(&view), &printed(&moved));
        assert!(!c.is_equal());
        assert!(c.only_golden.is_empty() && c.only_now.is_empty());
        let col = |n: &str| c.column(n).expect("a column");
        let t_of = |n: &str| -> f64 {
            col(n)
                .at
                .as_ref()
                .expect("a difference")
                .1
                .parse()
                .expect("a time")
        };
        // The printed digits bound the error: 1 um, 1e-5 deg, 0.1 us.
        assert!((col("p_wb_y_m").max_abs - 3.2e-3).abs() <= 1.1e-6, "{c:?}");
        assert!(t_of("p_wb_y_m") >= 10.0);
        assert!((col("yaw_deg").max_abs - 0.01).abs() <= 1.1e-5, "{c:?}");
        assert!(t_of("yaw_deg") >= 15.0);
        let td = col("td_ms");
        assert!((td.max_abs - 0.05).abs() <= 1.1e-4, "{c:?}");
        assert_eq!(td.at.as_ref().map(|a| a.0), Some(Kind::Keyframe));
        assert!(t_of("td_ms") >= 12.0);
        // Yaw about the world's z leaves roll and pitch (up to the last printed digit).
        assert!(col("roll_deg").max_abs <= 1.1e-5 && col("pitch_deg").max_abs <= 1.1e-5);
        for n in [
            "p_wb_x_m",
            "p_wb_z_m",
            "v_wb_x_mps",
            "v_wb_y_mps",
            "v_wb_z_mps",
            "bg_x_rps",
            "bg_y_rps",
            "bg_z_rps",
            "ba_x_mps2",
            "ba_y_mps2",
            "ba_z_mps2",
        ] {
            assert_eq!(col(n).max_abs, 0.0, "{n} moved: {c:?}");
        }
        let moved_by = |kind: Kind, what: &str| {
            let (_, m) = c.summary.iter().find(|s| s.0 == kind).expect("a kind");
            m.iter().find(|m| m.what == what).expect("a quantity").max
        };
        assert!(
            (moved_by(Kind::Imu, "position") - 3.2).abs() <= 1.1e-3,
            "{c:?}"
        );
        assert!(
            (moved_by(Kind::Keyframe, "position") - 3.2).abs() <= 1.1e-3,
            "{c:?}"
        );
        assert!(
            (moved_by(Kind::Imu, "attitude") - 0.01).abs() <= 2e-5,
            "{c:?}"
        );
        assert!(
            (moved_by(Kind::Keyframe, "td") - 0.05).abs() <= 1.1e-4,
            "{c:?}"
        );
        assert_eq!(moved_by(Kind::Imu, "velocity"), 0.0);
        let text = c.describe();
        println!("{text}");
        assert!(text.contains("position 3.20 mm"), "{text}");

        // The message of a failing golden check: the hashes' first difference and the columns
        // (against this run's own files, so that blessing the goldens in parallel cannot race).
        let msg = mismatch_message(
            "sim-robot-seed2-20s-gt",
            &moved,
            &hashes_of(&moved),
            &hashes_of(&view),
            Some(&table::render("t", &table::table_of(&view), BLESS)),
            &table::render("t", &table::table_of(&moved), BLESS),
        );
        println!("{msg}");
        let i = imu.iter().position(|s| after(s.t_ns, 10.0)).expect("10 s");
        let first = format!(
            "first differing state: #{i}, t = {} ns (10.000 s",
            imu[i].t_ns
        );
        assert!(msg.contains(&first), "{msg}");
        assert!(msg.contains("position 3.20 mm"), "{msg}");
        assert!(msg.contains("\n      p_wb_y_m "), "{msg}");
    });
}

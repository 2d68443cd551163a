//! LiDAR enhancement end to end on the simulator (robot scenario, Livox rosette, edge outliers
//! on): depths are associated and used, and they improve accuracy over PO-VINS-WO.

mod common;

use common::*;
use povins::core::estimator::{DepthEventKind, EstimatorConfig, KeyframeReport, PoVins};
use povins::core::inertial::NavState;
use povins::core::lidar::LdmMode;
use povins::host_tools::sim::Scenario;
use povins::platform::dataset::Dataset;

struct Run {
    counters: povins::core::estimator::Counters,
    states: Vec<NavState>,
    reports: Vec<KeyframeReport>,
    associated: usize,
    rejected: usize,
}

fn lidar_config(ds: &Dataset, on: bool, ldm: LdmMode, reject: bool, dopt: bool) -> EstimatorConfig {
    let mut cfg = sim_lidar_config(ds, on);
    cfg.lidar.ldm = ldm;
    cfg.lidar.depth_outlier_rejection = reject;
    cfg.lidar.depth_only_opt = dopt;
    cfg
}

/// Replays IMU, frames and sweeps in time order; a sweep is pushed after the first IMU sample
/// at or past its last point.
fn run(ds: &Dataset, cfg: EstimatorConfig) -> Run {
    run_sweeps(ds, cfg, &sweeps_of(ds))
}

/// [`run`] with the sweeps given as `(push time, points)`.
fn run_sweeps(
    ds: &Dataset,
    mut cfg: EstimatorConfig,
    sweeps: &[(i64, &[povins::core::lidar::LidarPoint])],
) -> Run {
    let (start, s0) = gt_start(ds, &mut cfg);
    let mut est: Box<PoVins> = new_estimator(cfg);
    est.initialize(s0).unwrap();
    let frames = frames_of(ds);
    let mut out = Run {
        counters: Default::default(),
        states: Vec::new(),
        reports: Vec::new(),
        associated: 0,
        rejected: 0,
    };
    drive_lidar(&mut est, &ds.imu[start..], &frames, sweeps, |est, _, o| {
        if let Some(r) = o.keyframe {
            out.reports.push(r);
            for e in est.lidar_events() {
                match e.kind {
                    DepthEventKind::Associated => out.associated += 1,
                    DepthEventKind::Rejected => out.rejected += 1,
                    DepthEventKind::Culled => {}
                }
            }
        }
        if let Some(n) = o.nav {
            out.states.push(n);
        }
        true
    });
    out.counters = est.counters();
    out
}

#[test]
fn lidar_depths_are_associated_used_and_improve_accuracy() {
    small_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 2, 40.0);
        let off = run(&ds, lidar_config(&ds, false, LdmMode::Msc, true, true));
        let on = run(&ds, lidar_config(&ds, true, LdmMode::Msc, true, true));
        let direct = run(&ds, lidar_config(&ds, true, LdmMode::Direct, true, true));
        let norej = run(&ds, lidar_config(&ds, true, LdmMode::Msc, false, true));
        let (a_off, a_on, a_dir, a_nr) = (
            ate_m(&ds, &off.states),
            ate_m(&ds, &on.states),
            ate_m(&ds, &direct.states),
            ate_m(&ds, &norej.states),
        );
        let ldm: u32 = on.reports.iter().map(|r| r.ldm_count).sum();
        eprintln!(
            "ATE off {a_off:.3} on {a_on:.3} direct {a_dir:.3} no-reject {a_nr:.3}; associated {} rejected {} ldm/kf {:.1}",
            on.associated,
            on.rejected,
            f64::from(ldm) / on.reports.len() as f64
        );
        assert!(on.associated > 1000, "associated {}", on.associated);
        assert!(ldm > 0);
        assert_eq!(off.associated, 0);
        assert!(a_on < a_off, "LiDAR on {a_on} vs off {a_off}");
    });
}

/// Corrupt or absurd sweeps (NaN, inf, all zeros, a huge count, reversed and far-off times)
/// are rejected and counted, never panic, and do not spoil the estimate.
#[test]
fn corrupt_sweeps_are_rejected_and_counted() {
    use povins::core::lidar::LidarPoint;
    small_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 4, 15.0);
        let clean = run(&ds, lidar_config(&ds, true, LdmMode::Msc, true, true));
        let mut bad = ds.clone();
        // Push times stay those of the clean sweeps: the estimator must cope with the content.
        let push_t: Vec<i64> = sweeps_of(&ds).iter().map(|w| w.0).collect();
        let mut n_invalid = 0u64;
        for (k, scan) in bad.lidar.iter_mut().enumerate() {
            match k % 10 {
                1 => scan.points.iter_mut().for_each(|p| p.p_l[0] = f32::NAN),
                3 => scan
                    .points
                    .iter_mut()
                    .for_each(|p| p.p_l[2] = f32::INFINITY),
                5 => scan.points.iter_mut().for_each(|p| p.p_l = [0.0; 3]),
                7 => scan
                    .points
                    .iter_mut()
                    .for_each(|p| p.t_ns += 3_600_000_000_000),
                9 => scan
                    .points
                    .iter_mut()
                    .for_each(|p| p.t_ns -= 3_600_000_000_000),
                _ => continue,
            }
            n_invalid += scan.points.len() as u64;
        }
        let mut sweeps: Vec<(i64, &[LidarPoint])> = push_t
            .iter()
            .zip(bad.lidar.iter())
            .map(|(t, s)| (*t, s.points.as_slice()))
            .collect();
        // A huge sweep (4x the buffer) with times in reverse order.
        let mut huge: Vec<LidarPoint> = ds.lidar[20..30]
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .collect();
        huge.extend(huge.clone());
        huge.extend(huge.clone());
        huge.reverse();
        let t_huge = push_t[29];
        sweeps.insert(30, (t_huge, huge.as_slice()));
        let out = run_sweeps(
            &bad,
            lidar_config(&bad, true, LdmMode::Msc, true, true),
            &sweeps,
        );
        let (a_clean, a_bad) = (ate_m(&ds, &clean.states), ate_m(&bad, &out.states));
        eprintln!(
            "clean ATE {a_clean:.3} m, with corrupt sweeps {a_bad:.3} m; rejected {} of {} invalid",
            out.counters.lidar_points_rejected, n_invalid
        );
        assert!(out.counters.lidar_points_rejected >= n_invalid);
        assert!(out.counters.lidar_points_evicted > 0);
        assert!(out.reports.len() > 40);
        assert!(out.states.iter().all(state_is_finite));
        assert!(a_bad < 2.0 * a_clean + 0.05, "{a_bad} vs {a_clean}");
    });
}

/// The whole problem's analytic gradient (MSC blocks with the inverse depth projected out at
/// tau*, direct LDM rows, visual, IMU and prior factors) against central differences of its
/// cost, after 30 keyframes of the robot with LiDAR.
#[test]
fn gradient_check_with_lidar_depths() {
    small_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 5, 12.0);
        for ldm in [LdmMode::Msc, LdmMode::Direct] {
            let mut cfg = lidar_config(&ds, true, ldm, true, true);
            let (start, s0) = gt_start(&ds, &mut cfg);
            let mut est = new_estimator(cfg);
            est.initialize(s0).unwrap();
            let frames = frames_of(&ds);
            let sweeps = sweeps_of(&ds);
            let mut ldm_used = 0;
            drive_lidar(&mut est, &ds.imu[start..], &frames, &sweeps, |e, _, o| {
                if let Some(r) = o.keyframe {
                    ldm_used = r.ldm_count;
                }
                e.counters().keyframes < 30
            });
            assert_eq!(est.counters().keyframes, 30);
            assert!(
                ldm_used > 10,
                "{ldm:?}: only {ldm_used} LiDAR-depth measurements"
            );
            let worst = est.gradient_check(1e-6).expect("gradient check");
            println!("{ldm:?}: worst relative gradient error {worst:.3e}");
            assert!(
                worst < 1e-4,
                "{ldm:?}: worst relative gradient error {worst:.3e}"
            );
        }
    });
}

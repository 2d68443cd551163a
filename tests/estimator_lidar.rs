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
fn run(ds: &Dataset, mut cfg: EstimatorConfig) -> Run {
    let (start, s0) = gt_start(ds, &mut cfg);
    let mut est: Box<PoVins> = new_estimator(cfg);
    est.initialize(s0).unwrap();
    let frames = frames_of(ds);
    let sweeps = sweeps_of(ds);
    let mut out = Run {
        states: Vec::new(),
        reports: Vec::new(),
        associated: 0,
        rejected: 0,
    };
    drive_lidar(&mut est, &ds.imu[start..], &frames, &sweeps, |est, _, o| {
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
    out
}

#[test]
fn lidar_depths_are_associated_used_and_improve_accuracy() {
    big_stack(|| {
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

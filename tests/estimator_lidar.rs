//! LiDAR enhancement end to end on the simulator (robot scenario, Livox rosette, edge outliers
//! on): depths are associated and used, and they improve accuracy over PO-VINS-WO.

mod common;

use common::*;
use povins::core::estimator::{DepthEventKind, EstimatorConfig, KeyframeReport, PoVins};
use povins::core::inertial::NavState;
use povins::core::lidar::{LdmMode, LidarExtrinsic};
use povins::host_tools::runner::config_for;
use povins::host_tools::sim::{simulate, Scenario, SimConfig};
use povins::platform::dataset::Dataset;

pub fn simulate_with_lidar(sc: Scenario, seed: u64, secs: f64) -> Dataset {
    let cfg = SimConfig::new(sc, seed, secs);
    simulate(&cfg, &|_, _, _| {})
        .unwrap_or_else(|e| panic!("simulation failed: {e:#}"))
        .dataset
}

struct Run {
    states: Vec<NavState>,
    reports: Vec<KeyframeReport>,
    associated: usize,
    rejected: usize,
}

fn lidar_config(ds: &Dataset, on: bool, ldm: LdmMode, reject: bool, dopt: bool) -> EstimatorConfig {
    let mut cfg = config_for(ds);
    cfg.clock = None;
    let t_bl = ds.calib.t_bl.expect("the simulated robot has a LiDAR");
    cfg.lidar.enabled = on;
    cfg.lidar.ldm = ldm;
    cfg.lidar.depth_outlier_rejection = reject;
    cfg.lidar.depth_only_opt = dopt;
    cfg.lidar.extrinsic = LidarExtrinsic {
        q_bl: t_bl.q_ab,
        p_bl: t_bl.p_ab,
    };
    cfg
}

/// Replays IMU, frames and sweeps in time order; a sweep is pushed after the first IMU sample
/// at or past its last point.
fn run(ds: &Dataset, mut cfg: EstimatorConfig) -> Run {
    let (start, s0) = gt_start(ds, &mut cfg);
    let mut est: Box<PoVins> = new_estimator(cfg);
    est.initialize(s0).unwrap();
    let frames = frames_of(ds);
    let sweeps: Vec<(i64, usize)> = {
        let mut v: Vec<(i64, usize)> = ds
            .lidar
            .iter()
            .enumerate()
            .map(|(i, s)| (s.points.iter().map(|p| p.t_ns).max().unwrap_or(s.t_ns), i))
            .collect();
        v.sort();
        v
    };
    let mut li = sweeps.partition_point(|s| s.0 < ds.imu[start].t_ns);
    let mut out = Run {
        states: Vec::new(),
        reports: Vec::new(),
        associated: 0,
        rejected: 0,
    };
    drive(&mut est, &ds.imu[start..], &frames, |est, s, o| {
        while let Some(&(t_end, i)) = sweeps.get(li).filter(|w| w.0 <= s.t_ns) {
            let _ = t_end;
            est.push_lidar(&ds.lidar[i].points);
            li += 1;
        }
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

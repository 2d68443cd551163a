mod common;
use common::*;
use povins::core::estimator::DepthEventKind;
use povins::host_tools::eval::lidar_assoc::true_depth_m;
use povins::host_tools::runner::{config_for, replay, InitMode};
use povins::host_tools::sim::Scenario;
use std::collections::{HashMap, HashSet};
#[test]
fn assoc() {
    big_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 1, 30.0);
        let mut cfg = config_for(&ds);
        cfg.lidar.sigma_dr_rel = std::env::var("REL")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0);
        let out = replay(&ds, cfg, InitMode::Groundtruth, &quiet()).unwrap();
        let truth = ds.sim_truth.as_ref().unwrap();
        let lm: HashMap<u64, _> = truth.landmarks_w.iter().cloned().collect();
        let edge: HashSet<u64> = truth.edge_features.iter().cloned().collect();
        let mut dv = HashMap::new();
        for st in &out.lidar_events {
            for e in &st.events {
                if e.kind == DepthEventKind::Rejected {
                    dv.insert(e.id, e.depth_m);
                }
            }
        }
        let mut n = 0;
        for st in &out.lidar_events {
            for e in &st.events {
                if e.kind != DepthEventKind::Associated {
                    continue;
                }
                let Some(p) = lm.get(&e.id) else { continue };
                let t = true_depth_m(
                    &ds.ground_truth,
                    &ds.calib.t_bc,
                    ds.calib.td_s,
                    st.t_cam_ns,
                    p,
                )
                .unwrap_or(f64::NAN);
                let gross = (e.depth_m - t).abs() > 1.0;
                if let Some(v) = dv.get(&e.id) {
                    if n < 30 {
                        eprintln!(
                            "rej id {} truth {:.2} d_r {:.2} d_v {:.2} edge {}",
                            e.id,
                            t,
                            e.depth_m,
                            v,
                            edge.contains(&e.id)
                        );
                        n += 1;
                    }
                } else if gross {
                    eprintln!(
                        "GROSS kept id {} truth {:.2} d_r {:.2} edge {}",
                        e.id,
                        t,
                        e.depth_m,
                        edge.contains(&e.id)
                    );
                }
            }
        }
    });
}

mod common;
use common::*;
use povins::core::estimator::DepthEventKind;
use povins::host_tools::eval::lidar_assoc::true_depth_m;
use povins::host_tools::runner::{config_for, replay, InitMode};
use povins::host_tools::sim::Scenario;
#[test]
fn assoc() {
    big_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 1, 30.0);
        let out = replay(&ds, config_for(&ds), InitMode::Groundtruth, &quiet()).unwrap();
        let truth = ds.sim_truth.as_ref().unwrap();
        let lm: std::collections::HashMap<u64, _> = truth.landmarks_w.iter().cloned().collect();
        let edge: std::collections::HashSet<u64> = truth.edge_features.iter().cloned().collect();
        let mut rejected = std::collections::HashSet::new();
        for st in &out.lidar_events {
            for e in &st.events {
                if e.kind == DepthEventKind::Rejected {
                    rejected.insert(e.id);
                }
            }
        }
        let mut rows = vec![];
        for st in &out.lidar_events {
            for e in &st.events {
                if e.kind != DepthEventKind::Associated {
                    continue;
                }
                let Some(p) = lm.get(&e.id) else { continue };
                let Some(t) = true_depth_m(
                    &ds.ground_truth,
                    &ds.calib.t_bc,
                    ds.calib.td_s,
                    st.t_cam_ns,
                    p,
                ) else {
                    continue;
                };
                rows.push((
                    t,
                    e.depth_m - t,
                    edge.contains(&e.id),
                    rejected.contains(&e.id),
                ));
            }
        }
        for (name, f) in [
            (
                "all",
                &(|_r: &(f64, f64, bool, bool)| true) as &dyn Fn(&(f64, f64, bool, bool)) -> bool,
            ),
            ("edge", &|r| r.2),
            ("nonedge", &|r| !r.2),
        ] {
            let mut v: Vec<f64> = rows.iter().filter(|r| f(r)).map(|r| r.1.abs()).collect();
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
            let q = |p: f64| v[((v.len() as f64 - 1.0) * p) as usize];
            let bad = v.iter().filter(|x| **x > 0.3).count();
            let rej_bad = rows
                .iter()
                .filter(|r| f(r) && r.1.abs() > 0.3 && r.3)
                .count();
            let rej_good = rows
                .iter()
                .filter(|r| f(r) && r.1.abs() <= 0.3 && r.3)
                .count();
            eprintln!("{name}: n {} med {:.3} p80 {:.3} p90 {:.3} p95 {:.3} bad {} rejected bad {} rejected good {}", v.len(), q(0.5), q(0.8), q(0.9), q(0.95), bad, rej_bad, rej_good);
        }
        for (lo, hi) in [(0.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 100.0)] {
            let v: Vec<&(f64, f64, bool, bool)> =
                rows.iter().filter(|r| r.0 >= lo && r.0 < hi).collect();
            let bad = v.iter().filter(|r| r.1.abs() > 0.3).count();
            let mut e: Vec<f64> = v.iter().map(|r| r.1.abs()).collect();
            e.sort_by(|a, b| a.partial_cmp(b).unwrap());
            if !e.is_empty() {
                eprintln!(
                    "depth {lo}-{hi}: n {} bad {} med {:.3} ; bias {:.3}",
                    v.len(),
                    bad,
                    e[e.len() / 2],
                    v.iter().map(|r| r.1).sum::<f64>() / v.len() as f64
                );
            }
        }
    });
}

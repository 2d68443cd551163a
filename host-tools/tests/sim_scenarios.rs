//! Scenario sanity: speeds per carrier, feature counts, track lengths, sensor rates and the
//! edge-case bookkeeping.

use povins_host_tools::sim::{simulate, LidarKind, Scenario, SimConfig, T0_NS};
use std::collections::BTreeMap;

#[test]
fn scenarios_are_sane() {
    for sc in [Scenario::Robot, Scenario::Handheld, Scenario::Vehicle] {
        let mut cfg = SimConfig::new(sc, 21, 15.0);
        if sc != Scenario::Vehicle {
            cfg.lidar_points = Some(3_000);
        }
        let out = simulate(&cfg, &|_, _, _| {}).expect("simulate");
        let ds = &out.dataset;
        let s = &out.summary;
        let truth = ds.sim_truth.as_ref().expect("truth");

        // Rates and bookkeeping.
        assert_eq!(ds.imu.len(), 3001);
        assert_eq!(ds.ground_truth.len(), ds.imu.len());
        assert!(ds
            .imu
            .windows(2)
            .all(|w| w[1].t_ns - w[0].t_ns == 5_000_000));
        assert!(ds
            .imu
            .iter()
            .zip(&ds.ground_truth)
            .all(|(m, g)| m.t_ns == g.t_ns));
        assert_eq!(ds.imu[0].t_ns, T0_NS);
        let cam_hz = if sc == Scenario::Vehicle { 10.0 } else { 20.0 };
        assert_eq!(ds.features.len(), (15.0 * cam_hz) as usize + 1);
        assert_eq!(ds.lidar.len(), 150);
        assert_eq!(truth.lidar_edge_points.len(), ds.lidar.len());
        let default_lidar = if sc == Scenario::Vehicle {
            LidarKind::Ouster
        } else {
            LidarKind::Livox
        };
        assert_eq!(cfg.lidar.unwrap_or(default_lidar), default_lidar);

        // Speed per carrier (after the start-up ramp).
        let (vmin, vmax) = s.speed_range_mps;
        match sc {
            Scenario::Robot => assert!(vmax <= 1.5 && vmin > 0.5, "robot {vmin}..{vmax}"),
            Scenario::Handheld => assert!(
                vmin > 0.5 && vmax < 2.0 && s.max_rate_rps > 1.5,
                "handheld {vmin}..{vmax}"
            ),
            Scenario::Vehicle => assert!(vmin >= 15.0 && vmax <= 30.0, "vehicle {vmin}..{vmax}"),
            // Not in this test's list (the MAV scenarios are checked elsewhere).
            Scenario::Flight | Scenario::Fast => {}
        }

        // Features: within the cap, inside the image, enough of them, sorted ids per frame.
        let cap = if sc == Scenario::Vehicle { 150 } else { 200 };
        let cam = &ds.calib.camera;
        let mut len: BTreeMap<u64, usize> = BTreeMap::new();
        for f in &ds.features {
            assert!(f.obs.len() <= cap);
            assert!(f.obs.windows(2).all(|w| w[0].id < w[1].id));
            for o in &f.obs {
                assert!(
                    o.u_px > 0.0
                        && o.v_px > 0.0
                        && o.u_px < cam.width as f64
                        && o.v_px < cam.height as f64
                );
                *len.entry(o.id).or_insert(0) += 1;
            }
        }
        assert!(
            s.mean_features > 0.6 * cap as f64,
            "{sc:?}: {} features/frame",
            s.mean_features
        );
        let mean_len = len.values().sum::<usize>() as f64 / len.len() as f64;
        assert!(
            (4.0..60.0).contains(&mean_len),
            "{sc:?}: mean track length {mean_len}"
        );
        assert!(len.values().any(|&l| l >= 20), "{sc:?}: no long tracks");
        assert_eq!(
            len.len(),
            truth.landmarks_w.len(),
            "every id has a landmark"
        );

        // Edge cases exist but are a minority.
        let n_tracks = truth.landmarks_w.len();
        assert!(!truth.wrong_tracks.is_empty() && truth.wrong_tracks.len() * 20 < n_tracks);
        assert!(!truth.edge_features.is_empty() && truth.edge_features.len() * 2 < n_tracks);
        let pts: usize = ds.lidar.iter().map(|l| l.points.len()).sum();
        let edge_pts: usize = truth
            .lidar_edge_points
            .iter()
            .flatten()
            .filter(|&&b| b)
            .count();
        assert!(pts > 150 * 1_000, "{sc:?}: {pts} LiDAR points");
        assert!(
            edge_pts > 0 && edge_pts * 4 < pts,
            "{sc:?}: {edge_pts} edge points of {pts}"
        );
        // Calibration: nominal LiDAR mounting stored, the true one differs by the configured error.
        let nominal = ds.calib.t_bl.expect("t_bl");
        let truth_bl = out.t_bl_true.expect("true t_bl");
        let ang = nominal.q_ab.angle_to(&truth_bl.q_ab).to_degrees();
        assert!(
            (ang - 0.5).abs() < 1e-6,
            "{sc:?}: extrinsic rotation error {ang}"
        );
        assert!(((nominal.p_ab - truth_bl.p_ab).norm() - 0.03).abs() < 1e-9);
    }
}

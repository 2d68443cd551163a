//! Feature prediction for INS-aided tracking (`Estimator::predict_features`): where the window's
//! landmarks will appear in the next image, from the INS pose and the landmark depths (pose-only
//! depths, and depth-only optimized LiDAR depths). Measured against the positions the real EuRoC
//! front end found, and the simulator's tracks with LiDAR; the baseline is "the feature stays
//! where it was in the previous image".

mod common;

use common::*;
use povins::core::camera::FeatureObs;
use povins::core::estimator::{EstimatorConfig, FeaturePrediction, PoVins, VisualMode};
use povins::core::inertial::NavState;
use povins::core::lidar::LidarPoint;
use povins::core::Error;
use povins::host_tools::sim::Scenario;
use povins::platform::dataset::Dataset;
use std::collections::BTreeMap;

#[derive(Default)]
struct Errors {
    /// Predicted vs observed, px.
    predicted: Vec<f64>,
    /// The same features: previous observation vs observed, px.
    still: Vec<f64>,
    /// Predicted vs observed for LiDAR landmarks, px.
    lidar: Vec<f64>,
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Replays like `drive_lidar`, predicting every frame just before it is offered.
fn prediction_errors(
    ds: &Dataset,
    cfg: EstimatorConfig,
    start: Option<(usize, NavState)>,
    sweeps: &[(i64, &[LidarPoint])],
) -> Errors {
    let mut est = new_estimator(cfg);
    let imu = match start {
        Some((i, st)) => {
            est.initialize(st).expect("initialize");
            &ds.imu[i..]
        }
        None => &ds.imu[..],
    };
    let frames = frames_of(ds);
    let t0 = imu.first().map_or(i64::MIN, |s| s.t_ns);
    let (mut fi, mut li) = (
        frames.partition_point(|f| f.0 < t0),
        sweeps.partition_point(|w| w.0 < t0),
    );
    let mut buf = vec![FeaturePrediction::EMPTY; 200];
    let mut prev: BTreeMap<u64, (f64, f64)> = BTreeMap::new();
    let mut e = Errors::default();
    for s in imu {
        while let Some(f) = frames.get(fi).filter(|f| f.0 <= s.t_ns) {
            let obs: BTreeMap<u64, (f64, f64)> =
                f.1.iter()
                    .map(|o: &FeatureObs| (o.id, (o.u_px, o.v_px)))
                    .collect();
            if let Ok(n) = est.predict_features(f.0, &mut buf) {
                for p in &buf[..n] {
                    let (Some(o), Some(q)) = (obs.get(&p.id), prev.get(&p.id)) else {
                        continue;
                    };
                    let err = (p.uv_px[0] - o.0).hypot(p.uv_px[1] - o.1);
                    e.predicted.push(err);
                    e.still.push((q.0 - o.0).hypot(q.1 - o.1));
                    if p.lidar {
                        e.lidar.push(err);
                    }
                }
            }
            let _ = est.push_frame(f.0, f.1);
            prev = obs;
            fi += 1;
        }
        let _ = est.push_imu(s);
        while let Some(w) = sweeps.get(li).filter(|w| w.0 <= s.t_ns) {
            let _ = est.push_lidar(w.1);
            li += 1;
        }
        while step(&mut est).is_some() {}
    }
    e
}

#[test]
fn euroc_predictions_land_near_the_tracked_features() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let e = prediction_errors(&ds, euroc_config(&ds, VisualMode::PoseOnly), None, &[]);
        let (mp, ms) = (median(&e.predicted), median(&e.still));
        println!(
            "EuRoC 30 s: {} predictions, median error {mp:.2} px (features stay put: {ms:.2} px)",
            e.predicted.len()
        );
        assert!(e.predicted.len() > 5_000, "{}", e.predicted.len());
        assert!(mp < 1.5, "median prediction error {mp:.2} px");
        assert!(mp < 0.4 * ms, "{mp:.2} px vs {ms:.2} px without prediction");
    });
}

#[test]
fn lidar_landmarks_are_predicted_from_their_depth_only_optimized_depth() {
    small_stack(|| {
        let ds = simulate_with_lidar(Scenario::Handheld, 3, 20.0);
        let mut cfg = sim_lidar_config(&ds, true);
        let start = gt_start(&ds, &mut cfg);
        let sweeps = sweeps_of(&ds);
        let e = prediction_errors(&ds, cfg, Some(start), &sweeps);
        let (mp, ml, ms) = (median(&e.predicted), median(&e.lidar), median(&e.still));
        println!(
            "hand-held 20 s: {} predictions ({} LiDAR), median error {mp:.2} px, LiDAR {ml:.2} px \
             (features stay put: {ms:.2} px)",
            e.predicted.len(),
            e.lidar.len()
        );
        assert!(e.lidar.len() > 500, "{}", e.lidar.len());
        // 1 px pixel noise on both the anchor and the new observation: about 1.5 px median.
        assert!(ml < 2.5, "median LiDAR prediction error {ml:.2} px");
        assert!(mp < 0.2 * ms, "{mp:.2} px vs {ms:.2} px without prediction");
    });
}

#[test]
fn prediction_refuses_what_it_cannot_know() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let mut est: Box<PoVins> = new_estimator(euroc_config(&ds, VisualMode::PoseOnly));
        let mut buf = [FeaturePrediction::EMPTY; 4];
        let t = ds.imu[0].t_ns;
        assert_eq!(
            est.predict_features(t, &mut buf),
            Err(Error::NotInitialized)
        );
        let frames = frames_of(&ds);
        drive(&mut est, &ds.imu[..ds.imu.len() / 2], &frames, |_, _, _| {
            true
        });
        let t_end = ds.imu[ds.imu.len() / 2 - 1].t_ns;
        // Far past the newest IMU sample, or long before the buffered span: out of range.
        assert_eq!(
            est.predict_features(t_end + 1_000_000_000, &mut buf),
            Err(Error::OutOfRange)
        );
        assert_eq!(est.predict_features(t, &mut buf), Err(Error::OutOfRange));
        // An empty buffer takes nothing; a small one is filled, never overrun.
        assert_eq!(est.predict_features(t_end, &mut []), Ok(0));
        assert_eq!(est.predict_features(t_end, &mut buf), Ok(4));
        assert!(buf
            .iter()
            .all(|p| p.depth_m > 0.0 && p.uv_px[0].is_finite()));
    });
}

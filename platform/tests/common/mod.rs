//! Shared helpers of the platform integration tests.
#![allow(dead_code)]

use povins_core::camera::{Distortion, FeatureObs, PinholeCamera};
use povins_core::inertial::{ImuNoise, ImuSample, NavState};
use povins_core::lidar::LidarPoint;
use povins_core::math::{Quat, Vec3};
use povins_platform::dataset::{
    Calibration, Dataset, Extrinsic, FeatureFrame, ImageFrame, LidarScan, SimTruth,
};
use std::path::PathBuf;

/// A data folder: the repository's copy (`tests/data`) when there is one, else the shared one
/// (tests on it are `#[ignore]`d); fails (never skips) when it is missing.
pub fn shared(rel: &str) -> PathBuf {
    let repo = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data")).join(rel);
    if repo.exists() {
        return repo;
    }
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")).join(rel);
    assert!(
        p.exists(),
        "shared data not found at {} (clone the repo next to shared/)",
        p.display()
    );
    p
}

/// Non-trivial values with full mantissas (so lossy formatting would show).
fn wobble(i: usize, k: f64) -> f64 {
    (i as f64 * 0.37 + k).sin() * (1.0 + k) / 3.0
}

/// A small synthetic sequence with every sensor: 0.5 s of 200 Hz IMU, 10 Hz features and
/// 16x12 images, 2 LiDAR sweeps, 20 Hz ground truth and simulator truth.
pub fn synthetic(name: &str) -> Dataset {
    let t0: i64 = 1_520_531_836_203_640_699;
    let imu = (0..100)
        .map(|i| ImuSample {
            t_ns: t0 + i as i64 * 5_000_000 + (i as i64 % 3),
            gyro_rps: Vec3::new(wobble(i, 0.1), wobble(i, 0.2), wobble(i, 0.3)),
            accel_mps2: Vec3::new(wobble(i, 1.1), wobble(i, 1.2), 9.81 + wobble(i, 1.3)),
        })
        .collect();
    let features = (0..5)
        .map(|f| FeatureFrame {
            t_ns: t0 + f as i64 * 100_000_000,
            obs: (0..7)
                .map(|k| FeatureObs {
                    id: (f + k) as u64 * 3 + 100,
                    // Multiples of 1/64 px are exact in f32, as the MCAP channels carry them.
                    u_px: 10.0 + ((f * 37 + k * 91) % 700) as f64 + (k as f64) / 64.0,
                    v_px: 5.0 + ((f * 53 + k * 29) % 450) as f64 + (f as f64) / 32.0,
                })
                .collect(),
        })
        .collect();
    let images = (0..3)
        .map(|f| ImageFrame {
            t_ns: t0 + f as i64 * 100_000_000,
            width: 16,
            height: 12,
            mono8: (0..16 * 12)
                .map(|p| ((p * 7 + f * 31) % 256) as u8)
                .collect(),
            path: None,
        })
        .collect();
    let lidar = (0..2)
        .map(|s| LidarScan {
            t_ns: t0 + s as i64 * 100_000_000,
            points: (0..50)
                .map(|p| LidarPoint {
                    t_ns: t0 + s as i64 * 100_000_000 + p as i64 * 1_999_999,
                    p_l: [
                        wobble(p, 2.0) as f32 * 10.0,
                        wobble(p, 2.5) as f32 * 10.0,
                        wobble(p, 3.0) as f32,
                    ],
                    intensity: p as f32 * 1.5,
                })
                .collect(),
        })
        .collect();
    let ground_truth = (0..10)
        .map(|i| NavState {
            t_ns: t0 + i as i64 * 50_000_000,
            p_wb: Vec3::new(wobble(i, 4.0), wobble(i, 4.1), 1.0 + wobble(i, 4.2)),
            q_wb: Quat::from_euler_angles(wobble(i, 5.0), wobble(i, 5.1), 3.0 * wobble(i, 5.2)),
            v_wb: Vec3::new(wobble(i, 6.0), wobble(i, 6.1), wobble(i, 6.2)),
            bg: Vec3::new(1e-3 * wobble(i, 7.0), 2e-3, -3e-3),
            ba: Vec3::new(0.05, -0.02 * wobble(i, 8.0), 0.01),
        })
        .collect();
    Dataset {
        name: name.into(),
        calib: Calibration {
            camera: PinholeCamera {
                readout_s: 0.0,
                width: 16,
                height: 12,
                fx: 458.654,
                fy: 457.296,
                cx: 367.215,
                cy: 248.375,
                distortion: Distortion::RadTan {
                    k1: -0.28340811,
                    k2: 0.07395907,
                    p1: 0.00019359,
                    p2: 1.76187114e-05,
                },
            },
            t_bc: Extrinsic {
                q_ab: Quat::from_euler_angles(-1.55, 0.02, -1.56),
                p_ab: Vec3::new(-0.0216401454975, -0.064676986768, 0.00981073058949),
            },
            td_s: 0.0013,
            camera_rate_hz: 10.0,
            imu_noise: ImuNoise {
                bias_corr_time_s: Some(300.0),
                ..ImuNoise::EUROC_ADIS16448
            },
            imu_rate_hz: 200.0,
            gravity_mps2: 9.80766,
            t_bl: Some(Extrinsic {
                q_ab: Quat::from_euler_angles(0.01, -0.02, 1.2),
                p_ab: Vec3::new(0.1, 0.0, -0.05),
            }),
            td_l_s: -0.0042,
        },
        imu,
        features,
        images,
        lidar,
        ground_truth,
        sim_truth: Some(SimTruth {
            landmarks_w: vec![
                (100, Vec3::new(1.0 / 3.0, -2.5, 7.125)),
                (103, Vec3::new(0.1, 0.2, 0.3)),
            ],
            wrong_tracks: vec![103],
            edge_features: vec![100, 106],
            lidar_edge_points: vec![vec![true, false, false], vec![false; 50]],
        }),
    }
}

/// The stamps of the simulator's truth messages povins writes for `ds` (one per stamp at which
/// ids are first observed), in order.
pub fn sim_truth_stamps(ds: &Dataset) -> Vec<i64> {
    let truth = ds.sim_truth.as_ref().expect("a simulator truth");
    let mut stamps: Vec<i64> = truth
        .landmarks(&ds.features)
        .iter()
        .map(|l| l.first_ns)
        .collect();
    stamps.dedup();
    stamps
}

/// Angle between two rotations, rad (exactly 0 only for bit-identical quaternions).
pub fn angle(a: &Quat, b: &Quat) -> f64 {
    if a == b {
        0.0
    } else {
        a.angle_to(b).max(f64::MIN_POSITIVE)
    }
}

/// Asserts two datasets are equal, quaternions within `q_tol_rad` and ground-truth velocities
/// within `v_tol` (everything else bit-exact).
pub fn assert_same(a: &Dataset, b: &Dataset, q_tol_rad: f64, v_tol: f64) {
    assert_eq!(a.name, b.name);
    let (ca, cb) = (&a.calib, &b.calib);
    assert_eq!(ca.camera, cb.camera);
    assert_eq!(ca.t_bc.p_ab, cb.t_bc.p_ab);
    assert!(angle(&ca.t_bc.q_ab, &cb.t_bc.q_ab) <= q_tol_rad);
    assert_eq!(ca.t_bl.is_some(), cb.t_bl.is_some());
    if let (Some(x), Some(y)) = (&ca.t_bl, &cb.t_bl) {
        assert_eq!(x.p_ab, y.p_ab);
        assert!(angle(&x.q_ab, &y.q_ab) <= q_tol_rad);
    }
    assert_eq!(ca.td_l_s, cb.td_l_s);
    assert_eq!(
        (
            ca.td_s,
            ca.camera_rate_hz,
            ca.imu_noise,
            ca.imu_rate_hz,
            ca.gravity_mps2
        ),
        (
            cb.td_s,
            cb.camera_rate_hz,
            cb.imu_noise,
            cb.imu_rate_hz,
            cb.gravity_mps2
        )
    );
    assert_eq!(a.imu, b.imu);
    assert_eq!(a.features, b.features);
    assert_eq!(a.lidar, b.lidar);
    assert_eq!(a.images.len(), b.images.len());
    for (x, y) in a.images.iter().zip(&b.images) {
        assert_eq!((x.t_ns, x.width, x.height), (y.t_ns, y.width, y.height));
        assert!(x.mono8 == y.mono8, "pixels differ at {} ns", x.t_ns);
    }
    assert_eq!(a.ground_truth.len(), b.ground_truth.len());
    for (x, y) in a.ground_truth.iter().zip(&b.ground_truth) {
        assert_eq!((x.t_ns, x.p_wb, x.bg, x.ba), (y.t_ns, y.p_wb, y.bg, y.ba));
        assert!(angle(&x.q_wb, &y.q_wb) <= q_tol_rad, "{} ns", x.t_ns);
        assert!(
            (x.v_wb - y.v_wb).amax() <= v_tol,
            "{} ns: {} vs {}",
            x.t_ns,
            x.v_wb,
            y.v_wb
        );
    }
    // The per-point LiDAR edge flags are the simulator's statistics: no file keeps them.
    let evaluated = |t: &Option<SimTruth>| {
        t.clone().map(|t| SimTruth {
            lidar_edge_points: Vec::new(),
            ..t
        })
    };
    assert_eq!(evaluated(&a.sim_truth), evaluated(&b.sim_truth));
}

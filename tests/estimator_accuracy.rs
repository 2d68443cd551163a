//! End-to-end accuracy on real and peer-simulated data: the IMU-rate trajectory against ground
//! truth (position ATE after position + yaw alignment, as `povins run` reports it), solver
//! health, and the gradient self-check of the assembled problem on real data.

mod common;

use common::*;
use povins::core::estimator::VisualMode;
use povins::host_tools::runner::{replay, InitMode};
use povins::host_tools::sim::{simulate, LidarKind, Scenario, SimConfig};

#[test]
fn euroc_30s_pose_only_static_init() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, VisualMode::PoseOnly);
        let out = replay(&ds, cfg, InitMode::Static, &quiet()).expect("replay");
        let ate = ate_m(&ds, &out.imu_rate);
        println!(
            "EuRoC 30 s pose-only: ATE {ate:.4} m, {} keyframes, counters {:?}",
            out.reports.len(),
            out.counters
        );
        assert!(ate < 0.2, "EuRoC pose-only ATE {ate:.4} m >= 0.2 m");
        assert_eq!(out.counters.solver_failures, 0, "{:?}", out.counters);
        assert!(
            out.reports.len() > 40,
            "only {} keyframes",
            out.reports.len()
        );
        assert!(out.imu_rate.iter().all(state_is_finite));
    });
}
/// Without the VINS-Mono re-use of marginalized landmarks, each observation is counted once:
/// the re-anchored landmarks leave the information their observation at 0 adds given the others
/// (the whole factor less the part that stays, `estimator::marginalize`). It was 0.100 m when the
/// observation at 0 left as a two-view residual.
#[test]
fn euroc_30s_marginalization_without_reuse() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let mut cfg = povins::host_tools::runner::config_for(&ds);
        cfg.reuse_marginalized_landmarks = false;
        let out = replay(&ds, cfg, InitMode::Static, &quiet()).expect("replay");
        let ate = ate_m(&ds, &out.imu_rate);
        println!("EuRoC 30 s without re-use: ATE {ate:.4} m");
        assert!(ate < 0.06, "ATE {ate:.4} m >= 0.06 m");
        assert_eq!(out.counters.solver_failures, 0, "{:?}", out.counters);
    });
}

/// Issue 13's bar with the default configuration (the `sensor.yaml` densities, which describe the
/// IMU at rest): the window measures the vibration in flight and raises the white-noise densities
/// (`estimator::imu_noise`); without that it is 0.0318 m (0.036 m before the delay's wide prior
/// with its information hold, issue 31; 0.041 m before the feature velocities came from the INS
/// motion: each made the fixed-noise run better, the measured-noise one stays at 0.0294 m).
#[test]
fn euroc_30s_default_config_measures_the_vibration() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let run = |adapt: bool| {
            let mut cfg = povins::host_tools::runner::config_for(&ds);
            cfg.imu_noise_adapt.enabled = adapt;
            let out = replay(&ds, cfg, InitMode::Static, &quiet()).expect("replay");
            let scale = out.reports.last().map_or(0.0, |r| r.imu_noise_scale);
            (ate_se3_m(&ds, &out.imu_rate), scale)
        };
        let ((ate, scale), (ate_fixed, scale_fixed)) = (run(true), run(false));
        println!(
            "EuRoC 30 s default config: ATE (SE3) {ate:.4} m with the noise measured (x{scale:.2}), \
             {ate_fixed:.4} m with sensor.yaml's"
        );
        assert!(ate <= 0.030, "ATE {ate:.4} m > 0.030 m (issue 13's bar)");
        assert!(ate < 0.95 * ate_fixed, "{ate:.4} vs {ate_fixed:.4} m");
        assert!((2.0..10.0).contains(&scale), "noise scale {scale}");
        assert_eq!(scale_fixed, 1.0);
    });
}

/// The simulated EuRoC-like flight (the same IMU with exactly `sensor.yaml`'s noise): the window
/// finds nothing to add; the measurement does run (with no tolerance for the window's own
/// approximations it would raise the noise).
#[test]
fn exact_imu_noise_is_left_alone() {
    small_stack(|| {
        let mut sc = SimConfig::new(Scenario::Flight, 3, 40.0);
        sc.lidar = Some(LidarKind::None);
        let ds = simulate(&sc, &|_, _, _| {}).expect("simulation").dataset;
        let largest = |tolerance: f64| {
            let mut cfg = povins::host_tools::runner::config_for(&ds);
            cfg.imu_noise_adapt.tolerance = tolerance;
            let out = replay(&ds, cfg, InitMode::Groundtruth, &quiet()).expect("replay");
            assert!(out.reports.len() > 40);
            out.reports
                .iter()
                .map(|r| r.imu_noise_scale)
                .fold(0.0, f64::max)
        };
        let default = povins::core::estimator::ImuNoiseAdapt::default().tolerance;
        let (max, max_strict) = (largest(default), largest(0.5));
        println!(
            "simulated flight, exact IMU noise: largest noise scale {max:.3} ({max_strict:.3} with \
             tolerance 0.5)"
        );
        assert!((1.0..1.2).contains(&max), "noise scale {max}");
        assert!(
            max_strict > 1.3,
            "noise scale with tolerance 0.5: {max_strict}"
        );
    });
}

#[test]
fn euroc_30s_inverse_depth_static_init() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, VisualMode::InverseDepth);
        let out = replay(&ds, cfg, InitMode::Static, &quiet()).expect("replay");
        let ate = ate_m(&ds, &out.imu_rate);
        println!(
            "EuRoC 30 s inverse-depth: ATE {ate:.4} m, {} keyframes, counters {:?}",
            out.reports.len(),
            out.counters
        );
        assert!(ate < 0.5, "EuRoC inverse-depth ATE {ate:.4} m >= 0.5 m");
        assert!(
            out.reports.len() > 40,
            "only {} keyframes",
            out.reports.len()
        );
        assert!(out.imu_rate.iter().all(state_is_finite));
    });
}
#[test]
#[ignore = "needs ../shared/data/openvins-sim-corridor-mono (large shared sequence; CI runs it with --ignored)"]
fn openvins_corridor_first_100s_gt_init() {
    small_stack(|| {
        let mut ds = load(OPENVINS_CORRIDOR);
        truncate(&mut ds, 100.0);
        let cfg = povins::host_tools::runner::config_for(&ds);
        let out = replay(&ds, cfg, InitMode::Groundtruth, &quiet()).expect("replay");
        let ate = ate_m(&ds, &out.imu_rate);
        println!(
            "OpenVINS corridor 100 s: ATE {ate:.4} m, {} keyframes, counters {:?}",
            out.reports.len(),
            out.counters
        );
        assert!(ate < 0.2, "corridor ATE {ate:.4} m >= 0.2 m");
        assert!(
            out.reports.len() > 100,
            "only {} keyframes",
            out.reports.len()
        );
        assert!(out.imu_rate.iter().all(state_is_finite));
    });
}
#[test]
fn gradient_check_after_30_keyframes_of_euroc() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, VisualMode::PoseOnly);
        let mut est = new_estimator(cfg);
        let frames = frames_of(&ds);
        // Stop feeding once 30 keyframes exist: the window is full and a marginalization prior
        // (from 20 marginalizations) is part of the problem.
        drive(&mut est, &ds.imu, &frames, |e, _, _| {
            e.counters().keyframes < 30
        });
        assert_eq!(est.counters().keyframes, 30);
        assert_eq!(est.keyframes().count(), 10, "the window is full");
        let worst = est.gradient_check(1e-6).expect("gradient check");
        println!("gradient check after 30 EuRoC keyframes: worst relative error {worst:.3e}");
        assert!(worst < 1e-4, "worst relative gradient error {worst:.3e}");
    });
}

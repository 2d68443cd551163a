//! The health monitor catches a window that slides away as a whole.
//!
//! A simulated robot (seed 9, 30 s) with exact feature tracks (no pixel noise) and 3% wrong
//! tracks breaks down at 27 s: one solve moves the keyframes of the last 3 s by about 8 m while
//! the newest keyframe's velocity, biases and residuals stay within the monitor's limits, so the
//! checks of the newest keyframe alone let it through and the run ends 3.4 m off (ATE). The
//! window-correction check (`HealthConfig::max_window_correction_m`) sees the jump of the older
//! keyframes, drops the window and continues from the INS.

mod common;

use common::*;
use povins::core::estimator::Breakdown;
use povins::host_tools::runner::config_for;
use povins::host_tools::sim::{simulate, LidarKind, Scenario, SimConfig};

struct Outcome {
    ate_m: f64,
    jumps: usize,
    reinitializations: u64,
    max_correction_m: f64,
}

fn run(check: bool) -> Outcome {
    let mut sc = SimConfig::new(Scenario::Robot, 9, 30.0);
    sc.lidar = Some(LidarKind::None);
    sc.pixel_noise_px = 0.0;
    sc.wrong_track_rate = Some(0.03);
    let ds = simulate(&sc, &|_, _, _| {})
        .unwrap_or_else(|e| panic!("simulation failed: {e:#}"))
        .dataset;
    let mut cfg = config_for(&ds);
    cfg.td_s = 0.0;
    cfg.estimate_td = false;
    if !check {
        cfg.health.max_window_correction_m = f64::INFINITY;
    }
    let (start, s0) = gt_start(&ds, &mut cfg);
    let mut est = new_estimator(cfg);
    est.initialize(s0).expect("initialize from ground truth");
    let frames = frames_of(&ds);
    let (mut states, mut jumps, mut max_correction_m) = (Vec::new(), 0, 0.0f64);
    drive(&mut est, &ds.imu[start..], &frames, |_, _, o| {
        states.extend(o.nav);
        if let Some(r) = o.keyframe {
            jumps += usize::from(r.breakdown == Some(Breakdown::WindowJump));
            max_correction_m = max_correction_m.max(r.window_correction_m);
        }
        true
    });
    assert!(states.iter().all(state_is_finite));
    Outcome {
        ate_m: ate_m(&ds, &states),
        jumps,
        reinitializations: est.counters().reinitializations,
        max_correction_m,
    }
}

#[test]
fn a_window_that_slides_away_as_a_whole_is_caught_and_reinitialized() {
    small_stack(|| {
        let without = run(false);
        let with = run(true);
        println!(
            "without the check: ATE {:.3} m, largest correction {:.2} m; with it: ATE {:.3} m, \
             {} window jumps, {} re-initializations",
            without.ate_m, without.max_correction_m, with.ate_m, with.jumps, with.reinitializations
        );
        // The breakdown this test is about happens (else it tests nothing).
        assert!(without.max_correction_m > 3.0, "no jump to catch");
        assert!(
            without.ate_m > 1.0,
            "ATE {:.3} m without the check",
            without.ate_m
        );
        // Caught, counted, and the run stays near the truth.
        assert!(with.jumps >= 1, "the jump was not caught");
        assert_eq!(with.reinitializations, with.jumps as u64);
        assert!(with.ate_m < 0.2, "ATE {:.3} m with the check", with.ate_m);
    });
}

//! The health monitor catches a window that slides away as a whole, and the images' rest is not
//! believed against the INS speed.
//!
//! A simulated robot (seed 9, 30 s) with exact feature tracks (no pixel noise) and 3% wrong
//! tracks, with zero-velocity updates trusted whatever the INS speed (as before
//! `zupt.max_speed_mps`), breaks down at 27 s: one solve moves the keyframes of the last 3 s by
//! about 8 m while the newest keyframe's velocity, biases and residuals stay within the monitor's
//! limits, so the checks of the newest keyframe alone let it through and the run ends 3.4 m off
//! (ATE). The window-correction check (`HealthConfig::max_window_correction_m`) sees the jump of
//! the older keyframes, drops the window and continues from the INS.
//!
//! The run's first error was a zero-velocity update at motion onset: the robot starts at 2.0 s,
//! its features hardly move in the first half second, and the keyframe at 2.5 s (true speed
//! 0.098 m/s) got a zero-velocity and a zero-motion factor, which pulled the accelerometer bias
//! off. With the INS speed gate that keyframe moves freely and the same run needs no rescue.

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
    /// Keyframes given the zero-velocity factor while the truth moved faster than 2 cm/s.
    rest_while_moving: usize,
}

/// Robot seed 9, 30 s, exact tracks, `wrong_track_rate` wrong ones, delay 0 and known.
/// `check`: the window-correction check on; `gate`: the INS speed gate of the zero-velocity
/// updates on.
fn run(wrong_track_rate: f64, check: bool, gate: bool) -> Outcome {
    let mut sc = SimConfig::new(Scenario::Robot, 9, 30.0);
    sc.lidar = Some(LidarKind::None);
    sc.pixel_noise_px = 0.0;
    sc.wrong_track_rate = Some(wrong_track_rate);
    let ds = simulate(&sc, &|_, _, _| {})
        .unwrap_or_else(|e| panic!("simulation failed: {e:#}"))
        .dataset;
    let mut cfg = config_for(&ds);
    cfg.td_s = 0.0;
    cfg.td.estimate = false;
    if !check {
        cfg.health.max_window_correction_m = f64::INFINITY;
    }
    if !gate {
        cfg.zupt.max_speed_mps = 1e9;
    }
    let (start, s0) = gt_start(&ds, &mut cfg);
    let mut est = new_estimator(cfg);
    est.initialize(s0).expect("initialize from ground truth");
    let frames = frames_of(&ds);
    let (mut states, mut jumps, mut max_correction_m) = (Vec::new(), 0, 0.0f64);
    let mut rest_while_moving = 0;
    drive(&mut est, &ds.imu[start..], &frames, |_, _, o| {
        states.extend(o.nav);
        if let Some(r) = o.keyframe {
            jumps += usize::from(r.breakdown == Some(Breakdown::WindowJump));
            max_correction_m = max_correction_m.max(r.window_correction_m);
            rest_while_moving += usize::from(r.at_rest && true_speed_mps(&ds, r.t_ns) > 0.02);
        }
        true
    });
    assert!(states.iter().all(state_is_finite));
    Outcome {
        ate_m: ate_m(&ds, &states),
        jumps,
        reinitializations: est.counters().reinitializations,
        max_correction_m,
        rest_while_moving,
    }
}

/// Speed of the ground truth at its last sample not after `t_ns`, m/s.
fn true_speed_mps(ds: &povins::platform::dataset::Dataset, t_ns: i64) -> f64 {
    let i = ds.ground_truth.partition_point(|g| g.t_ns <= t_ns);
    ds.ground_truth
        .get(i.saturating_sub(1))
        .map_or(f64::NAN, |g| g.v_wb.norm())
}

#[test]
fn a_window_that_slides_away_as_a_whole_is_caught_and_reinitialized() {
    small_stack(|| {
        let without = run(0.03, false, false);
        let with = run(0.03, true, false);
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

#[test]
fn the_images_rest_is_not_believed_while_the_ins_moves() {
    small_stack(|| {
        for wrong in [0.0, 0.03] {
            let trusted = run(wrong, true, false);
            let gated = run(wrong, true, true);
            println!(
                "{:.0}% wrong tracks: rest trusted: ATE {:.4} m, {} keyframes at rest while moving, \
                 {} re-initializations; gated: ATE {:.4} m, {}, {}",
                100.0 * wrong,
                trusted.ate_m,
                trusted.rest_while_moving,
                trusted.reinitializations,
                gated.ate_m,
                gated.rest_while_moving,
                gated.reinitializations
            );
            assert!(trusted.rest_while_moving >= 1, "no false rest to avoid");
            assert_eq!(gated.rest_while_moving, 0);
            assert_eq!(gated.reinitializations, 0);
            assert!(
                gated.ate_m < 0.6 * trusted.ate_m && gated.ate_m < 0.05,
                "ATE {:.4} m gated against {:.4} m trusted",
                gated.ate_m,
                trusted.ate_m
            );
        }
    });
}

//! The IMU-rate fast path (`povins_core::inertial::FastPath`) follows the estimator's own
//! IMU-rate state bit for bit on real data: applied at once (lockstep, the threaded pipeline's
//! deterministic mode) at every sample, and applied late (as a back-end thread delivers them)
//! at every sample once no update is in flight.

mod common;

use common::*;
use povins::core::camera::FeatureObs;
use povins::core::estimator::VisualMode;
use povins::core::inertial::{FastPath, ImuSample, InsUpdate};
use std::collections::VecDeque;

struct Tally {
    compared: usize,
    updates: usize,
    keyframes: usize,
}

/// Replays EuRoC V1_01 (30 s, static initialization) and feeds every accepted sample to a fast
/// path, applying each estimator update `delay` samples after it was made.
fn follow_euroc(delay: usize) -> Tally {
    let ds = load(EUROC_30S);
    let cfg = euroc_config(&ds, VisualMode::PoseOnly);
    let mut est = new_estimator(cfg);
    let mut fast: FastPath<256> = FastPath::with_limits(cfg.max_gyro_rps, cfg.max_accel_mps2);
    let frames: Vec<(i64, &[FeatureObs])> = ds
        .features
        .iter()
        .map(|f| (f.t_ns, f.obs.as_slice()))
        .collect();
    let mut in_flight: VecDeque<(usize, InsUpdate)> = VecDeque::new();
    let mut tally = Tally {
        compared: 0,
        updates: 0,
        keyframes: 0,
    };
    let mut k = 0usize;
    drive(&mut est, &ds.imu, &frames, |_, s: &ImuSample, out| {
        let f = fast
            .push_imu(s)
            .expect("the estimator accepted this sample");
        if let Some(u) = out.ins {
            in_flight.push_back((k + delay, u));
            tally.updates += 1;
        }
        tally.keyframes += usize::from(out.keyframe.is_some());
        let mut latest = f;
        while in_flight.front().is_some_and(|(at, _)| *at <= k) {
            if let Some((_, u)) = in_flight.pop_front() {
                latest = fast.apply(&u);
            }
        }
        if in_flight.is_empty() {
            assert_eq!(
                latest.map(|n| state_bits(&n)),
                out.nav.map(|n| state_bits(&n)),
                "fast path differs from the estimator at sample {k} (t = {} ns, delay {delay})",
                s.t_ns
            );
            tally.compared += usize::from(out.nav.is_some());
        }
        k += 1;
        true
    });
    assert_eq!(fast.counters().updates_too_old, 0);
    assert!(fast.counters().max_replay as usize >= delay.min(1));
    tally
}

#[test]
fn fast_path_in_lockstep_is_the_estimators_output() {
    let t = small_stack(|| follow_euroc(0));
    // Every running sample compared; updates at keyframes and interpolated frames only.
    assert!(t.keyframes > 40, "only {} keyframes", t.keyframes);
    assert!(t.compared > 4000, "only {} states compared", t.compared);
    assert!(
        t.updates < t.compared / 2,
        "{} updates for {} states: the fast path is not following the INS on its own",
        t.updates,
        t.compared
    );
}

#[test]
fn late_updates_replay_to_the_estimators_output() {
    // Updates come at most once per camera frame (10 IMU samples on EuRoC): delays below that
    // leave samples with none in flight, where the states must agree exactly.
    for delay in [1, 5, 9] {
        let t = small_stack(move || follow_euroc(delay));
        assert!(
            t.compared > 500,
            "delay {delay}: only {} compared",
            t.compared
        );
    }
}

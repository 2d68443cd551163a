//! The IMU-rate fast path (`povins_core::inertial::FastPath`) follows the estimator's own
//! IMU-rate state bit for bit on real data: applied at once (lockstep, the threaded pipeline's
//! deterministic mode) at every sample, and applied late (as a back-end thread delivers them)
//! at every sample once no update is in flight.

mod common;

use common::*;
use povins::core::estimator::VisualMode;
use povins::core::inertial::{FastPath, InsUpdate};
use povins::platform::dataset::Dataset;
use std::collections::VecDeque;

struct Tally {
    compared: usize,
    updates: usize,
    keyframes: usize,
    withheld: usize,
}

/// Replays EuRoC V1_01 (30 s, static initialization) and feeds every accepted sample to a fast
/// path, applying each estimator update `delay` samples after it was made.
fn follow_euroc(delay: usize) -> Tally {
    follow(&load(EUROC_30S), delay)
}

/// [`follow_euroc`] on `ds`, in the replay's order (`common::drive`), the fast path fed each
/// sample as it is pushed (as the pipeline feeds it). The states are compared where no update
/// is in flight and the estimator's output is for the sample just pushed (after a clock jump
/// the samples wait for a frame, and their outputs come together later).
fn follow(ds: &Dataset, delay: usize) -> Tally {
    let cfg = euroc_config(ds, VisualMode::PoseOnly);
    let mut est = new_estimator(cfg);
    let mut fast: FastPath<256> = FastPath::with_limits(cfg.max_gyro_rps, cfg.max_accel_mps2);
    let mut in_flight: VecDeque<(usize, InsUpdate)> = VecDeque::new();
    let mut tally = Tally {
        compared: 0,
        updates: 0,
        keyframes: 0,
        withheld: 0,
    };
    let mut k = 0usize;
    let mut fi = 0;
    for s in &ds.imu {
        while let Some(f) = ds.features.get(fi).filter(|f| f.t_ns <= s.t_ns) {
            let _ = est.push_frame(f.t_ns, &f.obs);
            fi += 1;
        }
        let _ = est.push_imu(s);
        let mut latest = fast
            .push_imu(s)
            .expect("the estimator accepted this sample");
        while let Some(out) = step(&mut est) {
            if let Some(u) = out.ins {
                in_flight.push_back((k + delay, u));
                tally.updates += 1;
            }
            tally.keyframes += usize::from(out.keyframe.is_some());
            tally.withheld += usize::from(out.nav_withheld);
            while in_flight.front().is_some_and(|(at, _)| *at <= k) {
                if let Some((_, u)) = in_flight.pop_front() {
                    latest = fast.apply(&u);
                }
            }
            if in_flight.is_empty() && out.nav.is_none_or(|n| n.t_ns == s.t_ns) {
                assert_eq!(
                    latest.map(|n| state_bits(&n)),
                    out.nav.map(|n| state_bits(&n)),
                    "fast path differs from the estimator at sample {k} (t = {} ns, delay {delay})",
                    s.t_ns
                );
                tally.compared += usize::from(out.nav.is_some());
            }
            k += 1;
        }
    }
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

/// A +1 h clock jump in every stream 15 s in (`estimator::clock_jump`): the fast path, which
/// sees the jump as a gap and stops, is handed the INS on the inputs' clock and follows the
/// estimator bit for bit again.
#[test]
fn the_fast_path_follows_across_a_clock_jump() {
    let t = small_stack(|| {
        let ds = load(EUROC_30S);
        let at = ds.imu[0].t_ns + 15_000_000_000;
        follow(&jumped(&ds, at, 3_600_000_000_000), 0)
    });
    assert!(t.compared > 4000, "only {} states compared", t.compared);
}

/// A 1 s IMU gap 15 s in, bridged as a long gap: the estimator withholds its state after the
/// gap until keyframes correct it, the fast path is reset for that time (it publishes nothing
/// either) and then follows the estimator bit for bit again.
#[test]
fn the_fast_path_is_reset_while_the_state_after_a_long_gap_is_withheld() {
    let t = small_stack(|| {
        let mut ds = load(EUROC_30S);
        let at = ds.imu[0].t_ns + 15_000_000_000;
        ds.imu
            .retain(|s| s.t_ns <= at || s.t_ns > at + 1_000_000_000);
        follow(&ds, 0)
    });
    assert!(t.withheld > 0, "nothing withheld after the gap");
    assert!(t.compared > 4000, "only {} states compared", t.compared);
}

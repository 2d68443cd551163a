//! The estimator never panics on bad input and counts what it rejects. The base stream is real
//! (EuRoC V1_01, first 30 s, static start, `configs/euroc.toml`), corrupted in one way per test.
//!
//! Where the corruption only adds input that must be rejected (non-finite or out-of-order IMU
//! samples, junk observations, out-of-order frames), the test also asserts that the accepted
//! input's output is bit-identical to the clean run: a rejected item must change nothing.

mod common;

use common::*;
use povins::core::camera::FeatureObs;
use povins::core::estimator::{
    Counters, PoVins, Status, VisualMode, GAP_WITHHOLD_MAX_S, MAX_FEATURES,
};
use povins::core::inertial::{ImuSample, NavState};
use povins::core::math::Vec3;
use povins::host_tools::runner::interpolate_state;
use povins::platform::dataset::Dataset;

/// What a run produced.
struct Run {
    states: Vec<NavState>,
    keyframe_times: Vec<i64>,
    counters: Counters,
    status: Status,
}

type Frames = Vec<(i64, Vec<FeatureObs>)>;

fn euroc() -> (Dataset, Frames) {
    let ds = load(EUROC_30S);
    let frames = ds
        .features
        .iter()
        .map(|f| (f.t_ns, f.obs.clone()))
        .collect();
    (ds, frames)
}

/// Replays `imu` and `frames` (in the given order) from a static start; `hook` runs after every
/// accepted sample.
fn run_with(
    ds: &Dataset,
    imu: &[ImuSample],
    frames: &Frames,
    mut hook: impl FnMut(&mut PoVins, &ImuSample),
) -> Run {
    let mut est = new_estimator(euroc_config(ds, VisualMode::PoseOnly));
    let slices: Vec<(i64, &[FeatureObs])> =
        frames.iter().map(|(t, o)| (*t, o.as_slice())).collect();
    let mut states = Vec::with_capacity(imu.len());
    let mut keyframe_times = Vec::new();
    drive(&mut est, imu, &slices, |e, s, o| {
        if let Some(n) = o.nav {
            states.push(n);
        }
        if let Some(r) = o.keyframe {
            keyframe_times.push(r.t_ns);
        }
        hook(e, s);
        true
    });
    Run {
        states,
        keyframe_times,
        counters: est.counters(),
        status: est.status(),
    }
}

fn run(ds: &Dataset, imu: &[ImuSample], frames: &Frames) -> Run {
    run_with(ds, imu, frames, |_, _| {})
}

fn assert_same_states(clean: &Run, other: &Run, what: &str) {
    assert_eq!(
        clean.states.len(),
        other.states.len(),
        "{what}: state counts differ"
    );
    if let Some(i) = (0..clean.states.len())
        .find(|&i| state_bits(&clean.states[i]) != state_bits(&other.states[i]))
    {
        panic!(
            "{what}: the output changed at state #{i} (t = {} ns)",
            clean.states[i].t_ns
        );
    }
}

fn assert_finite(r: &Run, what: &str) {
    if let Some(s) = r.states.iter().find(|s| !state_is_finite(s)) {
        panic!("{what}: non-finite state at t = {} ns: {s:?}", s.t_ns);
    }
}

/// Time of a run's first navigation output (its static initialization), ns.
fn init_time(r: &Run) -> i64 {
    r.states.first().expect("the run initializes").t_ns
}

/// ATE of the uncorrupted run, m (the reference of the fault tests).
fn clean_ate(ds: &Dataset, frames: &Frames) -> f64 {
    ate_m(ds, &run(ds, &ds.imu, frames).states)
}

fn secs(ds: &Dataset, s: f64) -> i64 {
    ds.imu[0].t_ns + (s * 1e9) as i64
}

/// `ds`'s IMU samples less those after `gap0` up to `gap1` (ns): an IMU gap.
fn imu_without(ds: &Dataset, gap0: i64, gap1: i64) -> Vec<ImuSample> {
    ds.imu
        .iter()
        .copied()
        .filter(|s| s.t_ns <= gap0 || s.t_ns > gap1)
        .collect()
}

fn keyframes_after(r: &Run, t_ns: i64) -> usize {
    r.keyframe_times.iter().filter(|&&t| t > t_ns).count()
}

/// `fix` undoes the expected effect of the corruption on `other`'s counters; everything else
/// must equal the clean run's.
fn assert_counters_equal_except(
    clean: &Counters,
    other: &Counters,
    mut fix: impl FnMut(&mut Counters),
) {
    let mut o = *other;
    fix(&mut o);
    assert_eq!(*clean, o, "counters differ beyond the injected corruption");
}

#[test]
fn nonfinite_imu_samples_are_rejected_counted_and_change_nothing() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let clean = run(&ds, &ds.imu, &frames);
        let mut imu = Vec::new();
        let mut injected = 0u64;
        for (k, s) in ds.imu.iter().enumerate() {
            imu.push(*s);
            if k % 97 == 50 {
                // A newer stamp, so only the values can be the reason for the rejection.
                let mut bad = ImuSample {
                    t_ns: s.t_ns + 1_000,
                    ..*s
                };
                match injected % 4 {
                    0 => bad.gyro_rps.x = f64::NAN,
                    1 => bad.accel_mps2.z = f64::INFINITY,
                    2 => bad.accel_mps2.y = f64::NEG_INFINITY,
                    _ => bad.gyro_rps = Vec3::repeat(f64::NAN),
                }
                imu.push(bad);
                injected += 1;
            }
        }
        let r = run(&ds, &imu, &frames);
        println!("injected {injected} non-finite samples: {:?}", r.counters);
        assert!(injected > 60);
        assert_eq!(r.counters.imu_rejected_nonfinite, injected);
        assert_counters_equal_except(&clean.counters, &r.counters, |c| {
            c.imu_rejected_nonfinite = 0
        });
        assert_same_states(&clean, &r, "non-finite IMU samples");
    });
}

#[test]
fn imu_time_going_backwards_or_repeating_is_rejected_counted_and_changes_nothing() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let clean = run(&ds, &ds.imu, &frames);
        let mut imu = Vec::new();
        let mut injected = 0u64;
        for (k, s) in ds.imu.iter().enumerate() {
            imu.push(*s);
            if k % 89 == 20 {
                let bad = match injected % 4 {
                    // An exact repeat.
                    0 => *s,
                    // The same stamp with other values.
                    1 => ImuSample {
                        gyro_rps: s.gyro_rps * 3.0,
                        ..*s
                    },
                    // Half a sample period back.
                    2 => ImuSample {
                        t_ns: s.t_ns - 2_500_000,
                        accel_mps2: -s.accel_mps2,
                        ..*s
                    },
                    // A second back.
                    _ => ImuSample {
                        t_ns: s.t_ns - 1_000_000_000,
                        ..*s
                    },
                };
                imu.push(bad);
                injected += 1;
            }
        }
        let r = run(&ds, &imu, &frames);
        println!("injected {injected} out-of-order samples: {:?}", r.counters);
        assert!(injected > 60);
        assert_eq!(r.counters.imu_rejected_time, injected);
        assert_counters_equal_except(&clean.counters, &r.counters, |c| c.imu_rejected_time = 0);
        assert_same_states(&clean, &r, "out-of-order IMU samples");
    });
}

/// A 1 s IMU gap while the MAV still stands on the ground: the estimator resets, and the static
/// period after the gap initializes it again.
#[test]
fn imu_gap_at_rest_resets_and_reinitializes_from_the_next_static_period() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let (gap0, gap1) = (secs(&ds, 2.4), secs(&ds, 3.4));
        let imu = imu_without(&ds, gap0, gap1);
        let r = run(&ds, &imu, &frames);
        let ate = ate_m(&ds, &r.states);
        println!(
            "gap at rest: {:?}, {} keyframes after the gap, ATE {ate:.4} m",
            r.counters,
            keyframes_after(&r, gap1)
        );
        assert!(init_time(&r) < gap0, "initialized before the gap");
        assert_eq!(r.counters.resets, 1);
        // No output between the reset and the new initialization (>= min_static_s later).
        let reinit = r
            .states
            .iter()
            .find(|s| s.t_ns > gap1)
            .expect("output after the gap")
            .t_ns;
        assert!(
            reinit >= gap1 + 1_000_000_000,
            "re-initialized {} ns after the gap",
            reinit - gap1
        );
        assert!(keyframes_after(&r, gap1) > 40);
        assert_eq!(r.status, Status::Running);
        assert_finite(&r, "gap at rest");
        assert!(ate < 0.2, "ATE {ate:.4} m after re-initialization");
    });
}

/// A 2 s IMU gap in flight (longer than `imu_gap.bridge_max_s`, and the line over 2 s of this
/// vibrating accelerometer misses by more than the long-gap limits): the estimator resets and
/// waits (there is no static period); `initialize` with the true state restarts it and it
/// produces keyframes again.
#[test]
fn imu_gap_in_flight_resets_and_restarts_after_initialize() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let (gap0, gap1) = (secs(&ds, 15.0), secs(&ds, 17.0));
        let imu = imu_without(&ds, gap0, gap1);
        let mut restarted = None;
        let r = run_with(&ds, &imu, &frames, |e, s| {
            if s.t_ns > gap1 && restarted.is_none() {
                // The first sample after the gap has reset the estimator.
                assert_eq!(e.counters().resets, 1);
                assert_eq!(e.status(), Status::WaitingForInit);
                let gt = interpolate_state(&ds.ground_truth, s.t_ns).expect("ground truth");
                e.initialize(gt).expect("initialize");
                restarted = Some(s.t_ns);
            }
        });
        let t_re = restarted.expect("the gap was reached");
        let after: Vec<NavState> = r.states.iter().copied().filter(|s| s.t_ns > t_re).collect();
        let ate = ate_m(&ds, &after);
        let last = r.states.last().expect("output");
        let gt_last = interpolate_state(&ds.ground_truth, last.t_ns).expect("ground truth");
        let err_end = (last.p_wb - gt_last.p_wb).norm();
        println!(
            "gap in flight: {:?}, {} keyframes after the restart, ATE after it {ate:.4} m, \
             final position error {err_end:.3} m",
            r.counters,
            keyframes_after(&r, t_re)
        );
        assert_eq!(r.counters.resets, 1);
        assert!(keyframes_after(&r, t_re) > 20);
        assert_eq!(r.counters.solver_failures, 0);
        assert_finite(&r, "gap in flight");
        assert!(ate < 0.2, "ATE {ate:.4} m after the restart");
        // Started in the ground-truth frame: no alignment needed.
        assert!(err_end < 0.5, "final position error {err_end:.3} m");
    });
}

/// IMU gaps in flight up to `imu_gap.bridge_max_s` (0.6 s) are bridged: no reset, the output
/// continues across the gap (an estimate at the first sample after it), each gap is counted
/// and reported at its sample, no keyframe is taken inside the gap, and the accuracy stays near
/// the clean run's (real EuRoC V1_01, gaps 15 s in).
#[test]
fn imu_gaps_in_flight_are_bridged_without_a_reset() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let ate_clean = clean_ate(&ds, &frames);
        for gap_s in [0.06, 0.2, 0.5] {
            let (gap0, gap1) = (secs(&ds, 15.0), secs(&ds, 15.0 + gap_s));
            let imu = imu_without(&ds, gap0, gap1);
            let mut reported = Vec::new();
            let mut states = Vec::new();
            let mut keyframes = Vec::new();
            let mut est = new_estimator(euroc_config(&ds, VisualMode::PoseOnly));
            let slices: Vec<(i64, &[FeatureObs])> =
                frames.iter().map(|(t, o)| (*t, o.as_slice())).collect();
            drive(&mut est, &imu, &slices, |_, s, o| {
                if let Some(g) = o.gap_bridged_s {
                    reported.push((s.t_ns, g));
                }
                if let Some(n) = o.nav {
                    states.push(n);
                }
                if let Some(r) = o.keyframe {
                    keyframes.push(r.t_ns);
                }
                true
            });
            let c = est.counters();
            let ate = ate_m(&ds, &states);
            println!(
                "{gap_s} s gap: bridged {:?}, resets {}, ATE {ate:.4} m (clean {ate_clean:.4})",
                reported, c.resets
            );
            assert_eq!(c.resets, 0, "{gap_s} s gap: {c:?}");
            assert_eq!(c.imu_gaps_bridged, 1, "{gap_s} s gap: {c:?}");
            assert_eq!(reported.len(), 1, "{gap_s} s gap");
            let first_after = imu
                .iter()
                .find(|s| s.t_ns > gap1)
                .expect("IMU after the gap");
            assert_eq!(reported[0].0, first_after.t_ns);
            assert!((reported[0].1 - gap_s).abs() < 0.01, "{:?}", reported[0]);
            assert!(states.iter().any(|n| n.t_ns == first_after.t_ns));
            let inside = |t: i64| t > gap0 && t < first_after.t_ns;
            assert!(
                !keyframes.iter().any(|&t| inside(t)),
                "a keyframe inside the gap"
            );
            assert!(
                keyframes.iter().filter(|&&t| t > gap1).count() > 20,
                "keyframes after the gap"
            );
            assert!(
                ate < 1.5 * ate_clean + 0.01,
                "{gap_s} s gap: ATE {ate:.4} m"
            );
        }
    });
}

/// A 1 s IMU gap in flight, bridged as a long gap (`imu_gap.long_bridge_max_s`): the INS
/// crosses it on the line between the samples around it, so its state after the gap is
/// withheld (`ImuOutput::nav_withheld`, `nav_state()` `None`) from the first sample after the
/// gap until the second keyframe after it (the first whose interval was measured), and what
/// is then published stays near the clean run's state: before, the first outputs after the
/// gap were 0.40 m off and the velocity 0.5 m/s off until the second keyframe (ATE 0.0357 m).
#[test]
fn a_long_imu_gap_withholds_the_state_until_keyframes_correct_it() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let clean = run(&ds, &ds.imu, &frames);
        let (gap0, gap1) = (secs(&ds, 15.0), secs(&ds, 16.0));
        let imu = imu_without(&ds, gap0, gap1);
        let mut withheld = Vec::new();
        let mut states = Vec::new();
        let mut est = new_estimator(euroc_config(&ds, VisualMode::PoseOnly));
        let slices: Vec<(i64, &[FeatureObs])> =
            frames.iter().map(|(t, o)| (*t, o.as_slice())).collect();
        drive(&mut est, &imu, &slices, |e, s, o| {
            if o.nav_withheld {
                assert!(o.nav.is_none(), "a withheld state was handed out");
                assert!(e.nav_state().is_none(), "nav_state() hands it out");
                withheld.push(s.t_ns);
            }
            states.extend(o.nav);
            true
        });
        let c = est.counters();
        assert_eq!((c.resets, c.imu_gaps_bridged_long), (0, 1), "{c:?}");
        let first_after = imu
            .iter()
            .find(|s| s.t_ns > gap1)
            .expect("IMU after the gap");
        // Withheld from the first sample after the gap, until the second keyframe after it
        // (0.55 s here), and never longer than GAP_WITHHOLD_MAX_S.
        assert_eq!(withheld.first(), Some(&first_after.t_ns), "{withheld:?}");
        let span_s = (withheld[withheld.len() - 1] - withheld[0]) as f64 * 1e-9;
        assert!(span_s < GAP_WITHHOLD_MAX_S, "withheld for {span_s} s");
        let released = states
            .iter()
            .filter(|n| n.t_ns > gap1)
            .take_while(|n| n.t_ns < first_after.t_ns + 1_000_000_000);
        let mut worst = 0.0f64;
        for n in released {
            let c = povins::host_tools::runner::interpolate_state(&clean.states, n.t_ns)
                .expect("the clean run covers it");
            worst = worst.max((n.p_wb - c.p_wb).norm());
        }
        let ate = ate_m(&ds, &states);
        println!(
            "1 s gap: withheld {} samples ({span_s:.3} s), published within {worst:.3} m of the \
             clean run over the second after it, ATE {ate:.4} m",
            withheld.len()
        );
        assert!(
            worst < 0.1,
            "{worst} m from the clean run just after the gap"
        );
        assert!(ate < 0.032, "ATE {ate:.4} m");
    });
}

/// Inertial spikes inside the sensor's range are caught (`imu_spike`): single accelerometer
/// and gyro spikes, ten spikes half a second apart and a 0.1 s burst of garbage are dropped
/// and counted (the burst's hole bridged), a reading at the full scale is refused as clipped,
/// nothing resets, and the accuracy stays at the clean run's.
#[test]
fn imu_spikes_and_bursts_are_dropped_and_counted() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let ate_clean = clean_ate(&ds, &frames);
        let (t15, t16, t24) = (secs(&ds, 15.0), secs(&ds, 16.0), secs(&ds, 24.0));
        let t25 = secs(&ds, 25.0);
        let mut next_spike = secs(&ds, 17.0);
        let mut spikes = 0;
        // Garbage that alternates in sign from sample to sample, different on every axis.
        let garbage = |k: u64, scale: f64| {
            let sign = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
            Vec3::new(1.0, -0.7, 0.4 + 0.1 * (k % 5) as f64) * (sign * scale)
        };
        let (mut did15, mut did16, mut did25) = (false, false, false);
        let mut burst = 0u64;
        let imu: Vec<ImuSample> = ds
            .imu
            .iter()
            .map(|s| {
                let mut s = *s;
                if !did15 && s.t_ns >= t15 {
                    s.accel_mps2.x = 150.0;
                    did15 = true;
                } else if !did16 && s.t_ns >= t16 {
                    s.gyro_rps.y = 34.0;
                    did16 = true;
                } else if spikes < 10 && s.t_ns >= next_spike {
                    s.accel_mps2.z = -150.0;
                    spikes += 1;
                    next_spike += 500_000_000;
                } else if s.t_ns >= t24 && s.t_ns < t24 + 100_000_000 {
                    s.gyro_rps = garbage(burst, 30.0);
                    s.accel_mps2 = garbage(burst + 1, 150.0);
                    burst += 1;
                } else if !did25 && s.t_ns >= t25 {
                    s.accel_mps2.y = 160.0;
                    did25 = true;
                }
                s
            })
            .collect();
        let r = run(&ds, &imu, &frames);
        let ate = ate_m(&ds, &r.states);
        let c = r.counters;
        println!("spikes: {c:?}, ATE {ate:.4} m (clean {ate_clean:.4}), burst of {burst}");
        assert_eq!(c.resets, 0, "{c:?}");
        assert_eq!(c.imu_rejected_range, 1, "the clipped reading: {c:?}");
        assert!(c.imu_spikes_rejected >= 12 + burst - 2, "{c:?}");
        assert!(c.imu_spikes_rejected <= 12 + burst, "{c:?}");
        assert_eq!(c.imu_gaps_bridged, 1, "the burst's hole: {c:?}");
        assert_finite(&r, "spikes");
        assert!(
            ate < 1.2 * ate_clean,
            "ATE {ate:.4} m, clean {ate_clean:.4} m"
        );
    });
}

/// A 3 s camera dropout in flight: the open keyframe interval fills up, the window is dropped
/// and the INS goes on alone (no reset: an estimate at every IMU sample), and the first
/// frames after the dropout start a new window.
#[test]
fn a_camera_dropout_keeps_the_ins_going_and_starts_a_new_window() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let ate_clean = clean_ate(&ds, &frames);
        let (d0, d1) = (secs(&ds, 12.0), secs(&ds, 15.0));
        let kept: Frames = frames
            .iter()
            .filter(|(t, _)| *t < d0 || *t >= d1)
            .cloned()
            .collect();
        let r = run(&ds, &ds.imu, &kept);
        let ate = ate_m(&ds, &r.states);
        let c = r.counters;
        println!("camera dropout: {c:?}, ATE {ate:.4} m (clean {ate_clean:.4})");
        assert_eq!(c.resets, 0, "{c:?}");
        assert_eq!(c.interval_overflows, 1, "{c:?}");
        let during = r
            .states
            .iter()
            .filter(|s| s.t_ns >= d0 && s.t_ns < d1)
            .count();
        let imu_during = ds
            .imu
            .iter()
            .filter(|s| s.t_ns >= d0 && s.t_ns < d1)
            .count();
        assert_eq!(
            during, imu_during,
            "an estimate at every IMU sample of the dropout"
        );
        assert!(keyframes_after(&r, d1) > 20);
        assert_finite(&r, "camera dropout");
        // 0.125 m against 0.029 m clean on this 30 s run (the INS alone for the last 0.5 s of
        // the dropout, then a new window from its state).
        assert!(ate < 0.2, "ATE {ate:.4} m, clean {ate_clean:.4} m");
    });
}

/// Observations the front end must reject are appended to real frames: NaN and infinite pixels,
/// pixels outside the image, a repeated id (the first occurrence is the real one) and frames
/// longer than `MAX_FEATURES`. Every one is counted and none changes the output.
#[test]
fn junk_observations_are_rejected_counted_and_change_nothing() {
    small_stack(|| {
        let (ds, mut frames) = euroc();
        let clean = run(&ds, &ds.imu, &frames);
        // Frames before the initialization only feed track velocities and are not counted.
        let t_from = init_time(&clean) + 500_000_000;
        let (w, h) = (ds.calib.camera.width as f64, ds.calib.camera.height as f64);
        let mut injected = 0u64;
        let mut next_id = 1u64 << 40;
        let mut junk = |u_px: f64, v_px: f64| {
            next_id += 1;
            FeatureObs {
                id: next_id,
                u_px,
                v_px,
            }
        };
        let mut long_frames = 0;
        for (k, (t, obs)) in frames.iter_mut().enumerate() {
            if *t <= t_from || obs.is_empty() {
                continue;
            }
            if k % 3 == 0 {
                let first = obs[0];
                obs.extend([
                    junk(f64::NAN, 100.0),
                    junk(200.0, f64::NAN),
                    junk(f64::INFINITY, 100.0),
                    junk(-5.0, 100.0),
                    junk(100.0, h + 5.0),
                    junk(w + 5.0, 1e12),
                    FeatureObs {
                        u_px: first.u_px + 2.0,
                        ..first
                    },
                ]);
                injected += 7;
            }
            if k % 50 == 1 {
                // Past MAX_FEATURES: the tail is cut at the frame capacity, the rest is outside
                // the image.
                let n = MAX_FEATURES + 20 - obs.len();
                obs.extend((0..n).map(|_| junk(-100.0, -100.0)));
                injected += n as u64;
                long_frames += 1;
            }
        }
        let r = run(&ds, &ds.imu, &frames);
        println!(
            "injected {injected} junk observations ({long_frames} frames > MAX_FEATURES): {:?}",
            r.counters
        );
        assert!(long_frames >= 8);
        assert_eq!(
            r.counters.features_rejected,
            clean.counters.features_rejected + injected
        );
        assert_eq!(
            r.counters.features_received,
            clean.counters.features_received + injected
        );
        assert_counters_equal_except(&clean.counters, &r.counters, |c| {
            c.features_rejected -= injected;
            c.features_received -= injected;
        });
        assert_same_states(&clean, &r, "junk observations");
    });
}

/// Empty frames inserted between real ones, and a 1 s camera blackout (every frame empty) in
/// flight: the estimator keeps running on the INS and recovers when features return.
#[test]
fn empty_frames_and_a_camera_blackout_are_survived() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let (b0, b1) = (secs(&ds, 14.0), secs(&ds, 15.0));
        let mut corrupted: Frames = Vec::new();
        let mut inserted = 0u64;
        for (k, (t, obs)) in frames.iter().enumerate() {
            let in_blackout = *t > b0 && *t < b1;
            corrupted.push((*t, if in_blackout { Vec::new() } else { obs.clone() }));
            if k % 10 == 5 {
                if let Some((t_next, _)) = frames.get(k + 1) {
                    corrupted.push(((t + t_next) / 2, Vec::new()));
                    inserted += 1;
                }
            }
        }
        let r = run(&ds, &ds.imu, &corrupted);
        let ate = ate_m(&ds, &r.states);
        println!(
            "{inserted} empty frames + 1 s blackout: {:?}, {} keyframes after it, ATE {ate:.4} m",
            r.counters,
            keyframes_after(&r, b1)
        );
        assert_eq!(r.counters.frames, frames.len() as u64 + inserted);
        assert_eq!(r.counters.resets, 0);
        assert_eq!(r.counters.solver_failures, 0);
        assert!(keyframes_after(&r, b1) > 20);
        assert_finite(&r, "empty frames");
        assert!(ate < 0.2, "ATE {ate:.4} m");
    });
}

/// Frames whose stamp goes backwards or repeats are rejected and counted (also before the
/// initialization: the frame they follow is still pending) and change nothing.
#[test]
fn frame_time_going_backwards_is_rejected_counted_and_changes_nothing() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let clean = run(&ds, &ds.imu, &frames);
        let t_init = init_time(&clean);
        let mut corrupted: Frames = Vec::new();
        let (mut before, mut after) = (0u64, 0u64);
        for (k, (t, obs)) in frames.iter().enumerate() {
            corrupted.push((*t, obs.clone()));
            if k % 7 == 3 {
                let back = if k % 2 == 0 { *t } else { t - 10_000_000 };
                corrupted.push((back, obs.clone()));
                // The frame before it is still waiting for its IMU sample when this one comes.
                if *t < t_init - 100_000_000 {
                    before += 1;
                } else if *t > t_init + 100_000_000 {
                    after += 1;
                } else {
                    corrupted.pop();
                }
            }
        }
        // The replay offers a frame once the IMU reaches its stamp, so each backwards frame is
        // offered right after the frame it follows, while that one is still pending.
        let r = run(&ds, &ds.imu, &corrupted);
        println!("{before} + {after} backwards frames: {:?}", r.counters);
        assert!(before > 2 && after > 60);
        assert_eq!(r.counters.frames, clean.counters.frames + before + after);
        assert_counters_equal_except(&clean.counters, &r.counters, |c| {
            c.frames -= before + after;
            c.frames_rejected_time -= before + after;
        });
        assert_same_states(&clean, &r, "backwards frames");
    });
}

/// Replays with the frames offered at explicit IMU times: `(offer_at_ns, t_cam_ns, obs)`,
/// offered in list order once the IMU reaches `offer_at_ns`.
fn run_offered(ds: &Dataset, frames: &[(i64, i64, Vec<FeatureObs>)]) -> Run {
    let mut est = new_estimator(euroc_config(ds, VisualMode::PoseOnly));
    let (mut states, mut keyframe_times) = (Vec::new(), Vec::new());
    let mut fi = 0;
    for s in &ds.imu {
        while let Some((_, t_cam, obs)) = frames.get(fi).filter(|f| f.0 <= s.t_ns) {
            let _ = est.push_frame(*t_cam, obs);
            fi += 1;
        }
        let _ = est.push_imu(s);
        while let Some(o) = step(&mut est) {
            states.extend(o.nav);
            keyframe_times.extend(o.keyframe.map(|r| r.t_ns));
        }
    }
    Run {
        states,
        keyframe_times,
        counters: est.counters(),
        status: est.status(),
    }
}

/// One frame arrives stamped `lead_s` ahead of the IMU (right after the real frame at 12 s, a
/// copy of it). It replaces the pending real frame (counted as dropped) and, until the IMU
/// reaches its stamp, every real frame is older than it and rejected (counted).
fn frame_far_ahead(lead_s: f64) -> (Dataset, Run, u64, i64) {
    let (ds, frames) = euroc();
    let k = frames
        .iter()
        .position(|f| f.0 > secs(&ds, 12.0))
        .expect("a frame at 12 s");
    let t_far = frames[k].0 + (lead_s * 1e9) as i64;
    let mut offered: Vec<(i64, i64, Vec<FeatureObs>)> =
        frames.iter().map(|(t, o)| (*t, *t, o.clone())).collect();
    offered.insert(k + 1, (frames[k].0, t_far, frames[k].1.clone()));
    let blocked = frames
        .iter()
        .filter(|f| f.0 > frames[k].0 && f.0 <= t_far)
        .count() as u64;
    let r = run_offered(&ds, &offered);
    (ds, r, blocked, t_far)
}

/// A frame stamped 2 s or 5 s ahead of the IMU (beyond `max_frame_lead_s` = 1 s) is refused
/// at once and counted; the real frames after it are processed as usual and the estimator never
/// resets.
#[test]
fn frames_far_ahead_of_the_imu_are_refused_counted() {
    small_stack(|| {
        for lead_s in [2.0, 5.0] {
            let (ds, r, _blocked, t_far) = frame_far_ahead(lead_s);
            let ate = ate_m(&ds, &r.states);
            println!(
                "frame {lead_s} s ahead: {:?}, {} keyframes after it, ATE {ate:.4} m",
                r.counters,
                keyframes_after(&r, t_far)
            );
            assert_eq!(r.counters.frames_rejected_time, 1);
            assert_eq!(r.counters.frames_dropped_no_imu, 0);
            assert_eq!(r.counters.resets, 0);
            assert_eq!(r.status, Status::Running);
            assert!(r.counters.keyframes > 40);
            assert_finite(&r, "frame far ahead");
            assert!(ate < 0.2, "ATE {ate:.4} m");
        }
    });
}

/// The camera stream runs ahead of the IMU: frames arrive in bursts before the IMU reaches the
/// first of them. The estimator queues `PENDING_FRAMES` (4) of them and processes each at its
/// own time; in bursts of six the two oldest of each burst are dropped and counted.
#[test]
fn frames_arriving_ahead_of_the_imu_in_bursts_are_queued_or_dropped_counted() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let burst = 6;
        let offered: Vec<(i64, i64, Vec<FeatureObs>)> = frames
            .iter()
            .enumerate()
            .map(|(k, (t, o))| (frames[k - k % burst].0, *t, o.clone()))
            .collect();
        let r = run_offered(&ds, &offered);
        let bursts = (frames.len() / burst) as u64;
        let ate = ate_m(&ds, &r.states);
        println!("bursts of {burst} frames: {:?}, ATE {ate:.4} m", r.counters);
        let queued = povins::core::estimator::PENDING_FRAMES as u64;
        assert_eq!(
            r.counters.frames_dropped_no_imu,
            (burst as u64 - queued) * bursts
        );
        assert_eq!(r.counters.frames_rejected_time, 0);
        assert_eq!(r.counters.resets, 0);
        assert!(r.counters.keyframes > 40);
        assert_finite(&r, "bursts");
        assert!(ate < 0.2, "ATE {ate:.4} m");
    });
}

/// Absurd but finite IMU values (1e9 on every axis, three samples in flight) are not
/// rejected by the core (it has no range check): the run must survive without a panic and
/// with finite output. The trajectory after them is lost (see the printed numbers).
#[test]
fn absurd_finite_imu_values_do_not_panic_and_keep_the_output_finite() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let i0 = ds.imu.partition_point(|s| s.t_ns < secs(&ds, 15.0));
        let mut imu = ds.imu.clone();
        for s in &mut imu[i0..i0 + 3] {
            s.accel_mps2 = Vec3::new(1e9, -1e9, 1e9);
            s.gyro_rps = Vec3::new(1e9, 1e9, -1e9);
        }
        let r = run(&ds, &imu, &frames);
        let last = r.states.last().expect("output");
        println!(
            "absurd IMU: {:?}, status {:?}, final position {:?}",
            r.counters,
            r.status,
            last.p_wb.as_slice()
        );
        // Outside any MEMS range: rejected and counted, the rest of the run unaffected.
        assert_eq!(r.counters.imu_rejected_range, 3);
        assert_eq!(r.counters.imu_samples, imu.len() as u64 - 3);
        assert_eq!(r.counters.resets, 0);
        assert!(r.counters.keyframes > 40);
        assert_finite(&r, "absurd IMU values");
        let ate = ate_m(&ds, &r.states);
        assert!(ate < 0.2, "ATE {ate:.4} m");
    });
}

/// Finite values near `f64::MAX` would overflow the INS mechanization: they are refused by the
/// range check, so the output stays finite.
#[test]
fn huge_finite_imu_values_keep_the_output_finite() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let i0 = ds.imu.partition_point(|s| s.t_ns < secs(&ds, 15.0));
        let mut imu = ds.imu.clone();
        imu[i0].accel_mps2 = Vec3::repeat(1e300);
        imu[i0].gyro_rps = Vec3::repeat(1e300);
        let r = run(&ds, &imu, &frames);
        assert_eq!(r.counters.imu_rejected_range, 1);
        assert_finite(&r, "IMU values of 1e300");
    });
}

/// Timestamps at the ends of the `i64` range (a wrapped clock, a corrupt stamp) must be rejected
/// or absorbed without arithmetic overflow (the test profile checks overflow): a stream that
/// starts near `i64::MIN` and jumps to `i64::MAX`, with frames at both ends.
#[test]
fn extreme_timestamps_do_not_overflow() {
    small_stack(|| {
        let (ds, frames) = euroc();
        let mut est = new_estimator(euroc_config(&ds, VisualMode::PoseOnly));
        let t0 = i64::MIN + 1_000;
        let g0 = interpolate_state(&ds.ground_truth, ds.imu[1200].t_ns).expect("gt");
        est.initialize(NavState { t_ns: t0, ..g0 }).expect("init");
        let obs = frames[0].1.clone();
        let dt = 5_000_000;
        for (k, s) in ds.imu[1200..1300].iter().enumerate() {
            let t = t0 + k as i64 * dt;
            if k % 10 == 5 {
                let _ = est.push_frame(t, &obs);
            }
            let _ = est.push_imu(&ImuSample { t_ns: t, ..*s });
            while step(&mut est).is_some() {}
        }
        let _ = est.push_frame(i64::MAX, &obs);
        let _ = est.push_frame(i64::MIN, &obs);
        // A second of samples after the jump: they wait up to 0.5 s for a frame that could show
        // a clock jump (`estimator::clock_jump`); none comes, and the gap resets.
        let big = i64::MAX - 2_000_000_000;
        let after = (0..200).map(|k| big + k * dt);
        for t in after.chain([i64::MAX - 10, i64::MAX, i64::MIN]) {
            let _ = est.push_imu(&ImuSample {
                t_ns: t,
                ..ds.imu[1300]
            });
            while step(&mut est).is_some() {}
        }
        let c = est.counters();
        println!("extreme stamps: {c:?}");
        assert!(c.keyframes > 0, "{c:?}");
        assert_eq!(
            c.frames_rejected_time, 1,
            "the frame at i64::MAX is far ahead: {c:?}"
        );
        assert_eq!(c.imu_rejected_time, 1, "i64::MIN after i64::MAX: {c:?}");
        assert_eq!(c.resets, 1, "the jump to i64::MAX is a gap: {c:?}");
    });
}

//! Clock jumps (`estimator::clock_jump`) on real data (EuRoC V1_01, first 30 s, static start,
//! `configs/euroc.toml`): every stream's stamps stepping forward together keep the state and the
//! output goes on; the same gap with the platform moving through it (a recording paused) is
//! not taken for one.

mod common;

use common::*;
use povins::core::camera::FeatureObs;
use povins::core::estimator::{Counters, VisualMode};
use povins::core::inertial::{ImuSample, NavState};
use povins::platform::dataset::Dataset;

/// One hour, ns.
const HOUR_NS: i64 = 3_600_000_000_000;

struct Run {
    states: Vec<NavState>,
    counters: Counters,
    /// `(stamp of the processed sample, jump s)` of each reported clock jump.
    jumps: Vec<(i64, f64)>,
}

fn run(ds: &Dataset, frames: &[(i64, Vec<FeatureObs>)]) -> Run {
    let mut est = new_estimator(euroc_config(ds, VisualMode::PoseOnly));
    let slices: Vec<(i64, &[FeatureObs])> =
        frames.iter().map(|(t, o)| (*t, o.as_slice())).collect();
    let (mut states, mut jumps) = (Vec::new(), Vec::new());
    drive(&mut est, &ds.imu, &slices, |_, _, o| {
        if let Some(n) = o.nav {
            states.push(n);
        }
        if let (Some(j), Some(n)) = (o.clock_jump_s, o.nav) {
            jumps.push((n.t_ns, j));
        }
        true
    });
    Run {
        states,
        counters: est.counters(),
        jumps,
    }
}

fn frames_of(ds: &Dataset) -> Vec<(i64, Vec<FeatureObs>)> {
    ds.features
        .iter()
        .map(|f| (f.t_ns, f.obs.clone()))
        .collect()
}

/// A +1 h jump of every stream's clock 15 s in: counted and reported once, at the first sample
/// after it, with its size; no reset, no re-initialization (the window goes on); an estimate at
/// every IMU sample after it, on the inputs' clock; the published position continuous across
/// it; the accuracy that of the run without it.
#[test]
fn a_clock_jump_in_every_stream_keeps_the_state_and_the_output_goes_on() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let clean = run(&ds, &frames_of(&ds));
        let ate_clean = ate_m(&ds, &clean.states);
        let at = ds.imu[0].t_ns + 15_000_000_000;
        let dj = jumped(&ds, at, HOUR_NS);
        let r = run(&dj, &frames_of(&dj));
        let c = r.counters;
        let ate = ate_m(&dj, &r.states);
        println!(
            "clock jump: {:?}, ATE {ate:.4} m (clean {ate_clean:.4} m)",
            r.jumps
        );
        assert_eq!(c.clock_jumps, 1, "{c:?}");
        assert_eq!(
            (c.resets, c.reinitializations, c.imu_gaps_bridged),
            (0, 0, 0),
            "{c:?}"
        );
        let first_after = dj.imu.iter().find(|s| s.t_ns >= at + HOUR_NS).expect("IMU");
        assert_eq!(r.jumps.len(), 1);
        assert_eq!(r.jumps[0].0, first_after.t_ns);
        // The gap less one sample period (EuRoC's IMU: 200 Hz).
        assert!((r.jumps[0].1 - 3600.0).abs() < 0.01, "{:?}", r.jumps);
        let after = dj.imu.iter().filter(|s| s.t_ns >= at + HOUR_NS).count();
        let published = r.states.iter().filter(|s| s.t_ns >= at + HOUR_NS).count();
        assert_eq!(
            published, after,
            "an estimate at every sample after the jump"
        );
        let before = r.states.iter().rev().find(|s| s.t_ns < at).expect("before");
        let next = r.states.iter().find(|s| s.t_ns >= at).expect("after");
        let step = (next.p_wb - before.p_wb).norm();
        assert!(step < 0.02, "the published position stepped {step:.3} m");
        // The first frame after the jump is refused (pushed before the first sample after it,
        // 1 h ahead of the newest one): otherwise the run is the one without the jump.
        assert!(
            (ate - ate_clean).abs() < 0.05 * ate_clean,
            "ATE {ate:.4} m, clean {ate_clean:.4} m"
        );
    });
}

/// Two seconds without any sensor while the platform moves (a recording paused, not a clock
/// set): the images after it do not continue the ones before it, so it is no clock jump; the
/// gap is handled as any other (here: a reset, as EuRoC's motion is no line over 2 s).
#[test]
fn a_paused_recording_is_not_taken_for_a_clock_jump() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let (a, b) = (
            ds.imu[0].t_ns + 15_000_000_000,
            ds.imu[0].t_ns + 17_000_000_000,
        );
        let mut d = ds.clone();
        let out = |t: i64| t >= a && t < b;
        d.imu.retain(|s: &ImuSample| !out(s.t_ns));
        d.features.retain(|f| !out(f.t_ns));
        let r = run(&d, &frames_of(&d));
        let c = r.counters;
        println!("paused: {c:?}");
        assert_eq!(c.clock_jumps, 0, "{c:?}");
        assert!(r.jumps.is_empty());
        assert_eq!(c.resets + c.imu_gaps_bridged_long, 1, "{c:?}");
    });
}

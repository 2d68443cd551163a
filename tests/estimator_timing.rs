//! The estimator owns sensor timing (`povins_core::estimator::timing`): measurements pushed
//! late (within the delayed horizon) or early (LiDAR sweeps before the IMU has passed them) are
//! processed exactly as if a replay had ordered them, and a full queue is reported.

mod common;

use common::*;
use povins::core::camera::FeatureObs;
use povins::core::estimator::{EstimatorConfig, ImuOutput, PoVins, VisualMode, IMU_QUEUE};
use povins::core::inertial::ImuSample;
use povins::core::lidar::LidarPoint;
use povins::core::Error;
use povins::host_tools::sim::Scenario;

/// One processed sample: its state's time and bits, and the keyframe time if one was made.
type Processed = (i64, Vec<u64>, Option<i64>);

/// Every processed sample's state bits and keyframe time, in order.
fn record(out: &mut Vec<Processed>, o: &ImuOutput) {
    let bits = o.nav.as_ref().map_or(Vec::new(), state_bits);
    out.push((
        o.nav.map_or(0, |n| n.t_ns),
        bits,
        o.keyframe.map(|r| r.t_ns),
    ));
}

/// Pushes every measurement `lag_ns` after the IMU stream reached its stamp (frames at their
/// stamp, sweeps at their first point when `early_sweeps`, else at their last), draining
/// `update` after each IMU sample; at the end the rest, then `end_input` and a last drain.
fn replay_pushed_late(
    cfg: EstimatorConfig,
    imu: &[ImuSample],
    frames: &[(i64, &[FeatureObs])],
    sweeps: &[(i64, i64, &[LidarPoint])],
    lag_ns: i64,
    early_sweeps: bool,
    init: Option<povins::core::inertial::NavState>,
) -> (Vec<Processed>, povins::core::estimator::Counters) {
    let mut est: Box<PoVins> = new_estimator(cfg);
    if let Some(s0) = init {
        est.initialize(s0).expect("initial state");
    }
    let t0 = imu.first().map_or(i64::MIN, |s| s.t_ns);
    let mut fi = frames.partition_point(|f| f.0 < t0);
    let mut li = sweeps.partition_point(|w| w.1 < t0);
    let mut out = Vec::new();
    for s in imu {
        est.push_imu(s).expect("a valid sample, queue not full");
        while let Some(f) = frames.get(fi).filter(|f| f.0 + lag_ns <= s.t_ns) {
            let _ = est.push_frame(f.0, f.1);
            fi += 1;
        }
        while let Some(w) = sweeps
            .get(li)
            .filter(|w| if early_sweeps { w.0 } else { w.1 } + lag_ns <= s.t_ns)
        {
            let _ = est.push_lidar(w.2);
            li += 1;
        }
        while let Some(o) = step(&mut est) {
            record(&mut out, &o);
        }
    }
    for f in frames.get(fi..).unwrap_or_default() {
        let _ = est.push_frame(f.0, f.1);
    }
    for w in sweeps.get(li..).unwrap_or_default() {
        let _ = est.push_lidar(w.2);
    }
    est.end_input();
    while let Some(o) = step(&mut est) {
        record(&mut out, &o);
    }
    (out, est.counters())
}

#[test]
fn frames_pushed_late_within_the_horizon_give_the_same_output() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, VisualMode::PoseOnly);
        let frames: Vec<(i64, &[FeatureObs])> = ds
            .features
            .iter()
            .map(|f| (f.t_ns, f.obs.as_slice()))
            .collect();
        let (reference, _) = replay_pushed_late(cfg, &ds.imu, &frames, &[], 0, false, None);
        let held = EstimatorConfig {
            delay_horizon_s: 0.1,
            ..cfg
        };
        // Frames arrive 60 ms after the IMU of their time (a camera driver's latency).
        let (late, c) = replay_pushed_late(held, &ds.imu, &frames, &[], 60_000_000, false, None);
        let keyframes = reference.iter().filter(|r| r.2.is_some()).count();
        assert!(keyframes > 40, "only {keyframes} keyframes");
        // The horizon kept the last 0.1 s queued until the end of the input, then let it go.
        assert_eq!(late.len(), reference.len(), "samples left unprocessed");
        assert_eq!(&reference[..], &late[..], "the held replay differs");
        assert_eq!(c.frames_dropped_no_imu, 0);

        // Without the horizon the same late frames are processed late (rewound): the output
        // differs, which is what the horizon is for.
        let (unheld, _) = replay_pushed_late(cfg, &ds.imu, &frames, &[], 60_000_000, false, None);
        assert_ne!(&reference[..late.len()], &unheld[..late.len()]);
    });
}

#[test]
fn sweeps_pushed_before_the_imu_reaches_them_are_held() {
    small_stack(|| {
        let ds = simulate_with_lidar(Scenario::Robot, 1, 12.0);
        let mut cfg = sim_lidar_config(&ds, true);
        let (start, s0) = gt_start(&ds, &mut cfg);
        let frames = frames_of(&ds);
        let sweeps: Vec<(i64, i64, &[LidarPoint])> = ds
            .lidar
            .iter()
            .map(|w| {
                let t = |f: fn(i64, i64) -> i64| w.points.iter().map(|p| p.t_ns).fold(w.t_ns, f);
                (t(i64::min), t(i64::max), w.points.as_slice())
            })
            .collect();
        let imu = &ds.imu[start..];
        let run = |early| replay_pushed_late(cfg, imu, &frames, &sweeps, 0, early, Some(s0));
        let (on_time, c_on_time) = run(false);
        let (early, c_early) = run(true);
        assert!(c_on_time.lidar_points_accepted > 100_000, "{c_on_time:?}");
        assert_eq!(c_early.lidar_scans_refused, 0, "{c_early:?}");
        assert_eq!(
            c_early.lidar_points_accepted,
            c_on_time.lidar_points_accepted
        );
        assert_eq!(on_time, early, "sweeps pushed early changed the output");
    });
}

#[test]
fn a_full_imu_queue_is_reported_and_drains() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let mut est: Box<PoVins> = new_estimator(euroc_config(&ds, VisualMode::PoseOnly));
        for s in &ds.imu[..IMU_QUEUE] {
            est.push_imu(s).expect("room in the queue");
        }
        assert_eq!(est.queued_imu(), IMU_QUEUE);
        assert_eq!(
            est.push_imu(&ds.imu[IMU_QUEUE]),
            Err(Error::CapacityExceeded)
        );
        assert_eq!(est.counters().imu_dropped_queue_full, 1);
        // A sample not later than the newest queued one is refused as such.
        assert_eq!(est.push_imu(&ds.imu[3]), Err(Error::TimeNotIncreasing));
        let mut n = 0;
        while step(&mut est).is_some() {
            n += 1;
        }
        assert_eq!((n, est.queued_imu()), (IMU_QUEUE, 0));
        assert_eq!(est.counters().imu_samples, IMU_QUEUE as u64);
        est.push_imu(&ds.imu[IMU_QUEUE]).expect("room again");
    });
}

/// What the estimator holds back for later input is processed once the input ends
/// (`Estimator::end_input`): here the samples after a 1 s IMU gap near the end of the stream,
/// held while a frame after the gap could still tell a clock jump from an outage (none comes):
/// before, a recording ending so left them unprocessed.
#[test]
fn samples_held_for_later_input_are_processed_when_the_input_ends() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, VisualMode::PoseOnly);
        let t0 = ds.imu[0].t_ns;
        let (gap0, gap1, end) = (
            t0 + 15_000_000_000,
            t0 + 16_000_000_000,
            t0 + 16_300_000_000,
        );
        let imu: Vec<ImuSample> = ds
            .imu
            .iter()
            .copied()
            .filter(|s| (s.t_ns <= gap0 || s.t_ns > gap1) && s.t_ns <= end)
            .collect();
        let frames: Vec<(i64, &[FeatureObs])> = ds
            .features
            .iter()
            .filter(|f| f.t_ns <= gap0)
            .map(|f| (f.t_ns, f.obs.as_slice()))
            .collect();
        let mut est = new_estimator(cfg);
        let mut last = None;
        drive(&mut est, &imu, &frames, |_, _, o| {
            last = o.nav.map(|n| n.t_ns).or(last);
            true
        });
        let held = est.queued_imu();
        assert!(last.is_some_and(|t| t <= gap0), "{last:?}");
        assert!(held > 50, "only {held} samples held after the gap");
        est.end_input();
        let mut flushed = Vec::new();
        while let Some(o) = step(&mut est) {
            flushed.push(o);
        }
        assert_eq!(est.queued_imu(), 0);
        // One output per held sample; the gap was bridged as a long one and, no frame coming
        // after it to correct the INS, the state after it is withheld (`nav_withheld`).
        assert_eq!(flushed.len(), held);
        assert!(flushed.iter().all(|o| o.nav.is_none() && o.nav_withheld));
        assert_eq!(flushed[0].gap_bridged_s.map(|g| g > 0.99), Some(true));
        assert_eq!(est.counters().imu_gaps_bridged, 1, "{:?}", est.counters());
    });
}

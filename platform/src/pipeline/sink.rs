//! Outputs of the pipeline: a [`Sink`] receives every IMU-rate pose ([`PoseOut`], with its
//! latency) and every keyframe report ([`KeyframeOut`]) on the IMU thread. Provided:
//! [`CallbackSink`] (closures), [`super::TumSink`] (a TUM trajectory file) and
//! [`super::McapSink`] (MCAP for Foxglove), both written by a thread of their own during the run
//! ([`super::file_sink`]), [`super::MavlinkSink`] and [`super::FoxgloveSink`].

use crate::error::IoError;
use crate::trajectory::StampedPose;
use povins_core::estimator::KeyframeReport;
use povins_core::inertial::{InsCovariance, NavState};
use povins_core::odometry::LandmarkPoint;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// One IMU-rate pose as published.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseOut {
    /// The state at the IMU sample (`nav.t_ns` is the sample's stamp).
    pub nav: NavState,
    /// From the sample's arrival on the IMU thread (the source returned it) to publication, ns.
    pub latency_ns: u64,
    /// From the wall time the sample's stamp was due to publication, ns, when the source knows
    /// it ([`super::Source::stamp_instant`]).
    pub stamp_latency_ns: Option<u64>,
    /// The covariance of `nav`'s error state ([`InsCovariance`]; with the continuous output,
    /// of the exact state it follows), when the estimator computes one (`covariance = true`).
    pub covariance: Option<InsCovariance>,
}

/// One keyframe processed by the back end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeOut {
    /// The estimator's report.
    pub report: KeyframeReport,
    /// The newest keyframe's optimized state after the step.
    pub state: Option<NavState>,
}

/// Receives the pipeline's outputs, on the IMU thread: keep the calls short (no disk, no
/// blocking), or hand the data to another thread.
pub trait Sink {
    /// An IMU-rate pose.
    fn pose(&mut self, p: &PoseOut);
    /// A keyframe report (arrives at most a few IMU samples after the keyframe's sample in
    /// real-time mode).
    fn keyframe(&mut self, _k: &KeyframeOut) {}
    /// The end of the stream: write files, flush.
    fn finish(&mut self) -> Result<(), IoError> {
        Ok(())
    }

    /// Where the back end should put each keyframe's landmarks, for a sink that shows them
    /// (asked once, before the run; the first sink of a pair that has one gets them).
    fn landmark_tap(&self) -> Option<Arc<LandmarkTap>> {
        None
    }
}

/// The newest keyframe's landmarks, handed from the back-end thread to a sink's own thread
/// without waiting: the back end copies them in when the slot is free (`try_lock`; busy: that
/// keyframe's landmarks are skipped, counted), into room reserved up front; the reader copies
/// them out when [`LandmarkTap::version`] moved.
#[derive(Debug)]
pub struct LandmarkTap {
    slot: Mutex<(i64, Vec<LandmarkPoint>)>,
    capacity: usize,
    version: AtomicU64,
    skipped: AtomicU64,
}

impl LandmarkTap {
    /// Room for `capacity` landmarks (the estimator's landmark capacity; more are cut).
    pub fn new(capacity: usize) -> Self {
        LandmarkTap {
            slot: Mutex::new((0, Vec::with_capacity(capacity))),
            capacity,
            version: AtomicU64::new(0),
            skipped: AtomicU64::new(0),
        }
    }

    /// The back end: the landmarks of the keyframe at `t_ns`.
    pub fn publish(&self, t_ns: i64, points: &[LandmarkPoint]) {
        match self.slot.try_lock() {
            Ok(mut s) => {
                s.0 = t_ns;
                s.1.clear();
                s.1.extend_from_slice(&points[..points.len().min(self.capacity)]);
                self.version.fetch_add(1, Ordering::Release);
            }
            Err(_) => {
                self.skipped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Increments with every [`Self::publish`] that landed.
    pub fn version(&self) -> u64 {
        self.version.load(Ordering::Acquire)
    }

    /// Keyframes whose landmarks were skipped (the reader held the slot).
    pub fn skipped(&self) -> u64 {
        self.skipped.load(Ordering::Relaxed)
    }

    /// Copies the newest landmarks into `out`; their keyframe's time, ns.
    pub fn read(&self, out: &mut Vec<LandmarkPoint>) -> i64 {
        let Ok(s) = self.slot.lock() else {
            return 0;
        };
        out.clear();
        out.extend_from_slice(&s.1);
        s.0
    }
}

/// Decimates the IMU-rate output by sensor time: a pose passes when its stamp is at least one
/// period after the last one that passed (held to the period's grid while the stream keeps up,
/// so the same poses pass in every run of the same data). Used by the sinks that send at a set
/// rate (MAVLink, Foxglove).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateDecimator {
    period_ns: i64,
    next_due_ns: Option<i64>,
}

impl RateDecimator {
    /// `rate_hz` poses per second of sensor time (checked by the caller: finite, above 0).
    pub fn new(rate_hz: f64) -> Self {
        RateDecimator {
            period_ns: ((1e9 / rate_hz).round() as i64).max(1),
            next_due_ns: None,
        }
    }

    /// Whether the pose at `t_ns` passes.
    pub fn take(&mut self, t_ns: i64) -> bool {
        if self.next_due_ns.is_some_and(|due| t_ns < due) {
            return false;
        }
        self.next_due_ns = Some(match self.next_due_ns {
            Some(due) if t_ns < due.saturating_add(self.period_ns) => due + self.period_ns,
            _ => t_ns.saturating_add(self.period_ns),
        });
        true
    }
}

/// One output a sink hands to a thread of its own (the file writers, the Foxglove publisher).
#[derive(Debug, Clone, Copy)]
pub enum Stamped {
    /// An IMU-rate pose.
    Pose(StampedPose),
    /// A keyframe's optimized state.
    Keyframe(StampedPose),
}

/// A sink made of closures.
pub struct CallbackSink<P, K> {
    on_pose: P,
    on_keyframe: K,
}

impl<P: FnMut(&PoseOut)> CallbackSink<P, fn(&KeyframeOut)> {
    /// Calls `on_pose` for every pose; keyframes are ignored.
    pub fn poses(on_pose: P) -> Self {
        CallbackSink {
            on_pose,
            on_keyframe: |_| {},
        }
    }
}

impl<P: FnMut(&PoseOut), K: FnMut(&KeyframeOut)> CallbackSink<P, K> {
    /// Calls `on_pose` for every pose and `on_keyframe` for every keyframe.
    pub fn new(on_pose: P, on_keyframe: K) -> Self {
        CallbackSink {
            on_pose,
            on_keyframe,
        }
    }
}

impl<P: FnMut(&PoseOut), K: FnMut(&KeyframeOut)> Sink for CallbackSink<P, K> {
    fn pose(&mut self, p: &PoseOut) {
        (self.on_pose)(p);
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        (self.on_keyframe)(k);
    }
}

/// An optional sink: `None` ignores every output.
impl<S: Sink> Sink for Option<S> {
    fn pose(&mut self, p: &PoseOut) {
        if let Some(s) = self {
            s.pose(p);
        }
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        if let Some(s) = self {
            s.keyframe(k);
        }
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.as_mut().map_or(Ok(()), Sink::finish)
    }

    fn landmark_tap(&self) -> Option<Arc<LandmarkTap>> {
        self.as_ref().and_then(Sink::landmark_tap)
    }
}

/// Both sinks get every output (`(a, b)`).
impl<A: Sink, B: Sink> Sink for (A, B) {
    fn pose(&mut self, p: &PoseOut) {
        self.0.pose(p);
        self.1.pose(p);
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        self.0.keyframe(k);
        self.1.keyframe(k);
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.0.finish()?;
        self.1.finish()
    }

    fn landmark_tap(&self) -> Option<Arc<LandmarkTap>> {
        self.0.landmark_tap().or_else(|| self.1.landmark_tap())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::read_tum;

    /// 200 Hz decimated to 30 Hz: 30 poses a second, on the period's grid, the same ones again
    /// for the same stamps; a gap restarts the grid at the next pose.
    #[test]
    fn rate_decimator_keeps_the_rate_by_stamp() {
        let stamps: Vec<i64> = (0..400).map(|k| 1_000_000_000 + k * 5_000_000).collect();
        let run = || {
            let mut d = RateDecimator::new(30.0);
            stamps
                .iter()
                .copied()
                .filter(|&t| d.take(t))
                .collect::<Vec<_>>()
        };
        let kept = run();
        assert_eq!(kept, run(), "the same poses every run");
        assert_eq!(kept.len(), 60, "30 Hz over 2 s");
        assert!(kept
            .windows(2)
            .all(|w| (30_000_000..=35_000_000).contains(&(w[1] - w[0]))));
        let mut d = RateDecimator::new(30.0);
        assert!(d.take(0) && !d.take(10_000_000) && d.take(5_000_000_000));
        assert!(!d.take(5_010_000_000) && d.take(5_035_000_000));
    }

    fn pose(k: i64) -> PoseOut {
        PoseOut {
            nav: NavState {
                t_ns: 1_000_000_000 + k * 5_000_000,
                p_wb: povins_core::math::Vec3::new(k as f64, 2.0, -0.5),
                q_wb: povins_core::math::Quat::identity(),
                ..NavState::ZERO
            },
            latency_ns: 1000,
            stamp_latency_ns: None,
            covariance: None,
        }
    }

    #[test]
    fn callback_sink_sees_every_output() {
        let mut poses = Vec::new();
        let mut kfs = Vec::new();
        {
            let mut sink = CallbackSink::new(
                |p: &PoseOut| poses.push(p.nav.t_ns),
                |k: &KeyframeOut| kfs.push(k.report.t_ns),
            );
            for k in 0..3 {
                sink.pose(&pose(k));
            }
            sink.keyframe(&KeyframeOut {
                report: KeyframeReport {
                    t_ns: 42,
                    ..Default::default()
                },
                state: None,
            });
            sink.finish().expect("nothing to write");
        }
        assert_eq!(poses, vec![1_000_000_000, 1_005_000_000, 1_010_000_000]);
        assert_eq!(kfs, vec![42]);
    }

    #[test]
    fn tum_sink_writes_the_poses_as_they_come() {
        use super::super::{FileOptions, TumSink};
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("trajectory.tum");
        let mut count = 0usize;
        let opts = FileOptions {
            flush_period: std::time::Duration::from_millis(50),
            ..FileOptions::default()
        };
        let mut sink = (
            TumSink::create(&path, opts).expect("created"),
            CallbackSink::poses(|_: &PoseOut| count += 1),
        );
        for k in 0..4 {
            sink.pose(&pose(k));
        }
        // Written and flushed by the thread before the end.
        let mut seen = 0;
        for _ in 0..200 {
            std::thread::sleep(std::time::Duration::from_millis(10));
            seen = read_tum(&path).map_or(0, |v| v.len());
            if seen == 4 {
                break;
            }
        }
        assert_eq!(seen, 4, "the poses are in the file before finish");
        sink.finish().expect("written");
        let back = read_tum(&path).expect("readable");
        assert_eq!(back.len(), 4);
        assert_eq!(back[3].t_ns, pose(3).nav.t_ns);
        assert_eq!(back[3].p_wb.x, 3.0);
        assert_eq!(sink.0.counts().poses, 4);
        drop(sink);
        assert_eq!(count, 4);
    }
}

//! Where sensor messages come from: a [`Source`] yields [`SensorEvent`]s in arrival order, for
//! the single-threaded driver ([`crate::driver`]) and the threaded pipeline
//! ([`crate::pipeline`]) alike.
//!
//! - [`MergedSource`] replays a [`Recording`](crate::recording::Recording) (a dataset folder, an
//!   MCAP file, or a sequence in memory), pulling its streams incrementally, in the one order
//!   every consumer sees ([`merge`]'s docs), paced at the recorded rate ([`Pacing::Recorded`])
//!   or as fast as possible.
//! - [`Prefetch`] runs a source on a helper thread and decodes its images there, so a replay
//!   never waits for the decoder.
//! - A live driver implements [`Source`] itself (`platform/examples/live_source.rs`;
//!   [`crate::ouster::OusterUdp`] for an Ouster sensor over UDP).

mod merge;
mod prefetch;
#[cfg(test)]
mod tests;

pub use merge::{CameraInput, MergeOptions, MergeStats, MergedSource, SWEEP_LOOKAHEAD};
pub use prefetch::Prefetch;

use crate::error::IoError;
use crate::images::ImageData;
use povins_core::camera::FeatureObs;
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use std::time::{Duration, Instant};

/// One sensor message.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    /// An IMU sample (body frame, IMU clock).
    Imu(ImuSample),
    /// The tracked features of one camera frame: camera time, ns, and the observations in
    /// raw pixels (an external front end's output).
    Frame {
        /// Image time (camera clock), ns.
        t_cam_ns: i64,
        /// Tracked features, raw pixels.
        obs: Vec<FeatureObs>,
    },
    /// A camera image for the image front end, undecoded until the consumer needs it.
    Image {
        /// Image time (camera clock), ns.
        t_cam_ns: i64,
        /// The image.
        data: ImageData,
        /// Time the source spent reading and decoding it before handing it over, ns (0: none).
        prepared_ns: u64,
    },
    /// A whole LiDAR sweep (points in the LiDAR frame with their own times), offered once it is
    /// complete.
    Lidar(Vec<LidarPoint>),
}

/// Where sensor messages come from: a recording's replay, or a live driver.
///
/// `next` is called in a loop (by the pipeline's IMU thread, or the single-threaded driver); it
/// may block (a live driver waits for its device, a paced replay sleeps) and returns `Ok(None)`
/// at the end of the stream. An error ends the run (a file that cannot be read on): the
/// consumer reports it, it never ends a run silently. The events must come in the order
/// [`merge`] documents (the estimator orders the processing itself, but a message that
/// arrives late is processed late).
pub trait Source {
    /// The next event, `Ok(None)` at the end.
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError>;

    /// The wall time at which a sensor stamp (IMU clock, ns) was due, when the source knows it
    /// (a paced replay; a live driver whose clock is the monotonic clock): the pipeline then
    /// measures latency from the stamp too, not only from the event's arrival.
    fn stamp_instant(&self, _t_ns: i64) -> Option<Instant> {
        None
    }

    /// Whether the source runs against the wall clock. A real-time source cannot wait: when
    /// the back end's queue is full the pipeline drops the message (and counts it). A source
    /// that does not (an unpaced replay) makes the pipeline wait instead.
    fn is_realtime(&self) -> bool;
}

impl<S: Source + ?Sized> Source for Box<S> {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        (**self).next()
    }

    fn stamp_instant(&self, t_ns: i64) -> Option<Instant> {
        (**self).stamp_instant(t_ns)
    }

    fn is_realtime(&self) -> bool {
        (**self).is_realtime()
    }
}

/// A monotonic clock the pacing sleeps on (injected so tests need not sleep).
pub trait Clock {
    /// Now.
    fn now(&mut self) -> Instant;
    /// Returns once `t` has passed.
    fn sleep_until(&mut self, t: Instant);
}

/// The system's monotonic clock ([`Instant`], `std::thread::sleep`).
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&mut self) -> Instant {
        Instant::now()
    }

    fn sleep_until(&mut self, t: Instant) {
        let now = Instant::now();
        if t > now {
            std::thread::sleep(t - now);
        }
    }
}

/// How fast a replay runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// Each event at its recorded time divided by the factor (1.0: real time).
    Recorded(f64),
    /// No waiting.
    AsFastAsPossible,
}

/// Maps sensor stamps to wall time (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct Pacer {
    speed: Option<f64>,
    origin: Option<(i64, Instant)>,
}

impl Pacer {
    /// A pacer; a speed that is not finite and positive means as fast as possible.
    pub fn new(pacing: Pacing) -> Self {
        let speed = match pacing {
            Pacing::Recorded(x) if x.is_finite() && x > 0.0 => Some(x),
            _ => None,
        };
        Pacer {
            speed,
            origin: None,
        }
    }

    /// Whether it waits at all.
    pub fn is_paced(&self) -> bool {
        self.speed.is_some()
    }

    /// The wall time of stamp `t_ns` (`None` before the first [`Pacer::wait_for`], or unpaced).
    pub fn instant_of(&self, t_ns: i64) -> Option<Instant> {
        let (speed, (t0, w0)) = (self.speed?, self.origin?);
        let dt_s = (t_ns.saturating_sub(t0)).max(0) as f64 * 1e-9 / speed;
        Some(w0 + Duration::from_secs_f64(dt_s))
    }

    /// Sleeps on `clock` until stamp `t_ns` is due; the first call sets the origin (now).
    pub fn wait_for(&mut self, t_ns: i64, clock: &mut impl Clock) {
        if self.speed.is_none() {
            return;
        }
        if self.origin.is_none() {
            self.origin = Some((t_ns, clock.now()));
        }
        if let Some(t) = self.instant_of(t_ns) {
            clock.sleep_until(t);
        }
    }
}

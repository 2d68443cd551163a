//! Inputs of the pipeline: [`SensorEvent`]s from a [`Source`]; [`DatasetSource`] replays a
//! [`Dataset`] in the order `povins run` (`host-tools` `runner::replay`) feeds the estimator,
//! paced at the recorded rate ([`Pacing::Recorded`]) or as fast as possible.
//!
//! Time order (arrival order; the estimator orders the processing itself, so the pipeline's
//! output is the replay's): for every IMU sample `s` from the start on, first the camera frames
//! with `t_cam <= s.t_ns` not yet offered, then the LiDAR sweeps whose last point
//! ([`lidar_schedule`], on the IMU clock) is `<= s.t_ns`, then `s`. Frames and sweeps due before
//! the first IMU sample replayed are skipped, as the replay skips them.
//!
//! Pacing: every event is released at the wall time of the IMU sample it is grouped with (the
//! sample after it): the stream of IMU stamps is mapped to wall time from the first event on,
//! divided by the speed factor.

use super::frontend::ImageData;
use crate::dataset::{Dataset, ImageFrame};
use povins_core::camera::FeatureObs;
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use std::time::{Duration, Instant};

/// One input of the pipeline.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    /// An IMU sample (body frame, IMU clock).
    Imu(ImuSample),
    /// The tracked features of one camera frame: camera time, ns, and the observations in
    /// raw pixels (the estimator's `push_frame`).
    Frame {
        /// Image time (camera clock), ns.
        t_cam_ns: i64,
        /// Tracked features, raw pixels.
        obs: Vec<FeatureObs>,
    },
    /// A whole LiDAR sweep (points in the LiDAR frame with their own times), offered once the
    /// IMU has passed its last point.
    Lidar(Vec<LidarPoint>),
    /// A camera image for the image front end (decoded by the front-end stage, see
    /// `pipeline::frontend`), offered like a frame.
    Image {
        /// Image time (camera clock), ns.
        t_cam_ns: i64,
        /// The image, undecoded.
        data: ImageData,
    },
}

/// Where the pipeline's inputs come from: a dataset replay, or a live driver.
///
/// `next` is called by the pipeline's IMU thread in a loop; it may block (a live driver waits
/// for its device, a paced replay sleeps) and returns `None` at the end of the stream. The
/// events must come in the estimator's time order (see the module docs).
pub trait Source {
    /// The next event, `None` at the end.
    fn next(&mut self) -> Option<SensorEvent>;

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

/// When each LiDAR sweep of `ds` is due: `(trigger_ns, index into ds.lidar)` in push order.
/// The trigger is the sweep's last point time on the IMU clock (`max t_point + td_l_s`; the
/// sweep stamp for a sweep without points): the INS must have reached it to de-skew the whole
/// sweep. Ties keep the dataset order.
pub fn lidar_schedule(ds: &Dataset, td_l_s: f64) -> Vec<(i64, usize)> {
    let td_ns = (td_l_s * 1e9).round() as i64;
    let mut due: Vec<(i64, usize)> = ds
        .lidar
        .iter()
        .enumerate()
        .map(|(k, scan)| {
            let last = scan
                .points
                .iter()
                .map(|p| p.t_ns)
                .max()
                .unwrap_or(scan.t_ns);
            (last.saturating_add(td_ns), k)
        })
        .collect();
    due.sort_unstable();
    due
}

/// Replays a [`Dataset`]'s IMU samples, feature frames and LiDAR sweeps in the estimator's
/// time order (module docs), paced on a [`Clock`].
#[derive(Debug)]
pub struct DatasetSource<'a, C: Clock = SystemClock> {
    ds: &'a Dataset,
    imu: usize,
    frame: usize,
    /// Camera images instead of feature frames (the image front end).
    images: bool,
    image: usize,
    scans: Vec<(i64, usize)>,
    scan: usize,
    /// The pacing of the next sample has been waited for.
    paced: bool,
    pacer: Pacer,
    clock: C,
}

impl<'a> DatasetSource<'a, SystemClock> {
    /// Replays `ds` from its first IMU sample at or after `t_start_ns`; a LiDAR sweep arrives
    /// when the IMU clock reaches its last point (`td_l_s`: the estimator's `lidar.td_l_s`,
    /// `t_imu = t_lidar + td_l_s`).
    pub fn new(ds: &'a Dataset, t_start_ns: i64, td_l_s: f64, pacing: Pacing) -> Self {
        Self::with_clock(ds, t_start_ns, td_l_s, pacing, SystemClock)
    }
}

impl<'a, C: Clock> DatasetSource<'a, C> {
    /// [`DatasetSource::new`] on another clock.
    pub fn with_clock(
        ds: &'a Dataset,
        t_start_ns: i64,
        td_l_s: f64,
        pacing: Pacing,
        clock: C,
    ) -> Self {
        let imu = ds.imu.partition_point(|s| s.t_ns < t_start_ns);
        let t0 = ds.imu.get(imu).map_or(i64::MAX, |s| s.t_ns);
        // A sweep arrives when it is complete (its last point on the IMU clock); the estimator
        // holds it until it has processed the IMU that far.
        let scans = lidar_schedule(ds, td_l_s);
        DatasetSource {
            ds,
            imu,
            frame: ds.features.partition_point(|f| f.t_ns < t0),
            images: false,
            image: ds.images.partition_point(|f| f.t_ns < t0),
            scan: scans.partition_point(|&(t, _)| t < t0),
            scans,
            paced: false,
            pacer: Pacer::new(pacing),
            clock,
        }
    }

    /// Emits the dataset's camera images ([`SensorEvent::Image`], for the image front end)
    /// instead of its feature frames, in the same order: an image before the first IMU sample
    /// at or after its stamp (as `povins run --frontend images` pushes them).
    pub fn with_images(mut self) -> Self {
        self.images = true;
        self
    }

    /// IMU samples left to emit (the one being emitted included).
    pub fn imu_remaining(&self) -> usize {
        self.ds.imu.len().saturating_sub(self.imu)
    }

    /// The clock (tests read what it was asked to sleep).
    pub fn clock(&self) -> &C {
        &self.clock
    }
}

impl<C: Clock> Source for DatasetSource<'_, C> {
    fn next(&mut self) -> Option<SensorEvent> {
        let s = *self.ds.imu.get(self.imu)?;
        if !self.paced {
            self.pacer.wait_for(s.t_ns, &mut self.clock);
            self.paced = true;
        }
        if self.images {
            if let Some(im) = self.ds.images.get(self.image).filter(|f| f.t_ns <= s.t_ns) {
                self.image += 1;
                return Some(SensorEvent::Image {
                    t_cam_ns: im.t_ns,
                    data: image_data(im),
                });
            }
        } else if let Some(f) = self
            .ds
            .features
            .get(self.frame)
            .filter(|f| f.t_ns <= s.t_ns)
        {
            self.frame += 1;
            return Some(SensorEvent::Frame {
                t_cam_ns: f.t_ns,
                obs: f.obs.clone(),
            });
        }
        if let Some(&(_, k)) = self.scans.get(self.scan).filter(|(t, _)| *t <= s.t_ns) {
            self.scan += 1;
            if let Some(scan) = self.ds.lidar.get(k) {
                return Some(SensorEvent::Lidar(scan.points.clone()));
            }
        }
        // The sample's frames and sweeps are out: the sample, then on to the next one.
        self.paced = false;
        self.imu += 1;
        Some(SensorEvent::Imu(s))
    }

    fn stamp_instant(&self, t_ns: i64) -> Option<Instant> {
        self.pacer.instant_of(t_ns)
    }

    fn is_realtime(&self) -> bool {
        self.pacer.is_paced()
    }
}

/// A dataset image as the source hands it over: its file (decoded later), else its pixels.
fn image_data(im: &ImageFrame) -> ImageData {
    match (&im.path, im.mono8.is_empty()) {
        (Some(p), true) => ImageData::File(p.clone()),
        _ => ImageData::Mono8 {
            width: im.width as usize,
            height: im.height as usize,
            pixels: im.mono8.clone(),
        },
    }
}

#[cfg(test)]
#[path = "source_tests.rs"]
mod tests;

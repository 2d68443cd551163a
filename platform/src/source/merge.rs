//! The one arrival order of a recording's replay, for every consumer (`povins run`, the
//! threaded pipeline, the front end alone):
//!
//! for every IMU sample `s` from the start on, first the camera frames or images with
//! `t_cam <= s.t_ns` not yet offered, then the LiDAR sweeps that are complete by `s` (their last
//! point on the IMU clock, [`povins_core::lidar::sweep_due_ns`], `<= s.t_ns`; a sweep without
//! points at its stamp), then `s`. Frames, images and sweeps due before the first IMU sample
//! replayed are skipped. Messages after the last IMU sample are not offered (nothing would
//! process them).
//!
//! The streams are pulled incrementally ([`crate::recording::Stream`]): at any time the source
//! holds one IMU sample, one camera message and at most [`SWEEP_LOOKAHEAD`] sweeps. Sweeps are
//! offered in the order of their due times (ties in recorded order); a recording whose sweeps are
//! out of that order by more than the lookahead has the late ones offered late.
//!
//! Pacing: every event is released at the wall time of the IMU sample it is grouped with (the
//! sample after it): the stream of IMU stamps is mapped to wall time from the first event on,
//! divided by the speed factor.

use super::{Clock, Pacer, Pacing, SensorEvent, Source, SystemClock};
use crate::dataset::ImageFrame;
use crate::error::IoError;
use crate::images::ImageData;
use crate::recording::{Recording, Stream};
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use std::iter::Peekable;
use std::time::Instant;

/// Sweeps read ahead to offer them in the order of their due times.
pub const SWEEP_LOOKAHEAD: usize = 4;

/// What a replay offers of the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraInput {
    /// The recording's feature tracks ([`SensorEvent::Frame`]).
    Frames,
    /// The recording's images ([`SensorEvent::Image`]).
    Images,
    /// Nothing.
    None,
}

/// How a recording is replayed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeOptions {
    /// The replay starts at the first IMU sample at or after this stamp, ns.
    pub start_ns: i64,
    /// The LiDAR time offset (`t_imu = t_lidar + td_l_s`, the estimator's `lidar.td_l_s`), s.
    pub td_l_s: f64,
    /// Frames, images or no camera.
    pub camera: CameraInput,
    /// Whether LiDAR sweeps are offered.
    pub lidar: bool,
    /// Recorded rate or as fast as possible.
    pub pacing: Pacing,
}

impl MergeOptions {
    /// From the first sample, as fast as possible, the camera as given, the LiDAR on.
    pub fn new(camera: CameraInput) -> Self {
        MergeOptions {
            start_ns: i64::MIN,
            td_l_s: 0.0,
            camera,
            lidar: true,
            pacing: Pacing::AsFastAsPossible,
        }
    }
}

/// A recording's replay in the arrival order (module docs), paced on a [`Clock`].
pub struct MergedSource<'a, C: Clock = SystemClock> {
    imu: Peekable<Stream<'a, ImuSample>>,
    camera: Peekable<Stream<'a, (i64, SensorEvent)>>,
    sweeps: Stream<'a, (i64, Vec<LidarPoint>)>,
    /// Sweeps read ahead: `(due, arrival, points)`.
    ahead: Vec<(i64, u64, Vec<LidarPoint>)>,
    /// The first replayed sample's stamp, once known.
    t0: Option<i64>,
    start_ns: i64,
    /// The pacing of the next sample has been waited for.
    paced: bool,
    pacer: Pacer,
    clock: C,
    /// Counts of what was offered and skipped.
    stats: MergeStats,
}

/// What a replay read and offered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MergeStats {
    /// IMU samples offered.
    pub imu: u64,
    /// Camera frames or images read (offered or skipped).
    pub camera_read: u64,
    /// LiDAR sweeps read (offered, skipped, or read ahead and never due).
    pub sweeps_read: u64,
    /// Merge time of the first camera frame or image offered, ns.
    pub first_camera_ns: Option<i64>,
    /// Stamp of the first camera frame or image read, offered or skipped, ns (with
    /// [`MergedSource::pending_camera_ns`], what tells stamps in another unit or clock).
    pub first_camera_read_ns: Option<i64>,
    /// Camera frames or images read but skipped: stamped before the replay's first IMU sample.
    pub camera_skipped: u64,
    /// Stamps of the first and last IMU sample offered, ns.
    pub imu_span_ns: Option<(i64, i64)>,
}

impl<'a> MergedSource<'a, SystemClock> {
    /// Replays `rec` with `opts` on the system clock.
    pub fn new(rec: &'a dyn Recording, opts: &MergeOptions) -> Result<Self, IoError> {
        Self::with_clock(rec, opts, SystemClock)
    }
}

impl<'a, C: Clock> MergedSource<'a, C> {
    /// [`MergedSource::new`] on another clock.
    pub fn with_clock(
        rec: &'a dyn Recording,
        opts: &MergeOptions,
        clock: C,
    ) -> Result<Self, IoError> {
        let camera: Stream<'a, (i64, SensorEvent)> = match opts.camera {
            CameraInput::Frames => Box::new(rec.frames()?.map(|f| {
                f.map(|f| {
                    let ev = SensorEvent::Frame {
                        t_cam_ns: f.t_ns,
                        obs: f.obs,
                    };
                    (f.t_ns, ev)
                })
            })),
            CameraInput::Images => Box::new(rec.images()?.map(|im| {
                im.map(|im| {
                    let t_cam_ns = im.t_ns;
                    let ev = SensorEvent::Image {
                        t_cam_ns,
                        data: image_data(im),
                        prepared_ns: 0,
                    };
                    (t_cam_ns, ev)
                })
            })),
            CameraInput::None => Box::new(std::iter::empty()),
        };
        let sweeps: Stream<'a, (i64, Vec<LidarPoint>)> = if opts.lidar {
            let td_l_s = opts.td_l_s;
            let td_ns = (td_l_s * 1e9).round() as i64;
            Box::new(rec.sweeps()?.map(move |scan| {
                scan.map(|scan| {
                    let due = povins_core::lidar::sweep_due_ns(&scan.points, td_l_s)
                        .unwrap_or(scan.t_ns.saturating_add(td_ns));
                    (due, scan.points)
                })
            }))
        } else {
            Box::new(std::iter::empty())
        };
        Ok(MergedSource {
            imu: rec.imu()?.peekable(),
            camera: camera.peekable(),
            sweeps,
            ahead: Vec::with_capacity(SWEEP_LOOKAHEAD),
            t0: None,
            start_ns: opts.start_ns,
            paced: false,
            pacer: Pacer::new(opts.pacing),
            clock,
            stats: MergeStats::default(),
        })
    }

    /// What was read and offered so far.
    pub fn stats(&self) -> MergeStats {
        self.stats
    }

    /// The stamp of the next camera frame or image not read yet (at the end of a replay: one
    /// stamped after the last IMU sample, never due), ns.
    pub fn pending_camera_ns(&mut self) -> Option<i64> {
        match self.camera.peek() {
            Some(Ok((t, _))) => Some(*t),
            _ => None,
        }
    }

    /// The clock (tests read what it was asked to sleep).
    pub fn clock(&self) -> &C {
        &self.clock
    }

    /// The next IMU sample to replay (skipping those before the start), without taking it.
    fn peek_imu(&mut self) -> Result<Option<ImuSample>, IoError> {
        loop {
            match self.imu.peek() {
                None => return Ok(None),
                Some(Err(_)) => return Err(take_err(self.imu.next())),
                Some(Ok(s)) if s.t_ns < self.start_ns && self.t0.is_none() => {
                    let _ = self.imu.next();
                }
                Some(Ok(s)) => {
                    let s = *s;
                    if self.t0.is_none() {
                        self.t0 = Some(s.t_ns);
                    }
                    return Ok(Some(s));
                }
            }
        }
    }

    /// The next camera event due at or before `t_ns` (skipping those before the start).
    fn camera_due(&mut self, t_ns: i64, t0: i64) -> Result<Option<SensorEvent>, IoError> {
        loop {
            match self.camera.peek() {
                None => return Ok(None),
                Some(Err(_)) => return Err(take_err(self.camera.next())),
                Some(Ok((t, _))) if *t > t_ns => return Ok(None),
                Some(Ok((t, _))) => {
                    let t = *t;
                    let next = self.camera.next();
                    self.stats.camera_read += 1;
                    self.stats.first_camera_read_ns.get_or_insert(t);
                    if t < t0 {
                        self.stats.camera_skipped += 1;
                        continue;
                    }
                    self.stats.first_camera_ns.get_or_insert(t);
                    return Ok(next.and_then(Result::ok).map(|(_, ev)| ev));
                }
            }
        }
    }

    /// The next sweep due at or before `t_ns` (skipping those due before the start).
    fn sweep_due(&mut self, t_ns: i64, t0: i64) -> Result<Option<Vec<LidarPoint>>, IoError> {
        loop {
            while self.ahead.len() < SWEEP_LOOKAHEAD {
                match self.sweeps.next() {
                    None => break,
                    Some(Err(e)) => return Err(e),
                    Some(Ok((due, points))) => {
                        self.ahead.push((due, self.stats.sweeps_read, points));
                        self.stats.sweeps_read += 1;
                    }
                }
            }
            let Some(k) = (0..self.ahead.len()).min_by_key(|&k| (self.ahead[k].0, self.ahead[k].1))
            else {
                return Ok(None);
            };
            let due = self.ahead[k].0;
            if due > t_ns {
                return Ok(None);
            }
            let (_, _, points) = self.ahead.remove(k);
            if due >= t0 {
                return Ok(Some(points));
            }
        }
    }
}

/// The error of a stream item known to be one.
fn take_err<T>(item: Option<Result<T, IoError>>) -> IoError {
    match item {
        Some(Err(e)) => e,
        _ => IoError::Invalid {
            path: "<stream>".into(),
            msg: "a stream's error could not be taken".into(),
        },
    }
}

impl<C: Clock> Source for MergedSource<'_, C> {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        let Some(s) = self.peek_imu()? else {
            return Ok(None);
        };
        let t0 = self.t0.unwrap_or(s.t_ns);
        if !self.paced {
            self.pacer.wait_for(s.t_ns, &mut self.clock);
            self.paced = true;
        }
        if let Some(ev) = self.camera_due(s.t_ns, t0)? {
            return Ok(Some(ev));
        }
        if let Some(points) = self.sweep_due(s.t_ns, t0)? {
            return Ok(Some(SensorEvent::Lidar(points)));
        }
        // The sample's frames and sweeps are out: the sample, then on to the next one.
        self.paced = false;
        let _ = self.imu.next();
        self.stats.imu += 1;
        let first = self.stats.imu_span_ns.map_or(s.t_ns, |(a, _)| a);
        self.stats.imu_span_ns = Some((first, s.t_ns));
        Ok(Some(SensorEvent::Imu(s)))
    }

    fn stamp_instant(&self, t_ns: i64) -> Option<Instant> {
        self.pacer.instant_of(t_ns)
    }

    fn is_realtime(&self) -> bool {
        self.pacer.is_paced()
    }
}

/// A recording's image as a source hands it over: its file (decoded later), else its pixels.
fn image_data(im: ImageFrame) -> ImageData {
    match (im.path, im.mono8.is_empty()) {
        (Some(p), true) => ImageData::File(p),
        _ => ImageData::Mono8 {
            width: im.width as usize,
            height: im.height as usize,
            pixels: im.mono8,
        },
    }
}

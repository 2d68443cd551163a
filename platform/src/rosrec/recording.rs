//! A ROS recording as a [`Recording`]: the IMU, camera and LiDAR topics chosen by
//! [`super::topics`], their messages pulled in the container's log-time order and decoded one at
//! a time as the streams are pulled (images to gray then, not before; LiDAR clouds in whatever
//! driver layout, [`crate::cloud`]). The calibration is given by the caller (Kalibr files, an
//! EuRoC folder's `sensor.yaml` files, which give the LiDAR extrinsic `T_bl`).
//!
//! When the LiDAR stream ends, one line says what it gave: sweeps, points kept and dropped by
//! cause, and where the point times came from (a [`crate::recording::NOTE`] when nothing was
//! dropped or guessed, a warning otherwise).
//!
//! ## Stamps
//! A sample's time is its `header.stamp`. A stamp of zero (a driver that leaves the header
//! empty) is replaced by the message's log time, with one warning per topic. Faulty samples are
//! data, not errors: a sample whose stamp is not after the previous one of its topic (duplicated
//! or backward) is dropped and counted; only a topic where most samples are dropped (more than
//! half once [`MIN_SAMPLES_FOR_ORDER_CHECK`] were seen) is refused. A part of the container that
//! cannot be read (a corrupt chunk) is skipped with a warning naming its byte offset. The counts
//! are in [`Recording::warnings`] once a stream has ended.

use super::decode::{self, MsgError};
use super::merge::{self, AccelUnit, Merged};
use super::topics::{select_with, TopicChoice};
use super::{LogStream, MessageLog, TopicInfo};
use crate::cloud::{CloudCounts, CloudOptions, Decoded, TimeSource};
use crate::dataset::{Calibration, FeatureFrame, ImageFrame, LidarScan};
use crate::error::IoError;
use crate::recording::{Contents, Recording, Stream};
use povins_core::inertial::{ImuSample, NavState};
use std::sync::Mutex;

/// Samples of a topic seen before a mostly-out-of-order topic is refused.
pub const MIN_SAMPLES_FOR_ORDER_CHECK: u64 = 20;

/// A ROS recording with its chosen topics and a calibration (see the module docs).
#[derive(Debug)]
pub struct RosRecording {
    name: String,
    log: Box<dyn MessageLog>,
    calib: Calibration,
    imu: TopicInfo,
    camera: Option<TopicInfo>,
    accel: Option<TopicInfo>,
    lidar: Option<TopicInfo>,
    cloud: CloudOptions,
    unit: AccelUnit,
    warnings: std::sync::Arc<Mutex<Vec<String>>>,
}

impl RosRecording {
    /// Takes `log`, chooses its topics as `choice` says ([`super::topics`]), decides the
    /// accelerometer's unit ([`merge`]) and takes `calib` as its calibration. A recording
    /// without an IMU topic is an error listing its topics.
    pub fn new(
        log: Box<dyn MessageLog>,
        calib: Calibration,
        choice: &TopicChoice,
    ) -> Result<Self, IoError> {
        let path = log.path().to_path_buf();
        let invalid = |msg: String| IoError::Invalid {
            path: path.clone(),
            msg,
        };
        let all = log.topics();
        let sel = select_with(&all, choice).map_err(invalid)?;
        let imu = sel.imu.ok_or_else(|| {
            let mut list: Vec<String> = all
                .iter()
                .map(|t| format!("{} ({})", t.topic, t.msg_type))
                .collect();
            if list.is_empty() {
                list.push("none".into());
            }
            invalid(format!(
                "no sensor_msgs/Imu topic with messages; topics: {}",
                list.join(", ")
            ))
        })?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut warnings = log.warnings();
        if let Some(note) = sel.lidar_note {
            warnings.push(format!("{}: {note}", path.display()));
        }
        let warnings = std::sync::Arc::new(Mutex::new(warnings));
        let mut rec = RosRecording {
            name,
            log,
            calib,
            imu,
            camera: sel.camera,
            accel: sel.accel,
            lidar: sel.lidar,
            cloud: choice.cloud,
            unit: choice.accel_unit,
            warnings,
        };
        if rec.unit == AccelUnit::Auto {
            let (unit, warning) = merge::detect_unit(&rec.first_accels());
            rec.unit = unit;
            if let Some(w) = warning {
                rec.warn(format!("{}: {w}", path.display()));
            }
        }
        Ok(rec)
    }

    /// The first accelerometer samples (decodable ones), for the unit.
    fn first_accels(&self) -> Vec<povins_core::math::Vec3> {
        let t = self.accel.as_ref().unwrap_or(&self.imu);
        self.log
            .messages(&t.topic)
            .filter_map(|m| decode::imu(t.encoding, &m.ok()?.data).ok())
            .take(merge::UNIT_SAMPLES)
            .map(|s| s.accel_mps2)
            .collect()
    }

    /// The accelerometer's unit (decided when it was `Auto`).
    pub fn accel_unit(&self) -> AccelUnit {
        self.unit
    }

    /// The accelerometer topic merged into the IMU's samples.
    pub fn accel_topic(&self) -> Option<&TopicInfo> {
        self.accel.as_ref()
    }

    /// The container.
    pub fn log(&self) -> &dyn MessageLog {
        self.log.as_ref()
    }

    /// The chosen IMU topic.
    pub fn imu_topic(&self) -> &TopicInfo {
        &self.imu
    }

    /// The chosen camera topic.
    pub fn camera_topic(&self) -> Option<&TopicInfo> {
        self.camera.as_ref()
    }

    /// The chosen LiDAR topic.
    pub fn lidar_topic(&self) -> Option<&TopicInfo> {
        self.lidar.as_ref()
    }

    fn warn(&self, msg: String) {
        if let Ok(mut w) = self.warnings.lock() {
            w.push(msg);
        }
    }

    /// `topic`'s messages decoded by `decode`, with the stamp rules of the module docs.
    fn checked<'a, T: Stamped + Send + 'a>(
        &'a self,
        topic: &'a TopicInfo,
        decode: impl Fn(&[u8]) -> Result<T, MsgError> + Send + 'a,
    ) -> Stream<'a, T> {
        Box::new(Checked {
            _sample: std::marker::PhantomData,
            rec: self,
            topic,
            inner: self.log.messages(&topic.topic),
            decode,
            index: 0,
            last_ns: None,
            seen: 0,
            dropped_dup: 0,
            dropped_back: 0,
            skipped_parts: 0,
            zero_stamps: 0,
            done: false,
        })
    }
}

/// A sample with a time.
trait Stamped {
    fn t_ns(&self) -> i64;
    fn set_t_ns(&mut self, t_ns: i64);
}

impl Stamped for ImuSample {
    fn t_ns(&self) -> i64 {
        self.t_ns
    }
    fn set_t_ns(&mut self, t_ns: i64) {
        self.t_ns = t_ns;
    }
}

impl Stamped for LidarScan {
    fn t_ns(&self) -> i64 {
        self.t_ns
    }
    fn set_t_ns(&mut self, t_ns: i64) {
        self.t_ns = t_ns;
    }
}

impl Stamped for ImageFrame {
    fn t_ns(&self) -> i64 {
        self.t_ns
    }
    fn set_t_ns(&mut self, t_ns: i64) {
        self.t_ns = t_ns;
    }
}

/// One topic's decoded, stamp-checked samples (see the module docs).
struct Checked<'a, T, D> {
    _sample: std::marker::PhantomData<fn() -> T>,
    rec: &'a RosRecording,
    topic: &'a TopicInfo,
    inner: LogStream<'a>,
    decode: D,
    index: u64,
    last_ns: Option<i64>,
    seen: u64,
    dropped_dup: u64,
    dropped_back: u64,
    skipped_parts: u64,
    zero_stamps: u64,
    done: bool,
}

impl<T: Stamped, D: Fn(&[u8]) -> Result<T, MsgError>> Checked<'_, T, D> {
    fn path(&self) -> std::path::PathBuf {
        self.rec.log.path().to_path_buf()
    }

    /// The counts, as a warning, when something was dropped.
    fn finish(&mut self) {
        self.done = true;
        let t = &self.topic.topic;
        if self.dropped_dup + self.dropped_back > 0 {
            self.rec.warn(format!(
                "{}: {t}: {} of {} samples dropped ({} duplicated and {} backward stamps)",
                self.path().display(),
                self.dropped_dup + self.dropped_back,
                self.seen,
                self.dropped_dup,
                self.dropped_back
            ));
        }
        if self.skipped_parts > 0 {
            self.rec.warn(format!(
                "{}: {t}: {} unreadable parts skipped (see the warnings above)",
                self.path().display(),
                self.skipped_parts
            ));
        }
    }
}

impl<T: Stamped, D: Fn(&[u8]) -> Result<T, MsgError>> Iterator for Checked<'_, T, D> {
    type Item = Result<T, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        loop {
            let m = match self.inner.next() {
                None => {
                    self.finish();
                    return None;
                }
                Some(Err(IoError::Corrupt {
                    file,
                    what,
                    offset,
                    msg,
                })) => {
                    self.skipped_parts += 1;
                    self.rec.warn(format!(
                        "{}: {}: {what} at byte offset {offset} skipped: {msg}",
                        file.display(),
                        self.topic.topic
                    ));
                    continue;
                }
                Some(Err(e)) => {
                    self.done = true;
                    return Some(Err(e));
                }
                Some(Ok(m)) => m,
            };
            let k = self.index;
            self.index += 1;
            let mut s = match (self.decode)(&m.data) {
                Ok(s) => s,
                Err(e) => {
                    self.done = true;
                    return Some(Err(IoError::Corrupt {
                        file: self.path(),
                        what: format!(
                            "{} message {k} ({}, {})",
                            self.topic.topic,
                            self.topic.msg_type,
                            self.rec.log.locate(m.offset)
                        ),
                        offset: e.offset as u64,
                        msg: e.msg,
                    }));
                }
            };
            if s.t_ns() == 0 {
                if self.zero_stamps == 0 {
                    self.rec.warn(format!(
                        "{}: {}: header.stamp is zero: the log time is used instead",
                        self.path().display(),
                        self.topic.topic
                    ));
                }
                self.zero_stamps += 1;
                s.set_t_ns(m.log_time_ns);
            }
            self.seen += 1;
            let t = s.t_ns();
            match self.last_ns {
                Some(last) if t == last => self.dropped_dup += 1,
                Some(last) if t < last => self.dropped_back += 1,
                _ => {
                    self.last_ns = Some(t);
                    return Some(Ok(s));
                }
            }
            let dropped = self.dropped_dup + self.dropped_back;
            if self.seen >= MIN_SAMPLES_FOR_ORDER_CHECK && 2 * dropped > self.seen {
                self.done = true;
                return Some(Err(IoError::Invalid {
                    path: self.path(),
                    msg: format!(
                        "{}: {dropped} of the first {} samples have a stamp not after the \
                         previous one: the topic is mostly out of order",
                        self.topic.topic, self.seen
                    ),
                }));
            }
        }
    }
}

/// What the sweeps of a LiDAR topic dropped, and where their point times came from.
#[derive(Debug, Default)]
struct CloudTally {
    sweeps: u64,
    counts: CloudCounts,
    time: Option<TimeSource>,
    other_time: Option<TimeSource>,
}

impl CloudTally {
    fn add(&mut self, d: &Decoded) {
        self.sweeps += 1;
        self.counts.add(&d.counts);
        match self.time {
            None => self.time = Some(d.time),
            Some(t) if t != d.time && self.other_time.is_none() => self.other_time = Some(d.time),
            _ => {}
        }
    }
}

/// A LiDAR topic's sweeps; when they end, a line for the user on what was read and dropped.
struct Tallied<'a> {
    inner: Stream<'a, LidarScan>,
    tally: std::sync::Arc<Mutex<CloudTally>>,
    rec: &'a RosRecording,
    topic: &'a TopicInfo,
}

impl Iterator for Tallied<'_> {
    type Item = Result<LidarScan, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        let next = self.inner.next();
        if next.is_none() {
            let Ok(mut g) = self.tally.lock() else {
                return None;
            };
            if g.sweeps > 0 {
                let t = std::mem::take(&mut *g);
                self.rec.warn(describe_tally(self.rec, self.topic, &t));
            }
        }
        next
    }
}

/// `FILE: TOPIC (TYPE): N sweeps, M of P points kept (...); point time from ...`: a note when
/// nothing was dropped and the times are what the field says, else a warning.
fn describe_tally(rec: &RosRecording, topic: &TopicInfo, t: &CloudTally) -> String {
    let c = &t.counts;
    let clean = c.dropped() == 0
        && t.other_time.is_none()
        && matches!(t.time, Some(TimeSource::Field { expected: true, .. }));
    let mut s = format!(
        "{}{}: {} ({}): {} sweeps, {} of {} points kept",
        if clean { crate::recording::NOTE } else { "" },
        rec.log.path().display(),
        topic.topic,
        topic.msg_type,
        t.sweeps,
        c.points - c.dropped(),
        c.points
    );
    if c.dropped() > 0 {
        s.push_str(&format!("; {}", c.describe()));
    }
    if let Some(time) = t.time {
        s.push_str(&format!("; {time}"));
        if let TimeSource::Field {
            expected: false, ..
        } = time
        {
            s.push_str(
                " (not what the field's name and type suggest: the values fit only this; \
                 set [input] lidar_layout if it is wrong)",
            );
        }
    }
    if let Some(other) = t.other_time {
        s.push_str(&format!("; some sweeps differ: {other}"));
    }
    s
}

impl Recording for RosRecording {
    fn name(&self) -> &str {
        &self.name
    }

    fn calibration(&self) -> &Calibration {
        &self.calib
    }

    fn contents(&self) -> Contents {
        Contents {
            imu: true,
            frames: false,
            images: self.camera.is_some(),
            lidar: self.lidar.is_some(),
            ground_truth: false,
            imu_span_ns: self.imu.span_ns,
            image_count: self.camera.as_ref().map(|c| c.count as usize),
        }
    }

    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError> {
        let enc = self.imu.encoding;
        let gyro = self.checked(&self.imu, move |b| decode::imu(enc, b));
        let samples = match &self.accel {
            None => gyro,
            Some(a) => {
                let enc = a.encoding;
                let accel = self.checked(a, move |b| decode::imu(enc, b));
                let (warnings, path, topic) = (
                    self.warnings.clone(),
                    self.log.path().display().to_string(),
                    self.imu.topic.clone(),
                );
                let on_end = Box::new(move |dropped: u64| {
                    if let (true, Ok(mut w)) = (dropped > 0, warnings.lock()) {
                        w.push(format!(
                            "{path}: {topic}: {dropped} gyro samples outside the \
                             accelerometer's time span dropped (nothing to interpolate)"
                        ));
                    }
                });
                Box::new(Merged::new(gyro, accel, on_end))
            }
        };
        let k = merge::scale(self.unit);
        if k == 1.0 {
            return Ok(samples);
        }
        Ok(Box::new(samples.map(move |s| {
            s.map(|mut s| {
                s.accel_mps2 *= k;
                s
            })
        })))
    }

    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError> {
        Ok(Box::new(std::iter::empty()))
    }

    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError> {
        let Some(t) = &self.camera else {
            return Ok(Box::new(std::iter::empty()));
        };
        let (enc, ty) = (t.encoding, t.msg_type.clone());
        Ok(self.checked(t, move |b| decode::image(enc, &ty, b)))
    }

    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError> {
        let Some(t) = &self.lidar else {
            return Ok(Box::new(std::iter::empty()));
        };
        let (enc, ty, opts) = (t.encoding, t.msg_type.clone(), self.cloud);
        let tally = std::sync::Arc::new(Mutex::new(CloudTally::default()));
        let into = tally.clone();
        let inner = self.checked(t, move |b| {
            let d = decode::sweep(enc, &ty, b, &opts)?;
            if let Ok(mut g) = into.lock() {
                g.add(&d);
            }
            Ok(d.scan)
        });
        Ok(Box::new(Tallied {
            inner,
            tally,
            rec: self,
            topic: t,
        }))
    }

    fn ground_truth_stream(&self) -> Result<Stream<'_, NavState>, IoError> {
        Ok(Box::new(std::iter::empty()))
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.lock().map(|w| w.clone()).unwrap_or_default()
    }
}

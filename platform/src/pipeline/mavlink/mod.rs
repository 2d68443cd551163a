//! Odometry to the autopilot over MAVLink ([`MavlinkSink`]): `ODOMETRY` (#331) at a set rate,
//! `HEARTBEAT` at 1 Hz, and answers to the autopilot's `TIMESYNC` (#111) requests, over UDP or
//! a serial port ([`link`]).
//!
//! ## What is sent
//! `ODOMETRY` from system [`MavlinkOptions::system_id`] (default 1, the vehicle's), component
//! 197 (`MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY`), `estimator_type` VIO:
//! - `frame_id` `MAV_FRAME_LOCAL_FRD`, `child_frame_id` `MAV_FRAME_BODY_FRD`: the position and
//!   attitude in the local FRD frame, the velocity in the vehicle's body FRD frame ([`frames`]
//!   says how they follow from povins' z-up world and IMU body, and [`frames::BodyAxes`] how
//!   the IMU is mounted on the vehicle).
//! - `time_usec`: the **measurement's** time (the IMU sample the pose is at), on the sensor
//!   clock, in microseconds; not the time of sending. The autopilot maps it onto its own clock
//!   with `TIMESYNC`: a request (`tc1 = 0`, `ts1` its time) is answered with `tc1` = povins'
//!   sensor clock now, ns, `ts1` echoed. povins' "now" on the sensor clock is the newest
//!   published pose's stamp plus the time since that stamp was due (the source's
//!   [`stamp_instant`](crate::source::Source::stamp_instant); its arrival otherwise), so for a
//!   paced replay or a live source it runs with the wall clock. Requests before the first pose
//!   are not answered (counted).
//! - The rate: a pose is sent when its stamp is at least `1 / rate_hz` after the last one sent
//!   (the IMU-rate output decimated by sensor time, so the same poses are sent in every run).
//! - `reset_counter`: incremented when the estimator re-initializes (a keyframe report
//!   `First` after the first): the estimate restarts in a new world frame, and the autopilot
//!   must not fuse it as a continuation.
//! - `quality` (%): 0 before the first keyframe, then `100 * min(1, used / 50)` of the newest
//!   keyframe's landmarks used in its solve (at least 1): a heuristic of the visual
//!   constraint's strength, for PX4's `EKF2_EV_QMIN`.
//! - The covariances: the estimator's own (`EstimatorConfig::covariance`, which `povins replay
//!   --mavlink` turns on; [`povins_core::inertial::InsCovariance`]: the newest keyframe's
//!   marginal covariance propagated at IMU rate) in these frames ([`frames::covariance_to_frd`]):
//!   position and attitude (about the local frame's axes) in `pose_covariance`, the body
//!   velocity in `velocity_covariance`, whose angular-speed rows are NaN (the angular speeds
//!   are sent as NaN: unknown). Without a covariance (off, or before the first solve) both
//!   are sent as unknown (NaN first elements) and the autopilot uses its own noise parameters
//!   (`EKF2_EVP_NOISE`, `EKF2_EVV_NOISE`, `EKF2_EVA_NOISE`; ArduPilot `VISO_POS_M_NSE`,
//!   `VISO_VEL_M_NSE`, `VISO_YAW_M_NSE`). How well it describes the error: BENCHMARKS.md
//!   ("The covariance sent").
//!
//! ## Threads
//! The sink's calls run on the pipeline's IMU thread and only decimate, convert (a few
//! matrix products) and push to a lock-free queue; a sending thread builds and sends the
//! frames (and the heartbeat), a receiving thread answers `TIMESYNC`. A full queue drops the
//! pose (counted).

pub mod frames;
pub mod link;

pub use frames::{covariance_to_frd, from_frd, to_frd, BodyAxes, FrdCovariance, FrdPose};
pub use link::{Endpoint, Link};

use super::sink::{KeyframeOut, PoseOut, RateDecimator, Sink};
use crate::error::IoError;
use ::mavlink::dialects::common::{
    MavAutopilot, MavEstimatorType, MavFrame, MavMessage, MavModeFlag, MavState, MavType,
    HEARTBEAT_DATA, ODOMETRY_DATA, TIMESYNC_DATA, VISION_POSITION_ESTIMATE_DATA,
};
use ::mavlink::MavHeader;
use povins_core::frontend::KeyframeDecision;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// `MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY`.
pub const COMPONENT_VIO: u8 = 197;
/// Landmarks used in a keyframe's solve that give quality 100.
pub const QUALITY_FULL_LANDMARKS: u32 = 50;
/// Poses waiting for the sending thread.
const QUEUE: usize = 256;

/// How the odometry is sent.
#[derive(Debug, Clone, PartialEq)]
pub struct MavlinkOptions {
    /// Where to.
    pub endpoint: Endpoint,
    /// `ODOMETRY` messages per second (of sensor time).
    pub rate_hz: f64,
    /// The sender's system id (the vehicle's: PX4 and ArduPilot take external odometry from
    /// a component of their own system).
    pub system_id: u8,
    /// The sender's component id.
    pub component_id: u8,
    /// How the IMU sits on the vehicle.
    pub axes: BodyAxes,
    /// Also send `VISION_POSITION_ESTIMATE` (#102) with each `ODOMETRY`: the same position in
    /// the local FRD frame and the attitude as roll, pitch, yaw (for ArduPilot setups that take
    /// that message; its `reset_counter` follows `ODOMETRY`'s).
    pub vision_position: bool,
}

impl MavlinkOptions {
    /// `endpoint` at 30 Hz, system 1, component 197, an IMU mounted forward-left-up.
    pub fn new(endpoint: Endpoint) -> Self {
        MavlinkOptions {
            endpoint,
            rate_hz: 30.0,
            system_id: 1,
            component_id: COMPONENT_VIO,
            axes: BodyAxes::default(),
            vision_position: false,
        }
    }
}

/// What the MAVLink output did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MavlinkCounts {
    /// `ODOMETRY` messages sent.
    pub odometry_sent: u64,
    /// `VISION_POSITION_ESTIMATE` messages sent ([`MavlinkOptions::vision_position`]).
    pub vision_position_sent: u64,
    /// `ODOMETRY` messages not sent: the queue to the sending thread was full.
    pub odometry_dropped_queue: u64,
    /// `ODOMETRY` messages with nowhere to go (`udpin` before a peer spoke, a refused
    /// loopback port).
    pub odometry_unsent: u64,
    /// `HEARTBEAT`s sent.
    pub heartbeats_sent: u64,
    /// Messages received (any type).
    pub received: u64,
    /// Received frames that did not parse.
    pub received_bad: u64,
    /// `TIMESYNC` requests answered.
    pub timesync_answered: u64,
    /// `TIMESYNC` requests before the first pose (not answered: no clock yet).
    pub timesync_unanswered: u64,
    /// Estimator re-initializations (each incremented `reset_counter`).
    pub resets: u64,
    /// Failed sends or receives, and the first error.
    pub errors: u64,
    /// The first error.
    pub first_error: Option<String>,
}

/// State shared by the sink and its two threads.
struct Shared {
    stop: AtomicBool,
    /// Sensor clock minus the monotonic clock ([`Shared::mono_ns`]), ns; `i64::MIN` unset.
    offset_ns: AtomicI64,
    sequence: AtomicU8,
    t0: Instant,
    counts: Mutex<MavlinkCounts>,
    sent: AtomicU64,
    unsent: AtomicU64,
    vision_sent: AtomicU64,
}

impl Shared {
    fn mono_ns(&self) -> i64 {
        i64::try_from(self.t0.elapsed().as_nanos()).unwrap_or(i64::MAX)
    }

    fn header(&self, o: &MavlinkOptions) -> MavHeader {
        MavHeader {
            system_id: u32::from(o.system_id),
            component_id: o.component_id,
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
        }
    }

    fn error(&self, e: &dyn std::fmt::Display) {
        if let Ok(mut c) = self.counts.lock() {
            c.errors += 1;
            if c.first_error.is_none() {
                c.first_error = Some(e.to_string());
            }
        }
    }
}

/// One pose on its way to the sending thread.
#[derive(Debug, Clone, Copy)]
struct Odom {
    time_usec: u64,
    pose: FrdPose,
    /// `None`: unknown (sent as NaN first elements).
    cov: Option<FrdCovariance>,
    reset_counter: u8,
    quality: i8,
}

/// A [`Sink`] sending the IMU-rate poses to an autopilot (see the module doc).
pub struct MavlinkSink {
    opts: MavlinkOptions,
    rate: RateDecimator,
    inits: u64,
    reset_counter: u8,
    quality: i8,
    dropped: u64,
    tx: rtrb::Producer<Odom>,
    shared: Arc<Shared>,
    link: Arc<Link>,
    sender: Option<JoinHandle<()>>,
    receiver: Option<JoinHandle<()>>,
}

impl MavlinkSink {
    /// Opens the link and starts the sending and receiving threads.
    pub fn new(opts: MavlinkOptions) -> Result<MavlinkSink, IoError> {
        let bad = |msg: String| IoError::Invalid {
            path: "--mavlink-rate".into(),
            msg,
        };
        if !(opts.rate_hz.is_finite() && opts.rate_hz > 0.0 && opts.rate_hz <= 1000.0) {
            return Err(bad(format!(
                "MAVLink rate {} Hz: expected (0, 1000]",
                opts.rate_hz
            )));
        }
        let link = Arc::new(Link::open(&opts.endpoint)?);
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            offset_ns: AtomicI64::new(i64::MIN),
            sequence: AtomicU8::new(0),
            t0: Instant::now(),
            counts: Mutex::new(MavlinkCounts::default()),
            sent: AtomicU64::new(0),
            unsent: AtomicU64::new(0),
            vision_sent: AtomicU64::new(0),
        });
        let (tx, rx) = rtrb::RingBuffer::new(QUEUE);
        let spawn = |name: &str, f: Box<dyn FnOnce() + Send>| {
            std::thread::Builder::new()
                .name(name.into())
                .spawn(f)
                .map_err(|e| IoError::Io {
                    path: format!("thread {name}").into(),
                    source: e,
                })
        };
        let sender = {
            let (s, l, o) = (shared.clone(), link.clone(), opts.clone());
            spawn("mavlink-tx", Box::new(move || send_loop(&s, &l, &o, rx)))?
        };
        let receiver = {
            let (s, l, o) = (shared.clone(), link.clone(), opts.clone());
            spawn("mavlink-rx", Box::new(move || recv_loop(&s, &l, &o)))?
        };
        Ok(MavlinkSink {
            rate: RateDecimator::new(opts.rate_hz),
            opts,
            inits: 0,
            reset_counter: 0,
            quality: 0,
            dropped: 0,
            tx,
            shared,
            link,
            sender: Some(sender),
            receiver: Some(receiver),
        })
    }

    /// The counts so far (complete after [`Sink::finish`]).
    pub fn counts(&self) -> MavlinkCounts {
        let mut c = self
            .shared
            .counts
            .lock()
            .map(|c| c.clone())
            .unwrap_or_default();
        c.odometry_sent = self.shared.sent.load(Ordering::Relaxed);
        c.vision_position_sent = self.shared.vision_sent.load(Ordering::Relaxed);
        c.odometry_unsent = self.shared.unsent.load(Ordering::Relaxed);
        c.odometry_dropped_queue = self.dropped;
        c.resets = self.inits.saturating_sub(1);
        c
    }

    /// The options.
    pub fn options(&self) -> &MavlinkOptions {
        &self.opts
    }
}

impl Sink for MavlinkSink {
    fn pose(&mut self, p: &PoseOut) {
        let t_ns = p.nav.t_ns;
        if !self.rate.take(t_ns) {
            return;
        }
        let since_due = p.stamp_latency_ns.unwrap_or(p.latency_ns);
        let sensor_now = t_ns.saturating_add(i64::try_from(since_due).unwrap_or(0));
        self.shared
            .offset_ns
            .store(sensor_now - self.shared.mono_ns(), Ordering::Relaxed);
        let odom = Odom {
            time_usec: u64::try_from(t_ns / 1000).unwrap_or(0),
            pose: to_frd(&p.nav, &self.opts.axes),
            cov: p
                .covariance
                .as_ref()
                .map(|c| covariance_to_frd(&p.nav, c, &self.opts.axes)),
            reset_counter: self.reset_counter,
            quality: self.quality,
        };
        if self.tx.push(odom).is_err() {
            self.dropped += 1;
        } else if let Some(h) = &self.sender {
            h.thread().unpark();
        }
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        if k.report.decision == KeyframeDecision::First {
            self.inits += 1;
            if self.inits > 1 {
                self.reset_counter = self.reset_counter.wrapping_add(1);
            }
        }
        let used = k.report.landmarks_used.min(QUALITY_FULL_LANDMARKS);
        self.quality = ((100 * used / QUALITY_FULL_LANDMARKS).max(1)) as i8;
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(h) = self.sender.take() {
            h.thread().unpark();
            let _ = h.join();
        }
        // A serial port's receive may block without a timeout: that thread is left to end
        // with the process.
        if matches!(*self.link, Link::Udp { .. }) {
            if let Some(h) = self.receiver.take() {
                let _ = h.join();
            }
        }
        Ok(())
    }
}

impl Drop for MavlinkSink {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(h) = &self.sender {
            h.thread().unpark();
        }
    }
}

/// The pose and velocity covariances of `o` ([`FrdCovariance`]), NaN first elements when
/// unknown.
fn covariances(o: &Odom) -> ([f32; 21], [f32; 21]) {
    match &o.cov {
        Some(c) => (c.pose, c.velocity),
        None => {
            let mut unknown = [0.0f32; 21];
            unknown[0] = f32::NAN;
            (unknown, unknown)
        }
    }
}

/// The `ODOMETRY` message of `o`.
fn odometry(o: &Odom) -> MavMessage {
    let f = &o.pose;
    let q = f.q_lv.quaternion();
    let (pose_covariance, velocity_covariance) = covariances(o);
    MavMessage::ODOMETRY(ODOMETRY_DATA {
        time_usec: o.time_usec,
        x: f.p_l.x as f32,
        y: f.p_l.y as f32,
        z: f.p_l.z as f32,
        q: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
        vx: f.v_v.x as f32,
        vy: f.v_v.y as f32,
        vz: f.v_v.z as f32,
        rollspeed: f32::NAN,
        pitchspeed: f32::NAN,
        yawspeed: f32::NAN,
        pose_covariance,
        velocity_covariance,
        frame_id: MavFrame::MAV_FRAME_LOCAL_FRD,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
        reset_counter: o.reset_counter,
        estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality: o.quality,
    })
}

/// The `VISION_POSITION_ESTIMATE` message of `o`: the position in the local FRD frame, the
/// attitude of the vehicle's FRD body in it as roll, pitch, yaw (Z-Y-X), the covariance unknown.
fn vision_position_estimate(o: &Odom) -> MavMessage {
    let f = &o.pose;
    let (roll, pitch, yaw) = f.q_lv.euler_angles();
    let (covariance, _) = covariances(o);
    MavMessage::VISION_POSITION_ESTIMATE(VISION_POSITION_ESTIMATE_DATA {
        usec: o.time_usec,
        x: f.p_l.x as f32,
        y: f.p_l.y as f32,
        z: f.p_l.z as f32,
        roll: roll as f32,
        pitch: pitch as f32,
        yaw: yaw as f32,
        covariance,
        reset_counter: o.reset_counter,
    })
}

fn heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

fn send_loop(s: &Shared, link: &Link, o: &MavlinkOptions, mut rx: rtrb::Consumer<Odom>) {
    let mut last_heartbeat: Option<Instant> = None;
    loop {
        let stop = s.stop.load(Ordering::Acquire);
        while let Ok(odom) = rx.pop() {
            match link.send(s.header(o), &odometry(&odom)) {
                Ok(true) => s.sent.fetch_add(1, Ordering::Relaxed),
                Ok(false) => s.unsent.fetch_add(1, Ordering::Relaxed),
                Err(e) => {
                    s.error(&format_args!("sending ODOMETRY: {e}"));
                    0
                }
            };
            if o.vision_position {
                match link.send(s.header(o), &vision_position_estimate(&odom)) {
                    Ok(true) => {
                        s.vision_sent.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(false) => {}
                    Err(e) => s.error(&format_args!("sending VISION_POSITION_ESTIMATE: {e}")),
                }
            }
        }
        if last_heartbeat.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
            last_heartbeat = Some(Instant::now());
            match link.send(s.header(o), &heartbeat()) {
                Ok(true) => {
                    if let Ok(mut c) = s.counts.lock() {
                        c.heartbeats_sent += 1;
                    }
                }
                Ok(false) => {}
                Err(e) => s.error(&format_args!("sending HEARTBEAT: {e}")),
            }
        }
        if stop {
            return;
        }
        std::thread::park_timeout(Duration::from_millis(50));
    }
}

fn recv_loop(s: &Shared, link: &Link, o: &MavlinkOptions) {
    let mut buf = vec![0u8; 65_536];
    let mut msgs = Vec::new();
    while !s.stop.load(Ordering::Acquire) {
        let mut bad = 0;
        if let Err(e) = link.recv(&mut buf, &mut msgs, &mut bad) {
            s.error(&format_args!("receiving: {e}"));
            std::thread::sleep(link::RECV_TIMEOUT);
        }
        let mut answered = 0;
        let mut unanswered = 0;
        for (h, m) in &msgs {
            let MavMessage::TIMESYNC(t) = m else { continue };
            if t.tc1 != 0 {
                continue;
            }
            let offset = s.offset_ns.load(Ordering::Relaxed);
            if offset == i64::MIN {
                unanswered += 1;
                continue;
            }
            let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
                tc1: s.mono_ns().saturating_add(offset),
                ts1: t.ts1,
                target_system: u8::try_from(h.system_id).unwrap_or(0),
                target_component: h.component_id,
            });
            match link.send(s.header(o), &reply) {
                Ok(_) => answered += 1,
                Err(e) => s.error(&format_args!("sending TIMESYNC: {e}")),
            }
        }
        if let Ok(mut c) = s.counts.lock() {
            c.received += msgs.len() as u64;
            c.received_bad += bad;
            c.timesync_answered += answered;
            c.timesync_unanswered += unanswered;
        }
    }
}

#[cfg(test)]
mod tests;

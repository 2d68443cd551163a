//! The back-end thread: owns the odometry, takes the events in the order the IMU thread forwards
//! them (the source's order) and hands each to the one driver step ([`crate::driver::handle`]:
//! the same calls as a single-threaded replay, images decoded and tracked here, see the module
//! docs of [`super`] for why), and sends one [`FromBackend`] per IMU sample back: the estimator's
//! [`InsUpdate`] and keyframe report.

use super::sink::{KeyframeOut, LandmarkTap};
use super::stats::{PipelineCounters, Timing};
use super::{Shared, ToBackend};
use crate::driver::{elapsed_ns, handle, Handled, Observer};
use crate::source::SensorEvent;
use povins_core::inertial::InsUpdate;
use povins_core::odometry::{Odometry, Output};
use rtrb::{Consumer, Producer, PushError};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// What the back end says after one IMU sample.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FromBackend {
    /// The sample's stamp, ns.
    pub t_ns: i64,
    /// The estimator's INS update at this sample, if any.
    pub ins: Option<InsUpdate>,
    /// The keyframe processed at this sample, if any.
    pub keyframe: Option<KeyframeOut>,
}

/// How long a waiting thread sleeps before looking again (it is also woken by `unpark`).
pub(crate) const WAIT: Duration = Duration::from_micros(200);

/// The newest INS update and keyframe of one sample's outputs (an update is a whole INS: a
/// later one supersedes an earlier one).
struct Reply<'t> {
    ins: Option<InsUpdate>,
    keyframe: Option<KeyframeOut>,
    /// Where the keyframes' landmarks go, if a sink shows them.
    tap: Option<&'t LandmarkTap>,
}

impl Observer for Reply<'_> {
    fn output(&mut self, o: &Output<'_>) {
        self.ins = o.ins.or(self.ins);
        if let Some(k) = &o.keyframe {
            if let Some(tap) = self.tap {
                let t_ns = k.window.last().map_or(0, |kf| kf.state.t_ns);
                tap.publish(t_ns, k.landmarks);
            }
            self.keyframe = Some(KeyframeOut {
                report: k.report,
                state: k.window.last().map(|kf| kf.state),
            });
        }
    }
}

/// The back end's loop: returns its timing, the keyframe stamps (IMU clock, ns) and its
/// counters (images that could not be used).
pub(crate) fn run(
    odo: &mut (dyn Odometry + Send),
    mut rx: Consumer<ToBackend>,
    mut tx: Producer<FromBackend>,
    shared: &Shared,
    tap: Option<&LandmarkTap>,
) -> (Timing, Vec<i64>, PipelineCounters) {
    let mut timing = Timing::default();
    let mut counters = PipelineCounters::default();
    let mut keyframes = Vec::new();
    loop {
        let msg = match rx.pop() {
            Ok(m) => m,
            Err(_) if rx.is_abandoned() => break,
            Err(_) => {
                std::thread::park_timeout(WAIT);
                continue;
            }
        };
        let ToBackend::Event { ev, arrival, due } = msg else {
            finish(odo, &mut tx, shared, tap, &mut timing, &mut keyframes);
            break;
        };
        let t0 = Instant::now();
        let mut reply = Reply {
            ins: None,
            keyframe: None,
            tap,
        };
        let handled = handle(odo, &ev, &mut reply);
        let dt = elapsed_ns(t0);
        match (handled, &ev) {
            (Handled::Imu { keyframe, .. }, SensorEvent::Imu(s)) => {
                if keyframe {
                    timing.backend_keyframe.record(dt);
                    keyframes.push(s.t_ns);
                    if let Some(k) = &reply.keyframe {
                        timing.solve_work.record(u64::from(k.report.solve_work));
                    }
                } else {
                    timing.backend_imu.record(dt);
                }
                let newest = shared.newest_imu_ns.load(Ordering::Acquire);
                timing
                    .backend_lag
                    .record(u64::try_from(newest.saturating_sub(s.t_ns)).unwrap_or(0));
                let out = FromBackend {
                    t_ns: s.t_ns,
                    ins: reply.ins,
                    keyframe: reply.keyframe,
                };
                send(&mut tx, out, shared);
                shared.backend_done.fetch_add(1, Ordering::AcqRel);
                shared.wake_imu();
            }
            (Handled::Image { decode_ns, ok }, _) => {
                timing.frontend_decode.record(decode_ns);
                timing.frontend_image.record(dt);
                if !ok {
                    counters.image_failures += 1;
                    continue;
                }
                let now = Instant::now();
                timing
                    .image_arrival_to_frame
                    .record(elapsed_between(arrival, now));
                if let Some(due) = due {
                    timing
                        .image_stamp_to_frame
                        .record(elapsed_between(due, now));
                }
            }
            _ => timing.backend_input.record(dt),
        }
    }
    (timing, keyframes, counters)
}

/// The source's end: what the odometry held back for later input (a delay horizon, a spike's
/// confirmation, a clock jump's frame) is processed ([`Odometry::end_input`], as
/// [`crate::driver::run`] does), each output sent as its own reply (stamped with the newest
/// sample forwarded: the IMU thread applies every reply left once the back end has finished).
fn finish(
    odo: &mut (dyn Odometry + Send),
    tx: &mut Producer<FromBackend>,
    shared: &Shared,
    tap: Option<&LandmarkTap>,
    timing: &mut Timing,
    keyframes: &mut Vec<i64>,
) {
    odo.end_input();
    loop {
        let mut reply = Reply {
            ins: None,
            keyframe: None,
            tap,
        };
        let t0 = Instant::now();
        match odo.update() {
            Ok(Some(o)) => reply.output(&o),
            Ok(None) => return,
            Err(_) => continue,
        }
        let t_ns = shared.newest_imu_ns.load(Ordering::Acquire);
        if let Some(k) = &reply.keyframe {
            timing.backend_keyframe.record(elapsed_ns(t0));
            keyframes.push(k.state.map_or(t_ns, |s| s.t_ns));
        }
        let out = FromBackend {
            t_ns,
            ins: reply.ins,
            keyframe: reply.keyframe,
        };
        send(tx, out, shared);
    }
}

/// Sends a reply, waiting while the queue is full (the IMU thread drains it at every event).
fn send(tx: &mut Producer<FromBackend>, mut v: FromBackend, shared: &Shared) {
    loop {
        match tx.push(v) {
            Ok(()) => return,
            Err(PushError::Full(back)) => {
                if tx.is_abandoned() {
                    return;
                }
                v = back;
                shared.wake_imu();
                std::thread::park_timeout(WAIT);
            }
        }
    }
}

/// Nanoseconds from `a` to `b` (0 when `b` is not later).
fn elapsed_between(a: Instant, b: Instant) -> u64 {
    u64::try_from(b.saturating_duration_since(a).as_nanos()).unwrap_or(u64::MAX)
}

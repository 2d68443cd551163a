//! The back-end thread: owns the estimator, consumes IMU samples, frames and sweeps in the
//! order the IMU thread forwards them (the source's order, which is the replay's), and sends
//! one [`FromBackend`] per IMU sample back: the estimator's [`InsUpdate`] and keyframe report.
//! Images go through the front-end stage ([`super::frontend`]) here, in the same order.

use super::frontend::{self, Backend};
use super::sink::KeyframeOut;
use super::stats::{PipelineCounters, Timing};
use super::{Shared, ToBackend};
use povins_core::inertial::InsUpdate;
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

/// The back end's loop: returns its timing, the keyframe stamps (IMU clock, ns) and its
/// counters (the front-end stage's failures).
pub(crate) fn run<E: Backend + ?Sized>(
    est: &mut E,
    mut rx: Consumer<ToBackend>,
    mut tx: Producer<FromBackend>,
    shared: &Shared,
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
        let t0 = Instant::now();
        match msg {
            ToBackend::End => break,
            ToBackend::Frame { t_cam_ns, obs } => {
                // Refused frames are counted by the estimator (`counters()`).
                let _ = est.push_frame(t_cam_ns, &obs);
                timing.backend_input.record(elapsed_ns(t0));
            }
            ToBackend::Image(msg) => {
                frontend::process(est, &msg, &mut timing, &mut counters);
            }
            ToBackend::Lidar(points) => {
                let _ = est.push_lidar(&points);
                timing.backend_input.record(elapsed_ns(t0));
            }
            ToBackend::Imu(s) => {
                // Queue the sample and process what is due (with the default horizon of 0:
                // exactly this sample). The newest update and keyframe of the burst go back
                // (an update is a whole INS: a later one supersedes an earlier one).
                let (mut ins, mut report) = (None, None);
                if est.push_imu(&s).is_ok() {
                    loop {
                        match est.update() {
                            Ok(Some(o)) => {
                                ins = o.ins.or(ins);
                                report = o.keyframe.or(report);
                            }
                            Ok(None) => break,
                            Err(_) => {}
                        }
                    }
                }
                let dt = elapsed_ns(t0);
                let keyframe = report.map(|report| KeyframeOut {
                    report,
                    state: est.estimator().keyframes().last().map(|k| k.state),
                });
                if keyframe.is_some() {
                    timing.backend_keyframe.record(dt);
                    keyframes.push(s.t_ns);
                } else {
                    timing.backend_imu.record(dt);
                }
                let newest = shared.newest_imu_ns.load(Ordering::Acquire);
                timing
                    .backend_lag
                    .record(u64::try_from(newest.saturating_sub(s.t_ns)).unwrap_or(0));
                let reply = FromBackend {
                    t_ns: s.t_ns,
                    ins,
                    keyframe,
                };
                send(&mut tx, reply, shared);
                shared.backend_done.fetch_add(1, Ordering::AcqRel);
                shared.wake_imu();
            }
        }
    }
    (timing, keyframes, counters)
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

/// Nanoseconds since `t0`.
pub(crate) fn elapsed_ns(t0: Instant) -> u64 {
    u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

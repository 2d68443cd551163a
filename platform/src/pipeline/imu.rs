//! The IMU thread: reads the [`Source`], forwards every event to the back end, runs the
//! [`FastPath`] on IMU samples, applies the back end's updates and publishes every pose to the
//! [`Sink`] with its latency.
//!
//! Deterministic mode: after forwarding a sample it waits for the back end's reply for that
//! sample and applies its update before publishing (lockstep: the poses are the estimator's
//! own IMU-rate output, bit for bit). Real-time mode: it never waits for the back end except,
//! with a source that is not real time, to stay at most `max_lead_samples` ahead of it.

use super::backend::{FromBackend, WAIT};
use super::sink::{PoseOut, Sink};
use super::stats::{PipelineCounters, Timing};
use super::{PipelineConfig, Shared, ToBackend, FAST_PATH_RING};
use crate::driver::elapsed_ns;
use crate::error::IoError;
use crate::source::{SensorEvent, Source};
use povins_core::inertial::{FastPath, ImuSample, NavState, OutputSmoother};
use rtrb::{Consumer, Producer, PushError};
use std::sync::atomic::Ordering;
use std::time::Instant;

/// The IMU thread's state.
pub(crate) struct ImuWorker<'a, S, K> {
    pub source: S,
    pub sink: &'a mut K,
    pub tx: Producer<ToBackend>,
    pub rx: Consumer<FromBackend>,
    /// Boxed: the ring of samples is 2048 x 56 bytes.
    pub fast: Box<FastPath<FAST_PATH_RING>>,
    pub cfg: &'a PipelineConfig,
    pub shared: &'a Shared,
    pub timing: Timing,
    pub counters: PipelineCounters,
    /// IMU samples forwarded to the back end.
    pub sent: u64,
    /// The source's error that ended the stream, if any.
    pub error: Option<IoError>,
    /// The continuous output's offset ([`PipelineConfig::smooth_horizon_s`]).
    pub smoother: Option<OutputSmoother>,
    /// Corrections applied since the last publication (position), m.
    pub pending_correction_m: f64,
}

impl<S: Source, K: Sink> ImuWorker<'_, S, K> {
    /// Runs to the end of the source (or its error), then until the back end has finished.
    pub fn run(&mut self) {
        loop {
            let ev = match self.source.next() {
                Ok(Some(ev)) => ev,
                Ok(None) => break,
                Err(e) => {
                    self.error = Some(e);
                    break;
                }
            };
            let arrival = Instant::now();
            match ev {
                SensorEvent::Imu(s) => self.on_imu(&s, arrival),
                ev => self.on_message(ev, arrival),
            }
        }
        self.wait_until(|w| w.forward_blocking(ToBackend::End));
        while !self.shared.backend_finished.load(Ordering::Acquire) {
            self.drain();
            std::thread::park_timeout(WAIT);
        }
        self.drain();
        let fc = self.fast.counters();
        self.counters.updates_too_old = fc.updates_too_old;
        self.counters.max_replay = fc.max_replay;
    }

    /// A frame, image or sweep: counted and forwarded (a real-time source's is dropped and
    /// counted when the back end's queue is full).
    fn on_message(&mut self, ev: SensorEvent, arrival: Instant) {
        #[derive(Clone, Copy)]
        enum Kind {
            Frame,
            Image,
            Lidar,
        }
        let (kind, due) = match &ev {
            SensorEvent::Image { t_cam_ns, .. } => {
                (Kind::Image, self.source.stamp_instant(*t_cam_ns))
            }
            SensorEvent::Frame { .. } => (Kind::Frame, None),
            _ => (Kind::Lidar, None),
        };
        let c = &mut self.counters;
        match kind {
            Kind::Frame => c.frames_in += 1,
            Kind::Image => c.images_in += 1,
            Kind::Lidar => c.sweeps_in += 1,
        }
        if !self.forward(ToBackend::Event { ev, arrival, due }) {
            let c = &mut self.counters;
            match kind {
                Kind::Frame => c.dropped_frames += 1,
                Kind::Image => c.dropped_images += 1,
                Kind::Lidar => c.dropped_sweeps += 1,
            }
        }
    }

    /// One IMU sample: forward, propagate, (deterministic: wait and apply), publish.
    fn on_imu(&mut self, s: &ImuSample, arrival: Instant) {
        self.counters.imu_in += 1;
        self.shared.newest_imu_ns.store(s.t_ns, Ordering::Release);
        self.shared.imu_seen.fetch_add(1, Ordering::Relaxed);
        let mut fast_ns = self.drain();
        let sent = self.forward(ToBackend::Event {
            ev: SensorEvent::Imu(*s),
            arrival,
            due: None,
        });
        if sent {
            self.sent += 1;
        } else {
            self.counters.dropped_imu += 1;
        }
        let t0 = Instant::now();
        let mut latest = self.fast.push_imu(s).ok().flatten();
        fast_ns += elapsed_ns(t0);
        if sent && self.cfg.deterministic {
            let mut done = false;
            while !done {
                let mut got: Option<Option<NavState>> = None;
                let (ns, seen) = self.drain_until(s.t_ns, &mut got);
                fast_ns += ns;
                if seen {
                    done = true;
                    // An update decides the state, also when there is none (a reset: the
                    // estimator publishes nothing at this sample, nor does the fast path).
                    if let Some(g) = got {
                        latest = g;
                    }
                } else {
                    self.counters.backpressure_waits += 1;
                    std::thread::park_timeout(WAIT);
                }
            }
        } else if !self.source.is_realtime() {
            while self.sent
                > self.shared.backend_done.load(Ordering::Acquire) + self.cfg.max_lead_samples
            {
                self.counters.backpressure_waits += 1;
                fast_ns += self.drain();
                std::thread::park_timeout(WAIT);
            }
        }
        self.timing.fast_path.record(fast_ns);
        if let Some(nav) = latest {
            self.publish(nav, arrival);
        }
    }

    /// An update moved the fast path's newest state from `before` to `after`.
    fn on_correction(&mut self, before: Option<&NavState>, after: Option<&NavState>) {
        if let (Some(b), Some(a)) = (before, after) {
            if a.t_ns == b.t_ns {
                let m = (a.p_wb - b.p_wb).norm();
                let steps = &mut self.counters.output_steps;
                steps.max_correction_m = steps.max_correction_m.max(m);
                self.pending_correction_m += m;
            }
        }
        if let Some(s) = &mut self.smoother {
            s.on_update(before, after);
        }
    }

    /// Publishes one pose with its latencies (through the continuous output's offset when
    /// asked for).
    fn publish(&mut self, nav: NavState, arrival: Instant) {
        let (nav, departure_m) = match &mut self.smoother {
            Some(s) => {
                let out = s.output(&nav);
                (out, s.last_step_m())
            }
            None => (nav, self.pending_correction_m),
        };
        self.pending_correction_m = 0.0;
        self.counters.output_steps.step(departure_m);
        let now = Instant::now();
        let latency_ns = u64::try_from(now.duration_since(arrival).as_nanos()).unwrap_or(u64::MAX);
        let stamp_latency_ns = self.source.stamp_instant(nav.t_ns).map(|t| {
            u64::try_from(now.saturating_duration_since(t).as_nanos()).unwrap_or(u64::MAX)
        });
        self.timing.arrival_to_pose.record(latency_ns);
        if let Some(l) = stamp_latency_ns {
            self.timing.stamp_to_pose.record(l);
        }
        if latency_ns > self.cfg.imu_period_ns {
            self.counters.imu_deadline_misses += 1;
        }
        self.counters.poses_out += 1;
        self.sink.pose(&PoseOut {
            nav,
            latency_ns,
            stamp_latency_ns,
            covariance: self.fast.covariance().copied(),
        });
    }

    /// Applies every reply waiting; returns the time spent in the fast path, ns.
    fn drain(&mut self) -> u64 {
        let mut unused = None;
        self.drain_until(i64::MAX, &mut unused).0
    }

    /// Applies replies up to and including the one for sample `t_ns`; `got` is the state after
    /// the last update applied (`Some(None)` when it left no state: a reset). Returns the
    /// fast-path time, ns, and whether that reply came.
    fn drain_until(&mut self, t_ns: i64, got: &mut Option<Option<NavState>>) -> (u64, bool) {
        let mut ns = 0;
        while let Ok(r) = self.rx.pop() {
            if let Some(u) = &r.ins {
                let t0 = Instant::now();
                let before = self.fast.state().copied();
                let after = self.fast.apply(u);
                self.on_correction(before.as_ref(), after.as_ref());
                *got = Some(after);
                ns += elapsed_ns(t0);
            }
            if let Some(k) = &r.keyframe {
                self.counters.keyframes += 1;
                self.sink.keyframe(k);
            }
            if r.t_ns >= t_ns {
                return (ns, true);
            }
        }
        (ns, false)
    }

    /// Forwards a message; a real-time source's message is dropped when the queue is full
    /// (`false`), otherwise the thread waits for room (applying replies meanwhile).
    fn forward(&mut self, msg: ToBackend) -> bool {
        let drop_when_full = self.source.is_realtime() && !self.cfg.deterministic;
        let mut msg = msg;
        loop {
            match self.tx.push(msg) {
                Ok(()) => {
                    self.shared.wake_backend();
                    return true;
                }
                Err(PushError::Full(back)) => {
                    if drop_when_full || self.tx.is_abandoned() {
                        return false;
                    }
                    msg = back;
                    self.counters.backpressure_waits += 1;
                    self.drain();
                    std::thread::park_timeout(WAIT);
                }
            }
        }
    }

    /// Forwards a message whatever the source (the end marker).
    fn forward_blocking(&mut self, msg: ToBackend) -> bool {
        match self.tx.push(msg) {
            Ok(()) => {
                self.shared.wake_backend();
                true
            }
            Err(PushError::Full(_)) => self.tx.is_abandoned(),
        }
    }

    /// Retries `f` (applying replies in between) until it returns true.
    fn wait_until(&mut self, mut f: impl FnMut(&mut Self) -> bool) {
        while !f(self) {
            self.drain();
            std::thread::park_timeout(WAIT);
        }
    }
}

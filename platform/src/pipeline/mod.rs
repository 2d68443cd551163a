//! The onboard runtime: a pipeline of threads around the estimator (IMU/INS; front end and back
//! end), for Linux (x86-64 and aarch64).
//!
//! ```text
//!  Source ──> IMU thread ──(SPSC: IMU, frames, images, sweeps)──> back-end thread:
//!               │                                  driver::handle (decode, track) -> odometry
//!               │  FastPath <──(SPSC: InsUpdate, keyframe reports)──┘
//!               └──> Sink (pose at IMU rate + latency, keyframe reports)
//! ```
//!
//! - The **IMU thread** (module `imu`) reads the [`Source`], forwards every event to the back end
//!   over a lock-free single-producer single-consumer queue (`rtrb`), propagates the
//!   [`FastPath`] at every IMU sample, applies the
//!   estimator's [`InsUpdate`](povins_core::inertial::InsUpdate)s coming back over a second
//!   queue (re-propagating the samples after them), and publishes every pose to the [`Sink`]
//!   with its latency from the sample's arrival (and from its stamp, with a paced source).
//! - The **back-end thread** (module `backend`) owns the [`Odometry`] and hands the events, in the
//!   source's order, to the one driver step ([`crate::driver::handle`], the same code as the
//!   single-threaded replay), so the keyframe solves run there and the IMU-rate output never
//!   waits for them.
//! - The **image front end** runs on the back-end thread too: camera images travel undecoded
//!   from the source ([`crate::images::ImageData`]); the driver step decodes each one and tracks
//!   it with the estimator's INS prediction (the core's `Vio`) just before the estimator would
//!   take the frame. Why not on a thread of its own:
//!   - The tracker's seeds come from the estimator's state at the image time: the predicted
//!     pixel of every window landmark (which reads the window's keyframes and landmarks) and
//!     the gyro rotation with the current bias, delay and extrinsic. That state lives on the
//!     back-end thread and changes at every keyframe. A front-end thread would have to ask the
//!     back end for it and wait for the answer (the back end must first have processed the IMU
//!     up to the image), or be given a copy of the window per image (hundreds of kB): it would
//!     wait on the back end either way, and run the tracker on a state other than the
//!     single-threaded replay's, so the deterministic mode could not be bit-identical to
//!     `povins run --frontend images`.
//!   - With two cores there is no idle core for it: on core 0 it would compete with the IMU
//!     thread (whose p99 latency is the bar), on core 1 it would time-share with the back end,
//!     which has to wait for its output anyway. Measured (BENCHMARKS.md, issue 15): decoding
//!     and tracking an image take a few ms, well inside the keyframe period the back end may
//!     lag.
//!
//!   The images' latencies and processing times are recorded per image ([`Timing`]'s `image_*`
//!   and `frontend_*` histograms) and refused images counted
//!   ([`PipelineCounters::image_failures`]).
//! - Both threads are pinned to cores and ask for `SCHED_FIFO`; memory is locked ([`rt`]).
//!   What is not permitted is reported in [`PipelineReport::rt`] (and printed with
//!   [`PipelineConfig::announce`]) and the pipeline goes on.
//! - **Deterministic mode** ([`PipelineConfig::deterministic`]): the IMU thread waits for the
//!   back end at every sample and applies its update before publishing: the poses are then
//!   bit-identical to the single-threaded replay's IMU-rate output. Real-time mode never
//!   waits for the back end (a real-time source's messages are dropped and counted when the
//!   queue is full; a replay that is not paced stays at most
//!   [`PipelineConfig::max_lead_samples`] ahead of the back end instead).
//!
//! The estimator (`PoVins`, about 5 MB; `Vio` with the front end about 6-7 MB) is never on these threads' stacks: the caller owns it
//! (in a `Box` or a `static`, see the README's "Embedding the core") and lends it to
//! [`run`]; the back-end thread only needs the core's processing stack (under 96 KiB), so
//! both threads get [`THREAD_STACK_BYTES`].

#![warn(missing_docs)]

mod backend;
pub mod file_sink;
pub mod foxglove;
mod imu;
pub mod mavlink;
pub mod mcap_sink;
pub mod rt;
pub mod sink;
pub mod stats;

pub use self::foxglove::{FoxgloveCounts, FoxgloveOptions, FoxgloveSink};
pub use crate::source::{Clock, Pacer, Pacing, SensorEvent, Source, SystemClock};
pub use file_sink::{FileCounts, FileOptions, TumSink};
pub use mavlink::{MavlinkCounts, MavlinkOptions, MavlinkSink};
pub use mcap_sink::{McapCounts, McapOptions, McapSink};
pub use rt::RtStatus;
pub use sink::{CallbackSink, KeyframeOut, LandmarkTap, PoseOut, RateDecimator, Sink, Stamped};
pub use stats::{LatencyHist, OutputSteps, PipelineCounters, StageSummary, Timing, STAGES};

use crate::error::IoError;
use povins_core::estimator::Counters;
use povins_core::inertial::{FastPath, FastPathCounters};
use povins_core::odometry::Odometry;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::thread::Thread;
use std::time::{Duration, Instant};

/// IMU samples the fast path keeps to re-propagate late updates (an update more than this
/// many samples late is refused and counted).
pub const FAST_PATH_RING: usize = 2048;

/// Stack of each pipeline thread: the core's processing needs under 96 KiB; the rest is
/// margin for the sink's and the source's code.
pub const THREAD_STACK_BYTES: usize = 1 << 20;

/// How the pipeline runs.
#[derive(Debug, Clone, PartialEq)]
pub struct PipelineConfig {
    /// Lockstep (bit-identical to the single-threaded replay) instead of real time.
    pub deterministic: bool,
    /// The IMU period, ns: a pose published later than this after its sample's arrival is a
    /// deadline miss.
    pub imu_period_ns: u64,
    /// With a source that is not real time (unpaced replay), in real-time mode: the most IMU
    /// samples the IMU thread runs ahead of the back end.
    pub max_lead_samples: u64,
    /// Capacity of each queue, messages.
    pub queue_capacity: usize,
    /// `SCHED_FIFO` priority to ask for (1-99), `None` for normal scheduling.
    pub fifo_priority: Option<u8>,
    /// Lock the process's memory for the run (`mlockall`), unlocked at the end.
    pub lock_memory: bool,
    /// Print a line on stderr for each real-time setting not permitted.
    pub announce: bool,
    /// The continuous output: each estimator correction spread over this horizon, s
    /// ([`povins_core::inertial::OutputSmoother`]); `None`: the exact output (it jumps by the
    /// correction at an update).
    pub smooth_horizon_s: Option<f64>,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            deterministic: false,
            imu_period_ns: 5_000_000,
            max_lead_samples: 40,
            queue_capacity: 1024,
            fifo_priority: Some(80),
            lock_memory: true,
            announce: true,
            smooth_horizon_s: None,
        }
    }
}

/// Everything the pipeline measured.
#[derive(Debug, Clone)]
pub struct PipelineReport {
    /// Per-stage histograms.
    pub timing: Timing,
    /// Counters (drops, misses).
    pub counters: PipelineCounters,
    /// The fast path's counters.
    pub fast_path: FastPathCounters,
    /// The estimator's counters at the end.
    pub estimator: Counters,
    /// IMU stamps of the keyframes, ns.
    pub keyframe_t_ns: Vec<i64>,
    /// Median interval between keyframes, ns (the back-end lag deadline).
    pub keyframe_period_ns: Option<u64>,
    /// What real-time settings were granted.
    pub rt: RtStatus,
    /// Wall time of the run, s.
    pub wall_s: f64,
}

/// A message to the back end, in the source's order.
#[derive(Debug)]
pub(crate) enum ToBackend {
    /// An event with when the source returned it and when its stamp was due (paced or live
    /// sources).
    Event {
        ev: SensorEvent,
        arrival: Instant,
        due: Option<Instant>,
    },
    End,
}

/// What the two threads share besides the queues.
#[derive(Debug, Default)]
pub(crate) struct Shared {
    /// Stamp of the newest IMU sample the IMU thread received, ns.
    pub newest_imu_ns: AtomicI64,
    /// IMU samples the IMU thread received (progress).
    pub imu_seen: AtomicU64,
    /// IMU samples the back end finished.
    pub backend_done: AtomicU64,
    /// The back end has left its loop.
    pub backend_finished: AtomicBool,
    imu_thread: OnceLock<Thread>,
    backend_thread: OnceLock<Thread>,
}

impl Shared {
    /// Wakes the IMU thread if it waits.
    pub fn wake_imu(&self) {
        if let Some(t) = self.imu_thread.get() {
            t.unpark();
        }
    }

    /// Wakes the back end if it waits.
    pub fn wake_backend(&self) {
        if let Some(t) = self.backend_thread.get() {
            t.unpark();
        }
    }
}

/// Runs `source` through the odometry `odo` (configured, and initialized when the run starts
/// from a known state; the estimator alone for feature tracks, a `Vio` for images too) on the
/// two pinned threads, publishing to `sink`, and returns
/// what was measured once the source is exhausted and the back end has caught up. The calling
/// thread only waits, calling `on_tick(imu_samples_so_far)` about every 100 ms (a progress
/// bar). `sink.finish()` is called at the end, on the calling thread.
pub fn run<S, K>(
    odo: &mut (dyn Odometry + Send),
    source: S,
    sink: &mut K,
    cfg: &PipelineConfig,
    mut on_tick: impl FnMut(u64),
) -> Result<PipelineReport, IoError>
where
    S: Source + Send,
    K: Sink + Send,
{
    let shared = Shared::default();
    let tap = sink.landmark_tap();
    let mut rt = RtStatus {
        mlock: cfg.lock_memory.then(rt::lock_memory),
        threads: Vec::new(),
    };
    let limits = (odo.config().max_gyro_rps, odo.config().max_accel_mps2);
    // An estimator that already holds a state (initialized from ground truth) starts the fast
    // path with it: poses from the first sample, not from the back end's first reply.
    let seed = odo.fast_path_seed();
    let t_run = Instant::now();
    let (to_tx, to_rx) = rtrb::RingBuffer::<ToBackend>::new(cfg.queue_capacity.max(2));
    let (from_tx, from_rx) = rtrb::RingBuffer::new(cfg.queue_capacity.max(2) + 1);
    let sink_on_imu: &mut K = &mut *sink;
    let joined = std::thread::scope(|sc| {
        let shared = &shared;
        let tap = tap.as_deref();
        let backend = std::thread::Builder::new()
            .name("povins-backend".into())
            .stack_size(THREAD_STACK_BYTES)
            .spawn_scoped(sc, move || {
                let r = rt::setup_current_thread(
                    "back-end",
                    1,
                    cfg.fifo_priority.map(|p| p.saturating_sub(10).max(1)),
                );
                let _ = shared.backend_thread.set(std::thread::current());
                let out = backend::run(odo, to_rx, from_tx, shared, tap);
                shared.backend_finished.store(true, Ordering::Release);
                shared.wake_imu();
                (r, out, odo.counters().estimator)
            })?;
        let imu = std::thread::Builder::new()
            .name("povins-imu".into())
            .stack_size(THREAD_STACK_BYTES)
            .spawn_scoped(sc, move || {
                let r = rt::setup_current_thread("IMU", 0, cfg.fifo_priority);
                let _ = shared.imu_thread.set(std::thread::current());
                let mut fast = Box::new(FastPath::with_limits(limits.0, limits.1));
                if let Some(u) = &seed {
                    let _ = fast.apply(u);
                }
                let mut w = imu::ImuWorker {
                    source,
                    sink: sink_on_imu,
                    tx: to_tx,
                    rx: from_rx,
                    fast,
                    cfg,
                    shared,
                    timing: Timing::default(),
                    counters: PipelineCounters::default(),
                    sent: 0,
                    error: None,
                    smoother: cfg
                        .smooth_horizon_s
                        .map(povins_core::inertial::OutputSmoother::new),
                    pending_correction_m: 0.0,
                };
                w.run();
                (r, w.timing, w.counters, w.fast.counters(), w.error)
            })?;
        while !(imu.is_finished() && backend.is_finished()) {
            on_tick(shared.imu_seen.load(Ordering::Relaxed));
            std::thread::sleep(Duration::from_millis(100));
        }
        on_tick(shared.imu_seen.load(Ordering::Relaxed));
        let i = imu.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
        let b = backend
            .join()
            .unwrap_or_else(|p| std::panic::resume_unwind(p));
        Ok::<_, std::io::Error>((i, b))
    });
    if cfg.lock_memory {
        rt::unlock_memory();
    }
    let (
        (imu_rt, mut timing, mut counters, fast_path, source_error),
        (be_rt, (be_timing, kf_t, be_counters), est_counters),
    ) = joined.map_err(|e| IoError::io("<pipeline thread>", e))?;
    if let Some(e) = source_error {
        return Err(e);
    }
    counters.image_failures += be_counters.image_failures;
    rt.threads = vec![imu_rt, be_rt];
    if cfg.announce {
        for line in rt.notes() {
            eprintln!("{line}");
        }
    }
    timing.merge(&be_timing);
    let keyframe_period_ns = median_interval(&kf_t);
    if let Some(p) = keyframe_period_ns {
        counters.backend_lag_misses = timing.backend_lag.count_above(p);
    }
    sink.finish()?;
    Ok(PipelineReport {
        timing,
        counters,
        fast_path,
        estimator: est_counters,
        keyframe_t_ns: kf_t,
        keyframe_period_ns,
        rt,
        wall_s: t_run.elapsed().as_secs_f64(),
    })
}

/// Median of the positive differences of increasing stamps, ns.
fn median_interval(t: &[i64]) -> Option<u64> {
    let mut d: Vec<u64> = t
        .windows(2)
        .filter_map(|w| u64::try_from(w[1] - w[0]).ok())
        .collect();
    d.sort_unstable();
    d.get(d.len() / 2).copied()
}

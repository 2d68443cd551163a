//! Timing of the pipeline: one [`hdrhistogram`] per stage (ns, 3 significant digits), kept by
//! the thread that measures it and merged at the end, and the counters of drops and deadline
//! misses.

use hdrhistogram::Histogram;

/// Largest value a histogram records, ns (60 s; larger values are clamped).
const MAX_NS: u64 = 60_000_000_000;

/// The measured stages (see [`Timing`]).
pub const STAGES: [&str; 11] = [
    "imu fast path",
    "back end per IMU sample",
    "back end keyframe solve",
    "back end frame / sweep in",
    "IMU arrival -> pose out",
    "IMU stamp -> pose out",
    "back-end lag",
    "front end decode",
    "front end per image",
    "image arrival -> track frame",
    "image stamp -> track frame",
];

/// A latency histogram in ns.
#[derive(Debug, Clone)]
pub struct LatencyHist(Histogram<u64>);

impl Default for LatencyHist {
    fn default() -> Self {
        Self::new()
    }
}

impl LatencyHist {
    /// An empty histogram (1 ns to 60 s, 3 significant digits).
    pub fn new() -> Self {
        // The bounds are constants that hdrhistogram accepts: 1 <= low, 2 * low <= high, 3 digits.
        LatencyHist(Histogram::new_with_bounds(1, MAX_NS, 3).unwrap_or_else(|_| unreachable!()))
    }

    /// Records one value, ns (clamped to 60 s).
    pub fn record(&mut self, ns: u64) {
        self.0.saturating_record(ns.clamp(1, MAX_NS));
    }

    /// Adds another histogram's values.
    pub fn merge(&mut self, other: &LatencyHist) {
        // Same bounds: cannot fail.
        let _ = self.0.add(&other.0);
    }

    /// Values recorded.
    pub fn count(&self) -> u64 {
        self.0.len()
    }

    /// The value at percentile `p` (0-100), ns; 0 when empty.
    pub fn percentile_ns(&self, p: f64) -> u64 {
        if self.0.is_empty() {
            0
        } else {
            self.0.value_at_percentile(p)
        }
    }

    /// The largest value, ns.
    pub fn max_ns(&self) -> u64 {
        self.0.max()
    }

    /// Values above `limit_ns`.
    pub fn count_above(&self, limit_ns: u64) -> u64 {
        if self.0.is_empty() {
            return 0;
        }
        let below = self.0.count_between(0, limit_ns.min(MAX_NS));
        self.count().saturating_sub(below)
    }

    /// p50, p99, p99.9 and max in ms.
    pub fn summary_ms(&self) -> StageSummary {
        StageSummary {
            count: self.count(),
            p50_ms: self.percentile_ns(50.0) as f64 * 1e-6,
            p99_ms: self.percentile_ns(99.0) as f64 * 1e-6,
            p999_ms: self.percentile_ns(99.9) as f64 * 1e-6,
            max_ms: self.max_ns() as f64 * 1e-6,
        }
    }
}

/// p50 / p99 / p99.9 / max of one stage, ms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StageSummary {
    /// Values recorded.
    pub count: u64,
    /// Median, ms.
    pub p50_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// 99.9th percentile, ms (with fewer than 1000 values: the largest but a fraction of one).
    pub p999_ms: f64,
    /// Maximum, ms.
    pub max_ms: f64,
}

/// Every stage's histogram (the index of [`STAGES`] each field is).
#[derive(Debug, Clone, Default)]
pub struct Timing {
    /// The IMU thread's fast path per sample (updates applied, propagation): `STAGES[0]`.
    pub fast_path: LatencyHist,
    /// The back end's `push_imu` for samples that processed no keyframe: `STAGES[1]`.
    pub backend_imu: LatencyHist,
    /// The back end's `push_imu` for samples that processed a keyframe: `STAGES[2]`.
    pub backend_keyframe: LatencyHist,
    /// The back end's `push_frame` / `push_lidar`: `STAGES[3]`.
    pub backend_input: LatencyHist,
    /// IMU sample arrival (the source returned it) to its pose out: `STAGES[4]`.
    pub arrival_to_pose: LatencyHist,
    /// IMU stamp's wall time to its pose out (paced or live sources only): `STAGES[5]`.
    pub stamp_to_pose: LatencyHist,
    /// How far the back end is behind the newest IMU sample when it finishes a sample, in
    /// sensor time: `STAGES[6]`.
    pub backend_lag: LatencyHist,
    /// The front-end stage's image decoding (PNG/JPEG to mono8): `STAGES[7]`.
    pub frontend_decode: LatencyHist,
    /// The front-end stage per image: decoding, INS prediction, tracking, `push_frame`
    /// (`STAGES[8]`).
    pub frontend_image: LatencyHist,
    /// Image arrival (the source returned it) to its track frame in the estimator:
    /// `STAGES[9]`.
    pub image_arrival_to_frame: LatencyHist,
    /// Image stamp's wall time (paced or live sources) to its track frame in the estimator:
    /// `STAGES[10]`.
    pub image_stamp_to_frame: LatencyHist,
    /// The work of each keyframe's solve (`KeyframeReport::solve_work`, the unit of
    /// `[solve_budget] max_work`; counts, not ns): what the time does not show, independent of
    /// the machine and its load. Not one of [`STAGES`].
    pub solve_work: LatencyHist,
}

impl Timing {
    /// The histograms in [`STAGES`] order.
    pub fn stages(&self) -> [&LatencyHist; 11] {
        [
            &self.fast_path,
            &self.backend_imu,
            &self.backend_keyframe,
            &self.backend_input,
            &self.arrival_to_pose,
            &self.stamp_to_pose,
            &self.backend_lag,
            &self.frontend_decode,
            &self.frontend_image,
            &self.image_arrival_to_frame,
            &self.image_stamp_to_frame,
        ]
    }

    /// Adds the histograms of `other` (another thread's).
    pub fn merge(&mut self, other: &Timing) {
        self.fast_path.merge(&other.fast_path);
        self.backend_imu.merge(&other.backend_imu);
        self.backend_keyframe.merge(&other.backend_keyframe);
        self.backend_input.merge(&other.backend_input);
        self.arrival_to_pose.merge(&other.arrival_to_pose);
        self.stamp_to_pose.merge(&other.stamp_to_pose);
        self.backend_lag.merge(&other.backend_lag);
        self.frontend_decode.merge(&other.frontend_decode);
        self.frontend_image.merge(&other.frontend_image);
        self.image_arrival_to_frame
            .merge(&other.image_arrival_to_frame);
        self.image_stamp_to_frame.merge(&other.image_stamp_to_frame);
        self.solve_work.merge(&other.solve_work);
    }
}

/// What the pipeline counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct PipelineCounters {
    /// IMU samples from the source.
    pub imu_in: u64,
    /// Camera frames from the source.
    pub frames_in: u64,
    /// LiDAR sweeps from the source.
    pub sweeps_in: u64,
    /// Camera images from the source (image front end).
    pub images_in: u64,
    /// Poses published.
    pub poses_out: u64,
    /// Keyframes reported.
    pub keyframes: u64,
    /// IMU samples dropped: the back end's queue was full (real-time sources only).
    pub dropped_imu: u64,
    /// Camera frames dropped (queue full).
    pub dropped_frames: u64,
    /// LiDAR sweeps dropped (queue full).
    pub dropped_sweeps: u64,
    /// Camera images dropped (queue full).
    pub dropped_images: u64,
    /// Images the front-end stage could not use (not decodable, refused by the tracker).
    pub image_failures: u64,
    /// Times the IMU thread waited for the back end (unpaced sources and deterministic mode).
    pub backpressure_waits: u64,
    /// Poses published later than one IMU period after their sample's arrival.
    pub imu_deadline_misses: u64,
    /// Back-end samples finished more than one keyframe period behind the newest IMU sample.
    pub backend_lag_misses: u64,
    /// Estimator updates the fast path could not apply (older than its ring).
    pub updates_too_old: u64,
    /// Most IMU samples one update re-propagated on the fast path.
    pub max_replay: u32,
    /// How the published poses stepped (see [`OutputSteps`]).
    pub output_steps: OutputSteps,
}

/// How far the published IMU-rate output stepped away from the motion the IMU measured: an
/// estimator update restarts the INS and the exact output takes the whole correction in one
/// step; the continuous output ([`super::PipelineConfig::smooth_horizon_s`]) spreads it.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct OutputSteps {
    /// The largest correction of the exact state at one sample (position), m.
    pub max_correction_m: f64,
    /// The largest departure of one published step from the IMU-measured motion, m (the
    /// correction itself for the exact output).
    pub max_departure_m: f64,
    /// Published steps departing by more than 1 cm.
    pub steps_over_1cm: u64,
    /// Published steps departing by more than 5 cm.
    pub steps_over_5cm: u64,
}

impl OutputSteps {
    /// Records a published step's departure, m.
    pub fn step(&mut self, departure_m: f64) {
        self.max_departure_m = self.max_departure_m.max(departure_m);
        self.steps_over_1cm += u64::from(departure_m > 0.01);
        self.steps_over_5cm += u64::from(departure_m > 0.05);
    }
}

//! [`RunDigest`]: what `summary.json` needs of a run, kept in compact form while the run goes
//! (the [`RunSink`] `povins run` pairs with its files), so the run's memory does not grow with
//! the IMU-rate states, the reports or the per-image logs: what grows with the run is a few
//! figures per keyframe and per image (about 40 and 8 bytes); the poses and LiDAR events the
//! evaluation reads back are logged to temporary files ([`super::spill`]) and the prediction
//! errors counted in a histogram.

use super::spill::{EventLog, PoseLog, RowLog};
use super::window_use::WindowUseDigest;
use crate::frontend_stats::FrameDigest;
use crate::runner::{FrameLog, RunSink};
use povins_core::estimator::{DepthEvent, KeyframeReport};
use povins_core::inertial::{InsCovariance, NavState};
use povins_platform::recording::Recording;
use povins_platform::trajectory::StampedPose;

/// What the summary needs of a run: per keyframe its timings (ms, for the medians and
/// percentiles) and landmarks used, per image two figures ([`FrameDigest`]), the prediction
/// errors in a histogram (3 significant digits), running sums, and, only when the recording has
/// ground truth, the IMU-rate and keyframe poses ([`StampedPose`], logged for the ATE's passes)
/// and, with simulator truth, the LiDAR-depth events (logged).
#[derive(Debug, Default)]
pub struct RunDigest {
    /// Back-end time per keyframe, ms.
    pub(super) backend_ms: Vec<f64>,
    /// The work of each keyframe's solve (`KeyframeReport::solve_work`).
    pub(super) solve_work: Vec<u32>,
    /// Depth association time per keyframe, ms.
    pub(super) association_ms: Vec<f64>,
    /// Rejection time per keyframe, ms.
    pub(super) rejection_ms: Vec<f64>,
    /// Depth-only optimization time per keyframe, ms.
    pub(super) depth_opt_ms: Vec<f64>,
    /// Landmarks in the final solve, per keyframe.
    pub(super) landmarks_used: Vec<u32>,
    /// See [`super::WindowUse`].
    pub(super) window_use: WindowUseDigest,
    /// The last report's camera-IMU delay (s) and IMU noise factor.
    pub(super) last: Option<(f64, f64)>,
    /// The last estimated extrinsic and its deviations (with `estimate_extrinsic`).
    pub(super) last_extrinsic: Option<super::ExtrinsicEnd>,
    /// Sums over the keyframes of the depths associated, rejected and used in the solve.
    pub(super) depth_sums: [f64; 3],
    /// The image front end's figures.
    pub(super) frames: FrameDigest,
    /// The prediction errors, px.
    pub(super) prediction_px: PxHistogram,
    /// The LiDAR-depth events per keyframe (kept with simulator truth only).
    pub(super) lidar_events: EventLog,
    /// The IMU-rate poses (kept with ground truth only).
    pub(super) trajectory: Option<PoseLog>,
    /// The keyframe poses (kept with ground truth only).
    pub(super) keyframes: Option<PoseLog>,
    /// The IMU-rate velocities with their covariance, for the NEES (kept with ground truth
    /// only): see [`velocity_row`].
    pub(super) velocity_cov: Option<RowLog<VELOCITY_ROW>>,
    /// The spans of time the IMU-rate poses cover: consecutive poses at most
    /// [`super::COVERAGE_TOLERANCE_NS`] apart, first and last stamp (one span per outage).
    pub(super) covered: Vec<(i64, i64)>,
    /// The spans of the inputs' clock a clock jump skipped (no input in them).
    pub(super) skipped: Vec<(i64, i64)>,
}

impl RunDigest {
    /// A digest that keeps the poses and LiDAR events too (for a run collected in memory).
    pub fn keeping_all() -> Self {
        RunDigest {
            lidar_events: EventLog::new(),
            trajectory: Some(PoseLog::default()),
            keyframes: Some(PoseLog::default()),
            ..RunDigest::default()
        }
    }

    /// A digest for a run over `rec`: it keeps the poses when the recording has ground truth and
    /// the LiDAR events when it has simulator truth as well (what the evaluation needs).
    pub fn for_recording(rec: &dyn Recording) -> Self {
        let gt = rec.contents().ground_truth;
        RunDigest {
            lidar_events: if gt && rec.has_sim_truth() {
                EventLog::new()
            } else {
                EventLog::default()
            },
            trajectory: gt.then(PoseLog::default),
            keyframes: gt.then(PoseLog::default),
            velocity_cov: gt.then(RowLog::default),
            ..RunDigest::default()
        }
    }

    /// Keyframes reported.
    pub fn keyframes(&self) -> usize {
        self.backend_ms.len()
    }
}

/// Numbers of a [`velocity_row`].
pub(super) const VELOCITY_ROW: usize = 29;

/// The stamp (its bits), `q_wb` (x y z w), `v_wb` and the upper triangle, row by row, of the
/// covariance of the error `[theta, v]` (body-frame rotation error, rad; world-frame velocity,
/// m/s) of `s`: what [`crate::eval::nees`] needs for the world and the body velocity.
pub(super) fn velocity_row(s: &NavState, cov: &InsCovariance) -> [f64; VELOCITY_ROW] {
    let p = cov.state_order();
    let q = s.q_wb.quaternion();
    let mut row = [0.0; VELOCITY_ROW];
    let head = [
        f64::from_bits(s.t_ns as u64),
        q.i,
        q.j,
        q.k,
        q.w,
        s.v_wb.x,
        s.v_wb.y,
        s.v_wb.z,
    ];
    row[..8].copy_from_slice(&head);
    let mut k = 8;
    for i in 0..6 {
        for j in i..6 {
            row[k] = p[(3 + i, 3 + j)];
            k += 1;
        }
    }
    row
}

impl RunSink for RunDigest {
    fn clock_jump(&mut self, at_ns: i64, jump_ns: i64) {
        self.skipped.push((at_ns.saturating_sub(jump_ns), at_ns));
    }

    fn nav(&mut self, s: &NavState) {
        super::extend_spans(&mut self.covered, s.t_ns);
        if let Some(v) = &mut self.trajectory {
            v.push(&StampedPose::from(s));
        }
    }

    fn nav_covariance(&mut self, s: &NavState, cov: &InsCovariance) {
        if let Some(log) = &mut self.velocity_cov {
            log.push(&velocity_row(s, cov));
        }
    }

    fn report(&mut self, r: &KeyframeReport, lidar_events: &[DepthEvent]) {
        let ms = |ns: u64| ns as f64 * 1e-6;
        self.backend_ms.push(ms(r.backend_ns()));
        self.solve_work.push(r.solve_work);
        self.association_ms.push(ms(r.association_ns));
        self.rejection_ms.push(ms(r.rejection_ns));
        self.depth_opt_ms.push(ms(r.depth_opt_ns));
        self.landmarks_used.push(r.landmarks_used);
        self.window_use.push(r);
        self.last = Some((r.td_s, r.imu_noise_scale));
        if let (Some(e), Some(sd)) = (r.extrinsic, r.extrinsic_sd) {
            self.last_extrinsic = Some(super::ExtrinsicEnd::new(&e, &sd));
        }
        let depths = [r.depths_associated, r.depths_rejected, r.ldm_count];
        for (sum, n) in self.depth_sums.iter_mut().zip(depths) {
            *sum += f64::from(n);
        }
        self.lidar_events.push(r.t_cam_ns, lidar_events);
    }

    fn keyframe(&mut self, s: &NavState) {
        if let Some(v) = &mut self.keyframes {
            v.push(&StampedPose::from(s));
        }
    }

    fn frame(&mut self, f: &FrameLog) {
        self.frames.push(f);
    }

    fn prediction_errors(&mut self, e_px: &[f32]) {
        for &e in e_px {
            self.prediction_px.record(e);
        }
    }
}

/// Pixel distances counted in 0.001 px steps to 3 significant digits (`hdrhistogram`): the
/// median and 90th percentile of millions of prediction errors in a few kilobytes.
#[derive(Debug)]
pub(super) struct PxHistogram(hdrhistogram::Histogram<u64>);

/// Steps of [`PxHistogram`] per pixel.
const PX_STEPS: f64 = 1000.0;

impl Default for PxHistogram {
    fn default() -> Self {
        // 1 to 10^9 steps (1 mpx to 1000 km): any distance in an image.
        let h = hdrhistogram::Histogram::new_with_bounds(1, 1_000_000_000, 3);
        PxHistogram(h.expect("constant, valid bounds"))
    }
}

impl PxHistogram {
    /// Counts a distance (non-finite ones as the largest).
    pub(super) fn record(&mut self, e_px: f32) {
        let steps = (f64::from(e_px) * PX_STEPS).round();
        let v = if steps.is_finite() {
            steps as u64
        } else {
            u64::MAX
        };
        self.0.saturating_record(v.min(self.0.high()));
    }

    /// Distances counted.
    pub(super) fn len(&self) -> usize {
        usize::try_from(self.0.len()).unwrap_or(usize::MAX)
    }

    /// The distance at percentile `p` (0-100), px; `None` without distances.
    pub(super) fn percentile(&self, p: f64) -> Option<f64> {
        (!self.0.is_empty()).then(|| self.0.value_at_quantile(p / 100.0) as f64 / PX_STEPS)
    }
}

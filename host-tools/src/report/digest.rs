//! [`RunDigest`]: what `summary.json` needs of a run, kept in compact form while the run goes
//! (the [`RunSink`] `povins run` pairs with its files), so the run's memory does not grow with
//! the IMU-rate states, the reports or the per-image logs.

use super::window_use::WindowUseDigest;
use crate::frontend_stats::FrameDigest;
use crate::runner::{FrameLog, KeyframeDepthEvents, RunSink};
use povins_core::estimator::{DepthEvent, KeyframeReport};
use povins_core::inertial::NavState;
use povins_platform::recording::Recording;
use povins_platform::trajectory::StampedPose;

/// What the summary needs of a run: per keyframe its timings (ms, for the medians and
/// percentiles) and landmarks used, per image two figures ([`FrameDigest`]), every prediction
/// error (`f32`, for the exact median and 90th percentile), running sums, and, only when the
/// recording has ground truth, the IMU-rate and keyframe poses ([`StampedPose`], for the ATE:
/// the alignment needs them all at once) and, with simulator truth, the LiDAR-depth events.
#[derive(Debug, Clone, Default)]
pub struct RunDigest {
    /// Back-end time per keyframe, ms.
    pub(super) backend_ms: Vec<f64>,
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
    /// Sums over the keyframes of the depths associated, rejected and used in the solve.
    pub(super) depth_sums: [f64; 3],
    /// The image front end's figures.
    pub(super) frames: FrameDigest,
    /// Every prediction error, px.
    pub(super) prediction_err_px: Vec<f32>,
    /// The LiDAR-depth events per keyframe (kept with simulator truth only).
    pub(super) lidar_events: Option<Vec<KeyframeDepthEvents>>,
    /// The IMU-rate poses (kept with ground truth only).
    pub(super) trajectory: Option<Vec<StampedPose>>,
    /// The keyframe poses (kept with ground truth only).
    pub(super) keyframes: Option<Vec<StampedPose>>,
    /// The spans of time the IMU-rate poses cover: consecutive poses at most
    /// [`super::COVERAGE_TOLERANCE_NS`] apart, first and last stamp (one span per outage).
    pub(super) covered: Vec<(i64, i64)>,
}

impl RunDigest {
    /// A digest that keeps the poses and LiDAR events too (for a run collected in memory).
    pub fn keeping_all() -> Self {
        RunDigest {
            lidar_events: Some(Vec::new()),
            trajectory: Some(Vec::new()),
            keyframes: Some(Vec::new()),
            ..RunDigest::default()
        }
    }

    /// A digest for a run over `rec`: it keeps the poses when the recording has ground truth and
    /// the LiDAR events when it has simulator truth as well (what the evaluation needs).
    pub fn for_recording(rec: &dyn Recording) -> Self {
        let gt = rec.contents().ground_truth;
        RunDigest {
            lidar_events: (gt && rec.sim_truth().is_some()).then(Vec::new),
            trajectory: gt.then(Vec::new),
            keyframes: gt.then(Vec::new),
            ..RunDigest::default()
        }
    }

    /// Keyframes reported.
    pub fn keyframes(&self) -> usize {
        self.backend_ms.len()
    }
}

impl RunSink for RunDigest {
    fn nav(&mut self, s: &NavState) {
        match self.covered.last_mut() {
            Some((_, end)) if s.t_ns >= *end && s.t_ns - *end <= super::COVERAGE_TOLERANCE_NS => {
                *end = s.t_ns;
            }
            _ => self.covered.push((s.t_ns, s.t_ns)),
        }
        if let Some(v) = &mut self.trajectory {
            v.push(StampedPose::from(s));
        }
    }

    fn report(&mut self, r: &KeyframeReport, lidar_events: &[DepthEvent]) {
        let ms = |ns: u64| ns as f64 * 1e-6;
        self.backend_ms.push(ms(r.backend_ns()));
        self.association_ms.push(ms(r.association_ns));
        self.rejection_ms.push(ms(r.rejection_ns));
        self.depth_opt_ms.push(ms(r.depth_opt_ns));
        self.landmarks_used.push(r.landmarks_used);
        self.window_use.push(r);
        self.last = Some((r.td_s, r.imu_noise_scale));
        let depths = [r.depths_associated, r.depths_rejected, r.ldm_count];
        for (sum, n) in self.depth_sums.iter_mut().zip(depths) {
            *sum += f64::from(n);
        }
        if let Some(v) = &mut self.lidar_events {
            v.push(KeyframeDepthEvents {
                t_cam_ns: r.t_cam_ns,
                events: lidar_events.to_vec(),
            });
        }
    }

    fn keyframe(&mut self, s: &NavState) {
        if let Some(v) = &mut self.keyframes {
            v.push(StampedPose::from(s));
        }
    }

    fn frame(&mut self, f: &FrameLog) {
        self.frames.push(f);
    }

    fn prediction_errors(&mut self, e_px: &[f32]) {
        self.prediction_err_px.extend_from_slice(e_px);
    }
}

//! What a replay hands out: the [`RunSink`] that receives each output as it is produced, and
//! [`RunOutput`], everything collected in memory.

use povins_core::estimator::{Counters, DepthEvent, KeyframeReport};
use povins_core::frontend::image::TrackStats;
use povins_core::inertial::{InsCovariance, NavState};
use povins_core::lidar::LidarConfig;
use povins_core::vio::{ImageReport, VioCounters};
use povins_platform::driver::ImageIn;
use povins_platform::trajectory::StampedPose;

/// What drives the estimator's camera updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Frontend {
    /// The camera images through povins' own front end (`povins_core::vio`).
    Images,
    /// The dataset's feature tracks (`features0`, `/cam0/features`).
    Tracks,
}

/// The front end's result for one image of a replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameLog {
    /// Image time (camera clock), ns.
    pub t_ns: i64,
    /// What the core reported.
    pub report: ImageReport,
    /// Reading and decoding the image (helper thread), ms.
    pub decode_ms: f64,
}

impl FrameLog {
    /// The log of an image the front end tracked.
    pub fn of(t_ns: i64, report: ImageReport, im: &ImageIn<'_>) -> Self {
        FrameLog {
            t_ns,
            report,
            decode_ms: (im.prepared_ns + im.decode_ns) as f64 * 1e-6,
        }
    }

    /// The tracker's statistics.
    pub fn stats(&self) -> &TrackStats {
        &self.report.track
    }

    /// Front-end time (core clock), ms.
    pub fn frontend_ms(&self) -> f64 {
        self.report.frontend_ns as f64 * 1e-6
    }
}

/// The LiDAR-depth events of one keyframe step.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeDepthEvents {
    /// Camera time of the keyframe: `Associated` depths are z in this keyframe's camera, ns.
    pub t_cam_ns: i64,
    /// The events, in the core's order.
    pub events: Vec<DepthEvent>,
}

/// Receives a replay's outputs as they are produced (see [`super::replay_into`]): [`RunOutput`] collects
/// them, `povins run` streams them to its files ([`crate::report::OutputFiles`]) and keeps what
/// the summary needs ([`crate::report::RunDigest`]). A pair of sinks is a sink that hands each
/// output to both.
pub trait RunSink {
    /// An IMU-rate navigation state (INS from the newest optimized keyframe).
    fn nav(&mut self, s: &NavState);
    /// The covariance of the IMU-rate state just given to [`RunSink::nav`], when the estimator
    /// computes one (`covariance = true`) and knows it.
    fn nav_covariance(&mut self, _s: &NavState, _cov: &InsCovariance) {}
    /// A keyframe step's report and its LiDAR-depth events, in the order of the steps.
    fn report(&mut self, r: &KeyframeReport, lidar_events: &[DepthEvent]);
    /// A keyframe's final state: at its last optimized value, when it left the window or at the
    /// end, in the order of the keyframes' IMU stamps.
    fn keyframe(&mut self, s: &NavState);
    /// An image the front end tracked (images only).
    fn frame(&mut self, f: &FrameLog);
    /// The prediction errors of one camera frame after initialization, px (see
    /// [`RunOutput::prediction_err_px`]).
    fn prediction_errors(&mut self, e_px: &[f32]);
    /// The inputs' clock jumped by `jump_ns` before the sample at `at_ns`
    /// (`povins_core::estimator::clock_jump`): no input lies in `at_ns - jump_ns..at_ns`.
    fn clock_jump(&mut self, _at_ns: i64, _jump_ns: i64) {}
}

impl<A: RunSink, B: RunSink> RunSink for (A, B) {
    fn nav(&mut self, s: &NavState) {
        self.0.nav(s);
        self.1.nav(s);
    }
    fn nav_covariance(&mut self, s: &NavState, cov: &InsCovariance) {
        self.0.nav_covariance(s, cov);
        self.1.nav_covariance(s, cov);
    }
    fn report(&mut self, r: &KeyframeReport, lidar_events: &[DepthEvent]) {
        self.0.report(r, lidar_events);
        self.1.report(r, lidar_events);
    }
    fn keyframe(&mut self, s: &NavState) {
        self.0.keyframe(s);
        self.1.keyframe(s);
    }
    fn frame(&mut self, f: &FrameLog) {
        self.0.frame(f);
        self.1.frame(f);
    }
    fn prediction_errors(&mut self, e_px: &[f32]) {
        self.0.prediction_errors(e_px);
        self.1.prediction_errors(e_px);
    }
    fn clock_jump(&mut self, at_ns: i64, jump_ns: i64) {
        self.0.clock_jump(at_ns, jump_ns);
        self.1.clock_jump(at_ns, jump_ns);
    }
}

/// The stamps a replay read from the recording: what tells a camera that never reached the
/// estimator for its stamps (another unit, another clock) from one that did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InputStamps {
    /// First and last IMU sample replayed, ns.
    pub imu_span_ns: Option<(i64, i64)>,
    /// First camera frame or image read (offered or skipped), ns.
    pub first_camera_read_ns: Option<i64>,
    /// Camera frames or images read but skipped: stamped before the first IMU sample.
    pub camera_skipped: u64,
    /// The first camera frame or image never read: stamped after the last IMU sample, ns.
    pub camera_pending_ns: Option<i64>,
}

/// What a replay knows once it has ended (the counts and settings of [`RunOutput`]).
#[derive(Debug, Clone)]
pub struct RunTotals {
    /// Rejection counters.
    pub counters: Counters,
    /// Camera frames (or images) the replay read from the recording.
    pub camera_frames: usize,
    /// LiDAR sweeps the replay read from the recording.
    pub lidar_scans: usize,
    /// The LiDAR settings of the run.
    pub lidar: LidarConfig,
    /// Wall time of the whole replay (estimator calls only), s.
    pub estimator_wall_s: f64,
    /// The front end that fed the estimator.
    pub frontend: Frontend,
    /// Images that could not be read or were refused (images only).
    pub image_failures: usize,
    /// The first of them with the reason.
    pub image_errors: Vec<(i64, String)>,
    /// The image entry point's counters (images only).
    pub vio_counters: VioCounters,
    /// Merge time of the first camera frame or image offered, ns.
    pub first_camera_ns: Option<i64>,
    /// Stamp of the first IMU-rate estimate, ns.
    pub first_estimate_ns: Option<i64>,
    /// The stamps read from the recording.
    pub input: InputStamps,
}

/// Everything a replay produced, collected in memory (the [`RunSink`] of the tests, `demo`,
/// `regress` and `ablation`).
#[derive(Debug, Clone)]
pub struct RunOutput {
    /// IMU-rate navigation states (INS from the newest optimized keyframe).
    pub imu_rate: Vec<NavState>,
    /// Keyframe poses, each at its last optimized value (when it left the window, or at the end).
    pub keyframes: Vec<StampedPose>,
    /// The same keyframes' whole states (velocity and biases included), same order.
    pub keyframe_states: Vec<NavState>,
    /// One report per keyframe.
    pub reports: Vec<KeyframeReport>,
    /// LiDAR-depth events, one entry per report (same order).
    pub lidar_events: Vec<KeyframeDepthEvents>,
    /// Rejection counters.
    pub counters: Counters,
    /// Camera frames (or images) the replay read from the recording.
    pub camera_frames: usize,
    /// LiDAR sweeps the replay read from the recording.
    pub lidar_scans: usize,
    /// The LiDAR settings of the run.
    pub lidar: LidarConfig,
    /// Wall time of the whole replay (estimator calls only), s.
    pub estimator_wall_s: f64,
    /// Per camera frame after initialization, for every feature the estimator predicted
    /// (`predict_features`, just before the frame is offered) and the frame observes: the
    /// distance between prediction and observation, px. What an INS-aided tracker would gain.
    pub prediction_err_px: Vec<f32>,
    /// The front end that fed the estimator.
    pub frontend: Frontend,
    /// Per image tracked (images only).
    pub frames: Vec<FrameLog>,
    /// Images that could not be read or were refused (images only).
    pub image_failures: usize,
    /// The first of them with the reason.
    pub image_errors: Vec<(i64, String)>,
    /// The image entry point's counters (images only).
    pub vio_counters: VioCounters,
    /// Merge time of the first camera frame or image offered, ns.
    pub first_camera_ns: Option<i64>,
    /// Stamp of the first IMU-rate estimate, ns.
    pub first_estimate_ns: Option<i64>,
    /// The stamps read from the recording.
    pub input: InputStamps,
}

impl RunOutput {
    /// The outputs collected in `sink` with the run's `totals`.
    pub(super) fn new(sink: Collected, t: RunTotals) -> Self {
        RunOutput {
            imu_rate: sink.imu_rate,
            keyframes: sink.keyframe_states.iter().map(StampedPose::from).collect(),
            keyframe_states: sink.keyframe_states,
            reports: sink.reports,
            lidar_events: sink.lidar_events,
            counters: t.counters,
            camera_frames: t.camera_frames,
            lidar_scans: t.lidar_scans,
            lidar: t.lidar,
            estimator_wall_s: t.estimator_wall_s,
            prediction_err_px: sink.prediction_err_px,
            frontend: t.frontend,
            frames: sink.frames,
            image_failures: t.image_failures,
            image_errors: t.image_errors,
            vio_counters: t.vio_counters,
            first_camera_ns: t.first_camera_ns,
            first_estimate_ns: t.first_estimate_ns,
            input: t.input,
        }
    }

    /// The run's counts and settings.
    pub fn totals(&self) -> RunTotals {
        RunTotals {
            counters: self.counters,
            camera_frames: self.camera_frames,
            lidar_scans: self.lidar_scans,
            lidar: self.lidar,
            estimator_wall_s: self.estimator_wall_s,
            frontend: self.frontend,
            image_failures: self.image_failures,
            image_errors: self.image_errors.clone(),
            vio_counters: self.vio_counters,
            first_camera_ns: self.first_camera_ns,
            first_estimate_ns: self.first_estimate_ns,
            input: self.input,
        }
    }

    /// Hands every output to `sink` in the order a replay produced them, kind by kind (what
    /// `povins run` streamed, for the files written from a collected run).
    pub fn replay_into(&self, sink: &mut impl RunSink) {
        for s in &self.imu_rate {
            sink.nav(s);
        }
        for (k, r) in self.reports.iter().enumerate() {
            let events = self.lidar_events.get(k).map_or(&[][..], |e| &e.events[..]);
            sink.report(r, events);
        }
        for s in &self.keyframe_states {
            sink.keyframe(s);
        }
        for f in &self.frames {
            sink.frame(f);
        }
        sink.prediction_errors(&self.prediction_err_px);
    }
}

/// The outputs [`RunOutput`] collects.
#[derive(Debug, Default)]
pub(super) struct Collected {
    imu_rate: Vec<NavState>,
    keyframe_states: Vec<NavState>,
    reports: Vec<KeyframeReport>,
    lidar_events: Vec<KeyframeDepthEvents>,
    prediction_err_px: Vec<f32>,
    frames: Vec<FrameLog>,
}

impl RunSink for Collected {
    fn nav(&mut self, s: &NavState) {
        self.imu_rate.push(*s);
    }
    fn report(&mut self, r: &KeyframeReport, lidar_events: &[DepthEvent]) {
        self.lidar_events.push(KeyframeDepthEvents {
            t_cam_ns: r.t_cam_ns,
            events: lidar_events.to_vec(),
        });
        self.reports.push(*r);
    }
    fn keyframe(&mut self, s: &NavState) {
        self.keyframe_states.push(*s);
    }
    fn frame(&mut self, f: &FrameLog) {
        self.frames.push(*f);
    }
    fn prediction_errors(&mut self, e_px: &[f32]) {
        self.prediction_err_px.extend_from_slice(e_px);
    }
}

//! Replay of a [`Dataset`] through the estimator, in time order, exactly as a live system would
//! feed it: every measurement is pushed when the replay clock (the IMU stream) reaches its stamp
//! (a camera frame its stamp, a LiDAR sweep its last point on the IMU clock, see
//! [`lidar_schedule`]) and the core
//! orders the processing itself ([`povins_core::estimator::timing`]): a frame is processed at
//! the first IMU sample past `t_cam + td`, a sweep de-skewed once the IMU has passed
//! `max t_point + td_l`.

use crate::images::{with_images, LoadedImage};
use crate::progress::Progress;
use anyhow::{bail, Result};
use povins_core::camera::{CameraExtrinsic, FeatureObs};
use povins_core::estimator::{
    Counters, DepthEvent, EstimatorConfig, FeaturePrediction, KeyframeReport,
};
use povins_core::frontend::image::{ImageView, TrackStats, TrackerConfig};
use povins_core::inertial::NavState;
use povins_core::lidar::{LidarConfig, LidarExtrinsic};
use povins_core::vio::{EurocVio, HdVio, ImageReport, Vio, VioAiding, VioCounters};
use povins_platform::trajectory::StampedPose;
use povins_platform::Dataset;
use std::collections::BTreeMap;
use std::sync::OnceLock;
use std::time::Instant;

/// How the estimator starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum InitMode {
    /// Wait for a static period, level with gravity, take the gyro bias from the mean.
    Static,
    /// Start from the ground-truth state (velocity and biases included) at the first IMU
    /// sample covered by ground truth, as peers do in evaluation.
    Groundtruth,
}

/// What drives the estimator's camera updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Frontend {
    /// The camera images through povins' own front end (`povins_core::vio`).
    Images,
    /// The dataset's feature tracks (`features0`, `/cam0/features`).
    Tracks,
}

/// How camera frames reach the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontendOptions {
    /// Images or tracks.
    pub frontend: Frontend,
    /// The image front end's settings (images only).
    pub tracker: TrackerConfig,
    /// INS aiding of the tracker (images only).
    pub aiding: VioAiding,
}

impl FrontendOptions {
    /// The dataset's tracks.
    pub fn tracks() -> Self {
        FrontendOptions {
            frontend: Frontend::Tracks,
            tracker: TrackerConfig::default(),
            aiding: VioAiding::default(),
        }
    }

    /// The images with `tracker`.
    pub fn images(tracker: TrackerConfig) -> Self {
        FrontendOptions {
            frontend: Frontend::Images,
            tracker,
            aiding: VioAiding::default(),
        }
    }
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
    /// The tracker's statistics.
    pub fn stats(&self) -> &TrackStats {
        &self.report.track
    }

    /// Front-end time (core clock), ms.
    pub fn frontend_ms(&self) -> f64 {
        self.report.frontend_ns as f64 * 1e-6
    }
}

/// Monotonic nanoseconds since the first call (the core's timing clock).
pub fn monotonic_ns() -> u64 {
    static T0: OnceLock<Instant> = OnceLock::new();
    T0.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

/// The estimator configuration implied by a dataset's calibration (before `--config`).
pub fn config_for(ds: &Dataset) -> EstimatorConfig {
    let c = &ds.calib;
    let ext = CameraExtrinsic {
        p_bc: c.t_bc.p_ab,
        q_bc: c.t_bc.q_ab,
    };
    let mut cfg = EstimatorConfig::new(c.camera, ext, c.imu_noise);
    cfg.gravity_mps2 = c.gravity_mps2;
    cfg.td_s = c.td_s;
    cfg.clock = Some(monotonic_ns);
    if let (false, Some(t_bl)) = (ds.lidar.is_empty(), c.t_bl) {
        cfg.lidar.enabled = true;
        cfg.lidar.extrinsic = LidarExtrinsic {
            q_bl: t_bl.q_ab,
            p_bl: t_bl.p_ab,
        };
    }
    cfg
}

pub use povins_platform::pipeline::lidar_schedule;

/// The LiDAR-depth events of one keyframe step.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeDepthEvents {
    /// Camera time of the keyframe: `Associated` depths are z in this keyframe's camera, ns.
    pub t_cam_ns: i64,
    /// The events, in the core's order.
    pub events: Vec<DepthEvent>,
}

/// Everything a replay produced.
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
    /// Camera frames in the dataset.
    pub camera_frames: usize,
    /// LiDAR sweeps in the dataset.
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
}

/// Replays `ds` through a new estimator with `cfg`, fed with the dataset's feature tracks.
/// LiDAR sweeps are offered whatever `cfg.lidar.enabled` says: a disabled estimator refuses
/// (and counts) them.
pub fn replay(
    ds: &Dataset,
    cfg: EstimatorConfig,
    init: InitMode,
    progress: &Progress,
) -> Result<RunOutput> {
    replay_with(ds, cfg, init, &FrontendOptions::tracks(), progress)
}

/// Replays `ds` with the front end chosen in `fe`: the dataset's tracks, or its images through
/// the image front end ([`povins_core::vio::Vio`], images decoded lazily on a helper thread).
/// Errors when the chosen input is missing from the dataset.
pub fn replay_with(
    ds: &Dataset,
    cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    progress: &Progress,
) -> Result<RunOutput> {
    let (w, h) = (ds.calib.camera.width, ds.calib.camera.height);
    match fe.frontend {
        Frontend::Tracks => {
            if ds.features.is_empty() && !ds.images.is_empty() {
                bail!(
                    "{}: the dataset has camera images but no feature tracks (features0, \
                     /cam0/features): use --frontend images",
                    ds.name
                );
            }
            replay_vio::<EurocVio>(ds, cfg, init, fe, progress)
        }
        Frontend::Images => {
            if ds.images.is_empty() {
                bail!(
                    "{}: the dataset has no camera images (EuRoC cam0/data.csv with \
                     cam0/data/*.png, MCAP /cam0/image_raw or /cam0/image_raw/compressed){}",
                    ds.name,
                    if ds.features.is_empty() {
                        ""
                    } else {
                        "; it has feature tracks: use --frontend tracks"
                    }
                );
            }
            if w <= 752 && h <= 480 {
                replay_vio::<EurocVio>(ds, cfg, init, fe, progress)
            } else if w <= 1280 && h <= 720 {
                replay_vio::<HdVio>(ds, cfg, init, fe, progress)
            } else {
                bail!(
                    "{}: {w}x{h} images are larger than the front end's largest capacity \
                     (1280x720)",
                    ds.name
                )
            }
        }
    }
}

/// A [`Vio`] of any capacity, as the replay drives it.
pub trait VioDriver {
    /// Builds one.
    fn build(cfg: EstimatorConfig, tracker: TrackerConfig) -> Result<Box<Self>>;
    /// The estimator.
    fn est(&self) -> &povins_core::estimator::PoVins;
    /// The estimator, mutable.
    fn est_mut(&mut self) -> &mut povins_core::estimator::PoVins;
    /// [`Vio::push_imu`].
    fn imu(&mut self, s: &povins_core::inertial::ImuSample) -> Result<(), povins_core::Error>;
    /// [`Vio::update`].
    fn update(&mut self) -> Result<Option<povins_core::estimator::ImuOutput>, povins_core::Error>;
    /// [`Vio::push_image`].
    fn image(&mut self, t_ns: i64, view: &ImageView) -> Result<ImageReport, povins_core::Error>;
    /// [`Vio::features`].
    fn tracks(&self) -> &[FeatureObs];
    /// [`Vio::set_aiding`].
    fn aiding(&mut self, a: VioAiding);
    /// [`Vio::counters`].
    fn vio_counters(&self) -> VioCounters;
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> VioDriver
    for Vio<10, 200, 166, F, BYTES, LEVELS>
{
    fn build(cfg: EstimatorConfig, tracker: TrackerConfig) -> Result<Box<Self>> {
        // Built in place on the heap: never on the stack, also in unoptimized builds.
        povins_platform::boxed::boxed_vio(cfg, tracker)
            .map_err(|e| anyhow::anyhow!("invalid estimator or front-end configuration: {e}"))
    }
    fn est(&self) -> &povins_core::estimator::PoVins {
        self.estimator()
    }
    fn est_mut(&mut self) -> &mut povins_core::estimator::PoVins {
        self.estimator_mut()
    }
    fn imu(&mut self, s: &povins_core::inertial::ImuSample) -> Result<(), povins_core::Error> {
        self.push_imu(s)
    }
    fn update(&mut self) -> Result<Option<povins_core::estimator::ImuOutput>, povins_core::Error> {
        Vio::update(self)
    }
    fn image(&mut self, t_ns: i64, view: &ImageView) -> Result<ImageReport, povins_core::Error> {
        self.push_image(t_ns, view)
    }
    fn tracks(&self) -> &[FeatureObs] {
        self.features()
    }
    fn aiding(&mut self, a: VioAiding) {
        self.set_aiding(a);
    }
    fn vio_counters(&self) -> VioCounters {
        self.counters()
    }
}

/// Where a replay of `ds` starts with `init`: the index of the first IMU sample replayed and,
/// for [`InitMode::Groundtruth`], the true state there (the first keyframe's prior in `cfg` is
/// tightened accordingly). Errors when the dataset cannot start that way.
pub fn start_state(
    ds: &Dataset,
    cfg: &mut EstimatorConfig,
    init: InitMode,
) -> Result<(usize, Option<NavState>)> {
    if ds.imu.is_empty() {
        bail!("{}: the dataset has no IMU samples", ds.name);
    }
    if init == InitMode::Static {
        return Ok((0, None));
    }
    let Some(g0) = ds.ground_truth.first() else {
        bail!(
            "{}: --init groundtruth needs ground truth in the dataset",
            ds.name
        );
    };
    let start = ds
        .imu
        .iter()
        .position(|s| s.t_ns >= g0.t_ns)
        .unwrap_or(ds.imu.len());
    let Some(s0) = ds.imu.get(start) else {
        bail!(
            "{}: no IMU sample after the first ground-truth state",
            ds.name
        );
    };
    let gt0 = interpolate_state(&ds.ground_truth, s0.t_ns).unwrap_or(*g0);
    // The true state is known: the first keyframe's prior says so (peers do the same).
    cfg.first_prior.theta_rad = 2e-3;
    cfg.first_prior.v_mps = 0.01;
    cfg.first_prior.bg_rps = 1e-4;
    cfg.first_prior.ba_mps2 = 0.01;
    Ok((
        start,
        Some(NavState {
            t_ns: s0.t_ns,
            ..gt0
        }),
    ))
}

fn replay_vio<V: VioDriver>(
    ds: &Dataset,
    mut cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    progress: &Progress,
) -> Result<RunOutput> {
    let (start, gt_start) = start_state(ds, &mut cfg, init)?;
    let lidar = cfg.lidar;
    let mut vio = V::build(cfg, fe.tracker)?;
    vio.aiding(fe.aiding);
    if let Some(s0) = gt_start {
        vio.est_mut()
            .initialize(s0)
            .map_err(|e| anyhow::anyhow!("cannot initialize from ground truth: {e}"))?;
    }
    let images = fe.frontend == Frontend::Images;
    let mut out = RunOutput {
        imu_rate: Vec::with_capacity(ds.imu.len()),
        keyframes: Vec::new(),
        keyframe_states: Vec::new(),
        reports: Vec::new(),
        lidar_events: Vec::new(),
        counters: Counters::default(),
        camera_frames: if images {
            ds.images.len()
        } else {
            ds.features.len()
        },
        lidar_scans: ds.lidar.len(),
        lidar,
        estimator_wall_s: 0.0,
        prediction_err_px: Vec::new(),
        frontend: fe.frontend,
        frames: Vec::new(),
        image_failures: 0,
        image_errors: Vec::new(),
        vio_counters: VioCounters::default(),
    };
    let mut predicted = vec![FeaturePrediction::EMPTY; 512];
    // Time spent outside the estimator (prediction bookkeeping, waiting for decoded images).
    let mut other_s = 0.0;
    let mut kf_states: BTreeMap<i64, NavState> = BTreeMap::new();
    let t_start_ns = ds.imu[start].t_ns;
    let mut fi = ds.features.partition_point(|f| f.t_ns < t_start_ns);
    let first_image = ds.images.partition_point(|f| f.t_ns < t_start_ns);
    // Sweeps due before the first replayed IMU sample are skipped, like frames before it.
    let scans = lidar_schedule(ds, lidar.td_l_s);
    let mut li = scans.partition_point(|&(t, _)| t < t_start_ns);
    let image_list = if images {
        ds.images.get(first_image..).unwrap_or(&[])
    } else {
        &[]
    };
    let t_run = Instant::now();
    with_images(image_list, |stream| -> Result<()> {
        let mut stream = stream.peekable();
        for (i, s) in ds.imu.iter().enumerate().skip(start) {
            if images {
                loop {
                    let t_wait = Instant::now();
                    let due = stream.peek().is_some_and(|im| im.t_ns <= s.t_ns);
                    let next = if due { stream.next() } else { None };
                    other_s += t_wait.elapsed().as_secs_f64();
                    let Some(im) = next else { break };
                    let t_eval = Instant::now();
                    let n = vio
                        .est()
                        .predict_features(im.t_ns, &mut predicted)
                        .unwrap_or(0);
                    other_s += t_eval.elapsed().as_secs_f64();
                    push_image(&mut *vio, &im, &mut out);
                    let t_eval = Instant::now();
                    prediction_errors(&predicted[..n.min(predicted.len())], vio.tracks(), &mut out);
                    other_s += t_eval.elapsed().as_secs_f64();
                }
            } else {
                while let Some(f) = ds.features.get(fi).filter(|f| f.t_ns <= s.t_ns) {
                    if let Ok(n) = vio.est().predict_features(f.t_ns, &mut predicted) {
                        let t_eval = Instant::now();
                        prediction_errors(&predicted[..n.min(predicted.len())], &f.obs, &mut out);
                        other_s += t_eval.elapsed().as_secs_f64();
                    }
                    let _ = vio.est_mut().push_frame(f.t_ns, &f.obs);
                    fi += 1;
                }
            }
            let _ = vio.imu(s);
            // The core holds each sweep until the IMU has passed its last point: offer it when
            // it is complete (its last point, on the IMU clock).
            while let Some(&(_, k)) = scans.get(li).filter(|(t, _)| *t <= s.t_ns) {
                if let Some(scan) = ds.lidar.get(k) {
                    let _ = vio.est_mut().push_lidar(&scan.points);
                }
                li += 1;
            }
            loop {
                let o = match vio.update() {
                    Ok(Some(o)) => o,
                    Ok(None) => break,
                    Err(_) => continue,
                };
                if let Some(r) = o.keyframe {
                    out.lidar_events.push(KeyframeDepthEvents {
                        t_cam_ns: r.t_cam_ns,
                        events: vio.est().lidar_events().to_vec(),
                    });
                    out.reports.push(r);
                    for kf in vio.est().keyframes() {
                        kf_states.insert(kf.state.t_ns, kf.state);
                    }
                }
                if let Some(nav) = o.nav {
                    out.imu_rate.push(nav);
                }
            }
            if i % 1000 == 0 {
                progress.set_position(i as u64);
            }
        }
        Ok(())
    })?;
    out.estimator_wall_s = t_run.elapsed().as_secs_f64() - other_s;
    progress.finish();
    out.keyframe_states = kf_states.into_values().collect();
    out.keyframes = out.keyframe_states.iter().map(StampedPose::from).collect();
    out.counters = vio.est().counters();
    out.vio_counters = vio.vio_counters();
    Ok(out)
}

/// Most image errors kept with their message (the rest are counted).
const MAX_IMAGE_ERRORS: usize = 20;

/// Tracks one decoded image into the estimator, logging the result or the error.
fn push_image<V: VioDriver + ?Sized>(vio: &mut V, im: &LoadedImage<'_>, out: &mut RunOutput) {
    let mut fail = |msg: String| {
        out.image_failures += 1;
        if out.image_errors.len() < MAX_IMAGE_ERRORS {
            out.image_errors.push((im.t_ns, msg));
        }
    };
    let (w, h, px) = match &im.pixels {
        Ok(p) => p,
        Err(e) => return fail(e.clone()),
    };
    let view = match ImageView::new(px, *w, *h, *w) {
        Ok(v) => v,
        Err(e) => return fail(format!("image at {} ns ({w}x{h}): {e}", im.t_ns)),
    };
    match vio.image(im.t_ns, &view) {
        Ok(report) => out.frames.push(FrameLog {
            t_ns: im.t_ns,
            report,
            decode_ms: im.decode_s * 1e3,
        }),
        Err(e) => fail(format!("image at {} ns ({w}x{h}) refused: {e}", im.t_ns)),
    }
}

/// Appends the pixel distance of each prediction to the observation of the same feature.
fn prediction_errors(predicted: &[FeaturePrediction], obs: &[FeatureObs], out: &mut RunOutput) {
    let mut by_id: Vec<(u64, f64, f64)> = obs.iter().map(|o| (o.id, o.u_px, o.v_px)).collect();
    by_id.sort_by_key(|o| o.0);
    for p in predicted {
        if let Ok(k) = by_id.binary_search_by_key(&p.id, |o| o.0) {
            let (_, u, v) = by_id[k];
            out.prediction_err_px
                .push((p.uv_px[0] - u).hypot(p.uv_px[1] - v) as f32);
        }
    }
}

/// Ground-truth state at `t_ns` by linear interpolation (slerp for attitude).
pub fn interpolate_state(gt: &[NavState], t_ns: i64) -> Option<NavState> {
    let k = gt.partition_point(|g| g.t_ns <= t_ns);
    let (a, b) = (
        gt.get(k.checked_sub(1)?)?,
        gt.get(k).unwrap_or(gt.get(k - 1)?),
    );
    if b.t_ns == a.t_ns {
        return Some(NavState { t_ns, ..*a });
    }
    let w = (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
    Some(NavState {
        t_ns,
        p_wb: a.p_wb.lerp(&b.p_wb, w),
        q_wb: a.q_wb.slerp(&b.q_wb, w),
        v_wb: a.v_wb.lerp(&b.v_wb, w),
        bg: a.bg.lerp(&b.bg, w),
        ba: a.ba.lerp(&b.ba, w),
    })
}

/// One of the reports' `_ns` timings per keyframe, in ms, sorted ascending.
pub fn sorted_ms(reports: &[KeyframeReport], f: impl Fn(&KeyframeReport) -> u64) -> Vec<f64> {
    let mut v: Vec<f64> = reports.iter().map(|r| f(r) as f64 * 1e-6).collect();
    v.sort_by(f64::total_cmp);
    v
}

/// Percentile (nearest rank) of a sorted slice.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

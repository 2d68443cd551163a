//! Replay of a recording through the estimator, in time order, exactly as a live system would
//! feed it: the recording's streams merged into the one arrival order
//! ([`povins_platform::source::MergedSource`], images decoded ahead on a helper thread), each
//! message handed to the one driver step ([`povins_platform::driver`]) and the odometry's outputs
//! handed to a [`RunSink`] as they are produced (collected into a [`RunOutput`], or streamed).
//! The threaded pipeline ([`crate::realtime`]) builds the same
//! odometry, starts it the same way and reads the same source.

use crate::progress::Progress;
use anyhow::{bail, Context, Result};
use povins_core::camera::FeatureObs;
use povins_core::estimator::{EstimatorConfig, FeaturePrediction};
use povins_core::frontend::image::TrackerConfig;
use povins_core::inertial::NavState;
use povins_core::lidar::LidarExtrinsic;
use povins_core::odometry::{FrameOutput, KeyframeState, Odometry, Output};
use povins_core::vio::VioAiding;
use povins_platform::driver::{self, ImageIn, Observer};
use povins_platform::odometry::{boxed_odometry, FrontEnd};
use povins_platform::recording::Recording;
use povins_platform::source::{CameraInput, MergeOptions, MergedSource, Pacing, Prefetch};
use std::collections::BTreeMap;
use std::sync::OnceLock;
use std::time::Instant;

mod output;
mod truth;
use output::Collected;
pub use output::{
    FrameLog, Frontend, InputStamps, KeyframeDepthEvents, RunOutput, RunSink, RunTotals,
};
pub use truth::{interpolate_state, percentile, sorted_ms, GtCursor};

/// How the estimator starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum InitMode {
    /// The static initializer while the images show a rest, the in-motion one otherwise (the
    /// estimator's `[init] mode = "auto"`).
    Auto,
    /// Wait for a static period, level with gravity, take the gyro bias from the mean.
    Static,
    /// Only the in-motion initializer (gravity and velocity from the first frames' tracks and
    /// the IMU).
    Motion,
    /// Start from the ground-truth state (velocity and biases included) at the first IMU
    /// sample covered by ground truth, as peers do in evaluation.
    Groundtruth,
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

    /// The platform's description of the front end.
    pub fn front_end(&self) -> FrontEnd {
        match self.frontend {
            Frontend::Tracks => FrontEnd::Tracks,
            Frontend::Images => FrontEnd::Images {
                tracker: self.tracker,
                aiding: self.aiding,
            },
        }
    }

    /// What a replay offers of the camera.
    pub fn camera_input(&self) -> CameraInput {
        match self.frontend {
            Frontend::Tracks => CameraInput::Frames,
            Frontend::Images => CameraInput::Images,
        }
    }
}

/// Whether the core's stage timings use the thread's CPU time ([`use_cpu_time`]).
static CPU_TIME: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Times the estimator's stages (the keyframe reports' `*_ns`: `stats.csv`, the summary's
/// back-end figures) by the running thread's CPU time instead of the wall clock, for the runs
/// this process starts from now on (`--cpu-time`).
pub fn use_cpu_time(on: bool) {
    CPU_TIME.store(on, std::sync::atomic::Ordering::Relaxed);
}

/// The core's timing clock: [`monotonic_ns`], or with [`use_cpu_time`] the thread's CPU time.
pub fn core_clock() -> fn() -> u64 {
    if CPU_TIME.load(std::sync::atomic::Ordering::Relaxed) {
        povins_platform::pipeline::rt::thread_cpu_ns
    } else {
        monotonic_ns
    }
}

/// Monotonic nanoseconds since the first call (the core's timing clock).
pub fn monotonic_ns() -> u64 {
    static T0: OnceLock<Instant> = OnceLock::new();
    T0.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

/// The estimator configuration implied by a recording's calibration (before `--config`).
pub fn config_for(rec: &dyn Recording) -> EstimatorConfig {
    let c = rec.calibration();
    let ext = povins_core::camera::CameraExtrinsic {
        p_bc: c.t_bc.p_ab,
        q_bc: c.t_bc.q_ab,
    };
    let mut cfg = EstimatorConfig::new(c.camera, ext, c.imu_noise);
    cfg.gravity_mps2 = c.gravity_mps2;
    cfg.td_s = c.td_s;
    if let (true, Some(t_bl)) = (rec.contents().lidar, c.t_bl) {
        cfg.lidar.enabled = true;
        cfg.lidar.extrinsic = LidarExtrinsic {
            q_bl: t_bl.q_ab,
            p_bl: t_bl.p_ab,
        };
        cfg.lidar.td_l_s = c.td_l_s;
    }
    cfg
}

/// Replays `rec` through a new estimator with `cfg`, fed with the recording's feature tracks.
/// LiDAR sweeps are offered whatever `cfg.lidar.enabled` says: a disabled estimator refuses
/// (and counts) them.
pub fn replay(
    rec: &dyn Recording,
    cfg: EstimatorConfig,
    init: InitMode,
    progress: &Progress,
) -> Result<RunOutput> {
    replay_with(rec, cfg, init, &FrontendOptions::tracks(), progress)
}

/// Errors when the recording lacks what the front end in `fe` needs.
pub fn check_input(rec: &dyn Recording, fe: &FrontendOptions) -> Result<()> {
    let has = rec.contents();
    let name = rec.name();
    match fe.frontend {
        // Without a camera at all, the IMU (and LiDAR) alone still run.
        Frontend::Tracks if !has.frames && has.images => bail!(
            "{name}: the dataset has camera images but no feature tracks (features0, \
             /cam0/features): use --frontend images"
        ),
        Frontend::Images if !has.images => bail!(
            "{name}: the dataset has no camera images (EuRoC cam0/data.csv with \
             cam0/data/*.png, MCAP /cam0/image_raw or /cam0/image_raw/compressed){}",
            if has.frames {
                "; it has feature tracks: use --frontend tracks"
            } else {
                ""
            }
        ),
        _ => Ok(()),
    }
}

/// The odometry of a run over `rec`: built for `fe` (the front end's capacity chosen by the
/// camera's image size), started as `init` says (`cfg`'s first-keyframe prior tightened for a
/// ground-truth start), with the stamp of the first IMU sample the replay takes.
pub fn start(
    rec: &dyn Recording,
    mut cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
) -> Result<(Box<dyn Odometry + Send>, i64)> {
    check_input(rec, fe)?;
    let (start_ns, gt_start) = start_state(rec, &mut cfg, init)?;
    let mut odo = boxed_odometry(cfg, &fe.front_end(), Some(core_clock()))
        .with_context(|| rec.name().to_string())?;
    if let Some(s0) = gt_start {
        odo.initialize(s0)
            .map_err(|e| anyhow::anyhow!("cannot initialize from ground truth: {e}"))?;
    }
    Ok((odo, start_ns))
}

/// Replays `rec` with the front end chosen in `fe`: the recording's tracks, or its images
/// through the image front end ([`povins_core::vio::Vio`], images decoded ahead on a helper
/// thread). Errors when the chosen input is missing from the recording or it cannot be read.
pub fn replay_with(
    rec: &dyn Recording,
    cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    progress: &Progress,
) -> Result<RunOutput> {
    let mut sink = Collected::default();
    let totals = replay_into(rec, cfg, init, fe, progress, &mut sink)?;
    Ok(RunOutput::new(sink, totals))
}

/// [`replay_with`] handing each output to `sink` as it is produced (keyframe states when they
/// are final). On an error part-way, `sink` has had the outputs up to it (without the keyframes
/// still in the window).
pub fn replay_into(
    rec: &dyn Recording,
    cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    progress: &Progress,
    sink: &mut impl RunSink,
) -> Result<RunTotals> {
    let lidar = cfg.lidar;
    let (mut odo, start_ns) = start(rec, cfg, init, fe)?;
    let opts = MergeOptions {
        start_ns,
        td_l_s: lidar.td_l_s,
        camera: fe.camera_input(),
        lidar: true,
        pacing: Pacing::AsFastAsPossible,
    };
    let source = MergedSource::new(rec, &opts)?;
    let mut obs = RunObserver::new(sink, rec, progress);
    let (ran, mut source) = Prefetch::run(source, |p| driver::run(&mut *odo, p, &mut obs));
    let stats = ran.with_context(|| format!("reading {}", rec.name()))?;
    progress.finish();
    let read = source.stats();
    let (image_failures, image_errors, first_estimate_ns) = obs.finish();
    let c = odo.counters();
    Ok(RunTotals {
        counters: c.estimator,
        camera_frames: read.camera_read as usize,
        lidar_scans: read.sweeps_read as usize,
        lidar,
        estimator_wall_s: stats.odometry_s,
        frontend: fe.frontend,
        image_failures,
        image_errors,
        vio_counters: c.images,
        first_camera_ns: read.first_camera_ns,
        first_estimate_ns,
        input: InputStamps {
            imu_span_ns: read.imu_span_ns,
            first_camera_read_ns: read.first_camera_read_ns,
            camera_skipped: read.camera_skipped,
            camera_pending_ns: source.pending_camera_ns(),
        },
    })
}

/// Where a replay of `rec` starts with `init`: the stamp of the first IMU sample replayed and,
/// for [`InitMode::Groundtruth`], the true state there (the first keyframe's prior in `cfg` is
/// tightened accordingly). Errors when the recording cannot start that way.
pub fn start_state(
    rec: &dyn Recording,
    cfg: &mut EstimatorConfig,
    init: InitMode,
) -> Result<(i64, Option<NavState>)> {
    let name = rec.name();
    let mut imu = rec.imu()?;
    let Some(first) = imu.next().transpose()? else {
        bail!("{name}: the dataset has no IMU samples");
    };
    let core_mode = match init {
        InitMode::Auto => povins_core::estimator::InitMode::Auto,
        InitMode::Static => povins_core::estimator::InitMode::Static,
        InitMode::Motion => povins_core::estimator::InitMode::Motion,
        InitMode::Groundtruth => cfg.init.mode,
    };
    if init != InitMode::Groundtruth {
        cfg.init.mode = core_mode;
        return Ok((first.t_ns, None));
    }
    let mut gt = rec.ground_truth_stream()?;
    let Some(g0) = gt.next().transpose()? else {
        bail!("{name}: --init groundtruth needs ground truth in the dataset");
    };
    let mut s0 = Some(first);
    while let Some(s) = s0.filter(|s| s.t_ns < g0.t_ns) {
        let _ = s;
        s0 = imu.next().transpose()?;
    }
    let Some(s0) = s0 else {
        bail!("{name}: no IMU sample after the first ground-truth state");
    };
    let mut cursor = GtCursor::new(std::iter::once(Ok(g0)).chain(gt));
    // After the last state: the last state (as `interpolate_state` clamps).
    let gt0 = cursor.at(s0.t_ns).or(cursor.last()).unwrap_or(g0);
    if let Some(e) = cursor.error() {
        return Err(e.into());
    }
    // The true state is known: the first keyframe's prior says so (peers do the same).
    cfg.first_prior.theta_rad = 2e-3;
    cfg.first_prior.v_mps = 0.01;
    cfg.first_prior.bg_rps = 1e-4;
    cfg.first_prior.ba_mps2 = 0.01;
    Ok((
        s0.t_ns,
        Some(NavState {
            t_ns: s0.t_ns,
            ..gt0
        }),
    ))
}

/// Most image errors kept with their message (the rest are counted).
const MAX_IMAGE_ERRORS: usize = 20;

/// Progress of a replay over the recording's time (whole seconds), or over IMU samples when the
/// recording's span is unknown.
pub struct ReplayProgress<'p> {
    progress: &'p Progress,
    t_first_ns: Option<i64>,
    samples: u64,
}

impl<'p> ReplayProgress<'p> {
    /// Sets up `progress` for a replay of `rec`.
    pub fn new(rec: &dyn Recording, progress: &'p Progress) -> Self {
        let span = rec.contents().imu_span_ns;
        if let Some((a, b)) = span {
            progress.set_length(u64::try_from((b - a) / 1_000_000_000).unwrap_or(0));
            progress.set_message("s of recording");
        }
        ReplayProgress {
            progress,
            t_first_ns: span.map(|s| s.0),
            samples: 0,
        }
    }

    /// Seconds of `t_ns` from the recording's first IMU sample (or of the stamp when the
    /// recording does not say).
    pub fn seconds(&self, t_ns: i64) -> f64 {
        (t_ns - self.t_first_ns.unwrap_or(0)) as f64 * 1e-9
    }

    /// A line above the bar.
    pub fn note(&self, line: &str) {
        self.progress.note(line);
    }

    /// An IMU sample at `t_ns` was read.
    pub fn imu(&mut self, t_ns: i64) {
        self.samples += 1;
        if self.samples.is_multiple_of(1000) {
            self.progress.set_position(match self.t_first_ns {
                Some(t0) => u64::try_from((t_ns - t0) / 1_000_000_000).unwrap_or(0),
                None => self.samples,
            });
        }
    }
}

/// Hands a replay's outputs to a [`RunSink`] (the driver's observer): keyframe states once
/// final, prediction errors per frame; counts the images that failed.
struct RunObserver<'s, 'p, S: RunSink> {
    sink: &'s mut S,
    window: KeyframeWindow,
    progress: ReplayProgress<'p>,
    /// One frame's prediction errors (reused).
    errors_px: Vec<f32>,
    image_failures: usize,
    image_errors: Vec<(i64, String)>,
    /// Stamp of the newest IMU-rate estimate, and of the last one before an outage.
    last_nav_ns: Option<i64>,
    lost_at_ns: Option<i64>,
    first_nav_ns: Option<i64>,
    /// Stamp of the newest IMU sample taken from the source.
    t_imu_ns: i64,
}

impl<'s, 'p, S: RunSink> RunObserver<'s, 'p, S> {
    fn new(sink: &'s mut S, rec: &dyn Recording, progress: &'p Progress) -> Self {
        RunObserver {
            sink,
            window: KeyframeWindow::default(),
            progress: ReplayProgress::new(rec, progress),
            errors_px: Vec::new(),
            image_failures: 0,
            image_errors: Vec::new(),
            last_nav_ns: None,
            lost_at_ns: None,
            first_nav_ns: None,
            t_imu_ns: 0,
        }
    }

    /// Tells the user when the estimates stop (a full reset: the estimator waits for a new
    /// initialization) and when they are back, with the time in between.
    fn watch_outage(&mut self, nav: Option<&NavState>, t_ns: i64) {
        match (nav, self.lost_at_ns) {
            (None, None) if self.last_nav_ns.is_some() => {
                self.lost_at_ns = self.last_nav_ns;
                let at = self.progress.seconds(t_ns);
                self.progress.note(&format!(
                    "estimator reset at {at:.3} s: no estimate until it initializes again"
                ));
            }
            (Some(n), Some(lost)) => {
                self.lost_at_ns = None;
                self.progress.note(&format!(
                    "estimator back at {:.3} s, {:.3} s after its last estimate",
                    self.progress.seconds(n.t_ns),
                    (n.t_ns - lost) as f64 * 1e-9
                ));
            }
            _ => {}
        }
        if let Some(n) = nav {
            self.last_nav_ns = Some(n.t_ns);
            self.first_nav_ns.get_or_insert(n.t_ns);
        }
    }

    /// Hands over the keyframes still in the window; the image failures (count, first ones) and
    /// the first estimate's stamp.
    fn finish(self) -> (usize, Vec<(i64, String)>, Option<i64>) {
        let sink = self.sink;
        self.window.finish(|s| sink.keyframe(s));
        (self.image_failures, self.image_errors, self.first_nav_ns)
    }
}

impl<S: RunSink> Observer for RunObserver<'_, '_, S> {
    fn imu(&mut self, t_ns: i64) {
        self.progress.imu(t_ns);
        self.t_imu_ns = t_ns;
    }

    fn output(&mut self, o: &Output<'_>) {
        if !o.nav_withheld {
            self.watch_outage(o.nav.as_ref(), self.t_imu_ns);
        }
        if let Some(jump_s) = o.clock_jump_s {
            if let Some(n) = &o.nav {
                self.sink.clock_jump(n.t_ns, (jump_s * 1e9).round() as i64);
            }
            let at = self.progress.seconds(self.t_imu_ns);
            self.progress.note(&format!(
                "clock jump of {jump_s:+.3} s in every stream at {at:.3} s: the images show \
                 nothing moved; the estimate goes on"
            ));
        }
        if let Some(gap_s) = o.gap_bridged_s {
            let at = self.progress.seconds(self.t_imu_ns);
            let withheld = if o.nav_withheld {
                "; the estimate is withheld until keyframes after it correct the INS"
            } else {
                ""
            };
            self.progress.note(&format!(
                "IMU gap of {gap_s:.3} s ending at {at:.3} s bridged{withheld}"
            ));
        }
        if let Some(k) = &o.keyframe {
            if let Some(why) = k.report.breakdown {
                let at = self.progress.seconds(self.t_imu_ns);
                self.progress.note(&format!(
                    "window re-initialized at {at:.3} s ({why:?}): the INS continues, a new window starts"
                ));
            }
            self.sink.report(&k.report, k.lidar_events);
            let sink = &mut *self.sink;
            self.window.step(k.window, |s| sink.keyframe(s));
        }
        if let Some(nav) = o.nav {
            self.sink.nav(&nav);
            if let Some(cov) = o.nav_covariance {
                self.sink.nav_covariance(&nav, cov);
            }
        }
    }

    fn frame(&mut self, f: &FrameOutput<'_>, image: Option<&ImageIn<'_>>) {
        self.errors_px.clear();
        prediction_errors(f.predictions, f.tracks, &mut self.errors_px);
        if !self.errors_px.is_empty() {
            self.sink.prediction_errors(&self.errors_px);
        }
        if let (Some(report), Some(im)) = (f.image, image) {
            self.sink.frame(&FrameLog::of(f.t_cam_ns, report, im));
        }
    }

    fn image_failed(&mut self, t_cam_ns: i64, why: String) {
        self.image_failures += 1;
        if self.image_errors.len() < MAX_IMAGE_ERRORS {
            self.image_errors.push((t_cam_ns, why));
        }
    }
}

/// Which keyframe states are final. Each keyframe's state is its value in the last window that
/// held it; the states are handed over in the order of their IMU stamps. A keyframe that left
/// the window waits while an older one is still in it (a window may drop a newer keyframe
/// first); new keyframes are newer than every one before, so the states older than the
/// window's oldest are final.
#[derive(Debug, Default)]
struct KeyframeWindow {
    /// The window after the last step, by IMU stamp.
    window: BTreeMap<i64, NavState>,
    /// Left the window, not yet handed over, by IMU stamp.
    left: BTreeMap<i64, NavState>,
}

impl KeyframeWindow {
    /// A keyframe step left `window`: hands the states now final to `emit`, oldest first.
    fn step(&mut self, window: &[KeyframeState], mut emit: impl FnMut(&NavState)) {
        let before = std::mem::take(&mut self.window);
        for kf in window {
            self.left.remove(&kf.state.t_ns);
            self.window.insert(kf.state.t_ns, kf.state);
        }
        for (t, s) in before {
            if !self.window.contains_key(&t) {
                self.left.insert(t, s);
            }
        }
        // Without a window (after a reset), wait: the next one may hold older keyframes.
        if let Some((&oldest, _)) = self.window.first_key_value() {
            let keep = self.left.split_off(&oldest);
            for s in std::mem::replace(&mut self.left, keep).values() {
                emit(s);
            }
        }
    }

    /// The run ended: hands over every state not handed over yet, oldest first.
    fn finish(mut self, mut emit: impl FnMut(&NavState)) {
        self.left.append(&mut self.window);
        for s in self.left.values() {
            emit(s);
        }
    }
}

/// Appends the pixel distance of each prediction to the observation of the same feature.
fn prediction_errors(predicted: &[FeaturePrediction], obs: &[FeatureObs], out: &mut Vec<f32>) {
    if predicted.is_empty() {
        return;
    }
    let mut by_id: Vec<(u64, f64, f64)> = obs.iter().map(|o| (o.id, o.u_px, o.v_px)).collect();
    by_id.sort_by_key(|o| o.0);
    for p in predicted {
        if let Ok(k) = by_id.binary_search_by_key(&p.id, |o| o.0) {
            let (_, u, v) = by_id[k];
            out.push((p.uv_px[0] - u).hypot(p.uv_px[1] - v) as f32);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::KeyframeWindow;
    use povins_core::inertial::NavState;
    use povins_core::odometry::KeyframeState;
    use std::collections::BTreeMap;

    fn kf(t_ns: i64, step: usize) -> KeyframeState {
        let mut state = NavState::ZERO;
        state.t_ns = t_ns;
        // Marks the step that optimized it: the last value must win.
        state.p_wb.x = step as f64;
        KeyframeState {
            t_cam_ns: t_ns,
            state,
            td_s: 0.0,
        }
    }

    #[test]
    fn keyframes_are_handed_over_once_final_in_stamp_order_at_their_last_value() {
        // A window of up to four keyframes; every third step drops the second-newest keyframe
        // (which then leaves before older ones), otherwise the oldest; one step with an empty
        // window (a reset).
        let mut window: Vec<i64> = Vec::new();
        let mut steps: Vec<Vec<KeyframeState>> = Vec::new();
        for k in 0..40_i64 {
            let t = 1_000 + 10 * k;
            if window.len() == 4 {
                let drop = if k % 3 == 0 { 2 } else { 0 };
                window.remove(drop);
            }
            window.push(t);
            if k == 25 {
                window.clear();
            }
            steps.push(window.iter().map(|&t| kf(t, steps.len())).collect());
        }
        // What a run collected: each keyframe's value in the last window holding it, by stamp.
        let mut want: BTreeMap<i64, NavState> = BTreeMap::new();
        for w in &steps {
            for k in w {
                want.insert(k.state.t_ns, k.state);
            }
        }
        let mut got: Vec<NavState> = Vec::new();
        let mut handed_during_run = 0;
        let mut kw = KeyframeWindow::default();
        for w in &steps {
            kw.step(w, |s| got.push(*s));
            handed_during_run = got.len();
            // Nothing still in the window was handed over.
            for k in w {
                assert!(got.iter().all(|s| s.t_ns != k.state.t_ns));
            }
        }
        kw.finish(|s| got.push(*s));
        let want: Vec<NavState> = want.into_values().collect();
        assert_eq!(got, want);
        // Most were handed over during the run, not kept to the end.
        assert!(handed_during_run >= want.len() - 5, "{handed_during_run}");
    }
}

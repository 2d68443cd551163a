//! The threaded onboard pipeline (`povins_platform::pipeline`) over a dataset: what
//! `povins replay --realtime` and `povins timing` run. The estimator starts exactly as in
//! [`crate::runner::replay_with`] (same configuration, same start, same input order, the same
//! front end: the dataset's tracks into `PoVins`, or its images through the pipeline's
//! front-end stage into the core's `Vio`), so in deterministic mode the published poses are
//! the replay's `imu_rate`, bit for bit.

use crate::progress::Progress;
use crate::runner::{start_state, Frontend, FrontendOptions, InitMode, VioDriver};
use anyhow::{bail, Context, Result};
use povins_core::estimator::EstimatorConfig;
use povins_core::vio::{EurocVio, HdVio};
use povins_platform::pipeline::{
    self, Backend, DatasetSource, Pacing, PipelineConfig, PipelineReport, Sink,
};
use povins_platform::Dataset;

/// How the pipeline runs over a dataset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealtimeOptions {
    /// Paced at the recorded rate (times a factor) or as fast as possible.
    pub pacing: Pacing,
    /// Lockstep: bit-identical to the single-threaded replay.
    pub deterministic: bool,
    /// Ask for `SCHED_FIFO` and locked memory (and say when not permitted).
    pub realtime_priority: bool,
}

/// The median interval between IMU samples of `ds`, ns (5 ms when it has fewer than two).
pub fn imu_period_ns(ds: &Dataset) -> u64 {
    let mut d: Vec<u64> = ds
        .imu
        .windows(2)
        .filter_map(|w| u64::try_from(w[1].t_ns - w[0].t_ns).ok())
        .collect();
    d.sort_unstable();
    d.get(d.len() / 2).copied().unwrap_or(5_000_000)
}

/// Runs `ds`'s feature tracks through the pipeline with the estimator configured by `cfg` (as
/// `povins run --frontend tracks` builds it) and started by `init`, publishing to `sink`;
/// `progress` counts IMU samples.
pub fn run_dataset<K: Sink + Send>(
    ds: &Dataset,
    cfg: EstimatorConfig,
    init: InitMode,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
) -> Result<PipelineReport> {
    run_dataset_with(
        ds,
        cfg,
        init,
        &FrontendOptions::tracks(),
        opts,
        sink,
        progress,
    )
}

/// [`run_dataset`] with the front end chosen in `fe` (as `povins run --frontend`): the
/// dataset's tracks, or its images through the pipeline's front-end stage (the core's `Vio`,
/// `EurocVio` up to 752x480, `HdVio` up to 1280x720). Errors when the chosen input is missing.
pub fn run_dataset_with<K: Sink + Send>(
    ds: &Dataset,
    cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
) -> Result<PipelineReport> {
    match fe.frontend {
        Frontend::Tracks => {
            if ds.features.is_empty() {
                bail!(
                    "{}: the pipeline's tracks front end needs feature tracks (features0, \
                     /cam0/features); {}",
                    ds.name,
                    if ds.images.is_empty() {
                        "the dataset has none"
                    } else {
                        "the dataset has camera images only: use --frontend images"
                    }
                );
            }
            run_with(
                ds,
                cfg,
                init,
                opts,
                sink,
                progress,
                |cfg| {
                    // Built in place on the heap (never on a stack, also in unoptimized builds);
                    // the pipeline's threads only borrow it and need the core's processing stack.
                    povins_platform::boxed::boxed_povins(cfg)
                        .map_err(|e| anyhow::anyhow!("invalid estimator configuration: {e}"))
                },
                false,
            )
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
            let (w, h) = (ds.calib.camera.width, ds.calib.camera.height);
            if w <= 752 && h <= 480 {
                run_with(
                    ds,
                    cfg,
                    init,
                    opts,
                    sink,
                    progress,
                    |cfg| vio::<EurocVio>(cfg, fe),
                    true,
                )
            } else if w <= 1280 && h <= 720 {
                run_with(
                    ds,
                    cfg,
                    init,
                    opts,
                    sink,
                    progress,
                    |cfg| vio::<HdVio>(cfg, fe),
                    true,
                )
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

/// A `Vio` built in place on the heap ([`VioDriver::build`]: `boxed_vio`) with `fe`'s aiding.
fn vio<V: VioDriver>(cfg: EstimatorConfig, fe: &FrontendOptions) -> Result<Box<V>> {
    let mut v = V::build(cfg, fe.tracker)?;
    v.aiding(fe.aiding);
    Ok(v)
}

/// Builds the back end with `build`, starts it as the replay does and runs the pipeline;
/// `images`: the source emits the dataset's images instead of its tracks.
#[allow(clippy::too_many_arguments)]
fn run_with<B, K>(
    ds: &Dataset,
    mut cfg: EstimatorConfig,
    init: InitMode,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
    build: impl FnOnce(EstimatorConfig) -> Result<Box<B>>,
    images: bool,
) -> Result<PipelineReport>
where
    B: Backend + VioInit + ?Sized,
    K: Sink + Send,
{
    let (start, gt_start) = start_state(ds, &mut cfg, init)?;
    let mut est = build(cfg)?;
    if let Some(s0) = gt_start {
        est.init_from(s0)
            .map_err(|e| anyhow::anyhow!("cannot initialize from ground truth: {e}"))?;
    }
    let t_start = ds.imu.get(start).map_or(i64::MAX, |s| s.t_ns);
    let mut source = DatasetSource::new(ds, t_start, cfg.lidar.td_l_s, opts.pacing);
    if images {
        source = source.with_images();
    }
    let pcfg = PipelineConfig {
        deterministic: opts.deterministic,
        imu_period_ns: imu_period_ns(ds),
        fifo_priority: opts.realtime_priority.then_some(80),
        lock_memory: opts.realtime_priority,
        announce: opts.realtime_priority,
        ..PipelineConfig::default()
    };
    let report = pipeline::run(&mut *est, source, sink, &pcfg, |n| {
        progress.set_position(start as u64 + n);
    })
    .context("pipeline")?;
    progress.finish();
    Ok(report)
}

/// Initialization from a known state, whichever back end.
pub trait VioInit {
    /// `Estimator::initialize`.
    fn init_from(&mut self, s0: povins_core::inertial::NavState) -> Result<(), povins_core::Error>;
}

impl VioInit for povins_core::estimator::PoVins {
    fn init_from(&mut self, s0: povins_core::inertial::NavState) -> Result<(), povins_core::Error> {
        self.initialize(s0)
    }
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> VioInit
    for povins_core::vio::Vio<10, 200, 166, F, BYTES, LEVELS>
{
    fn init_from(&mut self, s0: povins_core::inertial::NavState) -> Result<(), povins_core::Error> {
        self.estimator_mut().initialize(s0)
    }
}

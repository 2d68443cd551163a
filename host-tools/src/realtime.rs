//! The threaded onboard pipeline (`povins_platform::pipeline`) over a dataset: what
//! `povins replay --realtime` and `povins timing` run. The estimator starts exactly as in
//! [`crate::runner::replay`] (same configuration, same start, same input order), so in
//! deterministic mode the published poses are the replay's `imu_rate`, bit for bit.

use crate::progress::Progress;
use crate::runner::{start_state, InitMode};
use anyhow::{bail, Context, Result};
use povins_core::estimator::EstimatorConfig;
use povins_platform::pipeline::{
    self, DatasetSource, Pacing, PipelineConfig, PipelineReport, Sink,
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

/// Runs `ds` through the pipeline with the estimator configured by `cfg` (as `povins run`
/// builds it) and started by `init`, publishing to `sink`; `progress` counts IMU samples.
/// Needs feature tracks: the image front end does not run on the pipeline's back end yet.
pub fn run_dataset<K: Sink + Send>(
    ds: &Dataset,
    mut cfg: EstimatorConfig,
    init: InitMode,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
) -> Result<PipelineReport> {
    if ds.features.is_empty() {
        bail!(
            "{}: the pipeline needs feature tracks (features0, /cam0/features); {} \
             (the image front end, povins_core::vio::Vio, does not run on the pipeline's back-end \
             thread yet: use povins run for images)",
            ds.name,
            if ds.images.is_empty() {
                "the dataset has none"
            } else {
                "the dataset has camera images only"
            }
        );
    }
    let (start, gt_start) = start_state(ds, &mut cfg, init)?;
    // Built in place on the heap (never on a stack, also in unoptimized builds); the
    // pipeline's threads only borrow it and need the core's processing stack.
    let mut est = povins_platform::boxed::boxed_povins(cfg)
        .map_err(|e| anyhow::anyhow!("invalid estimator configuration: {e}"))?;
    if let Some(s0) = gt_start {
        est.initialize(s0)
            .map_err(|e| anyhow::anyhow!("cannot initialize from ground truth: {e}"))?;
    }
    let t_start = ds.imu.get(start).map_or(i64::MAX, |s| s.t_ns);
    let source = DatasetSource::new(ds, t_start, cfg.lidar.td_l_s, opts.pacing);
    let pcfg = PipelineConfig {
        deterministic: opts.deterministic,
        imu_period_ns: imu_period_ns(ds),
        fifo_priority: opts.realtime_priority.then_some(80),
        lock_memory: opts.realtime_priority,
        announce: opts.realtime_priority,
        ..PipelineConfig::default()
    };
    let report = pipeline::run(&mut est, source, sink, &pcfg, |n| {
        progress.set_position(start as u64 + n);
    })
    .context("pipeline")?;
    progress.finish();
    Ok(report)
}

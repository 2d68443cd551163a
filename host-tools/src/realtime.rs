//! The threaded onboard pipeline (`povins_platform::pipeline`) over a recording: what `povins
//! replay --realtime` and `povins timing` run. The odometry is built and started by the same
//! code as the single-threaded replay ([`crate::runner::start`]), the pipeline reads the same
//! source ([`MergedSource`]) and its back end calls the same driver step, so in deterministic
//! mode the published poses are the replay's `imu_rate`, bit for bit.

use crate::progress::Progress;
use crate::runner::{start, FrontendOptions, InitMode};
use anyhow::{Context, Result};
use povins_core::estimator::EstimatorConfig;
use povins_platform::pipeline::{self, Pacing, PipelineConfig, PipelineReport, Sink};
use povins_platform::recording::Recording;
use povins_platform::source::{MergeOptions, MergedSource};

/// How the pipeline runs over a recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealtimeOptions {
    /// Paced at the recorded rate (times a factor) or as fast as possible.
    pub pacing: Pacing,
    /// Lockstep: bit-identical to the single-threaded replay.
    pub deterministic: bool,
    /// Ask for `SCHED_FIFO` and locked memory (and say when not permitted).
    pub realtime_priority: bool,
    /// The continuous output's horizon, s (`None`: exact output).
    pub smooth_horizon_s: Option<f64>,
}

/// IMU samples read to find the IMU period.
const PERIOD_SAMPLES: usize = 2000;

/// The median interval between the first IMU samples of `rec`, ns (5 ms when it has fewer
/// than two).
pub fn imu_period_ns(rec: &dyn Recording) -> Result<u64> {
    let mut t: Vec<i64> = Vec::with_capacity(PERIOD_SAMPLES);
    for s in rec.imu()?.take(PERIOD_SAMPLES) {
        t.push(s?.t_ns);
    }
    let mut d: Vec<u64> = t
        .windows(2)
        .filter_map(|w| u64::try_from(w[1] - w[0]).ok())
        .collect();
    d.sort_unstable();
    Ok(d.get(d.len() / 2).copied().unwrap_or(5_000_000))
}

/// Runs `rec` through the pipeline with the estimator configured by `cfg` (as `povins run`
/// builds it), started by `init` and fed by the front end in `fe` (the recording's tracks, or
/// its images through the pipeline's back end), publishing to `sink`; `progress` counts IMU
/// samples. Errors when the chosen input is missing or the recording cannot be read.
pub fn run_dataset_with<K: Sink + Send>(
    rec: &dyn Recording,
    cfg: EstimatorConfig,
    init: InitMode,
    fe: &FrontendOptions,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
) -> Result<PipelineReport> {
    let td_l_s = cfg.lidar.td_l_s;
    let (mut odo, start_ns) = start(rec, cfg, init, fe)?;
    let merge = MergeOptions {
        start_ns,
        td_l_s,
        camera: fe.camera_input(),
        lidar: true,
        pacing: opts.pacing,
    };
    let source = MergedSource::new(rec, &merge)?;
    let imu_period_ns = imu_period_ns(rec)?;
    if let Some((a, b)) = rec.contents().imu_span_ns {
        let n = u64::try_from(b - a).unwrap_or(0) / imu_period_ns.max(1) + 1;
        progress.set_length(n);
    }
    let pcfg = PipelineConfig {
        deterministic: opts.deterministic,
        imu_period_ns,
        fifo_priority: opts.realtime_priority.then_some(80),
        lock_memory: opts.realtime_priority,
        announce: opts.realtime_priority,
        smooth_horizon_s: opts.smooth_horizon_s,
        ..PipelineConfig::default()
    };
    let report = pipeline::run(&mut *odo, source, sink, &pcfg, |n| {
        progress.set_position(n);
    })
    .with_context(|| format!("pipeline over {}", rec.name()))?;
    progress.finish();
    Ok(report)
}

/// [`run_dataset_with`] on the recording's feature tracks.
pub fn run_dataset<K: Sink + Send>(
    rec: &dyn Recording,
    cfg: EstimatorConfig,
    init: InitMode,
    opts: &RealtimeOptions,
    sink: &mut K,
    progress: &Progress,
) -> Result<PipelineReport> {
    run_dataset_with(
        rec,
        cfg,
        init,
        &FrontendOptions::tracks(),
        opts,
        sink,
        progress,
    )
}

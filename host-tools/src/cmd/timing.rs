//! `povins timing DATASET`: the onboard pipeline (`povins_platform::pipeline`: IMU and back-end
//! threads, pinned, `SCHED_FIFO` when permitted; the image front-end stage on the back-end
//! thread when the dataset has images) over a dataset, paced at the recorded rate by default,
//! then the timing table: per-stage p50/p99/p99.9/max (the front end's per-image decode and
//! processing time and its image-stamp -> track-frame latency included), IMU-output latency,
//! back-end lag against the keyframe period, deadline misses and drops (`--json` for a
//! machine-readable copy). `povins replay --realtime` runs the same pipeline and prints the
//! same table.

use crate::progress::Progress;
use crate::realtime::{imu_period_ns, run_dataset_with, RealtimeOptions};
use crate::runner::Frontend;
use crate::setup::{default_frontend, RunArgs, RunSetup};
use anyhow::Result;
use povins_platform::pipeline::{
    CallbackSink, Pacing, PipelineCounters, PipelineReport, PoseOut, RtStatus, Sink, StageSummary,
    STAGES,
};
use povins_platform::recording::Recording;

/// What both `povins timing` and `povins replay --realtime` take.
#[derive(clap::Args, Debug, Clone)]
pub struct PipelineArgs {
    /// The recording and how to run it (as for `povins run`; the image front end runs on the
    /// pipeline's back-end thread).
    #[command(flatten)]
    pub run: RunArgs,
    /// Pacing factor on the recorded rate (1: real time, 2: twice as fast); 0 runs as fast as
    /// possible.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Lockstep: the IMU thread waits for the back end at every sample (poses bit-identical to
    /// `povins run`'s trajectory.tum).
    #[arg(long)]
    pub deterministic: bool,
    /// Do not ask for SCHED_FIFO and locked memory.
    #[arg(long)]
    pub no_rt: bool,
    /// The continuous output for control: each estimator correction spread over
    /// --continuous-horizon-s instead of taken in one IMU step (README, "Continuous output").
    #[arg(long)]
    pub continuous: bool,
    /// The continuous output's horizon, s.
    #[arg(long, value_name = "S", default_value_t = povins_core::inertial::smooth::DEFAULT_HORIZON_S, requires = "continuous")]
    pub continuous_horizon_s: f64,
}

/// Arguments of `povins timing`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The pipeline's settings.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Print the figures as JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// The timing figures of a run (`--json`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct TimingSummary {
    /// Dataset name.
    pub dataset: String,
    /// Pacing factor (0: as fast as possible).
    pub speed: f64,
    /// Lockstep mode.
    pub deterministic: bool,
    /// `exact` or `continuous (horizon S s)`.
    pub output: String,
    /// The front end that fed the estimator.
    pub frontend: Frontend,
    /// IMU period, ms.
    pub imu_period_ms: f64,
    /// Median keyframe period, ms.
    pub keyframe_period_ms: Option<f64>,
    /// Per stage, in the order of the table.
    pub stages: Vec<(String, StageSummary)>,
    /// The keyframes' solve work (`[solve_budget] max_work`'s unit; machine- and
    /// load-independent): p50, p99, p99.9, max.
    pub solve_work: [u64; 4],
    /// Drops, misses.
    pub counters: PipelineCounters,
    /// Real-time settings granted.
    pub rt: RtStatus,
    /// Wall time, s.
    pub wall_s: f64,
}

impl TimingSummary {
    /// The figures of `report` on `rec`.
    pub fn new(rec: &dyn Recording, a: &PipelineArgs, report: &PipelineReport) -> Result<Self> {
        Ok(TimingSummary {
            dataset: rec.name().to_string(),
            speed: a.speed,
            deterministic: a.deterministic,
            output: if a.continuous {
                format!("continuous (horizon {} s)", a.continuous_horizon_s)
            } else {
                "exact".into()
            },
            frontend: a.run.frontend.unwrap_or(default_frontend(rec)),
            imu_period_ms: imu_period_ns(rec)? as f64 * 1e-6,
            keyframe_period_ms: report.keyframe_period_ns.map(|p| p as f64 * 1e-6),
            stages: STAGES
                .iter()
                .zip(report.timing.stages())
                .map(|(n, h)| (n.to_string(), h.summary_ms()))
                .collect(),
            solve_work: {
                let w = &report.timing.solve_work;
                if w.count() == 0 {
                    [0; 4]
                } else {
                    [
                        w.percentile_ns(50.0),
                        w.percentile_ns(99.0),
                        w.percentile_ns(99.9),
                        w.max_ns(),
                    ]
                }
            },
            counters: report.counters,
            rt: report.rt.clone(),
            wall_s: report.wall_s,
        })
    }

    /// The table's lines.
    pub fn lines(&self) -> Vec<String> {
        let c = &self.counters;
        let mut v = vec![
            format!(
                "pipeline  {} ({}, {}, {} front end), {:.1} s wall",
                self.dataset,
                if self.speed > 0.0 {
                    format!("paced x{}", self.speed)
                } else {
                    "as fast as possible".to_string()
                },
                if self.deterministic {
                    "deterministic"
                } else {
                    "real time"
                },
                match self.frontend {
                    Frontend::Images => "image",
                    Frontend::Tracks => "tracks",
                },
                self.wall_s
            ),
            format!("threads   {}", self.rt.summary()),
            format!(
                "{:<28} {:>8} {:>10} {:>10} {:>10} {:>10}",
                "stage", "count", "p50 ms", "p99 ms", "p99.9 ms", "max ms"
            ),
        ];
        for (name, s) in &self.stages {
            if s.count == 0 && (name.contains("image") || name.starts_with("front end")) {
                continue;
            }
            v.push(format!(
                "{name:<28} {:>8} {:>10.4} {:>10.4} {:>10.4} {:>10.4}",
                s.count, s.p50_ms, s.p99_ms, s.p999_ms, s.max_ms
            ));
        }
        let [w50, w99, w999, wmax] = self.solve_work;
        v.push(format!(
            "solve work per keyframe (machine-independent units of [solve_budget] max_work): p50 \
             {w50}, p99 {w99}, p99.9 {w999}, max {wmax} ({:.2}x the median)",
            wmax as f64 / w50.max(1) as f64
        ));
        v.push(format!(
            "samples   {} IMU, {} frames, {} images, {} sweeps in; {} poses out, {} keyframes",
            c.imu_in, c.frames_in, c.images_in, c.sweeps_in, c.poses_out, c.keyframes
        ));
        v.push(format!(
            "dropped   {} IMU, {} frames, {} images, {} sweeps (queue full); {} waits on the \
             back end; {} images not decodable or refused by the tracker",
            c.dropped_imu,
            c.dropped_frames,
            c.dropped_images,
            c.dropped_sweeps,
            c.backpressure_waits,
            c.image_failures
        ));
        v.push(format!(
            "misses    {} poses later than one IMU period ({:.2} ms) after arrival; {} back-end \
             samples lagging more than one keyframe period ({})",
            c.imu_deadline_misses,
            self.imu_period_ms,
            c.backend_lag_misses,
            self.keyframe_period_ms
                .map_or("n/a".to_string(), |p| format!("{p:.1} ms"))
        ));
        v.push(format!(
            "fast path {} updates too old for the ring, at most {} samples re-propagated by one",
            c.updates_too_old, c.max_replay
        ));
        let o = &c.output_steps;
        v.push(format!(
            "output    {}: largest correction {:.1} mm; steps departing from the IMU's motion: \
             max {:.1} mm, {} over 1 cm, {} over 5 cm",
            self.output,
            o.max_correction_m * 1e3,
            o.max_departure_m * 1e3,
            o.steps_over_1cm,
            o.steps_over_5cm
        ));
        v
    }
}

/// The options of a pipeline run from its arguments.
pub fn options(a: &PipelineArgs) -> RealtimeOptions {
    RealtimeOptions {
        pacing: if a.speed > 0.0 {
            Pacing::Recorded(a.speed)
        } else {
            Pacing::AsFastAsPossible
        },
        deterministic: a.deterministic,
        realtime_priority: !a.no_rt,
        smooth_horizon_s: a.continuous.then_some(a.continuous_horizon_s),
    }
}

/// Configures the estimator as `povins run` does and runs the pipeline over `rec`.
pub fn run_pipeline<K: Sink + Send>(
    a: &PipelineArgs,
    rec: &dyn Recording,
    sink: &mut K,
    label: &str,
) -> Result<PipelineReport> {
    run_pipeline_with(a, rec, sink, label, false)
}

/// [`run_pipeline`], with the estimator's covariance computed when `covariance` (whatever
/// the configuration says): a sink that sends it (MAVLink) asks for it.
pub fn run_pipeline_with<K: Sink + Send>(
    a: &PipelineArgs,
    rec: &dyn Recording,
    sink: &mut K,
    label: &str,
    covariance: bool,
) -> Result<PipelineReport> {
    let mut setup = RunSetup::from_args(rec, &a.run)?;
    setup.estimator.covariance |= covariance;
    let progress = Progress::new(0, label);
    run_dataset_with(
        rec,
        setup.estimator,
        setup.init,
        &setup.frontend,
        &options(a),
        sink,
        &progress,
    )
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let rec = args.pipeline.run.open()?;
    let mut sink = CallbackSink::poses(|_: &PoseOut| {});
    let report = run_pipeline(&args.pipeline, &*rec, &mut sink, "timing")?;
    let summary = TimingSummary::new(&*rec, &args.pipeline, &report)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        for line in summary.lines() {
            println!("{line}");
        }
    }
    Ok(())
}

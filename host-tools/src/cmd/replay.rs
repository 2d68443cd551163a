//! `povins replay --realtime DATASET --out DIR`: the onboard pipeline (see `povins timing`)
//! over a dataset, writing the IMU-rate poses it published to `DIR/trajectory.tum` and
//! printing the timing table (and, with `--mcap-out FILE`, an MCAP file of the poses for
//! Foxglove: [`McapSink`]). With `--deterministic` the trajectory is bit-identical to
//! `povins run`'s on the same input and settings, with either front end (`--frontend tracks`,
//! or `images`: the pipeline's image front-end stage).

use super::timing::{run_pipeline, PipelineArgs, TimingSummary};
use crate::eval::{evaluate, Alignment, EvalOptions};
use crate::realtime::imu_samples_estimate;
use anyhow::{bail, Context, Result};
use povins_platform::pipeline::{McapSink, TumSink};
use povins_platform::trajectory::StampedPose;
use std::path::PathBuf;

/// Arguments of `povins replay`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Run the threaded real-time pipeline (the only replay this command does; the
    /// single-threaded replay is `povins run`).
    #[arg(long)]
    pub realtime: bool,
    /// The pipeline's settings.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Output folder (created if missing).
    #[arg(long, default_value = "out/replay")]
    pub out: PathBuf,
    /// Also write the published poses to this MCAP file for Foxglove: `foxglove.PoseInFrame`
    /// (JSON) on /povins/pose at IMU rate and each keyframe's optimized state on
    /// /povins/keyframe.
    #[arg(long, value_name = "FILE")]
    pub mcap_out: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    if !args.realtime {
        bail!("povins replay needs --realtime (the single-threaded replay is povins run)");
    }
    let rec = args.pipeline.run.open()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let path = args.out.join("trajectory.tum");
    // Room for every pose up front: the sinks do not allocate on the IMU thread.
    let n = imu_samples_estimate(&*rec)?;
    let mcap = args.mcap_out.as_ref().map(|f| McapSink::new(f, n));
    let mut both = (TumSink::new(&path, n), mcap);
    let report = run_pipeline(&args.pipeline, &*rec, &mut both, "replay")?;
    let (sink, mcap) = both;
    for line in TimingSummary::new(&*rec, &args.pipeline, &report)?.lines() {
        println!("{line}");
    }
    let ground_truth = rec.ground_truth()?;
    if !ground_truth.is_empty() && !sink.poses().is_empty() {
        let gt: Vec<StampedPose> = ground_truth.iter().map(StampedPose::from).collect();
        let opts = EvalOptions {
            alignment: Alignment::PosYaw,
            ..Default::default()
        };
        match evaluate(&gt, sink.poses(), &opts) {
            Ok(r) => println!(
                "ATE       {:.4} m, {:.3} deg (posyaw-aligned, {} poses)",
                r.ate_pos_m.rmse, r.ate_rot_deg.rmse, r.matched_poses
            ),
            Err(e) => eprintln!("warning: evaluation failed: {e:#}"),
        }
    }
    println!("output    {}", path.display());
    if let (Some(m), Some(f)) = (&mcap, &args.mcap_out) {
        println!(
            "mcap      {} ({} poses, {} keyframes)",
            f.display(),
            m.poses().len(),
            m.keyframes().len()
        );
    }
    Ok(())
}

//! `povins replay --realtime DATASET --out DIR`: the onboard pipeline (see `povins timing`)
//! over a dataset, writing the IMU-rate poses it published to `DIR/trajectory.tum` and
//! printing the timing table. With `--deterministic` the trajectory is bit-identical to
//! `povins run`'s on the same input and settings (tracks front end).

use super::run::load_dataset;
use super::timing::{run_pipeline, PipelineArgs, TimingSummary};
use crate::eval::{evaluate, Alignment, EvalOptions};
use anyhow::{bail, Context, Result};
use povins_platform::pipeline::TumSink;
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
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    if !args.realtime {
        bail!("povins replay needs --realtime (the single-threaded replay is povins run)");
    }
    let ds = load_dataset(&args.pipeline.dataset)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let path = args.out.join("trajectory.tum");
    let mut sink = TumSink::new(&path, ds.imu.len());
    let report = run_pipeline(&args.pipeline, &ds, &mut sink, "replay")?;
    for line in TimingSummary::new(&ds, &args.pipeline, &report).lines() {
        println!("{line}");
    }
    if !ds.ground_truth.is_empty() && !sink.poses().is_empty() {
        let gt: Vec<StampedPose> = ds.ground_truth.iter().map(StampedPose::from).collect();
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
    Ok(())
}

//! `povins run <dataset> --out DIR`: replays an EuRoC folder or an MCAP file through the
//! estimator, fed by the image front end (`--frontend images`, the default when the dataset has
//! camera images; `frontend.csv` gets a row per image) or by the dataset's feature tracks
//! (`--frontend tracks`), and writes `trajectory.tum` (IMU rate), `keyframes.tum`, `stats.csv`
//! (a row per keyframe), `summary.json` and `config.toml` (the run's effective configuration,
//! every key; `--config` it to repeat the run); with ground truth in the dataset it also evaluates
//! (ATE, position + yaw alignment) and prints the result. LiDAR sweeps in the dataset are used
//! by default (`--no-lidar`, `--ldm`, `--no-depth-outlier-rejection`, `--no-depth-only-opt`
//! switch parts off); with simulator truth the LiDAR depth association is checked against it.

use crate::progress::Progress;
use crate::report::{print_summary, summarize, write_outputs};
use crate::setup::{RunArgs, RunSetup};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `povins run`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording and how to run it.
    #[command(flatten)]
    pub run: RunArgs,
    /// Output folder (created if missing).
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let rec = args.run.open()?;
    let setup = RunSetup::from_args(&*rec, &args.run)?;
    for note in setup.notes(&*rec, &args.run.lidar) {
        eprintln!("{note}");
    }
    let progress = Progress::new(0, "run");
    let out = setup.replay(&*rec, &progress)?;
    for (t, e) in &out.image_errors {
        eprintln!("warning: image at {t} ns: {e}");
    }
    for w in rec.warnings() {
        eprintln!("warning: {w}");
    }
    if out.image_failures > out.image_errors.len() {
        eprintln!(
            "warning: {} more images could not be used",
            out.image_failures - out.image_errors.len()
        );
    }
    let summary = summarize(&*rec, &setup.mode_name(), setup.init, &out)?;
    write_outputs(&args.out, &out, &summary)?;
    let path = args.out.join("config.toml");
    std::fs::write(&path, setup.effective_toml()?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    print_summary(&summary, &args.out);
    Ok(())
}

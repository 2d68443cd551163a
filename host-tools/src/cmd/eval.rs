//! `povins eval`: ATE and RTE of an estimated trajectory against ground truth.
//!
//! Both files may be TUM (`t x y z qx qy qz qw`) or EuRoC ground-truth CSV (auto-detected).
//! Prints a table, or one JSON object with `--json` (keys in [`crate::eval::report`]).

use crate::eval::{evaluate, Alignment, EvalOptions};
use anyhow::{Context, Result};
use povins_platform::trajectory::{read_trajectory, StampedPose};
use std::path::{Path, PathBuf};

/// Arguments of `povins eval`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Ground-truth trajectory (TUM or EuRoC CSV).
    #[arg(long)]
    pub gt: PathBuf,
    /// Estimated trajectory (TUM or EuRoC CSV).
    #[arg(long)]
    pub est: PathBuf,
    /// Transform fitted before measuring errors.
    #[arg(long, value_enum, default_value_t = Alignment::PosYaw)]
    pub align: Alignment,
    /// Largest stamp difference for a match, s.
    #[arg(long, default_value_t = 0.01)]
    pub t_max_diff: f64,
    /// Offset added to the estimate's stamps before matching, s.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub t_offset: f64,
    /// RTE segment lengths along the ground truth, m (comma-separated; empty for none).
    #[arg(long, value_delimiter = ',', default_value = "8,16,24,32,40")]
    pub segments: Vec<f64>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Reads a trajectory file, naming its role in the error.
pub fn read(role: &str, path: &Path) -> Result<Vec<StampedPose>> {
    read_trajectory(path)
        .with_context(|| format!("cannot read the {role} trajectory {}", path.display()))
}

/// The evaluation options the arguments ask for.
pub fn options(args: &Args) -> EvalOptions {
    EvalOptions {
        alignment: args.align,
        t_max_diff_s: args.t_max_diff,
        t_offset_s: args.t_offset,
        segments_m: args.segments.clone(),
    }
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let gt = read("ground-truth", &args.gt)?;
    let est = read("estimated", &args.est)?;
    let report = evaluate(&gt, &est, &options(&args)).with_context(|| {
        format!(
            "evaluating {} against {}",
            args.est.display(),
            args.gt.display()
        )
    })?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{report}");
    }
    Ok(())
}

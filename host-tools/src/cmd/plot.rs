//! `povins plot`: a figure of an estimate against ground truth (SVG or PNG by extension).

use crate::cmd::eval::read;
use crate::eval::{Alignment, EvalOptions};
use crate::plot::{plot, read_stats_csv};
use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `povins plot`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Ground-truth trajectory (TUM or EuRoC CSV).
    #[arg(long)]
    pub gt: PathBuf,
    /// Estimated trajectory (TUM or EuRoC CSV).
    #[arg(long)]
    pub est: PathBuf,
    /// Per-keyframe timing CSV with `t_s` and `backend_ms` columns.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Transform fitted before plotting.
    #[arg(long, value_enum, default_value_t = Alignment::PosYaw)]
    pub align: Alignment,
    /// Largest stamp difference for a match, s.
    #[arg(long, default_value_t = 0.01)]
    pub t_max_diff: f64,
    /// Offset added to the estimate's stamps before matching, s.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub t_offset: f64,
    /// Output file: `.svg` or `.png`.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let gt = read("ground-truth", &args.gt)?;
    let est = read("estimated", &args.est)?;
    let backend = args.stats.as_deref().map(read_stats_csv).transpose()?;
    let opts = EvalOptions {
        alignment: args.align,
        t_max_diff_s: args.t_max_diff,
        t_offset_s: args.t_offset,
        segments_m: Vec::new(),
    };
    let name = |p: &PathBuf| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    let title = format!("{} vs ground truth {}", name(&args.est), name(&args.gt));
    let report = plot(&gt, &est, &opts, backend.as_deref(), &title, &args.out)?;
    eprintln!(
        "wrote {} ({} matched poses, ATE {:.4} m rmse, {} aligned)",
        args.out.display(),
        report.matched_poses,
        report.ate_pos_m.rmse,
        report.alignment.name()
    );
    Ok(())
}

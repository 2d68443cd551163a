//! `povins plot`: a figure of an estimate against ground truth (SVG or PNG by extension), or of
//! the estimate alone when there is no ground truth (top view, height, speed, the delay per
//! keyframe from `--stats`).

use crate::cmd::eval::read;
use crate::eval::{Alignment, EvalOptions};
use crate::plot::{plot, read_stats_csv};
use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `povins plot`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Ground-truth trajectory (TUM or EuRoC CSV); without it the estimate is drawn alone.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Estimated trajectory (TUM or EuRoC CSV).
    #[arg(long)]
    pub est: PathBuf,
    /// Per-keyframe CSV with `t_s` and `backend_ms` columns (without ground truth: `td_ms` if
    /// present, else `backend_ms`).
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
    let est = read("estimated", &args.est)?;
    let Some(gt_path) = &args.gt else {
        let name = args.est.display().to_string();
        let f = crate::plot_estimate::plot_estimate(&est, args.stats.as_deref(), &name, &args.out)?;
        eprintln!(
            "wrote {} (no ground truth: {:.1} m in {:.1} s, speed median {:.2} m/s, p90 {:.2}, max {:.2}; height range {:.2} m; extent {:.2} x {:.2} m; start to end {:.2} m)",
            args.out.display(),
            f.length_m,
            f.duration_s,
            f.speed_median_mps,
            f.speed_p90_mps,
            f.speed_max_mps,
            f.height_range_m,
            f.extent_xy_m.0,
            f.extent_xy_m.1,
            f.start_end_m
        );
        return Ok(());
    };
    let gt = read("ground-truth", gt_path)?;
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
    let title = format!("{} vs ground truth {}", name(&args.est), name(gt_path));
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

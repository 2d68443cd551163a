//! `povins run <dataset> --out DIR`: replays an EuRoC folder (with `features0`) or an MCAP file
//! through the estimator and writes `trajectory.tum` (IMU rate), `keyframes.tum`, `stats.csv`
//! (a row per keyframe) and `summary.json`; with ground truth in the dataset it also evaluates
//! (ATE, position + yaw alignment) and prints the result.

use crate::config::{ModeArg, RunConfigFile};
use crate::eval::{evaluate, Alignment, EvalOptions};
use crate::progress::Progress;
use crate::runner::{config_for, percentile, replay, InitMode, RunOutput};
use anyhow::{Context, Result};
use povins_platform::trajectory::{write_tum, StampedPose};
use povins_platform::Dataset;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `povins run`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// EuRoC ASL folder (containing `mav0/`) or an `.mcap` file.
    pub dataset: PathBuf,
    /// Output folder (created if missing).
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Visual measurement model (overrides the config file).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// How to initialize.
    #[arg(long, value_enum, default_value = "static")]
    pub init: InitMode,
    /// TOML file of estimator settings (see the `config` module docs / docs/formats.md).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Loads a dataset from a folder (EuRoC) or an `.mcap` file.
pub fn load_dataset(path: &Path) -> Result<Dataset> {
    if path.is_dir() {
        Ok(povins_platform::euroc::read_dataset(path)?)
    } else if path.extension().is_some_and(|e| e == "mcap") {
        Ok(povins_platform::mcap_io::read_dataset(path)?)
    } else if !path.exists() {
        anyhow::bail!("dataset {} does not exist", path.display())
    } else {
        anyhow::bail!(
            "{}: expected an EuRoC folder or an .mcap file",
            path.display()
        )
    }
}

/// Accuracy and timing of one run, as written to `summary.json`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    /// Dataset name.
    pub dataset: String,
    /// Visual mode.
    pub mode: String,
    /// Initialization.
    pub init: InitMode,
    /// Keyframes processed.
    pub keyframes: usize,
    /// Camera frames in the dataset.
    pub camera_frames: usize,
    /// Back-end time per keyframe (marginalization + optimization + culling), ms.
    pub backend_ms_median: f64,
    /// 99th percentile, ms.
    pub backend_ms_p99: f64,
    /// Maximum, ms.
    pub backend_ms_max: f64,
    /// Mean, ms.
    pub backend_ms_mean: f64,
    /// Back-end time summed over the run divided by the camera frames, ms.
    pub backend_ms_per_camera_frame: f64,
    /// Whole estimator (INS, front-end bookkeeping, back end) per camera frame, ms.
    pub estimator_ms_per_camera_frame: f64,
    /// Median landmarks in the final solve of a keyframe.
    pub landmarks_used_median: f64,
    /// ATE of the IMU-rate trajectory, position RMSE, m (posyaw alignment).
    pub ate_pos_rmse_m: Option<f64>,
    /// ATE rotation RMSE, deg.
    pub ate_rot_rmse_deg: Option<f64>,
    /// ATE of the keyframe trajectory, position RMSE, m.
    pub keyframe_ate_pos_rmse_m: Option<f64>,
    /// Matched poses of the IMU-rate ATE.
    pub matched_poses: Option<usize>,
    /// Rejection counters of the core.
    pub counters: serde_json::Value,
}

/// Computes the summary of a run (and its evaluation when ground truth exists).
pub fn summarize(ds: &Dataset, mode: &str, init: InitMode, out: &RunOutput) -> Result<Summary> {
    let mut ms: Vec<f64> = out
        .reports
        .iter()
        .map(|r| r.total_ns as f64 * 1e-6)
        .collect();
    ms.sort_by(f64::total_cmp);
    let mut used: Vec<f64> = out
        .reports
        .iter()
        .map(|r| f64::from(r.landmarks_used))
        .collect();
    used.sort_by(f64::total_cmp);
    // `sum` of no f64 is -0.0; start from +0.0 so an empty run prints 0.000.
    let total_ms: f64 = 0.0 + ms.iter().sum::<f64>();
    let frames = out.camera_frames.max(1) as f64;
    let mut s = Summary {
        dataset: ds.name.clone(),
        mode: mode.to_string(),
        init,
        keyframes: out.reports.len(),
        camera_frames: out.camera_frames,
        backend_ms_median: percentile(&ms, 50.0),
        backend_ms_p99: percentile(&ms, 99.0),
        backend_ms_max: ms.last().copied().unwrap_or(0.0),
        backend_ms_mean: if ms.is_empty() {
            0.0
        } else {
            total_ms / ms.len() as f64
        },
        backend_ms_per_camera_frame: total_ms / frames,
        estimator_ms_per_camera_frame: out.estimator_wall_s * 1e3 / frames,
        landmarks_used_median: percentile(&used, 50.0),
        ate_pos_rmse_m: None,
        ate_rot_rmse_deg: None,
        keyframe_ate_pos_rmse_m: None,
        matched_poses: None,
        counters: serde_json::to_value(format!("{:?}", out.counters))?,
    };
    if !ds.ground_truth.is_empty() && !out.imu_rate.is_empty() {
        let gt: Vec<StampedPose> = ds.ground_truth.iter().map(StampedPose::from).collect();
        let est: Vec<StampedPose> = out.imu_rate.iter().map(StampedPose::from).collect();
        let opts = EvalOptions {
            alignment: Alignment::PosYaw,
            ..Default::default()
        };
        match evaluate(&gt, &est, &opts) {
            Ok(r) => {
                s.ate_pos_rmse_m = Some(r.ate_pos_m.rmse);
                s.ate_rot_rmse_deg = Some(r.ate_rot_deg.rmse);
                s.matched_poses = Some(r.matched_poses);
            }
            Err(e) => eprintln!("warning: evaluation failed: {e:#}"),
        }
        if let Ok(r) = evaluate(&gt, &out.keyframes, &opts) {
            s.keyframe_ate_pos_rmse_m = Some(r.ate_pos_m.rmse);
        }
    }
    Ok(s)
}

/// Writes the run's files into `dir`.
pub fn write_outputs(dir: &Path, out: &RunOutput, summary: &Summary) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let traj: Vec<StampedPose> = out.imu_rate.iter().map(StampedPose::from).collect();
    write_tum(&dir.join("trajectory.tum"), &traj)?;
    write_tum(&dir.join("keyframes.tum"), &out.keyframes)?;
    let path = dir.join("stats.csv");
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(&path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    writeln!(
        f,
        "t_s,backend_ms,solve_ms,marginalization_ms,window,landmarks_total,landmarks_used,observations,residual_rms_px,iterations,culled_chi2,culled_observations,culled_landmarks,disabled_landmarks,marginalized_rank_deficiency,prior_rank_deficiency,cost_initial,cost_final,decision,termination"
    )?;
    for r in &out.reports {
        writeln!(
            f,
            "{},{:.4},{:.4},{:.4},{},{},{},{},{:.4},{},{},{},{},{},{},{},{:.4},{:.4},{:?},{}",
            povins_platform::trajectory::ns_to_seconds_string(r.t_ns),
            r.total_ns as f64 * 1e-6,
            r.solve_ns as f64 * 1e-6,
            r.marginalization_ns as f64 * 1e-6,
            r.window_len,
            r.landmarks_total,
            r.landmarks_used,
            r.observations_used,
            r.residual_rms_px,
            r.iterations,
            r.culled_chi2,
            r.culled_observations,
            r.culled_landmarks,
            r.disabled_landmarks,
            r.marginalized_rank_deficiency,
            r.prior_rank_deficiency,
            r.cost.0,
            r.cost.1,
            r.decision,
            r.termination
                .map_or("none".to_string(), |t| format!("{t:?}")),
        )?;
    }
    f.flush()?;
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(summary)? + "\n",
    )?;
    Ok(())
}

/// Prints the human-readable result lines.
pub fn print_summary(s: &Summary, out_dir: &Path) {
    println!(
        "dataset   {} ({} mode, {:?} init)",
        s.dataset, s.mode, s.init
    );
    println!(
        "keyframes {} of {} camera frames",
        s.keyframes, s.camera_frames
    );
    if s.keyframes == 0 && s.init == InitMode::Static {
        eprintln!(
            "warning: the estimator never initialized: no static period met the static-init \
             thresholds (a vibrating platform needs looser ones, see [static_init] in \
             configs/euroc.toml), or start from the true state with --init groundtruth"
        );
    }
    match (s.ate_pos_rmse_m, s.ate_rot_rmse_deg) {
        (Some(p), Some(r)) => println!(
            "ATE       {p:.4} m, {r:.3} deg (posyaw-aligned, {} poses)",
            s.matched_poses.unwrap_or(0)
        ),
        _ => println!("ATE       n/a (no ground truth, or no estimate to compare)"),
    }
    println!(
        "back end  median {:.3} ms, p99 {:.3} ms, max {:.3} ms per keyframe; {:.3} ms per camera frame",
        s.backend_ms_median, s.backend_ms_p99, s.backend_ms_max, s.backend_ms_per_camera_frame
    );
    println!("output    {}", out_dir.display());
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let ds = load_dataset(&args.dataset)?;
    let mut cfg = config_for(&ds);
    if let Some(path) = &args.config {
        RunConfigFile::read(path)?.apply(&mut cfg);
    }
    if let Some(m) = args.mode {
        cfg.mode = m.into();
    }
    let mode = format!("{:?}", cfg.mode);
    let progress = Progress::new(ds.imu.len() as u64, "run");
    let out = replay(&ds, cfg, args.init, &progress)?;
    let summary = summarize(&ds, &mode, args.init, &out)?;
    write_outputs(&args.out, &out, &summary)?;
    print_summary(&summary, &args.out);
    Ok(())
}

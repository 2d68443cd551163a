//! `povins run <dataset> --out DIR`: replays an EuRoC folder or an MCAP file through the
//! estimator, fed by the image front end (`--frontend images`, the default when the dataset has
//! camera images; `frontend.csv` gets a row per image) or by the dataset's feature tracks
//! (`--frontend tracks`), and writes `trajectory.tum` (IMU rate), `keyframes.tum`, `stats.csv`
//! (a row per keyframe), `summary.json` and `config.toml` (the run's effective configuration,
//! every key; `--config` it to repeat the run); with ground truth in the dataset it also evaluates
//! (ATE, position + yaw alignment) and prints the result. LiDAR sweeps in the dataset are used
//! by default (`--no-lidar`, `--ldm`, `--no-depth-outlier-rejection`, `--no-depth-only-opt`
//! switch parts off); with simulator truth the LiDAR depth association is checked against it.

use crate::config::{effective_toml, ldm_name, LidarArgs, ModeArg, RunConfigFile};
use crate::eval::lidar_assoc::{self, AssocQuality};
use crate::eval::{evaluate, Alignment, EvalOptions};
use crate::frontend_stats::{summarize_frames, summary_lines, write_frames_csv, FrontendSummary};
use crate::progress::Progress;
use crate::runner::{
    config_for, percentile, replay_with, sorted_ms, Frontend, FrontendOptions, InitMode, RunOutput,
};
use anyhow::{Context, Result};
use povins_core::estimator::{EstimatorConfig, KeyframeReport};
use povins_core::frontend::image::TrackerConfig;
use povins_core::inertial::NavState;
use povins_core::vio::VioAiding;
use povins_platform::recording::Recording;
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
    /// What feeds the estimator: the camera images through povins' front end, or the
    /// dataset's feature tracks (default: images when the dataset has them, else tracks).
    #[arg(long, value_enum)]
    pub frontend: Option<Frontend>,
    /// LiDAR switches (override the config file).
    #[command(flatten)]
    pub lidar: LidarArgs,
}

/// The front end of a run: `--frontend` (or the dataset's default) and the `[frontend]`
/// section of `--config`.
pub fn frontend_options(
    config: Option<&Path>,
    frontend: Option<Frontend>,
    ds: &dyn Recording,
) -> Result<FrontendOptions> {
    let frontend = frontend.unwrap_or(if ds.contents().images {
        Frontend::Images
    } else {
        Frontend::Tracks
    });
    let mut tracker = TrackerConfig::default();
    let mut aiding = VioAiding::default();
    if let Some(path) = config {
        RunConfigFile::read(path)?.apply_frontend(&mut tracker, &mut aiding)?;
    }
    Ok(FrontendOptions {
        frontend,
        tracker,
        aiding,
    })
}

/// The estimator configuration of a run: dataset calibration, then `--config`, then the
/// command-line switches.
pub fn estimator_config(args: &Args, ds: &Dataset) -> Result<EstimatorConfig> {
    estimator_config_from(args.config.as_deref(), args.mode, &args.lidar, ds)
}

/// [`estimator_config`] from its parts (shared with `povins replay` and `povins timing`).
pub fn estimator_config_from(
    config: Option<&Path>,
    mode: Option<ModeArg>,
    lidar: &LidarArgs,
    ds: &Dataset,
) -> Result<EstimatorConfig> {
    let mut cfg = config_for(ds);
    if let Some(path) = config {
        RunConfigFile::read(path)?.apply(&mut cfg)?;
    }
    if let Some(m) = mode {
        cfg.mode = m.into();
    }
    lidar.apply(&mut cfg.lidar);
    Ok(cfg)
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
    /// What the window offers and uses, over the keyframes whose window holds at least two
    /// keyframes (see [`WindowUse`]).
    pub window_use: WindowUse,
    /// Camera-IMU delay of the last keyframe, ms.
    pub td_end_ms: f64,
    /// Factor on the IMU white-noise densities at the last keyframe (`estimator::imu_noise`).
    pub imu_noise_scale_end: f64,
    /// Feature prediction for INS-aided tracking: predicted features the next frame observes.
    pub predictions: usize,
    /// Their distance to the observation, median and 90th percentile, px.
    pub prediction_px_median: Option<f64>,
    /// See `prediction_px_median`.
    pub prediction_px_p90: Option<f64>,
    /// ATE of the IMU-rate trajectory, position RMSE, m (posyaw alignment).
    pub ate_pos_rmse_m: Option<f64>,
    /// ATE rotation RMSE, deg.
    pub ate_rot_rmse_deg: Option<f64>,
    /// ATE of the keyframe trajectory, position RMSE, m.
    pub keyframe_ate_pos_rmse_m: Option<f64>,
    /// Matched poses of the IMU-rate ATE.
    pub matched_poses: Option<usize>,
    /// LiDAR enhancement active: enabled and the dataset has LiDAR sweeps.
    pub lidar: bool,
    /// LiDAR-depth measurement model (`msc` or `direct`).
    pub ldm: String,
    /// Uncertainty-based rejection of LiDAR depths on.
    pub depth_outlier_rejection: bool,
    /// Depth-only optimization on.
    pub depth_only_opt: bool,
    /// LiDAR sweeps in the dataset.
    pub lidar_scans: usize,
    /// Mean LiDAR depths associated per keyframe.
    pub depths_associated_per_kf: f64,
    /// Mean LiDAR depths rejected per keyframe.
    pub depths_rejected_per_kf: f64,
    /// Mean landmarks with a LiDAR-depth measurement in the final solve, per keyframe.
    pub ldm_per_kf: f64,
    /// Depth association time per keyframe, median, ms.
    pub association_ms_median: f64,
    /// Uncertainty-based rejection time per keyframe, median, ms.
    pub rejection_ms_median: f64,
    /// Maximum, ms.
    pub rejection_ms_max: f64,
    /// Depth-only optimization time per keyframe, median, ms.
    pub depth_opt_ms_median: f64,
    /// Maximum, ms.
    pub depth_opt_ms_max: f64,
    /// Association quality against the simulator's truth (only with simulator truth).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub assoc: Option<AssocSummary>,
    /// What fed the estimator.
    pub frontend: Frontend,
    /// The image front end's figures (images only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image_frontend: Option<FrontendSummary>,
    /// Images that could not be read or were refused (images only).
    pub image_failures: usize,
    /// Rejection counters of the core.
    pub counters: serde_json::Value,
}

/// LiDAR association quality in `summary.json` (see [`lidar_assoc`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AssocSummary {
    /// Associated depths checked against the true depth.
    pub assoc_checked: usize,
    /// Share within `3 sigma_dr` of the true depth, all associated depths.
    pub assoc_within_3sigma_before: Option<f64>,
    /// Share within `3 sigma_dr`, depths not rejected later.
    pub assoc_within_3sigma_after: Option<f64>,
    /// Share of checked depths on the simulator's edge features.
    pub edge_share_before: Option<f64>,
    /// The same after rejection.
    pub edge_share_after: Option<f64>,
}

impl From<&AssocQuality> for AssocSummary {
    fn from(q: &AssocQuality) -> Self {
        AssocSummary {
            assoc_checked: q.checked,
            assoc_within_3sigma_before: q.within_3sigma_before(),
            assoc_within_3sigma_after: q.within_3sigma_after(),
            edge_share_before: q.edge_share_before(),
            edge_share_after: q.edge_share_after(),
        }
    }
}

/// How much of what the window offers reaches the solver: tracks with valid observations in at
/// least two of the window's keyframes ("multi-keyframe"), and how many of them and of their
/// observations the final solve of each keyframe used (a landmark's observations are its
/// residuals plus its anchor observation). Over the keyframes whose window holds at least two
/// keyframes.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct WindowUse {
    /// Keyframes counted.
    pub keyframes: usize,
    /// Multi-keyframe tracks the window offers, median per keyframe.
    pub offered_tracks_median: f64,
    /// Their observations, median per keyframe.
    pub offered_observations_median: f64,
    /// Landmarks in the final solve, median per keyframe.
    pub used_landmarks_median: f64,
    /// Observations in the final solve (residuals plus anchors), median per keyframe.
    pub used_observations_median: f64,
    /// Observations used over observations offered, summed over the keyframes (`None` when
    /// nothing was offered).
    pub observation_share: Option<f64>,
}

impl WindowUse {
    /// The figures of a run's keyframe reports.
    pub fn of(reports: &[KeyframeReport]) -> Self {
        let counted: Vec<&KeyframeReport> = reports.iter().filter(|r| r.window_len >= 2).collect();
        let median_of = |f: &dyn Fn(&KeyframeReport) -> u32| {
            let mut v: Vec<f64> = counted.iter().map(|r| f64::from(f(r))).collect();
            v.sort_by(f64::total_cmp);
            percentile(&v, 50.0)
        };
        let used = |r: &KeyframeReport| r.observations_used + r.landmarks_used;
        let offered: u64 = counted
            .iter()
            .map(|r| u64::from(r.multi_view_observations))
            .sum();
        let used_sum: u64 = counted.iter().map(|r| u64::from(used(r))).sum();
        WindowUse {
            keyframes: counted.len(),
            offered_tracks_median: median_of(&|r| r.multi_view_tracks),
            offered_observations_median: median_of(&|r| r.multi_view_observations),
            used_landmarks_median: median_of(&|r| r.landmarks_used),
            used_observations_median: median_of(&used),
            observation_share: (offered > 0).then(|| used_sum as f64 / offered as f64),
        }
    }

    /// The `window` line of `povins run`'s summary (`None` before the window held two keyframes).
    pub fn line(&self) -> Option<String> {
        let share = self.observation_share?;
        Some(format!(
            "window    used {:.0} of {:.0} multi-keyframe tracks and {:.0} of {:.0} of their \
             observations (medians per keyframe); {:.1}% of all offered observations",
            self.used_landmarks_median,
            self.offered_tracks_median,
            self.used_observations_median,
            self.offered_observations_median,
            100.0 * share
        ))
    }
}

/// Mean per keyframe of a report count.
fn per_kf(reports: &[KeyframeReport], f: impl Fn(&KeyframeReport) -> u32) -> f64 {
    if reports.is_empty() {
        return 0.0;
    }
    reports.iter().map(|r| f64::from(f(r))).sum::<f64>() / reports.len() as f64
}

/// Computes the summary of a run (and its evaluation when ground truth exists).
pub fn summarize(ds: &Dataset, mode: &str, init: InitMode, out: &RunOutput) -> Result<Summary> {
    let ms = sorted_ms(&out.reports, |r| r.backend_ns());
    let association_ms = sorted_ms(&out.reports, |r| r.association_ns);
    let rejection_ms = sorted_ms(&out.reports, |r| r.rejection_ns);
    let depth_opt_ms = sorted_ms(&out.reports, |r| r.depth_opt_ns);
    let mut used: Vec<f64> = out
        .reports
        .iter()
        .map(|r| f64::from(r.landmarks_used))
        .collect();
    used.sort_by(f64::total_cmp);
    let mut pred: Vec<f64> = out
        .prediction_err_px
        .iter()
        .map(|&e| f64::from(e))
        .collect();
    pred.sort_by(f64::total_cmp);
    let pred_pct = |p: f64| (!pred.is_empty()).then(|| percentile(&pred, p));
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
        window_use: WindowUse::of(&out.reports),
        td_end_ms: out.reports.last().map_or(0.0, |r| r.td_s * 1e3),
        imu_noise_scale_end: out.reports.last().map_or(1.0, |r| r.imu_noise_scale),
        predictions: pred.len(),
        prediction_px_median: pred_pct(50.0),
        prediction_px_p90: pred_pct(90.0),
        ate_pos_rmse_m: None,
        ate_rot_rmse_deg: None,
        keyframe_ate_pos_rmse_m: None,
        matched_poses: None,
        lidar: out.lidar.enabled && out.lidar_scans > 0,
        ldm: ldm_name(out.lidar.ldm).to_string(),
        depth_outlier_rejection: out.lidar.depth_outlier_rejection,
        depth_only_opt: out.lidar.depth_only_opt,
        lidar_scans: out.lidar_scans,
        depths_associated_per_kf: per_kf(&out.reports, |r| r.depths_associated),
        depths_rejected_per_kf: per_kf(&out.reports, |r| r.depths_rejected),
        ldm_per_kf: per_kf(&out.reports, |r| r.ldm_count),
        association_ms_median: percentile(&association_ms, 50.0),
        rejection_ms_median: percentile(&rejection_ms, 50.0),
        rejection_ms_max: rejection_ms.last().copied().unwrap_or(0.0),
        depth_opt_ms_median: percentile(&depth_opt_ms, 50.0),
        depth_opt_ms_max: depth_opt_ms.last().copied().unwrap_or(0.0),
        assoc: lidar_assoc::assess(ds, &out.lidar_events, out.lidar.sigma_dr_m)
            .map(|q| AssocSummary::from(&q)),
        frontend: out.frontend,
        image_frontend: summarize_frames(&out.frames),
        image_failures: out.image_failures,
        counters: serde_json::to_value(format!("{:?} {:?}", out.counters, out.vio_counters))?,
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

/// Writes whole navigation states in the EuRoC ground-truth column layout (so the files of a run
/// and the dataset's `state_groundtruth_estimate0/data.csv` compare column by column).
fn write_states_csv(path: &Path, states: &[NavState]) -> Result<()> {
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    writeln!(
        f,
        "#timestamp [ns],p_wb_x [m],p_wb_y [m],p_wb_z [m],q_wb_w [],q_wb_x [],q_wb_y [],q_wb_z [],v_wb_x [m s^-1],v_wb_y [m s^-1],v_wb_z [m s^-1],bg_x [rad s^-1],bg_y [rad s^-1],bg_z [rad s^-1],ba_x [m s^-2],ba_y [m s^-2],ba_z [m s^-2]"
    )?;
    for s in states {
        let q = s.q_wb.quaternion();
        write!(f, "{}", s.t_ns)?;
        for v in [s.p_wb.x, s.p_wb.y, s.p_wb.z, q.w, q.i, q.j, q.k]
            .into_iter()
            .chain(s.v_wb.iter().copied())
            .chain(s.bg.iter().copied())
            .chain(s.ba.iter().copied())
        {
            write!(f, ",{v:.9}")?;
        }
        writeln!(f)?;
    }
    f.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// The LiDAR columns appended to `stats.csv` (one row per keyframe).
pub const STATS_LIDAR_COLUMNS: &str =
    "lidar_points,depths_associated,depths_rejected,ldm_count,association_ms,rejection_ms,depth_opt_ms";

/// The landmark-admission columns appended to `stats.csv` (see `core::estimator::Admission`).
pub const STATS_ADMISSION_COLUMNS: &str =
    "adm_admitted,adm_single_view,adm_low_parallax,adm_bad_depth,adm_uncertain_depth,td_ms,multi_view_tracks,multi_view_observations,landmarks_promoted,landmarks_evicted,imu_noise_scale,prior_pos_std_m,prior_yaw_std_rad,window_correction_m,at_rest";

/// Writes the run's files into `dir`.
pub fn write_outputs(dir: &Path, out: &RunOutput, summary: &Summary) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let traj: Vec<StampedPose> = out.imu_rate.iter().map(StampedPose::from).collect();
    write_tum(&dir.join("trajectory.tum"), &traj)?;
    write_tum(&dir.join("keyframes.tum"), &out.keyframes)?;
    write_states_csv(&dir.join("keyframes_state.csv"), &out.keyframe_states)?;
    let path = dir.join("stats.csv");
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(&path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    writeln!(
        f,
        "t_s,backend_ms,solve_ms,marginalization_ms,window,landmarks_total,landmarks_used,observations,residual_rms_px,iterations,culled_chi2,culled_observations,culled_landmarks,disabled_landmarks,marginalized_rank_deficiency,prior_rank_deficiency,cost_initial,cost_final,decision,termination,{STATS_LIDAR_COLUMNS},{STATS_ADMISSION_COLUMNS}"
    )?;
    for r in &out.reports {
        writeln!(
            f,
            "{},{:.4},{:.4},{:.4},{},{},{},{},{:.4},{},{},{},{},{},{},{},{:.4},{:.4},{:?},{},{},{},{},{},{:.4},{:.4},{:.4},{},{},{},{},{},{:.4},{},{},{},{},{:.4},{:.6e},{:.6e},{:.6e},{}",
            povins_platform::trajectory::ns_to_seconds_string(r.t_ns),
            r.backend_ns() as f64 * 1e-6,
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
            r.lidar_points,
            r.depths_associated,
            r.depths_rejected,
            r.ldm_count,
            r.association_ns as f64 * 1e-6,
            r.rejection_ns as f64 * 1e-6,
            r.depth_opt_ns as f64 * 1e-6,
            r.admission.admitted,
            r.admission.single_view,
            r.admission.low_parallax,
            r.admission.bad_depth,
            r.admission.uncertain_depth,
            r.td_s * 1e3,
            r.multi_view_tracks,
            r.multi_view_observations,
            r.landmarks_promoted,
            r.landmarks_evicted,
            r.imu_noise_scale,
            r.prior_gauge_std.0,
            r.prior_gauge_std.1,
            r.window_correction_m,
            u8::from(r.at_rest),
        )?;
    }
    f.flush()?;
    if out.frontend == Frontend::Images {
        write_frames_csv(&dir.join("frontend.csv"), &out.frames)?;
    }
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(summary)? + "\n",
    )?;
    Ok(())
}

/// Prints the human-readable result lines.
pub fn print_summary(s: &Summary, out_dir: &Path) {
    println!(
        "dataset   {} ({} mode, {:?} init, {} front end)",
        s.dataset,
        s.mode,
        s.init,
        match s.frontend {
            Frontend::Images => "image",
            Frontend::Tracks => "tracks",
        }
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
    if let Some(line) = s.window_use.line() {
        println!("{line}");
    }
    println!(
        "imu       white-noise densities x{:.2} (measured by the window), delay td {:.2} ms at the end",
        s.imu_noise_scale_end, s.td_end_ms
    );
    if let Some(fe) = &s.image_frontend {
        for line in summary_lines(fe) {
            println!("{line}");
        }
    }
    if s.image_failures > 0 {
        println!(
            "images    {} could not be used (see the warnings)",
            s.image_failures
        );
    }
    if let (Some(m), Some(p90)) = (s.prediction_px_median, s.prediction_px_p90) {
        println!(
            "predict   {m:.2} px median, {p90:.2} px p90 from INS pose and landmark depths to the \
             tracked feature ({} features)",
            s.predictions
        );
    }
    for line in lidar_lines(s) {
        println!("{line}");
    }
    println!("output    {}", out_dir.display());
}

fn pct(x: Option<f64>) -> String {
    x.map_or("n/a".to_string(), |v| format!("{:.1}%", 100.0 * v))
}

/// The LiDAR lines of [`print_summary`].
pub fn lidar_lines(s: &Summary) -> Vec<String> {
    if s.lidar_scans == 0 {
        return vec!["LiDAR     none in the dataset".to_string()];
    }
    if !s.lidar {
        return vec![format!(
            "LiDAR     off ({} sweeps in the dataset ignored)",
            s.lidar_scans
        )];
    }
    let on = |b: bool| if b { "on" } else { "off" };
    let mut v = vec![
        format!(
            "LiDAR     {} sweeps, {} LDM, rejection {}, depth-only opt {}",
            s.lidar_scans,
            s.ldm.to_uppercase(),
            on(s.depth_outlier_rejection),
            on(s.depth_only_opt)
        ),
        format!(
            "depths    {:.1} associated, {:.1} rejected, {:.1} LDM per keyframe",
            s.depths_associated_per_kf, s.depths_rejected_per_kf, s.ldm_per_kf
        ),
        format!(
            "LiDAR ms  association {:.3}, rejection {:.3} (max {:.3}), depth-only opt {:.3} (max {:.3}) median per keyframe",
            s.association_ms_median,
            s.rejection_ms_median,
            s.rejection_ms_max,
            s.depth_opt_ms_median,
            s.depth_opt_ms_max
        ),
    ];
    if let Some(a) = &s.assoc {
        v.push(format!(
            "assoc     {} checked vs truth: {} within 3 sigma_dr before rejection, {} after; edge features {} -> {}",
            a.assoc_checked,
            pct(a.assoc_within_3sigma_before),
            pct(a.assoc_within_3sigma_after),
            pct(a.edge_share_before),
            pct(a.edge_share_after)
        ));
    }
    v
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let ds = load_dataset(&args.dataset)?;
    let cfg = estimator_config(&args, &ds)?;
    if ds.lidar.is_empty() && args.lidar.any() {
        eprintln!("note: no LiDAR in dataset; the LiDAR switches change nothing");
    }
    if !ds.lidar.is_empty() && ds.calib.t_bl.is_none() && !cfg.lidar.enabled {
        eprintln!(
            "note: the dataset has LiDAR sweeps but no LiDAR extrinsic T_bl, so LiDAR is off \
             (set lidar.enabled and lidar.extrinsic.p_bl / q_bl in the config to use it)"
        );
    }
    let fe = frontend_options(args.config.as_deref(), args.frontend, &ds)?;
    let mode = format!("{:?}", cfg.mode);
    let progress = Progress::new(ds.imu.len() as u64, "run");
    let out = replay_with(&ds, cfg, args.init, &fe, &progress)?;
    for (t, e) in &out.image_errors {
        eprintln!("warning: image at {t} ns: {e}");
    }
    if out.image_failures > out.image_errors.len() {
        eprintln!(
            "warning: {} more images could not be used",
            out.image_failures - out.image_errors.len()
        );
    }
    let summary = summarize(&ds, &mode, args.init, &out)?;
    write_outputs(&args.out, &out, &summary)?;
    let effective = effective_toml(&cfg, &fe.tracker, &fe.aiding)?;
    let path = args.out.join("config.toml");
    std::fs::write(&path, effective).with_context(|| format!("cannot write {}", path.display()))?;
    print_summary(&summary, &args.out);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::WindowUse;
    use povins_core::estimator::KeyframeReport;

    fn report(window_len: u32, offered: (u32, u32), used: (u32, u32)) -> KeyframeReport {
        KeyframeReport {
            window_len,
            multi_view_tracks: offered.0,
            multi_view_observations: offered.1,
            landmarks_used: used.0,
            observations_used: used.1,
            ..KeyframeReport::default()
        }
    }

    #[test]
    fn window_use_counts_anchors_and_skips_single_keyframe_windows() {
        let reports = [
            // A one-keyframe window offers nothing and must not dilute the figures.
            report(1, (0, 0), (0, 0)),
            report(2, (10, 30), (5, 10)),
            report(3, (20, 60), (10, 35)),
            report(4, (30, 90), (20, 60)),
        ];
        let w = WindowUse::of(&reports);
        assert_eq!(w.keyframes, 3);
        assert_eq!(w.offered_tracks_median, 20.0);
        assert_eq!(w.offered_observations_median, 60.0);
        assert_eq!(w.used_landmarks_median, 10.0);
        // Residuals plus one anchor observation per landmark: 15, 45, 80.
        assert_eq!(w.used_observations_median, 45.0);
        assert_eq!(w.observation_share, Some(140.0 / 180.0));
        let line = w.line().unwrap_or_default();
        assert!(
            line.contains("used 10 of 20 multi-keyframe tracks"),
            "{line}"
        );
        assert!(line.contains("77.8%"), "{line}");
        assert_eq!(WindowUse::of(&reports[..1]).line(), None);
    }
}

//! The files of a run's output folder: `trajectory.tum` (IMU rate), `keyframes.tum`,
//! `keyframes_state.csv`, `stats.csv` (a row per keyframe), `frontend.csv` (a row per image,
//! image front end only) and `summary.json`.

use super::Summary;
use crate::frontend_stats::write_frames_csv;
use crate::runner::{Frontend, RunOutput};
use anyhow::{Context, Result};
use povins_core::inertial::NavState;
use povins_platform::trajectory::{write_tum, StampedPose};
use std::io::Write;
use std::path::Path;

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

//! The files of a run's output folder: `trajectory.tum` (IMU rate), `keyframes.tum`,
//! `keyframes_state.csv`, `stats.csv` (a row per keyframe), `frontend.csv` (a row per image,
//! image front end only) and `summary.json`. Each row is formatted in one place, used both by
//! [`OutputFiles`] (what `povins run` streams while the run goes) and by [`write_outputs`] (a
//! collected run through the same writer).

use super::Summary;
use crate::frontend_stats::{write_frame_row, FRAMES_HEADER};
use crate::runner::{FrameLog, Frontend, RunOutput, RunSink};
use anyhow::{Context, Result};
use povins_core::estimator::{DepthEvent, KeyframeReport};
use povins_core::inertial::NavState;
use povins_core::math::Vec3;
use povins_platform::trajectory::{write_tum_header, write_tum_row, StampedPose};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The header of `keyframes_state.csv`: whole navigation states in the EuRoC ground-truth column
/// layout (so the files of a run and the dataset's `state_groundtruth_estimate0/data.csv`
/// compare column by column).
const STATES_HEADER: &str = "#timestamp [ns],p_wb_x [m],p_wb_y [m],p_wb_z [m],q_wb_w [],q_wb_x [],q_wb_y [],q_wb_z [],v_wb_x [m s^-1],v_wb_y [m s^-1],v_wb_z [m s^-1],bg_x [rad s^-1],bg_y [rad s^-1],bg_z [rad s^-1],ba_x [m s^-2],ba_y [m s^-2],ba_z [m s^-2]";

/// One row of `keyframes_state.csv` (columns in [`STATES_HEADER`]).
fn write_state_row(f: &mut impl Write, s: &NavState) -> std::io::Result<()> {
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
    writeln!(f)
}

/// The last row of a `keyframes_state.csv` (or of any file in its column layout, the EuRoC
/// ground truth's): its stamp (ns) and IMU biases `(gyro rad/s, accelerometer m/s^2)`, for
/// `--biases-from`. Errors name the file, the line and the column.
pub fn read_last_biases(path: &Path) -> Result<(i64, Vec3, Vec3)> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (line, row) = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'))
        .last()
        .with_context(|| format!("{}: no state row (only a header, or empty)", path.display()))?;
    let cols: Vec<&str> = row.split(',').map(str::trim).collect();
    anyhow::ensure!(
        cols.len() == 17,
        "{}:{}: {} columns, expected the 17 of keyframes_state.csv ({})",
        path.display(),
        line + 1,
        cols.len(),
        STATES_HEADER.trim_start_matches('#')
    );
    let t_ns: i64 = cols[0].parse().with_context(|| {
        format!(
            "{}:{}: column 1 (timestamp [ns]) is {:?}, not an integer",
            path.display(),
            line + 1,
            cols[0]
        )
    })?;
    let mut b = [0.0; 6];
    for (i, v) in b.iter_mut().enumerate() {
        let name = STATES_HEADER.split(',').nth(11 + i).unwrap_or("a bias");
        *v = cols[11 + i]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .with_context(|| {
                format!(
                    "{}:{}: column {} ({name}) is {:?}, not a finite number",
                    path.display(),
                    line + 1,
                    12 + i,
                    cols[11 + i]
                )
            })?;
    }
    Ok((
        t_ns,
        Vec3::new(b[0], b[1], b[2]),
        Vec3::new(b[3], b[4], b[5]),
    ))
}

/// The LiDAR columns appended to `stats.csv` (one row per keyframe): `lidar_cropped`,
/// `lidar_lost` and `lidar_thinned` are the points of the sweeps since the previous keyframe
/// that the crop to the camera's view dropped, that were lost younger than the association's
/// span, and that the thinning of a LiDAR too fast for the buffer dropped
/// (`KeyframeReport::lidar_points_cropped_total`, `lidar_points_lost_total`,
/// `lidar_points_thinned_total`).
pub const STATS_LIDAR_COLUMNS: &str =
    "lidar_points,depths_associated,depths_rejected,ldm_count,association_ms,rejection_ms,depth_opt_ms,lidar_cropped,lidar_lost,lidar_thinned";

/// The landmark-admission columns appended to `stats.csv` (see `core::estimator::Admission`).
pub const STATS_ADMISSION_COLUMNS: &str =
    "adm_admitted,adm_single_view,adm_low_parallax,adm_bad_depth,adm_uncertain_depth,td_ms,multi_view_tracks,multi_view_observations,landmarks_promoted,landmarks_evicted,imu_noise_scale,prior_pos_std_m,prior_yaw_std_rad,window_correction_m,at_rest,td_info_per_s2";

/// The camera-IMU extrinsic columns appended to `stats.csv`: `T_bc` after the keyframe's solve
/// (the estimate with `estimate_extrinsic`, else the configured one; empty when the window broke
/// down at that keyframe), then the estimate's marginal standard deviations
/// (`core::estimator::ExtrinsicSd`: translation along the body axes, rotation about the camera
/// axes; empty unless estimated).
pub const STATS_EXTRINSIC_COLUMNS: &str = "p_bc_x_m,p_bc_y_m,p_bc_z_m,q_bc_w,q_bc_x,q_bc_y,q_bc_z,p_bc_sd_x_m,p_bc_sd_y_m,p_bc_sd_z_m,r_bc_sd_x_rad,r_bc_sd_y_rad,r_bc_sd_z_rad";

/// The header of `stats.csv` (a row per keyframe).
fn stats_header() -> String {
    format!(
        "t_s,backend_ms,solve_ms,marginalization_ms,window,landmarks_total,landmarks_used,observations,residual_rms_px,iterations,culled_chi2,culled_observations,culled_landmarks,disabled_landmarks,marginalized_rank_deficiency,prior_rank_deficiency,cost_initial,cost_final,decision,termination,{STATS_LIDAR_COLUMNS},{STATS_ADMISSION_COLUMNS},{STATS_EXTRINSIC_COLUMNS},solve_work"
    )
}

/// One row of `stats.csv` (columns in [`stats_header`]); `prev` is the previous row's report
/// (the LiDAR drop counts are differences).
fn write_stats_row(
    f: &mut impl Write,
    r: &KeyframeReport,
    prev: Option<&KeyframeReport>,
) -> std::io::Result<()> {
    let since = |now: u64, then: Option<u64>| now.saturating_sub(then.unwrap_or(0));
    write!(
        f,
        "{},{:.4},{:.4},{:.4},{},{},{},{},{:.4},{},{},{},{},{},{},{},{:.4},{:.4},{:?},{},{},{},{},{},{:.4},{:.4},{:.4},{},{},{},{},{},{},{},{},{:.4},{},{},{},{},{:.4},{:.6e},{:.6e},{:.6e},{},{:.4e}",
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
        since(
            r.lidar_points_cropped_total,
            prev.map(|p| p.lidar_points_cropped_total)
        ),
        since(
            r.lidar_points_lost_total,
            prev.map(|p| p.lidar_points_lost_total)
        ),
        since(
            r.lidar_points_thinned_total,
            prev.map(|p| p.lidar_points_thinned_total)
        ),
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
        r.td_info_per_s2,
    )?;
    match &r.extrinsic {
        Some(e) => {
            let q = e.q_bc.quaternion();
            for v in [e.p_bc.x, e.p_bc.y, e.p_bc.z, q.w, q.i, q.j, q.k] {
                write!(f, ",{v:.9}")?;
            }
        }
        None => write!(f, ",,,,,,,")?,
    }
    match &r.extrinsic_sd {
        Some(sd) => {
            for v in sd.p_bc_m.iter().chain(&sd.r_bc_rad) {
                write!(f, ",{v:.6e}")?;
            }
        }
        None => write!(f, ",,,,,,")?,
    }
    writeln!(f, ",{}", r.solve_work)
}

/// Writes the files of a collected run into `dir`: [`OutputFiles`] fed with `out`.
pub fn write_outputs(dir: &Path, out: &RunOutput, summary: &Summary) -> Result<()> {
    let mut files = OutputFiles::create(dir, out.frontend)?;
    out.replay_into(&mut files);
    files.finish(summary)
}

/// One output file being written: `NAME.partial` in the folder until the run has ended.
struct OutputFile {
    path: PathBuf,
    partial: PathBuf,
    w: BufWriter<File>,
}

impl OutputFile {
    fn create(dir: &Path, name: &str) -> Result<Self> {
        let path = dir.join(name);
        let partial = dir.join(format!("{name}{PARTIAL}"));
        let f = File::create(&partial)
            .with_context(|| format!("cannot write {}", partial.display()))?;
        Ok(OutputFile {
            path,
            partial,
            w: BufWriter::new(f),
        })
    }
}

/// The suffix of the files of a run still going (or that failed).
pub const PARTIAL: &str = ".partial";

/// The files of a run's output folder, written row by row while the run goes (a [`RunSink`]):
/// each into `NAME.partial` until [`OutputFiles::finish`] writes `summary.json` and renames them
/// all to their names; a run that fails leaves the `.partial` files with the rows up to the
/// failure ([`OutputFiles::abandon`]), and any earlier run's complete files untouched. The
/// first write error stops the writing and is returned by `finish`.
pub struct OutputFiles {
    dir: PathBuf,
    trajectory: OutputFile,
    keyframes: OutputFile,
    states: OutputFile,
    stats: OutputFile,
    frontend: Option<OutputFile>,
    error: Option<anyhow::Error>,
    /// Rows written (headers aside).
    rows: u64,
    /// The previous keyframe's report (`stats.csv`'s LiDAR drop counts are differences).
    last_report: Option<KeyframeReport>,
}

impl OutputFiles {
    /// Creates `dir` (if missing) and the files with their headers (`frontend.csv` for the
    /// image front end only).
    pub fn create(dir: &Path, frontend: Frontend) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let mut files = OutputFiles {
            dir: dir.to_path_buf(),
            trajectory: OutputFile::create(dir, "trajectory.tum")?,
            keyframes: OutputFile::create(dir, "keyframes.tum")?,
            states: OutputFile::create(dir, "keyframes_state.csv")?,
            stats: OutputFile::create(dir, "stats.csv")?,
            frontend: match frontend {
                Frontend::Images => Some(OutputFile::create(dir, "frontend.csv")?),
                Frontend::Tracks => None,
            },
            error: None,
            rows: 0,
            last_report: None,
        };
        files.write(|f| Some(&mut f.trajectory), write_tum_header);
        files.write(|f| Some(&mut f.keyframes), write_tum_header);
        files.write(|f| Some(&mut f.states), |w| writeln!(w, "{STATES_HEADER}"));
        files.write(
            |f| Some(&mut f.stats),
            |w| writeln!(w, "{}", stats_header()),
        );
        files.write(|f| f.frontend.as_mut(), |w| writeln!(w, "{FRAMES_HEADER}"));
        files.rows = 0;
        match files.error.take() {
            Some(e) => Err(e),
            None => Ok(files),
        }
    }

    /// The files.
    fn all(&mut self) -> impl Iterator<Item = &mut OutputFile> {
        [
            Some(&mut self.trajectory),
            Some(&mut self.keyframes),
            Some(&mut self.states),
            Some(&mut self.stats),
            self.frontend.as_mut(),
        ]
        .into_iter()
        .flatten()
    }

    /// Writes `row` into the file `which` picks (if any) unless a write failed before; keeps
    /// the error, naming the file, otherwise.
    fn write(
        &mut self,
        which: impl FnOnce(&mut Self) -> Option<&mut OutputFile>,
        row: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
    ) {
        self.rows += 1;
        if self.error.is_some() {
            return;
        }
        let Some(f) = which(self) else {
            return;
        };
        let failed = row(&mut f.w).err().map(|e| {
            anyhow::Error::new(e).context(format!("cannot write {}", f.partial.display()))
        });
        self.error = failed;
    }

    /// Flushes every file.
    fn flush(&mut self) -> Result<()> {
        let mut first: Option<anyhow::Error> = self.error.take();
        for f in self.all() {
            if let Err(e) = f.w.flush() {
                let e =
                    anyhow::Error::new(e).context(format!("cannot write {}", f.partial.display()));
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// The run ended: writes `summary` and gives every file its name.
    pub fn finish(mut self, summary: &Summary) -> Result<()> {
        if let Err(e) = self.flush() {
            return Err(self.abandon(e));
        }
        let json = serde_json::to_string_pretty(summary)? + "\n";
        let mut summary_json = OutputFile::create(&self.dir, "summary.json")?;
        summary_json
            .w
            .write_all(json.as_bytes())
            .and_then(|()| summary_json.w.flush())
            .with_context(|| format!("cannot write {}", summary_json.partial.display()))?;
        let mut files: Vec<&mut OutputFile> = self.all().collect();
        files.push(&mut summary_json);
        for f in files {
            std::fs::rename(&f.partial, &f.path).with_context(|| {
                format!(
                    "cannot rename {} to {}",
                    f.partial.display(),
                    f.path.display()
                )
            })?;
        }
        Ok(())
    }

    /// The run failed with `e`: flushes what was written and adds where it is (the `.partial`
    /// files) to `e`, or removes the files when the run failed before its first output.
    pub fn abandon(mut self, e: anyhow::Error) -> anyhow::Error {
        let flushed = self.flush();
        if self.rows == 0 {
            for f in self.all() {
                // Header only: nothing of the run is lost with it.
                let _ = std::fs::remove_file(&f.partial);
            }
            return e;
        }
        let names: Vec<String> = self
            .all()
            .map(|f| {
                f.partial
                    .file_name()
                    .map_or(String::new(), |n| n.to_string_lossy().into_owned())
            })
            .collect();
        let mut note = format!(
            "the outputs up to the failure are in {} ({}; incomplete, no summary.json)",
            self.dir.display(),
            names.join(", ")
        );
        if let Err(w) = flushed {
            note += &format!("; writing them failed too: {w:#}");
        }
        e.context(note)
    }
}

impl RunSink for OutputFiles {
    fn nav(&mut self, s: &NavState) {
        let p = StampedPose::from(s);
        self.write(|f| Some(&mut f.trajectory), |w| write_tum_row(w, &p));
    }

    fn report(&mut self, r: &KeyframeReport, _lidar_events: &[DepthEvent]) {
        let prev = self.last_report.replace(*r);
        self.write(
            |f| Some(&mut f.stats),
            |w| write_stats_row(w, r, prev.as_ref()),
        );
    }

    fn keyframe(&mut self, s: &NavState) {
        let p = StampedPose::from(s);
        self.write(|f| Some(&mut f.keyframes), |w| write_tum_row(w, &p));
        self.write(|f| Some(&mut f.states), |w| write_state_row(w, s));
    }

    fn frame(&mut self, fr: &FrameLog) {
        self.write(|f| f.frontend.as_mut(), |w| write_frame_row(w, fr));
    }

    fn prediction_errors(&mut self, _e_px: &[f32]) {}
}

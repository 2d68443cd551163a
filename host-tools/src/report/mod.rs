//! What a run reports: the summary (`summary.json`, the evaluation against ground truth and the
//! LiDAR association against the simulator's truth), the files of its output folder
//! ([`files`]) and the lines `povins run` prints ([`text`]). `povins run`, `demo`, `ablation` and
//! the tests all report through here.

mod digest;
pub mod faults;
pub mod files;
pub mod spill;
pub mod text;
mod window_use;

pub use digest::RunDigest;
pub use files::{
    write_outputs, OutputFiles, STATS_ADMISSION_COLUMNS, STATS_EXTRINSIC_COLUMNS,
    STATS_LIDAR_COLUMNS,
};
pub use text::{lidar_lines, print_summary};
pub use window_use::WindowUse;

use crate::config::ldm_name;
use crate::eval::lidar_assoc::{self, AssocQuality};
use crate::eval::nees;
use crate::eval::streamed::{ate_rmse, AteRmse, PoseStream};
use crate::eval::{Alignment, EvalOptions};
use crate::frontend_stats::FrontendSummary;
use crate::runner::{percentile, Frontend, GtCursor, InitMode, RunOutput, RunTotals};
use anyhow::Result;
use povins_core::inertial::NavState;
use povins_core::math::Vec3;
use povins_platform::recording::Recording;
use povins_platform::trajectory::StampedPose;
use spill::PoseLog;

/// The extrinsic estimated online at the end of a run ([`Summary::extrinsic_end`]): `T_bc` and
/// its marginal standard deviations (`core::estimator::ExtrinsicSd`: translation along the body
/// axes, rotation about the camera axes).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ExtrinsicEnd {
    /// Camera origin in the body frame, m.
    pub p_bc_m: [f64; 3],
    /// Rotation camera -> body, quaternion `[x, y, z, w]`.
    pub q_bc_xyzw: [f64; 4],
    /// Standard deviations of `p_bc`, m.
    pub p_bc_sd_m: [f64; 3],
    /// Standard deviations of the rotation, rad.
    pub r_bc_sd_rad: [f64; 3],
}

impl ExtrinsicEnd {
    fn new(
        e: &povins_core::camera::CameraExtrinsic,
        sd: &povins_core::estimator::ExtrinsicSd,
    ) -> Self {
        let q = e.q_bc.quaternion();
        ExtrinsicEnd {
            p_bc_m: [e.p_bc.x, e.p_bc.y, e.p_bc.z],
            q_bc_xyzw: [q.i, q.j, q.k, q.w],
            p_bc_sd_m: sd.p_bc_m,
            r_bc_sd_rad: sd.r_bc_rad,
        }
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
    /// Which initializer started the run: `static`, `motion` (both, joined by `+`, after a
    /// reset), `groundtruth`, or none.
    pub started_by: Option<String>,
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
    /// The work of a keyframe's solve (`solve_work` of `stats.csv`, the unit of
    /// `[solve_budget] max_work`), median.
    pub solve_work_median: u32,
    /// Maximum.
    pub solve_work_max: u32,
    /// Whole estimator (INS, front-end bookkeeping, back end) per camera frame, ms.
    pub estimator_ms_per_camera_frame: f64,
    /// Median landmarks in the final solve of a keyframe.
    pub landmarks_used_median: f64,
    /// What the window offers and uses, over the keyframes whose window holds at least two
    /// keyframes (see [`WindowUse`]).
    pub window_use: WindowUse,
    /// Camera-IMU delay of the last keyframe, ms.
    pub td_end_ms: f64,
    /// The camera-IMU extrinsic estimated online at the last keyframe that had it, with its
    /// deviations (`null` unless `estimate_extrinsic = true`).
    pub extrinsic_end: Option<ExtrinsicEnd>,
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
    /// The IMU-rate velocity's NEES against the ground truth (`covariance = true` only; see
    /// [`crate::eval::nees`]).
    pub velocity_nees: Option<nees::Nees>,
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
    /// Time from the first camera frame to the first IMU-rate estimate, s (negative: the
    /// estimator started before the camera, e.g. from ground truth or at rest).
    pub start_after_camera_s: Option<f64>,
    /// Share of the ground-truth stamps from the first camera frame on with an IMU-rate pose
    /// within [`COVERAGE_TOLERANCE_NS`] (with ground truth).
    pub coverage: Option<f64>,
    /// Share of the input's time, from the first camera frame (the first IMU sample without a
    /// camera) to the last IMU sample, covered by IMU-rate poses: poses at most
    /// [`COVERAGE_TOLERANCE_NS`] apart cover the time between them; a longer gap is uncovered.
    /// The time a clock jump skipped is no input's (not counted). Defined without ground truth
    /// too.
    pub input_coverage: Option<f64>,
    /// The estimator's counters (`resets`, `reinitializations`, rejections: see
    /// `povins_core::estimator::Counters`), and the image front end's under `front_end`.
    pub counters: serde_json::Value,
}

/// How far an estimate's stamp may be from a ground-truth stamp to cover it, ns.
pub const COVERAGE_TOLERANCE_NS: i64 = 10_000_000;

/// Adds an estimate's stamp to the spans of time its poses cover: consecutive poses at most
/// [`COVERAGE_TOLERANCE_NS`] apart extend a span (first and last stamp); a longer gap, or a stamp
/// that goes back, starts a new one.
pub fn extend_spans(spans: &mut Vec<(i64, i64)>, t_ns: i64) {
    match spans.last_mut() {
        Some((_, end)) if t_ns >= *end && t_ns - *end <= COVERAGE_TOLERANCE_NS => *end = t_ns,
        _ => spans.push((t_ns, t_ns)),
    }
}

/// The spans of [`extend_spans`] of a whole estimate.
pub fn spans_of(est: &[StampedPose]) -> Vec<(i64, i64)> {
    let mut spans = Vec::new();
    for p in est {
        extend_spans(&mut spans, p.t_ns);
    }
    spans
}

/// Share of the ground truth's stamps (increasing) at or after `from_ns` with an estimate
/// within [`COVERAGE_TOLERANCE_NS`], the estimate given by the spans its poses cover
/// ([`extend_spans`], increasing): a stamp is covered when it lies within the tolerance of a
/// span, which is when a pose lies within the tolerance of it. `None` without such ground truth;
/// the stream's error, if it fails.
pub fn coverage<E>(
    gt_t_ns: impl IntoIterator<Item = Result<i64, E>>,
    spans: &[(i64, i64)],
    from_ns: i64,
) -> Result<Option<f64>, E> {
    let (mut n, mut covered, mut k) = (0usize, 0usize, 0usize);
    for t in gt_t_ns {
        let t = t?;
        if t < from_ns {
            continue;
        }
        n += 1;
        while spans
            .get(k)
            .is_some_and(|s| s.1 + COVERAGE_TOLERANCE_NS < t)
        {
            k += 1;
        }
        covered += usize::from(
            spans
                .get(k)
                .is_some_and(|s| s.0 - COVERAGE_TOLERANCE_NS <= t),
        );
    }
    Ok((n > 0).then(|| covered as f64 / n as f64))
}

/// Share of `from_ns..to_ns`, less the `skipped` spans (a clock jump's: no input in them), inside
/// the `spans` (sorted, disjoint; none in a skipped span); `None` for an empty input.
pub fn input_coverage(
    spans: &[(i64, i64)],
    skipped: &[(i64, i64)],
    from_ns: i64,
    to_ns: i64,
) -> Option<f64> {
    let within = |v: &[(i64, i64)]| -> i64 {
        v.iter()
            .map(|&(a, b)| (b.min(to_ns) - a.max(from_ns)).max(0))
            .sum()
    };
    let total = (to_ns - from_ns) - within(skipped);
    (total > 0).then(|| within(spans) as f64 / total as f64)
}

impl Summary {
    /// The coverage a run is judged by: against the ground truth when the recording has it
    /// ([`Summary::coverage`]), else of the input's time ([`Summary::input_coverage`]); with
    /// its name.
    pub fn judged_coverage(&self) -> Option<(f64, &'static str)> {
        match (self.coverage, self.input_coverage) {
            (Some(c), _) => Some((c, "of the ground truth from the first camera frame on")),
            (None, Some(c)) => Some((c, "of the input's time from the first camera frame on")),
            _ => None,
        }
    }

    /// Why a run with camera frames gave no keyframe (see [`never_started_reason`]).
    pub fn never_started_reason(&self) -> String {
        never_started_reason(
            self.init,
            self.camera_frames,
            self.image_failures,
            &self.counters,
        )
    }
}

/// Why a run with camera frames gave no keyframe (the one place this is decided): every image
/// refused, or the initializers' refusals with their counts (`counters` as `summary.json` has
/// them).
pub fn never_started_reason(
    init: InitMode,
    camera_frames: usize,
    image_failures: usize,
    counters: &serde_json::Value,
) -> String {
    let n = |k: &str| counters[k].as_u64().unwrap_or(0);
    let motion = || {
        let kinds = [
            ("tracks", "too few tracks"),
            ("parallax", "too little parallax"),
            ("conditioning", "no excitation or ill-conditioned"),
            ("gravity", "gravity norm off"),
            ("residual", "large residuals"),
        ];
        let parts: Vec<String> = kinds
            .iter()
            .filter_map(|(k, what)| {
                let c = n(&format!("motion_init_refused_{k}"));
                (c > 0).then(|| format!("{what} {c}"))
            })
            .collect();
        if parts.is_empty() {
            "no in-motion start was tried (too few init frames with tracks)".to_string()
        } else {
            format!(
                "every in-motion start was refused: {} (summary.json counters \
                     motion_init_refused_*)",
                parts.join(", ")
            )
        }
    };
    let rest = "no static period met the static-init thresholds";
    match init {
        _ if image_failures >= camera_frames && camera_frames > 0 => {
            "every image was refused, see the warnings".to_string()
        }
        InitMode::Static => rest.to_string(),
        InitMode::Motion => motion(),
        InitMode::Auto => format!("{rest}, and {}", motion()),
        InitMode::Groundtruth => {
            "started from the ground truth, no camera frame became a keyframe".to_string()
        }
    }
}

/// The counters as `summary.json` carries them.
fn counters_json(t: &RunTotals) -> Result<serde_json::Value> {
    let mut v = serde_json::to_value(t.counters)?;
    if let Some(m) = v.as_object_mut() {
        m.insert("front_end".into(), serde_json::to_value(t.vio_counters)?);
    }
    Ok(v)
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

/// Computes the summary of a run collected in memory (and its evaluation when ground truth
/// exists): [`summarize_digest`] of the run's [`RunDigest`].
pub fn summarize(
    rec: &dyn Recording,
    mode: &str,
    init: InitMode,
    out: &RunOutput,
) -> Result<Summary> {
    let mut digest = RunDigest::keeping_all();
    out.replay_into(&mut digest);
    summarize_digest(rec, mode, init, digest, &out.totals())
}

/// Computes the summary of a run from its digest and totals (and its evaluation when ground
/// truth exists and the digest kept the poses).
pub fn summarize_digest(
    rec: &dyn Recording,
    mode: &str,
    init: InitMode,
    mut d: RunDigest,
    t: &RunTotals,
) -> Result<Summary> {
    // Unstable sorts: no scratch buffer, and under `total_cmp` equal elements are the same bits,
    // so the order is the stable sort's.
    let sorted = |v: &mut Vec<f64>| v.sort_unstable_by(f64::total_cmp);
    let take = std::mem::take::<Vec<f64>>;
    let (mut ms, mut association_ms) = (take(&mut d.backend_ms), take(&mut d.association_ms));
    let (mut rejection_ms, mut depth_opt_ms) =
        (take(&mut d.rejection_ms), take(&mut d.depth_opt_ms));
    for v in [
        &mut ms,
        &mut association_ms,
        &mut rejection_ms,
        &mut depth_opt_ms,
    ] {
        sorted(v);
    }
    d.landmarks_used.sort_unstable();
    d.solve_work.sort_unstable();
    let work_at = |q: usize| d.solve_work.get(q).copied().unwrap_or(0);
    let (solve_work_median, solve_work_max) = (
        work_at(d.solve_work.len() / 2),
        work_at(d.solve_work.len().saturating_sub(1)),
    );
    let pred = &d.prediction_px;
    // `sum` of no f64 is -0.0; start from +0.0 so an empty run prints 0.000.
    let total_ms: f64 = 0.0 + ms.iter().sum::<f64>();
    let frames = t.camera_frames.max(1) as f64;
    let keyframes = ms.len();
    let per_kf = |sum: f64| {
        if keyframes == 0 {
            0.0
        } else {
            sum / keyframes as f64
        }
    };
    let mut s = Summary {
        dataset: rec.name().to_string(),
        mode: mode.to_string(),
        init,
        started_by: None,
        keyframes,
        camera_frames: t.camera_frames,
        backend_ms_median: percentile(&ms, 50.0),
        backend_ms_p99: percentile(&ms, 99.0),
        backend_ms_max: ms.last().copied().unwrap_or(0.0),
        backend_ms_mean: if ms.is_empty() {
            0.0
        } else {
            total_ms / ms.len() as f64
        },
        backend_ms_per_camera_frame: total_ms / frames,
        solve_work_median,
        solve_work_max,
        estimator_ms_per_camera_frame: t.estimator_wall_s * 1e3 / frames,
        landmarks_used_median: percentile(&d.landmarks_used, 50.0),
        window_use: d.window_use.figures(),
        td_end_ms: d.last.map_or(0.0, |(td_s, _)| td_s * 1e3),
        extrinsic_end: d.last_extrinsic,
        imu_noise_scale_end: d.last.map_or(1.0, |(_, scale)| scale),
        predictions: pred.len(),
        prediction_px_median: pred.percentile(50.0),
        prediction_px_p90: pred.percentile(90.0),
        ate_pos_rmse_m: None,
        ate_rot_rmse_deg: None,
        keyframe_ate_pos_rmse_m: None,
        velocity_nees: None,
        matched_poses: None,
        lidar: t.lidar.enabled && t.lidar_scans > 0,
        ldm: ldm_name(t.lidar.ldm).to_string(),
        depth_outlier_rejection: t.lidar.depth_outlier_rejection,
        depth_only_opt: t.lidar.depth_only_opt,
        lidar_scans: t.lidar_scans,
        depths_associated_per_kf: per_kf(d.depth_sums[0]),
        depths_rejected_per_kf: per_kf(d.depth_sums[1]),
        ldm_per_kf: per_kf(d.depth_sums[2]),
        association_ms_median: percentile(&association_ms, 50.0),
        rejection_ms_median: percentile(&rejection_ms, 50.0),
        rejection_ms_max: rejection_ms.last().copied().unwrap_or(0.0),
        depth_opt_ms_median: percentile(&depth_opt_ms, 50.0),
        depth_opt_ms_max: depth_opt_ms.last().copied().unwrap_or(0.0),
        assoc: None,
        frontend: t.frontend,
        image_frontend: d.frames.summary(),
        image_failures: t.image_failures,
        start_after_camera_s: t
            .first_camera_ns
            .zip(t.first_estimate_ns)
            .map(|(c, e)| (e - c) as f64 * 1e-9),
        coverage: None,
        input_coverage: t.input.imu_span_ns.and_then(|(i0, i1)| {
            input_coverage(&d.covered, &d.skipped, t.first_camera_ns.unwrap_or(i0), i1)
        }),
        counters: counters_json(t)?,
    };
    s.started_by = started_by(init, &t.counters);
    evaluate_against_truth(rec, &mut d, t, &mut s)?;
    Ok(s)
}

/// The figures of `s` that need the recording's ground truth (coverage, ATE) and simulator
/// truth (the LiDAR association's quality), in passes over streams: the ground truth is read
/// from the recording once for the poses (twice with simulator truth), and the run's poses and
/// events from the digest's logs. Nothing without ground truth.
fn evaluate_against_truth(
    rec: &dyn Recording,
    d: &mut RunDigest,
    t: &RunTotals,
    s: &mut Summary,
) -> Result<()> {
    if !rec.contents().ground_truth {
        return Ok(());
    }
    // The ground truth's poses, read from the recording once (a pass over an MCAP file reads
    // every chunk) and logged for the passes below.
    let mut gt_log = PoseLog::default();
    for x in rec.ground_truth_stream()? {
        gt_log.push(&StampedPose::from(&x?));
    }
    gt_log.flush();
    if gt_log.is_empty() {
        return Ok(());
    }
    let truth = match d.lidar_events.is_kept() {
        true => rec.sim_landmarks()?,
        false => None,
    };
    if let Some(truth) = truth {
        let c = rec.calibration();
        let mut a = lidar_assoc::Assessor::new(truth, &c.t_bc, c.td_s, t.lidar.sigma_dr_m);
        // The check reads the pose only (velocity and biases are not logged).
        let states = gt_log.poses()?.map(|p| {
            p.map(|p| NavState {
                t_ns: p.t_ns,
                p_wb: p.p_wb,
                q_wb: p.q_wb,
                v_wb: Vec3::zeros(),
                bg: Vec3::zeros(),
                ba: Vec3::zeros(),
            })
        });
        let mut gt = GtCursor::new(states);
        d.lidar_events
            .for_each(|step| a.step(step.t_cam_ns, &step.events, |t| gt.at(t)))?;
        if let Some(e) = gt.error() {
            return Err(e);
        }
        // Evaluation-only: a truth that cannot be read leaves the check out, not the run.
        match a.finish() {
            Ok(q) => s.assoc = Some(AssocSummary::from(&q)),
            Err(e) => eprintln!("warning: the LiDAR association check was skipped: {e}"),
        }
    }
    if let Some(t0) = t.first_camera_ns.filter(|_| d.trajectory.is_some()) {
        let stamps = gt_log.poses()?.map(|p| p.map(|p| p.t_ns));
        s.coverage = coverage(stamps, &d.covered, t0)?;
    }
    let gt = || -> Result<PoseStream<'_>> { Ok(Box::new(gt_log.poses()?)) };
    let opts = EvalOptions {
        alignment: Alignment::PosYaw,
        ..Default::default()
    };
    let ate = |log: &mut Option<PoseLog>| -> Option<Result<AteRmse>> {
        let log = log.as_mut().filter(|l| !l.is_empty())?;
        log.flush();
        let log = &*log;
        let est = || -> Result<PoseStream<'_>> { Ok(Box::new(log.poses()?)) };
        Some(ate_rmse(&gt, &est, &opts))
    };
    match ate(&mut d.trajectory) {
        Some(Ok(r)) => {
            s.ate_pos_rmse_m = Some(r.pos_rmse_m);
            s.ate_rot_rmse_deg = Some(r.rot_rmse_deg);
            s.matched_poses = Some(r.matched);
            if let Some(log) = d.velocity_cov.as_mut().filter(|l| !l.is_empty()) {
                log.flush();
                let mut gt = GtCursor::new(rec.ground_truth_stream()?);
                let n = nees::velocity_nees(log.rows()?, |t| gt.at(t), &r.q_align)?;
                if let Some(e) = gt.error() {
                    return Err(e.into());
                }
                s.velocity_nees = n;
            }
        }
        Some(Err(e)) => eprintln!("warning: evaluation failed: {e:#}"),
        None => {}
    }
    if let Some(Ok(r)) = ate(&mut d.keyframes) {
        s.keyframe_ate_pos_rmse_m = Some(r.pos_rmse_m);
    }
    Ok(())
}

/// Which initializer started the run, from the estimator's counters.
fn started_by(init: InitMode, c: &povins_core::estimator::Counters) -> Option<String> {
    if init == InitMode::Groundtruth {
        return Some("groundtruth".into());
    }
    match (c.static_inits > 0, c.motion_inits > 0) {
        (true, true) => Some("static+motion".into()),
        (true, false) => Some("static".into()),
        (false, true) => Some("motion".into()),
        (false, false) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::RunSink;

    fn at(t_ms: i64) -> StampedPose {
        StampedPose {
            t_ns: t_ms * 1_000_000,
            p_wb: povins_core::math::Vec3::zeros(),
            q_wb: povins_core::math::Quat::identity(),
        }
    }

    /// Ground truth before the first camera frame does not count; a stamp counts when an
    /// estimate lies within 10 ms on either side.
    #[test]
    fn coverage_counts_ground_truth_with_an_estimate_within_10_ms() {
        let gt: Vec<StampedPose> = (0..10).map(|k| at(100 * k)).collect();
        let est = [at(290), at(410), at(611), at(795)];
        // From 200 ms: 200 300 400 500 600 700 800 900; covered 300 (290), 400 (410), 800 (795).
        let cov = |est: &[StampedPose], from_ns| {
            let stamps = gt.iter().map(|p| Ok::<_, ()>(p.t_ns));
            coverage(stamps, &spans_of(est), from_ns).unwrap()
        };
        assert_eq!(cov(&est, 200_000_000), Some(3.0 / 8.0));
        assert_eq!(cov(&[], 0), Some(0.0));
        assert_eq!(cov(&est, 1_000_000_000), None);
        // Poses 10 ms apart cover the time between them (and 10 ms beyond): 300 to 600 ms,
        // and 200 ms from 210 on.
        let dense: Vec<StampedPose> = (0..=30).map(|k| at(300 + 10 * k)).collect();
        assert_eq!(cov(&dense, 200_000_000), Some(4.0 / 8.0));
        let from_210: Vec<StampedPose> = (0..=39).map(|k| at(210 + 10 * k)).collect();
        assert_eq!(cov(&from_210, 200_000_000), Some(5.0 / 8.0));
    }

    /// Poses closer than 10 ms cover the time between them; a longer gap is uncovered; only
    /// the time from the first camera frame to the last IMU sample counts.
    #[test]
    fn input_coverage_counts_the_time_inside_the_covered_spans() {
        let spans = [(0, 400), (600, 1000)];
        assert_eq!(input_coverage(&spans, &[], 200, 1000), Some(0.75));
        assert_eq!(input_coverage(&spans, &[], 0, 1000), Some(0.8));
        assert_eq!(input_coverage(&[], &[], 0, 1000), Some(0.0));
        assert_eq!(input_coverage(&spans, &[], 1000, 1000), None);
        // A clock jump's skipped time is nobody's input.
        assert_eq!(input_coverage(&spans, &[(400, 600)], 0, 1000), Some(1.0));
        assert_eq!(input_coverage(&[], &[(0, 1000)], 0, 1000), None);
        let mut d = RunDigest::default();
        for t_ms in [0, 5, 10, 30, 35] {
            let mut s = povins_core::inertial::NavState::ZERO;
            s.t_ns = t_ms * 1_000_000;
            RunSink::nav(&mut d, &s);
        }
        assert_eq!(d.covered, vec![(0, 10_000_000), (30_000_000, 35_000_000)]);
    }

    /// The reason names each refusal kind that occurred with its count, and only those.
    #[test]
    fn never_started_reason_counts_the_refusals_by_kind() {
        let c = serde_json::json!({
            "motion_init_refused_conditioning": 213,
            "motion_init_refused_gravity": 0,
            "motion_init_refused_residual": 7,
        });
        let r = never_started_reason(InitMode::Auto, 541, 0, &c);
        assert!(r.starts_with("no static period met the static-init thresholds, and every"));
        assert!(
            r.contains("no excitation or ill-conditioned 213, large residuals 7 ("),
            "{r}"
        );
        assert!(!r.contains("gravity"), "{r}");
        let none = never_started_reason(InitMode::Motion, 541, 0, &serde_json::json!({}));
        assert!(none.starts_with("no in-motion start was tried"), "{none}");
        assert_eq!(
            never_started_reason(InitMode::Static, 10, 0, &c),
            "no static period met the static-init thresholds"
        );
        assert!(never_started_reason(InitMode::Auto, 10, 10, &c).starts_with("every image"));
    }
}

//! What the estimator tells its user: per-keyframe reports and running counters.

use crate::camera::CameraExtrinsic;
use crate::frontend::KeyframeDecision;
use crate::solver::Termination;

/// The marginal standard deviations of the estimated camera-IMU extrinsic `T_bc`
/// ([`crate::camera::CameraExtrinsic`]): the square roots of the diagonal of its block of the
/// window's inverse information after a solve (`estimator::covariance`), in the estimator's own
/// model (the configured pixel and IMU noise, the marginalization prior's gauge). Translation
/// along the body axes; rotation about the camera axes (the estimate is perturbed as
/// `q_bc Exp(dtheta)`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ExtrinsicSd {
    /// `p_bc` (camera origin in the body frame), m.
    pub p_bc_m: [f64; 3],
    /// `q_bc`, rad.
    pub r_bc_rad: [f64; 3],
}

/// Statistics of one keyframe's back-end step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct KeyframeReport {
    /// IMU time of the keyframe, ns.
    pub t_ns: i64,
    /// Camera time of the keyframe image, ns.
    pub t_cam_ns: i64,
    /// Why this frame became a keyframe.
    pub decision: KeyframeDecision,
    /// Keyframes in the window after the step.
    pub window_len: u32,
    /// Landmarks in the manager.
    pub landmarks_total: u32,
    /// Landmarks that entered the final optimization pass.
    pub landmarks_used: u32,
    /// Visual observations (2-row residuals) in the final pass.
    pub observations_used: u32,
    /// RMS of the visual reprojection error per axis after the solve, px.
    pub residual_rms_px: f64,
    /// LM iterations over both passes.
    pub iterations: u32,
    /// The work budget (`solve_budget`) ended the solve early (or left no second pass).
    pub budget_hit: bool,
    /// The work of the solve over both passes (the unit of `SolveBudget::max_work`: one
    /// observation's residual evaluated).
    pub solve_work: u32,
    /// Robust cost before and after the solve.
    pub cost: (f64, f64),
    /// Why the last LM pass stopped.
    pub termination: Option<Termination>,
    /// Observations removed by the chi-square test between the passes.
    pub culled_chi2: u32,
    /// Observations removed by the post-solve reprojection test.
    pub culled_observations: u32,
    /// Landmarks removed by the post-solve reprojection test.
    pub culled_landmarks: u32,
    /// Landmarks disabled for degenerate geometry during the solve.
    pub disabled_landmarks: u32,
    /// Pivots of the marginalized block dropped by the floor (directions the window could not
    /// determine, e.g. the yaw gauge): 0 means the Schur complement was exact.
    pub marginalized_rank_deficiency: u32,
    /// Zero (or floored) pivots of the new square-root prior: states the marginalized factors
    /// say nothing about (velocities and biases of keyframes linked to the oldest one only
    /// through landmarks) plus any direction lost to the floor.
    pub prior_rank_deficiency: u32,
    /// Standard deviations the marginalization prior gives the window's global position
    /// (largest axis), m, and yaw, rad ([`crate::estimator::prior::MargPrior::gauge_std`]): in a
    /// consistent window they never shrink from one keyframe to the next; a drop is
    /// information it cannot have. 0 when no prior was formed in this step.
    pub prior_gauge_std: (f64, f64),
    /// The keyframe got the zero-velocity factor (and a zero-motion factor to the previous one):
    /// the images showed rest since the previous keyframe and the INS speed agreed
    /// ([`super::ZuptConfig::max_speed_mps`]).
    pub at_rest: bool,
    /// The delay's information from the admitted observations of this solve,
    /// `sum |v * f| ^ 2 / sigma_px ^ 2` over their feature velocities `v` (1/s), focal lengths
    /// `f` and pixel noise, 1/s^2 ([`super::TdConfig::min_info_per_s2`] gates the delay on it).
    pub td_info_per_s2: f64,
    /// Largest position change the solve gave a keyframe that earlier solves had already
    /// estimated (every keyframe but the newest), m. A healthy window moves them by millimetres
    /// to centimetres; metres mean it broke down ([`super::HealthConfig`]).
    pub window_correction_m: f64,
    /// Time of the optimization (both passes, culling included), ns.
    pub solve_ns: u64,
    /// Time of the marginalization, ns.
    pub marginalization_ns: u64,
    /// Whole back-end step (landmark preparation, solve, marginalization, culling, LiDAR
    /// association), ns.
    pub total_ns: u64,
    /// LiDAR points (inside the association span) seen by the depth association.
    pub lidar_points: u32,
    /// LiDAR points the crop to the camera's view dropped since the start, at this keyframe
    /// (`Counters::lidar_points_outside_view`; the difference between two keyframes is what
    /// the sweeps between them lost).
    pub lidar_points_cropped_total: u64,
    /// LiDAR points lost younger than the association's span since the start, at this keyframe
    /// (`Counters::lidar_points_evicted_in_span`).
    pub lidar_points_lost_total: u64,
    /// LiDAR points thinned since the start, at this keyframe (`Counters::lidar_points_thinned`).
    pub lidar_points_thinned_total: u64,
    /// Features of this keyframe given a LiDAR depth.
    pub depths_associated: u32,
    /// LiDAR depths removed by the uncertainty-based rejection (paper IV.C) in this step.
    pub depths_rejected: u32,
    /// Landmarks entering the final solve with a LiDAR-depth measurement.
    pub ldm_count: u32,
    /// Time of the depth association (grid build and per-feature plane fits), ns.
    pub association_ns: u64,
    /// Time of the uncertainty-based rejection, ns.
    pub rejection_ns: u64,
    /// Time of the depth-only optimization, ns.
    pub depth_opt_ns: u64,
    /// Why the managed landmarks did or did not enter the first solve.
    pub admission: Admission,
    /// Camera-IMU time delay of the newest keyframe after the solve, s (`t_imu = t_cam + td`).
    pub td_s: f64,
    /// Camera-IMU extrinsic `T_bc` after the solve: the estimate when
    /// [`super::EstimatorConfig::estimate_extrinsic`], else the configured one. `None` when the
    /// step did not finish (the window broke down).
    pub extrinsic: Option<CameraExtrinsic>,
    /// The extrinsic's marginal standard deviations after the solve, when
    /// [`super::EstimatorConfig::estimate_extrinsic`] (`None` otherwise, or when the window's
    /// information leaves a direction at or after the extrinsic's columns unconstrained).
    pub extrinsic_sd: Option<ExtrinsicSd>,
    /// Factor on the IMU white-noise densities after this keyframe (`estimator::imu_noise`; 1
    /// until the window has measured the IMU against the camera).
    pub imu_noise_scale: f64,
    /// Tracks the window offers: valid observations in at least two of its keyframes.
    pub multi_view_tracks: u32,
    /// Their observations (compare with `observations_used + landmarks_used`).
    pub multi_view_observations: u32,
    /// Tracks given a landmark slot at this keyframe.
    pub landmarks_promoted: u32,
    /// Landmarks evicted for them.
    pub landmarks_evicted: u32,
    /// The health monitor found the window broken after this solve and re-initialized it
    /// (`estimator::health`); the keyframe was dropped with the window.
    pub breakdown: Option<Breakdown>,
}

/// Why the health monitor re-initialized the window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Breakdown {
    /// A state became non-finite or faster than `max_speed_mps`.
    State,
    /// A bias left its plausible range.
    Bias,
    /// The solve moved the newest velocity more than the INS could have drifted.
    VelocityJump,
    /// The visual residuals stayed many sigmas large.
    Residuals,
    /// The solve moved keyframes that earlier solves had estimated by more than
    /// `max_window_correction_m` plus `max_window_correction_rel` times the window's path.
    WindowJump,
}

/// Landmark admission at the first solve of a keyframe: every managed landmark is counted once,
/// under the first gate it failed (or as admitted).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Admission {
    /// Admitted to the optimization.
    pub admitted: u32,
    /// Seen in only one keyframe of the window.
    pub single_view: u32,
    /// Parallax below `min_parallax`.
    pub low_parallax: u32,
    /// Depth behind the anchor camera or outside `depth_range_m`.
    pub bad_depth: u32,
    /// Analytic depth uncertainty above `max_rel_depth_std` of the depth.
    pub uncertain_depth: u32,
}

impl KeyframeReport {
    /// The back end proper, ns: the whole step but the LiDAR depth association, which the
    /// paper counts as LiDAR front-end processing (reported in `association_ns`).
    pub fn backend_ns(&self) -> u64 {
        self.total_ns.saturating_sub(self.association_ns)
    }
}

/// What happened to a landmark's LiDAR depth (for evaluation against ground truth).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DepthEventKind {
    /// A depth was associated in the landmark's anchor keyframe (the keyframe of the report).
    Associated,
    /// The uncertainty-based test rejected the depth (the visual feature stays).
    Rejected,
    /// Outlier culling dropped the landmark together with its depth.
    Culled,
}

/// One LiDAR-depth event of a keyframe step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthEvent {
    /// Track id of the landmark.
    pub id: u64,
    /// What happened.
    pub kind: DepthEventKind,
    /// The LiDAR depth (z in the anchor camera), m.
    pub depth_m: f64,
}

/// Running counters of everything the estimator rejected, dropped or reset.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Counters {
    /// IMU samples accepted.
    pub imu_samples: u64,
    /// IMU samples rejected as non-finite.
    pub imu_rejected_nonfinite: u64,
    /// IMU samples rejected at or beyond the configured full scale (clipped).
    pub imu_rejected_range: u64,
    /// IMU samples rejected for non-increasing time.
    pub imu_rejected_time: u64,
    /// IMU samples refused because the queue was full (`update` not called often enough).
    pub imu_dropped_queue_full: u64,
    /// Camera frames offered.
    pub frames: u64,
    /// Frames rejected for non-increasing time, or for a stamp too far ahead of the IMU.
    pub frames_rejected_time: u64,
    /// Frames that arrived before initialization.
    pub frames_before_init: u64,
    /// Frames replaced before the IMU reached them (camera ahead of IMU).
    pub frames_dropped_no_imu: u64,
    /// Keyframes created.
    pub keyframes: u64,
    /// Feature observations offered.
    pub features_received: u64,
    /// Feature observations rejected (non-finite, outside image, duplicate id, undistortion,
    /// frame capacity).
    pub features_rejected: u64,
    /// Promotions refused because the landmark capacity was reached.
    pub landmarks_refused_capacity: u64,
    /// Landmarks evicted to give their slot to a more informative track.
    pub landmarks_evicted: u64,
    /// Solves that returned an error (the state kept its last accepted value).
    pub solver_failures: u64,
    /// Keyframes whose solve the work budget ended (`solve_budget`).
    pub solve_budget_hits: u64,
    /// Marginalizations that failed (the prior was dropped).
    pub marginalization_failures: u64,
    /// Estimator resets (IMU gap, preintegration overflow, divergence).
    pub resets: u64,
    /// Of the resets: those caused by a non-finite or implausibly fast INS state.
    pub divergence_resets: u64,
    /// Of the resets: IMU gaps too long to bridge (above `imu_gap.bridge_max_s`, and not a
    /// long gap after smooth motion).
    pub imu_gap_resets: u64,
    /// IMU gaps bridged (`imu_gap`): a sample spacing above `max_imu_dt_s` while running.
    pub imu_gaps_bridged: u64,
    /// Of the gaps bridged: those above `imu_gap.bridge_max_s`, bridged because the motion
    /// before them was smooth (`imu_gap.long_bridge_max_s`).
    pub imu_gaps_bridged_long: u64,
    /// Of the gaps bridged: those after which the images' pose was taken over the INS's, which
    /// the line across the gap had missed (`estimator::gap_pose`).
    pub imu_gap_poses_from_images: u64,
    /// Starts after a full reset whose yaw and position were carried across the outage by the
    /// images (the rotation and the direction of travel between the frames that came while the
    /// IMU was out, at the speed before it: `estimator::outage_heading`).
    pub outage_motion_from_images: u64,
    /// Clock jumps: gaps in every stream across which the images show nothing moved (the
    /// inputs' clock moved; the estimate went on: `estimator::clock_jump`).
    pub clock_jumps: u64,
    /// IMU samples dropped as spikes (`imu_spike`).
    pub imu_spikes_rejected: u64,
    /// Windows dropped because no keyframe came for as long as a keyframe interval holds
    /// samples (a camera dropout): the INS went on alone (also counted in `reinitializations`).
    pub interval_overflows: u64,
    /// Windows dropped by the health monitor, the INS continuing alone (`estimator::health`).
    pub reinitializations: u64,
    /// Starts by the static initializer.
    pub static_inits: u64,
    /// Starts by the in-motion initializer.
    pub motion_inits: u64,
    /// In-motion solves refused: too few tracks seen in 3 init frames.
    pub motion_init_refused_tracks: u64,
    /// ... too little parallax (pure rotation, rest).
    pub motion_init_refused_parallax: u64,
    /// ... ill-conditioned (constant velocity, too little motion) or non-finite.
    pub motion_init_refused_conditioning: u64,
    /// ... unconstrained gravity norm far from the configured one.
    pub motion_init_refused_gravity: u64,
    /// ... residuals too large or too few inliers.
    pub motion_init_refused_residual: u64,
    /// LiDAR sweeps offered.
    pub lidar_scans: u64,
    /// LiDAR sweeps refused whole (LiDAR disabled, not initialized, or larger than the buffer
    /// can take in one piece is *not* a refusal: the oldest points are evicted instead).
    pub lidar_scans_refused: u64,
    /// Of those: sweeps refused because the sweep queue had no room for them.
    pub lidar_scans_dropped_queue_full: u64,
    /// LiDAR points offered.
    pub lidar_points_received: u64,
    /// LiDAR points stored.
    pub lidar_points_accepted: u64,
    /// LiDAR points rejected (non-finite, range, time outside the INS window).
    pub lidar_points_rejected: u64,
    /// LiDAR points evicted from the full buffer (every stored point is, in the end, once the
    /// buffer has filled).
    pub lidar_points_evicted: u64,
    /// Of those, points younger than the association's span when evicted: lost before every
    /// keyframe that could use them had (the buffer is too small for the LiDAR's rate).
    pub lidar_points_evicted_in_span: u64,
    /// LiDAR points dropped when pushed: they cannot reach the camera's image
    /// ([`crate::lidar::crop`]).
    pub lidar_points_outside_view: u64,
    /// LiDAR points dropped by the thinning of a LiDAR whose rate would overflow the buffer
    /// within the association's span ([`crate::lidar::thin`]: a direction that took a point
    /// less than a quarter of the span before).
    pub lidar_points_thinned: u64,
}

impl Counters {
    /// All zero (what [`Default`] gives); `const` for static estimators.
    pub const ZERO: Counters = Counters {
        imu_samples: 0,
        imu_rejected_nonfinite: 0,
        imu_rejected_range: 0,
        imu_rejected_time: 0,
        imu_dropped_queue_full: 0,
        frames: 0,
        frames_rejected_time: 0,
        frames_before_init: 0,
        frames_dropped_no_imu: 0,
        keyframes: 0,
        features_received: 0,
        features_rejected: 0,
        landmarks_refused_capacity: 0,
        landmarks_evicted: 0,
        solver_failures: 0,
        solve_budget_hits: 0,
        marginalization_failures: 0,
        resets: 0,
        divergence_resets: 0,
        imu_gap_resets: 0,
        imu_gaps_bridged: 0,
        imu_gaps_bridged_long: 0,
        imu_gap_poses_from_images: 0,
        outage_motion_from_images: 0,
        clock_jumps: 0,
        imu_spikes_rejected: 0,
        interval_overflows: 0,
        reinitializations: 0,
        static_inits: 0,
        motion_inits: 0,
        motion_init_refused_tracks: 0,
        motion_init_refused_parallax: 0,
        motion_init_refused_conditioning: 0,
        motion_init_refused_gravity: 0,
        motion_init_refused_residual: 0,
        lidar_scans: 0,
        lidar_scans_refused: 0,
        lidar_scans_dropped_queue_full: 0,
        lidar_points_received: 0,
        lidar_points_accepted: 0,
        lidar_points_rejected: 0,
        lidar_points_evicted: 0,
        lidar_points_evicted_in_span: 0,
        lidar_points_outside_view: 0,
        lidar_points_thinned: 0,
    };
}

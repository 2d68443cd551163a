//! Estimator configuration: every threshold of the pipeline, with the paper's / LE-VINS'
//! values as defaults.

use crate::camera::{CameraExtrinsic, PinholeCamera};
use crate::frontend::{KeyframeConfig, RestConfig};
use crate::inertial::init::StaticInitConfig;
use crate::inertial::motion_init::MotionInitConfig;
use crate::inertial::preintegration::PreintConfig;
use crate::inertial::ImuNoise;
use crate::lidar::LidarConfig;
use crate::ranges::{self, InvalidSetting, Ranges};
use crate::solver::LmConfig;
use crate::Error;

mod groups;
mod imu_faults;

pub use groups::{CullConfig, SolveBudget, TdConfig, ZuptConfig};
pub use imu_faults::{ImuGapConfig, ImuSpikeConfig};

/// How visual landmarks enter the optimization.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum VisualMode {
    /// PO-VINS: landmarks are not states; pose-only reprojection measurements.
    PoseOnly,
    /// LE-VINS-WO baseline: inverse depth per landmark as a state, eliminated by Schur complement.
    InverseDepth,
}

/// Where a pose-only landmark's depth comes from (see `estimator::problem::visual`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum VisualDepth {
    /// The paper's two-view depth from the anchors `(s, e)`, exact in every residual.
    TwoView,
    /// The inverse depth and the anchor observation's bearing that best fit all the landmark's
    /// observations, the anchor's included, eliminated by their Schur complement at every
    /// linearization (no landmark state either; `estimator::problem::visual`). With the direct
    /// LDM the two-view form is used (see [`EstimatorConfig::depth_eliminated`]).
    Eliminated,
}

/// Standard deviations of the prior put on the first keyframe (it fixes the gauge until the
/// first marginalization folds it into the marginalization prior).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct FirstStatePrior {
    /// Position, m.
    pub p_m: f64,
    /// Attitude (each axis), rad.
    pub theta_rad: f64,
    /// Velocity, m/s.
    pub v_mps: f64,
    /// Gyro bias, rad/s.
    pub bg_rps: f64,
    /// Accelerometer bias, m/s^2.
    pub ba_mps2: f64,
}

/// Limits of the health monitor.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct HealthConfig {
    /// Check at all.
    pub enabled: bool,
    /// Largest plausible gyro bias (each axis), rad/s.
    pub max_gyro_bias_rps: f64,
    /// Largest plausible accelerometer bias (each axis), m/s^2.
    pub max_accel_bias_mps2: f64,
    /// Largest velocity correction of the newest keyframe by its solve (against the INS
    /// prediction), m/s.
    pub max_velocity_correction_mps: f64,
    /// Largest position change of an already estimated keyframe (every one but the newest) by
    /// one solve ([`super::KeyframeReport::window_correction_m`]), m, plus
    /// `max_window_correction_rel` times the path the window spans. The newest keyframe's
    /// checks cannot see a window that slides away as a whole while its newest state stays
    /// plausible.
    pub max_window_correction_m: f64,
    /// Part of the window's path (the sum of its keyframe-to-keyframe distances before the
    /// solve) added to `max_window_correction_m`: a fast vehicle's healthy corrections are
    /// larger in metres.
    pub max_window_correction_rel: f64,
    /// Visual residual RMS, in units of `sigma_px`, above which a keyframe counts as bad.
    pub max_residual_sigmas: f64,
    /// Consecutive bad keyframes that make a breakdown.
    pub bad_keyframes: u32,
    /// Prior of the first keyframe of a re-initialized window. After a camera dropout (the open
    /// interval full) only its position is used: attitude, velocity and biases start from the
    /// dropped window's newest covariance propagated over the dropout.
    pub reinit_prior: FirstStatePrior,
}

impl HealthConfig {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: HealthConfig = HealthConfig {
        enabled: true,
        max_gyro_bias_rps: 0.3,
        max_accel_bias_mps2: 2.0,
        max_velocity_correction_mps: 2.0,
        max_window_correction_m: 1.0,
        max_window_correction_rel: 0.1,
        max_residual_sigmas: 4.0,
        bad_keyframes: 3,
        reinit_prior: FirstStatePrior {
            p_m: 1e-3,
            theta_rad: 0.05,
            v_mps: 0.5,
            bg_rps: 0.01,
            ba_mps2: 0.3,
        },
    };
}

impl Default for HealthConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Which initializer may start the estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum InitMode {
    /// The static initializer while the images show the platform at rest (it wins when both
    /// could start), the in-motion one otherwise.
    Auto,
    /// Only the static initializer (a rest period is needed).
    Static,
    /// Only the in-motion initializer.
    Motion,
}

/// Initialization (`[init]`): the choice of initializer, the in-motion initializer's
/// thresholds and the prior of the first keyframe after an in-motion start.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct InitConfig {
    /// Which initializer may start the estimator.
    pub mode: InitMode,
    /// Thresholds of the in-motion initializer (`[init.motion]`).
    pub motion: MotionInitConfig,
    /// Prior of the first keyframe after an in-motion start (its velocity and attitude are
    /// known less well than at rest).
    pub motion_prior: FirstStatePrior,
    /// The IMU's biases, when known before the start (`[init.biases]`; unset: not known).
    pub biases: Option<KnownBiases>,
}

/// IMU biases known before the start (`[init.biases]`), in the body frame `b` (the IMU's), with
/// how well they are known.
///
/// A start in motion has a second or two of motion to solve from, over which an accelerometer
/// bias of 0.1-0.2 m/s^2 (a MEMS IMU's) looks like a tilt of gravity and a change of scale, and
/// which the first seconds of the window cannot separate either (BENCHMARKS.md, "What an
/// in-motion start lacks"). Given these, every in-motion start (the first, and those after a full
/// reset) integrates its init frames with them and starts the window from them, its first
/// keyframe's bias prior centred on them with these standard deviations instead of
/// `motion_prior`'s. A start at rest measures the gyro bias itself and does not use them.
///
/// Where they come from: the last keyframe of a run on the same IMU not powered off since
/// (`povins run --biases-from RUN/keyframes_state.csv`, a restarted process); a MEMS IMU's
/// turn-on biases change from one power cycle to the next by its datasheet's bias repeatability,
/// which the standard deviations must then cover.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct KnownBiases {
    /// Gyro bias `[x, y, z]`, rad/s (subtracted from the gyro's readings).
    pub gyro_rps: [f64; 3],
    /// Accelerometer bias `[x, y, z]`, m/s^2 (subtracted from the accelerometer's readings).
    pub accel_mps2: [f64; 3],
    /// Standard deviation of each gyro bias axis, rad/s.
    pub gyro_sd_rps: f64,
    /// Standard deviation of each accelerometer bias axis, m/s^2.
    pub accel_sd_mps2: f64,
}

impl KnownBiases {
    /// The standard deviations for biases from a previous run on the same powered IMU: on the
    /// simulated EuRoC-like flights started in motion these did best of 0.0002 / 0.01,
    /// 0.0005 / 0.02, 0.001 / 0.03 and 0.002 / 0.05 (BENCHMARKS.md, "An in-motion start given
    /// the biases").
    pub const PREVIOUS_RUN_SD: (f64, f64) = (5e-4, 0.02);

    /// Biases with [`Self::PREVIOUS_RUN_SD`].
    pub const fn from_previous_run(gyro_rps: [f64; 3], accel_mps2: [f64; 3]) -> Self {
        KnownBiases {
            gyro_rps,
            accel_mps2,
            gyro_sd_rps: Self::PREVIOUS_RUN_SD.0,
            accel_sd_mps2: Self::PREVIOUS_RUN_SD.1,
        }
    }

    /// Adds the out-of-range values to `r`: finite biases, positive standard deviations.
    pub(crate) fn check_ranges(&self, r: &mut Ranges<'_>) {
        let (g, a) = (self.gyro_rps, self.accel_mps2);
        for (key, v) in [
            ("init.biases.gyro_rps[0]", g[0]),
            ("init.biases.gyro_rps[1]", g[1]),
            ("init.biases.gyro_rps[2]", g[2]),
            ("init.biases.accel_mps2[0]", a[0]),
            ("init.biases.accel_mps2[1]", a[1]),
            ("init.biases.accel_mps2[2]", a[2]),
        ] {
            r.finite(key, v);
        }
        r.positive("init.biases.gyro_sd_rps", self.gyro_sd_rps);
        r.positive("init.biases.accel_sd_mps2", self.accel_sd_mps2);
    }
}

impl InitConfig {
    /// The defaults (what [`Default`] gives).
    pub const DEFAULT: InitConfig = InitConfig {
        mode: InitMode::Auto,
        motion: MotionInitConfig::DEFAULT,
        motion_prior: FirstStatePrior {
            p_m: 1e-3,
            theta_rad: 0.05,
            v_mps: 0.3,
            bg_rps: 0.01,
            ba_mps2: 0.3,
        },
        biases: None,
    };
}

impl Default for InitConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Everything the estimator needs to know before the first sample.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct EstimatorConfig {
    /// Camera intrinsics and distortion.
    pub camera: PinholeCamera,
    /// Camera-IMU extrinsic `T_bc` (initial value when estimated).
    pub extrinsic: CameraExtrinsic,
    /// Initial camera-IMU time delay, s (`t_imu = t_cam + td_s`).
    pub td_s: f64,
    /// IMU noise model.
    pub imu_noise: ImuNoise,
    /// Gravity magnitude, m/s^2.
    pub gravity_mps2: f64,
    /// Largest IMU sample spacing taken as measured, s: a longer one is a gap, bridged or
    /// ending in a reset ([`ImuGapConfig`]).
    pub max_imu_dt_s: f64,
    /// IMU gaps (`[imu_gap]`).
    pub imu_gap: ImuGapConfig,
    /// IMU spikes (`[imu_spike]`).
    pub imu_spike: ImuSpikeConfig,
    /// IMU full scale, gyro: a sample with a component at or beyond it is clipped and
    /// rejected, rad/s (set it to the IMU's configured range).
    pub max_gyro_rps: f64,
    /// IMU full scale, accelerometer: a sample with a component at or beyond it is clipped and
    /// rejected, m/s^2.
    pub max_accel_mps2: f64,
    /// The INS is considered diverged (and the estimator reset) above this speed, m/s.
    pub max_speed_mps: f64,
    /// Frames stamped (and LiDAR sweeps ending) more than this ahead of the newest IMU sample
    /// are rejected, s.
    pub max_frame_lead_s: f64,
    /// Delayed horizon of [`super::Estimator::update`]: an IMU sample is processed once the
    /// newest pushed sample is this much later, so that frames and sweeps arriving up to this
    /// late are still taken in time order, s (0: at once; at most 1 s).
    pub delay_horizon_s: f64,
    /// Visual measurement model.
    pub mode: VisualMode,
    /// Depth of the pose-only visual measurements.
    pub visual_depth: VisualDepth,
    /// Keyframe thresholds.
    pub keyframe: KeyframeConfig,
    /// Static initialization thresholds.
    pub static_init: StaticInitConfig,
    /// Rest detection from the images (static initialization and zero-velocity updates).
    pub rest: RestConfig,
    /// Zero-velocity updates (`[zupt]`).
    pub zupt: ZuptConfig,
    /// Preintegration (re-integration thresholds).
    pub preint: PreintConfig,
    /// Prior of the first keyframe.
    pub first_prior: FirstStatePrior,
    /// Initialization (`[init]`).
    pub init: InitConfig,
    /// Feature noise, px (paper: 1.5).
    pub sigma_px: f64,
    /// Huber threshold on the whitened visual residual norm.
    pub huber_delta: f64,
    /// Smallest parallax `|x_e x R_es x_s|` (rad-like) for a landmark to enter the optimization.
    pub min_parallax: f64,
    /// Largest analytic depth standard deviation, as a fraction of the depth, for a landmark to
    /// enter the optimization with a two-view depth ([`VisualDepth::TwoView`]: gates landmarks
    /// whose depth is still noise; an estimated or eliminated depth needs no such gate).
    pub max_rel_depth_std: f64,
    /// Whiten each pose-only residual `j != e` with the anchors' depth uncertainty (from
    /// `sigma_px`), see `factors::pose_only_visual`; off: the depth is taken as exact.
    pub depth_uncertainty_weighting: bool,
    /// Parallax `|x_e x R_es x_s|` at which the slot policy values a track fully (below it, in
    /// proportion, down to a tenth): see `estimator::slots`.
    pub slot_parallax_ref: f64,
    /// Valid landmark depth range, m (LE-VINS: 1-200 m).
    pub depth_range_m: (f64, f64),
    /// Outlier culls (`[cull]`).
    pub cull: CullConfig,
    /// Levenberg-Marquardt settings of the first pass.
    pub lm_first: LmConfig,
    /// Levenberg-Marquardt settings of the second pass (after the chi-square cull).
    pub lm_second: LmConfig,
    /// The work budget of a keyframe's two passes (`[solve_budget]`).
    pub solve_budget: SolveBudget,
    /// Fold the visual residuals of the oldest keyframe into the marginalization prior (landmarks
    /// anchored there are re-anchored first, see `estimator::marginalize`). Without, the prior
    /// carries only the IMU and earlier-prior information.
    pub marginalize_visual: bool,
    /// Marginalization of landmarks anchored in the oldest keyframe: fold all their residuals
    /// into the prior and keep using them after re-anchoring (VINS-Mono; counts them twice), or
    /// (false) re-anchor them first and fold only the oldest observation's residual
    /// (`estimator::marginalize`).
    pub reuse_marginalized_landmarks: bool,
    /// Estimation of the camera-IMU time delay (`[td]`).
    pub td: TdConfig,
    /// Estimate the camera-IMU extrinsic.
    pub estimate_extrinsic: bool,
    /// Prior standard deviations of the extrinsic: translation m, rotation rad.
    pub extrinsic_prior: (f64, f64),
    /// Compute the newest keyframe's marginal covariance after each solve and propagate it with
    /// the IMU-rate state ([`crate::inertial::Ins::covariance`]; `estimator::covariance`): one
    /// more factorization of the window per keyframe. Changes no estimate.
    pub covariance: bool,
    /// Online scale of the IMU white-noise densities ([`super::ImuNoiseAdapt`]).
    pub imu_noise_adapt: super::ImuNoiseAdapt,
    /// Health monitor limits and the re-initialization prior.
    pub health: HealthConfig,
    /// LiDAR enhancement (off by default: PO-VINS-WO).
    pub lidar: LidarConfig,
}

impl EstimatorConfig {
    /// Whether visual landmarks have their depth eliminated from all observations
    /// ([`VisualDepth::Eliminated`]). The direct LDM is defined on the two anchors of the paper's
    /// two-view depth, so with it every landmark keeps the two-view form (a window mixing both
    /// forms with an estimated delay gave a 1e-3 gradient mismatch, not explained yet).
    pub fn depth_eliminated(&self) -> bool {
        self.visual_depth == VisualDepth::Eliminated
            && !(self.lidar.enabled && self.lidar.ldm == crate::lidar::LdmMode::Direct)
    }

    /// Defaults for a camera and IMU: LE-VINS keyframe rules, sigma_p = 1.5 px, Huber 1 sigma.
    pub const fn new(
        camera: PinholeCamera,
        extrinsic: CameraExtrinsic,
        imu_noise: ImuNoise,
    ) -> Self {
        // A relative cost decrease of 1e-3 (a few units of the whitened cost: a step within
        // about one standard deviation of the estimate) ends the solve. 1e-2 was tried
        // (2026-11-29; with the second pass's 0.1: corridor back end 1.74 -> 1.30 ms, ATE
        // geometric mean 1.013 over 102 regression sequences against 0.1 alone), but about one
        // Gauss-Newton step per keyframe leaves the prior linearized at less converged states:
        // on a 60 s vehicle run the prior's yaw standard deviation shrank at 59 marginalizations
        // instead of 21 (spurious gauge information) and the ATE went from 1.5 to 12 m. The
        // damping starts almost at Gauss-Newton: Marquardt damping
        // scales with diag(H), which a precise IMU makes huge, and then freezes the weakly
        // observable directions (velocity/scale along a nearly straight path) that the
        // optimization exists to correct (measured on the simulator: 2-6x lower ATE).
        let lm = LmConfig {
            max_iterations: 6,
            function_tolerance: 1e-3,
            initial_lambda: 1e-9,
            ..LmConfig::DEFAULT
        };
        EstimatorConfig {
            camera,
            extrinsic,
            td_s: 0.0,
            imu_noise,
            gravity_mps2: 9.81,
            max_imu_dt_s: 0.05,
            imu_gap: ImuGapConfig::DEFAULT,
            imu_spike: ImuSpikeConfig::DEFAULT,
            // 2000 deg/s and 16 g: the full scale of common MEMS IMUs.
            max_gyro_rps: 35.0,
            max_accel_mps2: 160.0,
            max_speed_mps: 100.0,
            max_frame_lead_s: 1.0,
            delay_horizon_s: 0.0,
            mode: VisualMode::PoseOnly,
            visual_depth: VisualDepth::Eliminated,
            keyframe: KeyframeConfig::DEFAULT,
            static_init: StaticInitConfig::DEFAULT,
            rest: RestConfig::DEFAULT,
            zupt: ZuptConfig::DEFAULT,
            preint: PreintConfig::DEFAULT,
            first_prior: FirstStatePrior {
                p_m: 1e-3,
                theta_rad: 0.02,
                v_mps: 0.05,
                bg_rps: 5e-3,
                ba_mps2: 0.1,
            },
            init: InitConfig::DEFAULT,
            sigma_px: 1.5,
            huber_delta: 1.0,
            min_parallax: 0.002,
            max_rel_depth_std: 0.1,
            slot_parallax_ref: 0.02,
            depth_uncertainty_weighting: false,
            depth_range_m: (0.1, 200.0),
            cull: CullConfig::DEFAULT,
            lm_first: lm,
            lm_second: lm,
            solve_budget: SolveBudget::DEFAULT,
            marginalize_visual: true,
            reuse_marginalized_landmarks: true,
            td: TdConfig::DEFAULT,
            estimate_extrinsic: false,
            extrinsic_prior: (0.02, 0.02),
            covariance: false,
            imu_noise_adapt: super::ImuNoiseAdapt::DEFAULT,
            health: HealthConfig::DEFAULT,
            lidar: LidarConfig::DEFAULT,
        }
    }

    /// What an unconfigured estimator holds ([`super::Estimator::empty`]): every number zero
    /// (quaternions too), every switch off, every option `None`, every mode its first variant,
    /// so that its bits are all zero and a `static` estimator lives in `.bss`. Not a usable
    /// configuration: it fails [`EstimatorConfig::validate`].
    pub const PLACEHOLDER: EstimatorConfig = {
        const LM: LmConfig = LmConfig {
            max_iterations: 0,
            max_retries: 0,
            max_trials: 0,
            max_work: 0,
            initial_lambda: 0.0,
            lambda_min: 0.0,
            lambda_max: 0.0,
            diag_min: 0.0,
            diag_max: 0.0,
            function_tolerance: 0.0,
            gradient_tolerance: 0.0,
            step_tolerance: 0.0,
            min_gain_ratio: 0.0,
            pivot_floor: crate::solver::PivotFloor {
                relative: 0.0,
                absolute: 0.0,
            },
        };
        const PRIOR: FirstStatePrior = FirstStatePrior {
            p_m: 0.0,
            theta_rad: 0.0,
            v_mps: 0.0,
            bg_rps: 0.0,
            ba_mps2: 0.0,
        };
        const Q0: crate::math::Quat =
            crate::math::Quat::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));
        EstimatorConfig {
            camera: PinholeCamera {
                readout_s: 0.0,
                width: 0,
                height: 0,
                fx: 0.0,
                fy: 0.0,
                cx: 0.0,
                cy: 0.0,
                distortion: crate::camera::Distortion::None,
            },
            extrinsic: CameraExtrinsic {
                p_bc: crate::math::VEC3_ZERO,
                q_bc: Q0,
            },
            td_s: 0.0,
            imu_noise: ImuNoise {
                gyro_noise_density: 0.0,
                accel_noise_density: 0.0,
                gyro_bias_rw: 0.0,
                accel_bias_rw: 0.0,
                bias_corr_time_s: None,
            },
            gravity_mps2: 0.0,
            max_imu_dt_s: 0.0,
            imu_gap: ImuGapConfig {
                bridge_max_s: 0.0,
                accel_sigma_mps2: 0.0,
                gyro_sigma_rps: 0.0,
                long_bridge_max_s: 0.0,
                long_max_rotation_rad: 0.0,
                long_max_velocity_mps: 0.0,
                clock_jumps: false,
            },
            imu_spike: ImuSpikeConfig {
                enabled: false,
                max_accel_step_mps2: 0.0,
                max_gyro_step_rps: 0.0,
            },
            max_gyro_rps: 0.0,
            max_accel_mps2: 0.0,
            max_speed_mps: 0.0,
            max_frame_lead_s: 0.0,
            delay_horizon_s: 0.0,
            mode: VisualMode::PoseOnly,
            visual_depth: VisualDepth::TwoView,
            keyframe: KeyframeConfig {
                min_interval_s: 0.0,
                min_translation_m: 0.0,
                min_translation_interval_s: 0.0,
                max_rotation_rad: 0.0,
                max_interval_s: 0.0,
                min_parallax_px: None,
                compensate_rotation: false,
                min_tracked_ratio: 0.0,
            },
            static_init: StaticInitConfig {
                gravity_mps2: 0.0,
                accel_norm_tol_mps2: 0.0,
                accel_std_max_mps2: 0.0,
                gyro_std_max_rps: 0.0,
                vibration_accel_std_max_mps2: 0.0,
                vibration_gyro_std_max_rps: 0.0,
                min_static_s: 0.0,
                noise_std_factor: 0.0,
                max_dt_s: 0.0,
            },
            rest: RestConfig {
                max_px: 0.0,
                min_features: 0,
            },
            zupt: ZuptConfig {
                enabled: false,
                sigma_mps: 0.0,
                max_speed_mps: 0.0,
                motion_sigma_m: 0.0,
                motion_sigma_rad: 0.0,
            },
            preint: PreintConfig {
                max_dt_s: 0.0,
                reint_bg_rps: 0.0,
                reint_ba_mps2: 0.0,
            },
            first_prior: PRIOR,
            init: InitConfig {
                mode: InitMode::Auto,
                motion: MotionInitConfig {
                    min_spacing_s: 0.0,
                    max_span_s: 0.0,
                    min_frames: 0,
                    min_tracks: 0,
                    min_parallax_rad: 0.0,
                    sigma_rad: 0.0,
                    min_accel_excitation_mps2: 0.0,
                    max_velocity_std_mps: 0.0,
                    max_velocity_rel_std: 0.0,
                    max_gravity_std_rad: 0.0,
                    max_gravity_norm_error: 0.0,
                    max_residual_sigmas: 0.0,
                    min_inlier_ratio: 0.0,
                },
                motion_prior: PRIOR,
                biases: None,
            },
            sigma_px: 0.0,
            huber_delta: 0.0,
            min_parallax: 0.0,
            max_rel_depth_std: 0.0,
            depth_uncertainty_weighting: false,
            slot_parallax_ref: 0.0,
            depth_range_m: (0.0, 0.0),
            cull: CullConfig {
                chi2_threshold: 0.0,
                second_pass_min_culled_frac: 0.0,
                mean_px: 0.0,
                obs_px: 0.0,
                whole_tracks: false,
            },
            lm_first: LM,
            lm_second: LM,
            solve_budget: SolveBudget {
                max_linearizations: 0,
                max_trials: 0,
                max_work: 0,
                max_work_ratio: 0.0,
            },
            marginalize_visual: false,
            reuse_marginalized_landmarks: false,
            td: TdConfig {
                estimate: false,
                rw_s_per_sqrt_s: 0.0,
                prior_s: 0.0,
                min_info_per_s2: 0.0,
            },
            estimate_extrinsic: false,
            extrinsic_prior: (0.0, 0.0),
            covariance: false,
            imu_noise_adapt: super::ImuNoiseAdapt {
                enabled: false,
                max_density_scale: 0.0,
                forgetting: 0.0,
                min_redundancy: 0.0,
                tolerance: 0.0,
            },
            health: HealthConfig {
                enabled: false,
                max_gyro_bias_rps: 0.0,
                max_accel_bias_mps2: 0.0,
                max_velocity_correction_mps: 0.0,
                max_window_correction_m: 0.0,
                max_window_correction_rel: 0.0,
                max_residual_sigmas: 0.0,
                bad_keyframes: 0,
                reinit_prior: PRIOR,
            },
            lidar: LidarConfig {
                enabled: false,
                ldm: crate::lidar::LdmMode::Msc,
                depth_outlier_rejection: false,
                depth_only_opt: false,
                sigma_dr_m: 0.0,
                sigma_dr_rel: 0.0,
                rejection_sigma_px: 0.0,
                rejection_sigmas: 0.0,
                extrinsic: crate::lidar::LidarExtrinsic {
                    q_bl: Q0,
                    p_bl: crate::math::VEC3_ZERO,
                },
                td_l_s: 0.0,
                association: crate::lidar::AssociationConfig {
                    cell_rad: 0.0,
                    neighbours: 0,
                    max_neighbour_rad: 0.0,
                    max_plane_dist_m: 0.0,
                    max_range_spread: 0.0,
                    min_incidence_cos: 0.0,
                    depth_range_m: (0.0, 0.0),
                    span_s: 0.0,
                },
                crop_to_view: false,
                view_margin_rad: 0.0,
            },
        }
    };

    /// Checks ranges: [`EstimatorConfig::find_invalid`] finds nothing (the same checks, one
    /// list: [`EstimatorConfig::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The first setting out of its range, with its TOML key, its value and the allowed range
    /// (`None` when [`EstimatorConfig::validate`] accepts the configuration).
    pub fn find_invalid(&self) -> Option<InvalidSetting> {
        ranges::first_invalid(|r| self.check_ranges(r))
    }

    /// Largest camera-IMU delay [`EstimatorConfig::td_s`] accepted, s: a delay of a second is
    /// already far beyond any synchronized camera's; a larger one is a unit or clock mistake
    /// (it would move every frame outside the IMU's time), not a delay to estimate.
    pub const MAX_TD_S: f64 = 1.0;

    /// Every range check of the configuration, in the order [`Self::find_invalid`] reports
    /// them: the top-level settings, then each group's own list (`[zupt]`, `[td]`, `[cull]`,
    /// `[lidar]`, ...).
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        let c = &self.camera;
        r.positive("camera.fx", c.fx);
        r.positive("camera.fy", c.fy);
        let readout = c.readout_s;
        r.within(
            "camera.readout_s",
            readout,
            0.0,
            crate::camera::MAX_READOUT_S,
            "0..=0.2",
        );
        let td = self.td_s;
        r.within("td_s", td, -Self::MAX_TD_S, Self::MAX_TD_S, "-1..=1 (s)");
        r.positive("gravity_mps2", self.gravity_mps2);
        r.positive("max_imu_dt_s", self.max_imu_dt_s);
        r.positive("max_gyro_rps", self.max_gyro_rps);
        r.positive("max_accel_mps2", self.max_accel_mps2);
        r.positive("max_speed_mps", self.max_speed_mps);
        r.positive("max_frame_lead_s", self.max_frame_lead_s);
        let horizon = self.delay_horizon_s;
        r.within("delay_horizon_s", horizon, 0.0, 1.0, "0..=1");
        r.positive("sigma_px", self.sigma_px);
        r.positive("huber_delta", self.huber_delta);
        r.non_negative("min_parallax", self.min_parallax);
        r.positive("max_rel_depth_std", self.max_rel_depth_std);
        r.positive("rest.max_px", self.rest.max_px);
        r.positive("slot_parallax_ref", self.slot_parallax_ref);
        let (near, far) = self.depth_range_m;
        r.positive("depth_range_m[0]", near);
        r.check("depth_range_m[1]", far, "> depth_range_m[0]", far > near);
        r.positive("extrinsic_prior[0]", self.extrinsic_prior.0);
        r.positive("extrinsic_prior[1]", self.extrinsic_prior.1);
        let p = &self.first_prior;
        r.positive("first_prior.p_m", p.p_m);
        r.positive("first_prior.theta_rad", p.theta_rad);
        r.positive("first_prior.v_mps", p.v_mps);
        r.positive("first_prior.bg_rps", p.bg_rps);
        r.positive("first_prior.ba_mps2", p.ba_mps2);
        let p = &self.init.motion_prior;
        r.positive("init.motion_prior.p_m", p.p_m);
        r.positive("init.motion_prior.theta_rad", p.theta_rad);
        r.positive("init.motion_prior.v_mps", p.v_mps);
        r.positive("init.motion_prior.bg_rps", p.bg_rps);
        r.positive("init.motion_prior.ba_mps2", p.ba_mps2);
        self.init.motion.check_ranges(r);
        if let Some(b) = &self.init.biases {
            b.check_ranges(r);
        }
        self.imu_noise.check_ranges(r);
        self.imu_noise_adapt.check_ranges(r);
        self.static_init.check_ranges(r);
        self.keyframe.check_ranges(r);
        self.zupt.check_ranges(r);
        self.imu_gap.check_ranges(r);
        self.imu_spike.check_ranges(r);
        self.td.check_ranges(r);
        self.cull.check_ranges(r);
        self.solve_budget.check_ranges(r);
        self.lidar.check_ranges(r);
        // Each further group adds its own list here.
    }
}

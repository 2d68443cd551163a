//! `--config FILE.toml` for `povins run`: overrides of the estimator defaults.
//!
//! Every key is optional; unknown keys are an error (so a typo is never silently ignored).
//!
//! ```toml
//! mode = "pose-only"            # or "inverse-depth"
//! visual_depth = "eliminated"   # or "two-view" (the paper's anchors): pose-only depth source
//! sigma_px = 1.5                # feature noise
//! huber_delta = 1.0             # Huber threshold, in sigmas
//! min_parallax = 0.01           # landmark gate (|x_e x R x_s|)
//! max_rel_depth_std = 0.1       # landmark gate: analytic depth std / depth
//! depth_uncertainty_weighting = true  # whiten pose-only residuals with the depth's uncertainty
//! slot_parallax_ref = 0.02      # parallax at which the slot policy values a track fully
//! depth_range_m = [0.1, 200.0]
//! cull_mean_px = 4.5
//! cull_obs_px = 4.5
//! cull_whole_tracks = false     # drop and ban the track instead of the single observation
//! chi2_threshold = 5.991
//! lm_max_iterations = 6
//! lm_second_max_iterations = 6  # the pass after the chi-square cull (overrides the above)
//! second_pass_min_culled_frac = 0.02 # run that pass only if the cull removed this share of obs
//! lm_initial_lambda = 1e-4      # Marquardt damping relative to diag(H)
//! lm_function_tolerance = 1e-3  # stop when the cost decreases by less than this fraction
//! marginalize_visual = true     # fold the oldest keyframe's visual residuals into the prior
//! reuse_marginalized_landmarks = true  # VINS-Mono: fold all, keep using them (counted twice)
//! zupt = true                   # zero-velocity updates while the images show rest
//! zupt_sigma_mps = 0.01
//! estimate_td = true
//! td_s = 0.0                    # initial camera-IMU delay (replaces the dataset's), s
//! td_prior_s = 0.005            # prior std of the first keyframe's delay
//! td_rw_s_per_sqrt_s = 1e-4     # random walk of the delay between keyframes
//! estimate_extrinsic = false
//! delay_horizon_s = 0.0         # process an IMU sample once the newest one is this much later
//!
//! [imu]                         # replaces the dataset's noise model (continuous densities)
//! gyro_noise_density = 2.0e-3
//! accel_noise_density = 2.9e-2
//! gyro_bias_rw = 2.0e-5
//! accel_bias_rw = 3.0e-3
//! bias_corr_time_s = 3600.0     # Gauss-Markov biases (omit for random walk)
//! adapt_noise = true            # raise the white-noise densities to what the window measures
//! max_noise_scale = 30.0        # largest factor on them (1 = measure and report only)
//! noise_forgetting = 0.97       # per-keyframe weight of the earlier measurements
//! noise_tolerance = 2.0         # variance ratio left to the window's own approximations
//!
//! [keyframe]                    # LE-VINS rules
//! min_interval_s = 0.096
//! min_translation_m = 0.2
//! min_translation_interval_s = 0.285
//! max_rotation_deg = 10.0
//! max_interval_s = 0.475
//! min_parallax_px = 20.0        # IC-GVINS rule instead of translation (optional)
//!
//! [static_init]
//! accel_std_max_mps2 = 0.05
//! gyro_std_max_rps = 0.005
//! vibration_accel_std_max_mps2 = 2.5  # limits while the images confirm the rest
//! vibration_gyro_std_max_rps = 0.2
//! min_static_s = 1.0
//!
//! [rest]                        # rest detection from the feature tracks
//! max_px = 2.0                  # median feature displacement since the rest began
//! min_features = 8
//!
//! [lidar]                       # LiDAR enhancement (on by default when the dataset has LiDAR)
//! enabled = true                # false = PO-VINS-WO (`--no-lidar`)
//! ldm = "msc"                   # or "direct" (`--ldm`): LiDAR-depth measurement model
//! depth_outlier_rejection = true  # uncertainty-based rejection (`--no-depth-outlier-rejection`)
//! depth_only_opt = true         # depth-only optimization (`--no-depth-only-opt`)
//! sigma_dr_m = 0.1              # std of an associated LiDAR depth at short range
//! sigma_dr_rel = 0.01           # plus this fraction of the depth (sqrt of the sum of squares)
//! rejection_sigma_px = 1.5      # feature noise in the rejection's depth uncertainty
//! rejection_sigmas = 3.0        # rejection gate, in std of 1/d_v - 1/d_r
//! p_bl_m = [0.0, 0.0, 0.1]      # LiDAR origin in the body (replaces the dataset's T_bl)
//! q_bl_xyzw = [0.0, 0.0, 0.0, 1.0]  # LiDAR -> body rotation (normalized; |q| must be 1 +- 1e-3)
//! td_l_s = 0.0                  # LiDAR-IMU time offset, t_imu = t_lidar + td_l_s
//!
//! [lidar.association]           # depth association on the camera's unit sphere
//! cell_deg = 0.5                # angular grid cell
//! neighbours = 5                # points in the plane fit (3..=8)
//! max_neighbour_deg = 2.0       # largest angle between the feature and a neighbour
//! max_plane_dist_m = 0.1        # largest neighbour distance from the fitted plane
//! max_range_spread = 0.1        # largest neighbour range spread / mean range
//! min_incidence_cos = 0.2       # smallest cos(ray, plane normal)
//! depth_range_m = [0.5, 80.0]   # accepted depth (z in the camera)
//! span_s = 0.5                  # points older than this before the keyframe are not used
//!
//! [frontend]                    # image front end (`povins run --frontend images`, `povins track`)
//! max_features = 150            # features kept per frame (at most 256)
//! grid = [8, 6]                 # detection grid: columns, rows
//! max_per_cell = 8              # features per grid cell
//! min_distance_px = 20.0        # between features
//! quality_level = 0.01          # corner response relative to the frame's best
//! min_eigen = 1.0               # absolute corner response floor, (grey/px)^2
//! window = 21                   # LK window, px (odd)
//! max_level = 3                 # coarsest pyramid level without an INS or gyro seed
//! predicted_max_level = 1       # with an INS prediction
//! rotation_max_level = 1        # with the gyro rotation
//! fb_check = true               # forward-backward check
//! fb_threshold_px = 0.5
//! ransac = "auto"               # "auto", "eight-point", "two-point" or "off"
//! ransac_threshold_px = 1.5     # 8-point model
//! ransac_two_point_threshold_px = 3.0
//! equalization = "off"          # "off", "global" or "clahe" (clip 3, 8x8 tiles)
//! predictions = true            # seed features with a depth at their INS prediction
//! gyro_rotation = true          # seed the others with the gyro rotation
//! ```
//!
//! The command-line switches of `povins run` ([`LidarArgs`]) override the file.

use anyhow::{bail, Context, Result};
use povins_core::estimator::{EstimatorConfig, VisualMode};
use povins_core::frontend::image::{Equalization, RansacModel, TrackerConfig};
use povins_core::inertial::ImuNoise;
use povins_core::lidar::{LdmMode, LidarConfig};
use povins_core::math::{Quat, Vec3};
use povins_core::vio::VioAiding;
use serde::Deserialize;
use std::path::Path;

/// Visual mode names on the command line and in TOML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ModeArg {
    /// PO-VINS pose-only visual measurements.
    PoseOnly,
    /// Conventional inverse-depth bundle adjustment (LE-VINS-WO).
    InverseDepth,
}

impl From<ModeArg> for VisualMode {
    fn from(m: ModeArg) -> Self {
        match m {
            ModeArg::PoseOnly => VisualMode::PoseOnly,
            ModeArg::InverseDepth => VisualMode::InverseDepth,
        }
    }
}

/// Pose-only depth sources in TOML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VisualDepthArg {
    /// The paper's two anchors.
    TwoView,
    /// All observations, eliminated.
    Eliminated,
}

impl From<VisualDepthArg> for povins_core::estimator::VisualDepth {
    fn from(m: VisualDepthArg) -> Self {
        match m {
            VisualDepthArg::TwoView => Self::TwoView,
            VisualDepthArg::Eliminated => Self::Eliminated,
        }
    }
}

/// LiDAR-depth measurement names on the command line and in TOML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum LdmArg {
    /// MSC-based LiDAR-depth measurement (PO-VINS, paper eq. 25-30).
    Msc,
    /// Direct LiDAR-depth measurement (paper eq. 24).
    Direct,
}

impl From<LdmArg> for LdmMode {
    fn from(m: LdmArg) -> Self {
        match m {
            LdmArg::Msc => LdmMode::Msc,
            LdmArg::Direct => LdmMode::Direct,
        }
    }
}

/// The command-line / JSON name of an LDM mode.
pub fn ldm_name(m: LdmMode) -> &'static str {
    match m {
        LdmMode::Msc => "msc",
        LdmMode::Direct => "direct",
    }
}

/// Run-time LiDAR switches (paper Table VI ablations); they override the TOML file.
#[derive(clap::Args, Debug, Clone, Default, PartialEq, Eq)]
pub struct LidarArgs {
    /// Ignore the LiDAR (PO-VINS-WO).
    #[arg(long)]
    pub no_lidar: bool,
    /// LiDAR-depth measurement model.
    #[arg(long, value_enum)]
    pub ldm: Option<LdmArg>,
    /// Keep every associated LiDAR depth (no uncertainty-based rejection).
    #[arg(long)]
    pub no_depth_outlier_rejection: bool,
    /// Skip the depth-only optimization of LiDAR landmarks.
    #[arg(long)]
    pub no_depth_only_opt: bool,
}

impl LidarArgs {
    /// Whether any switch was given.
    pub fn any(&self) -> bool {
        self.no_lidar
            || self.ldm.is_some()
            || self.no_depth_outlier_rejection
            || self.no_depth_only_opt
    }

    /// Applies the switches to `cfg`.
    pub fn apply(&self, cfg: &mut LidarConfig) {
        if self.no_lidar {
            cfg.enabled = false;
        }
        if let Some(m) = self.ldm {
            cfg.ldm = m.into();
        }
        if self.no_depth_outlier_rejection {
            cfg.depth_outlier_rejection = false;
        }
        if self.no_depth_only_opt {
            cfg.depth_only_opt = false;
        }
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImuSection {
    gyro_noise_density: Option<f64>,
    accel_noise_density: Option<f64>,
    gyro_bias_rw: Option<f64>,
    accel_bias_rw: Option<f64>,
    bias_corr_time_s: Option<f64>,
    adapt_noise: Option<bool>,
    max_noise_scale: Option<f64>,
    noise_forgetting: Option<f64>,
    noise_tolerance: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeSection {
    min_interval_s: Option<f64>,
    min_translation_m: Option<f64>,
    min_translation_interval_s: Option<f64>,
    max_rotation_deg: Option<f64>,
    max_interval_s: Option<f64>,
    min_parallax_px: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct StaticSection {
    accel_norm_tol_mps2: Option<f64>,
    accel_std_max_mps2: Option<f64>,
    gyro_std_max_rps: Option<f64>,
    vibration_accel_std_max_mps2: Option<f64>,
    vibration_gyro_std_max_rps: Option<f64>,
    min_static_s: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RestSection {
    max_px: Option<f64>,
    min_features: Option<usize>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct AssociationSection {
    cell_deg: Option<f64>,
    neighbours: Option<usize>,
    max_neighbour_deg: Option<f64>,
    max_plane_dist_m: Option<f64>,
    max_range_spread: Option<f64>,
    min_incidence_cos: Option<f64>,
    depth_range_m: Option<[f64; 2]>,
    span_s: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct LidarSection {
    enabled: Option<bool>,
    ldm: Option<LdmArg>,
    depth_outlier_rejection: Option<bool>,
    depth_only_opt: Option<bool>,
    sigma_dr_m: Option<f64>,
    sigma_dr_rel: Option<f64>,
    rejection_sigma_px: Option<f64>,
    rejection_sigmas: Option<f64>,
    p_bl_m: Option<[f64; 3]>,
    q_bl_xyzw: Option<[f64; 4]>,
    td_l_s: Option<f64>,
    #[serde(default)]
    association: AssociationSection,
}

/// RANSAC models in TOML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum RansacArg {
    Auto,
    EightPoint,
    TwoPoint,
    Off,
}

/// Equalizations in TOML.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum EqualizationArg {
    Off,
    Global,
    Clahe,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FrontendSection {
    max_features: Option<usize>,
    grid: Option<[usize; 2]>,
    max_per_cell: Option<usize>,
    min_distance_px: Option<f32>,
    quality_level: Option<f32>,
    min_eigen: Option<f32>,
    window: Option<usize>,
    max_level: Option<usize>,
    predicted_max_level: Option<usize>,
    rotation_max_level: Option<usize>,
    fb_check: Option<bool>,
    fb_threshold_px: Option<f32>,
    ransac: Option<RansacArg>,
    ransac_threshold_px: Option<f64>,
    ransac_two_point_threshold_px: Option<f64>,
    equalization: Option<EqualizationArg>,
    predictions: Option<bool>,
    gyro_rotation: Option<bool>,
}

/// A quaternion given as `[x, y, z, w]`, normalized; `None` unless its norm is 1 within 1e-3
/// (a typo should not silently become some other rotation).
fn unit_quat_xyzw(q: [f64; 4]) -> Option<Quat> {
    let [x, y, z, w] = q;
    let n = (x * x + y * y + z * z + w * w).sqrt();
    ((n - 1.0).abs() <= 1e-3).then(|| Quat::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)))
}

/// The TOML file.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfigFile {
    mode: Option<ModeArg>,
    visual_depth: Option<VisualDepthArg>,
    sigma_px: Option<f64>,
    huber_delta: Option<f64>,
    min_parallax: Option<f64>,
    max_rel_depth_std: Option<f64>,
    depth_uncertainty_weighting: Option<bool>,
    slot_parallax_ref: Option<f64>,
    depth_range_m: Option<[f64; 2]>,
    cull_mean_px: Option<f64>,
    cull_obs_px: Option<f64>,
    cull_whole_tracks: Option<bool>,
    chi2_threshold: Option<f64>,
    lm_max_iterations: Option<usize>,
    lm_second_max_iterations: Option<usize>,
    second_pass_min_culled_frac: Option<f64>,
    lm_initial_lambda: Option<f64>,
    lm_function_tolerance: Option<f64>,
    zupt: Option<bool>,
    zupt_sigma_mps: Option<f64>,
    estimate_td: Option<bool>,
    td_s: Option<f64>,
    td_prior_s: Option<f64>,
    td_rw_s_per_sqrt_s: Option<f64>,
    marginalize_visual: Option<bool>,
    reuse_marginalized_landmarks: Option<bool>,
    estimate_extrinsic: Option<bool>,
    delay_horizon_s: Option<f64>,
    #[serde(default)]
    imu: ImuSection,
    #[serde(default)]
    keyframe: KeyframeSection,
    #[serde(default)]
    static_init: StaticSection,
    #[serde(default)]
    rest: RestSection,
    #[serde(default)]
    lidar: LidarSection,
    #[serde(default)]
    frontend: FrontendSection,
}

impl RunConfigFile {
    /// Reads and parses a file (errors name the file and the TOML location).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("invalid config {}", path.display()))
    }

    /// Parses TOML text (unknown keys and malformed values are errors).
    pub fn parse(text: &str) -> Result<Self> {
        let f: Self = toml::from_str(text)?;
        if let Some(q) = f.lidar.q_bl_xyzw {
            if unit_quat_xyzw(q).is_none() {
                bail!("lidar.q_bl_xyzw = {q:?} is not a unit quaternion [x, y, z, w]");
            }
        }
        Ok(f)
    }

    /// Applies the `[frontend]` overrides to the image front end's settings and INS aiding;
    /// errors when the result is invalid (naming the section).
    pub fn apply_frontend(&self, t: &mut TrackerConfig, aiding: &mut VioAiding) -> Result<()> {
        fn set<T: Copy>(dst: &mut T, v: Option<T>) {
            if let Some(v) = v {
                *dst = v;
            }
        }
        let f = &self.frontend;
        set(&mut t.max_features, f.max_features);
        if let Some([c, r]) = f.grid {
            t.detector.grid_cols = c;
            t.detector.grid_rows = r;
        }
        set(&mut t.detector.max_per_cell, f.max_per_cell);
        set(&mut t.detector.min_distance_px, f.min_distance_px);
        set(&mut t.detector.quality_level, f.quality_level);
        set(&mut t.detector.min_eigen, f.min_eigen);
        set(&mut t.lk.window, f.window);
        set(&mut t.max_level, f.max_level);
        set(&mut t.predicted_max_level, f.predicted_max_level);
        set(&mut t.rotation_max_level, f.rotation_max_level);
        set(&mut t.fb_check, f.fb_check);
        set(&mut t.fb_threshold_px, f.fb_threshold_px);
        if let Some(m) = f.ransac {
            t.ransac.model = match m {
                RansacArg::Auto => RansacModel::Auto,
                RansacArg::EightPoint => RansacModel::EightPoint,
                RansacArg::TwoPoint => RansacModel::TwoPoint,
                RansacArg::Off => RansacModel::Off,
            };
        }
        set(&mut t.ransac.threshold_px, f.ransac_threshold_px);
        set(
            &mut t.ransac.two_point_threshold_px,
            f.ransac_two_point_threshold_px,
        );
        if let Some(e) = f.equalization {
            t.equalization = match e {
                EqualizationArg::Off => Equalization::Off,
                EqualizationArg::Global => Equalization::Global,
                EqualizationArg::Clahe => Equalization::CLAHE_3_8X8,
            };
        }
        set(&mut aiding.predictions, f.predictions);
        set(&mut aiding.gyro_rotation, f.gyro_rotation);
        if t.validate().is_err() || t.max_features > 256 || t.max_level > 3 {
            bail!(
                "[frontend]: invalid settings (max_features 1..=256, max_level <= 3, levels of \
                 the seeds <= max_level, odd window 5..=31, grid and thresholds positive): {t:?}"
            );
        }
        Ok(())
    }

    /// The visual mode the file asks for, if any.
    pub fn mode(&self) -> Option<ModeArg> {
        self.mode
    }

    /// Applies the overrides to `cfg`.
    pub fn apply(&self, cfg: &mut EstimatorConfig) {
        fn set<T: Copy>(dst: &mut T, v: Option<T>) {
            if let Some(v) = v {
                *dst = v;
            }
        }
        if let Some(m) = self.mode {
            cfg.mode = m.into();
        }
        if let Some(d) = self.visual_depth {
            cfg.visual_depth = d.into();
        }
        set(&mut cfg.sigma_px, self.sigma_px);
        set(&mut cfg.huber_delta, self.huber_delta);
        set(&mut cfg.min_parallax, self.min_parallax);
        set(&mut cfg.max_rel_depth_std, self.max_rel_depth_std);
        set(
            &mut cfg.depth_uncertainty_weighting,
            self.depth_uncertainty_weighting,
        );
        set(&mut cfg.slot_parallax_ref, self.slot_parallax_ref);
        if let Some([a, b]) = self.depth_range_m {
            cfg.depth_range_m = (a, b);
        }
        set(&mut cfg.cull_mean_px, self.cull_mean_px);
        set(&mut cfg.cull_obs_px, self.cull_obs_px);
        set(&mut cfg.cull_whole_tracks, self.cull_whole_tracks);
        set(&mut cfg.chi2_threshold, self.chi2_threshold);
        if let Some(n) = self.lm_max_iterations {
            cfg.lm_first.max_iterations = n;
            cfg.lm_second.max_iterations = n;
        }
        if let Some(f) = self.second_pass_min_culled_frac {
            cfg.second_pass_min_culled_frac = f;
        }
        if let Some(n) = self.lm_second_max_iterations {
            cfg.lm_second.max_iterations = n;
        }
        if let Some(l) = self.lm_initial_lambda {
            cfg.lm_first.initial_lambda = l;
            cfg.lm_second.initial_lambda = l;
        }
        if let Some(t) = self.lm_function_tolerance {
            cfg.lm_first.function_tolerance = t;
            cfg.lm_second.function_tolerance = t;
        }
        set(&mut cfg.estimate_td, self.estimate_td);
        set(&mut cfg.td_s, self.td_s);
        set(&mut cfg.zupt, self.zupt);
        set(&mut cfg.zupt_sigma_mps, self.zupt_sigma_mps);
        set(&mut cfg.td_prior_s, self.td_prior_s);
        set(&mut cfg.td_rw_s_per_sqrt_s, self.td_rw_s_per_sqrt_s);
        set(&mut cfg.marginalize_visual, self.marginalize_visual);
        set(
            &mut cfg.reuse_marginalized_landmarks,
            self.reuse_marginalized_landmarks,
        );
        set(&mut cfg.estimate_extrinsic, self.estimate_extrinsic);
        set(&mut cfg.delay_horizon_s, self.delay_horizon_s);
        let i = &self.imu;
        let n: &mut ImuNoise = &mut cfg.imu_noise;
        set(&mut n.gyro_noise_density, i.gyro_noise_density);
        set(&mut n.accel_noise_density, i.accel_noise_density);
        set(&mut n.gyro_bias_rw, i.gyro_bias_rw);
        set(&mut n.accel_bias_rw, i.accel_bias_rw);
        if i.bias_corr_time_s.is_some() {
            n.bias_corr_time_s = i.bias_corr_time_s;
        }
        let a = &mut cfg.imu_noise_adapt;
        set(&mut a.enabled, i.adapt_noise);
        set(&mut a.max_density_scale, i.max_noise_scale);
        set(&mut a.forgetting, i.noise_forgetting);
        set(&mut a.tolerance, i.noise_tolerance);
        let k = &self.keyframe;
        set(&mut cfg.keyframe.min_interval_s, k.min_interval_s);
        set(&mut cfg.keyframe.min_translation_m, k.min_translation_m);
        set(
            &mut cfg.keyframe.min_translation_interval_s,
            k.min_translation_interval_s,
        );
        if let Some(d) = k.max_rotation_deg {
            cfg.keyframe.max_rotation_rad = d.to_radians();
        }
        set(&mut cfg.keyframe.max_interval_s, k.max_interval_s);
        if k.min_parallax_px.is_some() {
            cfg.keyframe.min_parallax_px = k.min_parallax_px;
        }
        let s = &self.static_init;
        set(
            &mut cfg.static_init.accel_norm_tol_mps2,
            s.accel_norm_tol_mps2,
        );
        set(
            &mut cfg.static_init.accel_std_max_mps2,
            s.accel_std_max_mps2,
        );
        set(&mut cfg.static_init.gyro_std_max_rps, s.gyro_std_max_rps);
        set(&mut cfg.static_init.min_static_s, s.min_static_s);
        set(
            &mut cfg.static_init.vibration_accel_std_max_mps2,
            s.vibration_accel_std_max_mps2,
        );
        set(
            &mut cfg.static_init.vibration_gyro_std_max_rps,
            s.vibration_gyro_std_max_rps,
        );
        set(&mut cfg.rest.max_px, self.rest.max_px);
        set(&mut cfg.rest.min_features, self.rest.min_features);
        let l = &self.lidar;
        let c = &mut cfg.lidar;
        set(&mut c.enabled, l.enabled);
        if let Some(m) = l.ldm {
            c.ldm = m.into();
        }
        set(&mut c.depth_outlier_rejection, l.depth_outlier_rejection);
        set(&mut c.depth_only_opt, l.depth_only_opt);
        set(&mut c.sigma_dr_m, l.sigma_dr_m);
        set(&mut c.sigma_dr_rel, l.sigma_dr_rel);
        set(&mut c.rejection_sigma_px, l.rejection_sigma_px);
        set(&mut c.rejection_sigmas, l.rejection_sigmas);
        if let Some(p) = l.p_bl_m {
            c.extrinsic.p_bl = Vec3::from(p);
        }
        if let Some(q) = l.q_bl_xyzw.and_then(unit_quat_xyzw) {
            c.extrinsic.q_bl = q;
        }
        set(&mut c.td_l_s, l.td_l_s);
        let a = &l.association;
        let ca = &mut c.association;
        if let Some(d) = a.cell_deg {
            ca.cell_rad = d.to_radians();
        }
        set(&mut ca.neighbours, a.neighbours);
        if let Some(d) = a.max_neighbour_deg {
            ca.max_neighbour_rad = d.to_radians();
        }
        set(&mut ca.max_plane_dist_m, a.max_plane_dist_m);
        set(&mut ca.max_range_spread, a.max_range_spread);
        set(&mut ca.min_incidence_cos, a.min_incidence_cos);
        if let Some([lo, hi]) = a.depth_range_m {
            ca.depth_range_m = (lo, hi);
        }
        set(&mut ca.span_s, a.span_s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::{CameraExtrinsic, PinholeCamera};

    fn base() -> EstimatorConfig {
        let cam = PinholeCamera::EUROC_CAM0;
        let ext = CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: Quat::identity(),
        };
        EstimatorConfig::new(cam, ext, ImuNoise::EUROC_ADIS16448)
    }

    #[test]
    fn every_lidar_key_parses_and_reaches_the_config() {
        let f = RunConfigFile::parse(
            r#"
            [lidar]
            enabled = true
            ldm = "direct"
            depth_outlier_rejection = false
            depth_only_opt = false
            sigma_dr_m = 0.2
            rejection_sigma_px = 2.5
            rejection_sigmas = 4.0
            p_bl_m = [0.1, -0.2, 0.3]
            q_bl_xyzw = [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]
            td_l_s = -0.004

            [lidar.association]
            cell_deg = 1.0
            neighbours = 6
            max_neighbour_deg = 3.0
            max_plane_dist_m = 0.05
            max_range_spread = 0.2
            min_incidence_cos = 0.3
            depth_range_m = [1.0, 50.0]
            span_s = 0.25
            "#,
        )
        .expect("valid file");
        let mut cfg = base();
        f.apply(&mut cfg);
        let l = &cfg.lidar;
        assert!(l.enabled);
        assert_eq!(l.ldm, LdmMode::Direct);
        assert!(!l.depth_outlier_rejection && !l.depth_only_opt);
        assert_eq!(
            (l.sigma_dr_m, l.rejection_sigma_px, l.rejection_sigmas),
            (0.2, 2.5, 4.0)
        );
        assert_eq!(l.extrinsic.p_bl, Vec3::new(0.1, -0.2, 0.3));
        // 90 deg about z: x_l maps to y_b.
        let x_b = l.extrinsic.q_bl * Vec3::x();
        assert!((x_b - Vec3::y()).norm() < 1e-12, "{x_b:?}");
        assert_eq!(l.td_l_s, -0.004);
        let a = &l.association;
        assert!((a.cell_rad - 1f64.to_radians()).abs() < 1e-15);
        assert_eq!(a.neighbours, 6);
        assert!((a.max_neighbour_rad - 3f64.to_radians()).abs() < 1e-15);
        assert_eq!(
            (a.max_plane_dist_m, a.max_range_spread, a.min_incidence_cos),
            (0.05, 0.2, 0.3)
        );
        assert_eq!(a.depth_range_m, (1.0, 50.0));
        assert_eq!(a.span_s, 0.25);
        assert!(cfg.validate().is_ok());
    }

    #[test]
    fn omitted_lidar_keys_keep_the_defaults() {
        let f = RunConfigFile::parse("[lidar]\nldm = \"msc\"\n").expect("valid file");
        let mut cfg = base();
        f.apply(&mut cfg);
        assert_eq!(cfg.lidar, LidarConfig::default());
    }

    #[test]
    fn unknown_or_malformed_lidar_keys_are_errors() {
        for bad in [
            "[lidar]\nenable = true\n",
            "[lidar]\nldm = \"msc-based\"\n",
            "[lidar.association]\nneighbors = 5\n",
            "[lidar]\nq_bl_xyzw = [0.0, 0.0, 0.0, 0.5]\n",
            "[lidar]\np_bl_m = [0.0, 0.0]\n",
            "[lidar_association]\ncell_deg = 1.0\n",
        ] {
            let e = RunConfigFile::parse(bad);
            assert!(e.is_err(), "accepted {bad:?}");
        }
        let msg = format!(
            "{:#}",
            RunConfigFile::parse("[lidar]\nenable = true\n").unwrap_err()
        );
        assert!(msg.contains("enable"), "{msg}");
    }

    #[test]
    fn switches_override_the_file() {
        let f =
            RunConfigFile::parse("[lidar]\nenabled = true\nldm = \"msc\"\ndepth_only_opt = true\n")
                .expect("valid file");
        let mut cfg = base();
        f.apply(&mut cfg);
        let sw = LidarArgs {
            no_lidar: true,
            ldm: Some(LdmArg::Direct),
            no_depth_outlier_rejection: true,
            no_depth_only_opt: true,
        };
        assert!(sw.any());
        assert!(!LidarArgs::default().any());
        sw.apply(&mut cfg.lidar);
        assert!(!cfg.lidar.enabled);
        assert_eq!(cfg.lidar.ldm, LdmMode::Direct);
        assert!(!cfg.lidar.depth_outlier_rejection && !cfg.lidar.depth_only_opt);
    }
}

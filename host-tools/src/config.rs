//! `--config FILE.toml` for `povins run`: overrides of the estimator defaults.
//!
//! Every key is optional; unknown keys are an error (so a typo is never silently ignored).
//!
//! ```toml
//! mode = "pose-only"            # or "inverse-depth"
//! sigma_px = 1.5                # feature noise
//! huber_delta = 1.0             # Huber threshold, in sigmas
//! min_parallax = 0.01           # landmark gate (|x_e x R x_s|)
//! max_rel_depth_std = 0.1       # landmark gate: analytic depth std / depth
//! depth_range_m = [0.1, 200.0]
//! cull_mean_px = 4.5
//! cull_obs_px = 4.5
//! chi2_threshold = 5.991
//! lm_max_iterations = 6
//! lm_initial_lambda = 1e-4      # Marquardt damping relative to diag(H)
//! lm_function_tolerance = 1e-3  # stop when the cost decreases by less than this fraction
//! marginalize_visual = true     # fold anchored landmarks into the prior (VINS-Mono)
//! reuse_marginalized_landmarks = true  # re-anchor them and keep using them (VINS-Mono)
//! estimate_td = false
//! estimate_extrinsic = false
//!
//! [imu]                         # replaces the dataset's noise model (continuous densities)
//! gyro_noise_density = 2.0e-3
//! accel_noise_density = 2.9e-2
//! gyro_bias_rw = 2.0e-5
//! accel_bias_rw = 3.0e-3
//! bias_corr_time_s = 3600.0     # Gauss-Markov biases (omit for random walk)
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
//! min_static_s = 1.0
//! ```

use anyhow::{Context, Result};
use povins_core::estimator::{EstimatorConfig, VisualMode};
use povins_core::inertial::ImuNoise;
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

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImuSection {
    gyro_noise_density: Option<f64>,
    accel_noise_density: Option<f64>,
    gyro_bias_rw: Option<f64>,
    accel_bias_rw: Option<f64>,
    bias_corr_time_s: Option<f64>,
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
    min_static_s: Option<f64>,
}

/// The TOML file.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfigFile {
    mode: Option<ModeArg>,
    sigma_px: Option<f64>,
    huber_delta: Option<f64>,
    min_parallax: Option<f64>,
    max_rel_depth_std: Option<f64>,
    depth_range_m: Option<[f64; 2]>,
    cull_mean_px: Option<f64>,
    cull_obs_px: Option<f64>,
    chi2_threshold: Option<f64>,
    lm_max_iterations: Option<usize>,
    lm_initial_lambda: Option<f64>,
    lm_function_tolerance: Option<f64>,
    estimate_td: Option<bool>,
    marginalize_visual: Option<bool>,
    reuse_marginalized_landmarks: Option<bool>,
    estimate_extrinsic: Option<bool>,
    #[serde(default)]
    imu: ImuSection,
    #[serde(default)]
    keyframe: KeyframeSection,
    #[serde(default)]
    static_init: StaticSection,
}

impl RunConfigFile {
    /// Reads and parses a file (errors name the file and the TOML location).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid config {}", path.display()))
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
        set(&mut cfg.sigma_px, self.sigma_px);
        set(&mut cfg.huber_delta, self.huber_delta);
        set(&mut cfg.min_parallax, self.min_parallax);
        set(&mut cfg.max_rel_depth_std, self.max_rel_depth_std);
        if let Some([a, b]) = self.depth_range_m {
            cfg.depth_range_m = (a, b);
        }
        set(&mut cfg.cull_mean_px, self.cull_mean_px);
        set(&mut cfg.cull_obs_px, self.cull_obs_px);
        set(&mut cfg.chi2_threshold, self.chi2_threshold);
        if let Some(n) = self.lm_max_iterations {
            cfg.lm_first.max_iterations = n;
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
        set(&mut cfg.marginalize_visual, self.marginalize_visual);
        set(
            &mut cfg.reuse_marginalized_landmarks,
            self.reuse_marginalized_landmarks,
        );
        set(&mut cfg.estimate_extrinsic, self.estimate_extrinsic);
        let i = &self.imu;
        let n: &mut ImuNoise = &mut cfg.imu_noise;
        set(&mut n.gyro_noise_density, i.gyro_noise_density);
        set(&mut n.accel_noise_density, i.accel_noise_density);
        set(&mut n.gyro_bias_rw, i.gyro_bias_rw);
        set(&mut n.accel_bias_rw, i.accel_bias_rw);
        if i.bias_corr_time_s.is_some() {
            n.bias_corr_time_s = i.bias_corr_time_s;
        }
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
    }
}

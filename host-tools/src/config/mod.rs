//! `--config FILE.toml`: the estimator and front-end settings, read straight into the core's
//! configuration types (`povins-core` feature `serde`).
//!
//! The documentation of every key is the doc comment of its field in the core:
//! - the top level is [`EstimatorConfig`] (with its tables `[camera]`, `[extrinsic]`,
//!   `[imu_noise]` ([`povins_core::inertial::ImuNoise`]), `[keyframe]`, `[static_init]`,
//!   `[rest]`, `[preint]`, `[first_prior]`, `[lm_first]` / `[lm_second]`
//!   ([`povins_core::solver::LmConfig`]), `[solve_budget]`
//!   ([`povins_core::estimator::SolveBudget`]), `[zupt]`, `[td]`, `[cull]`
//!   ([`povins_core::estimator::ZuptConfig`], [`povins_core::estimator::TdConfig`],
//!   [`povins_core::estimator::CullConfig`]), `[imu_noise_adapt]`, `[health]`, `[lidar]`,
//!   `[lidar.extrinsic]`, `[lidar.association]`);
//! - `[frontend]` is the image front end's [`TrackerConfig`] (`[frontend.detector]`,
//!   `[frontend.lk]`, `[frontend.ransac]`, `[frontend.reference]`: the anchored refinement,
//!   `enabled = true` to turn it on; `[frontend.provisional]`: the first-steps check of new
//!   tracks against occlusion-edge corners, `enabled = true` to turn it on) and `[aiding]` its
//!   [`VioAiding`];
//! - `[input]` is the host side's [`InputOptions`] (the recording's topics and calibration files,
//!   [`input`]); it is not laid over the estimator.
//!
//! Every key is optional: the file is laid over the configuration the dataset gives (its camera,
//! extrinsics, IMU noise, gravity, camera delay and LiDAR), key by key, nested tables merged.
//! Unknown keys are errors naming the file and the key; a key that moved into a table (`[zupt]`,
//! `[td]`, `[cull]`: [`MOVED`]) is an error naming its new place. Enums are kebab-case strings
//! (`mode = "inverse-depth"`), or a one-key table for a variant with fields
//! (`equalization = { clahe = { clip_limit = 3.0, tiles_x = 8, tiles_y = 8 } }`); vectors are
//! arrays, quaternions `[x, y, z, w]` (normalized; the norm must be 1 within 1e-3); angles are in
//! radians (`keyframe.max_rotation_rad`). An option (`keyframe.min_parallax_px`,
//! `imu_noise.bias_corr_time_s`) is set by giving it and left unset by omitting it.
//!
//! ```toml
//! mode = "pose-only"            # or "inverse-depth"
//! sigma_px = 1.5
//!
//! [imu_noise]                   # replaces the dataset's noise model
//! gyro_noise_density = 2.0e-3
//! accel_noise_density = 2.9e-2
//!
//! [lm_second]
//! max_iterations = 4
//!
//! [lidar]
//! ldm = "direct"
//! [lidar.extrinsic]             # replaces the dataset's T_bl
//! p_bl = [0.0, 0.0, 0.1]
//! q_bl = [0.0, 0.0, 0.0, 1.0]
//!
//! [frontend]
//! max_features = 200
//! [frontend.detector]
//! min_distance_px = 15.0
//! ```
//!
//! `povins run` writes the effective configuration of the run (every key) as `config.toml` into
//! its output folder; given back as `--config`, it reproduces the run's configuration exactly.
//! The command-line switches ([`LidarArgs`], `--mode`) override the file.

mod args;
pub mod input;
#[cfg(test)]
mod tests;

pub use args::{ldm_name, LdmArg, LidarArgs, ModeArg};
pub use input::{AccelUnit, InputArgs, InputOptions};

use anyhow::{anyhow, Context, Result};
use povins_core::estimator::EstimatorConfig;
use povins_core::frontend::image::TrackerConfig;
use povins_core::vio::VioAiding;
use std::path::Path;
use toml::{Table, Value};

/// Top-level tables that are not part of [`EstimatorConfig`].
const FRONTEND: &str = "frontend";
const AIDING: &str = "aiding";
/// The host-side `[input]` table ([`InputOptions`]).
const INPUT: &str = "input";

/// Top-level keys that moved into a table: `(old key, table, new keys)`. A file giving an old
/// key is refused with an error naming the new ones (two new keys: the old value was a pair).
pub const MOVED: &[(&str, &str, &[&str])] = &[
    ("zupt", "zupt", &["enabled"]),
    ("zupt_sigma_mps", "zupt", &["sigma_mps"]),
    ("zupt_max_speed_mps", "zupt", &["max_speed_mps"]),
    (
        "zupt_motion_sigma",
        "zupt",
        &["motion_sigma_m", "motion_sigma_rad"],
    ),
    ("estimate_td", "td", &["estimate"]),
    ("td_rw_s_per_sqrt_s", "td", &["rw_s_per_sqrt_s"]),
    ("td_prior_s", "td", &["prior_s"]),
    ("chi2_threshold", "cull", &["chi2_threshold"]),
    (
        "second_pass_min_culled_frac",
        "cull",
        &["second_pass_min_culled_frac"],
    ),
    ("cull_mean_px", "cull", &["mean_px"]),
    ("cull_obs_px", "cull", &["obs_px"]),
    ("cull_whole_tracks", "cull", &["whole_tracks"]),
];

/// Keys replaced by a key of other meaning: `(table or "" for the top level, old key, new key in
/// the same table, what changed)`. A file giving an old key is refused with an error naming the
/// new one.
pub const REPLACED: &[(&str, &str, &str, &str)] = &[
    (
        "td",
        "min_landmarks",
        "min_info_per_s2",
        "the delay is held while the observations carry too little information on it (1/s^2), \
         not while there are too few landmarks",
    ),
    (
        "",
        "td_min_landmarks",
        "[td] min_info_per_s2",
        "the delay is held while the observations carry too little information on it (1/s^2), \
         not while there are too few landmarks",
    ),
];

/// The error for the first key of `user` that was replaced ([`REPLACED`]).
fn replaced_key(user: &Table) -> Option<anyhow::Error> {
    REPLACED.iter().find_map(|&(table, old, new, why)| {
        let (place, scope) = if table.is_empty() {
            (format!("`{old}`"), Some(user))
        } else {
            (
                format!("`[{table}] {old}`"),
                user.get(table).and_then(Value::as_table),
            )
        };
        scope?.get(old)?;
        let new = if table.is_empty() {
            format!("`{new}`")
        } else {
            format!("`[{table}] {new}`")
        };
        Some(anyhow!("{place} was replaced by {new}: {why}"))
    })
}

/// The error for the first key of `user`'s top level that moved into a table ([`MOVED`]).
fn moved_key(user: &Table) -> Option<anyhow::Error> {
    MOVED.iter().find_map(|&(old, table, new)| {
        let v = user.get(old)?;
        // `zupt` names the old switch and the new table: a table is the new form.
        if old == table && v.is_table() {
            return None;
        }
        let new: Vec<String> = new.iter().map(|k| format!("`[{table}] {k}`")).collect();
        Some(anyhow!("`{old}` moved to {}", new.join(" and ")))
    })
}

/// A parsed configuration file: the user's keys, to be laid over a base configuration.
#[derive(Debug, Clone)]
pub struct RunConfigFile {
    /// Where it came from (for the errors).
    source: String,
    /// The folder of the file: relative paths in `[input]` are relative to it.
    dir: Option<std::path::PathBuf>,
    /// The file's keys.
    table: Table,
}

impl RunConfigFile {
    /// Reads and parses a file (errors name the file).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        let mut f = Self::parse_named(&text, &path.display().to_string())?;
        f.dir = Some(path.parent().unwrap_or(Path::new("")).to_path_buf());
        Ok(f)
    }

    /// Parses TOML text. The keys are checked when the file is applied (against the
    /// configuration it is laid over: a field of an enum variant, such as
    /// `[camera.distortion.rad-tan]`, is valid only where that variant is in force).
    pub fn parse(text: &str) -> Result<Self> {
        Self::parse_named(text, "<text>")
    }

    fn parse_named(text: &str, source: &str) -> Result<Self> {
        let table: Table =
            toml::from_str(text).with_context(|| format!("invalid config {source}"))?;
        Ok(RunConfigFile {
            source: source.to_string(),
            dir: None,
            table,
        })
    }

    /// Lays the file's estimator keys over `cfg`; errors name the file and the offending key,
    /// or say which range check failed. `cfg` is unchanged on error.
    pub fn apply(&self, cfg: &mut EstimatorConfig) -> Result<()> {
        let mut user = self.table.clone();
        user.remove(FRONTEND);
        user.remove(AIDING);
        user.remove(INPUT);
        if let Some(e) = moved_key(&user).or_else(|| replaced_key(&user)) {
            return Err(self.error(e));
        }
        let merged: EstimatorConfig = overlay(cfg, &user).map_err(|e| self.error(e))?;
        // The core's one list of range checks names the key, the value and the range.
        if let Some(bad) = merged.find_invalid() {
            let path = bad.key.split('[').next().unwrap_or(bad.key);
            let mut at = Some(&user);
            let mut set = false;
            for (k, part) in path.split('.').enumerate() {
                let v = at.and_then(|t| t.get(part));
                set = v.is_some() && k == path.split('.').count() - 1;
                at = v.and_then(Value::as_table);
            }
            let source = if set {
                ""
            } else {
                " (not set in this file: the value it was laid over, from the recording's \
                 calibration or the defaults)"
            };
            return Err(anyhow!("config {}: {bad}{source}", self.source));
        }
        *cfg = merged;
        Ok(())
    }

    /// Lays the `[frontend]` and `[aiding]` tables over the image front end's settings and INS
    /// aiding; errors when a key is unknown or the result is invalid.
    pub fn apply_frontend(&self, t: &mut TrackerConfig, aiding: &mut VioAiding) -> Result<()> {
        let section = |name: &str| -> Result<Table> {
            match self.table.get(name) {
                None => Ok(Table::new()),
                Some(Value::Table(s)) => Ok(Table::from_iter([(
                    name.to_string(),
                    Value::Table(s.clone()),
                )])),
                Some(_) => Err(self.error(anyhow!("`{name}` must be a table"))),
            }
        };
        let tracker: TrackerConfig =
            overlay_section(t, FRONTEND, &section(FRONTEND)?).map_err(|e| self.error(e))?;
        let aid: VioAiding =
            overlay_section(aiding, AIDING, &section(AIDING)?).map_err(|e| self.error(e))?;
        // The ranges here; what the front end's capacity allows is checked against the type
        // the run builds (`RunSetup::check`).
        if tracker.validate().is_err() {
            return Err(self.error(anyhow!(
                "[frontend]: invalid settings (levels of the seeds <= max_level, odd windows \
                 5..=31, grid and thresholds positive): {tracker:?}"
            )));
        }
        *t = tracker;
        *aiding = aid;
        Ok(())
    }

    fn error(&self, e: anyhow::Error) -> anyhow::Error {
        e.context(format!("invalid config {}", self.source))
    }
}

/// A configuration to check files against: EuRoC's camera and IMU (tests).
#[cfg(test)]
fn default_base() -> EstimatorConfig {
    use povins_core::camera::{CameraExtrinsic, PinholeCamera};
    use povins_core::math::{Quat, Vec3};
    let ext = CameraExtrinsic {
        p_bc: Vec3::zeros(),
        q_bc: Quat::identity(),
    };
    EstimatorConfig::new(
        PinholeCamera::EUROC_CAM0,
        ext,
        povins_core::inertial::ImuNoise::EUROC_ADIS16448,
    )
}

/// The effective configuration of a run as TOML: every key, loadable by [`RunConfigFile`].
pub fn effective_toml(
    cfg: &EstimatorConfig,
    tracker: &TrackerConfig,
    aiding: &VioAiding,
) -> Result<String> {
    let mut t = Table::try_from(cfg).context("cannot serialize the estimator configuration")?;
    t.insert(FRONTEND.into(), Value::try_from(tracker)?);
    t.insert(AIDING.into(), Value::try_from(aiding)?);
    Ok(format!(
        "# Effective configuration of this run (every key; `povins run --config` this file to \
         repeat it).\n# The keys are documented on povins_core's configuration types: \
         EstimatorConfig, TrackerConfig ([frontend]), VioAiding ([aiding]).\n\n{}",
        toml::to_string_pretty(&t)?
    ))
}

/// `user` laid over `base` (serialized), deserialized again.
fn overlay<T>(base: &T, user: &Table) -> Result<T>
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    let mut merged = Table::try_from(base).context("cannot serialize the base configuration")?;
    let mut unknown = Vec::new();
    merge(&mut merged, user, "", &mut unknown);
    merged
        .try_into::<T>()
        .map_err(|e| explain(&e.to_string(), &unknown))
}

/// `user` (the table `{ name = {...} }` or empty) laid over `base` as the table `name`.
fn overlay_section<T>(base: &T, name: &str, user: &Table) -> Result<T>
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    let mut merged = Table::new();
    merged.insert(name.to_string(), Value::try_from(base)?);
    let mut unknown = Vec::new();
    merge(&mut merged, user, "", &mut unknown);
    let section = merged.remove(name).unwrap_or(Value::Table(Table::new()));
    section
        .try_into::<T>()
        .map_err(|e| explain(&e.to_string(), &unknown))
}

/// A key of the user's file that the base does not have, and the keys the base has there.
#[derive(Debug)]
struct UnknownKey {
    path: String,
    valid: Vec<String>,
}

/// Merges `user` into `base` key by key; nested tables merge, anything else replaces. A one-key
/// table replacing a different one-key table (an enum variant with fields, such as
/// `distortion`) replaces it whole.
fn merge(base: &mut Table, user: &Table, prefix: &str, unknown: &mut Vec<UnknownKey>) {
    for (k, v) in user {
        let path = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match (base.get_mut(k), v) {
            (Some(Value::Table(b)), Value::Table(u)) if !switches_variant(b, u) => {
                merge(b, u, &path, unknown)
            }
            (Some(slot), _) => *slot = v.clone(),
            (None, _) => {
                unknown.push(UnknownKey {
                    path,
                    valid: base.keys().cloned().collect(),
                });
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

fn switches_variant(base: &Table, user: &Table) -> bool {
    base.len() == 1 && user.len() == 1 && base.keys().ne(user.keys())
}

/// The deserializer's message, with the key's full path when it is about an unknown key.
fn explain(msg: &str, unknown: &[UnknownKey]) -> anyhow::Error {
    let msg = msg.trim();
    let named = msg
        .split_once("unknown field `")
        .and_then(|(_, rest)| rest.split_once('`'))
        .map(|(name, _)| name);
    let hit = unknown
        .iter()
        .find(|u| Some(u.path.rsplit('.').next().unwrap_or(&u.path)) == named);
    match hit {
        Some(u) => anyhow!(
            "unknown key `{}` ({msg}; the keys there: {})",
            u.path,
            u.valid.join(", ")
        ),
        None if !unknown.is_empty() => {
            let paths: Vec<&str> = unknown.iter().map(|u| u.path.as_str()).collect();
            anyhow!(
                "{msg} (keys not in the base configuration: {})",
                paths.join(", ")
            )
        }
        None => anyhow!("{msg}"),
    }
}

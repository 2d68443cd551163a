//! One run setup: what a run of the estimator needs, read once from the recording (its
//! calibration: [`crate::runner::config_for`]), the TOML file (`--config`, laid over it, the
//! estimator's and the front end's keys in one read) and the command line (the switches, laid
//! over both). `povins run`, `replay --realtime` and `timing` take the same [`RunArgs`]; `demo`,
//! `regress` and `ablation` start from [`RunSetup::defaults`]. The front end's capacity is
//! checked against the camera here (the platform's one dispatch,
//! [`povins_platform::odometry::check`]), so a setting that does not fit is an error naming the
//! file before anything runs.

use crate::config::input::open_bag;
use crate::config::{effective_toml, InputArgs, InputOptions, LidarArgs, ModeArg, RunConfigFile};
use crate::progress::Progress;
use crate::runner::{
    config_for, replay_into, replay_with, Frontend, FrontendOptions, InitMode, RunOutput, RunSink,
    RunTotals,
};
use anyhow::{Context, Result};
use povins_core::estimator::{EstimatorConfig, KnownBiases};
use povins_platform::recording::Recording;
use std::path::{Path, PathBuf};

/// The command-line arguments that name a recording and how to open it (`run`, `timing`,
/// `convert`).
#[derive(clap::Args, Debug, Clone)]
pub struct RecordingArgs {
    /// EuRoC ASL folder (containing `mav0/`), an `.mcap` file written by povins, or a ROS
    /// recording (a ROS 1 `.bag`, a ROS 2 bag folder or `.db3` file, any other `.mcap` file)
    /// with its calibration (`--calib`, or its own CameraInfo and `/tf_static`).
    pub dataset: PathBuf,
    /// The recording's calibration files and topics (override the config's `[input]`).
    #[command(flatten)]
    pub input: InputArgs,
}

impl RecordingArgs {
    /// Opens the recording named by `dataset`: a ROS recording with the calibration and topics
    /// of the switches and `config`'s `[input]` ([`InputOptions`]), laid over `config`'s
    /// `[imu_noise]` when no file gives the IMU noise.
    pub fn open(&self, config: Option<&Path>) -> Result<Box<dyn Recording>> {
        let file = config.map(RunConfigFile::read).transpose()?;
        let input = InputOptions::new(file.as_ref(), &self.input)?;
        if !povins_platform::containers::is_ros_recording(&self.dataset) {
            anyhow::ensure!(
                !input.any_for_bags(),
                "--calib, --imu-calib, --camera, --imu-topic, --image-topic, --accel-topic, \
                 --accel-unit, --lidar-topic, --lidar-layout and --lidar-no-time (and their \
                 `[input]` keys) apply to ROS recordings only"
            );
            return Ok(povins_platform::open_recording(&self.dataset)?);
        }
        let toml_noise = file
            .as_ref()
            .map(RunConfigFile::imu_noise)
            .transpose()?
            .flatten();
        open_bag(&self.dataset, &input, toml_noise)
    }
}

/// Longest time from a previous run's last keyframe to the recording's first IMU sample that
/// `--biases-from` takes without a warning.
const BIASES_MAX_AGE_S: f64 = 600.0;

/// Why the biases of a previous run ending at `t_ns` may not be this recording's IMU's: that run
/// ends after this recording starts (another session of the sensor, or its clock restarted), or
/// long before it. Turn-on biases change with each power cycle (`KnownBiases`).
fn biases_stamp_warning(rec: &dyn Recording, t_ns: i64) -> Result<Option<String>> {
    let Some(first) = rec.imu()?.next().transpose()? else {
        return Ok(None);
    };
    let age_s = first.t_ns.saturating_sub(t_ns) as f64 * 1e-9;
    Ok(if age_s < 0.0 {
        Some(format!(
            "the previous run's last keyframe ({:.3} s) is after this recording's first IMU \
             sample ({:.3} s): not a run of the same IMU session? Biases from another power cycle \
             differ by the IMU's bias repeatability, which [init.biases] gyro_sd_rps and \
             accel_sd_mps2 must then cover",
            t_ns as f64 * 1e-9,
            first.t_ns as f64 * 1e-9
        ))
    } else if age_s > BIASES_MAX_AGE_S {
        Some(format!(
            "the previous run ended {age_s:.0} s before this recording starts: biases drift, and \
             change with each power cycle ([init.biases] gyro_sd_rps and accel_sd_mps2 must cover \
             it)"
        ))
    } else {
        None
    })
}

/// The command-line arguments every estimating command over a recording takes.
#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    /// The recording.
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// How to initialize.
    #[arg(long, value_enum, default_value = "auto")]
    pub init: InitMode,
    /// TOML file of estimator and front-end settings (docs/formats.md).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// What feeds the estimator: the camera images through povins' front end, or the
    /// dataset's feature tracks (default: images when the dataset has them, else tracks).
    #[arg(long, value_enum)]
    pub frontend: Option<Frontend>,
    /// Visual measurement model (overrides the config file).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// LiDAR switches (override the config file).
    #[command(flatten)]
    pub lidar: LidarArgs,
    /// The IMU's biases known before the start, from the last row of a previous run's
    /// `keyframes_state.csv` on the same IMU, not powered off since (a restarted process): the
    /// prior of a start in motion (`[init.biases]`, its standard deviations from `--config`
    /// when it gives them, else 0.0005 rad/s and 0.02 m/s^2).
    #[arg(long, value_name = "KEYFRAMES_STATE_CSV")]
    pub biases_from: Option<PathBuf>,
    /// Time the estimator's stages (`stats.csv`, the back-end figures of the summary) by the
    /// thread's CPU time instead of the wall clock: the work done, without the time the OS gave
    /// to other processes (worst cases compared on a shared machine). The output is the same.
    #[arg(long)]
    pub cpu_time: bool,
}

impl RunArgs {
    /// Opens the recording ([`RecordingArgs::open`] with `--config`'s `[input]`), and selects
    /// the core's timing clock (`--cpu-time`) for the run.
    pub fn open(&self) -> Result<Box<dyn Recording>> {
        crate::runner::use_cpu_time(self.cpu_time);
        self.recording.open(self.config.as_deref())
    }
}

/// What a run needs besides its recording (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct RunSetup {
    /// The estimator's configuration.
    pub estimator: EstimatorConfig,
    /// The front end and its settings.
    pub frontend: FrontendOptions,
    /// How the estimator starts.
    pub init: InitMode,
}

/// The front end a recording gets without `--frontend`: its images when it has them.
pub fn default_frontend(rec: &dyn Recording) -> Frontend {
    if rec.contents().images {
        Frontend::Images
    } else {
        Frontend::Tracks
    }
}

impl RunSetup {
    /// The defaults for `rec`: its calibration, the front end for what it has, started as
    /// `init`.
    pub fn defaults(rec: &dyn Recording, init: InitMode) -> Self {
        let frontend = match default_frontend(rec) {
            Frontend::Images => FrontendOptions::images(Default::default()),
            Frontend::Tracks => FrontendOptions::tracks(),
        };
        RunSetup {
            estimator: config_for(rec),
            frontend,
            init,
        }
    }

    /// `rec`'s defaults with `a`'s file and switches (see the module docs). Errors name the
    /// file and the key, or the setting that does not fit.
    pub fn from_args(rec: &dyn Recording, a: &RunArgs) -> Result<Self> {
        let mut s = Self::defaults(rec, a.init);
        if let Some(f) = a.frontend {
            s.frontend.frontend = f;
        }
        // `--biases-from`: the file's biases, with the config file's standard deviations when
        // it gives them (laid over these), else the defaults for a previous run's.
        let biases = a
            .biases_from
            .as_ref()
            .map(|path| -> Result<_> {
                let (t_ns, gyro, accel) = crate::report::files::read_last_biases(path)?;
                if let Some(w) = biases_stamp_warning(rec, t_ns)? {
                    eprintln!("warning: --biases-from {}: {w}", path.display());
                }
                Ok(KnownBiases::from_previous_run(gyro.into(), accel.into()))
            })
            .transpose()?;
        s.estimator.init.biases = biases.or(s.estimator.init.biases);
        if let Some(path) = &a.config {
            s.apply_file(path)?;
        }
        if let (Some(given), Some(b)) = (biases, s.estimator.init.biases.as_mut()) {
            (b.gyro_rps, b.accel_mps2) = (given.gyro_rps, given.accel_mps2);
        }
        if let Some(m) = a.mode {
            s.estimator.mode = m.into();
        }
        a.lidar.apply(&mut s.estimator.lidar);
        let from = a
            .config
            .as_ref()
            .map_or("the recording's calibration".to_string(), |p| {
                format!("config {} or the recording's calibration", p.display())
            });
        // The file's values were checked as it was applied: what is left came from the
        // recording's calibration (Kalibr's `timeshift_cam_imu` as `td_s`, ...).
        if let Some(bad) = s.estimator.find_invalid() {
            anyhow::bail!(
                "{}: the recording's calibration gives {bad}{}",
                rec.name(),
                calibration_hint(bad.key)
            );
        }
        // A zero image size is how a recording without a camera says so: with camera data it
        // would refuse every feature.
        let has = rec.contents();
        let cam = s.estimator.camera;
        if has.frames || has.images {
            for (key, v) in [("camera.width", cam.width), ("camera.height", cam.height)] {
                anyhow::ensure!(
                    v > 0,
                    "{}: {key} = {v} (from {from}) is out of range for a recording with camera \
                     data (allowed: >= 1 px)",
                    rec.name()
                );
            }
        }
        s.check().with_context(|| {
            a.config
                .as_ref()
                .map_or("the run's settings".to_string(), |p| {
                    format!("the run's settings (with {})", p.display())
                })
        })?;
        Ok(s)
    }

    /// Lays the TOML file at `path` over the estimator's and the front end's settings (read
    /// once).
    pub fn apply_file(&mut self, path: &Path) -> Result<()> {
        let file = RunConfigFile::read(path)?;
        file.apply(&mut self.estimator)?;
        file.apply_frontend(&mut self.frontend.tracker, &mut self.frontend.aiding)
    }

    /// Whether the core accepts the settings for the front end's capacity.
    pub fn check(&self) -> Result<()> {
        Ok(povins_platform::odometry::check(
            &self.estimator,
            &self.frontend.front_end(),
        )?)
    }

    /// The visual mode's name for the summaries.
    pub fn mode_name(&self) -> String {
        format!("{:?}", self.estimator.mode)
    }

    /// The effective configuration as TOML (every key, `--config` it to repeat the run).
    pub fn effective_toml(&self) -> Result<String> {
        effective_toml(
            &self.estimator,
            &self.frontend.tracker,
            &self.frontend.aiding,
        )
    }

    /// Notes for the user about `rec` and these settings (LiDAR switches without a LiDAR, a
    /// LiDAR without an extrinsic).
    pub fn notes(&self, rec: &dyn Recording, lidar_args: &LidarArgs) -> Vec<String> {
        let has = rec.contents();
        let mut v = Vec::new();
        if !has.lidar && lidar_args.any() {
            v.push("note: no LiDAR in dataset; the LiDAR switches change nothing".to_string());
        }
        if has.lidar && rec.calibration().t_bl.is_none() && !self.estimator.lidar.enabled {
            v.push(
                "note: the dataset has LiDAR sweeps but no LiDAR extrinsic T_bl, so LiDAR is off \
                 (set lidar.enabled and lidar.extrinsic.p_bl / q_bl in the config to use it)"
                    .to_string(),
            );
        }
        v
    }

    /// Replays `rec` with these settings ([`replay_with`]).
    pub fn replay(&self, rec: &dyn Recording, progress: &Progress) -> Result<RunOutput> {
        replay_with(rec, self.estimator, self.init, &self.frontend, progress)
    }

    /// Replays `rec` with these settings into `sink` ([`replay_into`]).
    pub fn replay_into(
        &self,
        rec: &dyn Recording,
        progress: &Progress,
        sink: &mut impl RunSink,
    ) -> Result<RunTotals> {
        replay_into(
            rec,
            self.estimator,
            self.init,
            &self.frontend,
            progress,
            sink,
        )
    }
}

/// Where a calibration's out-of-range setting comes from, for the error.
fn calibration_hint(key: &str) -> &'static str {
    match key {
        "td_s" => {
            " (the camera-IMU delay, `t_imu = t_cam + td`: EuRoC cam0/sensor.yaml or Kalibr \
             camchain `timeshift_cam_imu`, in seconds; `td_s` in a --config file overrides it)"
        }
        _ => " (a --config file can override it)",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::{CameraExtrinsic, PinholeCamera};
    use povins_core::frontend::image::TrackerConfig;
    use povins_core::math::{Quat, Vec3};

    fn setup(camera: PinholeCamera, tracker: TrackerConfig) -> RunSetup {
        let ext = CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: Quat::identity(),
        };
        RunSetup {
            estimator: EstimatorConfig::new(
                camera,
                ext,
                povins_core::inertial::ImuNoise::EUROC_ADIS16448,
            ),
            frontend: FrontendOptions::images(tracker),
            init: InitMode::Static,
        }
    }

    #[test]
    fn the_front_ends_capacity_is_checked_for_the_camera() {
        let euroc = PinholeCamera::EUROC_CAM0;
        assert!(setup(euroc, TrackerConfig::default()).check().is_ok());
        let too_many = TrackerConfig {
            max_features: 300,
            ..TrackerConfig::default()
        };
        let e = setup(euroc, too_many)
            .check()
            .expect_err("256 features at most");
        assert!(format!("{e:#}").contains("invalid"), "{e:#}");
        let huge = PinholeCamera {
            readout_s: 0.0,
            width: 1921,
            height: 1200,
            ..euroc
        };
        let e = setup(huge, TrackerConfig::default())
            .check()
            .expect_err("larger than the largest capacity");
        assert!(
            format!("{e:#}").contains(
                "1921x1200 images are larger than the front end's largest capacity (1920x1200)"
            ),
            "{e:#}"
        );
    }
}

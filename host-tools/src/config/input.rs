//! The host-side `[input]` table of the run TOML and its command-line switches: which topics of a
//! recording to read and where its calibration is. The switches override the table key by key.
//!
//! ```toml
//! [input]
//! calib = "kalibr/camchain-imucam.yaml"  # a Kalibr camchain file, or an EuRoC folder
//! imu_calib = "kalibr/imu.yaml"          # a Kalibr imu.yaml
//! camera = "cam0"                        # the camchain's camera
//! imu_topic = "/imu0"
//! image_topic = "/cam0/image_raw"
//! lidar_topic = "/points"                # PointCloud2 or Livox CustomMsg
//! lidar_layout = "auto"                  # or a driver's: "ouster" | "velodyne" | "hesai" |
//!                                        # "robosense" | "livox2" | "compact"
//! lidar_no_time = "stamp"                # clouds without point times: "stamp" | "spin-start" |
//!                                        # "spin-end" (points spread by azimuth)
//! lidar_spin = "cw"                      # "cw" | "ccw", seen from above, for "spin-*"
//! lidar_sweep_period_s = 0.1             # for "spin-*"
//! accel_topic = "/camera/accel/sample"
//! accel_unit = "auto"                    # "mps2" | "g" | "auto"
//! ```
//!
//! How LiDAR clouds are read, and what the layouts are: [`povins_platform::cloud`].
//!
//! Relative paths in the table are relative to the TOML file's folder (on the command line, to
//! the working directory). Unknown keys are errors naming the file and the key.
//!
//! The calibration of a ROS 1 bag ([`InputOptions::calibration`]): `calib` a directory is an
//! EuRoC folder (its `cam0` and `imu0` `sensor.yaml`), a file is a Kalibr camchain
//! ([`povins_platform::kalibr`]). The IMU noise comes from `imu_calib` (it replaces an EuRoC
//! folder's), else the EuRoC folder, else the four densities of the TOML's `[imu_noise]`;
//! without any of them the run is refused naming all three places.

use super::RunConfigFile;
use anyhow::{anyhow, bail, Context, Result};
use povins_core::inertial::ImuNoise;
use povins_platform::dataset::{Calibration, Extrinsic};
use povins_platform::kalibr::{self, KalibrCalibration, KalibrCamera, KalibrImu};
use povins_platform::recording::Recording;
use povins_platform::rosrec::MessageLog;
use serde::Deserialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The unit of the accelerometer's samples (`[input] accel_unit`, `--accel-unit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum AccelUnit {
    /// m/s^2 (ROS' `sensor_msgs/Imu` unit).
    Mps2,
    /// Standard gravities (some LiDARs' built-in IMUs).
    G,
    /// Told from the magnitude ([`povins_platform::rosrec::merge`]).
    #[default]
    Auto,
}

impl From<AccelUnit> for povins_platform::rosrec::merge::AccelUnit {
    fn from(u: AccelUnit) -> Self {
        use povins_platform::rosrec::merge::AccelUnit as P;
        match u {
            AccelUnit::Mps2 => P::Mps2,
            AccelUnit::G => P::G,
            AccelUnit::Auto => P::Auto,
        }
    }
}

/// A driver's PointCloud2 layout (`[input] lidar_layout`, `--lidar-layout`; absent: told from
/// the cloud, [`povins_platform::cloud`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LidarLayout {
    /// Told from the cloud's fields and values.
    Auto,
    /// povins' own 20-byte points.
    Compact,
    /// ouster-ros.
    Ouster,
    /// velodyne_pointcloud XYZIRT.
    Velodyne,
    /// Hesai ROS drivers.
    Hesai,
    /// RoboSense rslidar_sdk XYZIRT.
    Robosense,
    /// livox_ros_driver2's PointCloud2.
    Livox2,
}

impl LidarLayout {
    fn layout(self) -> Option<povins_platform::cloud::Layout> {
        use povins_platform::cloud::Layout as L;
        match self {
            LidarLayout::Auto => None,
            LidarLayout::Compact => Some(L::Compact),
            LidarLayout::Ouster => Some(L::Ouster),
            LidarLayout::Velodyne => Some(L::Velodyne),
            LidarLayout::Hesai => Some(L::Hesai),
            LidarLayout::Robosense => Some(L::Robosense),
            LidarLayout::Livox2 => Some(L::Livox2),
        }
    }
}

/// What a cloud without point times is taken to mean (`[input] lidar_no_time`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum LidarNoTime {
    /// Every point at the stamp (no de-skew).
    #[default]
    Stamp,
    /// Spread by azimuth over the sweep period, the stamp the sweep's start.
    SpinStart,
    /// Spread by azimuth over the sweep period, the stamp the sweep's end.
    SpinEnd,
}

/// The spin direction seen from above (`[input] lidar_spin`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LidarSpin {
    /// Clockwise (azimuth decreasing).
    #[default]
    Cw,
    /// Counter-clockwise.
    Ccw,
}

/// Default `lidar_sweep_period_s` (10 Hz).
pub const DEFAULT_SWEEP_PERIOD_S: f64 = 0.1;

/// The `[input]` keys (see the module docs).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputOptions {
    /// The IMU topic.
    pub imu_topic: Option<String>,
    /// The camera topic.
    pub image_topic: Option<String>,
    /// The LiDAR topic.
    pub lidar_topic: Option<String>,
    /// The LiDAR clouds' layout (absent: told from each cloud).
    pub lidar_layout: Option<LidarLayout>,
    /// What a cloud without point times is taken to mean.
    #[serde(default)]
    pub lidar_no_time: LidarNoTime,
    /// Spin direction for `lidar_no_time = "spin-*"`.
    #[serde(default)]
    pub lidar_spin: LidarSpin,
    /// Sweep period for `lidar_no_time = "spin-*"`, s.
    pub lidar_sweep_period_s: Option<f64>,
    /// A separate accelerometer topic, merged into the IMU's.
    pub accel_topic: Option<String>,
    /// Kalibr camchain file or EuRoC folder.
    pub calib: Option<PathBuf>,
    /// Kalibr `imu.yaml`.
    pub imu_calib: Option<PathBuf>,
    /// The camchain's camera, `camN`.
    pub camera: Option<String>,
    /// The accelerometer's unit.
    #[serde(default)]
    pub accel_unit: AccelUnit,
}

/// The command-line switches of [`InputOptions`].
#[derive(clap::Args, Debug, Clone, Default)]
pub struct InputArgs {
    /// Calibration of a ROS 1 bag: a Kalibr `camchain-imucam.yaml` file, or an EuRoC ASL folder
    /// whose `imu0` and `cam0` `sensor.yaml` give it (overrides `[input] calib`).
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Kalibr `imu.yaml` with the IMU noise (overrides `[input] imu_calib`).
    #[arg(long)]
    pub imu_calib: Option<PathBuf>,
    /// The camera of the Kalibr camchain, `camN` (default `cam0`).
    #[arg(long)]
    pub camera: Option<String>,
    /// IMU topic of a bag (default: the Kalibr `rostopic` when the bag has it, else its one
    /// `sensor_msgs/Imu` topic).
    #[arg(long)]
    pub imu_topic: Option<String>,
    /// Camera topic of a bag (default: the Kalibr `rostopic` when the bag has it, else its one
    /// `sensor_msgs/Image` or `CompressedImage` topic).
    #[arg(long)]
    pub image_topic: Option<String>,
    /// LiDAR topic of a bag: `sensor_msgs/PointCloud2` or Livox `CustomMsg` (default: its one
    /// such topic; with several, none is read and a warning lists them).
    #[arg(long)]
    pub lidar_topic: Option<String>,
    /// The LiDAR clouds' point layout (default: told from each cloud's fields and values).
    #[arg(long, value_enum)]
    pub lidar_layout: Option<LidarLayout>,
    /// What a cloud without per-point times is taken to mean (default: every point at the
    /// stamp, with a warning).
    #[arg(long, value_enum)]
    pub lidar_no_time: Option<LidarNoTime>,
    /// Accelerometer topic to merge into the IMU's, interpolated to the gyro's stamps (default:
    /// a RealSense `.../gyro/...` and `.../accel/...` pair is found by name).
    #[arg(long)]
    pub accel_topic: Option<String>,
    /// The accelerometer's unit (default: told from the magnitude of its first samples).
    #[arg(long, value_enum)]
    pub accel_unit: Option<AccelUnit>,
}

impl InputOptions {
    /// The `[input]` table of `file` (empty when it has none), paths made relative to its folder.
    pub fn from_file(file: &RunConfigFile) -> Result<Self> {
        let Some(v) = file.table.get(super::INPUT) else {
            return Ok(Self::default());
        };
        let mut o: InputOptions = v
            .clone()
            .try_into()
            .map_err(|e| file.error(anyhow!("[input]: {}", e.to_string().trim())))?;
        if let Some(dir) = &file.dir {
            for p in [&mut o.calib, &mut o.imu_calib].into_iter().flatten() {
                if p.is_relative() {
                    *p = dir.join(&*p);
                }
            }
        }
        o.validate().map_err(|e| file.error(e.context("[input]")))?;
        Ok(o)
    }

    /// The options of `config` (if any) with `args` laid over them.
    pub fn new(config: Option<&RunConfigFile>, args: &InputArgs) -> Result<Self> {
        let mut o = match config {
            Some(f) => Self::from_file(f)?,
            None => Self::default(),
        };
        let pick = |cli: &Option<String>, slot: &mut Option<String>| {
            if cli.is_some() {
                slot.clone_from(cli);
            }
        };
        pick(&args.imu_topic, &mut o.imu_topic);
        pick(&args.image_topic, &mut o.image_topic);
        pick(&args.lidar_topic, &mut o.lidar_topic);
        pick(&args.accel_topic, &mut o.accel_topic);
        pick(&args.camera, &mut o.camera);
        if args.calib.is_some() {
            o.calib.clone_from(&args.calib);
        }
        if args.imu_calib.is_some() {
            o.imu_calib.clone_from(&args.imu_calib);
        }
        if let Some(u) = args.accel_unit {
            o.accel_unit = u;
        }
        if args.lidar_layout.is_some() {
            o.lidar_layout = args.lidar_layout;
        }
        if let Some(n) = args.lidar_no_time {
            o.lidar_no_time = n;
        }
        o.validate().context("the input switches")?;
        Ok(o)
    }

    fn validate(&self) -> Result<()> {
        for (key, v) in [
            ("imu_topic", &self.imu_topic),
            ("image_topic", &self.image_topic),
            ("lidar_topic", &self.lidar_topic),
            ("accel_topic", &self.accel_topic),
        ] {
            if v.as_deref().is_some_and(|t| t.trim().is_empty()) {
                bail!("`{key}` is empty");
            }
        }
        if let Some(p) = self.lidar_sweep_period_s {
            if !(p.is_finite() && (0.001..=1.0).contains(&p)) {
                bail!("`lidar_sweep_period_s` = {p}: expected 0.001 to 1 s");
            }
        }
        if let Some(c) = &self.camera {
            let n = c.strip_prefix("cam").unwrap_or("");
            if n.is_empty() || !n.bytes().all(|b| b.is_ascii_digit()) {
                bail!("`camera` {c:?} is not camN (cam0, cam1, ...)");
            }
        }
        Ok(())
    }

    /// Whether any key that applies to bags only is set.
    pub fn any_for_bags(&self) -> bool {
        self.calib.is_some()
            || self.imu_calib.is_some()
            || self.camera.is_some()
            || self.imu_topic.is_some()
            || self.image_topic.is_some()
            || self.accel_topic.is_some()
            || self.accel_unit != AccelUnit::Auto
            || self.lidar_topic.is_some()
            || self.lidar_layout.and_then(LidarLayout::layout).is_some()
            || self.lidar_no_time != LidarNoTime::Stamp
    }

    /// How LiDAR clouds are read.
    pub fn cloud_options(&self) -> povins_platform::cloud::CloudOptions {
        use povins_platform::cloud::{CloudOptions, NoTime};
        let period_ns =
            (self.lidar_sweep_period_s.unwrap_or(DEFAULT_SWEEP_PERIOD_S) * 1e9).round() as i64;
        let clockwise = self.lidar_spin == LidarSpin::Cw;
        CloudOptions {
            layout: self.lidar_layout.and_then(LidarLayout::layout),
            no_time: match self.lidar_no_time {
                LidarNoTime::Stamp => NoTime::Stamp,
                LidarNoTime::SpinStart | LidarNoTime::SpinEnd => NoTime::Spin {
                    period_ns,
                    clockwise,
                    stamp_is_end: self.lidar_no_time == LidarNoTime::SpinEnd,
                },
            },
        }
    }

    /// The topic choice for the recording layer, the Kalibr `rostopic`s (`kalibr_*`) being the
    /// defaults when the recording has those topics (`all`).
    pub fn topic_choice(
        &self,
        all: &[povins_platform::rosrec::TopicInfo],
        kalibr_imu: Option<&str>,
        kalibr_image: Option<&str>,
    ) -> povins_platform::rosrec::topics::TopicChoice {
        let pick = |given: &Option<String>, kalibr: Option<&str>| {
            given.clone().or_else(|| {
                kalibr
                    .filter(|k| all.iter().any(|t| t.topic == *k))
                    .map(str::to_string)
            })
        };
        povins_platform::rosrec::topics::TopicChoice {
            imu: pick(&self.imu_topic, kalibr_imu),
            image: pick(&self.image_topic, kalibr_image),
            accel: self.accel_topic.clone(),
            accel_unit: self.accel_unit.into(),
            lidar: self.lidar_topic.clone(),
            cloud: self.cloud_options(),
        }
    }

    /// The calibration found ([`CalibrationFound`]): the files, or without `calib` the
    /// recording's own (`log`: [`from_recording`]); an error says what is missing and where it
    /// was looked for.
    pub fn calibration_files(&self, log: &dyn MessageLog) -> Result<CalibrationFound> {
        let mut found = self.camera_and_imu(log)?;
        if found.t_bl.is_none() {
            self.lidar_from_tf_static(log, &mut found);
        }
        Ok(found)
    }

    /// The LiDAR extrinsic `T_bl` from the recording's `/tf_static` (the IMU's and the LiDAR
    /// messages' frames), when the recording has a LiDAR topic and no file gave one; where it
    /// came from, or why there is none, goes into `found.sources`.
    fn lidar_from_tf_static(&self, log: &dyn MessageLog, found: &mut CalibrationFound) {
        use povins_platform::rosrec::{calib_msgs, topics};
        let all = log.topics();
        let Ok(sel) = topics::select_with(&all, &self.topic_choice(&all, None, None)) else {
            return;
        };
        let (Some(imu), Some(lidar)) = (sel.imu, sel.lidar) else {
            return;
        };
        match calib_msgs::t_b_from_log(log, &imu, &lidar) {
            Some(Ok(t)) => {
                found.t_bl = Some(t);
                let _ = write!(
                    found.sources,
                    "\nLiDAR   T_bl from {}'s /tf_static ({} to {})",
                    log.path().display(),
                    imu.topic,
                    lidar.topic
                );
            }
            Some(Err(e)) => {
                let _ = write!(found.sources, "\nLiDAR   no T_bl: {e}");
            }
            None => {
                let _ = write!(
                    found.sources,
                    "\nLiDAR   no T_bl: no /tf_static in the recording (give [lidar.extrinsic] in \
                     --config, or an EuRoC --calib folder with lidar0/sensor.yaml)"
                );
            }
        }
    }

    /// [`Self::calibration_files`] before the LiDAR's `/tf_static`.
    fn camera_and_imu(&self, log: &dyn MessageLog) -> Result<CalibrationFound> {
        let Some(calib) = &self.calib else {
            let mut found = from_recording(log, self)?;
            if let Some(p) = &self.imu_calib {
                found.imu = Some(kalibr::read_imu(p)?);
                let _ = write!(found.sources, "\nIMU     {} (Kalibr)", p.display());
            }
            return Ok(found);
        };
        let camera = self.camera.as_deref().unwrap_or(kalibr::DEFAULT_CAMERA);
        let mut found = if calib.is_dir() {
            if camera != kalibr::DEFAULT_CAMERA {
                bail!(
                    "--camera {camera}: the EuRoC folder {} has cam0 only",
                    calib.display()
                );
            }
            let c = povins_platform::euroc::EurocFolder::open(calib)
                .with_context(|| format!("--calib {}", calib.display()))?
                .calibration()
                .clone();
            CalibrationFound::from_euroc(c, calib)
        } else {
            CalibrationFound {
                camera: kalibr::read_camchain(calib, camera)?,
                imu: None,
                t_bl: None,
                td_l_s: 0.0,
                sources: format!("camera  {} ({camera}, Kalibr)", calib.display()),
            }
        };
        if let Some(p) = &self.imu_calib {
            found.imu = Some(kalibr::read_imu(p)?);
            let _ = write!(found.sources, "\nIMU     {} (Kalibr)", p.display());
        }
        Ok(found)
    }
}

/// The calibration files of a bag: the camera, and the IMU when a file gave it.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationFound {
    /// The camera and its extrinsic.
    pub camera: KalibrCamera,
    /// The IMU, when a file gave it.
    pub imu: Option<KalibrImu>,
    /// The LiDAR extrinsic: an EuRoC folder's, or the recording's `/tf_static`.
    pub t_bl: Option<Extrinsic>,
    /// The LiDAR's time offset (`t_imu = t_lidar + td_l_s`), s: an EuRoC folder's
    /// `timeshift_lidar_imu`, else 0.
    pub td_l_s: f64,
    /// Where they came from, a line each.
    pub sources: String,
}

impl CalibrationFound {
    fn from_euroc(c: Calibration, dir: &Path) -> Self {
        CalibrationFound {
            camera: KalibrCamera {
                camera: c.camera,
                t_bc: c.t_bc,
                td_s: c.td_s,
                rate_hz: c.camera_rate_hz,
                rostopic: None,
            },
            imu: Some(KalibrImu {
                noise: c.imu_noise,
                rate_hz: c.imu_rate_hz,
                gravity_mps2: c.gravity_mps2,
                rostopic: None,
            }),
            t_bl: c.t_bl,
            td_l_s: c.td_l_s,
            sources: format!(
                "camera  {} (EuRoC cam0)\nIMU     the same folder",
                dir.display()
            ),
        }
    }

    /// The calibration, the IMU noise from the files or else from `toml_noise` (the TOML's
    /// `[imu_noise]`, IMU rate unknown: 0, gravity 9.81).
    pub fn calibration(&self, toml_noise: Option<ImuNoise>) -> Result<KalibrCalibration> {
        let imu = match (&self.imu, toml_noise) {
            (Some(imu), _) => imu.clone(),
            (None, Some(noise)) => KalibrImu {
                noise,
                rate_hz: 0.0,
                gravity_mps2: povins_platform::euroc::DEFAULT_GRAVITY_MPS2,
                rostopic: None,
            },
            (None, None) => bail!(
                "IMU noise missing: give --imu-calib (a Kalibr imu.yaml) or `[input] imu_calib`, \
                 or all of [imu_noise] gyro_noise_density, accel_noise_density, gyro_bias_rw \
                 and accel_bias_rw in --config (looked in: {})",
                self.sources.replace('\n', "; ")
            ),
        };
        let mut k = KalibrCalibration::new(self.camera.clone(), imu);
        k.calib.t_bl = self.t_bl;
        k.calib.td_l_s = self.td_l_s;
        Ok(k)
    }

    /// What `povins info` prints.
    pub fn describe(&self) -> String {
        let c = &self.camera;
        let cam = &c.camera;
        let mut s = String::new();
        for l in self.sources.lines() {
            let _ = writeln!(s, "calib     {l}");
        }
        let _ = writeln!(
            s,
            "camera    {}x{} fx {} fy {} cx {} cy {} {:?}",
            cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.distortion
        );
        let q = c.t_bc.q_ab.coords;
        let p = c.t_bc.p_ab;
        let _ = writeln!(
            s,
            "T_bc      p_bc [{}, {}, {}] m, q_bc [{}, {}, {}, {}] (x y z w)",
            p.x, p.y, p.z, q.x, q.y, q.z, q.w
        );
        if let Some(t) = &self.t_bl {
            let (q, p) = (t.q_ab.coords, t.p_ab);
            let _ = writeln!(
                s,
                "T_bl      p_bl [{}, {}, {}] m, q_bl [{}, {}, {}, {}] (x y z w)",
                p.x, p.y, p.z, q.x, q.y, q.z, q.w
            );
            let _ = writeln!(s, "td_l_s    {} s (t_imu = t_lidar + td_l_s)", self.td_l_s);
        }
        let _ = writeln!(s, "td_s      {} s (t_imu = t_cam + td_s)", c.td_s);
        if let Some(t) = &c.rostopic {
            let _ = writeln!(s, "rostopic  camera {t}");
        }
        match &self.imu {
            Some(i) => {
                let n = &i.noise;
                let _ = writeln!(
                    s,
                    "IMU       gyro {} rad/s/sqrt(Hz), rw {}; accel {} m/s^2/sqrt(Hz), rw {}; \
                     {} Hz; gravity {} m/s^2",
                    n.gyro_noise_density,
                    n.gyro_bias_rw,
                    n.accel_noise_density,
                    n.accel_bias_rw,
                    i.rate_hz,
                    i.gravity_mps2
                );
                if let Some(t) = &i.rostopic {
                    let _ = writeln!(s, "rostopic  IMU {t}");
                }
            }
            None => {
                let _ = writeln!(
                    s,
                    "IMU       no noise model in the files (--imu-calib, or [imu_noise] in \
                     --config)"
                );
            }
        }
        s
    }
}

impl RunConfigFile {
    /// The TOML's `[imu_noise]` when it gives all four densities (bias correlation time
    /// optional), else `None`.
    pub fn imu_noise(&self) -> Result<Option<ImuNoise>> {
        let Some(toml::Value::Table(t)) = self.table.get("imu_noise") else {
            return Ok(None);
        };
        let keys = [
            "gyro_noise_density",
            "accel_noise_density",
            "gyro_bias_rw",
            "accel_bias_rw",
        ];
        if !keys.iter().all(|k| t.contains_key(*k)) {
            return Ok(None);
        }
        let n: ImuNoise = toml::Value::Table(t.clone())
            .try_into()
            .map_err(|e| self.error(anyhow!("[imu_noise]: {}", e.to_string().trim())))?;
        Ok(Some(n))
    }
}

/// The camera calibration a recording carries, for a run without `--calib`: the intrinsics
/// from the `sensor_msgs/CameraInfo` beside the camera topic and `T_bc` from `/tf_static`
/// ([`povins_platform::rosrec::calib_msgs`]); `td_s` 0. Either missing is an error saying where
/// it was looked for.
pub fn from_recording(log: &dyn MessageLog, input: &InputOptions) -> Result<CalibrationFound> {
    use povins_platform::rosrec::{calib_msgs, topics};
    let path = log.path().display().to_string();
    let all = log.topics();
    let sel = topics::select_with(&all, &input.topic_choice(&all, None, None))
        .map_err(|e| anyhow!("{path}: {e}"))?;
    let (Some(imu), Some(cam)) = (sel.imu, sel.camera) else {
        bail!(
            "{path}: calibration missing: no --calib (a Kalibr camchain-imucam.yaml, or an EuRoC \
             folder) and the recording has no IMU and camera topics to find one beside"
        );
    };
    let missing = |what: &str| {
        anyhow!(
            "{path}: calibration missing: {what}; give --calib (a Kalibr camchain-imucam.yaml, \
             or an EuRoC folder with mav0/cam0 and mav0/imu0 sensor.yaml) or `[input] calib`"
        )
    };
    let camera = match calib_msgs::camera_from_log(log, &cam.topic) {
        None => {
            return Err(missing(&format!(
                "no sensor_msgs/CameraInfo beside {} (looked for its camera_info topic)",
                cam.topic
            )))
        }
        Some(r) => r.map_err(|e| anyhow!("{path}: {e}"))?,
    };
    let t_bc = match calib_msgs::t_b_from_log(log, &imu, &cam) {
        None => {
            return Err(missing(
                "the camera-IMU extrinsic T_bc: the recording has no /tf_static",
            ))
        }
        Some(r) => r.map_err(|e| anyhow!("{path}: {e}"))?,
    };
    Ok(CalibrationFound {
        camera: KalibrCamera {
            camera,
            t_bc,
            td_s: 0.0,
            rate_hz: 0.0,
            rostopic: Some(cam.topic.clone()),
        },
        imu: None,
        t_bl: None,
        td_l_s: 0.0,
        sources: format!(
            "camera  {path} (sensor_msgs/CameraInfo beside {}, T_bc from /tf_static, td_s 0)",
            cam.topic
        ),
    })
}

/// Opens the ROS recording at `path` with the calibration and topics of `input` (`toml_noise`:
/// the TOML's `[imu_noise]`, see [`CalibrationFound::calibration`]). A Kalibr `rostopic` is the
/// default topic when the recording has it.
pub fn open_bag(
    path: &Path,
    input: &InputOptions,
    toml_noise: Option<ImuNoise>,
) -> Result<Box<dyn Recording>> {
    let log = povins_platform::containers::open_log(path)?;
    let k = input
        .calibration_files(&*log)?
        .calibration(toml_noise)
        .with_context(|| format!("{}", path.display()))?;
    let choice = input.topic_choice(
        &log.topics(),
        k.imu_topic.as_deref(),
        k.image_topic.as_deref(),
    );
    Ok(Box::new(
        povins_platform::rosrec::recording::RosRecording::new(log, k.calib, &choice)?,
    ))
}

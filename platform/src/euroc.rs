//! EuRoC ASL folders (`mav0/...`), including the `features0` and `lidar0` extensions.
//!
//! Layout read and written (under `mav0/`):
//! - `imu0/data.csv` (`#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_z [m s^-2]`) and
//!   `imu0/sensor.yaml` (`rate_hz`, `gyroscope_noise_density`, `gyroscope_random_walk`,
//!   `accelerometer_noise_density`, `accelerometer_random_walk`, optional `T_BS`; povins also
//!   reads the optional `gravity_magnitude` (default 9.81 m/s^2) and `bias_correlation_time` (s)).
//!   Required: a folder without them is an error.
//! - `cam0/sensor.yaml`: `T_BS` (4x4 row-major, body-from-camera), `rate_hz`, `resolution`,
//!   `intrinsics` `[fu, fv, cu, cv]`, `distortion_model` (`radial-tangential` | `equidistant` |
//!   `none`), `distortion_coefficients`, optional Kalibr `timeshift_cam_imu` (s,
//!   `t_imu = t_cam + shift`, default 0), optional povins `readout_s` (a rolling shutter's readout
//!   time, s, default 0: [`PinholeCamera::readout_s`]; written only when not 0). `cam0/data.csv` (`#timestamp [ns],filename`) lists
//!   images in `cam0/data/`; they are decoded only by [`read_images`].
//! - `features0/data.csv` (`#timestamp [ns],feature_id,u [px],v [px]`): rows of one frame are
//!   consecutive and share the stamp; frames increase in time; ids are unique within a frame.
//! - `lidar0/sensor.yaml` (`T_BS`, optional povins `timeshift_lidar_imu`: s, `t_imu = t_lidar +
//!   shift`, default 0) and `lidar0/data.csv` (povins extension, `#timestamp
//!   [ns],point_timestamp [ns],x [m],y [m],z [m],intensity`): one row per point, the first column
//!   is the sweep time, rows of one sweep are consecutive. Sweeps without points cannot be stored.
//! - `state_groundtruth_estimate0/data.csv` via [`crate::trajectory`].
//!
//! The body frame of [`Dataset`] is the IMU frame: when `imu0/sensor.yaml` has a non-identity
//! `T_BS`, camera and LiDAR extrinsics are re-expressed in it (`T_imu_cam = T_B_imu^-1 T_B_cam`).
//! `SimTruth` and the dataset name are not stored in a folder (the name is the folder's name).
//!
//! Numbers are written with Rust's shortest round-trip formatting, so reading a written folder
//! gives back the same `f64`/`f32` bits; extrinsic and ground-truth quaternions go through a
//! rotation matrix or renormalization and come back within 1e-15 rad.

mod csv;
mod png_io;
pub mod rows;
pub mod writer;
mod yaml;

pub use png_io::{read_mono8 as read_png_mono8, write_mono8 as write_png_mono8};
pub use writer::{EurocWriter, Written};

use crate::dataset::{Calibration, Dataset, Extrinsic, FeatureFrame, ImageFrame, LidarScan};
use crate::error::IoError;
use crate::recording::{Contents, Recording, Stream};
use crate::trajectory::GroundTruthRows;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
use povins_core::camera::{Distortion, PinholeCamera, MAX_READOUT_S};
use povins_core::inertial::{ImuNoise, ImuSample, NavState};
use povins_core::lidar::MAX_TD_L_S;
use povins_core::math::Vec3;
use std::path::{Path, PathBuf};
use yaml::Doc;

/// Gravity magnitude assumed when `imu0/sensor.yaml` has no `gravity_magnitude`, m/s^2.
pub const DEFAULT_GRAVITY_MPS2: f64 = 9.81;

const IMU_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";
const FEATURES_HEADER: &str = "#timestamp [ns],feature_id,u [px],v [px]";
const CAM_HEADER: &str = "#timestamp [ns],filename";
const LIDAR_HEADER: &str = "#timestamp [ns],point_timestamp [ns],x [m],y [m],z [m],intensity";

/// The `mav0` folder of `dir` (which may be the folder holding `mav0/` or `mav0/` itself), and
/// the dataset name.
fn locate(dir: &Path) -> (PathBuf, String) {
    let (mav0, named) = if dir.join("mav0").is_dir() {
        (dir.join("mav0"), dir.to_path_buf())
    } else {
        let parent = match dir.file_name() {
            Some(n) if n == "mav0" => dir.parent().map(Path::to_path_buf),
            _ => None,
        };
        (
            dir.to_path_buf(),
            parent.unwrap_or_else(|| dir.to_path_buf()),
        )
    };
    let abs = std::fs::canonicalize(&named).unwrap_or(named);
    let name = abs
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    (mav0, name)
}

/// An EuRoC ASL folder as a [`Recording`]: the calibration is read when it is opened, the
/// sensors' `data.csv` files row by row when their streams are pulled ([`rows`]).
#[derive(Debug, Clone)]
pub struct EurocFolder {
    name: String,
    calib: Calibration,
    imu: PathBuf,
    features: Option<PathBuf>,
    images: Option<(PathBuf, PathBuf)>,
    lidar: Option<PathBuf>,
    ground_truth: Option<PathBuf>,
    imu_span_ns: Option<(i64, i64)>,
    image_count: Option<usize>,
}

impl EurocFolder {
    /// Opens an EuRoC ASL folder (the folder containing `mav0/`, or `mav0/` itself): reads its
    /// calibration and finds its sensors' files.
    pub fn open(dir: &Path) -> Result<Self, IoError> {
        let (mav0, name) = locate(dir);
        let imu_dir = mav0.join("imu0");
        if !imu_dir.join("data.csv").is_file() || !imu_dir.join("sensor.yaml").is_file() {
            return Err(IoError::Invalid {
                path: imu_dir,
                msg: "imu0/data.csv and imu0/sensor.yaml are required".into(),
            });
        }
        let imu_yaml = Doc::read(&imu_dir.join("sensor.yaml"))?;
        let t_b_imu = match doc_t_bs(&imu_yaml)? {
            Some(t) => t,
            None => Extrinsic::identity(),
        };
        let cam_dir = mav0.join("cam0");
        let cam_yaml_path = cam_dir.join("sensor.yaml");
        let features_path = mav0.join("features0").join("data.csv");
        let cam_csv = cam_dir.join("data.csv");
        let cam_yaml = if cam_yaml_path.is_file() {
            Some(Doc::read(&cam_yaml_path)?)
        } else if features_path.is_file() || cam_csv.is_file() {
            return Err(IoError::Invalid {
                path: cam_yaml_path,
                msg: "camera data present but cam0/sensor.yaml is missing".into(),
            });
        } else {
            None
        };
        let (camera, t_bc, td_s, camera_rate_hz) = match &cam_yaml {
            Some(d) => {
                let (cam, t, td, rate) = read_camera(d)?;
                (cam, compose_in_imu(&t_b_imu, &t), td, rate)
            }
            // No camera at all: a placeholder the estimator cannot mistake for a real one.
            None => (crate::dataset::no_camera(), Extrinsic::identity(), 0.0, 0.0),
        };
        let (imu_noise, imu_rate_hz, gravity_mps2) = read_imu_yaml(&imu_yaml)?;
        let lidar_dir = mav0.join("lidar0");
        let (t_bl, td_l_s) = if lidar_dir.join("sensor.yaml").is_file() {
            let d = Doc::read(&lidar_dir.join("sensor.yaml"))?;
            let t = doc_t_bs(&d)?.ok_or_else(|| d.error(1, "lidar0/sensor.yaml needs T_BS"))?;
            (Some(compose_in_imu(&t_b_imu, &t)), read_lidar_td(&d)?)
        } else {
            (None, 0.0)
        };
        let file = |p: PathBuf| p.is_file().then_some(p);
        let imu = imu_dir.join("data.csv");
        let imu_span_ns = first_stamp(&imu).zip(rows::last_stamp(&imu));
        let image_count = cam_csv
            .is_file()
            .then(|| rows::count_rows(&cam_csv))
            .flatten();
        Ok(EurocFolder {
            name,
            calib: Calibration {
                camera,
                t_bc,
                td_s,
                camera_rate_hz,
                imu_noise,
                imu_rate_hz,
                gravity_mps2,
                t_bl,
                td_l_s,
            },
            imu,
            features: file(features_path),
            images: file(cam_csv).map(|c| (c, cam_dir.join("data"))),
            lidar: file(lidar_dir.join("data.csv")),
            ground_truth: file(mav0.join("state_groundtruth_estimate0").join("data.csv")),
            imu_span_ns,
            image_count,
        })
    }
}

impl Recording for EurocFolder {
    fn name(&self) -> &str {
        &self.name
    }

    fn calibration(&self) -> &Calibration {
        &self.calib
    }

    fn contents(&self) -> Contents {
        Contents {
            imu: true,
            frames: self.features.is_some(),
            images: self.images.is_some(),
            lidar: self.lidar.is_some(),
            ground_truth: self.ground_truth.is_some(),
            imu_span_ns: self.imu_span_ns,
            image_count: self.image_count.filter(|_| self.images.is_some()),
        }
    }

    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError> {
        Ok(Box::new(rows::ImuRows::open(&self.imu)?))
    }

    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError> {
        Ok(match &self.features {
            Some(p) => Box::new(rows::FeatureRows::open(p)?),
            None => Box::new(std::iter::empty()),
        })
    }

    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError> {
        Ok(match &self.images {
            Some((list, dir)) => Box::new(rows::ImageRows::open(list, dir, &self.calib.camera)?),
            None => Box::new(std::iter::empty()),
        })
    }

    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError> {
        Ok(match &self.lidar {
            Some(p) => Box::new(rows::LidarRows::open(p)?),
            None => Box::new(std::iter::empty()),
        })
    }

    fn ground_truth_stream(&self) -> Result<Stream<'_, NavState>, IoError> {
        Ok(match &self.ground_truth {
            Some(p) => Box::new(GroundTruthRows::open(p)?),
            None => Box::new(std::iter::empty()),
        })
    }
}

/// The stamp of the first data row of a `data.csv`, or `None`.
fn first_stamp(path: &Path) -> Option<i64> {
    rows::ImuRows::open(path).ok()?.next()?.ok().map(|s| s.t_ns)
}

/// Noise model, rate and gravity of `imu0/sensor.yaml`.
fn read_imu_yaml(imu_yaml: &Doc) -> Result<(ImuNoise, f64, f64), IoError> {
    let r = imu_yaml.root();
    let imu_noise = ImuNoise {
        gyro_noise_density: imu_yaml.f64(r, "gyroscope_noise_density")?,
        accel_noise_density: imu_yaml.f64(r, "accelerometer_noise_density")?,
        gyro_bias_rw: imu_yaml.f64(r, "gyroscope_random_walk")?,
        accel_bias_rw: imu_yaml.f64(r, "accelerometer_random_walk")?,
        bias_corr_time_s: imu_yaml.opt_f64(r, "bias_correlation_time")?,
    };
    if !imu_noise.is_valid() {
        return Err(imu_yaml.error(
            imu_yaml.line_of(r, "gyroscope_noise_density"),
            "noise densities must be non-negative and the correlation time positive",
        ));
    }
    let imu_rate_hz = imu_yaml.f64(r, "rate_hz")?;
    let gravity_mps2 = imu_yaml
        .opt_f64(r, "gravity_magnitude")?
        .unwrap_or(DEFAULT_GRAVITY_MPS2);
    Ok((imu_noise, imu_rate_hz, gravity_mps2))
}

/// Reads an EuRoC ASL folder whole (the folder containing `mav0/`, or `mav0/` itself): every
/// stream of [`EurocFolder`] collected. Images are listed with their paths and the `cam0`
/// resolution; call [`read_images`] for the pixels.
pub fn read_dataset(dir: &Path) -> Result<Dataset, IoError> {
    let f = EurocFolder::open(dir)?;
    let imu = f.imu()?.collect::<Result<_, _>>()?;
    let features = f.frames()?.collect::<Result<_, _>>()?;
    let images = f.images()?.collect::<Result<_, _>>()?;
    let lidar = f.sweeps()?.collect::<Result<_, _>>()?;
    let ground_truth = f.ground_truth()?;
    Ok(Dataset {
        name: f.name,
        calib: f.calib,
        imu,
        features,
        images,
        lidar,
        ground_truth,
        sim_truth: None,
    })
}

/// Decodes every listed image that has a path and no pixels yet (8-bit grayscale PNG).
pub fn read_images(ds: &mut Dataset) -> Result<(), IoError> {
    for im in &mut ds.images {
        if !im.mono8.is_empty() {
            continue;
        }
        if let Some(p) = &im.path {
            let (w, h, px) = png_io::read_mono8(p)?;
            im.width = w;
            im.height = h;
            im.mono8 = px;
        }
    }
    Ok(())
}

/// `T_BS` of a sensor.yaml, if present.
fn doc_t_bs(d: &Doc) -> Result<Option<Extrinsic>, IoError> {
    let Some(m) = d.opt_map(d.root(), "T_BS")? else {
        return Ok(None);
    };
    let line = d.line_of(d.root(), "T_BS");
    for k in ["rows", "cols"] {
        if let Some(v) = d.opt_f64(m, k)? {
            if v != 4.0 {
                return Err(d.error(d.line_of(m, k), format!("T_BS {k} must be 4")));
            }
        }
    }
    let a = d.list_f64(m, "data", Some(16))?;
    let data_line = d.line_of(m, "data");
    if a[12] != 0.0 || a[13] != 0.0 || a[14] != 0.0 || a[15] != 1.0 {
        return Err(d.error(data_line, "T_BS last row must be [0, 0, 0, 1]"));
    }
    let r = Matrix3::new(a[0], a[1], a[2], a[4], a[5], a[6], a[8], a[9], a[10]);
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !(err < 1e-6 && r.determinant() > 0.0) {
        return Err(d.error(
            line,
            format!("T_BS rotation is not a rotation (|R^T R - I| = {err:e})"),
        ));
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Some(Extrinsic {
        q_ab: UnitQuaternion::new_normalize(q.into_inner()),
        p_ab: Vec3::new(a[3], a[7], a[11]),
    }))
}

/// `T_imu_s = T_B_imu^-1 T_B_s`, skipped (exactly) when `T_B_imu` is the identity.
fn compose_in_imu(t_b_imu: &Extrinsic, t_b_s: &Extrinsic) -> Extrinsic {
    if *t_b_imu == Extrinsic::identity() {
        return *t_b_s;
    }
    let qi = t_b_imu.q_ab.inverse();
    Extrinsic {
        q_ab: qi * t_b_s.q_ab,
        p_ab: qi * (t_b_s.p_ab - t_b_imu.p_ab),
    }
}

fn read_camera(d: &Doc) -> Result<(PinholeCamera, Extrinsic, f64, f64), IoError> {
    let r = d.root();
    if let Some(m) = d.opt_str(r, "camera_model")? {
        if m != "pinhole" {
            return Err(d.error(
                d.line_of(r, "camera_model"),
                format!("camera_model {m:?} is not pinhole"),
            ));
        }
    }
    let t = doc_t_bs(d)?.ok_or_else(|| d.error(d.line_of(r, "T_BS"), "cam0 needs T_BS"))?;
    let res = d.list_f64(r, "resolution", Some(2))?;
    let res_line = d.line_of(r, "resolution");
    let dim = |v: f64| -> Result<u32, IoError> {
        if v.fract() == 0.0 && v > 0.0 && v <= f64::from(u32::MAX) {
            Ok(v as u32)
        } else {
            Err(d.error(
                res_line,
                format!("resolution {v} is not a positive integer"),
            ))
        }
    };
    let k = d.list_f64(r, "intrinsics", Some(4))?;
    if !(k[0] > 0.0 && k[1] > 0.0) {
        return Err(d.error(d.line_of(r, "intrinsics"), "focal lengths must be positive"));
    }
    let model = d.opt_str(r, "distortion_model")?.unwrap_or("none");
    let model_line = d.line_of(r, "distortion_model");
    let distortion = match model {
        "radial-tangential" | "radtan" | "plumb_bob" => {
            let c = d.list_f64(r, "distortion_coefficients", Some(4))?;
            Distortion::RadTan {
                k1: c[0],
                k2: c[1],
                p1: c[2],
                p2: c[3],
            }
        }
        "equidistant" | "fisheye" => {
            let c = d.list_f64(r, "distortion_coefficients", Some(4))?;
            Distortion::Equidistant {
                k: [c[0], c[1], c[2], c[3]],
            }
        }
        "none" => Distortion::None,
        other => {
            return Err(d.error(
                model_line,
                format!("unsupported distortion_model {other:?}"),
            ));
        }
    };
    let readout_s = d.opt_f64(r, "readout_s")?.unwrap_or(0.0);
    if !(0.0..=MAX_READOUT_S).contains(&readout_s) {
        return Err(d.error(
            d.line_of(r, "readout_s"),
            format!("readout_s {readout_s} s is outside [0, {MAX_READOUT_S}] s"),
        ));
    }
    let camera = PinholeCamera {
        readout_s,
        width: dim(res[0])?,
        height: dim(res[1])?,
        fx: k[0],
        fy: k[1],
        cx: k[2],
        cy: k[3],
        distortion,
    };
    let td_s = d.opt_f64(r, "timeshift_cam_imu")?.unwrap_or(0.0);
    let rate = d.f64(r, "rate_hz")?;
    Ok((camera, t, td_s, rate))
}

/// The LiDAR's time offset from `lidar0/sensor.yaml`: `timeshift_lidar_imu` (s, `t_imu = t_lidar
/// + shift`, Kalibr's sign for the camera's `timeshift_cam_imu`; default 0), at most
/// [`MAX_TD_L_S`] in magnitude.
fn read_lidar_td(d: &Doc) -> Result<f64, IoError> {
    let r = d.root();
    let td = d.opt_f64(r, "timeshift_lidar_imu")?.unwrap_or(0.0);
    if td.abs() > MAX_TD_L_S {
        return Err(d.error(
            d.line_of(r, "timeshift_lidar_imu"),
            format!("timeshift_lidar_imu {td} s is outside [-{MAX_TD_L_S}, {MAX_TD_L_S}] s"),
        ));
    }
    Ok(td)
}

/// Writes calibration, IMU, features, LiDAR, images and ground truth as an EuRoC ASL folder
/// under `dir/mav0` (through [`EurocWriter`]). Images with pixels are encoded as PNG; images with
/// only a path are copied.
pub fn write_dataset(dir: &Path, ds: &Dataset) -> Result<(), IoError> {
    let mut w = EurocWriter::create(dir, &ds.calib)?;
    for s in &ds.imu {
        w.imu(s)?;
    }
    for im in &ds.images {
        w.image(im)?;
    }
    for fr in &ds.features {
        w.frame(fr)?;
    }
    for s in &ds.lidar {
        w.sweep(s)?;
    }
    w.ground_truth(&ds.ground_truth)?;
    w.finish().map(|_| ())
}

//! Kalibr calibration files: `camchain-imucam.yaml` (cameras and camera-IMU extrinsics) and
//! `imu.yaml` (IMU noise), read into a [`Calibration`] and written from one.
//!
//! YAML goes through `serde-saphyr` (pure Rust, panic-free parsing with resource budgets, errors
//! with line and column), so block lists (`- [..]` rows of `T_cam_imu`) and flow lists read alike.
//!
//! Keys read from `camN` of the camchain (the camera is chosen by name, default `cam0`):
//! - `camera_model`: `pinhole` only (others are refused naming the value).
//! - `intrinsics` `[fu, fv, pu, pv]` (px), `resolution` `[width, height]` (px).
//! - `distortion_model` `radtan` (4 `distortion_coeffs` k1 k2 p1 p2), `equidistant` (k1..k4) or
//!   `none` (no coefficients); anything else (`fov`, ...) is refused naming the value.
//! - `T_cam_imu`: 4x4, camera <- IMU (`P_c = T_cam_imu P_imu`), row lists. It is checked to be
//!   rigid (last row `[0, 0, 0, 1]`, rotation orthonormal within 1e-6, determinant > 0) and
//!   inverted as a matrix into our `T_bc` (body = IMU frame).
//! - `timeshift_cam_imu` (s, optional, default 0): Kalibr's convention is `t_imu = t_cam +
//!   shift`, the same as our `td_s` (`t_imu = t_cam + td_s`), so `td_s = timeshift_cam_imu`.
//! - `rostopic` (optional): the camera's topic, returned for the topic choice.
//! - `rate_hz` (optional, a povins extension Kalibr does not write): the camera rate; without it
//!   [`Calibration::camera_rate_hz`] is 0 (unknown; it is informational).
//!
//! Other keys (`cam_overlaps`, `T_cn_cnm1`, ...) are ignored.
//!
//! Keys read from `imu.yaml`, at the top level or under `imu0:` (Kalibr's result files nest
//! them): `accelerometer_noise_density`, `accelerometer_random_walk`, `gyroscope_noise_density`,
//! `gyroscope_random_walk` (continuous-time densities, the units of [`ImuNoise`]),
//! `update_rate` (Hz), `rostopic` (optional); povins extensions (the same as EuRoC's
//! `sensor.yaml`): `gravity_magnitude` (m/s^2, default 9.81) and `bias_correlation_time` (s).
//!
//! What Kalibr does not hold: gravity, a bias correlation time and the camera rate (the povins
//! extensions above), and the LiDAR extrinsic ([`Calibration::t_bl`] is `None` when read and not
//! written).

use crate::dataset::{Calibration, Extrinsic};
use crate::error::IoError;
use crate::euroc::DEFAULT_GRAVITY_MPS2;
use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion};
use povins_core::camera::{Distortion, PinholeCamera};
use povins_core::inertial::ImuNoise;
use povins_core::math::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The camera read when none is named.
pub const DEFAULT_CAMERA: &str = "cam0";

/// One camera of a camchain file.
#[derive(Debug, Clone, PartialEq)]
pub struct KalibrCamera {
    /// Intrinsics and distortion.
    pub camera: PinholeCamera,
    /// Camera in body (IMU): the inverse of Kalibr's `T_cam_imu`.
    pub t_bc: Extrinsic,
    /// `t_imu = t_cam + td_s`, s (Kalibr's `timeshift_cam_imu`).
    pub td_s: f64,
    /// Camera rate, Hz (povins' `rate_hz`; 0 = unknown).
    pub rate_hz: f64,
    /// The camera's `rostopic`.
    pub rostopic: Option<String>,
}

/// An `imu.yaml` file.
#[derive(Debug, Clone, PartialEq)]
pub struct KalibrImu {
    /// Noise densities and random walks.
    pub noise: ImuNoise,
    /// `update_rate`, Hz.
    pub rate_hz: f64,
    /// Gravity magnitude, m/s^2 (`gravity_magnitude`, default 9.81).
    pub gravity_mps2: f64,
    /// The IMU's `rostopic`.
    pub rostopic: Option<String>,
}

/// A calibration read from Kalibr files, with the topics they name.
#[derive(Debug, Clone, PartialEq)]
pub struct KalibrCalibration {
    /// The calibration (no LiDAR).
    pub calib: Calibration,
    /// The chosen camera's `rostopic`.
    pub image_topic: Option<String>,
    /// The IMU's `rostopic`.
    pub imu_topic: Option<String>,
}

/// A camera entry as written in the file (every key optional: missing ones are named in errors).
#[derive(Debug, Default, Deserialize)]
struct RawCam {
    camera_model: Option<String>,
    intrinsics: Option<Vec<f64>>,
    distortion_model: Option<String>,
    distortion_coeffs: Option<Vec<f64>>,
    #[serde(rename = "T_cam_imu")]
    t_cam_imu: Option<Vec<Vec<f64>>>,
    timeshift_cam_imu: Option<f64>,
    rostopic: Option<String>,
    resolution: Option<Vec<f64>>,
    rate_hz: Option<f64>,
}

/// The IMU keys, at the top level or under `imu0`.
#[derive(Debug, Default, Deserialize, Serialize)]
struct RawImu {
    accelerometer_noise_density: Option<f64>,
    accelerometer_random_walk: Option<f64>,
    gyroscope_noise_density: Option<f64>,
    gyroscope_random_walk: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rostopic: Option<String>,
    update_rate: Option<f64>,
    gravity_magnitude: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    bias_correlation_time: Option<f64>,
}

#[derive(Debug, Deserialize)]
struct ImuFile {
    imu0: Option<RawImu>,
    #[serde(flatten)]
    top: RawImu,
}

/// A camera as written (Kalibr's key order).
#[derive(Serialize)]
struct CamOut<'a> {
    camera_model: &'a str,
    intrinsics: [f64; 4],
    distortion_model: &'a str,
    distortion_coeffs: Vec<f64>,
    #[serde(rename = "T_cam_imu")]
    t_cam_imu: [[f64; 4]; 4],
    timeshift_cam_imu: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    rostopic: Option<&'a str>,
    resolution: [u32; 2],
    rate_hz: f64,
}

fn invalid(path: &Path, msg: impl Into<String>) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        msg: msg.into(),
    }
}

fn read_text(path: &Path) -> Result<String, IoError> {
    std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))
}

fn parse<T: serde::de::DeserializeOwned>(
    path: &Path,
    text: &str,
    what: &str,
) -> Result<T, IoError> {
    serde_saphyr::from_str(text).map_err(|e| {
        let line = e.location().map_or(0, |l| l.line() as usize);
        IoError::Parse {
            path: path.to_path_buf(),
            line,
            msg: format!("not a Kalibr {what}: {}", e.render().trim()),
        }
    })
}

/// Reads camera `camera` (`camN`) of the camchain file at `path`.
pub fn read_camchain(path: &Path, camera: &str) -> Result<KalibrCamera, IoError> {
    camchain_from_str(path, &read_text(path)?, camera)
}

/// [`read_camchain`] of `text` (`path` names it in errors).
pub fn camchain_from_str(path: &Path, text: &str, camera: &str) -> Result<KalibrCamera, IoError> {
    let mut cams: BTreeMap<String, RawCam> = parse(path, text, "camchain (a map of camN)")?;
    let names: Vec<String> = cams.keys().cloned().collect();
    let raw = cams.remove(camera).ok_or_else(|| {
        invalid(
            path,
            format!(
                "no camera `{camera}` (the file has: {})",
                if names.is_empty() {
                    "nothing".to_string()
                } else {
                    names.join(", ")
                }
            ),
        )
    })?;
    camera_of(path, camera, raw)
}

fn camera_of(path: &Path, cam: &str, raw: RawCam) -> Result<KalibrCamera, IoError> {
    let missing = |key: &str| {
        invalid(
            path,
            format!("missing key `{key}` (looked for under `{cam}:`)"),
        )
    };
    let bad = |key: &str, msg: String| invalid(path, format!("`{cam}.{key}`: {msg}"));
    let model = raw.camera_model.ok_or_else(|| missing("camera_model"))?;
    if model != "pinhole" {
        return Err(bad(
            "camera_model",
            format!("{model:?} is not supported (pinhole only)"),
        ));
    }
    let k = raw.intrinsics.ok_or_else(|| missing("intrinsics"))?;
    let [fx, fy, cx, cy] = <[f64; 4]>::try_from(k.as_slice()).map_err(|_| {
        bad(
            "intrinsics",
            format!("{} values, expected 4 [fu, fv, pu, pv]", k.len()),
        )
    })?;
    if !(fx > 0.0
        && fy > 0.0
        && cx.is_finite()
        && cy.is_finite()
        && fx.is_finite()
        && fy.is_finite())
    {
        return Err(bad(
            "intrinsics",
            "focal lengths must be positive and finite".into(),
        ));
    }
    let res = raw.resolution.ok_or_else(|| missing("resolution"))?;
    let dims: Vec<u32> = res
        .iter()
        .filter(|v| v.fract() == 0.0 && **v > 0.0 && **v <= f64::from(u32::MAX))
        .map(|v| *v as u32)
        .collect();
    let [width, height] = <[u32; 2]>::try_from(dims.as_slice()).map_err(|_| {
        bad(
            "resolution",
            format!("{res:?} is not two positive integers [width, height]"),
        )
    })?;
    let dm = raw
        .distortion_model
        .ok_or_else(|| missing("distortion_model"))?;
    let coeffs = raw.distortion_coeffs.unwrap_or_default();
    let four = |name: &str| -> Result<[f64; 4], IoError> {
        <[f64; 4]>::try_from(coeffs.as_slice()).map_err(|_| {
            bad(
                "distortion_coeffs",
                format!("{} values; {name} needs 4", coeffs.len()),
            )
        })
    };
    let distortion = match dm.as_str() {
        "radtan" => {
            let [k1, k2, p1, p2] = four("radtan")?;
            Distortion::RadTan { k1, k2, p1, p2 }
        }
        "equidistant" => Distortion::Equidistant {
            k: four("equidistant")?,
        },
        "none" if coeffs.iter().all(|c| *c == 0.0) => Distortion::None,
        "none" => {
            return Err(bad(
                "distortion_coeffs",
                "non-zero with distortion_model none".into(),
            ))
        }
        other => {
            return Err(bad(
                "distortion_model",
                format!("{other:?} is not supported (radtan, equidistant or none)"),
            ))
        }
    };
    let t = raw.t_cam_imu.ok_or_else(|| missing("T_cam_imu"))?;
    let t_bc = rigid_inverse(&t).map_err(|m| bad("T_cam_imu", m))?;
    let td_s = raw.timeshift_cam_imu.unwrap_or(0.0);
    if !td_s.is_finite() {
        return Err(bad("timeshift_cam_imu", "not finite".into()));
    }
    Ok(KalibrCamera {
        camera: PinholeCamera {
            readout_s: 0.0,
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion,
        },
        t_bc,
        td_s,
        rate_hz: raw.rate_hz.unwrap_or(0.0),
        rostopic: raw.rostopic,
    })
}

/// `T_ab` from the rows of a 4x4 matrix `T_ba`: checked to be rigid, inverted as a matrix.
fn rigid_inverse(rows: &[Vec<f64>]) -> Result<Extrinsic, String> {
    if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
        let shape: Vec<usize> = rows.iter().map(Vec::len).collect();
        return Err(format!(
            "expected 4 rows of 4 numbers, got rows of {shape:?}"
        ));
    }
    let m = Matrix4::from_fn(|i, j| rows[i][j]);
    if !m.iter().all(|v| v.is_finite()) {
        return Err("not finite".into());
    }
    if m.row(3) != nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0) {
        return Err("not rigid: the last row must be [0, 0, 0, 1]".into());
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !(err < 1e-6 && r.determinant() > 0.0) {
        return Err(format!(
            "not rigid: the rotation is not a rotation (|R^T R - I| = {err:e}, det {:.6})",
            r.determinant()
        ));
    }
    let inv = m.try_inverse().ok_or("not invertible")?;
    let r_ab = inv.fixed_view::<3, 3>(0, 0).into_owned();
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_ab));
    Ok(Extrinsic {
        q_ab: UnitQuaternion::new_normalize(q.into_inner()),
        p_ab: Vec3::new(inv[(0, 3)], inv[(1, 3)], inv[(2, 3)]),
    })
}

/// Reads a Kalibr `imu.yaml` (keys at the top level or under `imu0:`).
pub fn read_imu(path: &Path) -> Result<KalibrImu, IoError> {
    imu_from_str(path, &read_text(path)?)
}

/// [`read_imu`] of `text` (`path` names it in errors).
pub fn imu_from_str(path: &Path, text: &str) -> Result<KalibrImu, IoError> {
    let file: ImuFile = parse(path, text, "imu.yaml")?;
    let (raw, place) = match file.imu0 {
        Some(r) => (r, "under `imu0:`"),
        None => (file.top, "at the top level or under `imu0:`"),
    };
    let need = |v: Option<f64>, key: &str| -> Result<f64, IoError> {
        let v =
            v.ok_or_else(|| invalid(path, format!("missing key `{key}` (looked for {place})")))?;
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(invalid(
                path,
                format!("`{key}`: {v} is not a non-negative number"),
            ))
        }
    };
    let noise = ImuNoise {
        gyro_noise_density: need(raw.gyroscope_noise_density, "gyroscope_noise_density")?,
        accel_noise_density: need(
            raw.accelerometer_noise_density,
            "accelerometer_noise_density",
        )?,
        gyro_bias_rw: need(raw.gyroscope_random_walk, "gyroscope_random_walk")?,
        accel_bias_rw: need(raw.accelerometer_random_walk, "accelerometer_random_walk")?,
        bias_corr_time_s: raw.bias_correlation_time,
    };
    if !noise.is_valid() {
        return Err(invalid(path, "`bias_correlation_time` must be positive"));
    }
    let rate_hz = need(raw.update_rate, "update_rate")?;
    if rate_hz <= 0.0 {
        return Err(invalid(path, "`update_rate` must be positive"));
    }
    let gravity_mps2 = raw.gravity_magnitude.unwrap_or(DEFAULT_GRAVITY_MPS2);
    if !(gravity_mps2.is_finite() && gravity_mps2 > 0.0) {
        return Err(invalid(path, "`gravity_magnitude` must be positive"));
    }
    Ok(KalibrImu {
        noise,
        rate_hz,
        gravity_mps2,
        rostopic: raw.rostopic,
    })
}

impl KalibrCalibration {
    /// The calibration of camera `cam` of `camchain` with the IMU of `imu`.
    pub fn new(cam: KalibrCamera, imu: KalibrImu) -> Self {
        KalibrCalibration {
            calib: Calibration {
                camera: cam.camera,
                t_bc: cam.t_bc,
                td_s: cam.td_s,
                camera_rate_hz: cam.rate_hz,
                imu_noise: imu.noise,
                imu_rate_hz: imu.rate_hz,
                gravity_mps2: imu.gravity_mps2,
                t_bl: None,
                td_l_s: 0.0,
            },
            image_topic: cam.rostopic,
            imu_topic: imu.rostopic,
        }
    }
}

/// Reads camera `camera` of `camchain` and the IMU of `imu` (see the module docs).
pub fn read(camchain: &Path, imu: &Path, camera: &str) -> Result<KalibrCalibration, IoError> {
    Ok(KalibrCalibration::new(
        read_camchain(camchain, camera)?,
        read_imu(imu)?,
    ))
}

/// The camchain text of `c` as `cam0` (with `rostopic` when given).
pub fn camchain_string(c: &Calibration, rostopic: Option<&str>) -> Result<String, String> {
    let cam = &c.camera;
    let (model, coeffs) = match cam.distortion {
        Distortion::None => ("none", Vec::new()),
        Distortion::RadTan { k1, k2, p1, p2 } => ("radtan", vec![k1, k2, p1, p2]),
        Distortion::Equidistant { k } => ("equidistant", k.to_vec()),
    };
    let r_cb = c.t_bc.q_ab.inverse().to_rotation_matrix();
    let p_cb = -(r_cb * c.t_bc.p_ab);
    let r = r_cb.matrix();
    let row = |i: usize| [r[(i, 0)], r[(i, 1)], r[(i, 2)], p_cb[i]];
    let out = CamOut {
        camera_model: "pinhole",
        intrinsics: [cam.fx, cam.fy, cam.cx, cam.cy],
        distortion_model: model,
        distortion_coeffs: coeffs,
        t_cam_imu: [row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]],
        timeshift_cam_imu: c.td_s,
        rostopic,
        resolution: [cam.width, cam.height],
        rate_hz: c.camera_rate_hz,
    };
    let doc = BTreeMap::from([(DEFAULT_CAMERA, out)]);
    serde_saphyr::to_string(&doc).map_err(|e| e.to_string())
}

/// The `imu.yaml` text of `c` (with `rostopic` when given).
pub fn imu_string(c: &Calibration, rostopic: Option<&str>) -> Result<String, String> {
    let n = &c.imu_noise;
    let raw = RawImu {
        accelerometer_noise_density: Some(n.accel_noise_density),
        accelerometer_random_walk: Some(n.accel_bias_rw),
        gyroscope_noise_density: Some(n.gyro_noise_density),
        gyroscope_random_walk: Some(n.gyro_bias_rw),
        rostopic: rostopic.map(str::to_string),
        update_rate: Some(c.imu_rate_hz),
        gravity_magnitude: Some(c.gravity_mps2),
        bias_correlation_time: n.bias_corr_time_s,
    };
    serde_saphyr::to_string(&raw).map_err(|e| e.to_string())
}

/// Writes `c`'s camera as `cam0` of a Kalibr camchain file (LiDAR not written).
pub fn write_camchain(path: &Path, c: &Calibration, rostopic: Option<&str>) -> Result<(), IoError> {
    let text = camchain_string(c, rostopic).map_err(|m| invalid(path, m))?;
    std::fs::write(path, text).map_err(|e| IoError::io(path, e))
}

/// Writes `c`'s IMU as a Kalibr `imu.yaml` (top-level keys).
pub fn write_imu(path: &Path, c: &Calibration, rostopic: Option<&str>) -> Result<(), IoError> {
    let text = imu_string(c, rostopic).map_err(|m| invalid(path, m))?;
    std::fs::write(path, text).map_err(|e| IoError::io(path, e))
}

#[cfg(test)]
mod tests;

//! [`Dataset`](crate::dataset::Dataset) items to and from ROS 2 messages.
//!
//! - IMU sample -> `sensor_msgs/msg/Imu`, frame `body`: `angular_velocity` = gyro (rad/s),
//!   `linear_acceleration` = specific force (m/s^2), no orientation (`orientation_covariance[0] =
//!   -1`), other covariances zero (unknown).
//! - Ground truth -> `nav_msgs/msg/Odometry`, frame `world`, child `body`: pose = `p_wb`, `q_wb`;
//!   `twist.linear` is the body velocity expressed in the child frame `body` as ROS requires
//!   (`R_wb^T v_wb`; reading rotates it back, so `v_wb` returns within a few ulps), angular
//!   velocity zero (not part of the state). Biases go to `sensor_msgs/msg/Imu` with
//!   `angular_velocity` = `bg`, `linear_acceleration` = `ba`, same stamp.
//! - LiDAR sweep -> `sensor_msgs/msg/PointCloud2`, frame `lidar0`, unordered (`height` 1), 20-byte
//!   little-endian points: `x`, `y`, `z`, `intensity` FLOAT32 at 0, 4, 8, 12 and `t` UINT32 at 16:
//!   the point time in integer nanoseconds after the header stamp (the sweep start), as Ouster
//!   drivers publish it (povins' compact layout; [`lidar_to_msg_in`] writes a driver's layout,
//!   [`crate::cloud`]). Exact for offsets up to 4.29 s; a point before the sweep start or later
//!   than that cannot be written. Reading takes every driver layout [`crate::cloud`] knows.
//! - Image -> `sensor_msgs/msg/Image`, frame `cam0`, `mono8`, `step` = width. Reading also takes
//!   `sensor_msgs/msg/CompressedImage` (JPEG or PNG, any colour type, decoded to mono8).
//! - Feature frame -> `sensor_msgs/msg/PointCloud`, frame `cam0`, following VINS-Mono's
//!   `feature_tracker` (`/feature_tracker/feature`): `points` are the *undistorted normalized*
//!   coordinates `(x, y, 1)`; channels, in VINS-Mono's order, are `id_of_point` (track id),
//!   `u_of_point`, `v_of_point` (raw distorted pixels, what the dataset stores), and
//!   `velocity_x_of_point`, `velocity_y_of_point` (normalized-plane velocity against the previous
//!   frame, 1/s, zero for new tracks). VINS-Mono leaves channel names empty and reads channels by
//!   index; we name them and read by name, falling back to the index for unnamed channels. Values
//!   are `float32`: ids must stay below 2^24 and pixels are rounded to `f32` (3e-5 px at 752 px).

use super::msgs::{ChannelFloat32, CompressedImage, Image, Imu, Odometry, PointCloud, PointCloud2};
use super::Header;
use crate::dataset::{FeatureFrame, ImageFrame, LidarScan};
use nalgebra::Quaternion;
use povins_core::camera::{FeatureObs, PinholeCamera};
use povins_core::inertial::{ImuSample, NavState};
use povins_core::math::{Quat, Vec3};
use std::collections::HashMap;

/// Frame id of IMU and ground-truth child frames.
pub const FRAME_BODY: &str = "body";
/// Frame id of the ground-truth parent.
pub const FRAME_WORLD: &str = "world";
/// Frame id of images and features.
pub const FRAME_CAM: &str = "cam0";
/// Frame id of LiDAR sweeps.
pub const FRAME_LIDAR: &str = "lidar0";
/// Largest feature id a `float32` channel carries exactly.
pub const MAX_FEATURE_ID: u64 = 1 << 24;
/// VINS-Mono's channel names, in its order.
pub const FEATURE_CHANNELS: [&str; 5] = [
    "id_of_point",
    "u_of_point",
    "v_of_point",
    "velocity_x_of_point",
    "velocity_y_of_point",
];

fn v3(v: &Vec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A unit quaternion from wire `[x, y, z, w]`: kept bit-exact when already unit to rounding,
/// renormalized when close, rejected otherwise.
pub fn quat_from_xyzw(q: [f64; 4]) -> Option<Quat> {
    let raw = Quaternion::new(q[3], q[0], q[1], q[2]);
    let n = raw.norm();
    if !(n.is_finite() && (n - 1.0).abs() < 1e-3) {
        return None;
    }
    Some(if (n - 1.0).abs() <= 4.0 * f64::EPSILON {
        Quat::new_unchecked(raw)
    } else {
        Quat::new_normalize(raw)
    })
}

/// Wire `[x, y, z, w]` of a unit quaternion.
pub fn quat_to_xyzw(q: &Quat) -> [f64; 4] {
    [q.i, q.j, q.k, q.w]
}

/// IMU sample message.
pub fn imu_to_msg(s: &ImuSample) -> Imu {
    Imu::new(
        Header::new(s.t_ns, FRAME_BODY),
        v3(&s.gyro_rps),
        v3(&s.accel_mps2),
    )
}

/// IMU sample from a message; `None` when a value is not finite.
pub fn imu_from_msg(m: &Imu) -> Option<ImuSample> {
    let s = ImuSample {
        t_ns: m.header.t_ns,
        gyro_rps: Vec3::from(m.angular_velocity),
        accel_mps2: Vec3::from(m.linear_acceleration),
    };
    s.is_finite().then_some(s)
}

/// Ground-truth pose/velocity message and bias message.
pub fn ground_truth_to_msgs(s: &NavState) -> (Odometry, Imu) {
    let v_b = s.q_wb.inverse() * s.v_wb;
    let odom = Odometry {
        header: Header::new(s.t_ns, FRAME_WORLD),
        child_frame_id: FRAME_BODY.into(),
        position: v3(&s.p_wb),
        orientation: quat_to_xyzw(&s.q_wb),
        pose_covariance: [0.0; 36],
        linear: v3(&v_b),
        angular: [0.0; 3],
        twist_covariance: [0.0; 36],
    };
    let bias = Imu::new(Header::new(s.t_ns, FRAME_BODY), v3(&s.bg), v3(&s.ba));
    (odom, bias)
}

/// Ground truth from its odometry message and (optional) bias message.
pub fn ground_truth_from_msgs(o: &Odometry, bias: Option<&Imu>) -> Result<NavState, String> {
    let q_wb = quat_from_xyzw(o.orientation)
        .ok_or_else(|| format!("orientation {:?} is not a unit quaternion", o.orientation))?;
    let s = NavState {
        t_ns: o.header.t_ns,
        p_wb: Vec3::from(o.position),
        q_wb,
        v_wb: q_wb * Vec3::from(o.linear),
        bg: bias.map_or(Vec3::zeros(), |b| Vec3::from(b.angular_velocity)),
        ba: bias.map_or(Vec3::zeros(), |b| Vec3::from(b.linear_acceleration)),
    };
    let finite = [s.p_wb, s.v_wb, s.bg, s.ba]
        .iter()
        .all(|v| v.iter().all(|x| x.is_finite()));
    if finite {
        Ok(s)
    } else {
        Err("non-finite value".into())
    }
}

/// LiDAR sweep message in povins' compact layout ([`crate::cloud::Layout::Compact`]).
pub fn lidar_to_msg(s: &LidarScan) -> Result<PointCloud2, String> {
    lidar_to_msg_in(crate::cloud::Layout::Compact, s, FRAME_LIDAR)
}

/// LiDAR sweep message in a driver's point layout, frame `frame_id`.
pub fn lidar_to_msg_in(
    layout: crate::cloud::Layout,
    s: &LidarScan,
    frame_id: &str,
) -> Result<PointCloud2, String> {
    let n = u32::try_from(s.points.len()).map_err(|_| "too many points".to_string())?;
    let (fields, step, data) = crate::cloud::encode_points(layout, s)?;
    let dense = s.points.iter().all(|p| p.p_l.iter().all(|x| x.is_finite()));
    Ok(PointCloud2 {
        header: Header::new(s.t_ns, frame_id),
        height: 1,
        width: n,
        fields,
        is_bigendian: false,
        point_step: step,
        row_step: step * n,
        data,
        is_dense: dense,
    })
}

/// LiDAR sweep from a message in any driver layout, told from its fields
/// ([`crate::cloud::decode_point_cloud2`]; dropped points are not reported here).
pub fn lidar_from_msg(m: &PointCloud2) -> Result<LidarScan, String> {
    crate::cloud::decode_point_cloud2(m, &crate::cloud::CloudOptions::default()).map(|d| d.scan)
}

/// Image message (mono8). `px` are the pixels (from the frame or its file).
pub fn image_to_msg(im: &ImageFrame, px: Vec<u8>) -> Result<Image, String> {
    if px.len() as u64 != u64::from(im.width) * u64::from(im.height) {
        return Err(format!(
            "{} pixels for a {}x{} image",
            px.len(),
            im.width,
            im.height
        ));
    }
    Ok(Image {
        header: Header::new(im.t_ns, FRAME_CAM),
        height: im.height,
        width: im.width,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: im.width,
        data: px,
    })
}

/// Image frame from a `mono8` message (rows copied without their `step` padding).
pub fn image_from_msg(m: Image) -> Result<ImageFrame, String> {
    if m.encoding != "mono8" && m.encoding != "8UC1" {
        return Err(format!("encoding {:?} is not mono8", m.encoding));
    }
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    if step < w || h.checked_mul(step).is_none_or(|b| b > m.data.len()) {
        return Err(format!(
            "{w}x{h} image with step {step} does not fit {} bytes",
            m.data.len()
        ));
    }
    let mono8 = if step == w && m.data.len() == w * h {
        m.data
    } else {
        let mut px = Vec::with_capacity(w * h);
        for r in 0..h {
            px.extend_from_slice(m.data.get(r * step..r * step + w).unwrap_or(&[]));
        }
        px
    };
    Ok(ImageFrame {
        t_ns: m.header.t_ns,
        width: m.width,
        height: m.height,
        mono8,
        path: None,
    })
}

/// Image frame from a `sensor_msgs/msg/CompressedImage` (JPEG or PNG, decoded to mono8, colour
/// converted to luma; see [`crate::image_codec`]).
pub fn image_from_compressed_msg(m: &CompressedImage) -> Result<ImageFrame, String> {
    let im = crate::image_codec::decode_mono8(&m.format, &m.data)?;
    Ok(ImageFrame {
        t_ns: m.header.t_ns,
        width: im.width,
        height: im.height,
        mono8: im.pixels,
        path: None,
    })
}

/// Feature frames to VINS-Mono style messages (velocities need the previous frame).
pub fn features_to_msgs(
    frames: &[FeatureFrame],
    cam: &PinholeCamera,
) -> Result<Vec<PointCloud>, String> {
    let mut prev: HashMap<u64, (f64, f64)> = HashMap::new();
    let mut prev_t: Option<i64> = None;
    let mut out = Vec::with_capacity(frames.len());
    for fr in frames {
        let dt_s = prev_t.map(|t| (fr.t_ns - t) as f64 * 1e-9);
        let mut cur = HashMap::with_capacity(fr.obs.len());
        let mut points = Vec::with_capacity(fr.obs.len());
        let mut ch: [Vec<f32>; 5] = Default::default();
        for o in &fr.obs {
            if o.id >= MAX_FEATURE_ID {
                return Err(format!(
                    "feature id {} at {} ns does not fit a float32 channel (< 2^24)",
                    o.id, fr.t_ns
                ));
            }
            // The core's camera model, so the published points are exactly what the estimator
            // computes from the raw pixels.
            let (x, y) = match cam.undistort(o.u_px, o.v_px) {
                Ok(p) => (p.x, p.y),
                Err(e) => {
                    return Err(format!(
                        "feature {} at {} ns ({}, {}) px cannot be undistorted: {e}",
                        o.id, fr.t_ns, o.u_px, o.v_px
                    ))
                }
            };
            let (vx, vy) = match (prev.get(&o.id), dt_s) {
                (Some(&(px, py)), Some(dt)) if dt > 0.0 => ((x - px) / dt, (y - py) / dt),
                _ => (0.0, 0.0),
            };
            cur.insert(o.id, (x, y));
            points.push([x as f32, y as f32, 1.0]);
            ch[0].push(o.id as f32);
            ch[1].push(o.u_px as f32);
            ch[2].push(o.v_px as f32);
            ch[3].push(vx as f32);
            ch[4].push(vy as f32);
        }
        prev = cur;
        prev_t = Some(fr.t_ns);
        out.push(PointCloud {
            header: Header::new(fr.t_ns, FRAME_CAM),
            points,
            channels: FEATURE_CHANNELS
                .iter()
                .zip(ch)
                .map(|(n, values)| ChannelFloat32 {
                    name: (*n).into(),
                    values,
                })
                .collect(),
        });
    }
    Ok(out)
}

/// Feature frame from a VINS-Mono style message (ids and raw pixels from the channels).
pub fn features_from_msg(m: &PointCloud) -> Result<FeatureFrame, String> {
    let chan = |k: usize| -> Result<&ChannelFloat32, String> {
        let name = FEATURE_CHANNELS[k];
        let c = match m.channels.iter().find(|c| c.name == name) {
            Some(c) => Some(c),
            None => m.channels.get(k).filter(|c| c.name.is_empty()),
        };
        let c = c.ok_or_else(|| format!("channel {name:?} is missing"))?;
        if c.values.len() != m.points.len() {
            return Err(format!(
                "channel {name:?} has {} values for {} points",
                c.values.len(),
                m.points.len()
            ));
        }
        Ok(c)
    };
    let (ids, us, vs) = (chan(0)?, chan(1)?, chan(2)?);
    let mut obs = Vec::with_capacity(m.points.len());
    for ((&id, &u), &v) in ids.values.iter().zip(&us.values).zip(&vs.values) {
        if !(id >= 0.0 && id.fract() == 0.0 && (id as u64) < MAX_FEATURE_ID) {
            return Err(format!("feature id {id} is not an integer in 0..2^24"));
        }
        if !(u.is_finite() && v.is_finite()) {
            return Err(format!("feature {id} has non-finite pixel ({u}, {v})"));
        }
        obs.push(FeatureObs {
            id: id as u64,
            u_px: f64::from(u),
            v_px: f64::from(v),
        });
    }
    Ok(FeatureFrame {
        t_ns: m.header.t_ns,
        obs,
    })
}

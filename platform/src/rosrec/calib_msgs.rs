//! Calibration carried by a recording: `sensor_msgs/CameraInfo` (the camera's intrinsics and
//! distortion, a fallback when no calibration file gives them) and `tf2_msgs/TFMessage` on
//! `/tf_static` (the sensors' frames, for the camera-IMU extrinsic), in ROS 1 or CDR encoding.
//!
//! ## CameraInfo
//! `K = [fx 0 cx; 0 fy cy; 0 0 1]` row-major; `distortion_model`:
//! - `plumb_bob` (`D = [k1 k2 t1 t2 k3]`): radial-tangential with `p1 = t1`, `p2 = t2`; povins'
//!   model has no `k3`, so a non-zero `k3` is refused (an empty `D` means no distortion);
//! - `equidistant` (`D = [k1 k2 k3 k4]`): the equidistant fisheye model;
//! - `rational_polynomial` and any other model: refused, naming it.
//!
//! A camera's info topic is the `camera_info` beside its image topic (`/cam/image_raw` and
//! `/cam/image_raw/compressed` -> `/cam/camera_info`), else the only `CameraInfo` topic.
//!
//! ## `/tf_static`
//! Each `geometry_msgs/TransformStamped` is `T_parent_child`: the child frame's origin
//! (`translation`) and orientation (`rotation`, x y z w) in the parent frame. The camera in the
//! body, `T_bc`, is found by walking both frames (the IMU message's `header.frame_id` is `b`, the
//! image's is `c`) up to a common root: `T_bc = T_rb^-1 T_rc`.

use super::decode::MsgError;
use super::{Encoding, MessageLog, TopicInfo};
use crate::cdr::CdrReader;
use crate::dataset::Extrinsic;
use crate::rosbag1::msgs::Reader;
use povins_core::camera::{Distortion, PinholeCamera};
use povins_core::math::{Quat, Vec3};
use std::collections::HashMap;

/// `sensor_msgs/CameraInfo`.
pub const CAMERA_INFO_TYPE: &str = "sensor_msgs/CameraInfo";
/// `tf2_msgs/TFMessage`.
pub const TF_TYPE: &str = "tf2_msgs/TFMessage";

/// The fields both encodings read the same way.
trait Wire {
    /// `std_msgs/Header`: stamp (ns) and frame id.
    fn header(&mut self) -> Result<(i64, String), MsgError>;
    fn u32(&mut self) -> Result<u32, MsgError>;
    fn f64(&mut self) -> Result<f64, MsgError>;
    fn string(&mut self) -> Result<String, MsgError>;
    /// A sequence's length whose elements take at least `min` bytes.
    fn seq_len(&mut self, min: usize) -> Result<usize, MsgError>;
}

impl Wire for Reader<'_> {
    fn header(&mut self) -> Result<(i64, String), MsgError> {
        let (t, frame) = self.header_with_frame()?;
        Ok((t, frame.to_owned()))
    }
    fn u32(&mut self) -> Result<u32, MsgError> {
        Reader::u32(self)
    }
    fn f64(&mut self) -> Result<f64, MsgError> {
        Ok(Reader::f64s::<1>(self)?[0])
    }
    fn string(&mut self) -> Result<String, MsgError> {
        Reader::string(self).map(str::to_owned)
    }
    fn seq_len(&mut self, min: usize) -> Result<usize, MsgError> {
        let n = Reader::u32(self)? as usize;
        if n.saturating_mul(min) > self.remaining() {
            return Err(self.err(format!("sequence of {n} elements cannot fit")));
        }
        Ok(n)
    }
}

impl Wire for CdrReader<'_> {
    fn header(&mut self) -> Result<(i64, String), MsgError> {
        let h = crate::ros2::Header::decode(self)?;
        Ok((h.t_ns, h.frame_id))
    }
    fn u32(&mut self) -> Result<u32, MsgError> {
        Ok(CdrReader::u32(self)?)
    }
    fn f64(&mut self) -> Result<f64, MsgError> {
        Ok(CdrReader::f64(self)?)
    }
    fn string(&mut self) -> Result<String, MsgError> {
        Ok(CdrReader::string(self)?.to_owned())
    }
    fn seq_len(&mut self, min: usize) -> Result<usize, MsgError> {
        Ok(CdrReader::seq_len(self, min)?)
    }
}

/// Runs `f` over a message of encoding `enc`.
fn with_wire<T>(
    enc: Encoding,
    msg: &[u8],
    f: impl FnOnce(&mut dyn Wire) -> Result<T, MsgError>,
) -> Result<T, MsgError> {
    match enc {
        Encoding::Ros1 => f(&mut Reader::new(msg)),
        Encoding::Cdr => f(&mut CdrReader::new(msg)?),
    }
}

/// A message's `header.frame_id` (every stamped message starts with its header).
pub fn frame_id(enc: Encoding, msg: &[u8]) -> Result<String, MsgError> {
    with_wire(enc, msg, |r| Ok(r.header()?.1))
}

/// The parts of `sensor_msgs/CameraInfo` povins reads.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// `distortion_model`.
    pub model: String,
    /// `D`.
    pub d: Vec<f64>,
    /// `K`, row-major.
    pub k: [f64; 9],
}

/// Decodes a `sensor_msgs/CameraInfo`.
pub fn camera_info(enc: Encoding, msg: &[u8]) -> Result<CameraInfo, MsgError> {
    with_wire(enc, msg, |r| {
        r.header()?;
        let height = r.u32()?;
        let width = r.u32()?;
        let model = r.string()?;
        let n = r.seq_len(8)?;
        let d = (0..n).map(|_| r.f64()).collect::<Result<Vec<_>, _>>()?;
        let mut k = [0.0; 9];
        for x in &mut k {
            *x = r.f64()?;
        }
        Ok(CameraInfo {
            width,
            height,
            model,
            d,
            k,
        })
    })
}

impl CameraInfo {
    /// The camera model (see the module docs for what is refused).
    pub fn camera(&self) -> Result<PinholeCamera, String> {
        let d = &self.d;
        let distortion = match (self.model.as_str(), d.len()) {
            (_, 0) => Distortion::None,
            ("plumb_bob", 4 | 5) => {
                let k3 = d.get(4).copied().unwrap_or(0.0);
                if k3 != 0.0 {
                    return Err(format!(
                        "plumb_bob k3 = {k3}: povins' radial-tangential model has k1 k2 p1 p2 \
                         only (calibrate without k3, or give a Kalibr file)"
                    ));
                }
                Distortion::RadTan {
                    k1: d[0],
                    k2: d[1],
                    p1: d[2],
                    p2: d[3],
                }
            }
            ("equidistant", 4) => Distortion::Equidistant {
                k: [d[0], d[1], d[2], d[3]],
            },
            (m, n) => {
                return Err(format!(
                    "distortion model {m:?} with {n} coefficients is not supported (plumb_bob \
                     with k3 = 0, or equidistant with 4)"
                ))
            }
        };
        let [fx, _, cx, _, fy, cy, ..] = self.k;
        if !(fx > 0.0 && fy > 0.0 && self.width > 0 && self.height > 0) {
            return Err(format!(
                "K = {:?} and {}x{} are not a calibrated camera (uncalibrated driver output?)",
                self.k, self.width, self.height
            ));
        }
        Ok(PinholeCamera {
            readout_s: 0.0,
            width: self.width,
            height: self.height,
            fx,
            fy,
            cx,
            cy,
            distortion,
        })
    }
}

/// The `CameraInfo` topic of the camera topic `image_topic` (see the module docs).
pub fn camera_info_topic<'a>(all: &'a [TopicInfo], image_topic: &str) -> Option<&'a TopicInfo> {
    let infos: Vec<&TopicInfo> = all
        .iter()
        .filter(|t| t.msg_type == CAMERA_INFO_TYPE && t.count > 0)
        .collect();
    let mut ns = image_topic.trim_end_matches("/compressed");
    ns = ns.rsplit_once('/').map_or("", |(a, _)| a);
    let beside = format!("{ns}/camera_info");
    infos
        .iter()
        .find(|t| t.topic == beside)
        .or(match infos.as_slice() {
            [one] => Some(one),
            _ => None,
        })
        .copied()
}

/// The camera of `image_topic` from the recording's `CameraInfo`: `None` when it has none.
pub fn camera_from_log(
    log: &dyn MessageLog,
    image_topic: &str,
) -> Option<Result<PinholeCamera, String>> {
    let all = log.topics();
    let t = camera_info_topic(&all, image_topic)?;
    let first = log.messages(&t.topic).next()?;
    let what = |e: String| format!("{} ({}) message 0: {e}", t.topic, t.msg_type);
    Some(
        first
            .map_err(|e| what(e.to_string()))
            .and_then(|m| {
                camera_info(t.encoding, &m.data)
                    .map_err(|e| what(format!("byte {}: {}", e.offset, e.msg)))
            })
            .and_then(|c| c.camera().map_err(what)),
    )
}

/// Decodes a `tf2_msgs/TFMessage` into `(parent, child, T_parent_child)`.
pub fn tf_message(enc: Encoding, msg: &[u8]) -> Result<Vec<(String, String, Extrinsic)>, MsgError> {
    with_wire(enc, msg, |r| {
        let n = r.seq_len(8 + 8 * 7)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let (_, parent) = r.header()?;
            let child = r.string()?;
            let mut v = [0.0; 7];
            for x in &mut v {
                *x = r.f64()?;
            }
            let [px, py, pz, qx, qy, qz, qw] = v;
            let q =
                crate::ros2::convert::quat_from_xyzw([qx, qy, qz, qw]).ok_or_else(|| MsgError {
                    offset: 0,
                    msg: format!(
                        "{parent} -> {child}: rotation {:?} is not a unit quaternion",
                        [qx, qy, qz, qw]
                    ),
                })?;
            out.push((
                parent,
                child,
                Extrinsic {
                    q_ab: q,
                    p_ab: Vec3::new(px, py, pz),
                },
            ));
        }
        Ok(out)
    })
}

/// `T_ab` of frames `a` and `b` from the static transforms `tf` (see the module docs); `None`
/// when they are not in one tree.
pub fn relative(tf: &[(String, String, Extrinsic)], a: &str, b: &str) -> Option<Extrinsic> {
    let parent: HashMap<&str, (&str, &Extrinsic)> = tf
        .iter()
        .map(|(p, c, t)| (c.as_str(), (p.as_str(), t)))
        .collect();
    // (root, T_root_x): composed up the parents (a loop or a 64-deep chain stops the walk).
    let chain = |x: &str| {
        let (mut q, mut p) = (Quat::identity(), Vec3::zeros());
        let mut seen = vec![x];
        let mut cur = x;
        while let Some(&(up, t)) = parent.get(cur) {
            if seen.contains(&up) || seen.len() > 64 {
                break;
            }
            // T_up_x = T_up_cur T_cur_x.
            p = t.q_ab * p + t.p_ab;
            q = t.q_ab * q;
            seen.push(up);
            cur = up;
        }
        (cur.to_string(), q, p)
    };
    let (ra, q_ra, p_ra) = chain(a);
    let (rb, q_rb, p_rb) = chain(b);
    if ra != rb {
        return None;
    }
    // T_ab = T_ra^-1 T_rb.
    let q_ar = q_ra.inverse();
    Some(Extrinsic {
        q_ab: q_ar * q_rb,
        p_ab: q_ar * (p_rb - p_ra),
    })
}

/// A sensor in the body, `T_bs` (the camera's `T_bc`, the LiDAR's `T_bl`), from the recording's
/// `/tf_static` and the `header.frame_id` of the first message of the IMU topic and of the
/// sensor's topic `other`: `None` when the recording has no `/tf_static`, an error when it has one
/// that does not link the two frames.
pub fn t_b_from_log(
    log: &dyn MessageLog,
    imu: &TopicInfo,
    other: &TopicInfo,
) -> Option<Result<Extrinsic, String>> {
    let all = log.topics();
    let tf_topic = all
        .iter()
        .find(|t| t.topic == "/tf_static" && t.msg_type == TF_TYPE && t.count > 0)?;
    let first_frame = |t: &TopicInfo| -> Result<String, String> {
        let m = log
            .messages(&t.topic)
            .next()
            .ok_or_else(|| format!("{} has no message", t.topic))?
            .map_err(|e| e.to_string())?;
        frame_id(t.encoding, &m.data)
            .map_err(|e| format!("{}: byte {}: {}", t.topic, e.offset, e.msg))
    };
    let run = || -> Result<Extrinsic, String> {
        let mut tf = Vec::new();
        for (k, m) in log.messages(&tf_topic.topic).enumerate() {
            let m = m.map_err(|e| e.to_string())?;
            let part = tf_message(tf_topic.encoding, &m.data)
                .map_err(|e| format!("/tf_static message {k}: byte {}: {}", e.offset, e.msg))?;
            tf.extend(part);
        }
        let (b, c) = (first_frame(imu)?, first_frame(other)?);
        relative(&tf, &b, &c).ok_or_else(|| {
            format!(
                "/tf_static does not link the IMU's frame {b:?} and {}'s frame {c:?}",
                other.topic
            )
        })
    };
    Some(run())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ext(q: Quat, p: [f64; 3]) -> Extrinsic {
        Extrinsic {
            q_ab: q,
            p_ab: Vec3::from(p),
        }
    }

    #[test]
    fn frames_are_related_through_their_common_root() {
        let rz = |a: f64| Quat::from_axis_angle(&Vec3::z_axis(), a);
        let tf = vec![
            (
                "link".to_string(),
                "imu".to_string(),
                ext(rz(0.3), [0.1, 0.0, 0.0]),
            ),
            (
                "link".to_string(),
                "cam".to_string(),
                ext(rz(-0.2), [0.0, 0.2, 0.0]),
            ),
            (
                "cam".to_string(),
                "cam_optical".to_string(),
                ext(rz(1.0), [0.0, 0.0, 0.05]),
            ),
        ];
        let t = relative(&tf, "imu", "cam_optical").unwrap();
        // Direct: T_imu_optical = T_link_imu^-1 T_link_cam T_cam_optical.
        let iso = |e: &Extrinsic| nalgebra::Isometry3::from_parts(e.p_ab.into(), e.q_ab);
        let want = iso(&tf[0].2).inverse() * iso(&tf[1].2) * iso(&tf[2].2);
        assert!((t.q_ab.angle_to(&want.rotation)) < 1e-12);
        assert!((t.p_ab - want.translation.vector).norm() < 1e-12);
        assert!(relative(&tf, "imu", "elsewhere").is_none());
        let same = relative(&tf, "cam", "cam").unwrap();
        assert!(same.p_ab.norm() == 0.0 && same.q_ab.angle() == 0.0);
    }

    #[test]
    fn camera_info_models() {
        let info = |model: &str, d: Vec<f64>| CameraInfo {
            width: 640,
            height: 480,
            model: model.into(),
            d,
            k: [380.0, 0.0, 320.0, 0.0, 381.0, 240.0, 0.0, 0.0, 1.0],
        };
        let c = info("plumb_bob", vec![0.1, -0.2, 0.001, 0.002, 0.0])
            .camera()
            .unwrap();
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (380.0, 381.0, 320.0, 240.0));
        assert_eq!(
            c.distortion,
            Distortion::RadTan {
                k1: 0.1,
                k2: -0.2,
                p1: 0.001,
                p2: 0.002
            }
        );
        let e = info("plumb_bob", vec![0.1, -0.2, 0.0, 0.0, 0.3])
            .camera()
            .unwrap_err();
        assert!(e.contains("k3 = 0.3"), "{e}");
        let e = info("rational_polynomial", vec![0.0; 8])
            .camera()
            .unwrap_err();
        assert!(e.contains("rational_polynomial"), "{e}");
        assert!(matches!(
            info("equidistant", vec![0.1, 0.2, 0.3, 0.4])
                .camera()
                .unwrap()
                .distortion,
            Distortion::Equidistant { .. }
        ));
        let mut zero = info("plumb_bob", vec![]);
        zero.k = [0.0; 9];
        assert!(zero
            .camera()
            .unwrap_err()
            .contains("not a calibrated camera"));
    }

    #[test]
    fn camera_info_decodes_in_both_encodings_and_its_topic_is_found() {
        // ROS 1: header, height, width, model, D, K, R, P, binning, roi.
        let mut m = 0u32.to_le_bytes().to_vec();
        m.extend([0u8; 8]);
        m.extend(3u32.to_le_bytes());
        m.extend(b"cam");
        m.extend(480u32.to_le_bytes());
        m.extend(640u32.to_le_bytes());
        m.extend(9u32.to_le_bytes());
        m.extend(b"plumb_bob");
        m.extend(5u32.to_le_bytes());
        for v in [
            0.1, 0.2, 0.0, 0.0, 0.0, 380.0, 0.0, 320.0, 0.0, 381.0, 240.0, 0.0, 0.0, 1.0,
        ] {
            m.extend(f64::to_le_bytes(v));
        }
        let c = camera_info(Encoding::Ros1, &m).unwrap();
        assert_eq!((c.width, c.height, c.d.len()), (640, 480, 5));
        assert_eq!(frame_id(Encoding::Ros1, &m).unwrap(), "cam");
        for cut in 0..m.len() {
            assert!(camera_info(Encoding::Ros1, &m[..cut]).is_err());
        }
        let t = |name: &str, ty: &str| TopicInfo {
            topic: name.into(),
            msg_type: ty.into(),
            encoding: Encoding::Ros1,
            count: 1,
            span_ns: None,
        };
        let all = [
            t("/a/camera_info", CAMERA_INFO_TYPE),
            t("/b/camera_info", CAMERA_INFO_TYPE),
            t("/b/image_raw", "sensor_msgs/Image"),
        ];
        assert_eq!(
            camera_info_topic(&all, "/b/image_raw/compressed")
                .unwrap()
                .topic,
            "/b/camera_info"
        );
        assert!(camera_info_topic(&all, "/c/image_raw").is_none());
        assert_eq!(
            camera_info_topic(&all[..1], "/c/image_raw").unwrap().topic,
            "/a/camera_info"
        );
    }

    /// A ROS 1 `tf2_msgs/TFMessage` of `(parent, child, T_parent_child)`.
    fn tf_ros1(tfs: &[(&str, &str, Extrinsic)]) -> Vec<u8> {
        let string = |b: &mut Vec<u8>, s: &str| {
            b.extend((s.len() as u32).to_le_bytes());
            b.extend(s.as_bytes());
        };
        let mut b = (tfs.len() as u32).to_le_bytes().to_vec();
        for (parent, child, t) in tfs {
            b.extend([0u8; 12]); // seq, stamp
            string(&mut b, parent);
            string(&mut b, child);
            for v in [t.p_ab.x, t.p_ab.y, t.p_ab.z] {
                b.extend(v.to_le_bytes());
            }
            let q = t.q_ab.coords;
            for v in [q.x, q.y, q.z, q.w] {
                b.extend(v.to_le_bytes());
            }
        }
        b
    }

    /// A log of three topics, one message each.
    #[derive(Debug)]
    struct Log(Vec<(TopicInfo, Vec<u8>)>);

    impl MessageLog for Log {
        fn path(&self) -> &std::path::Path {
            std::path::Path::new("mem.bag")
        }
        fn describe(&self) -> String {
            "memory".into()
        }
        fn topics(&self) -> Vec<TopicInfo> {
            self.0.iter().map(|(t, _)| t.clone()).collect()
        }
        fn messages(&self, topic: &str) -> super::super::LogStream<'_> {
            let v: Vec<_> = self
                .0
                .iter()
                .filter(|(t, _)| t.topic == topic)
                .map(|(_, d)| {
                    Ok(super::super::LogMessage {
                        log_time_ns: 1,
                        offset: 0,
                        data: d.clone(),
                    })
                })
                .collect();
            Box::new(v.into_iter())
        }
        fn warnings(&self) -> Vec<String> {
            Vec::new()
        }
    }

    #[test]
    fn a_lidar_extrinsic_is_found_in_tf_static_from_the_clouds_frame() {
        let topic = |name: &str, ty: &str| TopicInfo {
            topic: name.into(),
            msg_type: ty.into(),
            encoding: Encoding::Ros1,
            count: 1,
            span_ns: None,
        };
        let header = |frame: &str| {
            let mut b = vec![0u8; 12];
            b.extend((frame.len() as u32).to_le_bytes());
            b.extend(frame.as_bytes());
            b
        };
        let rz = |a: f64| Quat::from_axis_angle(&Vec3::z_axis(), a);
        let t_base_imu = ext(rz(0.1), [0.0, 0.0, 0.1]);
        let t_base_lidar = ext(rz(-0.4), [0.2, 0.0, 0.3]);
        let cloud = crate::rosbag1::msgs::encode_point_cloud2(
            &crate::dataset::LidarScan {
                t_ns: 1_000_000_000,
                points: Vec::new(),
            },
            0,
            "os_lidar",
        )
        .unwrap();
        let log = Log(vec![
            (topic("/imu", "sensor_msgs/Imu"), header("imu_link")),
            (topic("/points", "sensor_msgs/PointCloud2"), cloud),
            (
                topic("/tf_static", TF_TYPE),
                tf_ros1(&[
                    ("base", "imu_link", t_base_imu),
                    ("base", "os_lidar", t_base_lidar),
                ]),
            ),
        ]);
        let all = log.topics();
        let t_bl = t_b_from_log(&log, &all[0], &all[1]).unwrap().unwrap();
        // T_bl = T_base_imu^-1 T_base_lidar.
        let want_q = t_base_imu.q_ab.inverse() * t_base_lidar.q_ab;
        let want_p = t_base_imu.q_ab.inverse() * (t_base_lidar.p_ab - t_base_imu.p_ab);
        assert!((t_bl.q_ab.angle_to(&want_q)).abs() < 1e-12);
        assert!((t_bl.p_ab - want_p).norm() < 1e-12);
        // A cloud in a frame /tf_static does not know: an error naming the topic and frame.
        let mut other = log.0.clone();
        other[1].1 = crate::rosbag1::msgs::encode_point_cloud2(
            &crate::dataset::LidarScan {
                t_ns: 1,
                points: Vec::new(),
            },
            0,
            "velodyne",
        )
        .unwrap();
        let log = Log(other);
        let e = t_b_from_log(&log, &all[0], &all[1]).unwrap().unwrap_err();
        assert!(e.contains("/points") && e.contains("velodyne"), "{e}");
    }
}

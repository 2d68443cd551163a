//! Livox's `CustomMsg`, as `livox_ros_driver` (ROS 1) and `livox_ros_driver2` (ROS 1 and 2)
//! publish it: the same definition in both packages.
//!
//! ```text
//! std_msgs/Header header   # stamp = timebase
//! uint64 timebase          # time of the first point, ns
//! uint32 point_num
//! uint8 lidar_id
//! uint8[3] rsvd
//! CustomPoint[] points     # uint32 offset_time (ns after timebase), float32 x y z,
//!                          # uint8 reflectivity, uint8 tag, uint8 line
//! ```
//!
//! A point's time is `timebase + offset_time`. `point_num` is informational (the array's length
//! is used). `reflectivity` becomes the intensity. The `tag` byte flags noise ([`is_noise`]).
//! CDR is read and written here; ROS 1 serialization by [`crate::rosbag1::msgs`]
//! (`livox_custom_msg`, `encode_livox_custom_msg`, `LIVOX_CUSTOM_MSG`).

use super::{CloudCounts, Decoded, TimeRef, TimeSource, TimeSpec, TimeUnit, MAX_SWEEP_SPAN_NS};
use crate::cdr::{CdrError, CdrReader, CdrWriter};
use crate::dataset::LidarScan;
use povins_core::lidar::LidarPoint;

/// `livox_ros_driver/CustomMsg`, ROS 1 form.
pub const CUSTOM_MSG_TYPE: &str = "livox_ros_driver/CustomMsg";
/// `livox_ros_driver2/CustomMsg`, ROS 1 form.
pub const CUSTOM_MSG2_TYPE: &str = "livox_ros_driver2/CustomMsg";
/// Both.
pub const CUSTOM_MSG_TYPES: [&str; 2] = [CUSTOM_MSG_TYPE, CUSTOM_MSG2_TYPE];

/// The ROS 1 md5sum of `CustomMsg` (the same in both packages: nested types enter it by their
/// own md5sum). Checked against the `rosbags` Python package's in `tests/livox_python.rs`.
pub const CUSTOM_MSG_MD5: &str = "e4d6829bdfe657cb6c21a746c86b21a6";

/// `livox_ros_driver2/msg/CustomMsg`'s definition for a `ros2msg` schema (nested types after it,
/// [`crate::ros2::schema_text`]).
pub const CUSTOM_MSG2_ROS2_DEF: &str = "std_msgs/Header header\nuint64 timebase\n\
uint32 point_num\nuint8 lidar_id\nuint8[3] rsvd\nlivox_ros_driver2/CustomPoint[] points\n";

/// `CustomPoint`'s definition.
pub const CUSTOM_POINT_DEF: &str = "uint32 offset_time\nfloat32 x\nfloat32 y\nfloat32 z\n\
uint8 reflectivity\nuint8 tag\nuint8 line\n";

/// The `ros2msg` schema of `livox_ros_driver2/msg/CustomMsg`.
pub fn custom_msg2_schema() -> String {
    use crate::ros2::defs;
    crate::ros2::schema_text(
        CUSTOM_MSG2_ROS2_DEF,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
            ("livox_ros_driver2/CustomPoint", CUSTOM_POINT_DEF),
        ],
    )
}

/// Its ROS 2 type description hash (Python `rosbags`' `hash_rihs01`, Humble).
pub const RIHS01_CUSTOM_MSG2: &str =
    "RIHS01_2eb17e5e35bf5a2d6cd079f3c57f33abf95e5bf7d71b42cddc05daace73d815a";

/// Livox's noise flags in a point's `tag`: spatial (bits 0-1) at high or moderate confidence
/// (01, 10), intensity (bits 2-3) noise (01), or nearby waveform distortion (bits 6-7, 01).
/// Low-confidence spatial noise (11) and the return number (bits 4-5) are kept.
pub fn is_noise(tag: u8) -> bool {
    let spatial = tag & 0b11;
    let intensity = (tag >> 2) & 0b11;
    let waveform = (tag >> 6) & 0b11;
    spatial == 0b01 || spatial == 0b10 || intensity == 0b01 || waveform == 0b01
}

/// One `CustomPoint`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CustomPoint {
    /// ns after `timebase`.
    pub offset_time: u32,
    /// Position in the LiDAR frame, m.
    pub p_l: [f32; 3],
    /// Reflectivity, 0-255.
    pub reflectivity: u8,
    /// Noise and return flags ([`is_noise`]).
    pub tag: u8,
    /// Laser (line) number.
    pub line: u8,
}

/// A `CustomMsg`.
#[derive(Debug, Clone, PartialEq)]
pub struct CustomMsg {
    /// `header.stamp`, ns.
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub frame_id: String,
    /// Time of the first point, ns.
    pub timebase_ns: u64,
    /// `point_num` as written.
    pub point_num: u32,
    /// Device id.
    pub lidar_id: u8,
    /// The points.
    pub points: Vec<CustomPoint>,
}

/// Bytes of a `CustomPoint` in ROS 1 serialization (packed); CDR pads it to 20 but the last.
pub const POINT_BYTES: usize = 19;

impl CustomMsg {
    /// Decodes a CDR message (ROS 2, `livox_ros_driver2`).
    pub fn decode_cdr(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        let header = crate::ros2::Header::decode(&mut r)?;
        let timebase_ns = r.u64()?;
        let point_num = r.u32()?;
        let lidar_id = r.u8()?;
        for _ in 0..3 {
            r.u8()?;
        }
        // Each point takes 19 bytes and is padded to 20 but the last.
        let n = r.seq_len(POINT_BYTES)?;
        let mut points = Vec::with_capacity(n);
        for _ in 0..n {
            let offset_time = r.u32()?;
            let p_l = [r.f32()?, r.f32()?, r.f32()?];
            points.push(CustomPoint {
                offset_time,
                p_l,
                reflectivity: r.u8()?,
                tag: r.u8()?,
                line: r.u8()?,
            });
        }
        Ok(CustomMsg {
            stamp_ns: header.t_ns,
            frame_id: header.frame_id,
            timebase_ns,
            point_num,
            lidar_id,
            points,
        })
    }

    /// The message of a sweep as the driver writes it: `timebase` and the stamp are the first
    /// point's time (the sweep's stamp without points), offsets after it, reflectivity the
    /// intensity clamped to 0-255, tags and lines 0.
    pub fn from_scan(scan: &LidarScan, frame_id: &str) -> Result<Self, String> {
        let base = scan
            .points
            .iter()
            .map(|p| p.t_ns)
            .min()
            .unwrap_or(scan.t_ns);
        let timebase_ns =
            u64::try_from(base).map_err(|_| format!("sweep time {base} ns is before 1970"))?;
        let points = scan
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                Ok(CustomPoint {
                    offset_time: u32::try_from(p.t_ns - base).map_err(|_| {
                        format!("point {i} is 2^32 ns or more after the sweep's first point")
                    })?,
                    p_l: p.p_l,
                    reflectivity: p.intensity.clamp(0.0, 255.0) as u8,
                    tag: 0,
                    line: 0,
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        Ok(CustomMsg {
            stamp_ns: base,
            frame_id: frame_id.into(),
            timebase_ns,
            point_num: points.len() as u32,
            lidar_id: 0,
            points,
        })
    }

    /// CDR serialization (ROS 2).
    pub fn encode_cdr(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(64 + self.frame_id.len() + 20 * self.points.len());
        crate::ros2::Header::new(self.stamp_ns, &self.frame_id).encode(&mut w)?;
        w.u64(self.timebase_ns);
        w.u32(self.point_num);
        w.u8(self.lidar_id);
        for _ in 0..3 {
            w.u8(0);
        }
        w.seq_len(self.points.len())?;
        for p in &self.points {
            w.u32(p.offset_time);
            for v in p.p_l {
                w.f32(v);
            }
            w.u8(p.reflectivity);
            w.u8(p.tag);
            w.u8(p.line);
        }
        Ok(w.into_inner())
    }

    /// The sweep: stamped with `timebase`, points at `timebase + offset_time`, the same drops as
    /// a PointCloud2 ([`super::CloudCounts`]).
    pub fn decode(&self) -> Result<Decoded, String> {
        let base = i64::try_from(self.timebase_ns)
            .map_err(|_| format!("timebase {} ns is out of range", self.timebase_ns))?;
        let mut counts = CloudCounts {
            points: self.points.len() as u64,
            ..CloudCounts::default()
        };
        let mut points = Vec::with_capacity(self.points.len());
        for p in &self.points {
            if p.p_l.iter().any(|v| !v.is_finite()) {
                counts.non_finite += 1;
            } else if p.p_l == [0.0; 3] {
                counts.no_return += 1;
            } else if is_noise(p.tag) {
                counts.flagged_noise += 1;
            } else if i64::from(p.offset_time) > MAX_SWEEP_SPAN_NS {
                counts.out_of_sweep += 1;
            } else {
                points.push(LidarPoint {
                    t_ns: base + i64::from(p.offset_time),
                    p_l: p.p_l,
                    intensity: f32::from(p.reflectivity),
                });
            }
        }
        Ok(Decoded {
            scan: LidarScan { t_ns: base, points },
            counts,
            time: TimeSource::Field {
                spec: TimeSpec {
                    field: "offset_time",
                    unit: TimeUnit::Ns,
                    reference: TimeRef::Header,
                },
                expected: true,
            },
        })
    }
}

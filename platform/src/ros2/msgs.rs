//! CDR codecs of the ROS 2 messages, field for field in definition order (see the schema texts in
//! [`super::defs`]). Decoders borrow nothing from the input past their return, so a message can be
//! dropped right after decoding; large byte payloads are copied once.

use super::Header;
use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// `sensor_msgs/msg/Imu`. Vectors are `[x, y, z]`, the quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Imu {
    /// Header.
    pub header: Header,
    /// Orientation `[x, y, z, w]`.
    pub orientation: [f64; 4],
    /// Row-major covariance; `[0] = -1` means "no orientation" (REP 145).
    pub orientation_covariance: [f64; 9],
    /// Angular velocity, rad/s.
    pub angular_velocity: [f64; 3],
    /// Covariance (zeros = unknown).
    pub angular_velocity_covariance: [f64; 9],
    /// Linear acceleration (specific force), m/s^2.
    pub linear_acceleration: [f64; 3],
    /// Covariance (zeros = unknown).
    pub linear_acceleration_covariance: [f64; 9],
}

impl Imu {
    /// An IMU message without orientation and with unknown covariances.
    pub fn new(header: Header, angular_velocity: [f64; 3], linear_acceleration: [f64; 3]) -> Self {
        let mut orientation_covariance = [0.0; 9];
        orientation_covariance[0] = -1.0;
        Imu {
            header,
            orientation: [0.0, 0.0, 0.0, 1.0],
            orientation_covariance,
            angular_velocity,
            angular_velocity_covariance: [0.0; 9],
            linear_acceleration,
            linear_acceleration_covariance: [0.0; 9],
        }
    }

    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(340);
        self.header.encode(&mut w)?;
        w.f64_array(&self.orientation);
        w.f64_array(&self.orientation_covariance);
        w.f64_array(&self.angular_velocity);
        w.f64_array(&self.angular_velocity_covariance);
        w.f64_array(&self.linear_acceleration);
        w.f64_array(&self.linear_acceleration_covariance);
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        Ok(Imu {
            header: Header::decode(&mut r)?,
            orientation: r.f64_array()?,
            orientation_covariance: r.f64_array()?,
            angular_velocity: r.f64_array()?,
            angular_velocity_covariance: r.f64_array()?,
            linear_acceleration: r.f64_array()?,
            linear_acceleration_covariance: r.f64_array()?,
        })
    }
}

/// `sensor_msgs/msg/Image`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding, e.g. `mono8`.
    pub encoding: String,
    /// 1 when multi-byte pixels are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// `step * height` bytes.
    pub data: Vec<u8>,
}

impl Image {
    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.encode(&mut w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding)?;
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.bytes(&self.data)?;
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        Ok(Image {
            header: Header::decode(&mut r)?,
            height: r.u32()?,
            width: r.u32()?,
            encoding: r.string()?.to_owned(),
            is_bigendian: r.u8()?,
            step: r.u32()?,
            data: r.bytes()?.to_vec(),
        })
    }
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage {
    /// Header.
    pub header: Header,
    /// Codec description, e.g. `jpeg`, `png`, `bgr8; jpeg compressed bgr8`.
    pub format: String,
    /// The compressed image.
    pub data: Vec<u8>,
}

impl CompressedImage {
    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.encode(&mut w)?;
        w.string(&self.format)?;
        w.bytes(&self.data)?;
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        Ok(CompressedImage {
            header: Header::decode(&mut r)?,
            format: r.string()?.to_owned(),
            data: r.bytes()?.to_vec(),
        })
    }
}

/// `sensor_msgs/msg/PointField` datatype `UINT32`.
pub const POINT_FIELD_UINT32: u8 = 6;
/// `sensor_msgs/msg/PointField` datatype `FLOAT32`.
pub const POINT_FIELD_FLOAT32: u8 = 7;
/// `sensor_msgs/msg/PointField` datatype `FLOAT64`.
pub const POINT_FIELD_FLOAT64: u8 = 8;

/// `sensor_msgs/msg/PointField`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PointField {
    /// Field name.
    pub name: String,
    /// Byte offset inside a point.
    pub offset: u32,
    /// One of the `POINT_FIELD_*` datatypes.
    pub datatype: u8,
    /// Elements per point.
    pub count: u32,
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud2 {
    /// Header.
    pub header: Header,
    /// Rows (1 for an unordered cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// Layout of one point.
    pub fields: Vec<PointField>,
    /// Byte order of the point data.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// Point data.
    pub data: Vec<u8>,
    /// True when no point is invalid (NaN).
    pub is_dense: bool,
}

impl PointCloud2 {
    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 256);
        self.header.encode(&mut w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.seq_len(self.fields.len())?;
        for f in &self.fields {
            w.string(&f.name)?;
            w.u32(f.offset);
            w.u8(f.datatype);
            w.u32(f.count);
        }
        w.bool(self.is_bigendian);
        w.u32(self.point_step);
        w.u32(self.row_step);
        w.bytes(&self.data)?;
        w.bool(self.is_dense);
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        let header = Header::decode(&mut r)?;
        let height = r.u32()?;
        let width = r.u32()?;
        // A field takes at least 4 (name length) + 1 + 4 + 1 + 4 bytes.
        let n = r.seq_len(13)?;
        let mut fields = Vec::with_capacity(n);
        for _ in 0..n {
            fields.push(PointField {
                name: r.string()?.to_owned(),
                offset: r.u32()?,
                datatype: r.u8()?,
                count: r.u32()?,
            });
        }
        Ok(PointCloud2 {
            header,
            height,
            width,
            fields,
            is_bigendian: r.bool()?,
            point_step: r.u32()?,
            row_step: r.u32()?,
            data: r.bytes()?.to_vec(),
            is_dense: r.bool()?,
        })
    }
}

/// `sensor_msgs/msg/ChannelFloat32`.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelFloat32 {
    /// Channel name.
    pub name: String,
    /// One value per point.
    pub values: Vec<f32>,
}

/// `sensor_msgs/msg/PointCloud` (points as `geometry_msgs/Point32`).
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    /// Header.
    pub header: Header,
    /// Points `[x, y, z]`.
    pub points: Vec<[f32; 3]>,
    /// Per-point channels.
    pub channels: Vec<ChannelFloat32>,
}

impl PointCloud {
    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let n: usize = self.channels.iter().map(|c| c.values.len() * 4 + 16).sum();
        let mut w = CdrWriter::with_capacity(self.points.len() * 12 + n + 64);
        self.header.encode(&mut w)?;
        w.seq_len(self.points.len())?;
        for p in &self.points {
            w.f32(p[0]);
            w.f32(p[1]);
            w.f32(p[2]);
        }
        w.seq_len(self.channels.len())?;
        for c in &self.channels {
            w.string(&c.name)?;
            w.f32_seq(&c.values)?;
        }
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        let header = Header::decode(&mut r)?;
        let n = r.seq_len(12)?;
        let mut points = Vec::with_capacity(n);
        for _ in 0..n {
            points.push([r.f32()?, r.f32()?, r.f32()?]);
        }
        // A channel takes at least 4 (name length) + 1 + 4 (value count) bytes.
        let nc = r.seq_len(9)?;
        let mut channels = Vec::with_capacity(nc);
        for _ in 0..nc {
            channels.push(ChannelFloat32 {
                name: r.string()?.to_owned(),
                values: r.f32_seq()?,
            });
        }
        Ok(PointCloud {
            header,
            points,
            channels,
        })
    }
}

/// `nav_msgs/msg/Odometry`: pose of `child_frame_id` in `header.frame_id`, twist in
/// `child_frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    /// Header (parent frame).
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Position `[x, y, z]`.
    pub position: [f64; 3],
    /// Orientation `[x, y, z, w]`.
    pub orientation: [f64; 4],
    /// Pose covariance, row-major 6x6.
    pub pose_covariance: [f64; 36],
    /// Linear velocity in the child frame.
    pub linear: [f64; 3],
    /// Angular velocity in the child frame.
    pub angular: [f64; 3],
    /// Twist covariance, row-major 6x6.
    pub twist_covariance: [f64; 36],
}

impl Odometry {
    /// Encodes the message.
    pub fn encode(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::with_capacity(720);
        self.header.encode(&mut w)?;
        w.string(&self.child_frame_id)?;
        w.f64_array(&self.position);
        w.f64_array(&self.orientation);
        w.f64_array(&self.pose_covariance);
        w.f64_array(&self.linear);
        w.f64_array(&self.angular);
        w.f64_array(&self.twist_covariance);
        Ok(w.into_inner())
    }

    /// Decodes the message.
    pub fn decode(msg: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(msg)?;
        Ok(Odometry {
            header: Header::decode(&mut r)?,
            child_frame_id: r.string()?.to_owned(),
            position: r.f64_array()?,
            orientation: r.f64_array()?,
            pose_covariance: r.f64_array()?,
            linear: r.f64_array()?,
            angular: r.f64_array()?,
            twist_covariance: r.f64_array()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic xorshift so the "fuzz" cases are the same on every run.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
    }

    fn samples() -> Vec<(&'static str, Vec<u8>)> {
        let h = Header::new(1_403_715_273_262_142_976, "body");
        let imu = Imu::new(h.clone(), [0.1, -0.2, 0.3], [9.8, 0.01, -0.5]);
        let img = Image {
            header: Header::new(5, "cam0"),
            height: 3,
            width: 4,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 4,
            data: (0..12).collect(),
        };
        let pc2 = PointCloud2 {
            header: Header::new(-1_500_000_000, "lidar0"),
            height: 1,
            width: 2,
            fields: vec![
                PointField {
                    name: "x".into(),
                    offset: 0,
                    datatype: POINT_FIELD_FLOAT32,
                    count: 1,
                },
                PointField {
                    name: "t".into(),
                    offset: 4,
                    datatype: POINT_FIELD_UINT32,
                    count: 1,
                },
            ],
            is_bigendian: false,
            point_step: 8,
            row_step: 16,
            data: (0..16).collect(),
            is_dense: true,
        };
        let pc = PointCloud {
            header: Header::new(7, "cam0"),
            points: vec![[0.1, 0.2, 1.0], [0.3, -0.4, 1.0]],
            channels: vec![
                ChannelFloat32 {
                    name: "id_of_point".into(),
                    values: vec![3.0, 4.0],
                },
                ChannelFloat32 {
                    name: "u_of_point".into(),
                    values: vec![10.5, 20.25],
                },
            ],
        };
        let odom = Odometry {
            header: Header::new(9, "world"),
            child_frame_id: "body".into(),
            position: [1.0, 2.0, 3.0],
            orientation: [0.0, 0.0, 0.0, 1.0],
            pose_covariance: [0.5; 36],
            linear: [0.1, 0.2, 0.3],
            angular: [0.0; 3],
            twist_covariance: [0.25; 36],
        };
        let cimg = CompressedImage {
            header: Header::new(6, "cam0"),
            format: "png".into(),
            data: vec![0x89, b'P', b'N', b'G', 1, 2, 3],
        };
        vec![
            ("cimg", cimg.encode().unwrap()),
            ("imu", imu.encode().unwrap()),
            ("image", img.encode().unwrap()),
            ("pc2", pc2.encode().unwrap()),
            ("pc", pc.encode().unwrap()),
            ("odom", odom.encode().unwrap()),
        ]
    }

    fn decode(kind: &str, m: &[u8]) -> Result<(), CdrError> {
        match kind {
            "imu" => Imu::decode(m).map(drop),
            "image" => Image::decode(m).map(drop),
            "cimg" => CompressedImage::decode(m).map(drop),
            "pc2" => PointCloud2::decode(m).map(drop),
            "pc" => PointCloud::decode(m).map(drop),
            _ => Odometry::decode(m).map(drop),
        }
    }

    #[test]
    fn messages_round_trip_and_know_their_sizes() {
        let mut s = samples();
        let c = CompressedImage::decode(&s.remove(0).1).unwrap();
        assert_eq!(
            (c.header.t_ns, c.format.as_str(), c.data.len()),
            (6, "png", 7)
        );
        // Imu layout by hand: 4 header bytes, then in the payload sec 0..4, nanosec 4..8, length
        // 8..12, "body\0" 12..17, padding to 24, 37 float64 = 296 bytes: 4 + 24 + 296.
        assert_eq!(s[0].1.len(), 324);
        let h = Header::new(1_403_715_273_262_142_976, "body");
        let imu = Imu::new(h, [0.1, -0.2, 0.3], [9.8, 0.01, -0.5]);
        assert_eq!(Imu::decode(&s[0].1).unwrap(), imu);
        let pc2 = PointCloud2::decode(&s[2].1).unwrap();
        assert_eq!(pc2.header.t_ns, -1_500_000_000);
        assert_eq!(pc2.fields[1].name, "t");
        assert_eq!(pc2.encode().unwrap(), s[2].1);
        let pc = PointCloud::decode(&s[3].1).unwrap();
        assert_eq!(pc.channels[1].values, vec![10.5, 20.25]);
        assert_eq!(pc.encode().unwrap(), s[3].1);
        let odom = Odometry::decode(&s[4].1).unwrap();
        assert_eq!(odom.child_frame_id, "body");
        assert_eq!(odom.encode().unwrap(), s[4].1);
        assert_eq!(Image::decode(&s[1].1).unwrap().data.len(), 12);
    }

    #[test]
    fn every_truncation_fails_with_an_offset_inside_the_message() {
        for (kind, m) in samples() {
            assert!(decode(kind, &m).is_ok());
            for cut in 0..m.len() {
                let e = decode(kind, &m[..cut]).expect_err(kind);
                assert!(e.offset <= cut, "{kind} cut {cut}: offset {}", e.offset);
            }
        }
    }

    #[test]
    fn random_byte_flips_never_panic() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut errors = 0;
        for (kind, m) in samples() {
            for _ in 0..2000 {
                let mut c = m.clone();
                for _ in 0..1 + rng.next() % 4 {
                    let i = (rng.next() as usize) % c.len();
                    c[i] ^= 1 << (rng.next() % 8);
                }
                if decode(kind, &c).is_err() {
                    errors += 1;
                }
            }
        }
        // Flips in lengths, bools and the header must be caught; flips in floats cannot be.
        assert!(errors > 500, "{errors}");
    }
}

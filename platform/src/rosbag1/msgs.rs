//! ROS 1 message decoders (`sensor_msgs/Imu`, `sensor_msgs/Image`, `sensor_msgs/CompressedImage`)
//! and encoders (the same and `sensor_msgs/PointCloud2`, with their definitions and md5sums for
//! a bag's connection records: [`MsgType`]).
//!
//! ROS 1 serialization is little-endian with no alignment: primitives back to back, strings and
//! variable arrays a `u32` length then the elements (strings without a NUL), fixed arrays
//! without a length. `std_msgs/Header` is `seq: u32`, `stamp` (`sec: u32`, `nsec: u32`),
//! `frame_id: string`; `header.stamp` is the sample's time. Every read is bounds-checked and
//! fails with the byte offset in the message.

use crate::dataset::ImageFrame;
use povins_core::inertial::ImuSample;
use povins_core::math::Vec3;

/// `sensor_msgs/Imu`.
pub const IMU_TYPE: &str = "sensor_msgs/Imu";
/// `sensor_msgs/Image`.
pub const IMAGE_TYPE: &str = "sensor_msgs/Image";
/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED_IMAGE_TYPE: &str = "sensor_msgs/CompressedImage";

/// A decoding failure at a byte offset of the message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MsgError {
    /// Byte offset in the message.
    pub offset: usize,
    /// What was wrong.
    pub msg: String,
}

/// Cursor over one ROS 1 message.
pub(crate) struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// A cursor at the start of `b`.
    pub(crate) fn new(b: &'a [u8]) -> Self {
        Reader { b, pos: 0 }
    }

    pub(crate) fn err(&self, msg: impl Into<String>) -> MsgError {
        MsgError {
            offset: self.pos,
            msg: msg.into(),
        }
    }

    pub(crate) fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], MsgError> {
        let left = self.b.len() - self.pos;
        if n > left {
            return Err(self.err(format!("truncated: {what} needs {n} bytes, {left} left")));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub(crate) fn arr<const N: usize>(&mut self, what: &str) -> Result<[u8; N], MsgError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }

    pub(crate) fn u8(&mut self) -> Result<u8, MsgError> {
        Ok(self.arr::<1>("uint8")?[0])
    }

    pub(crate) fn u32(&mut self) -> Result<u32, MsgError> {
        Ok(u32::from_le_bytes(self.arr("uint32")?))
    }

    pub(crate) fn f64s<const N: usize>(&mut self) -> Result<[f64; N], MsgError> {
        let mut a = [0.0; N];
        for x in &mut a {
            *x = f64::from_le_bytes(self.arr("float64")?);
        }
        Ok(a)
    }

    fn bytes(&mut self, what: &str) -> Result<&'a [u8], MsgError> {
        let n = self.u32()? as usize;
        self.take(n, what)
    }

    pub(crate) fn string(&mut self) -> Result<&'a str, MsgError> {
        let at = self.pos;
        let b = self.bytes("string")?;
        std::str::from_utf8(b).map_err(|_| MsgError {
            offset: at,
            msg: "string is not UTF-8".into(),
        })
    }

    /// `std_msgs/Header`: the stamp in ns.
    pub(crate) fn header(&mut self) -> Result<i64, MsgError> {
        Ok(self.header_with_frame()?.0)
    }

    /// `std_msgs/Header`: the stamp in ns and the frame id.
    pub(crate) fn header_with_frame(&mut self) -> Result<(i64, &'a str), MsgError> {
        let _seq = self.u32()?;
        let t = super::record::time_ns(&self.arr::<8>("stamp")?);
        Ok((t, self.string()?))
    }

    /// Bytes left.
    pub(crate) fn remaining(&self) -> usize {
        self.b.len() - self.pos
    }
}

/// `sensor_msgs/Imu` -> IMU sample (gyro rad/s, specific force m/s^2, in the message's frame;
/// orientation and covariances ignored).
pub fn imu(msg: &[u8]) -> Result<ImuSample, MsgError> {
    let mut r = Reader { b: msg, pos: 0 };
    let t_ns = r.header()?;
    r.f64s::<4>()?; // orientation
    r.f64s::<9>()?;
    let w = r.f64s::<3>()?;
    r.f64s::<9>()?;
    let a = r.f64s::<3>()?;
    r.f64s::<9>()?;
    let s = ImuSample {
        t_ns,
        gyro_rps: Vec3::from(w),
        accel_mps2: Vec3::from(a),
    };
    if !s.is_finite() {
        return Err(r.err("non-finite IMU sample"));
    }
    Ok(s)
}

/// `sensor_msgs/Image` -> gray image (see [`crate::image_raw`] for the encodings).
pub fn image(msg: &[u8]) -> Result<ImageFrame, MsgError> {
    let mut r = Reader { b: msg, pos: 0 };
    let t_ns = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let encoding = r.string()?;
    let is_bigendian = r.u8()? != 0;
    let step = r.u32()?;
    let at = r.pos;
    let data = r.bytes("data")?;
    let mono8 = crate::image_raw::mono8_from_raw(encoding, width, height, step, is_bigendian, data)
        .map_err(|msg| MsgError { offset: at, msg })?;
    Ok(ImageFrame {
        t_ns,
        width,
        height,
        mono8,
        path: None,
    })
}

/// `sensor_msgs/CompressedImage` (JPEG or PNG) -> gray image (see [`crate::image_codec`]).
pub fn compressed_image(msg: &[u8]) -> Result<ImageFrame, MsgError> {
    let mut r = Reader { b: msg, pos: 0 };
    let t_ns = r.header()?;
    let format = r.string()?;
    let at = r.pos;
    let data = r.bytes("data")?;
    let im = crate::image_codec::decode_mono8(format, data)
        .map_err(|msg| MsgError { offset: at, msg })?;
    Ok(ImageFrame {
        t_ns,
        width: im.width,
        height: im.height,
        mono8: im.pixels,
        path: None,
    })
}

/// Decodes an image message of type `msg_type` (Image or CompressedImage).
pub fn any_image(msg_type: &str, msg: &[u8]) -> Result<ImageFrame, MsgError> {
    if msg_type == COMPRESSED_IMAGE_TYPE {
        compressed_image(msg)
    } else {
        image(msg)
    }
}

/// `sensor_msgs/PointCloud2` -> the same struct the CDR decoder gives
/// ([`crate::ros2::msgs::PointCloud2`]); the point data is read by [`crate::cloud`].
pub fn point_cloud2(msg: &[u8]) -> Result<crate::ros2::msgs::PointCloud2, MsgError> {
    use crate::ros2::msgs::{PointCloud2, PointField};
    let mut r = Reader::new(msg);
    let (t_ns, frame_id) = r.header_with_frame()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let at = r.pos;
    let n = r.u32()? as usize;
    // A field takes at least 13 bytes (empty name, offset, datatype, count).
    if n.saturating_mul(13) > r.remaining() {
        return Err(MsgError {
            offset: at,
            msg: format!(
                "{n} point fields cannot fit in the {} bytes left",
                r.remaining()
            ),
        });
    }
    let mut fields = Vec::with_capacity(n);
    for _ in 0..n {
        fields.push(PointField {
            name: r.string()?.to_owned(),
            offset: r.u32()?,
            datatype: r.u8()?,
            count: r.u32()?,
        });
    }
    let is_bigendian = r.u8()? != 0;
    let point_step = r.u32()?;
    let row_step = r.u32()?;
    let data = r.bytes("data")?.to_vec();
    let is_dense = r.u8()? != 0;
    Ok(PointCloud2 {
        header: crate::ros2::Header {
            t_ns,
            frame_id: frame_id.to_owned(),
        },
        height,
        width,
        fields,
        is_bigendian,
        point_step,
        row_step,
        data,
        is_dense,
    })
}

/// A ROS 1 message type as a bag's connection record names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MsgType {
    /// `package/Name`.
    pub name: &'static str,
    /// The type's md5sum (ROS 1's hash of the definition without comments, nested types
    /// replaced by their md5sums).
    pub md5sum: &'static str,
    /// The full definition as `rosbag record` stores it: the type's fields, then each nested
    /// type after a line of 80 `=` and `MSG: package/Name`.
    pub definition: &'static str,
}

macro_rules! header_def {
    () => {
        "================================================================================\n\
         MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    };
}

/// `sensor_msgs/Imu` (fields of ros/common_msgs `sensor_msgs/msg/Imu.msg`, comments dropped).
pub const IMU_MSG: MsgType = MsgType {
    name: IMU_TYPE,
    md5sum: "6a62c6daae103f4ff57a132d6f95cec2",
    definition: concat!(
        "Header header\n\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\n",
        "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\n",
        "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
        header_def!(),
        "================================================================================\n",
        "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
        "================================================================================\n",
        "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
    ),
};

/// `sensor_msgs/Image`.
pub const IMAGE_MSG: MsgType = MsgType {
    name: IMAGE_TYPE,
    md5sum: "060021388200f6f0f447d0fcd9c64743",
    definition: concat!(
        "Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n",
        "uint32 step\nuint8[] data\n",
        header_def!()
    ),
};

/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED_IMAGE_MSG: MsgType = MsgType {
    name: COMPRESSED_IMAGE_TYPE,
    md5sum: "8f7a12909da2c9d3332d540a0977563f",
    definition: concat!(
        "Header header\nstring format\nuint8[] data\n",
        header_def!()
    ),
};

/// `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2_MSG: MsgType = MsgType {
    name: "sensor_msgs/PointCloud2",
    md5sum: "1158d486dd51d683ce2f1be655c3c181",
    definition: concat!(
        "Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\n",
        "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
        header_def!(),
        "================================================================================\n",
        "MSG: sensor_msgs/PointField\nuint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\n",
        "uint8 UINT16  = 4\nuint8 INT32   = 5\nuint8 UINT32  = 6\nuint8 FLOAT32 = 7\n",
        "uint8 FLOAT64 = 8\n\nstring name\nuint32 offset\nuint8  datatype\nuint32 count\n"
    ),
};

/// A ROS time (`sec: u32`, `nsec: u32`, little-endian) of `t_ns`, when it fits one.
pub fn ros_time(t_ns: i64) -> Option<[u8; 8]> {
    let sec = u32::try_from(t_ns.div_euclid(1_000_000_000)).ok()?;
    let nsec = t_ns.rem_euclid(1_000_000_000) as u32;
    let mut b = [0u8; 8];
    b[..4].copy_from_slice(&sec.to_le_bytes());
    b[4..].copy_from_slice(&nsec.to_le_bytes());
    Some(b)
}

/// Appends ROS 1 fields to a message.
struct Writer(Vec<u8>);

impl Writer {
    fn u32(&mut self, v: u32) {
        self.0.extend(v.to_le_bytes());
    }

    fn len(&mut self, n: usize) -> Result<(), MsgError> {
        let n = u32::try_from(n).map_err(|_| MsgError {
            offset: self.0.len(),
            msg: format!("{n} elements do not fit a ROS 1 array length"),
        })?;
        self.u32(n);
        Ok(())
    }

    fn bytes(&mut self, b: &[u8]) -> Result<(), MsgError> {
        self.len(b.len())?;
        self.0.extend_from_slice(b);
        Ok(())
    }

    fn f64s(&mut self, v: &[f64]) {
        for x in v {
            self.0.extend(x.to_le_bytes());
        }
    }

    /// `std_msgs/Header`.
    fn header(seq: u32, t_ns: i64, frame_id: &str) -> Result<Self, MsgError> {
        let stamp = ros_time(t_ns).ok_or_else(|| MsgError {
            offset: 4,
            msg: format!("stamp {t_ns} ns is not a ROS 1 time (0 to 2^32 s)"),
        })?;
        let mut w = Writer(Vec::new());
        w.u32(seq);
        w.0.extend(stamp);
        w.bytes(frame_id.as_bytes())?;
        Ok(w)
    }
}

/// `sensor_msgs/Imu` of a sample: orientation unknown (covariance element 0 is -1, as the
/// message's documentation asks), covariances of the rates zero ("unknown").
pub fn encode_imu(s: &ImuSample, seq: u32, frame_id: &str) -> Result<Vec<u8>, MsgError> {
    let mut w = Writer::header(seq, s.t_ns, frame_id)?;
    let mut unknown = [0.0; 9];
    unknown[0] = -1.0;
    w.f64s(&[0.0, 0.0, 0.0, 1.0]);
    w.f64s(&unknown);
    w.f64s(s.gyro_rps.as_slice());
    w.f64s(&[0.0; 9]);
    w.f64s(s.accel_mps2.as_slice());
    w.f64s(&[0.0; 9]);
    Ok(w.0)
}

/// `sensor_msgs/Image` of a gray image: `mono8`, step = width.
pub fn encode_mono8(im: &ImageFrame, seq: u32, frame_id: &str) -> Result<Vec<u8>, MsgError> {
    if im.mono8.len() as u64 != u64::from(im.width) * u64::from(im.height) {
        return Err(MsgError {
            offset: 0,
            msg: format!(
                "{} pixels for a {}x{} image",
                im.mono8.len(),
                im.width,
                im.height
            ),
        });
    }
    let mut w = Writer::header(seq, im.t_ns, frame_id)?;
    w.u32(im.height);
    w.u32(im.width);
    w.bytes(b"mono8")?;
    w.0.push(0);
    w.u32(im.width);
    w.bytes(&im.mono8)?;
    Ok(w.0)
}

/// `sensor_msgs/CompressedImage` (`format` e.g. `png` or `jpeg`).
pub fn encode_compressed_image(
    t_ns: i64,
    seq: u32,
    frame_id: &str,
    format: &str,
    data: &[u8],
) -> Result<Vec<u8>, MsgError> {
    let mut w = Writer::header(seq, t_ns, frame_id)?;
    w.bytes(format.as_bytes())?;
    w.bytes(data)?;
    Ok(w.0)
}

/// `sensor_msgs/PointCloud2` of a sweep in povins' compact layout
/// ([`crate::cloud::Layout::Compact`]), stamped with the sweep time.
pub fn encode_point_cloud2(
    scan: &crate::dataset::LidarScan,
    seq: u32,
    frame_id: &str,
) -> Result<Vec<u8>, MsgError> {
    encode_point_cloud2_in(crate::cloud::Layout::Compact, scan, seq, frame_id)
}

/// `sensor_msgs/PointCloud2` of a sweep in a driver's layout ([`crate::cloud::encode_points`]):
/// one row, little-endian, stamped with the sweep time.
pub fn encode_point_cloud2_in(
    layout: crate::cloud::Layout,
    scan: &crate::dataset::LidarScan,
    seq: u32,
    frame_id: &str,
) -> Result<Vec<u8>, MsgError> {
    let mut w = Writer::header(seq, scan.t_ns, frame_id)?;
    let (fields, step, data) =
        crate::cloud::encode_points(layout, scan).map_err(|msg| MsgError { offset: 0, msg })?;
    w.u32(1);
    w.len(scan.points.len())?;
    w.len(fields.len())?;
    for f in &fields {
        w.bytes(f.name.as_bytes())?;
        w.u32(f.offset);
        w.0.push(f.datatype);
        w.u32(f.count);
    }
    w.0.push(0);
    w.u32(step);
    w.len(data.len())?;
    w.bytes(&data)?;
    w.0.push(1);
    Ok(w.0)
}

use crate::cloud::livox;

macro_rules! custom_msg_def {
    ($pkg:literal) => {
        concat!(
            "std_msgs/Header header\nuint64 timebase\nuint32 point_num\nuint8 lidar_id\n",
            "uint8[3] rsvd\n",
            $pkg,
            "/CustomPoint[] points\n",
            "================================================================================\n",
            "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n",
            "================================================================================\n",
            "MSG: ",
            $pkg,
            "/CustomPoint\nuint32 offset_time\nfloat32 x\nfloat32 y\nfloat32 z\n",
            "uint8 reflectivity\nuint8 tag\nuint8 line\n"
        )
    };
}

/// `livox_ros_driver/CustomMsg` for a ROS 1 bag's connection record.
pub const LIVOX_CUSTOM_MSG: MsgType = MsgType {
    name: livox::CUSTOM_MSG_TYPE,
    md5sum: livox::CUSTOM_MSG_MD5,
    definition: custom_msg_def!("livox_ros_driver"),
};

/// `livox_ros_driver2/CustomMsg` for a ROS 1 bag's connection record.
pub const LIVOX_CUSTOM_MSG2: MsgType = MsgType {
    name: livox::CUSTOM_MSG2_TYPE,
    md5sum: livox::CUSTOM_MSG_MD5,
    definition: custom_msg_def!("livox_ros_driver2"),
};

/// `livox_ros_driver/CustomMsg` or `livox_ros_driver2/CustomMsg` ([`livox`]).
pub fn livox_custom_msg(msg: &[u8]) -> Result<livox::CustomMsg, MsgError> {
    let mut r = Reader::new(msg);
    let (stamp_ns, frame_id) = r.header_with_frame()?;
    let timebase_ns = u64::from_le_bytes(r.arr("timebase")?);
    let point_num = r.u32()?;
    let lidar_id = r.u8()?;
    r.take(3, "rsvd")?;
    let at = msg.len() - r.remaining();
    let n = r.u32()? as usize;
    if n.saturating_mul(livox::POINT_BYTES) > r.remaining() {
        return Err(MsgError {
            offset: at,
            msg: format!(
                "{n} points of {} bytes cannot fit in the {} bytes left",
                livox::POINT_BYTES,
                r.remaining()
            ),
        });
    }
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        let b = r.take(livox::POINT_BYTES, "CustomPoint")?;
        let f = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        points.push(livox::CustomPoint {
            offset_time: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            p_l: [f(4), f(8), f(12)],
            reflectivity: b[16],
            tag: b[17],
            line: b[18],
        });
    }
    Ok(livox::CustomMsg {
        stamp_ns,
        frame_id: frame_id.to_owned(),
        timebase_ns,
        point_num,
        lidar_id,
        points,
    })
}

/// A Livox `CustomMsg` in ROS 1 serialization (`seq` is the header's).
pub fn encode_livox_custom_msg(m: &livox::CustomMsg, seq: u32) -> Result<Vec<u8>, MsgError> {
    let stamp = ros_time(m.stamp_ns).ok_or_else(|| MsgError {
        offset: 0,
        msg: format!("stamp {} ns does not fit a ROS 1 time", m.stamp_ns),
    })?;
    let mut b = Vec::with_capacity(48 + m.frame_id.len() + 19 * m.points.len());
    b.extend(seq.to_le_bytes());
    b.extend(stamp);
    b.extend((m.frame_id.len() as u32).to_le_bytes());
    b.extend(m.frame_id.as_bytes());
    b.extend(m.timebase_ns.to_le_bytes());
    b.extend(m.point_num.to_le_bytes());
    b.push(m.lidar_id);
    b.extend([0u8; 3]);
    b.extend((m.points.len() as u32).to_le_bytes());
    for p in &m.points {
        b.extend(p.offset_time.to_le_bytes());
        for v in p.p_l {
            b.extend(v.to_le_bytes());
        }
        b.extend([p.reflectivity, p.tag, p.line]);
    }
    Ok(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(t_ns: i64, frame: &str) -> Vec<u8> {
        let mut b = 7u32.to_le_bytes().to_vec();
        b.extend(((t_ns / 1_000_000_000) as u32).to_le_bytes());
        b.extend(((t_ns % 1_000_000_000) as u32).to_le_bytes());
        b.extend((frame.len() as u32).to_le_bytes());
        b.extend(frame.as_bytes());
        b
    }

    fn string(s: &str) -> Vec<u8> {
        let mut b = (s.len() as u32).to_le_bytes().to_vec();
        b.extend(s.as_bytes());
        b
    }

    #[test]
    fn imu_fields_are_read_unaligned() {
        let mut m = header(1_500_000_001, "imu");
        let vals: Vec<f64> = (0..(4 + 9 + 3 + 9 + 3 + 9)).map(f64::from).collect();
        for v in &vals {
            m.extend(v.to_le_bytes());
        }
        let s = imu(&m).unwrap();
        assert_eq!(s.t_ns, 1_500_000_001);
        assert_eq!(s.gyro_rps, Vec3::new(13.0, 14.0, 15.0));
        assert_eq!(s.accel_mps2, Vec3::new(25.0, 26.0, 27.0));
        for cut in 0..m.len() {
            assert!(imu(&m[..cut]).is_err());
        }
        let e = imu(&m[..40]).unwrap_err();
        assert!(e.msg.contains("truncated"), "{e:?}");
    }

    #[test]
    fn image_with_step_padding_and_bad_step() {
        let mut m = header(2_000_000_000, "cam");
        m.extend(2u32.to_le_bytes()); // height
        m.extend(3u32.to_le_bytes()); // width
        m.extend(string("mono8"));
        m.push(0);
        m.extend(4u32.to_le_bytes());
        m.extend(8u32.to_le_bytes());
        m.extend([1, 2, 3, 0, 4, 5, 6, 0]);
        let im = image(&m).unwrap();
        assert_eq!((im.t_ns, im.width, im.height), (2_000_000_000, 3, 2));
        assert_eq!(im.mono8, vec![1, 2, 3, 4, 5, 6]);
        let mut bad = m.clone();
        let step_at = m.len() - 8 - 4 - 4;
        bad[step_at..step_at + 4].copy_from_slice(&2u32.to_le_bytes());
        let e = image(&bad).unwrap_err();
        assert!(e.msg.contains("step 2"), "{e:?}");
    }

    #[test]
    fn compressed_image_errors_name_the_payload() {
        let mut m = header(0, "cam");
        m.extend(string("jpeg"));
        m.extend(string("notanimage"));
        let e = compressed_image(&m).unwrap_err();
        assert!(e.msg.contains("neither JPEG nor PNG"), "{e:?}");
    }
}

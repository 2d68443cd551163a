//! ROS 1 message decoders: `sensor_msgs/Imu`, `sensor_msgs/Image`, `sensor_msgs/CompressedImage`.
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

    fn arr<const N: usize>(&mut self, what: &str) -> Result<[u8; N], MsgError> {
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

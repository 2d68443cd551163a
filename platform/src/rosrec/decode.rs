//! The messages a run reads, decoded by their encoding: ROS 1 serialization through
//! [`crate::rosbag1::msgs`], CDR through [`crate::ros2::msgs`]. Raw image encodings become 8-bit
//! gray through [`crate::image_raw`] and compressed ones through [`crate::image_codec`] for both,
//! so a message gives the same sample whatever container and encoding carried it.

use super::Encoding;
use crate::cdr::CdrError;
use crate::cloud::{self, livox, CloudOptions, Decoded};
use crate::dataset::ImageFrame;
use crate::ros2::msgs as cdr_msgs;
use crate::rosbag1::msgs as ros1_msgs;
use povins_core::inertial::ImuSample;

pub use crate::rosbag1::msgs::MsgError;

/// `sensor_msgs/Imu`.
pub const IMU_TYPE: &str = "sensor_msgs/Imu";
/// `sensor_msgs/Image`.
pub const IMAGE_TYPE: &str = "sensor_msgs/Image";
/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED_IMAGE_TYPE: &str = "sensor_msgs/CompressedImage";
/// `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2_TYPE: &str = "sensor_msgs/PointCloud2";
/// The LiDAR message types read: PointCloud2 in any driver layout, Livox's CustomMsg of both
/// drivers ([`crate::cloud`]).
pub const LIDAR_TYPES: [&str; 3] = [
    POINT_CLOUD2_TYPE,
    livox::CUSTOM_MSG_TYPE,
    livox::CUSTOM_MSG2_TYPE,
];

impl From<CdrError> for MsgError {
    fn from(e: CdrError) -> Self {
        MsgError {
            offset: e.offset,
            msg: e.msg,
        }
    }
}

/// `sensor_msgs/Imu` -> IMU sample at `header.stamp` (gyro rad/s, specific force m/s^2, in the
/// message's frame; orientation and covariances ignored). A non-finite value is an error.
pub fn imu(enc: Encoding, msg: &[u8]) -> Result<ImuSample, MsgError> {
    match enc {
        Encoding::Ros1 => ros1_msgs::imu(msg),
        Encoding::Cdr => {
            let m = cdr_msgs::Imu::decode(msg)?;
            crate::ros2::convert::imu_from_msg(&m).ok_or_else(|| MsgError {
                offset: 0,
                msg: "non-finite IMU sample".into(),
            })
        }
    }
}

/// An image message of type `msg_type` (`sensor_msgs/Image` or `sensor_msgs/CompressedImage`)
/// -> gray image at `header.stamp`.
pub fn image(enc: Encoding, msg_type: &str, msg: &[u8]) -> Result<ImageFrame, MsgError> {
    match enc {
        Encoding::Ros1 => ros1_msgs::any_image(msg_type, msg),
        Encoding::Cdr if msg_type == COMPRESSED_IMAGE_TYPE => {
            let m = cdr_msgs::CompressedImage::decode(msg)?;
            let im = crate::image_codec::decode_mono8(&m.format, &m.data)
                .map_err(|msg| MsgError { offset: 0, msg })?;
            Ok(ImageFrame {
                t_ns: m.header.t_ns,
                width: im.width,
                height: im.height,
                mono8: im.pixels,
                path: None,
            })
        }
        Encoding::Cdr => {
            let m = cdr_msgs::Image::decode(msg)?;
            let mono8 = crate::image_raw::mono8_from_raw(
                &m.encoding,
                m.width,
                m.height,
                m.step,
                m.is_bigendian != 0,
                &m.data,
            )
            .map_err(|msg| MsgError { offset: 0, msg })?;
            Ok(ImageFrame {
                t_ns: m.header.t_ns,
                width: m.width,
                height: m.height,
                mono8,
                path: None,
            })
        }
    }
}

/// A LiDAR message of type `msg_type` ([`LIDAR_TYPES`]) -> the sweep, the points dropped and
/// where the point times came from ([`crate::cloud`]).
pub fn sweep(
    enc: Encoding,
    msg_type: &str,
    msg: &[u8],
    opts: &CloudOptions,
) -> Result<Decoded, MsgError> {
    let bad = |msg: String| MsgError { offset: 0, msg };
    if livox::CUSTOM_MSG_TYPES.contains(&msg_type) {
        let m = match enc {
            Encoding::Ros1 => ros1_msgs::livox_custom_msg(msg)?,
            Encoding::Cdr => livox::CustomMsg::decode_cdr(msg)?,
        };
        return m.decode().map_err(bad);
    }
    let m = match enc {
        Encoding::Ros1 => ros1_msgs::point_cloud2(msg)?,
        Encoding::Cdr => cdr_msgs::PointCloud2::decode(msg)?,
    };
    cloud::decode_point_cloud2(&m, opts).map_err(bad)
}

//! A [`Dataset`] as ROS messages, whatever the container: this module alone decides the topics,
//! their types and definitions, the order of the messages and each message's bytes (ROS 1
//! serialization or CDR, by the container's [`Encoding`]); a container writer
//! ([`ContainerWriter`]: a ROS 1 bag, a ROS 2 bag, an MCAP file) only stores what it is given.
//!
//! Messages are given in time order (IMU before an image before a sweep at equal times), each
//! with its log time equal to its `header.stamp`. Feature tracks, ground truth and the calibration
//! are not written (the calibration goes beside the recording as Kalibr / EuRoC files).
//!
//! | stream | ROS 1 type | ROS 2 type | content |
//! |---|---|---|---|
//! | IMU | `sensor_msgs/Imu` | `sensor_msgs/msg/Imu` | gyro, specific force; orientation unknown (`orientation_covariance[0] = -1`), covariances zero |
//! | images | `sensor_msgs/Image` | `sensor_msgs/msg/Image` | `mono8`, `step` = width |
//! | images, compressed | `sensor_msgs/CompressedImage` | `sensor_msgs/msg/CompressedImage` | the bytes an [`ImageCompressor`] gives, with its `format` |
//! | LiDAR | `sensor_msgs/PointCloud2` | `sensor_msgs/msg/PointCloud2` | povins' 20-byte points ([`crate::cloud::Layout::Compact`]), or a driver's layout ([`DatasetTopics::lidar_wire`]) |
//! | LiDAR, Livox | `livox_ros_driver{,2}/CustomMsg` | `livox_ros_driver2/msg/CustomMsg` | [`crate::cloud::livox`] |

use super::Encoding;
use crate::cloud::{livox, Wire};
use crate::dataset::{Dataset, ImageFrame};
use crate::error::IoError;
use crate::ros2::{self, msgs as ros2msgs, Header};
use crate::rosbag1::msgs::{self as ros1, MsgType};
use std::path::Path;

/// A topic as a container declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicSpec {
    /// Topic name.
    pub topic: String,
    /// Message type as the encoding names it: `sensor_msgs/Imu` (ROS 1) or
    /// `sensor_msgs/msg/Imu` (ROS 2).
    pub msg_type: String,
    /// How its messages are serialized.
    pub encoding: Encoding,
    /// The full definition: ROS 1 (`rosbag record`'s connection `message_definition`, MCAP
    /// `ros1msg` schema) or ROS 2 (`ros2msg` schema, rosbag2's `message_definitions`).
    pub definition: String,
    /// ROS 1: the type's md5sum; ROS 2: its `RIHS01_` type description hash.
    pub type_hash: String,
}

/// A container being written: declares topics, stores serialized messages.
pub trait ContainerWriter {
    /// Declares a topic; the returned id names it in [`ContainerWriter::write`].
    fn add_topic(&mut self, spec: &TopicSpec) -> Result<usize, IoError>;
    /// Stores the serialized message `data` of topic `topic`, logged at `t_ns`.
    fn write(&mut self, topic: usize, t_ns: i64, data: &[u8]) -> Result<(), IoError>;
}

/// Topics and frame ids of a sequence written as ROS messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DatasetTopics {
    /// `sensor_msgs/Imu` topic and its `header.frame_id`.
    pub imu: (String, String),
    /// `sensor_msgs/Image` (mono8) topic and frame id.
    pub image: (String, String),
    /// `sensor_msgs/PointCloud2` topic and frame id.
    pub lidar: (String, String),
    /// How sweeps are written (default povins' compact PointCloud2).
    pub lidar_wire: Wire,
}

impl DatasetTopics {
    /// The names an Intel RealSense D435i's ROS driver publishes (`realsense2_camera`, infra1
    /// stream, IMU united on one topic), and `/lidar/points` for a LiDAR.
    pub fn realsense() -> Self {
        let pair = |a: &str, b: &str| (a.to_string(), b.to_string());
        DatasetTopics {
            imu: pair("/camera/imu", "camera_imu_optical_frame"),
            image: pair(
                "/camera/infra1/image_rect_raw",
                "camera_infra1_optical_frame",
            ),
            lidar: pair("/lidar/points", "lidar"),
            lidar_wire: Wire::default(),
        }
    }

    /// The topic images go to: `image`, or `image/compressed` (`image_transport`'s naming)
    /// when they are compressed.
    pub fn image_topic(&self, compressed: bool) -> String {
        if compressed {
            format!("{}/compressed", self.image.0)
        } else {
            self.image.0.clone()
        }
    }
}

/// What [`write_dataset`] wrote: messages per topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DatasetCounts {
    /// IMU messages.
    pub imu: u64,
    /// Image messages.
    pub images: u64,
    /// Point clouds.
    pub sweeps: u64,
}

/// Compresses a gray image for a `sensor_msgs/CompressedImage`: its `format` (`jpeg`, `png`)
/// and `encode`, which gives the payload or the reason it cannot.
pub struct ImageCompressor<'a> {
    /// The message's `format` field.
    pub format: String,
    /// Gray pixels (width, height, row-major mono8) -> the compressed payload.
    #[allow(clippy::type_complexity)]
    pub encode: &'a (dyn Fn(u32, u32, &[u8]) -> Result<Vec<u8>, String> + Sync),
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Imu,
    Image,
    CompressedImage,
    Lidar(Wire),
}

/// ROS 2 `RIHS01` type description hashes (Humble to Jazzy give the same types; computed by
/// Python `rosbags` 0.11.9, `hash_rihs01`).
const RIHS01_IMU: &str = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b";
const RIHS01_IMAGE: &str =
    "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47";
const RIHS01_COMPRESSED_IMAGE: &str =
    "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a";
const RIHS01_POINT_CLOUD2: &str =
    "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5";

impl Kind {
    fn spec(self, topic: &str, encoding: Encoding) -> TopicSpec {
        let (ros1, ros2_type, ros2_schema, rihs): (MsgType, &str, fn() -> String, &str) = match self
        {
            Kind::Imu => (
                ros1::IMU_MSG,
                "sensor_msgs/msg/Imu",
                ros2::imu_schema,
                RIHS01_IMU,
            ),
            Kind::Image => (
                ros1::IMAGE_MSG,
                "sensor_msgs/msg/Image",
                ros2::image_schema,
                RIHS01_IMAGE,
            ),
            Kind::CompressedImage => (
                ros1::COMPRESSED_IMAGE_MSG,
                "sensor_msgs/msg/CompressedImage",
                ros2::compressed_image_schema,
                RIHS01_COMPRESSED_IMAGE,
            ),
            Kind::Lidar(Wire::Cloud(_)) => (
                ros1::POINT_CLOUD2_MSG,
                "sensor_msgs/msg/PointCloud2",
                ros2::point_cloud2_schema,
                RIHS01_POINT_CLOUD2,
            ),
            Kind::Lidar(Wire::LivoxCustom) => (
                ros1::LIVOX_CUSTOM_MSG,
                "livox_ros_driver/msg/CustomMsg",
                livox::custom_msg2_schema,
                livox::RIHS01_CUSTOM_MSG2,
            ),
            Kind::Lidar(Wire::Livox2Custom) => (
                ros1::LIVOX_CUSTOM_MSG2,
                "livox_ros_driver2/msg/CustomMsg",
                livox::custom_msg2_schema,
                livox::RIHS01_CUSTOM_MSG2,
            ),
        };
        match encoding {
            Encoding::Ros1 => TopicSpec {
                topic: topic.into(),
                msg_type: ros1.name.into(),
                encoding,
                definition: ros1.definition.into(),
                type_hash: ros1.md5sum.into(),
            },
            Encoding::Cdr => TopicSpec {
                topic: topic.into(),
                msg_type: ros2_type.into(),
                encoding,
                definition: ros2_schema(),
                type_hash: rihs.into(),
            },
        }
    }
}

/// An encoding failure: byte offset in the message (0 when none applies) and the reason.
type EncError = (usize, String);

fn ros1_err(e: ros1::MsgError) -> EncError {
    (e.offset, e.msg)
}

fn cdr_err(e: crate::cdr::CdrError) -> EncError {
    (e.offset, e.msg)
}

/// The pixels of `im`: in memory, or read from its PNG file.
fn pixels(im: &ImageFrame) -> Result<std::borrow::Cow<'_, [u8]>, IoError> {
    if !im.mono8.is_empty() {
        return Ok(std::borrow::Cow::Borrowed(&im.mono8));
    }
    let Some(p) = &im.path else {
        return Ok(std::borrow::Cow::Borrowed(&im.mono8));
    };
    let (w, h, px) = crate::euroc::read_png_mono8(p)?;
    if (w, h) != (im.width, im.height) {
        return Err(IoError::Invalid {
            path: p.clone(),
            msg: format!(
                "image is {w}x{h}, the dataset says {}x{}",
                im.width, im.height
            ),
        });
    }
    Ok(std::borrow::Cow::Owned(px))
}

fn encode_image(
    im: &ImageFrame,
    px: &[u8],
    seq: u32,
    frame_id: &str,
    encoding: Encoding,
    compress: Option<&ImageCompressor<'_>>,
) -> Result<Vec<u8>, EncError> {
    let n = u64::from(im.width) * u64::from(im.height);
    if px.len() as u64 != n {
        return Err((
            0,
            format!("{} pixels for a {}x{} image", px.len(), im.width, im.height),
        ));
    }
    if let Some(c) = compress {
        let data = (c.encode)(im.width, im.height, px).map_err(|e| (0, e))?;
        return match encoding {
            Encoding::Ros1 => {
                ros1::encode_compressed_image(im.t_ns, seq, frame_id, &c.format, &data)
                    .map_err(ros1_err)
            }
            Encoding::Cdr => ros2msgs::CompressedImage {
                header: Header::new(im.t_ns, frame_id),
                format: c.format.clone(),
                data,
            }
            .encode()
            .map_err(cdr_err),
        };
    }
    match encoding {
        Encoding::Ros1 if !im.mono8.is_empty() => {
            ros1::encode_mono8(im, seq, frame_id).map_err(ros1_err)
        }
        Encoding::Ros1 => {
            let frame = ImageFrame {
                mono8: px.to_vec(),
                path: None,
                ..*im
            };
            ros1::encode_mono8(&frame, seq, frame_id).map_err(ros1_err)
        }
        Encoding::Cdr => ros2msgs::Image {
            header: Header::new(im.t_ns, frame_id),
            height: im.height,
            width: im.width,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: im.width,
            data: px.to_vec(),
        }
        .encode()
        .map_err(cdr_err),
    }
}

fn encode_sweep(
    s: &crate::dataset::LidarScan,
    seq: u32,
    frame: &str,
    wire: Wire,
    encoding: Encoding,
) -> Result<Vec<u8>, EncError> {
    match (wire, encoding) {
        (Wire::Cloud(l), Encoding::Ros1) => {
            ros1::encode_point_cloud2_in(l, s, seq, frame).map_err(ros1_err)
        }
        (Wire::Cloud(l), Encoding::Cdr) => ros2::convert::lidar_to_msg_in(l, s, frame)
            .map_err(|e| (0, e))
            .and_then(|m| m.encode().map_err(cdr_err)),
        (_, _) => {
            let m = livox::CustomMsg::from_scan(s, frame).map_err(|e| (0, e))?;
            match encoding {
                Encoding::Ros1 => ros1::encode_livox_custom_msg(&m, seq).map_err(ros1_err),
                Encoding::Cdr => m.encode_cdr().map_err(cdr_err),
            }
        }
    }
}

/// Writes the IMU samples, the images (in memory or as PNG files; compressed by `compress` when
/// given) and the LiDAR sweeps of `ds` into `w` on `topics` in `encoding` (see the module docs).
/// Errors name `path` (the container), the topic and the message index.
pub fn write_dataset(
    w: &mut dyn ContainerWriter,
    path: &Path,
    ds: &Dataset,
    topics: &DatasetTopics,
    encoding: Encoding,
    compress: Option<&ImageCompressor<'_>>,
) -> Result<DatasetCounts, IoError> {
    let image_kind = if compress.is_some() {
        Kind::CompressedImage
    } else {
        Kind::Image
    };
    let image_topic = topics.image_topic(compress.is_some());
    let ci = w.add_topic(&Kind::Imu.spec(&topics.imu.0, encoding))?;
    let cc = match ds.images.is_empty() {
        true => None,
        false => Some(w.add_topic(&image_kind.spec(&image_topic, encoding))?),
    };
    let wire = topics.lidar_wire;
    if (wire, encoding) == (Wire::LivoxCustom, Encoding::Cdr) && !ds.lidar.is_empty() {
        return Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: "livox_ros_driver/CustomMsg is ROS 1 only (the driver has no ROS 2 version): \
                  write livox2-custom"
                .into(),
        });
    }
    let cl = match ds.lidar.is_empty() {
        true => None,
        false => Some(w.add_topic(&Kind::Lidar(wire).spec(&topics.lidar.0, encoding))?),
    };
    // (time, stream, index): stream 0 IMU, 1 image, 2 sweep.
    let mut order: Vec<(i64, u8, usize)> = Vec::new();
    order.extend(ds.imu.iter().enumerate().map(|(k, s)| (s.t_ns, 0, k)));
    order.extend(ds.images.iter().enumerate().map(|(k, s)| (s.t_ns, 1, k)));
    order.extend(ds.lidar.iter().enumerate().map(|(k, s)| (s.t_ns, 2, k)));
    order.sort_unstable();
    let mut n = DatasetCounts::default();
    for (t_ns, stream, k) in order {
        let seq = k as u32;
        let (id, topic, data) = match (stream, cc, cl) {
            (0, _, _) => {
                let s = &ds.imu[k];
                let frame = &topics.imu.1;
                let data = match encoding {
                    Encoding::Ros1 => ros1::encode_imu(s, seq, frame).map_err(ros1_err),
                    Encoding::Cdr => ros2msgs::Imu::new(
                        Header::new(s.t_ns, frame),
                        [s.gyro_rps.x, s.gyro_rps.y, s.gyro_rps.z],
                        [s.accel_mps2.x, s.accel_mps2.y, s.accel_mps2.z],
                    )
                    .encode()
                    .map_err(cdr_err),
                };
                (ci, &topics.imu.0, data)
            }
            (1, Some(c), _) => {
                let im = &ds.images[k];
                let px = pixels(im)?;
                let data = encode_image(im, &px, seq, &topics.image.1, encoding, compress);
                (c, &image_topic, data)
            }
            (2, _, Some(c)) => {
                let s = &ds.lidar[k];
                let frame = &topics.lidar.1;
                let data = encode_sweep(s, seq, frame, wire, encoding);
                (c, &topics.lidar.0, data)
            }
            _ => continue,
        };
        let data = data.map_err(|(offset, msg)| IoError::Invalid {
            path: path.to_path_buf(),
            msg: format!("{topic} message {k}: byte {offset}: {msg}"),
        })?;
        w.write(id, t_ns, &data)?;
        match stream {
            0 => n.imu += 1,
            1 => n.images += 1,
            _ => n.sweeps += 1,
        }
    }
    Ok(n)
}

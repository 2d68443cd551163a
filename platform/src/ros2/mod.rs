//! The ROS 2 messages povins reads and writes, as plain structs with a CDR codec each, and their
//! `ros2msg` schema texts (the message definition followed by every nested definition after a
//! line of 80 `=` and `MSG: pkg/Type`, as `ros2 bag record` stores them in MCAP).
//!
//! Only the fields povins uses are given meaning; the rest are written with their ROS defaults
//! and checked for well-formedness when read.

pub mod convert;
pub mod msgs;

use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// `std_msgs/Header`: stamp as integer nanoseconds since the epoch plus the frame id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// `stamp.sec * 1e9 + stamp.nanosec`.
    pub t_ns: i64,
    /// `frame_id`.
    pub frame_id: String,
}

impl Header {
    /// A header for frame `frame_id` at `t_ns`.
    pub fn new(t_ns: i64, frame_id: &str) -> Self {
        Header {
            t_ns,
            frame_id: frame_id.into(),
        }
    }

    /// Decodes `builtin_interfaces/Time stamp` + `string frame_id`.
    pub fn decode(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let sec = r.i32()?;
        let at = r.offset();
        let nanosec = r.u32()?;
        if nanosec >= 1_000_000_000 {
            return Err(CdrError {
                offset: at,
                msg: format!("stamp.nanosec {nanosec} is not below 1e9"),
            });
        }
        let frame_id = r.string()?.to_owned();
        Ok(Header {
            t_ns: i64::from(sec) * 1_000_000_000 + i64::from(nanosec),
            frame_id,
        })
    }

    /// Encodes the header; fails when the time does not fit `builtin_interfaces/Time`
    /// (`int32` seconds).
    pub fn encode(&self, w: &mut CdrWriter) -> Result<(), CdrError> {
        let sec = self.t_ns.div_euclid(1_000_000_000);
        let nanosec = self.t_ns.rem_euclid(1_000_000_000) as u32;
        let sec = i32::try_from(sec).map_err(|_| CdrError {
            offset: 4,
            msg: format!("time {} ns does not fit int32 seconds", self.t_ns),
        })?;
        w.i32(sec);
        w.u32(nanosec);
        w.string(&self.frame_id)
    }
}

/// Joins a message definition with its nested definitions in the `ros2msg` schema layout.
pub fn schema_text(main: &str, deps: &[(&str, &str)]) -> String {
    let mut s = String::from(main.trim_end());
    s.push('\n');
    for (name, def) in deps {
        s.push_str(&"=".repeat(80));
        s.push_str("\nMSG: ");
        s.push_str(name);
        s.push('\n');
        s.push_str(def.trim_end());
        s.push('\n');
    }
    s
}

/// Nested definitions used by the messages below.
pub mod defs {
    /// `std_msgs/Header`.
    pub const HEADER: &str = "\
# Standard metadata for higher-level stamped data types.
builtin_interfaces/Time stamp
string frame_id
";
    /// `builtin_interfaces/Time`.
    pub const TIME: &str = "\
int32 sec
uint32 nanosec
";
    /// `geometry_msgs/Quaternion`.
    pub const QUATERNION: &str = "\
float64 x 0
float64 y 0
float64 z 0
float64 w 1
";
    /// `geometry_msgs/Vector3`.
    pub const VECTOR3: &str = "\
float64 x
float64 y
float64 z
";
    /// `geometry_msgs/Point`.
    pub const POINT: &str = VECTOR3;
    /// `geometry_msgs/Point32`.
    pub const POINT32: &str = "\
float32 x
float32 y
float32 z
";
    /// `sensor_msgs/Imu`.
    pub const IMU: &str = "\
std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
";
    /// `sensor_msgs/Image`.
    pub const IMAGE: &str = "\
std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
";
    /// `sensor_msgs/CompressedImage`.
    pub const COMPRESSED_IMAGE: &str = "\
std_msgs/Header header
string format
uint8[] data
";
    /// `sensor_msgs/PointCloud2`.
    pub const POINT_CLOUD2: &str = "\
std_msgs/Header header
uint32 height
uint32 width
PointField[] fields
bool    is_bigendian
uint32  point_step
uint32  row_step
uint8[] data
bool is_dense
";
    /// `sensor_msgs/PointField`.
    pub const POINT_FIELD: &str = "\
uint8 INT8    = 1
uint8 UINT8   = 2
uint8 INT16   = 3
uint8 UINT16  = 4
uint8 INT32   = 5
uint8 UINT32  = 6
uint8 FLOAT32 = 7
uint8 FLOAT64 = 8
string name
uint32 offset
uint8  datatype
uint32 count
";
    /// `sensor_msgs/PointCloud`.
    pub const POINT_CLOUD: &str = "\
std_msgs/Header header
geometry_msgs/Point32[] points
ChannelFloat32[] channels
";
    /// `sensor_msgs/ChannelFloat32`.
    pub const CHANNEL_FLOAT32: &str = "\
string name
float32[] values
";
    /// `nav_msgs/Odometry`.
    pub const ODOMETRY: &str = "\
std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
";
    /// `geometry_msgs/PoseWithCovariance`.
    pub const POSE_WITH_COVARIANCE: &str = "\
Pose pose
float64[36] covariance
";
    /// `geometry_msgs/Pose`.
    pub const POSE: &str = "\
Point position
Quaternion orientation
";
    /// `geometry_msgs/TwistWithCovariance`.
    pub const TWIST_WITH_COVARIANCE: &str = "\
Twist twist
float64[36] covariance
";
    /// `geometry_msgs/Twist`.
    pub const TWIST: &str = "\
Vector3  linear
Vector3  angular
";
}

/// `ros2msg` schema of `sensor_msgs/msg/Imu`.
pub fn imu_schema() -> String {
    schema_text(
        defs::IMU,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
            ("geometry_msgs/Quaternion", defs::QUATERNION),
            ("geometry_msgs/Vector3", defs::VECTOR3),
        ],
    )
}

/// `ros2msg` schema of `sensor_msgs/msg/Image`.
pub fn image_schema() -> String {
    schema_text(
        defs::IMAGE,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
        ],
    )
}

/// `ros2msg` schema of `sensor_msgs/msg/CompressedImage`.
pub fn compressed_image_schema() -> String {
    schema_text(
        defs::COMPRESSED_IMAGE,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
        ],
    )
}

/// `ros2msg` schema of `sensor_msgs/msg/PointCloud2`.
pub fn point_cloud2_schema() -> String {
    schema_text(
        defs::POINT_CLOUD2,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
            ("sensor_msgs/PointField", defs::POINT_FIELD),
        ],
    )
}

/// `ros2msg` schema of `sensor_msgs/msg/PointCloud`.
pub fn point_cloud_schema() -> String {
    schema_text(
        defs::POINT_CLOUD,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
            ("geometry_msgs/Point32", defs::POINT32),
            ("sensor_msgs/ChannelFloat32", defs::CHANNEL_FLOAT32),
        ],
    )
}

/// `ros2msg` schema of `nav_msgs/msg/Odometry`.
pub fn odometry_schema() -> String {
    schema_text(
        defs::ODOMETRY,
        &[
            ("std_msgs/Header", defs::HEADER),
            ("builtin_interfaces/Time", defs::TIME),
            (
                "geometry_msgs/PoseWithCovariance",
                defs::POSE_WITH_COVARIANCE,
            ),
            ("geometry_msgs/Pose", defs::POSE),
            ("geometry_msgs/Point", defs::POINT),
            ("geometry_msgs/Quaternion", defs::QUATERNION),
            (
                "geometry_msgs/TwistWithCovariance",
                defs::TWIST_WITH_COVARIANCE,
            ),
            ("geometry_msgs/Twist", defs::TWIST),
            ("geometry_msgs/Vector3", defs::VECTOR3),
        ],
    )
}

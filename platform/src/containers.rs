//! Which container a path is, and opening it as a [`MessageLog`]: the one place that knows
//! the containers (kept out of [`crate::rosrec`], which the containers build on).

use crate::error::IoError;
use crate::rosrec::MessageLog;
use std::path::Path;

/// Opens the message log at `path` by its kind: a `.bag` file is a ROS 1 bag, a folder holding
/// `metadata.yaml` a ROS 2 bag, a `.db3` file a ROS 2 sqlite3 bag, an `.mcap` file any MCAP file.
pub fn open_log(path: &Path) -> Result<Box<dyn MessageLog>, IoError> {
    match LogKind::of(path) {
        Some(LogKind::Ros1Bag) => Ok(Box::new(crate::rosbag1::Bag::open(path)?)),
        Some(LogKind::Ros2Bag) => Ok(Box::new(crate::rosbag2::Rosbag2::open(path)?)),
        Some(LogKind::Mcap) => Ok(Box::new(crate::mcap_log::McapLog::open(path)?)),
        None => Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: "not a ROS recording povins reads (a ROS 1 .bag, a ROS 2 bag folder with \
                  metadata.yaml, a .db3 file or an .mcap file)"
                .into(),
        }),
    }
}

/// Whether `path` is a ROS recording to open with [`open_log`] (and a calibration given
/// apart): a ROS 1 bag, a ROS 2 bag, or an MCAP file that is not povins' own (an MCAP carrying
/// the [`crate::mcap_io::CALIBRATION_METADATA`] record opens with [`crate::open_recording`]).
pub fn is_ros_recording(path: &Path) -> bool {
    match LogKind::of(path) {
        Some(LogKind::Mcap) => {
            !crate::mcap_log::has_metadata(path, crate::mcap_io::CALIBRATION_METADATA)
        }
        Some(_) => true,
        None => false,
    }
}

/// The containers [`open_log`] reads.
enum LogKind {
    Ros1Bag,
    Ros2Bag,
    Mcap,
}

impl LogKind {
    fn of(path: &Path) -> Option<Self> {
        let ext = |e: &str| path.extension().is_some_and(|x| x == e) && !path.is_dir();
        if ext("bag") {
            Some(LogKind::Ros1Bag)
        } else if ext("db3") || crate::rosbag2::is_bag_folder(path) {
            Some(LogKind::Ros2Bag)
        } else if ext("mcap") {
            Some(LogKind::Mcap)
        } else {
            None
        }
    }
}

//! # povins-platform
//!
//! The std side of povins for Linux (x86-64 and aarch64): dataset readers and writers (EuRoC ASL
//! folders, MCAP with ROS 2 CDR messages, TUM trajectories), the in-memory [`dataset::Dataset`]
//! they all produce, and the runtime around the `no_std` core: [`pipeline`], the IMU and
//! back-end threads (SPSC queues, pinned cores, `SCHED_FIFO`, latency histograms) fed by a
//! [`pipeline::Source`] and publishing to a [`pipeline::Sink`].

pub mod boxed;
pub mod cdr;
pub mod cloud;
pub mod containers;
pub mod dataset;
pub mod driver;
pub mod error;
pub mod euroc;
pub mod image_codec;
pub mod image_raw;
pub mod images;
pub mod kalibr;
pub mod mcap_io;
pub mod mcap_log;
pub mod mcap_record;
pub mod odometry;
pub mod ouster;
pub mod pipeline;
pub mod recording;
pub mod ros2;
pub mod rosbag1;
pub mod rosbag2;
pub mod rosrec;
pub mod source;
pub mod trajectory;

pub use dataset::Dataset;
pub use error::IoError;

use recording::Recording;
use std::path::Path;

/// Opens a recording by path: a folder is an EuRoC ASL folder, an `.mcap` file written by povins
/// an MCAP file ([`mcap_io`]); a ROS recording ([`containers::is_ros_recording`]) is refused with a
/// hint, as it needs a calibration given apart.
pub fn open_recording(path: &Path) -> Result<Box<dyn Recording>, IoError> {
    if containers::is_ros_recording(path) {
        Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: "a ROS recording (ROS 1 or ROS 2 bag, MCAP file) carries no calibration \
                  povins reads yet: open it with rosrec::recording::RosRecording (povins run \
                  RECORDING --calib EUROC_FOLDER)"
                .into(),
        })
    } else if path.is_dir() {
        Ok(Box::new(crate::euroc::EurocFolder::open(path)?))
    } else if path.extension().is_some_and(|e| e == "mcap") {
        Ok(Box::new(crate::mcap_io::McapRecording::open(path)?))
    } else if !path.exists() {
        Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: "does not exist".into(),
        })
    } else {
        Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: "expected an EuRoC folder (containing mav0/) or an .mcap file".into(),
        })
    }
}

/// Reads a whole recording into memory ([`Dataset`]): for the tools that need every message at
/// once (a run streams it instead, [`open_recording`]).
pub fn read_dataset(path: &Path) -> Result<Dataset, IoError> {
    if path.is_dir() {
        euroc::read_dataset(path)
    } else {
        mcap_io::read_dataset(path)
    }
}

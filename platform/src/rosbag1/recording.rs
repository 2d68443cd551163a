//! A ROS 1 bag as a [`Recording`]: the IMU and camera topics chosen by [`super::topics`], their
//! messages pulled in the bag's receipt-time order and decoded one at a time as the streams are
//! pulled (images to gray then, not before). The calibration is not read from the bag (next
//! piece: Kalibr files, CameraInfo, `/tf_static`): the caller gives it, e.g. from an EuRoC
//! folder's `sensor.yaml` files.
//!
//! Samples carry their `header.stamp`. The streams are in the bag's receipt order; a stamp out
//! of order within a topic is passed on as it is (the driver's checks apply).

use super::topics::{select, TopicInfo};
use super::{msgs, Bag};
use crate::dataset::{Calibration, FeatureFrame, ImageFrame, LidarScan};
use crate::error::IoError;
use crate::recording::{Contents, Recording, Stream};
use povins_core::inertial::{ImuSample, NavState};
use std::path::Path;

/// An opened bag with its chosen topics and a calibration (see the module docs).
#[derive(Debug, Clone)]
pub struct BagRecording {
    name: String,
    bag: Bag,
    calib: Calibration,
    imu: TopicInfo,
    camera: Option<TopicInfo>,
}

impl BagRecording {
    /// Opens `path`, chooses its topics (`imu_topic`, `image_topic` name them; otherwise by
    /// type) and takes `calib` as its calibration. A bag without an IMU topic is an error.
    pub fn open(
        path: &Path,
        calib: Calibration,
        imu_topic: Option<&str>,
        image_topic: Option<&str>,
    ) -> Result<Self, IoError> {
        let bag = Bag::open(path)?;
        let invalid = |msg: String| IoError::Invalid {
            path: path.to_path_buf(),
            msg,
        };
        let sel = select(&bag, imu_topic, image_topic).map_err(invalid)?;
        let imu = sel.imu.ok_or_else(|| {
            let mut all: Vec<String> = super::topics::topics(&bag)
                .iter()
                .map(|t| format!("{} ({})", t.topic, t.msg_type))
                .collect();
            if all.is_empty() {
                all.push("none".into());
            }
            invalid(format!(
                "no sensor_msgs/Imu topic with messages; topics: {}",
                all.join(", ")
            ))
        })?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        Ok(BagRecording {
            name,
            bag,
            calib,
            imu,
            camera: sel.camera,
        })
    }

    /// The bag.
    pub fn bag(&self) -> &Bag {
        &self.bag
    }

    /// A decoding error naming the file, the topic and the message index.
    fn bad(&self, topic: &TopicInfo, k: usize, e: msgs::MsgError) -> IoError {
        IoError::Corrupt {
            file: self.bag.path.clone(),
            what: format!("{} message {k} ({})", topic.topic, topic.msg_type),
            offset: e.offset as u64,
            msg: e.msg,
        }
    }
}

impl Recording for BagRecording {
    fn name(&self) -> &str {
        &self.name
    }

    fn calibration(&self) -> &Calibration {
        &self.calib
    }

    fn contents(&self) -> Contents {
        Contents {
            imu: true,
            frames: false,
            images: self.camera.is_some(),
            lidar: false,
            ground_truth: false,
            imu_span_ns: None,
            image_count: self.camera.as_ref().map(|c| c.count as usize),
        }
    }

    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError> {
        let t = &self.imu;
        let msgs = self.bag.messages(self.bag.topic_conns(&t.topic));
        Ok(Box::new(msgs.enumerate().map(move |(k, m)| {
            msgs::imu(&m?.data).map_err(|e| self.bad(t, k, e))
        })))
    }

    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError> {
        Ok(Box::new(std::iter::empty()))
    }

    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError> {
        let Some(t) = &self.camera else {
            return Ok(Box::new(std::iter::empty()));
        };
        let msgs = self.bag.messages(self.bag.topic_conns(&t.topic));
        Ok(Box::new(msgs.enumerate().map(move |(k, m)| {
            msgs::any_image(&t.msg_type, &m?.data).map_err(|e| self.bad(t, k, e))
        })))
    }

    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError> {
        Ok(Box::new(std::iter::empty()))
    }

    fn ground_truth(&self) -> Result<Vec<NavState>, IoError> {
        Ok(Vec::new())
    }
}

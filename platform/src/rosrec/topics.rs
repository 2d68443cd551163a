//! Which topics of a recording a run uses: one IMU (`sensor_msgs/Imu`) and one camera
//! (`sensor_msgs/Image` or `sensor_msgs/CompressedImage`), chosen by message type among the
//! topics that have messages, or named by the user. Two candidates of a kind is an error listing
//! them; every other topic is skipped.
//!
//! A RealSense publishes its gyro and its accelerometer as two `sensor_msgs/Imu` topics at
//! different rates (`/camera/gyro/sample`, `/camera/accel/sample`), each with only its own half
//! filled in. When the user names an accelerometer topic (`accel`), or when the IMU candidates
//! are exactly two and one name contains `gyro` and the other `accel`, the gyro topic is the IMU
//! and the accelerometer topic is merged into it ([`super::merge`]).
//!
//! The LiDAR topic (`sensor_msgs/PointCloud2`, Livox `CustomMsg`) is chosen the same way, except
//! that several candidates are not an error: none is used, and [`Selection::lidar_note`] says
//! why (a bag often holds a driver's cloud beside filtered ones).

use super::decode::{COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, IMU_TYPE, LIDAR_TYPES};
use super::TopicInfo;

/// The topics a run reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Selection {
    /// The IMU topic.
    pub imu: Option<TopicInfo>,
    /// The camera topic.
    pub camera: Option<TopicInfo>,
    /// The accelerometer topic merged into the IMU topic's samples, when the IMU's
    /// accelerometer is published apart.
    pub accel: Option<TopicInfo>,
    /// The LiDAR topic.
    pub lidar: Option<TopicInfo>,
    /// Why no LiDAR topic was chosen among several.
    pub lidar_note: Option<String>,
}

/// Chooses the IMU and camera topics: `want_*` names one, otherwise the single topic of the
/// kind that has messages. Errors list the candidates.
pub fn select(
    all: &[TopicInfo],
    want_imu: Option<&str>,
    want_camera: Option<&str>,
) -> Result<Selection, String> {
    select_with(
        all,
        &TopicChoice {
            imu: want_imu.map(Into::into),
            image: want_camera.map(Into::into),
            ..TopicChoice::default()
        },
    )
}

/// What the user chose (every field optional: the default chooses by type).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopicChoice {
    /// The IMU topic (the gyro's when the accelerometer is apart).
    pub imu: Option<String>,
    /// The camera topic.
    pub image: Option<String>,
    /// The accelerometer topic to merge into the IMU's samples.
    pub accel: Option<String>,
    /// The accelerometer's unit.
    pub accel_unit: super::merge::AccelUnit,
    /// The LiDAR topic.
    pub lidar: Option<String>,
    /// How its clouds are read.
    pub cloud: crate::cloud::CloudOptions,
}

/// [`select`] with every choice, the accelerometer topic among them.
pub fn select_with(all: &[TopicInfo], choice: &TopicChoice) -> Result<Selection, String> {
    let want_imu = choice.imu.as_deref();
    let want_camera = choice.image.as_deref();
    let want_accel = choice.accel.as_deref();
    let (imu, accel) = match (want_imu, want_accel) {
        (None, None) => match gyro_accel_pair(all) {
            Some((g, a)) => (Some(g), Some(a)),
            None => (pick(all, "IMU", &[IMU_TYPE], None)?, None),
        },
        (imu, None) => (pick(all, "IMU", &[IMU_TYPE], imu)?, None),
        (imu, Some(accel)) => {
            let accel = pick(all, "accelerometer", &[IMU_TYPE], Some(accel))?;
            let rest: Vec<TopicInfo> = all
                .iter()
                .filter(|t| Some(&t.topic) != accel.as_ref().map(|a| &a.topic))
                .cloned()
                .collect();
            (pick(&rest, "IMU (gyro)", &[IMU_TYPE], imu)?, accel)
        }
    };
    let camera = pick(
        all,
        "camera",
        &[IMAGE_TYPE, COMPRESSED_IMAGE_TYPE],
        want_camera,
    )?;
    let (lidar, lidar_note) = match pick(all, "LiDAR", &LIDAR_TYPES, choice.lidar.as_deref()) {
        Ok(t) => (t, None),
        Err(e) if choice.lidar.is_none() => (
            None,
            Some(format!(
                "{e}; no LiDAR is read (name one with --lidar-topic)"
            )),
        ),
        Err(e) => return Err(e),
    };
    Ok(Selection {
        imu,
        camera,
        accel,
        lidar,
        lidar_note,
    })
}

/// The RealSense pair among the IMU candidates: exactly two, one named `gyro` and one `accel`.
fn gyro_accel_pair(all: &[TopicInfo]) -> Option<(TopicInfo, TopicInfo)> {
    let imus: Vec<&TopicInfo> = all
        .iter()
        .filter(|t| t.count > 0 && t.msg_type == IMU_TYPE)
        .collect();
    let [a, b] = imus.as_slice() else {
        return None;
    };
    let named = |t: &TopicInfo, w: &str| t.topic.to_ascii_lowercase().contains(w);
    match (
        named(a, "gyro"),
        named(a, "accel"),
        named(b, "gyro"),
        named(b, "accel"),
    ) {
        (true, false, false, true) => Some(((*a).clone(), (*b).clone())),
        (false, true, true, false) => Some(((*b).clone(), (*a).clone())),
        _ => None,
    }
}

fn pick(
    all: &[TopicInfo],
    kind: &str,
    types: &[&str],
    want: Option<&str>,
) -> Result<Option<TopicInfo>, String> {
    let list = |v: &[&TopicInfo]| {
        v.iter()
            .map(|t| format!("{} ({}, {} messages)", t.topic, t.msg_type, t.count))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if let Some(name) = want {
        let t = all
            .iter()
            .find(|t| t.topic == name)
            .ok_or_else(|| format!("{kind} topic {name:?} is not in the recording"))?;
        if !types.contains(&t.msg_type.as_str()) {
            return Err(format!(
                "{kind} topic {name:?} has type {}, expected {}",
                t.msg_type,
                types.join(" or ")
            ));
        }
        return Ok(Some(t.clone()));
    }
    let cands: Vec<&TopicInfo> = all
        .iter()
        .filter(|t| t.count > 0 && types.contains(&t.msg_type.as_str()))
        .collect();
    match cands.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some((*one).clone())),
        many => Err(format!(
            "{} {kind} topics, choose one: {}",
            many.len(),
            list(many)
        )),
    }
}

//! Which topics of a recording a run uses: one IMU (`sensor_msgs/Imu`) and one camera
//! (`sensor_msgs/Image` or `sensor_msgs/CompressedImage`), chosen by message type among the
//! topics that have messages, or named by the user. Two candidates of a kind is an error listing
//! them; every other topic is skipped.

use super::decode::{COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, IMU_TYPE};
use super::TopicInfo;

/// The topics a run reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Selection {
    /// The IMU topic.
    pub imu: Option<TopicInfo>,
    /// The camera topic.
    pub camera: Option<TopicInfo>,
}

/// Chooses the IMU and camera topics: `want_*` names one, otherwise the single topic of the
/// kind that has messages. Errors list the candidates.
pub fn select(
    all: &[TopicInfo],
    want_imu: Option<&str>,
    want_camera: Option<&str>,
) -> Result<Selection, String> {
    let imu = pick(all, "IMU", &[IMU_TYPE], want_imu)?;
    let camera = pick(
        all,
        "camera",
        &[IMAGE_TYPE, COMPRESSED_IMAGE_TYPE],
        want_camera,
    )?;
    Ok(Selection { imu, camera })
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

//! Which topics of a bag a run uses: one IMU (`sensor_msgs/Imu`) and one camera
//! (`sensor_msgs/Image` or `sensor_msgs/CompressedImage`), chosen by message type among the
//! topics that have messages, or named by the user. Two candidates of a kind is an error listing
//! them; every other topic is skipped.

use super::msgs::{COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, IMU_TYPE};
use super::Bag;

/// One topic of a bag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// Topic name.
    pub topic: String,
    /// Message type.
    pub msg_type: String,
    /// Messages (all its connections).
    pub count: u64,
}

/// The bag's topics, by name (a topic published with two types appears twice).
pub fn topics(bag: &Bag) -> Vec<TopicInfo> {
    let mut out: Vec<TopicInfo> = Vec::new();
    for c in bag.connections.values() {
        let n = bag.count(c.id);
        match out
            .iter_mut()
            .find(|t| t.topic == c.topic && t.msg_type == c.msg_type)
        {
            Some(t) => t.count += n,
            None => out.push(TopicInfo {
                topic: c.topic.clone(),
                msg_type: c.msg_type.clone(),
                count: n,
            }),
        }
    }
    out.sort_by(|a, b| (&a.topic, &a.msg_type).cmp(&(&b.topic, &b.msg_type)));
    out
}

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
    bag: &Bag,
    want_imu: Option<&str>,
    want_camera: Option<&str>,
) -> Result<Selection, String> {
    let all = topics(bag);
    let imu = pick(&all, "IMU", &[IMU_TYPE], want_imu)?;
    let camera = pick(
        &all,
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
            .ok_or_else(|| format!("{kind} topic {name:?} is not in the bag"))?;
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

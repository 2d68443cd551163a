//! [`McapSink`]: the pipeline's outputs as an MCAP file for Foxglove: every IMU-rate pose on
//! [`TOPIC_POSE`] and every keyframe's optimized state on [`TOPIC_KEYFRAME`], both as
//! `foxglove.PoseInFrame` messages (JSON schema encoding, JSON messages: Foxglove's 3D panel
//! shows them as poses, its plot panel their fields).
//!
//! Like [`super::TumSink`], the sink only copies each output into memory reserved up front (no
//! disk, no lock, no allocation on the IMU thread while the reservation lasts); the file is
//! written at [`Sink::finish`].

use super::sink::{KeyframeOut, PoseOut, Sink};
use crate::error::IoError;
use crate::trajectory::StampedPose;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Topic of the IMU-rate poses.
pub const TOPIC_POSE: &str = "/povins/pose";
/// Topic of the keyframes' optimized states (one per keyframe step).
pub const TOPIC_KEYFRAME: &str = "/povins/keyframe";
/// Schema name Foxglove recognizes.
pub const POSE_IN_FRAME: &str = "foxglove.PoseInFrame";
/// The frame the poses are given in (the estimator's world frame, z up).
pub const WORLD_FRAME: &str = "world";

/// Collects poses and keyframe states; writes them as MCAP at [`Sink::finish`].
#[derive(Debug)]
pub struct McapSink {
    path: PathBuf,
    poses: Vec<StampedPose>,
    keyframes: Vec<StampedPose>,
}

impl McapSink {
    /// A sink writing `path`, with room for `capacity` poses reserved up front (the number of
    /// IMU samples) and for one keyframe per 10 of them.
    pub fn new(path: impl Into<PathBuf>, capacity: usize) -> Self {
        McapSink {
            path: path.into(),
            poses: Vec::with_capacity(capacity),
            keyframes: Vec::with_capacity(capacity / 10 + 16),
        }
    }

    /// The poses collected so far.
    pub fn poses(&self) -> &[StampedPose] {
        &self.poses
    }

    /// The keyframe states collected so far.
    pub fn keyframes(&self) -> &[StampedPose] {
        &self.keyframes
    }
}

impl Sink for McapSink {
    fn pose(&mut self, p: &PoseOut) {
        self.poses.push(StampedPose::from(&p.nav));
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        if let Some(s) = &k.state {
            self.keyframes.push(StampedPose::from(s));
        }
    }

    fn finish(&mut self) -> Result<(), IoError> {
        write_poses_mcap(&self.path, &self.poses, &self.keyframes)
    }
}

/// The JSON schema of `foxglove.PoseInFrame` (the fields this sink writes; Foxglove's own
/// schema adds optional lineage fields).
pub fn pose_in_frame_schema() -> serde_json::Value {
    let number = serde_json::json!({ "type": "number" });
    let object = |title: &str, keys: &[&str]| {
        let props: serde_json::Map<String, serde_json::Value> = keys
            .iter()
            .map(|k| ((*k).to_string(), number.clone()))
            .collect();
        serde_json::json!({
            "title": title,
            "type": "object",
            "properties": props,
            "required": keys,
        })
    };
    serde_json::json!({
        "title": POSE_IN_FRAME,
        "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "title": "time",
                "properties": {
                    "sec": { "type": "integer", "minimum": 0 },
                    "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
                }
            },
            "frame_id": { "type": "string" },
            "pose": {
                "title": "foxglove.Pose",
                "type": "object",
                "properties": {
                    "position": object("foxglove.Vector3", &["x", "y", "z"]),
                    "orientation": object("foxglove.Quaternion", &["x", "y", "z", "w"]),
                },
                "required": ["position", "orientation"]
            }
        },
        "required": ["timestamp", "frame_id", "pose"]
    })
}

/// One `foxglove.PoseInFrame` message (JSON), or `None` for a time before 1970.
pub fn pose_in_frame_json(p: &StampedPose) -> Option<serde_json::Value> {
    let t = u64::try_from(p.t_ns).ok()?;
    let q = p.q_wb.quaternion();
    Some(serde_json::json!({
        "timestamp": { "sec": t / 1_000_000_000, "nsec": t % 1_000_000_000 },
        "frame_id": WORLD_FRAME,
        "pose": {
            "position": { "x": p.p_wb.x, "y": p.p_wb.y, "z": p.p_wb.z },
            "orientation": { "x": q.i, "y": q.j, "z": q.k, "w": q.w }
        }
    }))
}

/// Writes `poses` on [`TOPIC_POSE`] and `keyframes` on [`TOPIC_KEYFRAME`] as
/// `foxglove.PoseInFrame` JSON messages (log and publish time: the pose's stamp).
pub fn write_poses_mcap(
    path: &Path,
    poses: &[StampedPose],
    keyframes: &[StampedPose],
) -> Result<(), IoError> {
    let me = |e: mcap::McapError| IoError::Corrupt {
        file: path.into(),
        what: "mcap".into(),
        offset: 0,
        msg: e.to_string(),
    };
    let f = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut w = mcap::WriteOptions::new()
        .create(std::io::BufWriter::with_capacity(1 << 20, f))
        .map_err(me)?;
    let schema = serde_json::to_vec(&pose_in_frame_schema()).map_err(|e| IoError::Invalid {
        path: path.into(),
        msg: e.to_string(),
    })?;
    let sid = w
        .add_schema(POSE_IN_FRAME, "jsonschema", &schema)
        .map_err(me)?;
    let no_meta = BTreeMap::new();
    for (topic, list) in [(TOPIC_POSE, poses), (TOPIC_KEYFRAME, keyframes)] {
        let cid = w.add_channel(sid, topic, "json", &no_meta).map_err(me)?;
        let mut buf = Vec::with_capacity(256);
        for (k, p) in list.iter().enumerate() {
            let (Ok(t), Some(msg)) = (u64::try_from(p.t_ns), pose_in_frame_json(p)) else {
                return Err(IoError::Invalid {
                    path: path.into(),
                    msg: format!(
                        "{topic}: time {} ns is before 1970 and cannot be an MCAP log time",
                        p.t_ns
                    ),
                });
            };
            buf.clear();
            serde_json::to_writer(&mut buf, &msg).map_err(|e| IoError::Invalid {
                path: path.into(),
                msg: e.to_string(),
            })?;
            let header = mcap::records::MessageHeader {
                channel_id: cid,
                sequence: u32::try_from(k + 1).unwrap_or(u32::MAX),
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&header, &buf).map_err(me)?;
        }
    }
    w.finish().map_err(me)?;
    w.into_inner()
        .into_inner()
        .map_err(|e| IoError::io(path, e.into_error()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::inertial::NavState;
    use povins_core::math::{Quat, Vec3};

    fn nav(k: i64) -> NavState {
        NavState {
            t_ns: 1_403_715_273_262_142_976 + k * 5_000_000,
            p_wb: Vec3::new(k as f64 * 0.1, 2.0, -0.5),
            q_wb: Quat::from_euler_angles(0.1, 0.2, 0.3 + k as f64 * 0.01),
            ..NavState::ZERO
        }
    }

    #[test]
    fn mcap_sink_writes_pose_in_frame_messages() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("poses.mcap");
        let mut sink = McapSink::new(&path, 8);
        for k in 0..5 {
            sink.pose(&PoseOut {
                nav: nav(k),
                latency_ns: 10,
                stamp_latency_ns: None,
            });
        }
        sink.keyframe(&KeyframeOut {
            report: Default::default(),
            state: Some(nav(2)),
        });
        sink.keyframe(&KeyframeOut {
            report: Default::default(),
            state: None,
        });
        assert!(!path.exists(), "written before finish");
        sink.finish().expect("written");
        let bytes = std::fs::read(&path).expect("the file");
        let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
            .expect("an MCAP file")
            .map(|m| m.expect("a message"))
            .collect();
        let on = |t: &str| msgs.iter().filter(|m| m.channel.topic == t).count();
        assert_eq!((on(TOPIC_POSE), on(TOPIC_KEYFRAME)), (5, 1));
        let first = &msgs[0];
        assert_eq!(first.log_time, nav(0).t_ns as u64);
        let v: serde_json::Value = serde_json::from_slice(&first.data).expect("JSON");
        let q = nav(0).q_wb;
        assert_eq!(v["pose"]["orientation"]["w"].as_f64(), Some(q.w));
        assert_eq!(v["pose"]["position"]["y"].as_f64(), Some(2.0));
        assert_eq!(v["timestamp"]["sec"].as_u64(), Some(1_403_715_273));
        assert_eq!(v["timestamp"]["nsec"].as_u64(), Some(262_142_976));
        let schema = first.channel.schema.as_ref().expect("a schema");
        assert_eq!(schema.name, POSE_IN_FRAME);
        let s: serde_json::Value = serde_json::from_slice(&schema.data).expect("JSON schema");
        assert_eq!(s["title"], POSE_IN_FRAME);
    }
}

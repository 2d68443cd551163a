//! [`McapSink`]: the pipeline's outputs as an MCAP file for Foxglove, written while the run goes
//! on: every IMU-rate pose on [`TOPIC_POSE`] and every keyframe's optimized state on
//! [`TOPIC_KEYFRAME`], both as `foxglove.PoseInFrame` messages (JSON schema encoding, JSON
//! messages: Foxglove's 3D panel shows them as poses, its plot panel their fields).
//!
//! ## Streaming
//! The sink's calls run on the pipeline's IMU thread: they copy the pose into a lock-free queue
//! ([`McapOptions::queue`] entries, allocated when the sink is made) and return; a writer thread
//! ([`super::file_sink`]) serializes and writes. The writer closes the open chunk (zstd, at most
//! [`McapOptions::chunk_bytes`] before compression) and flushes the file to the operating system
//! at least every [`McapOptions::flush_period`] (1 s), so a process that is killed (`SIGKILL`,
//! a crash, a power cut after the OS wrote its cache) leaves a file whose records up to the last
//! flush are complete and readable by a streaming MCAP reader (no summary or footer: readers
//! that need the index report it missing; `mcap recover` rebuilds it). A run that ends normally
//! ([`Sink::finish`]) writes the summary and footer. The file is created when the sink is made,
//! so a path that cannot be written fails before the run starts.
//!
//! A full queue (the disk slower than the IMU for longer than the queue lasts) drops the pose and
//! counts it ([`FileCounts::dropped_queue`]); a write error ends the writing, is counted, and is
//! returned by [`Sink::finish`] naming the file.

use super::file_sink::{FileCounts, FileOptions, FileSink, StampedWriter};
use super::sink::{KeyframeOut, PoseOut, Sink, Stamped};
use crate::error::IoError;
use crate::trajectory::StampedPose;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Topic of the IMU-rate poses.
pub const TOPIC_POSE: &str = "/povins/pose";
/// Topic of the keyframes' optimized states (one per keyframe step).
pub const TOPIC_KEYFRAME: &str = "/povins/keyframe";
/// Schema name Foxglove recognizes.
pub const POSE_IN_FRAME: &str = "foxglove.PoseInFrame";
/// The frame the poses are given in (the estimator's world frame, z up).
pub const WORLD_FRAME: &str = "world";

/// How [`McapSink`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct McapOptions {
    /// Longest time between two flushes of the file (each closes the open chunk).
    pub flush_period: Duration,
    /// Largest chunk before compression, bytes (a chunk is also closed at every flush).
    pub chunk_bytes: u64,
    /// Poses and keyframes the queue to the writer thread holds.
    pub queue: usize,
}

impl Default for McapOptions {
    /// Flushed every second, chunks of at most 1 MiB, a queue of 65,536 outputs.
    fn default() -> Self {
        let f = FileOptions::default();
        McapOptions {
            flush_period: f.flush_period,
            chunk_bytes: 1 << 20,
            queue: f.queue,
        }
    }
}

/// What the MCAP output did.
pub type McapCounts = FileCounts;

/// A [`Sink`] writing the poses and keyframe states to an MCAP file as the run goes (see the
/// module doc).
#[derive(Debug)]
pub struct McapSink {
    file: FileSink,
}

impl McapSink {
    /// Creates `path` (header, schema and channels on the disk before the first pose) and starts
    /// the writer thread.
    pub fn create(path: impl Into<PathBuf>, opts: McapOptions) -> Result<Self, IoError> {
        let path = path.into();
        if opts.chunk_bytes == 0 {
            return Err(IoError::Invalid {
                path,
                msg: format!("MCAP output options {opts:?}: the chunk size must be above 0"),
            });
        }
        let fo = FileOptions {
            flush_period: opts.flush_period,
            queue: opts.queue,
        };
        if fo.flush_period.is_zero() || fo.queue == 0 {
            return Err(IoError::Invalid {
                path,
                msg: format!(
                    "MCAP output options {opts:?}: the flush period and the queue must be above 0"
                ),
            });
        }
        let mut file = PoseMcapWriter::create(&path, opts.chunk_bytes)?;
        PoseMcapWriter::flush(&mut file)?;
        Ok(McapSink {
            file: FileSink::spawn("mcap-writer", &path, Box::new(file), fo)?,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        self.file.path()
    }

    /// The counts so far (complete after [`Sink::finish`]).
    pub fn counts(&self) -> McapCounts {
        self.file.counts()
    }
}

impl Sink for McapSink {
    fn pose(&mut self, p: &PoseOut) {
        self.file.push(Stamped::Pose(StampedPose::from(&p.nav)));
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        if let Some(s) = &k.state {
            self.file.push(Stamped::Keyframe(StampedPose::from(s)));
        }
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.file.stop()
    }
}

impl StampedWriter for PoseMcapWriter {
    fn write(&mut self, item: &Stamped) -> Result<(), IoError> {
        match item {
            Stamped::Pose(p) => PoseMcapWriter::write(self, Topic::Pose, p),
            Stamped::Keyframe(p) => PoseMcapWriter::write(self, Topic::Keyframe, p),
        }
    }

    fn flush(&mut self) -> Result<(), IoError> {
        PoseMcapWriter::flush(self)
    }

    fn finish(self: Box<Self>) -> Result<(), IoError> {
        PoseMcapWriter::finish(*self)
    }
}

/// The two channels of a pose file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// [`TOPIC_POSE`].
    Pose,
    /// [`TOPIC_KEYFRAME`].
    Keyframe,
}

/// An MCAP file of `foxglove.PoseInFrame` JSON messages on [`TOPIC_POSE`] and
/// [`TOPIC_KEYFRAME`] (log and publish time: the pose's stamp), written message by message.
pub struct PoseMcapWriter {
    path: PathBuf,
    w: mcap::Writer<mcap::write::NoSeek<BufWriter<File>>>,
    channels: [u16; 2],
    sequence: [u32; 2],
    buf: Vec<u8>,
}

impl std::fmt::Debug for PoseMcapWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoseMcapWriter")
            .field("path", &self.path)
            .field("sequence", &self.sequence)
            .finish_non_exhaustive()
    }
}

impl PoseMcapWriter {
    /// Creates `path` with its header, schema and channels; zstd chunks of at most
    /// `chunk_bytes` before compression, compressed on the calling thread.
    pub fn create(path: &Path, chunk_bytes: u64) -> Result<Self, IoError> {
        let f = File::create(path).map_err(|e| IoError::io(path, e))?;
        let me = mcap_error(path);
        let mut w = mcap::WriteOptions::new()
            .chunk_size(Some(chunk_bytes))
            .compression_threads(0)
            // Each chunk is built in memory and written whole when it closes: the file never
            // holds a chunk header whose length is still a placeholder (a seeking writer puts
            // one on the disk and patches it at the chunk's end; killed in between, a reader
            // takes the placeholder for a record of 2^64 bytes).
            .disable_seeking(true)
            .create(mcap::write::NoSeek::new(BufWriter::with_capacity(
                1 << 16,
                f,
            )))
            .map_err(&me)?;
        let schema = serde_json::to_vec(&pose_in_frame_schema()).map_err(|e| IoError::Invalid {
            path: path.into(),
            msg: e.to_string(),
        })?;
        let sid = w
            .add_schema(POSE_IN_FRAME, "jsonschema", &schema)
            .map_err(&me)?;
        let no_meta = BTreeMap::new();
        let pose = w
            .add_channel(sid, TOPIC_POSE, "json", &no_meta)
            .map_err(&me)?;
        let keyframe = w
            .add_channel(sid, TOPIC_KEYFRAME, "json", &no_meta)
            .map_err(&me)?;
        Ok(PoseMcapWriter {
            path: path.into(),
            w,
            channels: [pose, keyframe],
            sequence: [0, 0],
            buf: Vec::with_capacity(512),
        })
    }

    /// One message on `topic`; an error for a time before 1970 (not an MCAP log time).
    pub fn write(&mut self, topic: Topic, p: &StampedPose) -> Result<(), IoError> {
        let k = topic as usize;
        let name = [TOPIC_POSE, TOPIC_KEYFRAME][k];
        let (Ok(t), Some(msg)) = (u64::try_from(p.t_ns), pose_in_frame_json(p)) else {
            return Err(IoError::Invalid {
                path: self.path.clone(),
                msg: format!(
                    "{name}: time {} ns is before 1970 and cannot be an MCAP log time",
                    p.t_ns
                ),
            });
        };
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, &msg).map_err(|e| IoError::Invalid {
            path: self.path.clone(),
            msg: e.to_string(),
        })?;
        self.sequence[k] = self.sequence[k].saturating_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[k],
            sequence: self.sequence[k],
            log_time: t,
            publish_time: t,
        };
        self.w
            .write_to_known_channel(&header, &self.buf)
            .map_err(mcap_error(&self.path))
    }

    /// Closes the open chunk and hands everything written to the operating system.
    pub fn flush(&mut self) -> Result<(), IoError> {
        self.w.flush().map_err(mcap_error(&self.path))
    }

    /// Writes the summary and the footer and closes the file.
    pub fn finish(mut self) -> Result<(), IoError> {
        let me = mcap_error(&self.path);
        self.w.finish().map_err(&me)?;
        self.w
            .into_inner()
            .into_inner()
            .into_inner()
            .map_err(|e| IoError::io(&self.path, e.into_error()))?;
        Ok(())
    }
}

/// An MCAP writer's error as an [`IoError`] naming `path` (the OS's error as such).
fn mcap_error(path: &Path) -> impl Fn(mcap::McapError) -> IoError + '_ {
    move |e| match e {
        mcap::McapError::Io(e) => IoError::io(path, e),
        e => IoError::Invalid {
            path: path.into(),
            msg: format!("writing MCAP: {e}"),
        },
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

/// Writes `poses` on [`TOPIC_POSE`] and `keyframes` on [`TOPIC_KEYFRAME`] at once
/// ([`PoseMcapWriter`]).
pub fn write_poses_mcap(
    path: &Path,
    poses: &[StampedPose],
    keyframes: &[StampedPose],
) -> Result<(), IoError> {
    let mut w = PoseMcapWriter::create(path, McapOptions::default().chunk_bytes)?;
    for p in poses {
        w.write(Topic::Pose, p)?;
    }
    for p in keyframes {
        w.write(Topic::Keyframe, p)?;
    }
    w.finish()
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

    fn pose_out(k: i64) -> PoseOut {
        PoseOut {
            nav: nav(k),
            latency_ns: 10,
            stamp_latency_ns: None,
            covariance: None,
        }
    }

    /// The messages of a (possibly unfinished) MCAP file, read as a stream up to its end or its
    /// first incomplete record: (topic, log time, JSON).
    fn stream(bytes: &[u8]) -> Vec<(String, u64, serde_json::Value)> {
        let mut out = Vec::new();
        let Ok(msgs) = mcap::MessageStream::new(bytes) else {
            return out;
        };
        for m in msgs {
            let Ok(m) = m else { break };
            let v = serde_json::from_slice(&m.data).expect("JSON");
            out.push((m.channel.topic.clone(), m.log_time, v));
        }
        out
    }

    #[test]
    fn mcap_sink_writes_pose_in_frame_messages() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("poses.mcap");
        let mut sink = McapSink::create(&path, McapOptions::default()).expect("created");
        for k in 0..5 {
            sink.pose(&pose_out(k));
        }
        sink.keyframe(&KeyframeOut {
            report: Default::default(),
            state: Some(nav(2)),
        });
        sink.keyframe(&KeyframeOut {
            report: Default::default(),
            state: None,
        });
        sink.finish().expect("written");
        let c = sink.counts();
        assert_eq!((c.poses, c.keyframes, c.dropped_queue), (5, 1, 0));
        let bytes = std::fs::read(&path).expect("the file");
        let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
            .expect("an MCAP file")
            .map(|m| m.expect("a message"))
            .collect();
        let on = |t: &str| msgs.iter().filter(|m| m.channel.topic == t).count();
        assert_eq!((on(TOPIC_POSE), on(TOPIC_KEYFRAME)), (5, 1));
        let first = &msgs[0];
        assert_eq!(first.log_time, nav(0).t_ns as u64);
        assert_eq!(first.sequence, 1);
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
        // Finished: the summary indexes every message.
        let summary = mcap::Summary::read(&bytes)
            .expect("a summary")
            .expect("present");
        let stats = summary.stats.expect("statistics");
        assert_eq!(stats.message_count, 6);
    }

    /// While the run goes on, what was pushed is in the file within the flush period, as complete
    /// records a streaming reader reads without the (missing) summary.
    #[test]
    fn mcap_sink_flushes_while_running() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("live.mcap");
        let opts = McapOptions {
            flush_period: Duration::from_millis(100),
            ..McapOptions::default()
        };
        let mut sink = McapSink::create(&path, opts).expect("created");
        let header = std::fs::read(&path).expect("the file");
        assert!(
            header.starts_with(b"\x89MCAP0\r\n"),
            "the magic is written at once"
        );
        for k in 0..50 {
            sink.pose(&pose_out(k));
        }
        // Written and flushed by the thread within a few periods, the sink still open.
        let mut seen = Vec::new();
        for _ in 0..100 {
            std::thread::sleep(Duration::from_millis(20));
            seen = stream(&std::fs::read(&path).expect("the file"));
            if seen.len() == 50 {
                break;
            }
        }
        assert_eq!(seen.len(), 50, "all 50 poses readable before finish");
        assert!(seen.iter().all(|(t, _, _)| t == TOPIC_POSE));
        let times: Vec<u64> = seen.iter().map(|(_, t, _)| *t).collect();
        let want: Vec<u64> = (0..50).map(|k| nav(k).t_ns as u64).collect();
        assert_eq!(times, want);
        assert!(sink.counts().flushes >= 1);
        let unfinished = std::fs::read(&path).expect("the file");
        assert!(
            mcap::Summary::read(&unfinished).is_err()
                || mcap::Summary::read(&unfinished).is_ok_and(|s| s.is_none()),
            "no footer before finish"
        );
        for k in 50..60 {
            sink.pose(&pose_out(k));
        }
        sink.finish().expect("finished");
        let done = stream(&std::fs::read(&path).expect("the file"));
        assert_eq!(done.len(), 60);
    }

    /// A file cut anywhere (a process killed in the middle of a write) reads up to its last
    /// complete chunk: every message before the cut's chunk, in order, none invented.
    #[test]
    fn a_cut_file_reads_up_to_its_last_complete_chunk() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("cut.mcap");
        let mut w = PoseMcapWriter::create(&path, 4096).expect("created");
        for k in 0..400 {
            w.write(Topic::Pose, &StampedPose::from(&nav(k)))
                .expect("written");
            if k % 37 == 36 {
                w.flush().expect("flushed");
            }
        }
        w.finish().expect("finished");
        let bytes = std::fs::read(&path).expect("the file");
        let all = stream(&bytes);
        assert_eq!(all.len(), 400);
        let mut last = 0;
        for cut in (0..bytes.len()).step_by(97) {
            let part = stream(&bytes[..cut]);
            assert!(part.len() >= last, "more bytes never read fewer messages");
            last = part.len();
            assert_eq!(part[..], all[..part.len()], "a prefix of the messages");
        }
    }

    #[test]
    fn an_unwritable_path_fails_when_the_sink_is_made() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("no/such/folder/poses.mcap");
        let e = McapSink::create(&path, McapOptions::default()).expect_err("refused");
        assert!(e.to_string().contains("no/such/folder"), "{e}");
        let bad = McapOptions {
            queue: 0,
            ..McapOptions::default()
        };
        assert!(McapSink::create(dir.path().join("a.mcap"), bad).is_err());
    }

    #[test]
    fn a_full_queue_drops_and_counts() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("small.mcap");
        let opts = McapOptions {
            queue: 4,
            ..McapOptions::default()
        };
        let mut sink = McapSink::create(&path, opts).expect("created");
        for k in 0..10_000 {
            sink.pose(&pose_out(k));
        }
        sink.finish().expect("finished");
        let c = sink.counts();
        assert_eq!(c.poses + c.dropped_queue, 10_000);
        let read = stream(&std::fs::read(&path).expect("the file"));
        assert_eq!(read.len() as u64, c.poses);
    }
}

//! ROS recordings, whatever the container: a [`MessageLog`] (a ROS 1 bag, a ROS 2 bag, an MCAP
//! file) gives its topics and each topic's serialized messages in log-time order; this layer
//! chooses the topics ([`topics`]), decodes the messages by their encoding ([`decode`]) and
//! serves them as a [`crate::recording::Recording`] ([`recording::RosRecording`]), so a new
//! container is one `MessageLog` implementation and everything above it is written once. The
//! time-ordered merge of a topic's messages across a container's parts (chunks) is written once
//! too ([`parts`]): a container gives its parts' start times and a loader of one part.
//!
//! Message types are named the ROS 1 way (`sensor_msgs/Imu`); a ROS 2 name
//! (`sensor_msgs/msg/Imu`) is normalized by [`normalize_type`] when a container lists its topics.
//!
//! A container's message stream yields an `Err(IoError::Corrupt { .. })` for a part it could not
//! read (a corrupt chunk: its byte offset is in the error) and goes on with the next part; any
//! other error ends it. The recording layer skips the corrupt part with a warning
//! ([`recording::RosRecording`]).

pub mod calib_msgs;
pub mod decode;
pub mod merge;
pub mod parts;
pub mod recording;
pub mod topics;
pub mod write;

#[cfg(test)]
mod tests;

use crate::error::IoError;
use std::path::Path;

/// How a topic's messages are serialized.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// ROS 1 serialization: little-endian, unaligned (ROS 1 bags, MCAP `ros1`).
    Ros1,
    /// OMG CDR with its encapsulation header (ROS 2 bags, MCAP `cdr`).
    Cdr,
}

/// One topic of a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// Topic name.
    pub topic: String,
    /// Message type, ROS 1 form (`sensor_msgs/Imu`).
    pub msg_type: String,
    /// How its messages are serialized.
    pub encoding: Encoding,
    /// Messages (all its connections or channels).
    pub count: u64,
    /// Log time of its first and last message, ns, when the container knows it up front.
    pub span_ns: Option<(i64, i64)>,
}

/// One serialized message as a container stores it.
#[derive(Debug, Clone, PartialEq)]
pub struct LogMessage {
    /// Log (receipt) time, ns: the order of the container.
    pub log_time_ns: i64,
    /// Byte offset of the message's record, or of the chunk holding it, in the file.
    pub offset: u64,
    /// The serialized message.
    pub data: Vec<u8>,
}

/// A topic's messages in log-time order (see the module docs for errors).
pub type LogStream<'a> = Box<dyn Iterator<Item = Result<LogMessage, IoError>> + Send + 'a>;

/// A container of ROS messages (see the module docs).
pub trait MessageLog: Send + Sync + std::fmt::Debug {
    /// The file or folder.
    fn path(&self) -> &Path;
    /// The container's format, for people (`ROS 1 bag v2.0, indexed, 15 chunks`).
    fn describe(&self) -> String;
    /// Its topics, sorted by name then type (a topic with two types appears twice).
    fn topics(&self) -> Vec<TopicInfo>;
    /// The messages of `topic` in log-time order (every type it was published with).
    fn messages(&self, topic: &str) -> LogStream<'_>;
    /// What was wrong but could be read past when it was opened (a missing index, a cut file).
    fn warnings(&self) -> Vec<String>;
    /// Where the message at `offset` ([`LogMessage::offset`]) is, for an error message.
    fn locate(&self, offset: u64) -> String {
        format!("record at byte offset {offset}")
    }
}

/// A message type in ROS 1 form: `pkg/msg/Name` -> `pkg/Name`; other names unchanged.
pub fn normalize_type(t: &str) -> String {
    match t.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, "msg", name] => format!("{pkg}/{name}"),
        _ => t.to_string(),
    }
}

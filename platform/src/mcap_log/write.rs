//! Writing ROS messages to an MCAP file, as a [`ContainerWriter`]: one schema per message type
//! (`ros1msg` for ROS 1 messages, `ros2msg` for CDR), one channel per topic (message encoding
//! `ros1` or `cdr`), zstd chunks, a summary section with statistics and indexes (the `mcap`
//! crate writes the records). Log and publish times are the given time; sequence numbers count
//! each channel's messages from 1.
//!
//! The profile is `ros1` for ROS 1 messages (what `mcap-ros1-support` and `mcap convert` write),
//! `ros2` for CDR. A ROS 2 bag's MCAP storage adds channel metadata and a `rosbag2` metadata
//! record ([`crate::rosbag2::write`]).

use crate::error::IoError;
use crate::rosrec::write::{ContainerWriter, TopicSpec};
use crate::rosrec::Encoding;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// An MCAP file being written (see the module docs).
pub struct McapWriter {
    path: PathBuf,
    w: mcap::Writer<BufWriter<File>>,
    profile_encoding: Encoding,
    /// Schema id per message type.
    schemas: BTreeMap<String, u16>,
    /// (channel id, messages written) per topic id.
    channels: Vec<(u16, u32)>,
    /// Channel metadata given to each topic added after it is set.
    channel_metadata: BTreeMap<String, String>,
}

impl McapWriter {
    /// Creates the file at `path` (replacing one there) for messages in `encoding`.
    pub fn create(path: &Path, encoding: Encoding) -> Result<Self, IoError> {
        let profile = match encoding {
            Encoding::Ros1 => "ros1",
            Encoding::Cdr => "ros2",
        };
        let f = File::create(path).map_err(|e| IoError::io(path, e))?;
        let w = mcap::WriteOptions::new()
            .profile(profile)
            .library(concat!("povins ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, f))
            .map_err(|e| mcap_err(path, e))?;
        Ok(McapWriter {
            path: path.to_path_buf(),
            w,
            profile_encoding: encoding,
            schemas: BTreeMap::new(),
            channels: Vec::new(),
            channel_metadata: BTreeMap::new(),
        })
    }

    /// Sets the metadata of the channels added from now on (e.g. rosbag2's
    /// `offered_qos_profiles`).
    pub fn set_channel_metadata(&mut self, metadata: BTreeMap<String, String>) {
        self.channel_metadata = metadata;
    }

    /// Writes a metadata record `name` of string pairs.
    pub fn write_metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), IoError> {
        let m = mcap::records::Metadata {
            name: name.into(),
            metadata,
        };
        self.w
            .write_metadata(&m)
            .map_err(|e| mcap_err(&self.path, e))
    }

    /// Writes the summary and flushes the file.
    pub fn finish(mut self) -> Result<(), IoError> {
        self.w.finish().map_err(|e| mcap_err(&self.path, e))?;
        let mut f = self.w.into_inner();
        std::io::Write::flush(&mut f).map_err(|e| IoError::io(&self.path, e))
    }
}

fn mcap_err(path: &Path, e: mcap::McapError) -> IoError {
    IoError::Invalid {
        path: path.into(),
        msg: format!("writing MCAP: {e}"),
    }
}

impl ContainerWriter for McapWriter {
    fn add_topic(&mut self, spec: &TopicSpec) -> Result<usize, IoError> {
        let (schema_encoding, message_encoding) = match spec.encoding {
            Encoding::Ros1 => ("ros1msg", "ros1"),
            Encoding::Cdr => ("ros2msg", "cdr"),
        };
        if spec.encoding != self.profile_encoding {
            return Err(IoError::Invalid {
                path: self.path.clone(),
                msg: format!(
                    "topic {}: {message_encoding} messages in an MCAP file of another profile",
                    spec.topic
                ),
            });
        }
        let sid = match self.schemas.get(&spec.msg_type) {
            Some(id) => *id,
            None => {
                let id = self
                    .w
                    .add_schema(&spec.msg_type, schema_encoding, spec.definition.as_bytes())
                    .map_err(|e| mcap_err(&self.path, e))?;
                self.schemas.insert(spec.msg_type.clone(), id);
                id
            }
        };
        let cid = self
            .w
            .add_channel(sid, &spec.topic, message_encoding, &self.channel_metadata)
            .map_err(|e| mcap_err(&self.path, e))?;
        self.channels.push((cid, 0));
        Ok(self.channels.len() - 1)
    }

    fn write(&mut self, topic: usize, t_ns: i64, data: &[u8]) -> Result<(), IoError> {
        let path = &self.path;
        let Some((channel_id, seq)) = self.channels.get_mut(topic) else {
            return Err(IoError::Invalid {
                path: path.clone(),
                msg: format!("topic {topic} was not added"),
            });
        };
        let time = u64::try_from(t_ns).map_err(|_| IoError::Invalid {
            path: path.clone(),
            msg: format!("time {t_ns} ns is before 1970 and cannot be an MCAP log time"),
        })?;
        *seq += 1;
        let header = mcap::records::MessageHeader {
            channel_id: *channel_id,
            sequence: *seq,
            log_time: time,
            publish_time: time,
        };
        self.w
            .write_to_known_channel(&header, data)
            .map_err(|e| mcap_err(path, e))
    }
}

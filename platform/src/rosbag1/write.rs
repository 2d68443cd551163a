//! Writing ROS 1 bags (format 2.0), streaming: messages are appended to a chunk buffer that is
//! compressed (`none`, `lz4` or `bz2`) and written once it holds [`BagWriter::chunk_threshold`]
//! bytes, followed by its index data records; [`BagWriter::finish`] writes the index (every
//! connection, a chunk info per chunk) and fills in the bag header. Memory is one chunk and a
//! few numbers per chunk and per message of the current chunk, whatever the bag's length.
//!
//! The layout is what `rosbag record` writes (see [`super`] for the records): a connection's
//! record goes into the chunk holding its first message and again into the index; messages are
//! written in the order given (a bag is ordered by receipt time: give them in time order for
//! readers that assume it). The message types' definitions and md5sums are [`MsgType`]s
//! ([`super::msgs`] encodes the messages).

use super::msgs::{ros_time, MsgType};
use super::record::{
    OP_BAG_HEADER, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION, OP_INDEX_DATA, OP_MESSAGE,
};
use super::MAGIC;
use crate::error::IoError;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Bytes of the bag header record (with its padding), as `rosbag` writes it.
const BAG_HEADER_LEN: usize = 4096;

/// How chunks are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// Stored as is.
    None,
    /// LZ4 frame format (`rosbag record --lz4`).
    Lz4,
    /// bzip2 (`rosbag record --bz2`).
    Bz2,
}

impl Compression {
    /// The chunk header's `compression` value.
    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Lz4 => "lz4",
            Compression::Bz2 => "bz2",
        }
    }
}

/// A connection of the bag being written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnId(u32);

struct Conn {
    topic: String,
    name: String,
    md5sum: String,
    definition: String,
    in_a_chunk: bool,
}

/// The chunk being filled.
#[derive(Default)]
struct Chunk {
    data: Vec<u8>,
    start_ns: i64,
    end_ns: i64,
    /// Per connection: (receipt time, offset of the message record in `data`).
    index: BTreeMap<u32, Vec<([u8; 8], u32)>>,
}

struct ChunkInfo {
    pos: u64,
    start_ns: i64,
    end_ns: i64,
    counts: Vec<(u32, u32)>,
}

/// A ROS 1 bag being written (see the module docs). Errors name the file, and the topic and
/// message index for a message that cannot be stored.
pub struct BagWriter {
    path: PathBuf,
    f: BufWriter<File>,
    pos: u64,
    compression: Compression,
    /// Uncompressed bytes at which a chunk is written (default 768 kB, `rosbag`'s).
    pub chunk_threshold: usize,
    conns: Vec<Conn>,
    chunk: Chunk,
    chunks: Vec<ChunkInfo>,
    messages: u64,
}

/// One header field `name=value` with its length.
fn field(out: &mut Vec<u8>, name: &str, value: &[u8]) {
    out.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
    out.extend(name.as_bytes());
    out.push(b'=');
    out.extend(value);
}

/// A record: its header (`fields`), then `data`, each with its length.
fn record(out: &mut Vec<u8>, fields: &[(&str, &[u8])], data: &[u8]) {
    let mut h = Vec::new();
    for (name, value) in fields {
        field(&mut h, name, value);
    }
    out.extend((h.len() as u32).to_le_bytes());
    out.extend(h);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
}

fn time_bytes(t_ns: i64) -> [u8; 8] {
    // Times are checked when a message is written; chunk times are message times.
    ros_time(t_ns).unwrap_or_default()
}

impl BagWriter {
    /// Creates the bag at `path` (replacing a file there) with chunks compressed by
    /// `compression`.
    pub fn create(path: &Path, compression: Compression) -> Result<Self, IoError> {
        let file = File::create(path).map_err(|e| IoError::io(path, e))?;
        let mut w = BagWriter {
            path: path.to_path_buf(),
            f: BufWriter::with_capacity(1 << 16, file),
            pos: 0,
            compression,
            chunk_threshold: 768 * 1024,
            conns: Vec::new(),
            chunk: Chunk::default(),
            chunks: Vec::new(),
            messages: 0,
        };
        w.put(MAGIC)?;
        let header = w.bag_header(0);
        w.put(&header)?;
        Ok(w)
    }

    fn io(&self, e: std::io::Error) -> IoError {
        IoError::io(&self.path, e)
    }

    fn put(&mut self, b: &[u8]) -> Result<(), IoError> {
        self.f
            .write_all(b)
            .map_err(|e| IoError::io(&self.path, e))?;
        self.pos += b.len() as u64;
        Ok(())
    }

    /// The bag header record, padded with spaces to [`BAG_HEADER_LEN`] bytes.
    fn bag_header(&self, index_pos: u64) -> Vec<u8> {
        let mut h = Vec::new();
        field(&mut h, "index_pos", &index_pos.to_le_bytes());
        field(
            &mut h,
            "conn_count",
            &(self.conns.len() as u32).to_le_bytes(),
        );
        field(
            &mut h,
            "chunk_count",
            &(self.chunks.len() as u32).to_le_bytes(),
        );
        field(&mut h, "op", &[OP_BAG_HEADER]);
        let pad = BAG_HEADER_LEN - 8 - h.len();
        let mut out = Vec::with_capacity(BAG_HEADER_LEN);
        out.extend((h.len() as u32).to_le_bytes());
        out.extend(h);
        out.extend((pad as u32).to_le_bytes());
        out.resize(BAG_HEADER_LEN, b' ');
        out
    }

    /// Adds a connection: `topic` published with `msg_type`.
    pub fn add_connection(&mut self, topic: &str, msg_type: MsgType) -> ConnId {
        self.conns.push(Conn {
            topic: topic.to_string(),
            name: msg_type.name.into(),
            md5sum: msg_type.md5sum.into(),
            definition: msg_type.definition.into(),
            in_a_chunk: false,
        });
        ConnId(self.conns.len() as u32 - 1)
    }

    fn connection_record(&self, out: &mut Vec<u8>, id: u32) {
        let c = &self.conns[id as usize];
        let mut data = Vec::new();
        field(&mut data, "topic", c.topic.as_bytes());
        field(&mut data, "type", c.name.as_bytes());
        field(&mut data, "md5sum", c.md5sum.as_bytes());
        field(&mut data, "message_definition", c.definition.as_bytes());
        record(
            out,
            &[
                ("op", &[OP_CONNECTION]),
                ("conn", &id.to_le_bytes()),
                ("topic", c.topic.as_bytes()),
            ],
            &data,
        );
    }

    /// Appends the serialized message `data` on `conn`, received at `t_ns`.
    pub fn write(&mut self, conn: ConnId, t_ns: i64, data: &[u8]) -> Result<(), IoError> {
        let id = conn.0;
        let Some(c) = self.conns.get(id as usize) else {
            return Err(IoError::Invalid {
                path: self.path.clone(),
                msg: format!("connection {id} was not added"),
            });
        };
        let time = ros_time(t_ns).ok_or_else(|| IoError::Invalid {
            path: self.path.clone(),
            msg: format!(
                "{} message {}: time {t_ns} ns is not a ROS 1 time (0 to 2^32 s)",
                c.topic, self.messages
            ),
        })?;
        if !c.in_a_chunk {
            let mut rec = Vec::new();
            self.connection_record(&mut rec, id);
            self.chunk.data.extend(rec);
            self.conns[id as usize].in_a_chunk = true;
        }
        let ch = &mut self.chunk;
        if ch.index.is_empty() {
            (ch.start_ns, ch.end_ns) = (t_ns, t_ns);
        }
        ch.start_ns = ch.start_ns.min(t_ns);
        ch.end_ns = ch.end_ns.max(t_ns);
        let offset = ch.data.len() as u32;
        record(
            &mut ch.data,
            &[
                ("op", &[OP_MESSAGE]),
                ("conn", &id.to_le_bytes()),
                ("time", &time),
            ],
            data,
        );
        ch.index.entry(id).or_default().push((time, offset));
        self.messages += 1;
        if self.chunk.data.len() >= self.chunk_threshold {
            self.flush_chunk()?;
        }
        Ok(())
    }

    /// Writes the chunk being filled (if it holds a message) and its index data records.
    fn flush_chunk(&mut self) -> Result<(), IoError> {
        let ch = std::mem::take(&mut self.chunk);
        if ch.index.is_empty() {
            return Ok(());
        }
        let size = ch.data.len() as u32;
        let packed = self.compress(ch.data)?;
        let pos = self.pos;
        let mut out = Vec::with_capacity(packed.len() + 64);
        record(
            &mut out,
            &[
                ("compression", self.compression.name().as_bytes()),
                ("op", &[OP_CHUNK]),
                ("size", &size.to_le_bytes()),
            ],
            &packed,
        );
        let mut counts = Vec::new();
        for (id, entries) in &ch.index {
            let mut d = Vec::with_capacity(entries.len() * 12);
            for (time, offset) in entries {
                d.extend(time);
                d.extend(offset.to_le_bytes());
            }
            let n = entries.len() as u32;
            record(
                &mut out,
                &[
                    ("op", &[OP_INDEX_DATA]),
                    ("ver", &1u32.to_le_bytes()),
                    ("conn", &id.to_le_bytes()),
                    ("count", &n.to_le_bytes()),
                ],
                &d,
            );
            counts.push((*id, n));
        }
        self.put(&out)?;
        self.chunks.push(ChunkInfo {
            pos,
            start_ns: ch.start_ns,
            end_ns: ch.end_ns,
            counts,
        });
        Ok(())
    }

    fn compress(&self, data: Vec<u8>) -> Result<Vec<u8>, IoError> {
        match self.compression {
            Compression::None => Ok(data),
            Compression::Lz4 => {
                let mut enc = lz4::EncoderBuilder::new()
                    .build(Vec::with_capacity(data.len() / 2))
                    .map_err(|e| self.io(e))?;
                enc.write_all(&data).map_err(|e| self.io(e))?;
                let (out, r) = enc.finish();
                r.map_err(|e| self.io(e))?;
                Ok(out)
            }
            Compression::Bz2 => {
                let mut enc = bzip2::write::BzEncoder::new(
                    Vec::with_capacity(data.len() / 2),
                    bzip2::Compression::default(),
                );
                enc.write_all(&data).map_err(|e| self.io(e))?;
                enc.finish().map_err(|e| self.io(e))
            }
        }
    }

    /// Messages written so far.
    pub fn message_count(&self) -> u64 {
        self.messages
    }

    /// Writes the last chunk and the index, fills in the bag header and flushes the file.
    pub fn finish(mut self) -> Result<(), IoError> {
        self.flush_chunk()?;
        let index_pos = self.pos;
        let mut out = Vec::new();
        for id in 0..self.conns.len() as u32 {
            self.connection_record(&mut out, id);
        }
        for c in &self.chunks {
            let mut d = Vec::with_capacity(c.counts.len() * 8);
            for (id, n) in &c.counts {
                d.extend(id.to_le_bytes());
                d.extend(n.to_le_bytes());
            }
            record(
                &mut out,
                &[
                    ("op", &[OP_CHUNK_INFO]),
                    ("ver", &1u32.to_le_bytes()),
                    ("chunk_pos", &c.pos.to_le_bytes()),
                    ("start_time", &time_bytes(c.start_ns)),
                    ("end_time", &time_bytes(c.end_ns)),
                    ("count", &(c.counts.len() as u32).to_le_bytes()),
                ],
                &d,
            );
        }
        self.put(&out)?;
        let header = self.bag_header(index_pos);
        self.f
            .seek(SeekFrom::Start(MAGIC.len() as u64))
            .and_then(|_| self.f.write_all(&header))
            .and_then(|()| self.f.flush())
            .map_err(|e| IoError::io(&self.path, e))
    }
}

use crate::rosrec::write::{ContainerWriter, TopicSpec};
pub use crate::rosrec::write::{DatasetCounts, DatasetTopics};
use crate::rosrec::Encoding;

impl ContainerWriter for BagWriter {
    fn add_topic(&mut self, spec: &TopicSpec) -> Result<usize, IoError> {
        if spec.encoding != Encoding::Ros1 {
            return Err(IoError::Invalid {
                path: self.path.clone(),
                msg: format!(
                    "topic {}: a ROS 1 bag holds ROS 1 messages, not CDR",
                    spec.topic
                ),
            });
        }
        self.conns.push(Conn {
            topic: spec.topic.clone(),
            name: spec.msg_type.clone(),
            md5sum: spec.type_hash.clone(),
            definition: spec.definition.clone(),
            in_a_chunk: false,
        });
        Ok(self.conns.len() - 1)
    }

    fn write(&mut self, topic: usize, t_ns: i64, data: &[u8]) -> Result<(), IoError> {
        BagWriter::write(self, ConnId(topic as u32), t_ns, data)
    }
}

/// Writes the IMU samples, the images (they need their pixels) and the LiDAR sweeps of `ds` as
/// a ROS 1 bag at `path` on `topics`, in time order (IMU first at equal times), each message
/// received at its stamp ([`crate::rosrec::write`] decides the messages). Feature tracks,
/// ground truth and the calibration have no place in it.
pub fn write_dataset(
    path: &Path,
    ds: &crate::dataset::Dataset,
    topics: &DatasetTopics,
    compression: Compression,
) -> Result<DatasetCounts, IoError> {
    let mut w = BagWriter::create(path, compression)?;
    let n = crate::rosrec::write::write_dataset(&mut w, path, ds, topics, Encoding::Ros1, None)?;
    w.finish()?;
    Ok(n)
}

#[cfg(test)]
#[path = "write_tests.rs"]
mod tests;

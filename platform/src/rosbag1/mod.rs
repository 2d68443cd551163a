//! ROS 1 bags (format 2.0), read streaming with bounded memory.
//!
//! ## The format
//! `#ROSBAG V2.0\n`, then records (see [`record`]): the bag header (`op` 3: `index_pos`,
//! `conn_count`, `chunk_count`, padded to 4 kB), the chunk section (chunks, `op` 5, each holding
//! connection records `op` 7 and message records `op` 2 with the receipt `time`, compressed
//! `none`, `bz2` or `lz4`; each chunk followed by its index data records `op` 4), then at
//! `index_pos` the index: every connection again and one chunk info (`op` 6: chunk position,
//! start and end time, per-connection message counts) per chunk. All integers little-endian.
//!
//! ## Reading
//! [`Bag::open`] reads the header and the index: the connections (a connection seen again is
//! the same one; one topic may have several connections) and the chunks' time ranges and
//! counts, never a message. A bag without a usable index (`index_pos` 0 as a killed recorder
//! leaves it, an index past the end of a cut file, an index that does not parse) is scanned
//! instead: each chunk is read once, one at a time, for its connections, times and counts. A
//! bag cut at any byte is read up to its last complete message; what was lost is in
//! [`Bag::warnings`]. Messages are then pulled per set of connections in receipt-time order
//! ([`chunk::Messages`]): memory is the chunks overlapping in time (one or two in a bag written
//! by `rosbag record`), whatever the bag's length. The file is read with ordinary reads, not
//! mapped.
//!
//! Message stamps (`header.stamp`) are the samples' times; the receipt time orders the bag.
//!
//! Every error names the file, the byte offset and the problem.
//!
//! Hand-written rather than the `rosbag` crate (0.6.3): that crate maps the file and slices it
//! with the header's `index_pos` unchecked, so an unindexed bag (`index_pos` 0) or a cut one
//! (`index_pos` past the end) panics, and its errors carry no file or offset; the record layer
//! is small. Decompression is by crates (`bzip2`, `lz4`).

pub mod chunk;
mod log;
pub mod msgs;
pub mod record;
pub mod write;

#[cfg(test)]
mod tests;

use crate::error::IoError;
use record::{
    file_record, FileRecord, RecordError, OP_BAG_HEADER, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION,
};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// The version line every ROS 1 bag starts with.
pub const MAGIC: &[u8; 13] = b"#ROSBAG V2.0\n";

/// One connection: a topic published with one type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Connection {
    /// Id used by the message records.
    pub id: u32,
    /// Topic name.
    pub topic: String,
    /// Message type, e.g. `sensor_msgs/Imu`.
    pub msg_type: String,
    /// The type's md5sum.
    pub md5sum: String,
}

/// Where a chunk is and what it holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkInfo {
    /// Offset of the chunk record.
    pub pos: u64,
    /// Earliest receipt time, ns.
    pub start_ns: i64,
    /// Latest receipt time, ns.
    pub end_ns: i64,
    /// Message count per connection id.
    pub counts: Vec<(u32, u32)>,
    /// The chunk is cut by the end of the file (read what decompresses before the cut).
    pub cut: bool,
}

/// An opened ROS 1 bag (see the module docs).
#[derive(Debug, Clone)]
pub struct Bag {
    /// The file.
    pub path: PathBuf,
    /// Its length, bytes.
    pub file_len: u64,
    /// Connections by id.
    pub connections: BTreeMap<u32, Connection>,
    /// Chunks in file order.
    pub chunks: Vec<ChunkInfo>,
    /// True when the index was read (false: the chunks were scanned).
    pub indexed: bool,
    /// What was wrong but could be read past (missing index, cut file, bytes lost).
    pub warnings: Vec<String>,
}

impl Bag {
    /// Opens a bag: header and index, or a scan of the chunks when the index is missing.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let mut f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        let file_len = f.metadata().map_err(|e| IoError::io(path, e))?.len();
        let mut bag = Bag {
            path: path.to_path_buf(),
            file_len,
            connections: BTreeMap::new(),
            chunks: Vec::new(),
            indexed: false,
            warnings: Vec::new(),
        };
        let mut magic = [0u8; 13];
        if file_len < MAGIC.len() as u64 || f.read_exact(&mut magic).is_err() || &magic != MAGIC {
            let msg = if file_len == 0 {
                "empty file (0 bytes): not a ROS bag".to_string()
            } else {
                format!(
                    "does not start with {:?}: not a ROS 1 bag (v2.0)",
                    "#ROSBAG V2.0"
                )
            };
            return Err(bag.corrupt("file", 0, msg));
        }
        let head = match file_record(&mut f, MAGIC.len() as u64, file_len) {
            Ok(Some(h)) => h,
            Ok(None) => {
                return Err(bag.corrupt("bag header", 13, "file ends before the bag header"))
            }
            Err(e) => return Err(bag.error("bag header", e)),
        };
        let op = head.fields.op().map_err(|e| bag.error("bag header", e))?;
        if op != OP_BAG_HEADER {
            return Err(bag.corrupt(
                "bag header",
                13,
                format!("first record has op {op:#04x}, not 0x03"),
            ));
        }
        let index_pos = head
            .fields
            .u64("index_pos")
            .map_err(|e| bag.error("bag header", e))?;
        let chunk_count = head.fields.u32("chunk_count").unwrap_or(0);
        let start = head.end();
        if index_pos == 0 {
            bag.warn(format!(
                "unindexed bag (index_pos 0: the recorder did not close it): scanning {} bytes",
                file_len - start
            ));
            bag.scan(&mut f, start, file_len)?;
        } else if index_pos < start || index_pos > file_len {
            bag.warn(format!("index_pos {index_pos} is outside the file ({file_len} bytes): the bag is cut; scanning"));
            bag.scan(&mut f, start, file_len)?;
        } else {
            match bag.read_index(&mut f, index_pos, chunk_count) {
                Ok(()) => bag.indexed = true,
                Err(e) => {
                    bag.warn(format!(
                        "index at byte {index_pos} is unusable ({}: {}); scanning",
                        e.offset(),
                        e.msg()
                    ));
                    bag.connections.clear();
                    bag.chunks.clear();
                    bag.scan(&mut f, start, index_pos)?;
                }
            }
        }
        Ok(bag)
    }

    /// Connection ids of `topic`.
    pub fn topic_conns(&self, topic: &str) -> std::collections::HashSet<u32> {
        self.connections
            .values()
            .filter(|c| c.topic == topic)
            .map(|c| c.id)
            .collect()
    }

    /// The messages of `conns` in receipt-time order (see [`chunk::Messages`]).
    pub fn conn_messages(&self, conns: std::collections::HashSet<u32>) -> chunk::Messages<'_> {
        chunk::messages(self, conns)
    }

    /// Message count of connection `id` (from the index or the scan).
    pub fn count(&self, id: u32) -> u64 {
        self.chunks
            .iter()
            .flat_map(|c| &c.counts)
            .filter(|(c, _)| *c == id)
            .map(|(_, n)| u64::from(*n))
            .sum()
    }

    fn warn(&mut self, msg: String) {
        self.warnings
            .push(format!("{}: {msg}", self.path.display()));
    }

    fn corrupt(&self, what: &str, offset: u64, msg: impl Into<String>) -> IoError {
        IoError::Corrupt {
            file: self.path.clone(),
            what: what.into(),
            offset,
            msg: msg.into(),
        }
    }

    /// A record error as an I/O error naming the file.
    pub fn error(&self, what: &str, e: RecordError) -> IoError {
        let kind = if matches!(e, RecordError::Truncated { .. }) {
            "truncated: "
        } else {
            ""
        };
        self.corrupt(what, e.offset(), format!("{kind}{}", e.msg()))
    }

    fn add_connection(
        &mut self,
        fields: &record::Fields,
        data: &[u8],
        data_offset: u64,
    ) -> Result<(), RecordError> {
        let id = fields.u32("conn")?;
        let topic = fields.string("topic")?;
        let inner = record::Fields::parse(data, data_offset)?;
        let msg_type = inner.string("type")?;
        let md5sum = inner.string("md5sum").unwrap_or_default();
        let conn = Connection {
            id,
            topic,
            msg_type,
            md5sum,
        };
        match self.connections.get(&id) {
            Some(old) if *old != conn => Err(RecordError::Corrupt {
                offset: fields.offset,
                msg: format!(
                    "connection {id} is {} ({}) here but {} ({}) before",
                    conn.topic, conn.msg_type, old.topic, old.msg_type
                ),
            }),
            Some(_) => Ok(()),
            None => {
                self.connections.insert(id, conn);
                Ok(())
            }
        }
    }

    fn read_index(
        &mut self,
        f: &mut std::fs::File,
        index_pos: u64,
        chunk_count: u32,
    ) -> Result<(), RecordError> {
        let mut pos = index_pos;
        while let Some(rec) = file_record(f, pos, self.file_len)? {
            let mut data = || record::read_at(f, rec.data_offset, rec.data_len as usize);
            match rec.fields.op()? {
                OP_CONNECTION => {
                    let d = data()?;
                    self.add_connection(&rec.fields, &d, rec.data_offset)?;
                }
                OP_CHUNK_INFO => {
                    let d = data()?;
                    self.chunks.push(chunk_info(&rec, &d)?);
                }
                _ => {}
            }
            pos = rec.end();
        }
        if self.chunks.len() != chunk_count as usize {
            return Err(RecordError::Corrupt {
                offset: index_pos,
                msg: format!(
                    "{} chunk infos, the header says {chunk_count}",
                    self.chunks.len()
                ),
            });
        }
        self.chunks.sort_by_key(|c| c.pos);
        Ok(())
    }

    /// Reads the records from `start` to `end` one at a time (chunks decompressed one at a
    /// time) for the connections and the chunks' times and counts.
    fn scan(&mut self, f: &mut std::fs::File, start: u64, end: u64) -> Result<(), IoError> {
        let mut pos = start;
        while pos < end {
            let rec = match file_record(f, pos, end) {
                Ok(Some(r)) => r,
                Ok(None) => break,
                Err(RecordError::Truncated { offset, msg }) => {
                    // A cut chunk still gives what decompresses before the cut.
                    let op = file_record(f, pos, u64::MAX)
                        .ok()
                        .flatten()
                        .and_then(|r| r.fields.op().ok());
                    let recovered = match op {
                        None => "its header is cut: whatever it held is lost".to_string(),
                        Some(OP_CHUNK) => match self.scan_chunk(f, pos, end, true) {
                            Ok((n, lost)) => format!(
                                "{n} messages recovered from the chunk, {lost} bytes of its \
                                 decompressed data lost"
                            ),
                            Err(e) => format!("nothing recovered from the chunk ({e})"),
                        },
                        Some(op) => format!("op {op:#04x}, not a chunk: no message lost"),
                    };
                    self.warn(format!(
                        "truncated at byte {end}: the record at byte {offset} is cut ({msg}); \
                         {recovered}"
                    ));
                    return Ok(());
                }
                Err(e) => return Err(self.error("record", e)),
            };
            if rec.fields.op().map_err(|e| self.error("record", e))? == OP_CHUNK {
                self.scan_chunk(f, pos, end, false)?;
            } else if rec.fields.op().ok() == Some(OP_CONNECTION) {
                let d = record::read_at(f, rec.data_offset, rec.data_len as usize)
                    .map_err(|e| self.error("connection", e))?;
                self.add_connection(&rec.fields, &d, rec.data_offset)
                    .map_err(|e| self.error("connection", e))?;
            }
            pos = rec.end();
        }
        Ok(())
    }

    /// Reads one chunk for its connections, time range and counts; returns its message count
    /// and the bytes of its decompressed data lost to a cut.
    fn scan_chunk(
        &mut self,
        f: &mut std::fs::File,
        pos: u64,
        end: u64,
        cut: bool,
    ) -> Result<(u64, u64), IoError> {
        let data = chunk::read_chunk(f, pos, end, cut).map_err(|e| self.error("chunk", e))?;
        let mut conns = Vec::new();
        let msgs = chunk::walk_chunk(
            &data,
            |_| true,
            |fields, d| {
                conns.push((fields, d.to_vec()));
                Ok(())
            },
        )
        .map_err(|e| self.error("chunk", e))?;
        for (fields, d) in conns {
            self.add_connection(&fields, &d, pos)
                .map_err(|e| self.error("connection", e))?;
        }
        if msgs.is_empty() {
            return Ok((0, data.lost));
        }
        let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
        for m in &msgs {
            *counts.entry(m.conn).or_default() += 1;
        }
        self.chunks.push(ChunkInfo {
            pos,
            start_ns: msgs.iter().map(|m| m.time_ns).min().unwrap_or(0),
            end_ns: msgs.iter().map(|m| m.time_ns).max().unwrap_or(0),
            counts: counts.into_iter().collect(),
            cut,
        });
        Ok((msgs.len() as u64, data.lost))
    }
}

/// A chunk info record.
fn chunk_info(rec: &FileRecord, data: &[u8]) -> Result<ChunkInfo, RecordError> {
    let f = &rec.fields;
    let n = f.u32("count")? as usize;
    if data.len() < n.saturating_mul(8) {
        return Err(RecordError::Corrupt {
            offset: rec.data_offset,
            msg: format!("chunk info lists {n} connections in {} bytes", data.len()),
        });
    }
    let counts = (0..n)
        .filter_map(|i| {
            Some((
                record::le_u32(data, 8 * i)?,
                record::le_u32(data, 8 * i + 4)?,
            ))
        })
        .collect();
    Ok(ChunkInfo {
        pos: f.u64("chunk_pos")?,
        start_ns: f.time_ns("start_time")?,
        end_ns: f.time_ns("end_time")?,
        counts,
        cut: false,
    })
}

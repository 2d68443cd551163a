//! Any MCAP file as a [`MessageLog`]: channels with message encoding `ros1` or `cdr` are ROS
//! topics (schema names normalized to the ROS 1 form, `sensor_msgs/msg/Imu` ->
//! `sensor_msgs/Imu`); a channel of another encoding (`json`, `protobuf`, ...) is listed with
//! its type marked `(ENCODING encoding, not read)`, so choosing it is an error that says so.
//!
//! ## Opening
//! With a summary section (the footer points at it, and it holds the channels, the statistics
//! and one chunk index per chunk), the topics, counts and chunks come from it and nothing else is
//! read. Without one (a recorder killed before writing it, a writer that does not, a cut file, a
//! summary that does not parse), the file's records are walked once: every chunk is decompressed
//! and its CRC checked, one at a time, for the channels, the counts, the time ranges and which
//! channels each chunk holds. Record framing (opcode u8, length u64 little-endian) is followed by
//! this module, so every error names its true byte offset in the file; the records themselves
//! are parsed and chunks decompressed (zstd, lz4) by the `mcap` crate.
//!
//! A walk stops at the first record that does not fit in the file (a cut file, or a corrupt
//! length): what came before is read and a warning says at which byte and how much was lost.
//! A chunk that does not decompress or whose CRC does not match is kept out of the counts with a
//! warning, and is an `Err(IoError::Corrupt)` item (naming its byte offset and time range) in the
//! stream of every topic it might hold; the stream goes on.
//!
//! ## Streaming
//! A topic's messages come from the chunks that hold it, in log-time order across chunks
//! (see [`stream`], merged by [`crate::rosrec::parts`]): at most
//! [`crate::rosrec::parts::WINDOW_PARTS`] decompressed chunks are held at once, whatever the
//! file's length. Messages written outside chunks are read the same way, in runs of at most
//! [`LOOSE_RUN_BYTES`].

mod stream;
#[cfg(test)]
pub(crate) mod tests;
pub mod write;

use crate::error::IoError;
use crate::rosrec::{normalize_type, Encoding, LogStream, MessageLog, TopicInfo};
use mcap::records::{op, Record};
use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Largest record accepted (a chunk, compressed), bytes.
pub const MAX_RECORD_BYTES: u64 = 1 << 30;

/// Messages outside chunks are grouped in runs of at most this many bytes.
pub const LOOSE_RUN_BYTES: u64 = 4 << 20;

/// Bytes of a record's opcode and length.
const FRAME: u64 = 9;

/// A channel of the file.
#[derive(Debug, Clone)]
struct Channel {
    topic: String,
    /// ROS 1 form, or marked as not read.
    msg_type: String,
    encoding: Option<Encoding>,
}

/// A byte range of the file holding messages: one chunk record, or a run of records outside
/// chunks.
#[derive(Debug, Clone)]
struct Part {
    pos: u64,
    len: u64,
    start_ns: i64,
    end_ns: i64,
    /// The channels it holds (all when unknown: a corrupt chunk found by the walk).
    channels: Option<Vec<u16>>,
}

/// An MCAP file opened as a message log (see the module docs).
#[derive(Debug)]
pub struct McapLog {
    path: PathBuf,
    file_len: u64,
    channels: BTreeMap<u16, Channel>,
    counts: BTreeMap<u16, u64>,
    spans: BTreeMap<u16, (i64, i64)>,
    parts: Vec<Part>,
    from_summary: bool,
    chunks: usize,
    metadata: Vec<String>,
    warnings: Vec<String>,
}

fn corrupt(path: &Path, what: &str, offset: u64, msg: impl Into<String>) -> IoError {
    IoError::Corrupt {
        file: path.to_path_buf(),
        what: what.into(),
        offset,
        msg: msg.into(),
    }
}

/// Reads `len` bytes at `pos`.
fn read_at(f: &mut std::fs::File, path: &Path, pos: u64, len: u64) -> Result<Vec<u8>, IoError> {
    f.seek(SeekFrom::Start(pos))
        .map_err(|e| IoError::io(path, e))?;
    let mut b = vec![0; len as usize];
    f.read_exact(&mut b).map_err(|e| IoError::io(path, e))?;
    Ok(b)
}

/// The record framed at `pos`: (opcode, body length), or `None` when its frame or body does
/// not fit before `end`.
fn frame_at(
    f: &mut std::fs::File,
    path: &Path,
    pos: u64,
    end: u64,
) -> Result<Option<(u8, u64)>, IoError> {
    if pos + FRAME > end {
        return Ok(None);
    }
    let h = read_at(f, path, pos, FRAME)?;
    let mut len = [0u8; 8];
    len.copy_from_slice(&h[1..9]);
    let len = u64::from_le_bytes(len);
    if len > end - pos - FRAME {
        return Ok(None);
    }
    Ok(Some((h[0], len)))
}

fn ns(t: u64) -> i64 {
    i64::try_from(t).unwrap_or(i64::MAX)
}

/// Whether the file ends with the MCAP magic.
fn ends_with_magic(f: &mut std::fs::File, path: &Path, file_len: u64) -> Result<bool, IoError> {
    let n = mcap::MAGIC.len() as u64;
    Ok(file_len >= 2 * n && read_at(f, path, file_len - n, n)? == mcap::MAGIC)
}

/// The time range of a part, for people.
fn span_text(start_ns: i64, end_ns: i64) -> String {
    format!(
        "log time {:.3} .. {:.3} s",
        start_ns as f64 * 1e-9,
        end_ns as f64 * 1e-9
    )
}

impl McapLog {
    /// Opens the MCAP file at `path` (see the module docs). A file that is not MCAP, or that
    /// cannot be read at all, is an error; damage past the header is a warning.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let mut f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        let file_len = f.metadata().map_err(|e| IoError::io(path, e))?.len();
        let magic = mcap::MAGIC;
        if file_len < magic.len() as u64 || read_at(&mut f, path, 0, magic.len() as u64)? != magic {
            return Err(corrupt(path, "MCAP magic", 0, "not an MCAP file"));
        }
        let mut log = McapLog {
            path: path.to_path_buf(),
            file_len,
            channels: BTreeMap::new(),
            counts: BTreeMap::new(),
            spans: BTreeMap::new(),
            parts: Vec::new(),
            from_summary: false,
            chunks: 0,
            metadata: Vec::new(),
            warnings: Vec::new(),
        };
        match log.read_summary(&mut f) {
            Ok(true) => log.from_summary = true,
            Ok(false) => {
                if !ends_with_magic(&mut f, path, file_len)? {
                    log.warnings.push(format!(
                        "{}: no footer at the end (a cut file, or a recorder that was \
                         stopped): the file was scanned",
                        path.display()
                    ));
                }
                log.scan(&mut f)?
            }
            Err(e) => {
                log.warnings.push(format!(
                    "summary section not usable ({e}): the file was scanned"
                ));
                log.channels.clear();
                log.counts.clear();
                log.parts.clear();
                log.metadata.clear();
                log.scan(&mut f)?;
            }
        }
        Ok(log)
    }

    /// The names of the file's metadata records.
    pub fn metadata_names(&self) -> &[String] {
        &self.metadata
    }

    fn add_channel(&mut self, c: &mcap::records::Channel, schemas: &BTreeMap<u16, String>) {
        let name = schemas.get(&c.schema_id).cloned().unwrap_or_default();
        let encoding = match c.message_encoding.as_str() {
            "ros1" => Some(Encoding::Ros1),
            "cdr" => Some(Encoding::Cdr),
            _ => None,
        };
        let msg_type = match encoding {
            Some(_) => normalize_type(&name),
            None => format!(
                "{} ({} encoding, not read)",
                normalize_type(&name),
                c.message_encoding
            ),
        };
        self.channels.insert(
            c.id,
            Channel {
                topic: c.topic.clone(),
                msg_type,
                encoding,
            },
        );
    }

    /// Reads the summary section; `Ok(false)` when there is none or it lacks what a stream
    /// needs (statistics, a chunk index per chunk), so the file must be scanned.
    fn read_summary(&mut self, f: &mut std::fs::File) -> Result<bool, IoError> {
        let path = self.path.clone();
        let Some((summary_start, footer_pos)) = summary_range(f, &path, self.file_len)? else {
            return Ok(false);
        };
        let mut schemas = BTreeMap::new();
        let mut stats = None;
        let mut chunk_parts = Vec::new();
        let mut pos = summary_start;
        while pos < footer_pos {
            let Some((opcode, len)) = frame_at(f, &path, pos, footer_pos)? else {
                return Err(corrupt(
                    &path,
                    "summary record",
                    pos,
                    "runs past the footer",
                ));
            };
            if matches!(
                opcode,
                op::SCHEMA | op::CHANNEL | op::STATISTICS | op::CHUNK_INDEX | op::METADATA_INDEX
            ) {
                let body = read_at(f, &path, pos + FRAME, len)?;
                let rec = crate::mcap_record::parse_record(opcode, &body)
                    .map_err(|e| corrupt(&path, "summary record", pos, e.to_string()))?;
                match rec {
                    Record::Schema { header, .. } => {
                        schemas.insert(header.id, header.name);
                    }
                    Record::Channel(c) => self.add_channel(&c, &schemas),
                    Record::Statistics(s) => stats = Some(s),
                    Record::ChunkIndex(ci) => chunk_parts.push(Part {
                        pos: ci.chunk_start_offset,
                        len: ci.chunk_length,
                        start_ns: ns(ci.message_start_time),
                        end_ns: ns(ci.message_end_time),
                        // No message index: which channels it holds is known once read.
                        channels: (!ci.message_index_offsets.is_empty())
                            .then(|| ci.message_index_offsets.keys().copied().collect()),
                    }),
                    Record::MetadataIndex(m) => self.metadata.push(m.name),
                    _ => {}
                }
            }
            pos += FRAME + len;
        }
        let Some(stats) = stats else {
            return Ok(false);
        };
        let complete = stats.chunk_count as usize == chunk_parts.len()
            && (stats.chunk_count > 0 || stats.message_count == 0)
            && stats
                .channel_message_counts
                .keys()
                .all(|id| self.channels.contains_key(id));
        if !complete {
            return Ok(false);
        }
        self.counts = stats.channel_message_counts;
        self.chunks = chunk_parts.len();
        for p in &chunk_parts {
            for id in p.channels.iter().flatten() {
                let s = self.spans.entry(*id).or_insert((p.start_ns, p.end_ns));
                *s = (s.0.min(p.start_ns), s.1.max(p.end_ns));
            }
        }
        self.parts = chunk_parts;
        Ok(true)
    }

    /// Walks the data section's records once (see the module docs).
    fn scan(&mut self, f: &mut std::fs::File) -> Result<(), IoError> {
        let path = self.path.clone();
        let mut schemas = BTreeMap::new();
        let mut pos = mcap::MAGIC.len() as u64;
        // The run of message records outside chunks being gathered.
        let mut loose: Option<Part> = None;
        let flush = |loose: &mut Option<Part>, parts: &mut Vec<Part>| {
            if let Some(p) = loose.take() {
                parts.push(p);
            }
        };
        loop {
            let frame = frame_at(f, &path, pos, self.file_len)?;
            let Some((opcode, len)) = frame else {
                if pos < self.file_len {
                    self.warnings.push(format!(
                        "{}: file cut at byte {} inside the record at byte offset {pos}: the \
                         last {} bytes were lost (read up to the last complete record)",
                        path.display(),
                        self.file_len,
                        self.file_len - pos
                    ));
                }
                break;
            };
            if len > MAX_RECORD_BYTES {
                self.warnings.push(format!(
                    "{}: record at byte offset {pos} claims {len} bytes (more than \
                     {MAX_RECORD_BYTES}): the file is not read past it",
                    path.display()
                ));
                break;
            }
            if opcode == op::DATA_END || opcode == op::FOOTER {
                break;
            }
            if opcode != op::MESSAGE {
                flush(&mut loose, &mut self.parts);
            }
            match opcode {
                op::SCHEMA | op::CHANNEL | op::MESSAGE | op::METADATA | op::CHUNK => {
                    let body = read_at(f, &path, pos + FRAME, len)?;
                    self.scan_record(pos, opcode, &body, &mut schemas, &mut loose);
                }
                _ => {}
            }
            if loose.as_ref().is_some_and(|p| p.len >= LOOSE_RUN_BYTES) {
                flush(&mut loose, &mut self.parts);
            }
            pos += FRAME + len;
        }
        flush(&mut loose, &mut self.parts);
        Ok(())
    }

    /// One record of the walk.
    fn scan_record(
        &mut self,
        pos: u64,
        opcode: u8,
        body: &[u8],
        schemas: &mut BTreeMap<u16, String>,
        loose: &mut Option<Part>,
    ) {
        let rec = match crate::mcap_record::parse_record(opcode, body) {
            Ok(r) => r,
            Err(e) => {
                self.warnings.push(format!(
                    "{}: record (opcode {opcode:#04x}) at byte offset {pos} does not parse: \
                     {e}; skipped",
                    self.path.display()
                ));
                return;
            }
        };
        match rec {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => self.add_channel(&c, schemas),
            Record::Metadata(m) => self.metadata.push(m.name),
            Record::Message { header, .. } => {
                let t = ns(header.log_time);
                self.count(header.channel_id, t);
                let p = loose.get_or_insert(Part {
                    pos,
                    len: 0,
                    start_ns: t,
                    end_ns: t,
                    channels: Some(Vec::new()),
                });
                p.len = pos + FRAME + body.len() as u64 - p.pos;
                p.start_ns = p.start_ns.min(t);
                p.end_ns = p.end_ns.max(t);
                if let Some(ch) = p.channels.as_mut() {
                    if !ch.contains(&header.channel_id) {
                        ch.push(header.channel_id);
                    }
                }
            }
            Record::Chunk { header, .. } => {
                self.chunks += 1;
                let (start_ns, end_ns) =
                    (ns(header.message_start_time), ns(header.message_end_time));
                let mut part = Part {
                    pos,
                    len: FRAME + body.len() as u64,
                    start_ns,
                    end_ns,
                    channels: Some(Vec::new()),
                };
                match stream::chunk_records(body) {
                    Ok(recs) => {
                        let mut seen = Vec::new();
                        for r in recs {
                            match r {
                                Record::Schema { header, .. } => {
                                    schemas.insert(header.id, header.name);
                                }
                                Record::Channel(c) => self.add_channel(&c, schemas),
                                Record::Message { header, .. } => {
                                    self.count(header.channel_id, ns(header.log_time));
                                    if !seen.contains(&header.channel_id) {
                                        seen.push(header.channel_id);
                                    }
                                }
                                _ => {}
                            }
                        }
                        part.channels = Some(seen);
                    }
                    Err(e) => {
                        self.warnings.push(format!(
                            "{}: chunk at byte offset {pos} ({}) is corrupt ({e}): its \
                             messages are skipped",
                            self.path.display(),
                            span_text(start_ns, end_ns)
                        ));
                        part.channels = None;
                    }
                }
                self.parts.push(part);
            }
            _ => {}
        }
    }

    fn count(&mut self, channel: u16, t: i64) {
        *self.counts.entry(channel).or_insert(0) += 1;
        let s = self.spans.entry(channel).or_insert((t, t));
        *s = (s.0.min(t), s.1.max(t));
    }

    /// The channels of `topic` that a run can read.
    fn topic_channels(&self, topic: &str) -> Vec<(u16, Option<Encoding>)> {
        self.channels
            .iter()
            .filter(|(_, c)| c.topic == topic)
            .map(|(id, c)| (*id, c.encoding))
            .collect()
    }
}

impl MessageLog for McapLog {
    fn path(&self) -> &Path {
        &self.path
    }

    fn describe(&self) -> String {
        let how = if self.from_summary {
            "with summary"
        } else {
            "no usable summary: scanned"
        };
        format!(
            "MCAP, {how}, {} chunks, {} channels",
            self.chunks,
            self.channels.len()
        )
    }

    fn topics(&self) -> Vec<TopicInfo> {
        let mut out: Vec<TopicInfo> = Vec::new();
        for (id, c) in &self.channels {
            let n = self.counts.get(id).copied().unwrap_or(0);
            let span = self.spans.get(id).copied();
            match out
                .iter_mut()
                .find(|t| t.topic == c.topic && t.msg_type == c.msg_type)
            {
                Some(t) => {
                    t.count += n;
                    t.span_ns = match (t.span_ns, span) {
                        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
                        (a, b) => a.or(b),
                    };
                }
                None => out.push(TopicInfo {
                    topic: c.topic.clone(),
                    msg_type: c.msg_type.clone(),
                    encoding: c.encoding.unwrap_or(Encoding::Cdr),
                    count: n,
                    span_ns: span,
                }),
            }
        }
        out.sort_by(|a, b| (&a.topic, &a.msg_type).cmp(&(&b.topic, &b.msg_type)));
        out
    }

    fn messages(&self, topic: &str) -> LogStream<'_> {
        let channels: Vec<u16> = self
            .topic_channels(topic)
            .into_iter()
            .filter_map(|(id, enc)| enc.map(|_| id))
            .collect();
        Box::new(stream::messages(self, channels))
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }
}

/// Whether the MCAP file at `path` holds a metadata record named `name`: read from the
/// summary's metadata index when there is one, otherwise by walking the file's records without
/// decompressing chunks. A file that cannot be read holds none.
pub fn has_metadata(path: &Path, name: &str) -> bool {
    metadata_names(path).is_ok_and(|names| names.iter().any(|m| m == name))
}

fn metadata_names(path: &Path) -> Result<Vec<String>, IoError> {
    let mut f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let file_len = f.metadata().map_err(|e| IoError::io(path, e))?.len();
    let (start, end, wanted) = match summary_range(&mut f, path, file_len)? {
        Some((s, e)) => (s, e, op::METADATA_INDEX),
        None => (mcap::MAGIC.len() as u64, file_len, op::METADATA),
    };
    let mut names = Vec::new();
    let mut pos = start;
    while let Some((opcode, len)) = frame_at(&mut f, path, pos, end)? {
        if opcode == wanted && len <= MAX_RECORD_BYTES {
            let body = read_at(&mut f, path, pos + FRAME, len)?;
            match crate::mcap_record::parse_record(opcode, &body) {
                Ok(Record::Metadata(m)) => names.push(m.name),
                Ok(Record::MetadataIndex(m)) => names.push(m.name),
                _ => {}
            }
        }
        if opcode == op::DATA_END || opcode == op::FOOTER {
            break;
        }
        pos += FRAME + len;
    }
    Ok(names)
}

/// The summary section's byte range (from its start to the footer), when the file ends with a
/// footer that points at one.
fn summary_range(
    f: &mut std::fs::File,
    path: &Path,
    file_len: u64,
) -> Result<Option<(u64, u64)>, IoError> {
    let footer_len = FRAME + 20 + mcap::MAGIC.len() as u64;
    if file_len < 8 + footer_len {
        return Ok(None);
    }
    let footer_pos = file_len - footer_len;
    let tail = read_at(f, path, footer_pos, footer_len)?;
    if tail[0] != op::FOOTER || tail[FRAME as usize + 20..] != *mcap::MAGIC {
        return Ok(None);
    }
    match crate::mcap_record::parse_record(op::FOOTER, &tail[FRAME as usize..][..20]) {
        Ok(Record::Footer(ft)) if ft.summary_start >= 8 && ft.summary_start <= footer_pos => {
            Ok(Some((ft.summary_start, footer_pos)))
        }
        Ok(Record::Footer(ft)) if ft.summary_start == 0 => Ok(None),
        Ok(Record::Footer(ft)) => Err(corrupt(
            path,
            "MCAP footer",
            footer_pos,
            format!("summary start {} outside the file", ft.summary_start),
        )),
        _ => Ok(None),
    }
}

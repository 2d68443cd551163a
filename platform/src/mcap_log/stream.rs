//! A topic's messages across the parts (chunks, runs of loose messages) that hold it, in
//! log-time order.
//!
//! Parts are taken in order of their start time (from the chunk index, or from the walk; ties by
//! file position) and merged by [`crate::rosrec::parts`]: messages come out in log-time order
//! (ties: part order, then order in the part) even when chunks overlap in time or were written
//! out of order. Only the wanted channels' messages of the parts read and not yet emitted are
//! held, and at most [`crate::rosrec::parts::WINDOW_PARTS`] parts at once.

use super::{corrupt, read_at, span_text, McapLog, Part, FRAME};
use crate::error::IoError;
use crate::rosrec::parts::{PartLoader, PartMerge};
use crate::rosrec::LogMessage;
use mcap::records::{op, Record};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// Largest decompressed chunk accepted, bytes.
pub const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// The records of the chunk record whose body is `body`, decompressed and CRC-checked (the
/// check ends the chunk, so a chunk is used whole or not at all). No record inside, and not the
/// chunk decompressed, may claim more than [`MAX_CHUNK_BYTES`] (a corrupt length field: the
/// decoder would reserve it).
pub(super) fn chunk_records(body: &[u8]) -> Result<Vec<Record<'static>>, String> {
    let Record::Chunk { header, data } =
        crate::mcap_record::parse_record(op::CHUNK, body).map_err(|e| e.to_string())?
    else {
        return Err("not a chunk".into());
    };
    let size = header.uncompressed_size;
    if size > MAX_CHUNK_BYTES || (header.compression.is_empty() && size != data.len() as u64) {
        return Err(format!(
            "chunk header claims {size} bytes decompressed ({} bytes stored, compression {:?})",
            data.len(),
            header.compression
        ));
    }
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(MAX_CHUNK_BYTES as usize),
    );
    let mut frame = vec![op::CHUNK];
    frame.extend((body.len() as u64).to_le_bytes());
    let mut inputs = [&frame[..], body];
    let mut out = Vec::new();
    while let Some(ev) = reader.next_event() {
        match ev.map_err(|e| e.to_string())? {
            LinearReadEvent::ReadRequest(need) => {
                let input = inputs.iter_mut().find(|i| !i.is_empty());
                let n = input.as_ref().map_or(0, |i| need.min(i.len()));
                if let Some(input) = input {
                    reader.insert(n).copy_from_slice(&input[..n]);
                    *input = &input[n..];
                }
                reader.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => out.push(
                crate::mcap_record::parse_record(opcode, data)
                    .map_err(|e| e.to_string())?
                    .into_owned(),
            ),
        }
    }
    Ok(out)
}

/// One topic's stream: the merge of [`crate::rosrec::parts`] over the parts holding it.
pub(super) type Messages<'a> = PartMerge<PartReader<'a>>;

/// The merge over the channels `channels` of `log` (see [`Messages`]).
pub(super) fn messages(log: &McapLog, channels: Vec<u16>) -> Messages<'_> {
    let mut order: Vec<&Part> = if channels.is_empty() {
        Vec::new()
    } else {
        log.parts
            .iter()
            .filter(|p| {
                p.channels
                    .as_ref()
                    .is_none_or(|c| c.iter().any(|id| channels.contains(id)))
            })
            .collect()
    };
    order.sort_by_key(|p| (p.start_ns, p.pos));
    let starts = order.iter().map(|p| p.start_ns).collect();
    let reader = PartReader {
        log,
        file: None,
        channels,
        order,
    };
    PartMerge::new(reader, starts)
}

/// Reads the parts of a [`Messages`] merge, keeping the wanted channels' messages, on its own
/// file handle.
pub(super) struct PartReader<'a> {
    log: &'a McapLog,
    file: Option<std::fs::File>,
    channels: Vec<u16>,
    /// Parts that may hold wanted messages, by start time.
    order: Vec<&'a Part>,
}

impl PartLoader for PartReader<'_> {
    type Msg = LogMessage;

    /// The wanted messages of part `k`.
    fn load(&mut self, k: usize) -> Result<Vec<LogMessage>, IoError> {
        let Some(&p) = self.order.get(k) else {
            return Ok(Vec::new());
        };
        let path = &self.log.path;
        let what = format!("MCAP chunk ({})", span_text(p.start_ns, p.end_ns));
        if p.pos
            .checked_add(p.len)
            .is_none_or(|e| e > self.log.file_len)
        {
            return Err(corrupt(path, &what, p.pos, "runs past the end of the file"));
        }
        if self.file.is_none() {
            self.file = Some(std::fs::File::open(path).map_err(|e| IoError::io(path, e))?);
        }
        let Some(f) = self.file.as_mut() else {
            return Ok(Vec::new());
        };
        let bytes = read_at(f, path, p.pos, p.len)?;
        let mut out = Vec::new();
        let mut at = 0usize;
        while at < bytes.len() {
            let pos = p.pos + at as u64;
            let bad = |msg: String| corrupt(path, &what, pos, msg);
            if bytes.len() - at < FRAME as usize {
                return Err(bad("record frame cut".into()));
            }
            let opcode = bytes[at];
            let mut len = [0u8; 8];
            len.copy_from_slice(&bytes[at + 1..at + 9]);
            let len = u64::from_le_bytes(len);
            let body_at = at + FRAME as usize;
            if len > (bytes.len() - body_at) as u64 {
                return Err(bad(format!("record of {len} bytes runs past its part")));
            }
            let body = &bytes[body_at..body_at + len as usize];
            at = body_at + len as usize;
            if opcode != op::CHUNK && opcode != op::MESSAGE {
                continue;
            }
            let recs = if opcode == op::CHUNK {
                chunk_records(body).map_err(bad)?
            } else {
                vec![crate::mcap_record::parse_record(opcode, body)
                    .map_err(|e| bad(e.to_string()))?
                    .into_owned()]
            };
            for r in recs {
                if let Record::Message { header, data } = r {
                    if self.channels.contains(&header.channel_id) {
                        out.push(LogMessage {
                            log_time_ns: super::ns(header.log_time),
                            offset: pos,
                            data: data.into_owned(),
                        });
                    }
                }
            }
        }
        Ok(out)
    }

    fn time_ns(m: &LogMessage) -> i64 {
        m.log_time_ns
    }
}

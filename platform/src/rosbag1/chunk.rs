//! Chunks: reading one (decompressed: `none`, `bz2`, `lz4` frames), listing its messages, and
//! the time-ordered merge of the messages of some connections across chunks ([`Messages`]).
//!
//! ## Merge
//! Chunks are taken in order of their start time (from the index, or from the scan of an
//! unindexed bag; ties by file position) and merged by [`crate::rosrec::parts`]: messages come
//! out in receipt-time order (ties: file position, then order in the chunk) even when chunks
//! overlap or are written out of order. Only the wanted connections' messages are kept, and only
//! of the chunks read so far and not yet emitted; at most [`WINDOW_CHUNKS`] chunks are held at
//! once.

use super::record::{buf_record, file_record, read_at, RecordError, OP_CHUNK, OP_MESSAGE};
use super::{Bag, ChunkInfo};
use crate::error::IoError;
use crate::rosrec::parts::{PartLoader, PartMerge};
use std::collections::HashSet;
use std::io::Read;

/// Chunks held by a merge at once.
pub use crate::rosrec::parts::WINDOW_PARTS as WINDOW_CHUNKS;

/// A walk that read less than 1 / `SPARSE_SHARE` of its last chunk's bytes (a topic of small
/// messages sharing chunks with images) reads its file without read-ahead ([`advise`]).
pub const SPARSE_SHARE: u64 = 4;

/// Largest decompressed chunk accepted, bytes.
pub const MAX_CHUNK_BYTES: u32 = 1 << 30;

/// A chunk's records, decompressed.
#[derive(Debug)]
pub struct ChunkData {
    /// Offset of the chunk record in the file.
    pub pos: u64,
    /// The decompressed records.
    pub bytes: Vec<u8>,
    /// Bytes lost when the chunk was cut (the header's `size` minus what could be recovered).
    pub lost: u64,
    /// Bytes of the chunk's data skipped over in the file, never read (a sparse read).
    pub skipped: u64,
}

/// Reads and decompresses the chunk at `pos`; `allow_cut` recovers the part of a chunk that a
/// truncation cut (what decompresses before the cut), otherwise a cut chunk is an error.
pub fn read_chunk(
    f: &mut std::fs::File,
    pos: u64,
    file_len: u64,
    allow_cut: bool,
) -> Result<ChunkData, RecordError> {
    read_chunk_of(f, pos, file_len, allow_cut, None)
}

/// [`read_chunk`], keeping of an uncompressed, whole chunk only the message records whose
/// connection `keep` wants (and every other record): the others' data are skipped over in the
/// file, never read, so a topic of small messages sharing chunks with images costs its own
/// bytes. The records kept are laid end to end as in a chunk (offsets inside it then differ
/// from the file's chunk). Compressed or cut chunks are read whole.
pub fn read_chunk_of(
    f: &mut std::fs::File,
    pos: u64,
    file_len: u64,
    allow_cut: bool,
    keep: Option<&dyn Fn(u32) -> bool>,
) -> Result<ChunkData, RecordError> {
    let rec = match file_record(f, pos, file_len) {
        Ok(Some(r)) => r,
        Ok(None) => {
            return Err(RecordError::Truncated {
                offset: pos,
                msg: "chunk past the end of the file".into(),
            })
        }
        Err(RecordError::Truncated { .. }) if allow_cut => cut_record(f, pos, file_len)?,
        Err(e) => return Err(e),
    };
    let op = rec.fields.op()?;
    if op != OP_CHUNK {
        return Err(RecordError::Corrupt {
            offset: pos,
            msg: format!("record op {op:#04x} where the index puts a chunk"),
        });
    }
    let size = rec.fields.u32("size")?;
    if size > MAX_CHUNK_BYTES {
        return Err(RecordError::Corrupt {
            offset: pos,
            msg: format!("chunk of {size} bytes (more than {MAX_CHUNK_BYTES})"),
        });
    }
    let compression = rec.fields.string("compression")?;
    let avail = (file_len - rec.data_offset).min(u64::from(rec.data_len)) as usize;
    let cut = avail < rec.data_len as usize;
    if let (Some(keep), "none", false) = (keep, compression.as_str(), cut) {
        if size == rec.data_len {
            let bytes = sparse_records(f, rec.data_offset, rec.data_len, keep)?;
            return Ok(ChunkData {
                pos,
                skipped: u64::from(rec.data_len).saturating_sub(bytes.len() as u64),
                bytes,
                lost: 0,
            });
        }
    }
    let raw = read_at(f, rec.data_offset, avail)?;
    // The header's size is only a hint until the data decompresses to it.
    let mut out = Vec::with_capacity((size as usize).min(64 << 20));
    let res = match compression.as_str() {
        "none" => {
            out = raw;
            Ok(())
        }
        "bz2" => bzip2::read::BzDecoder::new(&raw[..])
            .take(u64::from(size))
            .read_to_end(&mut out)
            .map(drop),
        "lz4" => lz4::Decoder::new(&raw[..])
            .and_then(|d| d.take(u64::from(size)).read_to_end(&mut out).map(drop)),
        other => {
            return Err(RecordError::Corrupt {
                offset: pos,
                msg: format!("unknown chunk compression {other:?} (expected none, bz2 or lz4)"),
            })
        }
    };
    if let Err(e) = res {
        if !cut {
            return Err(RecordError::Corrupt {
                offset: rec.data_offset,
                msg: format!("{compression} chunk does not decompress: {e}"),
            });
        }
    }
    if out.len() != size as usize && !cut {
        return Err(RecordError::Corrupt {
            offset: pos,
            msg: format!(
                "{compression} chunk decompresses to {} bytes, its header says {size}",
                out.len()
            ),
        });
    }
    let lost = u64::from(size).saturating_sub(out.len() as u64);
    Ok(ChunkData {
        pos,
        bytes: out,
        lost,
        skipped: 0,
    })
}

/// The records of the uncompressed chunk data at `start` (`len` bytes), message records of
/// connections `keep` does not want left out without reading their data.
fn sparse_records(
    f: &mut std::fs::File,
    start: u64,
    len: u32,
    keep: &dyn Fn(u32) -> bool,
) -> Result<Vec<u8>, RecordError> {
    let end = start + u64::from(len);
    let mut out = Vec::new();
    let mut at = start;
    let u32_at = |f: &mut std::fs::File, p: u64| -> Result<u32, RecordError> {
        let b = read_at(f, p, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let over = |p: u64, what: &str| RecordError::Corrupt {
        offset: p,
        msg: format!("{what} runs past the end of its chunk"),
    };
    while at < end {
        if at + 4 > end {
            return Err(over(at, "record header length"));
        }
        let header_len = u64::from(u32_at(f, at)?);
        if at + 4 + header_len + 4 > end {
            return Err(over(at, "record header"));
        }
        let header = read_at(f, at + 4, header_len as usize)?;
        let data_len = u64::from(u32_at(f, at + 4 + header_len)?);
        let data_at = at + 4 + header_len + 4;
        if data_at + data_len > end {
            return Err(over(at, "record data"));
        }
        let fields = super::record::Fields::parse(&header, at + 4)?;
        let wanted = fields.op()? != OP_MESSAGE || keep(fields.u32("conn")?);
        if wanted {
            out.extend_from_slice(&(header_len as u32).to_le_bytes());
            out.extend_from_slice(&header);
            out.extend_from_slice(&(data_len as u32).to_le_bytes());
            out.extend_from_slice(&read_at(f, data_at, data_len as usize)?);
        }
        at = data_at + data_len;
    }
    Ok(out)
}

/// The header of a record whose data is cut (its header must be complete; the declared data
/// length is kept).
fn cut_record(
    f: &mut std::fs::File,
    pos: u64,
    file_len: u64,
) -> Result<super::record::FileRecord, RecordError> {
    // Re-read with a pretend length that covers the declared data.
    let probe = file_record(f, pos, u64::MAX)?.ok_or_else(|| RecordError::Truncated {
        offset: pos,
        msg: "empty".into(),
    })?;
    if probe.data_offset > file_len {
        return Err(RecordError::Truncated {
            offset: pos,
            msg: "chunk header cut".into(),
        });
    }
    Ok(probe)
}

/// Tells the kernel how the walk on `f` reads: `random` (a sparse walk, record by record with
/// the other topics' data skipped: no read-ahead, which would pull the skipped pages from disk
/// anyway) or sequential (a walk reading its chunks whole). A hint: when it fails, the default
/// read-ahead stays.
fn advise(f: &std::fs::File, random: bool) {
    use std::os::fd::AsRawFd;
    let advice = if random {
        libc::POSIX_FADV_RANDOM
    } else {
        libc::POSIX_FADV_SEQUENTIAL
    };
    // SAFETY: posix_fadvise takes a descriptor `f` owns (open for the call) and integers; it
    // touches no memory of ours.
    let _ = unsafe { libc::posix_fadvise(f.as_raw_fd(), 0, 0, advice) };
}

/// One message record of a chunk.
#[derive(Debug, Clone, PartialEq)]
pub struct RawMessage {
    /// Connection id.
    pub conn: u32,
    /// Receipt time (the record's `time`), ns.
    pub time_ns: i64,
    /// File offset of the chunk holding it.
    pub chunk_pos: u64,
    /// Offset of the record inside the decompressed chunk.
    pub offset_in_chunk: u64,
    /// The serialized message.
    pub data: Vec<u8>,
}

/// Walks the records of a decompressed chunk: messages (kept when `keep(conn)`) and
/// connections (given to `on_conn`). A record cut at the chunk's end stops the walk when the
/// chunk was cut (`lost > 0`), otherwise it is an error.
pub fn walk_chunk(
    chunk: &ChunkData,
    mut keep: impl FnMut(u32) -> bool,
    mut on_conn: impl FnMut(super::record::Fields, &[u8]) -> Result<(), RecordError>,
) -> Result<Vec<RawMessage>, RecordError> {
    let mut out = Vec::new();
    let mut pos = 0;
    loop {
        let (rec, next) = match buf_record(&chunk.bytes, pos, 0) {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(RecordError::Truncated { .. }) if chunk.lost > 0 => break,
            Err(e) => {
                return Err(RecordError::Corrupt {
                    offset: chunk.pos,
                    msg: format!("in the chunk, at byte {}: {}", e.offset(), e.msg()),
                })
            }
        };
        let in_chunk = |e: RecordError| RecordError::Corrupt {
            offset: chunk.pos,
            msg: format!("in the chunk, at byte {}: {}", e.offset(), e.msg()),
        };
        match rec.fields.op().map_err(in_chunk)? {
            OP_MESSAGE => {
                let conn = rec.fields.u32("conn").map_err(in_chunk)?;
                if keep(conn) {
                    out.push(RawMessage {
                        conn,
                        time_ns: rec.fields.time_ns("time").map_err(in_chunk)?,
                        chunk_pos: chunk.pos,
                        offset_in_chunk: pos as u64,
                        data: chunk.bytes[rec.data.clone()].to_vec(),
                    });
                }
            }
            super::record::OP_CONNECTION => {
                on_conn(rec.fields, &chunk.bytes[rec.data.clone()]).map_err(in_chunk)?
            }
            _ => {}
        }
        pos = next;
    }
    Ok(out)
}

/// The messages of some connections in receipt-time order across chunks: the merge of
/// [`crate::rosrec::parts`] over the chunks holding them. A chunk that cannot be read is an
/// `Err` item naming the file and its offset; the iteration goes on with the next chunk.
pub type Messages<'a> = PartMerge<ChunkLoader<'a>>;

/// The merge over the connections `conns` of `bag` (see [`Messages`]).
pub fn messages(bag: &Bag, conns: HashSet<u32>) -> Messages<'_> {
    let mut order: Vec<&ChunkInfo> = bag
        .chunks
        .iter()
        .filter(|c| c.counts.iter().any(|(id, n)| *n > 0 && conns.contains(id)))
        .collect();
    order.sort_by_key(|c| (c.start_ns, c.pos));
    let starts = order.iter().map(|c| c.start_ns).collect();
    let loader = ChunkLoader {
        bag,
        file: None,
        conns,
        order,
        random: false,
    };
    PartMerge::new(loader, starts)
}

/// Reads the chunks of a [`Messages`] merge, keeping the wanted connections' messages, on its
/// own file handle.
pub struct ChunkLoader<'a> {
    bag: &'a Bag,
    file: Option<std::fs::File>,
    conns: HashSet<u32>,
    /// Chunks with wanted messages, by start time.
    order: Vec<&'a ChunkInfo>,
    /// The file handle is read without read-ahead (see [`advise`]).
    random: bool,
}

impl ChunkLoader<'_> {
    /// The walk reads its file without read-ahead (its last chunk was read sparsely).
    pub fn is_random(&self) -> bool {
        self.random
    }
}

impl PartLoader for ChunkLoader<'_> {
    type Msg = RawMessage;

    fn load(&mut self, k: usize) -> Result<Vec<RawMessage>, IoError> {
        let Some(&info) = self.order.get(k) else {
            return Ok(Vec::new());
        };
        if self.file.is_none() {
            let f =
                std::fs::File::open(&self.bag.path).map_err(|e| IoError::io(&self.bag.path, e))?;
            advise(&f, false);
            self.file = Some(f);
        }
        let Some(f) = self.file.as_mut() else {
            return Ok(Vec::new());
        };
        let err = |e: RecordError| self.bag.error("chunk", e);
        let conns = &self.conns;
        let keep = |c: u32| conns.contains(&c);
        let chunk =
            read_chunk_of(f, info.pos, self.bag.file_len, info.cut, Some(&keep)).map_err(err)?;
        let sparse = chunk.skipped > 0
            && chunk.bytes.len() as u64 * SPARSE_SHARE < chunk.bytes.len() as u64 + chunk.skipped;
        if sparse != self.random {
            advise(f, sparse);
            self.random = sparse;
        }
        walk_chunk(&chunk, |c| conns.contains(&c), |_, _| Ok(())).map_err(err)
    }

    fn time_ns(m: &RawMessage) -> i64 {
        m.time_ns
    }
}

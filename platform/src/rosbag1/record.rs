//! The record layer of a ROS 1 bag: `header_len: u32`, the header (fields `field_len: u32` then
//! `name=value`), `data_len: u32`, the data. Every read is bounds-checked against the bytes that
//! exist; a record that runs past them is [`RecordError::Truncated`], anything else malformed is
//! [`RecordError::Corrupt`], both with the byte offset where the problem is.

use std::io::{Read, Seek, SeekFrom};

/// Opcodes of the records (the `op` header field).
pub const OP_MESSAGE: u8 = 0x02;
/// Bag header record.
pub const OP_BAG_HEADER: u8 = 0x03;
/// Index data record (message times and offsets of one connection in one chunk).
pub const OP_INDEX_DATA: u8 = 0x04;
/// Chunk record (compressed messages and connections).
pub const OP_CHUNK: u8 = 0x05;
/// Chunk info record (a chunk's position, time range and per-connection counts).
pub const OP_CHUNK_INFO: u8 = 0x06;
/// Connection record (topic, type, md5sum, definition).
pub const OP_CONNECTION: u8 = 0x07;

/// Largest record header accepted (message definitions are a few tens of kB).
pub const MAX_HEADER_BYTES: u32 = 16 << 20;

/// A record that could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RecordError {
    /// The record runs past the end of the bytes that exist (a cut file or chunk).
    Truncated {
        /// Offset of the record's start.
        offset: u64,
        /// What was missing.
        msg: String,
    },
    /// The bytes are not a valid record.
    Corrupt {
        /// Offset of the problem.
        offset: u64,
        /// What was wrong.
        msg: String,
    },
}

impl RecordError {
    /// The offset the error names.
    pub fn offset(&self) -> u64 {
        match self {
            RecordError::Truncated { offset, .. } | RecordError::Corrupt { offset, .. } => *offset,
        }
    }

    /// What was wrong.
    pub fn msg(&self) -> &str {
        match self {
            RecordError::Truncated { msg, .. } | RecordError::Corrupt { msg, .. } => msg,
        }
    }
}

fn corrupt(offset: u64, msg: impl Into<String>) -> RecordError {
    RecordError::Corrupt {
        offset,
        msg: msg.into(),
    }
}

/// The parsed header fields of one record (`name`, raw value), in file order.
#[derive(Debug, Clone, Default)]
pub struct Fields {
    fields: Vec<(String, Vec<u8>)>,
    /// Offset of the header's first byte (for errors).
    pub offset: u64,
}

impl Fields {
    /// Parses a header block that starts at file (or chunk) offset `offset`.
    pub fn parse(bytes: &[u8], offset: u64) -> Result<Self, RecordError> {
        let mut fields = Vec::new();
        let mut pos = 0usize;
        while pos < bytes.len() {
            let at = offset + pos as u64;
            let len = le_u32(bytes, pos).ok_or_else(|| corrupt(at, "header field length cut"))?;
            let start = pos + 4;
            let end = start
                .checked_add(len as usize)
                .filter(|&e| e <= bytes.len())
                .ok_or_else(|| {
                    corrupt(
                        at,
                        format!("header field of {len} bytes overruns the header"),
                    )
                })?;
            let field = &bytes[start..end];
            let eq = field
                .iter()
                .position(|&b| b == b'=')
                .ok_or_else(|| corrupt(at, "header field without '='"))?;
            let name = String::from_utf8_lossy(&field[..eq]).into_owned();
            fields.push((name, field[eq + 1..].to_vec()));
            pos = end;
        }
        Ok(Fields { fields, offset })
    }

    /// The raw value of field `name`, when present.
    pub fn get(&self, name: &str) -> Option<&[u8]> {
        self.fields
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }

    fn need(&self, name: &str) -> Result<&[u8], RecordError> {
        self.get(name)
            .ok_or_else(|| corrupt(self.offset, format!("header has no {name:?} field")))
    }

    fn fixed<const N: usize>(&self, name: &str) -> Result<[u8; N], RecordError> {
        let v = self.need(name)?;
        v.try_into().map_err(|_| {
            corrupt(
                self.offset,
                format!("field {name:?} has {} bytes, expected {N}", v.len()),
            )
        })
    }

    /// The `op` field.
    pub fn op(&self) -> Result<u8, RecordError> {
        Ok(self.fixed::<1>("op")?[0])
    }

    /// A `u32` field.
    pub fn u32(&self, name: &str) -> Result<u32, RecordError> {
        Ok(u32::from_le_bytes(self.fixed(name)?))
    }

    /// A `u64` field.
    pub fn u64(&self, name: &str) -> Result<u64, RecordError> {
        Ok(u64::from_le_bytes(self.fixed(name)?))
    }

    /// A ROS time field (`sec: u32`, `nsec: u32`) in nanoseconds.
    pub fn time_ns(&self, name: &str) -> Result<i64, RecordError> {
        Ok(time_ns(&self.fixed::<8>(name)?))
    }

    /// A text field.
    pub fn string(&self, name: &str) -> Result<String, RecordError> {
        Ok(String::from_utf8_lossy(self.need(name)?).into_owned())
    }
}

/// A ROS time (`sec: u32`, `nsec: u32`, little-endian) in nanoseconds.
pub fn time_ns(b: &[u8; 8]) -> i64 {
    let sec = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    let nsec = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
    i64::from(sec) * 1_000_000_000 + i64::from(nsec)
}

/// Little-endian `u32` at `pos`, when the bytes are there.
pub fn le_u32(b: &[u8], pos: usize) -> Option<u32> {
    let s = b.get(pos..pos.checked_add(4)?)?;
    Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// One record of a buffer (a decompressed chunk): its header and the range of its data.
#[derive(Debug, Clone)]
pub struct BufRecord {
    /// Header fields.
    pub fields: Fields,
    /// Data range in the buffer.
    pub data: std::ops::Range<usize>,
}

/// Reads the record at `pos` of `buf` (offsets in errors are `base + position`); returns the
/// record and the position after it, or `None` at the end of the buffer.
pub fn buf_record(
    buf: &[u8],
    pos: usize,
    base: u64,
) -> Result<Option<(BufRecord, usize)>, RecordError> {
    if pos >= buf.len() {
        return Ok(None);
    }
    let at = base + pos as u64;
    let cut = |what: &str| RecordError::Truncated {
        offset: at,
        msg: format!("{what} runs past the {} bytes available", buf.len() - pos),
    };
    let hlen = le_u32(buf, pos).ok_or_else(|| cut("header length"))? as usize;
    let hstart = pos + 4;
    let hend = hstart.checked_add(hlen).ok_or_else(|| cut("header"))?;
    let header = buf.get(hstart..hend).ok_or_else(|| cut("header"))?;
    let fields = Fields::parse(header, base + hstart as u64)?;
    let dlen = le_u32(buf, hend).ok_or_else(|| cut("data length"))? as usize;
    let dstart = hend + 4;
    let dend = dstart.checked_add(dlen).ok_or_else(|| cut("data"))?;
    if dend > buf.len() {
        return Err(cut("data"));
    }
    Ok(Some((
        BufRecord {
            fields,
            data: dstart..dend,
        },
        dend,
    )))
}

/// One record's header read from a file, its data left in place.
#[derive(Debug, Clone)]
pub struct FileRecord {
    /// Offset of the record.
    pub offset: u64,
    /// Header fields.
    pub fields: Fields,
    /// Offset of the data.
    pub data_offset: u64,
    /// Data length, bytes.
    pub data_len: u32,
}

impl FileRecord {
    /// Offset after the record.
    pub fn end(&self) -> u64 {
        self.data_offset + u64::from(self.data_len)
    }
}

/// Reads the header of the record at `offset` of a file of `file_len` bytes; `None` at its end.
pub fn file_record<R: Read + Seek>(
    f: &mut R,
    offset: u64,
    file_len: u64,
) -> Result<Option<FileRecord>, RecordError> {
    if offset >= file_len {
        return Ok(None);
    }
    let cut = |what: &str| RecordError::Truncated {
        offset,
        msg: format!(
            "{what} runs past the end of the file ({} bytes left)",
            file_len - offset
        ),
    };
    let io = |e: std::io::Error| corrupt(offset, format!("read failed: {e}"));
    f.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut n = [0u8; 4];
    if file_len - offset < 4 {
        return Err(cut("header length"));
    }
    f.read_exact(&mut n).map_err(io)?;
    let hlen = u32::from_le_bytes(n);
    if hlen > MAX_HEADER_BYTES {
        return Err(corrupt(
            offset,
            format!("record header of {hlen} bytes (more than {MAX_HEADER_BYTES})"),
        ));
    }
    let hstart = offset + 4;
    if hstart + u64::from(hlen) + 4 > file_len {
        return Err(cut("header"));
    }
    let mut header = vec![0u8; hlen as usize];
    f.read_exact(&mut header).map_err(io)?;
    let fields = Fields::parse(&header, hstart)?;
    f.read_exact(&mut n).map_err(io)?;
    let data_len = u32::from_le_bytes(n);
    let data_offset = hstart + u64::from(hlen) + 4;
    let rec = FileRecord {
        offset,
        fields,
        data_offset,
        data_len,
    };
    if rec.end() > file_len {
        return Err(cut("data"));
    }
    Ok(Some(rec))
}

/// Reads `len` bytes at `offset` (which the caller has checked exist).
pub fn read_at<R: Read + Seek>(f: &mut R, offset: u64, len: usize) -> Result<Vec<u8>, RecordError> {
    let io = |e: std::io::Error| corrupt(offset, format!("read failed: {e}"));
    f.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut buf = vec![0u8; len];
    f.read_exact(&mut buf).map_err(io)?;
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(name: &str, v: &[u8]) -> Vec<u8> {
        let mut f = ((name.len() + 1 + v.len()) as u32).to_le_bytes().to_vec();
        f.extend_from_slice(name.as_bytes());
        f.push(b'=');
        f.extend_from_slice(v);
        f
    }

    #[test]
    fn header_fields_parse_and_reject_overruns() {
        let mut h = field("op", &[2]);
        h.extend(field("conn", &7u32.to_le_bytes()));
        h.extend(field("time", &[1, 0, 0, 0, 5, 0, 0, 0]));
        let f = Fields::parse(&h, 100).unwrap();
        assert_eq!(f.op().unwrap(), 2);
        assert_eq!(f.u32("conn").unwrap(), 7);
        assert_eq!(f.time_ns("time").unwrap(), 1_000_000_005);
        let e = f.u64("conn").unwrap_err();
        assert!(e.msg().contains("expected 8"), "{e:?}");
        let mut bad = h.clone();
        bad.extend_from_slice(&50u32.to_le_bytes());
        bad.extend_from_slice(b"x=1");
        let e = Fields::parse(&bad, 100).unwrap_err();
        assert_eq!(e.offset(), 100 + h.len() as u64);
    }

    #[test]
    fn buffer_records_report_truncation_at_the_record() {
        let h = field("op", &[2]);
        let mut rec = (h.len() as u32).to_le_bytes().to_vec();
        rec.extend(&h);
        rec.extend(3u32.to_le_bytes());
        rec.extend([9, 9, 9]);
        let mut buf = rec.clone();
        buf.extend(&rec);
        let (r, next) = buf_record(&buf, 0, 1000).unwrap().unwrap();
        assert_eq!(&buf[r.data], &[9, 9, 9]);
        assert_eq!(next, rec.len());
        for cut in next + 1..buf.len() {
            match buf_record(&buf[..cut], next, 1000) {
                Err(RecordError::Truncated { offset, .. }) => {
                    assert_eq!(offset, 1000 + next as u64)
                }
                other => panic!("cut {cut}: {other:?}"),
            }
        }
        assert!(buf_record(&buf, buf.len(), 0).unwrap().is_none());
    }
}

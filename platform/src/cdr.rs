//! OMG CDR (XCDR1), the wire format of ROS 2 messages, as written by `rmw_fastrtps` and read by
//! every MCAP tool.
//!
//! A message is a 4-byte encapsulation header followed by the payload. The header is
//! `0x00 0x01 <options: 2 bytes>` for little-endian plain CDR (the only kind ROS 2 writes on
//! x86-64/aarch64; big-endian `0x00 0x00` is rejected). Inside the payload every primitive of
//! size `n` starts at an offset that is a multiple of `n`, counted from the payload start (byte 4
//! of the message), not from the message start. Strings are a `u32` length that includes the
//! terminating NUL, the bytes, then the NUL; sequences are a `u32` element count followed by the
//! elements; fixed arrays have no count.
//!
//! [`CdrReader`] borrows the message and never copies (strings and byte sequences are slices of
//! the input); every read is bounds-checked and fails with the byte offset (in the whole
//! message, header included) where decoding stopped, so a truncated or corrupt message can be
//! reported, never panic.

/// A decoding failure at a byte offset of the message (header included).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CdrError {
    /// Byte offset into the message where decoding failed.
    pub offset: usize,
    /// What was wrong.
    pub msg: String,
}

impl std::fmt::Display for CdrError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "byte {}: {}", self.offset, self.msg)
    }
}

impl std::error::Error for CdrError {}

/// Encapsulation header of little-endian plain CDR with no options.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
const HEADER_LEN: usize = 4;

/// Zero-copy cursor over one CDR message.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    payload: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header and positions the cursor at the payload start.
    pub fn new(msg: &'a [u8]) -> Result<Self, CdrError> {
        let Some((head, payload)) = msg.split_first_chunk::<HEADER_LEN>() else {
            return Err(CdrError {
                offset: msg.len(),
                msg: format!(
                    "message of {} bytes is shorter than the 4-byte CDR header",
                    msg.len()
                ),
            });
        };
        if head[0] != 0x00 || head[1] != 0x01 {
            return Err(CdrError {
                offset: 0,
                msg: format!(
                    "encapsulation {:02x} {:02x} is not little-endian CDR (00 01)",
                    head[0], head[1]
                ),
            });
        }
        Ok(CdrReader { payload, pos: 0 })
    }

    /// Offset of the cursor in the whole message (header included).
    pub fn offset(&self) -> usize {
        self.pos + HEADER_LEN
    }

    /// Bytes left after the cursor.
    pub fn remaining(&self) -> usize {
        self.payload.len() - self.pos
    }

    /// An error at the cursor.
    pub fn error(&self, msg: impl Into<String>) -> CdrError {
        CdrError {
            offset: self.offset(),
            msg: msg.into(),
        }
    }

    fn align(&mut self, n: usize) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        if pad > self.remaining() {
            return Err(self.error(format!("truncated: {pad} padding bytes missing")));
        }
        self.pos += pad;
        Ok(())
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CdrError> {
        if n > self.remaining() {
            return Err(self.error(format!(
                "truncated: {what} needs {n} bytes, {} left",
                self.remaining()
            )));
        }
        let s = &self.payload[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn prim<const N: usize>(&mut self, what: &str) -> Result<[u8; N], CdrError> {
        self.align(N)?;
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// `uint8`.
    pub fn u8(&mut self) -> Result<u8, CdrError> {
        Ok(self.prim::<1>("uint8")?[0])
    }

    /// `bool` (must be 0 or 1).
    pub fn bool(&mut self) -> Result<bool, CdrError> {
        let at = self.offset();
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(CdrError {
                offset: at,
                msg: format!("bool byte is {b}, not 0 or 1"),
            }),
        }
    }

    /// `uint32`.
    pub fn u32(&mut self) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.prim("uint32")?))
    }

    /// `uint64`.
    pub fn u64(&mut self) -> Result<u64, CdrError> {
        Ok(u64::from_le_bytes(self.prim("uint64")?))
    }

    /// `int32`.
    pub fn i32(&mut self) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.prim("int32")?))
    }

    /// `float32`.
    pub fn f32(&mut self) -> Result<f32, CdrError> {
        Ok(f32::from_le_bytes(self.prim("float32")?))
    }

    /// `float64`.
    pub fn f64(&mut self) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.prim("float64")?))
    }

    /// Fixed-size `float64[N]` array.
    pub fn f64_array<const N: usize>(&mut self) -> Result<[f64; N], CdrError> {
        let mut a = [0.0; N];
        for x in &mut a {
            *x = self.f64()?;
        }
        Ok(a)
    }

    /// `string` (UTF-8, NUL-terminated on the wire), borrowed from the message.
    pub fn string(&mut self) -> Result<&'a str, CdrError> {
        let at = self.offset();
        let len = self.u32()? as usize;
        if len == 0 {
            return Err(CdrError {
                offset: at,
                msg: "string length 0 (the NUL terminator is missing)".into(),
            });
        }
        let bytes = self.take(len, "string")?;
        let (nul, text) = bytes
            .split_last()
            .ok_or_else(|| self.error("empty string"))?;
        if *nul != 0 {
            return Err(self.error("string is not NUL-terminated"));
        }
        std::str::from_utf8(text).map_err(|e| CdrError {
            offset: at + 4 + e.valid_up_to(),
            msg: "string is not UTF-8".into(),
        })
    }

    /// Element count of a sequence whose elements take at least `min_elem_bytes` each; a count
    /// that cannot fit in the rest of the message is rejected before anything is allocated.
    pub fn seq_len(&mut self, min_elem_bytes: usize) -> Result<usize, CdrError> {
        let at = self.offset();
        let n = self.u32()? as usize;
        if n.saturating_mul(min_elem_bytes) > self.remaining() {
            return Err(CdrError {
                offset: at,
                msg: format!(
                    "sequence of {n} elements cannot fit in the {} bytes left",
                    self.remaining()
                ),
            });
        }
        Ok(n)
    }

    /// `uint8[]` sequence, borrowed from the message.
    pub fn bytes(&mut self) -> Result<&'a [u8], CdrError> {
        let n = self.seq_len(1)?;
        self.take(n, "uint8[]")
    }

    /// `float32[]` sequence.
    pub fn f32_seq(&mut self) -> Result<Vec<f32>, CdrError> {
        let n = self.seq_len(4)?;
        (0..n).map(|_| self.f32()).collect()
    }
}

/// Builds one CDR message (little-endian, header included).
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// An empty message with the little-endian encapsulation header.
    pub fn new() -> Self {
        Self::with_capacity(64)
    }

    /// Like [`CdrWriter::new`], with room for `n` payload bytes.
    pub fn with_capacity(n: usize) -> Self {
        let mut buf = Vec::with_capacity(n + HEADER_LEN);
        buf.extend_from_slice(&CDR_LE_HEADER);
        CdrWriter { buf }
    }

    /// The finished message.
    pub fn into_inner(self) -> Vec<u8> {
        self.buf
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - HEADER_LEN;
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// `uint8`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// `bool`.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `uint64`.
    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `float32`.
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Fixed-size `float64[N]` array.
    pub fn f64_array(&mut self, a: &[f64]) {
        for &x in a {
            self.f64(x);
        }
    }

    /// Sequence length prefix. Fails when the count does not fit in `u32`.
    pub fn seq_len(&mut self, n: usize) -> Result<(), CdrError> {
        let n32 = u32::try_from(n).map_err(|_| CdrError {
            offset: self.buf.len(),
            msg: format!("sequence of {n} elements exceeds u32"),
        })?;
        self.u32(n32);
        Ok(())
    }

    /// `string`. Fails when the text contains a NUL or is longer than `u32`.
    pub fn string(&mut self, s: &str) -> Result<(), CdrError> {
        if s.as_bytes().contains(&0) {
            return Err(CdrError {
                offset: self.buf.len(),
                msg: "string contains a NUL byte".into(),
            });
        }
        self.seq_len(s.len() + 1)?;
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        Ok(())
    }

    /// `uint8[]` sequence.
    pub fn bytes(&mut self, b: &[u8]) -> Result<(), CdrError> {
        self.seq_len(b.len())?;
        self.buf.extend_from_slice(b);
        Ok(())
    }

    /// `float32[]` sequence.
    pub fn f32_seq(&mut self, v: &[f32]) -> Result<(), CdrError> {
        self.seq_len(v.len())?;
        for &x in v {
            self.f32(x);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_counts_from_payload_start() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(1.5);
        w.string("ab").unwrap();
        w.u8(1);
        w.u32(9);
        let m = w.into_inner();
        // header 4 | u8 at 4 | pad to payload offset 8 -> f64 at message 12..20 | u32 len at 20 |
        // "ab\0" at 24..27 | u8 at 27 | u32 at 28.
        assert_eq!(m.len(), 32);
        assert_eq!(&m[12..20], &1.5f64.to_le_bytes());
        assert_eq!(&m[20..24], &3u32.to_le_bytes());
        assert_eq!(&m[24..27], b"ab\0");
        let mut r = CdrReader::new(&m).unwrap();
        assert_eq!(r.u8().unwrap(), 7);
        assert_eq!(r.f64().unwrap(), 1.5);
        assert_eq!(r.string().unwrap(), "ab");
        assert!(r.bool().unwrap());
        assert_eq!(r.u32().unwrap(), 9);
        assert_eq!(r.remaining(), 0);
        let e = r.u8().unwrap_err();
        assert_eq!(e.offset, 32);
    }

    #[test]
    fn rejects_bad_header_and_lengths() {
        assert_eq!(CdrReader::new(&[0, 1, 0]).unwrap_err().offset, 3);
        assert_eq!(CdrReader::new(&[0, 0, 0, 0]).unwrap_err().offset, 0);
        let mut w = CdrWriter::new();
        w.u32(1_000_000);
        let m = w.into_inner();
        let e = CdrReader::new(&m).unwrap().bytes().unwrap_err();
        assert_eq!(e.offset, 4);
        assert!(e.msg.contains("cannot fit"), "{e}");
        let mut w = CdrWriter::new();
        w.u32(2);
        w.u8(b'a');
        w.u8(b'b');
        let m = w.into_inner();
        let e = CdrReader::new(&m).unwrap().string().unwrap_err();
        assert!(e.msg.contains("NUL"), "{e}");
        let mut w = CdrWriter::new();
        w.u8(2);
        let e = CdrReader::new(&w.into_inner()).unwrap().bool().unwrap_err();
        assert_eq!(e.offset, 4);
    }
}

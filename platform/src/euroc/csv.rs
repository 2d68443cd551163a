//! Buffered line reader for EuRoC `data.csv` files that reuses one line buffer, so reading a
//! file allocates nothing per line.
//!
//! Line 1 may be a `#` header; it must have the expected number of comma-separated columns (so
//! a file of the wrong kind is caught). A `#` line anywhere else, or a blank line followed by more
//! data, is an error: nothing is skipped silently. Trailing blank lines are accepted.

use crate::error::IoError;
use std::io::BufRead;
use std::path::{Path, PathBuf};

/// A data line reader over one file.
pub struct CsvLines {
    path: PathBuf,
    rd: std::io::BufReader<std::fs::File>,
    buf: String,
    line: usize,
    columns: usize,
    blank_at: Option<usize>,
}

impl CsvLines {
    /// Opens `path` whose rows have `columns` comma-separated fields.
    pub fn open(path: &Path, columns: usize) -> Result<Self, IoError> {
        let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        Ok(CsvLines {
            path: path.into(),
            rd: std::io::BufReader::with_capacity(1 << 16, f),
            buf: String::with_capacity(256),
            line: 0,
            columns,
            blank_at: None,
        })
    }

    /// A parse error at the current line.
    pub fn err(&self, msg: impl Into<String>) -> IoError {
        IoError::Parse {
            path: self.path.clone(),
            line: self.line,
            msg: msg.into(),
        }
    }

    /// Advances to the next data line; `false` at the end of the file.
    pub fn next_line(&mut self) -> Result<bool, IoError> {
        loop {
            self.buf.clear();
            let n = self
                .rd
                .read_line(&mut self.buf)
                .map_err(|e| IoError::io(&self.path, e))?;
            if n == 0 {
                return Ok(false);
            }
            self.line += 1;
            let t = self.buf.trim();
            if t.is_empty() {
                self.blank_at.get_or_insert(self.line);
                continue;
            }
            if let Some(b) = self.blank_at {
                return Err(IoError::Parse {
                    path: self.path.clone(),
                    line: b,
                    msg: "blank line inside the data".into(),
                });
            }
            if let Some(h) = t.strip_prefix('#') {
                if self.line != 1 {
                    return Err(self.err("`#` line inside the data (only line 1 may be a header)"));
                }
                let cols = h.split(',').count();
                if cols != self.columns {
                    return Err(self.err(format!(
                        "header has {cols} columns, expected {}",
                        self.columns
                    )));
                }
                continue;
            }
            return Ok(true);
        }
    }

    /// The current data line split into exactly `N` trimmed fields.
    pub fn fields<const N: usize>(&self) -> Result<[&str; N], IoError> {
        let mut out = [""; N];
        let mut n = 0;
        for f in self.buf.trim().split(',') {
            if n < N {
                out[n] = f.trim();
            }
            n += 1;
        }
        if n != N {
            return Err(self.err(format!("expected {N} fields, found {n}")));
        }
        Ok(out)
    }

    /// Field `i` of the line as integer nanoseconds.
    pub fn ns(&self, i: usize, s: &str) -> Result<i64, IoError> {
        s.parse().map_err(|_| {
            self.err(format!(
                "field {} ({s:?}) is not integer nanoseconds",
                i + 1
            ))
        })
    }

    /// Field `i` as an unsigned integer.
    pub fn u64(&self, i: usize, s: &str) -> Result<u64, IoError> {
        s.parse().map_err(|_| {
            self.err(format!(
                "field {} ({s:?}) is not an unsigned integer",
                i + 1
            ))
        })
    }

    /// Field `i` as a finite `f64`.
    pub fn f64(&self, i: usize, s: &str) -> Result<f64, IoError> {
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.err(format!("field {} ({s:?}) is not a finite number", i + 1))),
        }
    }

    /// Field `i` as a finite `f32`.
    pub fn f32(&self, i: usize, s: &str) -> Result<f32, IoError> {
        match s.parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.err(format!("field {} ({s:?}) is not a finite number", i + 1))),
        }
    }

    /// Checks that `t_ns` is after `prev` (strictly, or equal allowed when `allow_equal`).
    pub fn check_time(
        &self,
        prev: Option<i64>,
        t_ns: i64,
        allow_equal: bool,
    ) -> Result<(), IoError> {
        match prev {
            Some(p) if t_ns < p || (t_ns == p && !allow_equal) => Err(self.err(format!(
                "time {t_ns} ns does not increase (previous {p} ns)"
            ))),
            _ => Ok(()),
        }
    }
}

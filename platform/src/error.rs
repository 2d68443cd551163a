//! Errors of the dataset readers and writers. Every error names the file (or MCAP topic) and the
//! line or byte offset, so a user can find the bad record.

use std::path::PathBuf;

/// A dataset I/O failure.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The OS refused to read or write a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A text record could not be parsed.
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What was wrong.
        msg: String,
    },
    /// A binary record is truncated or corrupt.
    #[error("{file}: {what} at byte offset {offset}: {msg}")]
    Corrupt {
        /// The file.
        file: PathBuf,
        /// Topic, record or field being decoded.
        what: String,
        /// Byte offset inside the record (or file) where decoding failed.
        offset: u64,
        /// What was wrong.
        msg: String,
    },
    /// The input is well-formed but not usable (missing sensor, unsupported model, ...).
    #[error("{path}: {msg}")]
    Invalid {
        /// The file or folder.
        path: PathBuf,
        /// What was wrong.
        msg: String,
    },
}

impl IoError {
    /// Wraps an OS error with its path.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.into(),
            source,
        }
    }
}

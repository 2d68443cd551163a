//! MCAP files with ROS 2 (CDR) messages.
//!
//! STUB: signatures fixed; bodies are implemented by the data-plane work.

use crate::dataset::Dataset;
use crate::error::IoError;
use std::path::Path;

/// Reads a whole MCAP file into a [`Dataset`].
pub fn read_dataset(path: &Path) -> Result<Dataset, IoError> {
    Err(IoError::Invalid {
        path: path.into(),
        msg: "not implemented yet".into(),
    })
}

/// Writes a [`Dataset`] as MCAP (ROS 2 CDR messages, calibration as metadata).
pub fn write_dataset(path: &Path, ds: &Dataset) -> Result<(), IoError> {
    let _ = ds;
    Err(IoError::Invalid {
        path: path.into(),
        msg: "not implemented yet".into(),
    })
}

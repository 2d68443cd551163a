//! EuRoC ASL folders (`mav0/...`), including the `features0` extension.
//!
//! STUB: signatures fixed; bodies are implemented by the data-plane work.

use crate::dataset::Dataset;
use crate::error::IoError;
use std::path::Path;

/// Reads an EuRoC ASL folder (the folder containing `mav0/`, or `mav0/` itself).
pub fn read_dataset(dir: &Path) -> Result<Dataset, IoError> {
    Err(IoError::Invalid {
        path: dir.into(),
        msg: "not implemented yet".into(),
    })
}

/// Writes camera calibration, IMU, features, images (if decoded) and ground truth as an EuRoC
/// ASL folder under `dir/mav0`.
pub fn write_dataset(dir: &Path, ds: &Dataset) -> Result<(), IoError> {
    let _ = ds;
    Err(IoError::Invalid {
        path: dir.into(),
        msg: "not implemented yet".into(),
    })
}

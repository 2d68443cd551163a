//! Trajectory files: TUM (`t[s] x y z qx qy qz qw`, body in world) and EuRoC ground truth
//! (`#timestamp [ns], p_RS_R_x [m], ..., q_RS_w [], q_RS_x, q_RS_y, q_RS_z, v_RS_R_x [m s^-1], ...,
//! b_w_RS_S_x [rad s^-1], ..., b_a_RS_S_x [m s^-2], ...`).
//!
//! STUB: signatures fixed; bodies are implemented by the data-plane work.

use crate::error::IoError;
use povins_core::inertial::NavState;
use povins_core::math::{Quat, Vec3};
use std::path::Path;

/// A timestamped pose of the body `b` in the world `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    /// Time, integer nanoseconds.
    pub t_ns: i64,
    /// Position of the body in `w`, m.
    pub p_wb: Vec3,
    /// Rotation body -> world.
    pub q_wb: Quat,
}

/// Reads a TUM trajectory.
pub fn read_tum(path: &Path) -> Result<Vec<StampedPose>, IoError> {
    Err(IoError::Invalid {
        path: path.into(),
        msg: "read_tum not implemented yet".into(),
    })
}

/// Writes a TUM trajectory (nanosecond-exact seconds with 9 decimals).
pub fn write_tum(path: &Path, poses: &[StampedPose]) -> Result<(), IoError> {
    let _ = poses;
    Err(IoError::Invalid {
        path: path.into(),
        msg: "write_tum not implemented yet".into(),
    })
}

/// Reads an EuRoC `state_groundtruth_estimate0/data.csv` (full state).
pub fn read_euroc_groundtruth(path: &Path) -> Result<Vec<NavState>, IoError> {
    Err(IoError::Invalid {
        path: path.into(),
        msg: "not implemented yet".into(),
    })
}

/// Writes an EuRoC ground-truth CSV.
pub fn write_euroc_groundtruth(path: &Path, states: &[NavState]) -> Result<(), IoError> {
    let _ = states;
    Err(IoError::Invalid {
        path: path.into(),
        msg: "not implemented yet".into(),
    })
}

/// Reads a trajectory in either format (detected from the content), as poses.
pub fn read_trajectory(path: &Path) -> Result<Vec<StampedPose>, IoError> {
    Err(IoError::Invalid {
        path: path.into(),
        msg: "not implemented yet".into(),
    })
}

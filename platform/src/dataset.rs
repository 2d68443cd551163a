//! The in-memory form of a recorded or simulated sequence, shared by every reader, writer, the
//! simulator and the replay runner.
//!
//! Frames: IMU samples are in the body (IMU) frame `b`; ground truth is the body in the world
//! frame `w` (z up); feature observations are raw distorted pixels of the camera; LiDAR points
//! are in the LiDAR frame `l`. Extrinsics follow the core's naming: `q_bc`/`p_bc` map camera
//! coordinates into the body frame (`P_b = R_bc P_c + p_bc`, EuRoC's `T_BS`).

use povins_core::camera::{Distortion, FeatureObs, PinholeCamera};
use povins_core::inertial::{ImuNoise, ImuSample, NavState};
use povins_core::lidar::LidarPoint;
use povins_core::math::{Quat, Vec3};

/// Rigid transform `T_ab`: maps points of frame `b` into frame `a`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extrinsic {
    /// Rotation `b -> a`.
    pub q_ab: Quat,
    /// Origin of `b` in `a`, m.
    pub p_ab: Vec3,
}

impl Extrinsic {
    /// The identity transform.
    pub fn identity() -> Self {
        Extrinsic {
            q_ab: Quat::identity(),
            p_ab: Vec3::zeros(),
        }
    }
}

/// The camera of a recording without one (LiDAR-inertial, IMU only): zero-size, so the
/// estimator cannot mistake it for a real camera.
pub fn no_camera() -> PinholeCamera {
    PinholeCamera {
        readout_s: 0.0,
        width: 0,
        height: 0,
        fx: 1.0,
        fy: 1.0,
        cx: 0.0,
        cy: 0.0,
        distortion: Distortion::None,
    }
}

/// Sensor calibration of a sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Camera intrinsics and distortion (cam0).
    pub camera: PinholeCamera,
    /// Camera in body: `T_bc` (EuRoC `T_BS` of cam0).
    pub t_bc: Extrinsic,
    /// Camera-IMU time offset, s, LE-VINS convention `t_imu = t_cam + td_s`.
    pub td_s: f64,
    /// Camera frame rate, Hz (informational).
    pub camera_rate_hz: f64,
    /// IMU noise model.
    pub imu_noise: ImuNoise,
    /// IMU rate, Hz.
    pub imu_rate_hz: f64,
    /// Gravity magnitude, m/s^2.
    pub gravity_mps2: f64,
    /// LiDAR in body `T_bl`, when the sequence has a LiDAR.
    pub t_bl: Option<Extrinsic>,
}

/// Feature observations of one camera frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureFrame {
    /// Image time, integer nanoseconds (camera clock).
    pub t_ns: i64,
    /// The tracked features in raw pixels.
    pub obs: Vec<FeatureObs>,
}

/// One LiDAR sweep; every point carries its own time.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarScan {
    /// Sweep (message) time, integer nanoseconds: the start of the sweep.
    pub t_ns: i64,
    /// Points in the LiDAR frame.
    pub points: Vec<LidarPoint>,
}

/// A camera image reference (EuRoC `cam0/data.csv` row) or decoded 8-bit mono pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageFrame {
    /// Image time, integer nanoseconds.
    pub t_ns: i64,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Row-major mono8 pixels (empty when only the path is known).
    pub mono8: Vec<u8>,
    /// Source file, when read from a folder.
    pub path: Option<std::path::PathBuf>,
}

/// What only a simulator knows, kept for evaluation (never fed to the estimator).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimTruth {
    /// True landmark positions in `w`, by feature id.
    pub landmarks_w: Vec<(u64, Vec3)>,
    /// Feature ids that are deliberately wrong tracks (outliers).
    pub wrong_tracks: Vec<u64>,
    /// Feature ids whose landmark lies on an object edge (LiDAR depth may hit the background).
    pub edge_features: Vec<u64>,
    /// Per scan (same order as [`Dataset::lidar`]), per point: true when the point is an edge case.
    pub lidar_edge_points: Vec<Vec<bool>>,
}

/// A whole sequence in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Human-readable name (folder or file stem, or scenario).
    pub name: String,
    /// Calibration.
    pub calib: Calibration,
    /// IMU samples, strictly increasing in time.
    pub imu: Vec<ImuSample>,
    /// Feature tracks per camera frame, increasing in time.
    pub features: Vec<FeatureFrame>,
    /// Images (may be empty).
    pub images: Vec<ImageFrame>,
    /// LiDAR sweeps (may be empty).
    pub lidar: Vec<LidarScan>,
    /// Ground truth of the body in the world (may be empty).
    pub ground_truth: Vec<NavState>,
    /// Simulator-only truth.
    pub sim_truth: Option<SimTruth>,
}

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
    /// LiDAR-IMU time offset, s, `t_imu = t_lidar + td_l_s` (the estimator's `lidar.td_l_s`;
    /// Kalibr's sign, as [`Self::td_s`]); 0 when the calibration gives none.
    pub td_l_s: f64,
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

/// One feature id of the simulator's truth, as the evaluation reads it one at a time
/// ([`crate::recording::Recording::sim_landmarks`]): increasing `first_ns`, so that a check over
/// a run holds only the tracks alive at its keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimLandmark {
    /// Feature id.
    pub id: u64,
    /// True landmark position in `w`, m (`None`: the id has flags but no landmark).
    pub p_w: Option<Vec3>,
    /// Camera stamp of the id's first observation, ns (`i64::MIN`: held from the start).
    pub first_ns: i64,
    /// Camera stamp of its last observation, ns (`i64::MAX`: held to the end).
    pub last_ns: i64,
    /// In [`SimTruth::wrong_tracks`].
    pub wrong: bool,
    /// In [`SimTruth::edge_features`].
    pub edge: bool,
}

impl SimTruth {
    /// Every id of the truth (landmarks and flags) with its span of observations in `frames`,
    /// by increasing first observation, then id; ids never observed come first, spanning the
    /// first frame only (`first_ns = last_ns`), or everything when there are no frames.
    pub fn landmarks(&self, frames: &[FeatureFrame]) -> Vec<SimLandmark> {
        use std::collections::BTreeMap;
        let mut by_id: BTreeMap<u64, SimLandmark> = BTreeMap::new();
        fn entry(m: &mut BTreeMap<u64, SimLandmark>, id: u64) -> &mut SimLandmark {
            m.entry(id).or_insert(SimLandmark {
                id,
                p_w: None,
                first_ns: i64::MAX,
                last_ns: i64::MIN,
                wrong: false,
                edge: false,
            })
        }
        for &(id, p) in &self.landmarks_w {
            entry(&mut by_id, id).p_w = Some(p);
        }
        for &id in &self.wrong_tracks {
            entry(&mut by_id, id).wrong = true;
        }
        for &id in &self.edge_features {
            entry(&mut by_id, id).edge = true;
        }
        for f in frames {
            for o in &f.obs {
                if let Some(l) = by_id.get_mut(&o.id) {
                    l.first_ns = l.first_ns.min(f.t_ns);
                    l.last_ns = l.last_ns.max(f.t_ns);
                }
            }
        }
        let t0 = frames.first().map(|f| f.t_ns);
        let mut v: Vec<SimLandmark> = by_id
            .into_values()
            .map(|mut l| {
                if l.first_ns > l.last_ns {
                    (l.first_ns, l.last_ns) = t0.map_or((i64::MIN, i64::MAX), |t| (t, t));
                }
                l
            })
            .collect();
        v.sort_by_key(|l| (l.first_ns, l.id));
        v
    }

    /// The truth rebuilt from [`SimTruth::landmarks`] (each list by increasing id; no LiDAR
    /// edge flags).
    pub fn from_landmarks(ls: impl IntoIterator<Item = SimLandmark>) -> SimTruth {
        let mut t = SimTruth::default();
        for l in ls {
            if let Some(p) = l.p_w {
                t.landmarks_w.push((l.id, p));
            }
            if l.wrong {
                t.wrong_tracks.push(l.id);
            }
            if l.edge {
                t.edge_features.push(l.id);
            }
        }
        t.landmarks_w.sort_by_key(|l| l.0);
        t.wrong_tracks.sort_unstable();
        t.edge_features.sort_unstable();
        t
    }
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

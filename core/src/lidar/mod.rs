//! LiDAR enhancement (paper III, IV.C, V.C-V.D): a bounded buffer of de-skewed points and the
//! depth association of visual features on the unit sphere of the keyframe camera.
//!
//! Pipeline (driven by [`crate::estimator`]):
//! 0. When a sweep is pushed, [`ViewCrop`] drops the points that cannot reach the camera's image
//!    (counted), and the rest wait in [`PendingSweeps`] until the INS has passed them.
//! 1. [`PointBuffer::push_scan`]: every point of a sweep is de-skewed with the INS pose at its
//!    own time (`t_imu = t_lidar + td_l_s`) and the LiDAR-IMU extrinsic `T_bl`, and stored in the
//!    INS world frame `w`. The buffer keeps the latest points up to its capacity and time span.
//!    A LiDAR whose rate would overflow the buffer within the association's span is thinned
//!    first by [`ThinGrid`] (one point per direction per quarter span, counted).
//! 2. At a keyframe, [`SphereGrid::build`] expresses the buffered points in the keyframe camera
//!    and keeps the nearest point per angular cell (foreground only).
//! 3. [`SphereGrid::associate`] gives a feature's LiDAR depth: neighbours of its bearing, plane
//!    fit with plane and range-spread checks, ray-plane intersection, depth = z in the camera.
//! 4. Before each solve, [`DepthPair::is_outlier`] tests the depth against the landmark's
//!    pose-only depth and its uncertainty (paper IV.C, in inverse depth: see [`rejection`]).
//!
//! Frames: `l` LiDAR, `b` body (IMU), `w` world, `c` camera; `T_bl` maps LiDAR points into the
//! body (`P_b = R_bl P_l + p_bl`).

mod angle_index;
pub mod association;
pub mod buffer;
pub mod config;
pub mod crop;
mod deskew;
pub mod pending;
mod plane;
pub mod rejection;
#[cfg(test)]
mod testutil;
pub mod thin;

pub use association::{AssocReject, DepthMeasurement, GridStats, SphereGrid};
pub use buffer::{PointBuffer, ScanStats, WorldPoint};
pub use config::{AssociationConfig, LdmMode, LidarConfig, LidarExtrinsic, MAX_TD_L_S};
pub use crop::ViewCrop;
pub use pending::{PendingSweeps, Queued};
pub use rejection::DepthPair;
pub use thin::ThinGrid;

/// One LiDAR return in the LiDAR frame `l`, with its own timestamp (so motion distortion can be
/// removed). Stored as `f32` to keep point buffers small; the math converts to `f64`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LidarPoint {
    /// Time of this return, integer nanoseconds.
    pub t_ns: i64,
    /// Position in the LiDAR frame, m.
    pub p_l: [f32; 3],
    /// Intensity (sensor units).
    pub intensity: f32,
}

/// When a sweep can be de-skewed whole: its last point on the IMU clock, `max t_point + td_l`
/// (`t_imu = t_lidar + td_l_s`), ns; `None` for a sweep without points. The estimator takes a
/// queued sweep at the first processed IMU sample at or past it ([`crate::estimator::timing`]);
/// a recording's replay offers the sweep then, as a live driver would once the sweep is
/// complete.
pub fn sweep_due_ns(points: &[LidarPoint], td_l_s: f64) -> Option<i64> {
    let td_ns = buffer::seconds_to_ns(td_l_s);
    points
        .iter()
        .map(|p| p.t_ns)
        .max()
        .map(|t| t.saturating_add(td_ns))
}

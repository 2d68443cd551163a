//! Depth association on the unit sphere of the keyframe camera (LE-VINS, paper III).
//!
//! SKELETON: the public API is fixed; the implementation is being written.

use super::buffer::PointBuffer;
use super::config::AssociationConfig;
use crate::camera::Vec2;
use crate::math::{Quat, Vec3};

/// Grid width (cells along the horizontal angle) of the estimator's sphere grid.
pub const GRID_W: usize = 256;
/// Grid height of the estimator's sphere grid.
pub const GRID_H: usize = 192;

/// What [`SphereGrid::build`] saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridStats {
    /// Buffered points considered (inside the time span).
    pub points: u32,
    /// Of those, in front of the camera and inside the grid.
    pub in_view: u32,
    /// Cells holding a point.
    pub cells_filled: u32,
}

/// A LiDAR depth for one feature bearing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMeasurement {
    /// Depth: z of the ray-plane intersection in the camera, m.
    pub depth_m: f64,
    /// Range along the ray, m.
    pub range_m: f64,
    /// Neighbours in the plane fit.
    pub neighbours: u8,
    /// RMS distance of the neighbours from the plane, m.
    pub plane_rms_m: f64,
}

/// Why a bearing got no depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AssocReject {
    /// Fewer than the configured neighbours within the angular radius.
    NoNeighbours,
    /// A neighbour is too far from the fitted plane (or the fit is degenerate).
    PlaneFit,
    /// Neighbour ranges spread too much (foreground mixed with background).
    RangeSpread,
    /// The ray grazes the plane.
    Incidence,
    /// The depth is outside the configured range.
    DepthRange,
    /// Non-finite input.
    NonFinite,
}

/// Nearest point per angular cell of a `W x H` grid centred on the optical axis.
#[derive(Debug, Clone)]
pub struct SphereGrid<const W: usize, const H: usize> {
    filled: u32,
}

impl<const W: usize, const H: usize> Default for SphereGrid<W, H> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const W: usize, const H: usize> SphereGrid<W, H> {
    /// An empty grid.
    pub fn new() -> Self {
        SphereGrid { filled: 0 }
    }

    /// Fills the grid with the buffered points of the last `cfg.span_s` before `t_kf_ns`,
    /// expressed in the camera with pose `(p_wc, q_wc)` in `w`.
    pub fn build<const P: usize>(
        &mut self,
        buf: &PointBuffer<P>,
        p_wc: &Vec3,
        q_wc: &Quat,
        t_kf_ns: i64,
        cfg: &AssociationConfig,
    ) -> GridStats {
        let _ = (buf, p_wc, q_wc, t_kf_ns, cfg);
        self.filled = 0;
        GridStats::default()
    }

    /// LiDAR depth of the feature at undistorted normalized coordinates `x_n`.
    pub fn associate(
        &self,
        x_n: &Vec2,
        cfg: &AssociationConfig,
    ) -> Result<DepthMeasurement, AssocReject> {
        let _ = (x_n, cfg);
        Err(AssocReject::NoNeighbours)
    }
}

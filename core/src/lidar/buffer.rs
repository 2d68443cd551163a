//! Bounded buffer of de-skewed LiDAR points in the INS world frame.
//!
//! SKELETON: the public API is fixed; the implementation is being written.

use super::config::LidarConfig;
use super::LidarPoint;
use crate::inertial::window::InsWindow;
use crate::math::Vec3;

/// Most points the estimator's buffer holds (about 0.5 s of a Livox Mid-70).
pub const MAX_LIDAR_POINTS: usize = 65_536;

/// A de-skewed point: its time and position in the INS world frame `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPoint {
    /// Time of the return (LiDAR clock), ns.
    pub t_ns: i64,
    /// Position in `w`, m.
    pub p_w: Vec3,
}

/// What one [`PointBuffer::push_scan`] did with the points it was given.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanStats {
    /// Points offered.
    pub received: u32,
    /// Points stored.
    pub accepted: u32,
    /// NaN/inf coordinates or time.
    pub rejected_nonfinite: u32,
    /// Too close (incl. all-zero returns) or too far.
    pub rejected_range: u32,
    /// Time outside the INS window (no pose to de-skew with).
    pub rejected_time: u32,
    /// Older points dropped to make room (capacity `P`).
    pub evicted: u32,
}

/// Ring buffer of the latest `P` de-skewed points.
#[derive(Debug, Clone)]
pub struct PointBuffer<const P: usize> {
    len: usize,
}

impl<const P: usize> Default for PointBuffer<P> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const P: usize> PointBuffer<P> {
    /// An empty buffer.
    pub fn new() -> Self {
        PointBuffer { len: 0 }
    }

    /// Drops every point.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Points stored.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// De-skews and stores a sweep: each point with the INS pose at `t + td_l_s` interpolated
    /// from `ins`, and the extrinsic of `cfg`. Invalid points are rejected and counted; never
    /// panics, whatever the input.
    pub fn push_scan<const K: usize>(
        &mut self,
        points: &[LidarPoint],
        ins: &InsWindow<K>,
        cfg: &LidarConfig,
    ) -> ScanStats {
        let _ = (ins, cfg);
        ScanStats {
            received: points.len() as u32,
            ..ScanStats::default()
        }
    }

    /// Stored points with time `>= t_min_ns`.
    pub fn iter_since(&self, t_min_ns: i64) -> impl Iterator<Item = WorldPoint> + '_ {
        let _ = t_min_ns;
        core::iter::empty()
    }
}

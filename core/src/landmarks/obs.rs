//! The observation values the landmark manager and the observation store share: a feature's
//! observation in one keyframe ([`KfObs`]) and a LiDAR depth associated with it
//! ([`LidarDepth`]). Both are plain values; who keeps them is decided in [`super::manager`]
//! (landmarks) and [`super::store`] (every track).

/// One observation of a landmark in a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct KfObs {
    /// Normalized image coordinates in that keyframe's camera.
    pub x_n: [f64; 2],
    /// Feature velocity on the normalized plane, 1/s.
    pub vel: [f64; 2],
    /// Time delay `td` (s) of the keyframe when the observation was taken (for `x - (td - td0) v`).
    pub td0_s: f64,
}

/// Status of a landmark's LiDAR depth (filled by the LiDAR layer).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LidarDepth {
    /// Depth (z in the anchor camera), m.
    pub depth_m: f64,
    /// Its standard deviation, m.
    pub sigma_m: f64,
}

impl LidarDepth {
    /// The whitened depth row of a landmark at inverse depth `tau` in its anchor camera,
    /// `(1/tau - depth_m) / sigma_m`, and its first and second derivatives in `tau`.
    pub fn row(&self, tau: f64) -> [f64; 3] {
        let s = self.sigma_m;
        let d1 = -1.0 / (tau * tau * s);
        [(1.0 / tau - self.depth_m) / s, d1, -2.0 * d1 / tau]
    }
}

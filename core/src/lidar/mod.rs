//! LiDAR points and (later) depth association.

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

//! Camera model and feature observations.
//!
//! Pixel `(u, v)` has its origin at the top-left pixel centre, u to the right, v down; the camera
//! frame `c` has x right, y down, z forward (optical axis). The normalized plane is `z = 1`.
//!
//! A point `P_c` maps to the normalized plane `x_n = (P_x/P_z, P_y/P_z)`, then through the lens
//! model to distorted normalized coordinates `x_d` ([`distortion`]), then to pixels
//! `u = fx x_d + cx`, `v = fy y_d + cy` ([`pinhole`]). [`PinholeCamera::undistort`] inverts the
//! lens model iteratively.

pub mod distortion;
pub mod extrinsic;
pub mod pinhole;

pub use extrinsic::{CameraExtrinsic, CameraPose};

/// 2-vector of `f64` (normalized-plane or pixel coordinates).
pub type Vec2 = nalgebra::Vector2<f64>;
/// 2x2 matrix of `f64`.
pub type Mat2 = nalgebra::Matrix2<f64>;

/// A feature observation: a tracked point in raw (distorted) pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeatureObs {
    /// Track (landmark) identifier, stable across frames.
    pub id: u64,
    /// Column, px.
    pub u_px: f64,
    /// Row, px.
    pub v_px: f64,
}

/// Lens distortion model of a [`PinholeCamera`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum Distortion {
    /// No distortion.
    None,
    /// Radial-tangential (plumb bob / Kalibr `radtan`).
    RadTan {
        /// Radial coefficient r^2.
        k1: f64,
        /// Radial coefficient r^4.
        k2: f64,
        /// Tangential coefficient.
        p1: f64,
        /// Tangential coefficient.
        p2: f64,
    },
    /// Equidistant fisheye (Kalibr `equidistant`, OpenCV fisheye).
    Equidistant {
        /// Coefficients of theta^3, theta^5, theta^7, theta^9.
        k: [f64; 4],
    },
}

/// Pinhole camera intrinsics with distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct PinholeCamera {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal length along u, px.
    pub fx: f64,
    /// Focal length along v, px.
    pub fy: f64,
    /// Principal point u, px.
    pub cx: f64,
    /// Principal point v, px.
    pub cy: f64,
    /// Distortion model.
    pub distortion: Distortion,
    /// Rolling-shutter readout time, s: the rows are read out from the top (row 0) to the bottom
    /// over this time; 0 for a global shutter. The frame's stamp is the time of its **middle**
    /// row, so a row at pixel `v` is captured [`Self::row_time_s`]`(v)` = `readout_s ((v + 0.5) /
    /// height - 0.5)` after the stamp (a camera that stamps its first row shifts the delay `td`
    /// by `readout_s / 2`, which the online delay absorbs). From Kalibr's rolling-shutter model:
    /// `line_delay * height`. Optional in a configuration file (default 0).
    #[cfg_attr(feature = "serde", serde(default))]
    pub readout_s: f64,
}

/// Largest accepted [`PinholeCamera::readout_s`], s (a frame's readout longer than 0.2 s is not a
/// rolling shutter but a wrong unit).
pub const MAX_READOUT_S: f64 = 0.2;

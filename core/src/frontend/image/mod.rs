//! Image front end: from 8-bit grayscale images to feature tracks, `no_std` and heap-free.
//!
//! - [`ImageView`]: a borrowed image (width, height, stride), checked once.
//! - [`Pyramid`]: an image pyramid in a fixed buffer (size it with [`pyramid_bytes`]), integer
//!   Gaussian or box downsampling, optional histogram equalization / CLAHE of level 0.
//! - [`GridDetector`]: Shi-Tomasi corners on a grid, computed only in cells that need features,
//!   with non-maximum suppression, a relative quality threshold and a minimum distance to the
//!   existing tracks (occupancy mask).
//! - [`track_point`]: pyramidal Lucas-Kanade of one point in OpenCV's fixed-point arithmetic.
//! - [`ransac`]: geometric outlier rejection, 2-point with the gyro rotation or 8-point.
//! - [`reference`](mod@reference), [`affine`]: optional anchored refinement of each track against the patch
//!   of its reference observation (affine LK), which removes the frame-to-frame drift.
//! - [`FeatureTracker`]: all of it per frame, with INS / gyro seeding, a forward-backward
//!   check, ids and ages; [`FeatureTracker::features`] are the
//!   [`crate::camera::FeatureObs`] the estimator consumes.
//!
//! Every result is bit-identical on x86-64 and aarch64: image arithmetic is integer (pyramid,
//! gradients, bilinear weights with 14 bits, LK sums), and the few floating-point steps
//! (eigenvalues, LK updates, RANSAC, undistortion) are plain IEEE operations in a fixed order
//! with `libm`, no fused multiply-add.

pub mod affine;
pub mod corners;
pub mod equalize;
pub mod lk;
pub mod provisional;
pub mod pyramid;
pub mod ransac;
pub mod reference;
pub mod tracker;
pub mod view;

#[cfg(test)]
pub(crate) mod testutil;

pub use affine::Photometric;
pub use corners::{Corner, DetectStats, DetectorConfig, GridDetector, OccupancyMask};
pub use equalize::{Equalization, Equalizer};
pub use lk::{track_point, track_point_no_residual, LkConfig, LkFailure, LkScratch, LkTrack};
pub use provisional::{ProvisionalConfig, Verdict};
pub use pyramid::{level_size, pyramid_bytes, Pyramid, PyramidFilter};
pub use ransac::{RansacConfig, RansacModel, RansacOutcome, XorShift64};
pub use reference::{ReferenceConfig, References, Refined, TEMPLATE_SIDE};
pub use tracker::{
    EurocTracker, FeatureTracker, HdTracker, RansacRun, TrackHints, TrackStats, TrackerConfig,
};
pub use view::{ImageView, MAX_IMAGE_SIDE};

//! Front end of the back end: turns raw feature tracks into keyframe observations.
//!
//! The image front end (corner detection and KLT tracking from images) is [`image`]; here a
//! frame of tracked pixels is validated, undistorted onto the normalized plane, given a per-feature velocity
//! (for the camera-IMU time-delay correction), and a keyframe decision is made from the
//! INS-predicted relative motion and the feature parallax; the features also tell whether the
//! platform is at rest ([`rest`]). A rolling shutter's rows are moved to the frame's stamp
//! ([`rolling_shutter`]).

pub mod image;
pub mod keyframe;
pub mod rest;
pub mod rolling_shutter;
pub mod tracks;

pub use image::{EurocTracker, FeatureTracker, ImageView, TrackHints, TrackStats, TrackerConfig};
pub use keyframe::{mean_parallax_px, KeyframeConfig, KeyframeDecision, KeyframeSelector};
pub use rest::{RestConfig, RestDetector, RestVerdict};
pub use tracks::{CameraMotion, FrameStats, NormalizedObs, TrackTable};

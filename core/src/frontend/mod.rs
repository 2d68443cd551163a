//! Front end of the back end: turns raw feature tracks into keyframe observations.
//!
//! The image front end (detection and KLT tracking) is outside this module; here a frame of
//! tracked pixels is validated, undistorted onto the normalized plane, given a per-feature velocity
//! (for the camera-IMU time-delay correction), and a keyframe decision is made from the
//! INS-predicted relative motion and the feature parallax; the features also tell whether the
//! platform is at rest ([`rest`]).

pub mod keyframe;
pub mod rest;
pub mod tracks;

pub use keyframe::{KeyframeConfig, KeyframeDecision, KeyframeSelector};
pub use rest::{RestConfig, RestDetector, RestVerdict};
pub use tracks::{FrameStats, NormalizedObs, TrackTable};

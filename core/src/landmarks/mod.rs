//! Landmark geometry: pose-only depth and its analytic uncertainty, landmark bookkeeping.

pub mod manager;
pub mod pose_only;
pub mod store;

pub use manager::{
    KfObs, Landmark, LandmarkManager, LidarDepth, ManagerStats, MargPlan, BANNED_TRACKS,
};
pub use pose_only::{depth_std, pose_only_depth, select_anchor, PoseOnlyDepth, TwoView};
pub use store::{ObservationStore, TrackObs};

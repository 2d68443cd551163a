//! Landmark geometry: pose-only depth and its analytic uncertainty, landmark bookkeeping.

pub mod manager;
pub mod pose_only;

pub use manager::{KfObs, Landmark, LandmarkManager, LidarDepth, ManagerStats};
pub use pose_only::{depth_std, pose_only_depth, select_anchor, PoseOnlyDepth, TwoView};

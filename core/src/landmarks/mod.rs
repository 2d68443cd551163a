//! Landmark geometry: pose-only depth and its analytic uncertainty, landmark bookkeeping.

pub mod pose_only;

pub use pose_only::{depth_std, pose_only_depth, select_anchor, PoseOnlyDepth, TwoView};

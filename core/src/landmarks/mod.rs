//! Landmark geometry: pose-only depth and its analytic uncertainty, landmark bookkeeping, a
//! camera's pose from landmarks ([`resection`]), the rotation between two frames from their
//! tracks alone ([`relative_rotation`]).

pub mod manager;
pub mod obs;
pub mod pose_only;
pub mod relative_rotation;
pub mod resection;
pub mod store;

pub use manager::{Landmark, LandmarkManager, ManagerStats, MargPlan, BANNED_TRACKS};
pub use obs::{KfObs, LidarDepth};
pub use pose_only::{depth_std, pose_only_depth, select_anchor, PoseOnlyDepth, TwoView};
pub use store::{ObservationStore, TrackObs};

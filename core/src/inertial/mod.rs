//! Inertial layer: IMU samples and noise, INS mechanization, the INS state window with pose
//! interpolation, static initialization, IMU preintegration between keyframes, and the IMU-rate
//! fast path that follows the estimator's INS from another thread ([`fast_path`]).

pub mod covariance;
pub mod fast_path;
pub mod imu;
pub mod increment;
pub mod init;
pub mod ins;
pub mod motion_init;
pub mod preintegration;
pub mod smooth;
pub mod state;
pub mod window;

pub use covariance::InsCovariance;
pub use fast_path::{FastPath, FastPathCounters, InsUpdate};
pub use imu::{ImuNoise, ImuSample};
pub use init::{StaticInitConfig, StaticInitializer, StaticStats};
pub use ins::{Ins, InsConfig};
pub use motion_init::{MotionInitConfig, MotionInitializer, Refusal};
pub use preintegration::{Mat15, PreintConfig, Preintegration, Vec15};
pub use smooth::OutputSmoother;
pub use state::{state_from_full, NavState};
pub use window::InsWindow;

//! Inertial layer: IMU samples and noise, INS mechanization, the INS state window with pose
//! interpolation, static initialization, and IMU preintegration between keyframes.

pub mod imu;
pub mod state;

pub use imu::{ImuNoise, ImuSample};
pub use state::NavState;

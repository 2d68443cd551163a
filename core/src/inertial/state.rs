//! The navigation state of the body (IMU) frame.

use crate::math::{Quat, Vec3};

/// Full INS state at one instant: pose and velocity of the body frame `b` in the world frame `w`
/// (z up), and the IMU biases (in `b`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState {
    /// Time, integer nanoseconds.
    pub t_ns: i64,
    /// Position of the body origin in `w`, m.
    pub p_wb: Vec3,
    /// Rotation body -> world.
    pub q_wb: Quat,
    /// Velocity of the body in `w`, m/s.
    pub v_wb: Vec3,
    /// Gyro bias, rad/s.
    pub bg: Vec3,
    /// Accelerometer bias, m/s^2.
    pub ba: Vec3,
}

impl NavState {
    /// Every number zero, the attitude too (not a unit quaternion: storage to overwrite, not a
    /// state to use). All bits zero, for `static` buffers.
    pub const ZERO: NavState = NavState {
        t_ns: 0,
        p_wb: crate::math::VEC3_ZERO,
        q_wb: Quat::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0)),
        v_wb: crate::math::VEC3_ZERO,
        bg: crate::math::VEC3_ZERO,
        ba: crate::math::VEC3_ZERO,
    };

    /// A state at rest at the origin with identity attitude and zero biases.
    pub const fn identity(t_ns: i64) -> Self {
        NavState {
            t_ns,
            p_wb: crate::math::VEC3_ZERO,
            q_wb: crate::math::QUAT_IDENTITY,
            v_wb: crate::math::VEC3_ZERO,
            bg: crate::math::VEC3_ZERO,
            ba: crate::math::VEC3_ZERO,
        }
    }
}

//! The navigation state of the body (IMU) frame, and its validation for starting the INS
//! ([`state_from_full`]).

use crate::math::{Quat, Vec3};
use crate::Error;

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

/// Validates a full state for starting the INS: every component finite and the quaternion
/// re-normalized ([`Error::NonFinite`], or [`Error::Degenerate`] for a (near-)zero quaternion).
pub fn state_from_full(s: &NavState) -> Result<NavState, Error> {
    let all_finite = s
        .p_wb
        .iter()
        .chain(s.v_wb.iter())
        .chain(s.bg.iter())
        .chain(s.ba.iter())
        .chain(s.q_wb.coords.iter())
        .all(|x| x.is_finite());
    if !all_finite {
        return Err(Error::NonFinite);
    }
    if s.q_wb.coords.norm() < 1e-6 {
        return Err(Error::Degenerate);
    }
    Ok(NavState {
        q_wb: renormalize(s.q_wb),
        ..*s
    })
}

/// Renormalizes a quaternion that drifted from unit norm by rounding.
pub(crate) fn renormalize(q: Quat) -> Quat {
    Quat::new_normalize(q.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_state_validation() {
        let mut s = NavState::identity(3);
        s.q_wb = Quat::new_unchecked(nalgebra::Quaternion::new(2.0, 0.0, 0.0, 0.0));
        let v = state_from_full(&s).unwrap();
        assert!((v.q_wb.coords.norm() - 1.0).abs() < 1e-15);
        s.q_wb = Quat::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));
        assert_eq!(state_from_full(&s).err(), Some(Error::Degenerate));
        s.bg.z = f64::INFINITY;
        assert_eq!(state_from_full(&s).err(), Some(Error::NonFinite));
    }
}

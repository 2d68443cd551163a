//! SO(3) exponential/logarithm and right Jacobians.
//!
//! `Exp(phi) = I + sin|phi|/|phi| [phi]x + (1-cos|phi|)/|phi|^2 [phi]x^2`;
//! `Jr(phi) = I - (1-cos|phi|)/|phi|^2 [phi]x + (|phi|-sin|phi|)/|phi|^3 [phi]x^2` so that
//! `Exp(phi + dphi) ~= Exp(phi) Exp(Jr(phi) dphi)`. Small angles use Taylor series to stay exact.

use super::{Mat3, Quat, Vec3};
use nalgebra::Quaternion;

/// Skew-symmetric matrix: `skew(a) * b == a.cross(&b)`.
#[inline]
pub fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Quaternion exponential of a rotation vector (`Exp(phi)` as a unit quaternion).
#[inline]
pub fn quat_exp(phi: &Vec3) -> Quat {
    let theta2 = phi.norm_squared();
    let theta = libm::sqrt(theta2);
    let half = 0.5 * theta;
    let (w, k) = if theta < 1e-8 {
        // sin(t/2)/t ~= 1/2 - t^2/48
        (1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0)
    } else {
        (libm::cos(half), libm::sin(half) / theta)
    };
    Quat::new_unchecked(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

/// Rotation matrix `Exp(phi)`.
#[inline]
pub fn exp_so3(phi: &Vec3) -> Mat3 {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    let (a, b) = if theta2 < 1e-10 {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        let theta = libm::sqrt(theta2);
        (libm::sin(theta) / theta, (1.0 - libm::cos(theta)) / theta2)
    };
    Mat3::identity() + k * a + k * k * b
}

/// Rotation vector of a unit quaternion, `Log(q)`, with angle in `[0, pi]`.
#[inline]
pub fn log_so3(q: &Quat) -> Vec3 {
    let q = q.quaternion();
    // Pick the hemisphere with w >= 0 so the angle is the short one.
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let n = v.norm();
    if n < 1e-8 {
        // atan2(n, w) / n ~= 1/w - n^2/(3 w^3)
        v * (2.0 / w - 2.0 * n * n / (3.0 * w * w * w))
    } else {
        v * (2.0 * libm::atan2(n, w) / n)
    }
}

/// Right Jacobian of SO(3).
#[inline]
pub fn jr_so3(phi: &Vec3) -> Mat3 {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    let (a, b) = if theta2 < 1e-10 {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        let theta = libm::sqrt(theta2);
        (
            (1.0 - libm::cos(theta)) / theta2,
            (theta - libm::sin(theta)) / (theta2 * theta),
        )
    };
    Mat3::identity() - k * a + k * k * b
}

/// Inverse of the right Jacobian of SO(3).
#[inline]
pub fn jr_inv_so3(phi: &Vec3) -> Mat3 {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    let c = if theta2 < 1e-10 {
        1.0 / 12.0 + theta2 / 720.0
    } else {
        let theta = libm::sqrt(theta2);
        1.0 / theta2 - (1.0 + libm::cos(theta)) / (2.0 * theta * libm::sin(theta))
    };
    Mat3::identity() + k * 0.5 + k * k * c
}

#[cfg(test)]
mod tests {
    use super::*;

    fn num_jr(phi: &Vec3) -> Mat3 {
        // Exp(phi + d) = Exp(phi) Exp(Jr d)  =>  Jr column i = Log(Exp(phi)^T Exp(phi + h e_i)) / h
        let h = 1e-6;
        let q0 = quat_exp(phi);
        let mut m = Mat3::zeros();
        for i in 0..3 {
            let mut d = *phi;
            d[i] += h;
            let dq = q0.inverse() * quat_exp(&d);
            m.set_column(i, &(log_so3(&dq) / h));
        }
        m
    }

    #[test]
    fn exp_log_round_trip_and_matrix_agree() {
        for phi in [
            Vec3::new(0.1, -0.2, 0.3),
            Vec3::new(1e-9, 2e-9, -1e-9),
            Vec3::new(3.0, 0.1, 0.0),
        ] {
            let q = quat_exp(&phi);
            assert!((log_so3(&q) - phi).norm() < 1e-12);
            assert!((q.to_rotation_matrix().into_inner() - exp_so3(&phi)).norm() < 1e-12);
        }
    }

    #[test]
    fn right_jacobian_matches_numerical_and_inverse() {
        for phi in [
            Vec3::new(0.1, -0.2, 0.3),
            Vec3::new(1e-7, 0.0, 0.0),
            Vec3::new(1.5, -0.5, 0.7),
        ] {
            let jr = jr_so3(&phi);
            assert!((jr - num_jr(&phi)).norm() < 1e-6, "Jr mismatch at {phi:?}");
            assert!((jr * jr_inv_so3(&phi) - Mat3::identity()).norm() < 1e-10);
        }
    }
}

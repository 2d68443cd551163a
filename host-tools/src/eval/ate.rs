//! Absolute trajectory error, as evo's APE defines it, on matched and aligned poses:
//!
//! - position: `e_i = |p_w,gt,i - p_w,est,i|` (evo `-r trans_part`, its default), m;
//! - rotation: `e_i = |Log(R_gt,i^T R_est,i)|` (evo `-r angle_deg`: the angle of the relative
//!   pose `T_gt^-1 T_est`), degrees.
//!
//! Angles come from the quaternion (`2 atan2(|v|, |w|)`), which stays accurate near zero where
//! `acos((tr R - 1) / 2)` would lose half the digits.

use povins_core::math::{log_so3, Quat, Vec3};

/// Angle of the rotation between two orientations, degrees.
pub fn rotation_error_deg(q_wb_gt: &Quat, q_wb_est: &Quat) -> f64 {
    log_so3(&(q_wb_gt.inverse() * q_wb_est)).norm().to_degrees()
}

/// Distance between two positions, m.
pub fn position_error_m(p_wb_gt: &Vec3, p_wb_est: &Vec3) -> f64 {
    (p_wb_gt - p_wb_est).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::math::quat_exp;

    #[test]
    fn errors_of_known_perturbations() {
        let q = quat_exp(&Vec3::new(0.3, -1.0, 2.0));
        let dq = quat_exp(&(Vec3::new(1.0, 2.0, -2.0) / 3.0 * 0.5f64.to_radians()));
        assert!((rotation_error_deg(&q, &(q * dq)) - 0.5).abs() < 1e-12);
        assert!((rotation_error_deg(&q, &(dq * q)) - 0.5).abs() < 1e-12);
        // A tiny angle keeps its digits (acos of the trace would return 0 here). Composing with
        // `q` costs ~1e-16 absolute in the quaternion, hence the absolute tolerance.
        let tiny = quat_exp(&Vec3::new(1e-9, 0.0, 0.0));
        let e = rotation_error_deg(&q, &(q * tiny));
        assert!((e - 1e-9f64.to_degrees()).abs() < 1e-13, "{e}");
        let e = rotation_error_deg(&Quat::identity(), &tiny);
        assert!((e - 1e-9f64.to_degrees()).abs() < 1e-21, "{e}");
        // q and -q are the same orientation.
        let neg = Quat::new_unchecked(-q.into_inner());
        assert!(rotation_error_deg(&q, &neg) < 1e-12);
        assert_eq!(
            position_error_m(&Vec3::new(1.0, 2.0, 3.0), &Vec3::new(4.0, 6.0, 3.0)),
            5.0
        );
    }
}

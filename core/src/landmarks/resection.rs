//! Camera resection: the pose of one camera from landmarks of known world position and their
//! observations in it (perspective-n-point), refined from an initial pose by Gauss–Newton with a
//! robust weight. Used after a bridged IMU gap, where the INS's pose is a guess and the window's
//! landmarks are not (`crate::estimator`'s gap check).
//!
//! Residual of a landmark `p_w` observed at the normalized point `x_n` (z = 1) in a camera at
//! `(p_wc, R_wc)`: `r = pi(P_c) - x_n`, `P_c = R_wc^T (p_w - p_wc)`, `pi(P) = (X/Z, Y/Z)`. The
//! pose is perturbed on the right, `R_wc <- R_wc Exp(dtheta)`, `p_wc <- p_wc + dp`, so
//! `dP_c/ddtheta = [P_c]x` and `dP_c/ddp = -R_wc^T` ([`reprojection_jacobian`]).

use crate::camera::CameraPose;
use crate::math::{quat_exp, skew, Vec3};
use nalgebra::{SMatrix, SVector};

/// Fewest landmarks a pose is fitted from.
pub const MIN_POINTS: usize = 8;
/// Fewest inliers a fit must keep.
pub const MIN_INLIERS: usize = 6;
/// Gauss–Newton iterations, at most.
const ITERATIONS: usize = 40;
/// Iterations before the points beyond [`INLIER_PX`] are left out (or fewer, once converged).
const ROBUST_ITERATIONS: usize = 30;
/// Huber threshold, px.
const HUBER_PX: f64 = 2.0;
/// An inlier's largest reprojection error, px.
pub const INLIER_PX: f64 = 4.0;
/// Nearest a landmark may be in front of the camera, m.
const MIN_DEPTH_M: f64 = 0.05;

/// A fitted camera pose ([`fit_camera_pose`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseFit {
    /// The camera pose (camera -> world).
    pub pose: CameraPose,
    /// Landmarks within [`INLIER_PX`] of their observation.
    pub inliers: usize,
    /// RMS reprojection error of the inliers, px.
    pub rms_px: f64,
}

/// The residual `pi(P_c) - x_n` and its Jacobian in `(dtheta, dp)` (see the module docs), or
/// `None` when the landmark is not at least [`MIN_DEPTH_M`] in front of the camera.
pub fn reprojection_jacobian(
    pose: &CameraPose,
    p_w: &Vec3,
    x_n: &[f64; 2],
) -> Option<(SVector<f64, 2>, SMatrix<f64, 2, 6>)> {
    let r_cw = pose.q_wc.inverse();
    let p_c = r_cw * (p_w - pose.p_wc);
    if !p_c.z.is_finite() || p_c.z < MIN_DEPTH_M {
        return None;
    }
    let iz = 1.0 / p_c.z;
    let r = SVector::<f64, 2>::new(p_c.x * iz - x_n[0], p_c.y * iz - x_n[1]);
    let j_p = SMatrix::<f64, 2, 3>::new(iz, 0.0, -p_c.x * iz * iz, 0.0, iz, -p_c.y * iz * iz);
    let mut j = SMatrix::<f64, 2, 6>::zeros();
    j.fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_p * skew(&p_c)));
    j.fixed_view_mut::<2, 3>(0, 3)
        .copy_from(&(-j_p * r_cw.to_rotation_matrix().matrix()));
    Some((r, j))
}

/// The camera pose that best reprojects `points` (`(p_w, x_n)`: world position, normalized
/// observation) from `init`, `focal_px` converting normalized units to pixels for the robust
/// weight and the inlier gate. `None`: fewer than [`MIN_POINTS`] points or inliers, a singular
/// system, or a non-finite result.
pub fn fit_camera_pose(
    points: &[(Vec3, [f64; 2])],
    init: &CameraPose,
    focal_px: f64,
) -> Option<PoseFit> {
    if points.len() < MIN_POINTS || !focal_px.is_finite() || focal_px <= 0.0 {
        return None;
    }
    let mut pose = *init;
    // Huber-weighted until converged, then once more with only the points near their
    // observation.
    let mut gated = false;
    for it in 0..ITERATIONS {
        gated |= it >= ROBUST_ITERATIONS;
        let gate = gated.then_some(INLIER_PX / focal_px);
        let (h, b, n) = normal_equations(points, &pose, HUBER_PX / focal_px, gate);
        if n < MIN_INLIERS {
            return None;
        }
        let dx = h.cholesky()?.solve(&(-b));
        if !dx.iter().all(|v| v.is_finite()) {
            return None;
        }
        let dtheta = Vec3::new(dx[0], dx[1], dx[2]);
        pose = CameraPose {
            q_wc: pose.q_wc * quat_exp(&dtheta),
            p_wc: pose.p_wc + Vec3::new(dx[3], dx[4], dx[5]),
        };
        if dx.norm() < 1e-10 {
            if gated {
                break;
            }
            gated = true;
        }
    }
    let (inliers, sq) = inliers_at(points, &pose, focal_px);
    let finite = pose
        .p_wc
        .iter()
        .chain(pose.q_wc.coords.iter())
        .all(|v| v.is_finite());
    (finite && inliers >= MIN_INLIERS).then(|| PoseFit {
        pose,
        inliers,
        rms_px: libm::sqrt(sq / inliers as f64),
    })
}

/// The points within [`INLIER_PX`] of their observation at `pose`, and the sum of their squared
/// reprojection errors, px^2.
pub fn inliers_at(points: &[(Vec3, [f64; 2])], pose: &CameraPose, focal_px: f64) -> (usize, f64) {
    let (mut inliers, mut sq) = (0usize, 0.0);
    for (p_w, x_n) in points {
        if let Some((r, _)) = reprojection_jacobian(pose, p_w, x_n) {
            let e_px = r.norm() * focal_px;
            if e_px <= INLIER_PX {
                inliers += 1;
                sq += e_px * e_px;
            }
        }
    }
    (inliers, sq)
}

/// The Huber-weighted normal equations `(J^T W J, J^T W r)` at `pose`, and the number of points
/// in them; with a `gate` (normalized units), the points beyond it are left out.
fn normal_equations(
    points: &[(Vec3, [f64; 2])],
    pose: &CameraPose,
    huber: f64,
    gate: Option<f64>,
) -> (SMatrix<f64, 6, 6>, SVector<f64, 6>, usize) {
    let mut h = SMatrix::<f64, 6, 6>::zeros();
    let mut b = SVector::<f64, 6>::zeros();
    let mut n = 0;
    for (p_w, x_n) in points {
        let Some((r, j)) = reprojection_jacobian(pose, p_w, x_n) else {
            continue;
        };
        let e = r.norm();
        if gate.is_some_and(|g| e > g) || !e.is_finite() {
            continue;
        }
        let w = if e <= huber { 1.0 } else { huber / e };
        h += j.transpose() * j * w;
        b += j.transpose() * r * w;
        n += 1;
    }
    (h, b, n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Quat;
    use heapless::Vec as HVec;

    fn scene(truth: &CameraPose) -> HVec<(Vec3, [f64; 2]), 64> {
        let mut pts = HVec::new();
        for k in 0..40 {
            let k = f64::from(k);
            // Points 2-6 m in front of the camera, spread over the view.
            let p_c = Vec3::new(
                libm::sin(k * 1.7) * 1.5,
                libm::cos(k * 2.3) * 1.0,
                4.0 + 2.0 * libm::sin(k * 0.9),
            );
            let p_w = truth.q_wc * p_c + truth.p_wc;
            let _ = pts.push((p_w, [p_c.x / p_c.z, p_c.y / p_c.z]));
        }
        pts
    }

    #[test]
    fn the_pose_is_found_from_far_off_and_outliers_are_left_out() {
        let truth = CameraPose {
            p_wc: Vec3::new(1.0, -2.0, 0.5),
            q_wc: Quat::from_euler_angles(0.3, -0.2, 1.0),
        };
        let mut pts = scene(&truth);
        // Five wrong tracks, 30-70 px off at 400 px focal.
        for k in 0..5 {
            if let Some(p) = pts.get_mut(k * 7) {
                p.1[0] += 0.08 + 0.02 * k as f64;
            }
        }
        // Off by 0.5 rad and 0.4 m.
        let init = CameraPose {
            p_wc: truth.p_wc + Vec3::new(0.3, 0.2, -0.2),
            q_wc: truth.q_wc * quat_exp(&Vec3::new(0.3, -0.3, 0.25)),
        };
        let fit = fit_camera_pose(&pts, &init, 400.0).expect("a fit");
        assert_eq!(fit.inliers, 35);
        assert!(fit.rms_px < 1e-6, "{}", fit.rms_px);
        assert!((fit.pose.p_wc - truth.p_wc).norm() < 1e-6);
        assert!(fit.pose.q_wc.angle_to(&truth.q_wc) < 1e-6);
        // Too few points: no fit.
        assert!(fit_camera_pose(&pts[1..MIN_POINTS], &init, 400.0).is_none());
        // Every point behind the camera: no fit.
        let behind = CameraPose {
            q_wc: truth.q_wc * quat_exp(&Vec3::new(0.0, core::f64::consts::PI, 0.0)),
            ..truth
        };
        assert!(fit_camera_pose(&pts, &behind, 400.0).is_none());
        // NaN input: no fit, no panic.
        let mut bad = pts.clone();
        for p in bad.iter_mut() {
            p.0.x = f64::NAN;
        }
        assert!(fit_camera_pose(&bad, &init, 400.0).is_none());
    }
}

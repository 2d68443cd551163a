//! The velocity NEES (normalized estimation error squared) of a run's IMU-rate output: how well
//! the covariance the estimator reports ([`povins_core::inertial::InsCovariance`]) describes its
//! actual error against the ground truth. Two velocities:
//!
//! - **body** (`v_b = R_wb^T v_wb`, what MAVLink's `ODOMETRY` carries, in the body frame):
//!   `e = v_b - R_gt^T v_gt`, covariance `J P J^T` with `J = [[v_b]x, R_wb^T]` over the error
//!   `[theta, v]` (`R_wb Exp(theta)`: `dv_b = R^T dv + [v_b]x theta`). No alignment: a
//!   body-frame velocity does not depend on the world's yaw, which a VIO cannot observe.
//! - **world** (`v_wb`): `e = R v_wb - v_gt` with `R` the ATE alignment's rotation, covariance
//!   `R P_v R^T`: the yaw the estimate drifted by since the alignment counts as error, and the
//!   covariance carries the yaw uncertainty only as far as the window's prior does.
//!
//! `NEES = e^T C^-1 e`; a consistent 3-DoF estimate averages 3 (median 2.37): below, the
//! covariance is too large (pessimistic); above, too small (overconfident).

use anyhow::Result;
use povins_core::inertial::NavState;
use povins_core::math::{skew, Mat3, Quat, Vec3};

/// Mean and median of one NEES.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct NeesStats {
    /// Mean NEES (3 when consistent).
    pub mean: f64,
    /// Median NEES (2.37 when consistent: the chi-square median with 3 DoF).
    pub median: f64,
}

impl NeesStats {
    fn of(mut v: Vec<f64>) -> Option<Self> {
        if v.is_empty() {
            return None;
        }
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.sort_by(f64::total_cmp);
        Some(NeesStats {
            mean,
            median: v[v.len() / 2],
        })
    }
}

/// What [`velocity_nees`] measures.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Nees {
    /// States compared (with a covariance and ground truth at their stamp).
    pub samples: usize,
    /// Of the body-frame velocity.
    pub body: NeesStats,
    /// Of the world-frame velocity after the alignment.
    pub world: NeesStats,
}

/// `e^T C^-1 e`, `None` when `C` is not positive definite or the result not finite.
fn nees(e: &Vec3, c: &Mat3) -> Option<f64> {
    let x = c.cholesky()?.solve(e);
    Some(e.dot(&x)).filter(|v| v.is_finite())
}

/// The velocity NEES of `rows` (stamp bits, `q_wb` x y z w, `v_wb`, the upper triangle of the
/// `[theta, v]` covariance: see `report::digest::velocity_row`) against the ground truth `gt_at`
/// (interpolated, `None` outside its span), the world's with the alignment `q_align`. `None`
/// when nothing could be compared; states whose covariance is not positive definite are
/// skipped.
pub fn velocity_nees(
    rows: impl Iterator<Item = Result<[f64; 29]>>,
    mut gt_at: impl FnMut(i64) -> Option<NavState>,
    q_align: &Quat,
) -> Result<Option<Nees>> {
    let r_align = q_align.to_rotation_matrix().into_inner();
    let (mut body, mut world) = (Vec::new(), Vec::new());
    for row in rows {
        let v = row?;
        let Some(gt) = gt_at(v[0].to_bits() as i64) else {
            continue;
        };
        let q = Quat::new_normalize(nalgebra::Quaternion::new(v[4], v[1], v[2], v[3]));
        let v_w = Vec3::new(v[5], v[6], v[7]);
        let mut p = nalgebra::Matrix6::<f64>::zeros();
        let mut k = 8;
        for i in 0..6 {
            for j in i..6 {
                p[(i, j)] = v[k];
                p[(j, i)] = v[k];
                k += 1;
            }
        }
        let r_t = q.to_rotation_matrix().into_inner().transpose();
        let v_b = r_t * v_w;
        let mut jac = nalgebra::Matrix3x6::<f64>::zeros();
        jac.fixed_view_mut::<3, 3>(0, 0).copy_from(&skew(&v_b));
        jac.fixed_view_mut::<3, 3>(0, 3).copy_from(&r_t);
        let e_b = v_b - gt.q_wb.inverse() * gt.v_wb;
        let e_w = r_align * v_w - gt.v_wb;
        let p_v: Mat3 = p.fixed_view::<3, 3>(3, 3).into_owned();
        if let (Some(b), Some(w)) = (
            nees(&e_b, &(jac * p * jac.transpose())),
            nees(&e_w, &(r_align * p_v * r_align.transpose())),
        ) {
            body.push(b);
            world.push(w);
        }
    }
    let samples = body.len();
    Ok(NeesStats::of(body)
        .zip(NeesStats::of(world))
        .map(|(body, world)| Nees {
            samples,
            body,
            world,
        }))
}

#[cfg(test)]
mod tests;

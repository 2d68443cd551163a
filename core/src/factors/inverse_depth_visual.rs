//! Inverse-depth reprojection factor: the conventional-BA baseline and the building block of the
//! MSC-based LiDAR-depth measurement (paper eq. 25–26, math notes sec. 5 step 1).
//!
//! The landmark is `x_s' / tau` in camera `s` (`tau` = inverse depth, 1/m) and is carried into
//! camera `j` through the body poses and the extrinsic:
//!
//! ```text
//! P_cs = x_s' / tau
//! P_bs = R_bc P_cs + p_bc          P_w  = R_s P_bs + p_s
//! P_bj = R_j^T (P_w - p_j)         P_cj = R_bc^T (P_bj - p_bc)
//! r    = W (pi(P_cj) - x_j'),      W = diag(fx, fy) / sigma_p
//! ```
//!
//! Jacobians (right perturbations, `A = R_bc^T R_j^T`):
//! pose s `[A, -A R_s [P_bs]x]`; pose j `[-A, R_bc^T [P_bj]x]`;
//! extrinsic `[A R_s - R_bc^T, -A R_s R_bc [P_cs]x + [P_cj]x]`;
//! `tau`: `-A R_s R_bc x_s' / tau^2`; `td_s`: `A R_s R_bc (-v_s) / tau`; `td_j`: `W v_j`
//! (all pre-multiplied by `W d pi / dP`).

use super::{all_finite_ext, all_finite_pose, d_pi, KeyframePose, TimedObs, MIN_Z_REL};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::math::{skew, Mat3, Vec3};
use crate::Error;
use nalgebra::{Matrix2x6, SMatrix};

/// Residual and Jacobians of one inverse-depth reprojection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseDepthJacobians {
    /// Whitened residual on the normalized plane.
    pub r: Vec2,
    /// W.r.t. the body pose of the anchor `s`, `[dp, dtheta]`.
    pub d_pose_s: Matrix2x6<f64>,
    /// W.r.t. the body pose of the observing keyframe `j`.
    pub d_pose_j: Matrix2x6<f64>,
    /// W.r.t. the extrinsic `[dp_bc, dtheta_bc]`.
    pub d_ext: Matrix2x6<f64>,
    /// W.r.t. the inverse depth `tau` (m).
    pub d_tau: Vec2,
    /// W.r.t. the time delays of `s` and `j` (1/s).
    pub d_td: [Vec2; 2],
}

/// Observation `j` of a landmark parameterized by its inverse depth in anchor keyframe `s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseDepthVisualFactor {
    /// Anchor keyframe.
    pub kf_s: usize,
    /// Observing keyframe (`!= kf_s`).
    pub kf_j: usize,
    /// Observation in the anchor.
    pub obs_s: TimedObs,
    /// Observation in `j`.
    pub obs_j: TimedObs,
    /// Whitening `f / sigma_p` per axis.
    pub sqrt_info: Vec2,
}

struct Chain {
    x_s: Vec3,
    x_j: Vec3,
    p_cs: Vec3,
    p_bs: Vec3,
    p_bj: Vec3,
    p_cj: Vec3,
    r_s: Mat3,
    r_bc: Mat3,
    a: Mat3,
}

impl InverseDepthVisualFactor {
    fn chain(
        &self,
        s: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<Chain, Error> {
        if self.kf_s == self.kf_j {
            return Err(Error::Degenerate);
        }
        let finite = self.obs_s.is_finite()
            && self.obs_j.is_finite()
            && all_finite_pose(s)
            && all_finite_pose(j)
            && all_finite_ext(ext)
            && tau.is_finite();
        if !finite {
            return Err(Error::NonFinite);
        }
        if !(self.sqrt_info.x > 0.0 && self.sqrt_info.y > 0.0) {
            return Err(Error::InvalidConfig);
        }
        if tau <= 0.0 {
            return Err(Error::Degenerate);
        }
        let r_s = s.q_wb.to_rotation_matrix().into_inner();
        let r_j = j.q_wb.to_rotation_matrix().into_inner();
        let r_bc = ext.q_bc.to_rotation_matrix().into_inner();
        let x_s = self.obs_s.corrected(s.td);
        let x_j = self.obs_j.corrected(j.td);
        let p_cs = x_s / tau;
        let p_bs = r_bc * p_cs + ext.p_bc;
        let p_w = r_s * p_bs + s.p_wb;
        let p_bj = r_j.transpose() * (p_w - j.p_wb);
        let p_cj = r_bc.transpose() * (p_bj - ext.p_bc);
        if !p_cj.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        if p_cj.z <= MIN_Z_REL * p_cj.norm() {
            return Err(Error::Degenerate);
        }
        Ok(Chain {
            x_s,
            x_j,
            p_cs,
            p_bs,
            p_bj,
            p_cj,
            r_s,
            r_bc,
            a: r_bc.transpose() * r_j.transpose(),
        })
    }

    fn whitened(&self, c: &Chain) -> Vec2 {
        let pi = Vec2::new(c.p_cj.x / c.p_cj.z, c.p_cj.y / c.p_cj.z);
        (pi - c.x_j.xy()).component_mul(&self.sqrt_info)
    }

    /// Whitened residual only.
    ///
    /// Errors: [`Error::Degenerate`] for `kf_s == kf_j`, `tau <= 0` or a point not in front of
    /// camera `j`; [`Error::NonFinite`]; [`Error::InvalidConfig`] for a non-positive whitening.
    pub fn residual(
        &self,
        s: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<Vec2, Error> {
        Ok(self.whitened(&self.chain(s, j, ext, tau)?))
    }

    /// Whitened residual and its derivative w.r.t. `tau` (what the 1-D depth solve needs).
    pub fn residual_and_d_tau(
        &self,
        s: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<(Vec2, Vec2), Error> {
        let c = self.chain(s, j, ext, tau)?;
        let h = self.projection_jacobian(&c);
        let d_tau = h * (c.a * c.r_s * c.r_bc * c.x_s) * (-1.0 / (tau * tau));
        Ok((self.whitened(&c), d_tau))
    }

    fn projection_jacobian(&self, c: &Chain) -> SMatrix<f64, 2, 3> {
        nalgebra::Matrix2::from_diagonal(&self.sqrt_info) * d_pi(&c.p_cj)
    }

    /// Whitened residual and all Jacobians.
    ///
    /// Errors: as [`Self::residual`].
    pub fn evaluate(
        &self,
        s: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<InverseDepthJacobians, Error> {
        let c = self.chain(s, j, ext, tau)?;
        let h = self.projection_jacobian(&c);
        let a_rs = c.a * c.r_s;
        let a_rs_rbc = a_rs * c.r_bc;

        let mut d_pose_s = Matrix2x6::zeros();
        d_pose_s.fixed_columns_mut::<3>(0).copy_from(&(h * c.a));
        d_pose_s
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (-(a_rs * skew(&c.p_bs)))));

        let mut d_pose_j = Matrix2x6::zeros();
        d_pose_j.fixed_columns_mut::<3>(0).copy_from(&(-(h * c.a)));
        d_pose_j
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (c.r_bc.transpose() * skew(&c.p_bj))));

        let mut d_ext = Matrix2x6::zeros();
        d_ext
            .fixed_columns_mut::<3>(0)
            .copy_from(&(h * (a_rs - c.r_bc.transpose())));
        d_ext
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (-(a_rs_rbc * skew(&c.p_cs)) + skew(&c.p_cj))));

        let d_tau = h * (a_rs_rbc * c.x_s) * (-1.0 / (tau * tau));
        let d_td_s = h * (a_rs_rbc * self.obs_s.d_corrected_d_td()) / tau;
        let d_td_j = self.obs_j.vel.component_mul(&self.sqrt_info);
        Ok(InverseDepthJacobians {
            r: self.whitened(&c),
            d_pose_s,
            d_pose_j,
            d_ext,
            d_tau,
            d_td: [d_td_s, d_td_j],
        })
    }
}

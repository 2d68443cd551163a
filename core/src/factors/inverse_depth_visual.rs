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

impl InverseDepthJacobians {
    /// The Jacobians without the extrinsic's.
    pub fn poses(&self) -> PoseJacobians {
        PoseJacobians {
            r: self.r,
            d_pose_s: self.d_pose_s,
            d_pose_j: self.d_pose_j,
            d_tau: self.d_tau,
            d_td: self.d_td,
        }
    }
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
    r_j: Mat3,
    r_bc: Mat3,
}

impl Chain {
    /// `A = R_bc^T R_j^T` (the residual alone does not need it).
    #[inline]
    fn a(&self) -> Mat3 {
        self.r_bc.transpose() * self.r_j.transpose()
    }
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
            r_j,
            r_bc,
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
        let d_tau = h * (c.a() * c.r_s * c.r_bc * c.x_s) * (-1.0 / (tau * tau));
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
        let a = c.a();
        let a_rs = a * c.r_s;
        let a_rs_rbc = a_rs * c.r_bc;

        let mut d_pose_s = Matrix2x6::zeros();
        d_pose_s.fixed_columns_mut::<3>(0).copy_from(&(h * a));
        d_pose_s
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (-(a_rs * skew(&c.p_bs)))));

        let mut d_pose_j = Matrix2x6::zeros();
        d_pose_j.fixed_columns_mut::<3>(0).copy_from(&(-(h * a)));
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

/// Rotations of a window formed once for many [`InverseDepthVisualFactor`] evaluations on the
/// same poses and extrinsic: each matrix is formed with the same operations on the same operands
/// as [`InverseDepthVisualFactor::evaluate`] forms it per call, so
/// [`InverseDepthVisualFactor::evaluate_poses`] is bit-identical to it.
#[derive(Debug, Clone)]
pub struct WindowRotations<const N: usize> {
    r_wb: [Mat3; N],
    r_bw: [Mat3; N],
    /// `R_bc^T R_j^T` per keyframe `j`.
    a: [Mat3; N],
    /// `A_j R_s` and `A_j R_s R_bc` per pair `[j][s]`.
    a_rs: [[(Mat3, Mat3); N]; N],
    r_bc: Mat3,
    r_cb: Mat3,
    p_bc: Vec3,
    finite: [bool; N],
    ext_finite: bool,
}

impl<const N: usize> WindowRotations<N> {
    /// The rotations of the first `count` keyframes of `poses` (the others are the identity).
    pub fn new(poses: &[KeyframePose; N], count: usize, ext: &CameraExtrinsic) -> Self {
        let r_bc = ext.q_bc.to_rotation_matrix().into_inner();
        let r_wb: [Mat3; N] = core::array::from_fn(|k| match poses.get(k) {
            Some(p) if k < count => p.q_wb.to_rotation_matrix().into_inner(),
            _ => Mat3::identity(),
        });
        let r_bw: [Mat3; N] = core::array::from_fn(|k| r_wb[k].transpose());
        let a: [Mat3; N] = core::array::from_fn(|k| r_bc.transpose() * r_bw[k]);
        let a_rs = core::array::from_fn(|j| {
            core::array::from_fn(|s| {
                if j < count && s < count {
                    let a_rs = a[j] * r_wb[s];
                    (a_rs, a_rs * r_bc)
                } else {
                    (Mat3::identity(), Mat3::identity())
                }
            })
        });
        WindowRotations {
            r_wb,
            r_bw,
            a,
            a_rs,
            r_bc,
            r_cb: r_bc.transpose(),
            p_bc: ext.p_bc,
            finite: core::array::from_fn(|k| poses.get(k).is_some_and(all_finite_pose)),
            ext_finite: all_finite_ext(ext),
        }
    }
}

/// The anchor's side of an [`InverseDepthVisualFactor`] at one inverse depth: the landmark in
/// camera `s`, body `s` and the world, shared by all the landmark's observations.
#[derive(Debug, Clone, Copy)]
pub struct AnchorPoint {
    x_s: Vec3,
    p_bs: Vec3,
    p_w: Vec3,
    tau: f64,
}

/// Residual and the Jacobians [`InverseDepthVisualFactor::evaluate_poses`] returns (those of
/// [`InverseDepthJacobians`] without the extrinsic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseJacobians {
    /// Whitened residual on the normalized plane.
    pub r: Vec2,
    /// W.r.t. the body pose of the anchor `s`.
    pub d_pose_s: Matrix2x6<f64>,
    /// W.r.t. the body pose of the observing keyframe `j`.
    pub d_pose_j: Matrix2x6<f64>,
    /// W.r.t. the inverse depth.
    pub d_tau: Vec2,
    /// W.r.t. the time delays of `s` and `j`.
    pub d_td: [Vec2; 2],
}

impl InverseDepthVisualFactor {
    /// The anchor side at `tau` (see [`AnchorPoint`]); `s` is the anchor's pose, `rot` the
    /// window's rotations for the extrinsic of the evaluation.
    pub fn anchor_point<const N: usize>(
        &self,
        s: &KeyframePose,
        rot: &WindowRotations<N>,
        tau: f64,
    ) -> AnchorPoint {
        let r_s = rot
            .r_wb
            .get(self.kf_s)
            .copied()
            .unwrap_or_else(Mat3::identity);
        let x_s = self.obs_s.corrected(s.td);
        let p_cs = x_s / tau;
        let p_bs = rot.r_bc * p_cs + rot.p_bc;
        AnchorPoint {
            x_s,
            p_bs,
            p_w: r_s * p_bs + s.p_wb,
            tau,
        }
    }

    /// [`Self::evaluate`] without the extrinsic Jacobian, from the window's rotations and the
    /// anchor point of the same `s` and `tau` (bit-identical values; an `Err` exactly when
    /// [`Self::evaluate`] fails).
    pub fn evaluate_poses<const N: usize>(
        &self,
        s: &KeyframePose,
        j: &KeyframePose,
        rot: &WindowRotations<N>,
        anchor: &AnchorPoint,
    ) -> Result<PoseJacobians, Error> {
        let tau = anchor.tau;
        if self.kf_s == self.kf_j {
            return Err(Error::Degenerate);
        }
        let pose_ok = |k: usize| rot.finite.get(k).copied().unwrap_or(false);
        let finite = self.obs_s.is_finite()
            && self.obs_j.is_finite()
            && pose_ok(self.kf_s)
            && pose_ok(self.kf_j)
            && all_finite_pose(s)
            && all_finite_pose(j)
            && rot.ext_finite
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
        let (Some(r_jt), Some(a), Some((a_rs, a_rs_rbc))) = (
            rot.r_bw.get(self.kf_j),
            rot.a.get(self.kf_j),
            rot.a_rs.get(self.kf_j).and_then(|row| row.get(self.kf_s)),
        ) else {
            return Err(Error::DimensionMismatch);
        };
        let x_j = self.obs_j.corrected(j.td);
        let p_bj = r_jt * (anchor.p_w - j.p_wb);
        let p_cj = rot.r_cb * (p_bj - rot.p_bc);
        if !p_cj.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        if p_cj.z <= MIN_Z_REL * p_cj.norm() {
            return Err(Error::Degenerate);
        }
        let h = nalgebra::Matrix2::from_diagonal(&self.sqrt_info) * d_pi(&p_cj);
        let ha = h * a;
        let mut d_pose_s = Matrix2x6::zeros();
        d_pose_s.fixed_columns_mut::<3>(0).copy_from(&ha);
        d_pose_s
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (-(a_rs * skew(&anchor.p_bs)))));
        let mut d_pose_j = Matrix2x6::zeros();
        d_pose_j.fixed_columns_mut::<3>(0).copy_from(&(-ha));
        d_pose_j
            .fixed_columns_mut::<3>(3)
            .copy_from(&(h * (rot.r_cb * skew(&p_bj))));
        let d_tau = h * (a_rs_rbc * anchor.x_s) * (-1.0 / (tau * tau));
        let d_td_s = h * (a_rs_rbc * self.obs_s.d_corrected_d_td()) / tau;
        let d_td_j = self.obs_j.vel.component_mul(&self.sqrt_info);
        let pi = Vec2::new(p_cj.x / p_cj.z, p_cj.y / p_cj.z);
        Ok(PoseJacobians {
            r: (pi - x_j.xy()).component_mul(&self.sqrt_info),
            d_pose_s,
            d_pose_j,
            d_tau,
            d_td: [d_td_s, d_td_j],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Quat;

    #[test]
    fn evaluate_poses_is_bit_identical_to_evaluate() {
        let mut seed = 99u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let q = |v: Vec3| Quat::from_scaled_axis(v);
        for _ in 0..50 {
            let poses: [KeyframePose; 4] = core::array::from_fn(|k| KeyframePose {
                p_wb: Vec3::new(rnd() * 0.2 + k as f64 * 0.3, rnd() * 0.2, rnd() * 0.1),
                q_wb: q(Vec3::new(rnd() * 0.2, rnd() * 0.2, rnd() * 0.2)),
                td: rnd() * 0.01,
            });
            let ext = CameraExtrinsic {
                p_bc: Vec3::new(rnd() * 0.1, rnd() * 0.1, rnd() * 0.1),
                q_bc: q(Vec3::new(rnd() * 0.1, rnd() * 0.1, rnd() * 0.1)),
            };
            let rot = WindowRotations::new(&poses, 3, &ext);
            let obs = |rnd: &mut dyn FnMut() -> f64| TimedObs {
                x_n: Vec2::new(rnd() * 0.4, rnd() * 0.4),
                vel: Vec2::new(rnd(), rnd()),
                td0: rnd() * 0.01,
            };
            let (s, j) = (1, if rnd() > 0.0 { 0 } else { 2 });
            let f = InverseDepthVisualFactor {
                kf_s: s,
                kf_j: j,
                obs_s: obs(&mut rnd),
                obs_j: obs(&mut rnd),
                sqrt_info: Vec2::new(450.0, 460.0),
            };
            let tau = 0.2 + rnd().abs();
            let anchor = f.anchor_point(&poses[s], &rot, tau);
            let lean = f.evaluate_poses(&poses[s], &poses[j], &rot, &anchor);
            match f.evaluate(&poses[s], &poses[j], &ext, tau) {
                Ok(full) => {
                    let lean = lean.unwrap();
                    let bits = |v: &[f64]| {
                        v.iter()
                            .map(|x| x.to_bits())
                            .collect::<heapless::Vec<u64, 12>>()
                    };
                    assert_eq!(bits(full.r.as_slice()), bits(lean.r.as_slice()));
                    assert_eq!(
                        bits(full.d_pose_s.as_slice()),
                        bits(lean.d_pose_s.as_slice())
                    );
                    assert_eq!(
                        bits(full.d_pose_j.as_slice()),
                        bits(lean.d_pose_j.as_slice())
                    );
                    assert_eq!(bits(full.d_tau.as_slice()), bits(lean.d_tau.as_slice()));
                    for k in 0..2 {
                        assert_eq!(bits(full.d_td[k].as_slice()), bits(lean.d_td[k].as_slice()));
                    }
                }
                Err(e) => assert_eq!(lean, Err(e)),
            }
        }
    }
}

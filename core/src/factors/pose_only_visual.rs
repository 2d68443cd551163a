//! Pose-only visual reprojection factor (paper eq. 19–23, math notes sec. 4).
//!
//! A landmark has anchor keyframes `s` and `e` (`s != e`); for every other observing keyframe
//! `j != s` (including `j == e`) the landmark in camera `j` is `P_j = d_s R_js x_s + t_js` with the
//! pose-only depth `d_s = -(a.b)/(a.a)` ([`crate::landmarks::pose_only`]). Because `pi` is
//! invariant to a positive scale, the factor uses the scale-free form that never divides by the
//! parallax:
//!
//! ```text
//! P~_j = -(a.b) R_js x_s + (a.a) t_js        (= (a.a) P_j)
//! r    = W (pi(P~_j) - x_j'),  W = diag(fx, fy) / sigma_p
//! ```
//!
//! with the time-delay corrected observations `x_k' = x_k - (td_k - td_k0) v_k` (`k = s, e, j`).
//!
//! Jacobians, with `D = -(a.b)`, `alpha = a.a`, `u_j = R_js x_s`:
//! `delta P~ = M_a delta a + M_b delta b + D delta u_j + alpha delta t_js`,
//! `M_a = 2 t_js a^T - u_j b^T`, `M_b = -u_j a^T`; `delta a`, `delta b` are chained to the camera
//! poses of `s`, `e` and to `x_s`, `x_e` by [`crate::landmarks::TwoView`], and
//! `delta u_j = -R_js [x_s]x dth_s + [u_j]x dth_j + R_js delta x_s`,
//! `delta t_js = R_j^T dp_s + [t_js]x dth_j - R_j^T dp_j` (camera-pose perturbations). Camera
//! blocks map to body and extrinsic blocks by `cam_to_body_ext`. When `j == e` the pose of `e`
//! plays both roles and its two Jacobians are summed (likewise its time delay).

use super::{
    all_finite_ext, all_finite_pose, cam_to_body_ext, d_pi, CamFrame, KeyframePose, TimedObs,
    MIN_Z_REL,
};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::landmarks::TwoView;
use crate::math::{skew, Mat3, Vec3};
use crate::Error;
use nalgebra::{Matrix2x6, SMatrix};

/// Residual and Jacobians of one pose-only reprojection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseOnlyJacobians {
    /// Whitened residual on the normalized plane (dimensionless, unit variance per axis).
    pub r: Vec2,
    /// W.r.t. the body pose of anchor `s`, `[dp, dtheta]`.
    pub d_pose_s: Matrix2x6<f64>,
    /// W.r.t. the body pose of anchor `e` (includes the `j` role when `j == e`).
    pub d_pose_e: Matrix2x6<f64>,
    /// W.r.t. the body pose of keyframe `j`; zero when `j == e`.
    pub d_pose_j: Matrix2x6<f64>,
    /// W.r.t. the extrinsic `[dp_bc, dtheta_bc]`.
    pub d_ext: Matrix2x6<f64>,
    /// W.r.t. the time delays of `s`, `e`, `j` (1/s); `d_td[2]` is zero when `j == e`.
    pub d_td: [Vec2; 3],
}

/// One observation `j` of a landmark anchored at keyframes `s` and `e`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseOnlyVisualFactor {
    /// Anchor keyframe `s` (first observation or LiDAR-depth frame).
    pub kf_s: usize,
    /// Anchor keyframe `e` (largest parallax).
    pub kf_e: usize,
    /// Observing keyframe `j` (may equal `kf_e`).
    pub kf_j: usize,
    /// Observation in `s`.
    pub obs_s: TimedObs,
    /// Observation in `e`.
    pub obs_e: TimedObs,
    /// Observation in `j` (equals `obs_e` when `j == e`).
    pub obs_j: TimedObs,
    /// Whitening `f / sigma_p` per axis.
    pub sqrt_info: Vec2,
}

/// Geometry shared by the evaluation paths.
struct Eval {
    two: TwoView,
    r_ew: Mat3,
    r_jw: Mat3,
    r_js: Mat3,
    t_js: Vec3,
    u_j: Vec3,
    p: Vec3,
    x_j: Vec3,
}

impl PoseOnlyVisualFactor {
    /// Checks the anchor structure: `s != e`, `s != j`, finite observations and a positive
    /// whitening. Errors: [`Error::Degenerate`], [`Error::NonFinite`], [`Error::InvalidConfig`].
    pub fn validate(&self) -> Result<(), Error> {
        if self.kf_s == self.kf_e || self.kf_s == self.kf_j {
            return Err(Error::Degenerate);
        }
        if !(self.obs_s.is_finite() && self.obs_e.is_finite() && self.obs_j.is_finite()) {
            return Err(Error::NonFinite);
        }
        if !(self.sqrt_info.x > 0.0 && self.sqrt_info.y > 0.0) {
            return Err(Error::InvalidConfig);
        }
        Ok(())
    }

    fn j_is_e(&self) -> bool {
        self.kf_j == self.kf_e
    }

    fn geometry(
        &self,
        s: &KeyframePose,
        e: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        frames: Option<&[CamFrame; 3]>,
    ) -> Result<(Eval, [CamFrame; 3]), Error> {
        self.validate()?;
        let j = if self.j_is_e() { e } else { j };
        if !(all_finite_pose(s) && all_finite_pose(e) && all_finite_pose(j) && all_finite_ext(ext))
        {
            return Err(Error::NonFinite);
        }
        let (cs, ce, cj) = match frames {
            Some([cs, ce, cj]) => (*cs, *ce, if self.j_is_e() { *ce } else { *cj }),
            None => (
                CamFrame::new(s, ext),
                CamFrame::new(e, ext),
                CamFrame::new(j, ext),
            ),
        };
        let x_s = self.obs_s.corrected(s.td);
        let x_e = self.obs_e.corrected(e.td);
        let x_j = self.obs_j.corrected(j.td);
        let (r_es, t_es) = ce.relative_from(&cs);
        let (r_js, t_js) = cj.relative_from(&cs);
        let two = TwoView::new(&x_s, &x_e, &r_es, &t_es);
        let alpha = two.a.norm_squared();
        let dd = -two.a.dot(&two.b);
        // dd = alpha * d_s: the landmark must be in front of camera s.
        let in_front_of_s = alpha > 0.0 && dd > 0.0;
        if !in_front_of_s {
            return Err(Error::Degenerate);
        }
        let u_j = r_js * x_s;
        let p = u_j * dd + t_js * alpha;
        if !p.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        if p.z <= MIN_Z_REL * p.norm() {
            return Err(Error::Degenerate);
        }
        Ok((
            Eval {
                two,
                r_ew: ce.r_wc.transpose(),
                r_jw: cj.r_wc.transpose(),
                r_js,
                t_js,
                u_j,
                p,
                x_j,
            },
            [cs, ce, cj],
        ))
    }

    fn whitened(&self, ev: &Eval) -> Vec2 {
        let pi = Vec2::new(ev.p.x / ev.p.z, ev.p.y / ev.p.z);
        (pi - ev.x_j.xy()).component_mul(&self.sqrt_info)
    }

    /// Whitened residual only. When `kf_j == kf_e`, `j` is ignored (pass `e` twice).
    ///
    /// Errors: see [`Self::validate`]; [`Error::Degenerate`] when the landmark is not in front of
    /// camera `s` or camera `j`, or the parallax is exactly zero.
    pub fn residual(
        &self,
        s: &KeyframePose,
        e: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
    ) -> Result<Vec2, Error> {
        let (ev, _) = self.geometry(s, e, j, ext, None)?;
        Ok(self.whitened(&ev))
    }

    /// [`Self::residual`] with the camera frames of `s`, `e`, `j` precomputed (`CamFrame::new`
    /// of the same poses and extrinsic; bit-identical result).
    pub fn residual_with_frames(
        &self,
        kfs: [&KeyframePose; 3],
        frames: &[CamFrame; 3],
        ext: &CameraExtrinsic,
    ) -> Result<Vec2, Error> {
        let (ev, _) = self.geometry(kfs[0], kfs[1], kfs[2], ext, Some(frames))?;
        Ok(self.whitened(&ev))
    }

    /// [`Self::evaluate`] with the camera frames precomputed (bit-identical result).
    pub fn evaluate_with_frames(
        &self,
        kfs: [&KeyframePose; 3],
        frames: &[CamFrame; 3],
        ext: &CameraExtrinsic,
    ) -> Result<PoseOnlyJacobians, Error> {
        self.evaluate_inner(kfs[0], kfs[1], kfs[2], ext, Some(frames))
    }

    /// Whitened residual and all Jacobians. When `kf_j == kf_e`, `j` is ignored (pass `e`
    /// twice) and the shared pose's blocks are summed into `d_pose_e` / `d_td[1]`.
    ///
    /// Errors: as [`Self::residual`].
    pub fn evaluate(
        &self,
        s: &KeyframePose,
        e: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
    ) -> Result<PoseOnlyJacobians, Error> {
        self.evaluate_inner(s, e, j, ext, None)
    }

    fn evaluate_inner(
        &self,
        s: &KeyframePose,
        e: &KeyframePose,
        j: &KeyframePose,
        ext: &CameraExtrinsic,
        frames: Option<&[CamFrame; 3]>,
    ) -> Result<PoseOnlyJacobians, Error> {
        let (ev, [cs, ce, cj]) = self.geometry(s, e, j, ext, frames)?;
        let two = &ev.two;
        let alpha = two.a.norm_squared();
        let dd = -two.a.dot(&two.b);

        let m_a = ev.t_js * (two.a.transpose() * 2.0) - ev.u_j * two.b.transpose();
        let m_b = -(ev.u_j * two.a.transpose());
        let ab = two.chain_ab::<3>(&m_a, &m_b, &ev.r_ew);

        // Terms through u_j and t_js.
        let d_th_s = ab.d_th_s - ev.r_js * skew(&two.x_s) * dd;
        let d_p_s = ab.d_p_s + ev.r_jw * alpha;
        let d_th_j = skew(&ev.u_j) * dd + skew(&ev.t_js) * alpha;
        let d_p_j = -(ev.r_jw * alpha);
        let d_xs = ab.d_xs + ev.r_js * dd;
        let d_xe = ab.d_xe;

        let w = Mat2x2::from_diagonal(&self.sqrt_info);
        let h: SMatrix<f64, 2, 3> = w * d_pi(&ev.p);

        let (bs, es) = cam_to_body_ext::<3>(&d_p_s, &d_th_s, &cs, ext);
        let (be, ee) = cam_to_body_ext::<3>(&ab.d_p_e, &ab.d_th_e, &ce, ext);
        let (bj, ej) = cam_to_body_ext::<3>(&d_p_j, &d_th_j, &cj, ext);

        let d_td_s = h * (d_xs * self.obs_s.d_corrected_d_td());
        let d_td_e = h * (d_xe * self.obs_e.d_corrected_d_td());
        // r contains -W x_j' and d x_j'/d td_j = -v_j.
        let d_td_j = self.obs_j.vel.component_mul(&self.sqrt_info);

        let d_ext = h * (es + ee + ej);
        let (d_pose_e, d_pose_j, d_td) = if self.j_is_e() {
            (
                h * (be + bj),
                Matrix2x6::zeros(),
                [d_td_s, d_td_e + d_td_j, Vec2::zeros()],
            )
        } else {
            (h * be, h * bj, [d_td_s, d_td_e, d_td_j])
        };
        Ok(PoseOnlyJacobians {
            r: self.whitened(&ev),
            d_pose_s: h * bs,
            d_pose_e,
            d_pose_j,
            d_ext,
            d_td,
        })
    }
}

type Mat2x2 = nalgebra::Matrix2<f64>;

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
//!
//! **Rank structure of the anchors.** `M_a delta a + M_b delta b = Q_j (S_a delta a + S_b delta b)`
//! with the per-observation `Q_j = W dpi [2 t_js, -u_j]` (2x2) and the
//! landmark-wide `S_a = [a^T; b^T]`, `S_b = [0; a^T]`. So for `j != e` the Jacobian on the body
//! pose of `e` is `Q_j E` with one `2 x 6` `E` per landmark, and the one on `s` is `Q_j F + G_j`
//! (`F` landmark-wide, `G_j` through `u_j` and `t_js`). [`PoseOnlyAnchors::pose_blocks`] returns
//! that form, so a landmark's `e`-block products reduce to `2 x 2` sums per observation.
//!
//! **Depth uncertainty** ([`PoseOnlyAnchors::with_depth_std`]). The residual of `j != e` treats
//! the anchors' depth as exact, but `d_s` carries the noise of `x_s` and `x_e` (std `sigma_d`,
//! [`crate::landmarks::depth_std`]). Its effect on `r_j` lies along `g_j = dr_j/dd_s = W dpi
//! alpha u_j` (the epipolar direction in image `j`), so the residual's covariance is
//! `I + sigma_d^2 g_j g_j^T` rather than `I`. With `k = sigma_d^2 |g_j|^2` the factor whitens by
//! `W_j = I - (1 - 1/sqrt(1 + k)) g^ g^T` (`g^ = g_j/|g_j|`): residual and Jacobian rows keep
//! their weight across the epipolar line (rotation and epipolar information) and lose it along
//! it in proportion to the depth uncertainty. Low-parallax landmarks then enter with the
//! information they have instead of being gated out. `W_j` is evaluated at the current state and
//! held fixed in the Jacobian (like the robust weight). For `j == e` the depth is fitted to
//! `x_e` itself, so `r_e` measures only the epipolar error: no inflation.

use super::{
    all_finite_ext, all_finite_pose, cam_to_body_ext, d_pi, CamFrame, KeyframePose, TimedObs,
    MIN_Z_REL,
};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::landmarks::pose_only::AbChainPre;
use crate::landmarks::TwoView;
use crate::math::{skew, Mat3, Vec3};
use crate::Error;
use core::cell::OnceCell;
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

/// The part of the pose-only reprojection that depends only on a landmark's anchors `s` and `e`
/// (their observations, camera frames and the two-view geometry). A landmark forms it once per
/// linearization or cost evaluation and then evaluates every observing keyframe `j` against it.
#[derive(Debug, Clone)]
pub struct PoseOnlyAnchors<'f> {
    kf_s: usize,
    kf_e: usize,
    obs_s: TimedObs,
    obs_e: TimedObs,
    sqrt_info: Vec2,
    td_e: f64,
    cs: &'f CamFrame,
    ce: &'f CamFrame,
    two: TwoView,
    /// `a.a`.
    alpha: f64,
    /// `-(a.b)` (`= alpha d_s`).
    dd: f64,
    /// The chain through `a` and `b`, formed on the first [`Self::evaluate`] (a cost-only
    /// evaluation never needs it).
    pre: OnceCell<AbChainPre>,
    /// `(F, E)` of the rank structure (module docs), formed on the first
    /// [`Self::pose_blocks`].
    shared: OnceCell<(Matrix2x6<f64>, Matrix2x6<f64>)>,
    /// `sigma_d^2` of the depth for the residual's depth term (module docs), m^2; 0 = none.
    depth_var: f64,
    /// `(X_s, X_e)`: the landmark-wide derivatives of `(S_a da + S_b db)` with respect to the
    /// observations `x_s` and `x_e`, formed on the first [`Self::td_jacobians`].
    shared_x: OnceCell<(SMatrix<f64, 2, 3>, SMatrix<f64, 2, 3>)>,
}

/// Whitened, robustly weighted residual of one observation `j` and its body-pose Jacobians in
/// the rank-structured form (module docs): on `s` `d_pose_s`, on `e` `q E` (plus `d_pose_j` when
/// `j == e`), on `j` `d_pose_j`. Camera extrinsic and time delays held fixed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseBlocks {
    /// `w r` (whitened residual times the robust weight's square root).
    pub r: Vec2,
    /// `w W dpi [2 t_js, -u_j]`: maps the landmark-wide [`PoseOnlyAnchors::shared_e`] to the
    /// observation's Jacobian on the pose of `e`.
    pub q: Mat2x2,
    /// W.r.t. the body pose of `s`, `[dp, dtheta]`.
    pub d_pose_s: Matrix2x6<f64>,
    /// W.r.t. the body pose of `j` (of `e` when `j == e`, to be added to `q E`).
    pub d_pose_j: Matrix2x6<f64>,
}

/// Geometry of one observation `j` against the anchors ([`PoseOnlyAnchors::geometry`]).
#[derive(Debug, Clone)]
pub struct InJ<'a> {
    cj: &'a CamFrame,
    r_js: Mat3,
    t_js: Vec3,
    u_j: Vec3,
    /// `P~_j = dd u_j + alpha t_js`.
    p: Vec3,
    x_j: Vec3,
    /// The depth-uncertainty whitening `W_j` (module docs), `None` for the identity.
    w_depth: Option<Mat2x2>,
    /// `j` is the anchor `e`.
    is_e: bool,
}

impl<'f> PoseOnlyAnchors<'f> {
    /// Anchors `s` (`kf_s`, observation `obs_s`, pose `s`, camera frame `cs`) and `e`; the
    /// frames must be `CamFrame::new` of the poses with `ext`. `rel_es` is
    /// `ce.relative_from(cs)` when the caller has it (a window evaluates every landmark against
    /// the same few keyframe pairs), `None` to compute it here; the result is bit-identical.
    ///
    /// Errors: [`Error::Degenerate`] when `kf_s == kf_e` or the landmark is not in front of
    /// camera `s` (zero parallax included), [`Error::NonFinite`] for non-finite input,
    /// [`Error::InvalidConfig`] for a non-positive whitening.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        (kf_s, kf_e): (usize, usize),
        obs_s: TimedObs,
        obs_e: TimedObs,
        sqrt_info: Vec2,
        (s, e): (&KeyframePose, &KeyframePose),
        (cs, ce): (&'f CamFrame, &'f CamFrame),
        ext: &CameraExtrinsic,
        rel_es: Option<(Mat3, Vec3)>,
    ) -> Result<Self, Error> {
        if kf_s == kf_e {
            return Err(Error::Degenerate);
        }
        if !(obs_s.is_finite() && obs_e.is_finite()) {
            return Err(Error::NonFinite);
        }
        if !(sqrt_info.x > 0.0 && sqrt_info.y > 0.0) {
            return Err(Error::InvalidConfig);
        }
        if !(all_finite_pose(s) && all_finite_pose(e) && all_finite_ext(ext)) {
            return Err(Error::NonFinite);
        }
        let x_s = obs_s.corrected(s.td);
        let x_e = obs_e.corrected(e.td);
        let (r_es, t_es) = rel_es.unwrap_or_else(|| ce.relative_from(cs));
        let two = TwoView::new(&x_s, &x_e, &r_es, &t_es);
        let alpha = two.a.norm_squared();
        let dd = -two.a.dot(&two.b);
        // dd = alpha * d_s: the landmark must be in front of camera s.
        let in_front_of_s = alpha > 0.0 && dd > 0.0;
        if !in_front_of_s {
            return Err(Error::Degenerate);
        }
        Ok(PoseOnlyAnchors {
            kf_s,
            kf_e,
            obs_s,
            obs_e,
            sqrt_info,
            td_e: e.td,
            cs,
            ce,
            two,
            alpha,
            dd,
            pre: OnceCell::new(),
            shared: OnceCell::new(),
            depth_var: 0.0,
            shared_x: OnceCell::new(),
        })
    }

    /// Accounts for the anchors' depth uncertainty `sigma_d_m` (std of `d_s`, m) in every
    /// residual `j != e` (module docs). Non-finite or non-positive values mean none.
    pub fn with_depth_std(mut self, sigma_d_m: f64) -> Self {
        let v = sigma_d_m * sigma_d_m;
        self.depth_var = if v.is_finite() && v > 0.0 { v } else { 0.0 };
        self
    }

    /// The two-view geometry of the anchors.
    pub fn two_view(&self) -> &TwoView {
        &self.two
    }

    /// Geometry of observation `obs_j` in keyframe `kf_j` (pose `j`, camera frame `cj`; both
    /// ignored when `kf_j` is the anchor `e`), for [`Self::whitened`] and [`Self::pose_blocks`].
    /// `rel_js` is `cj.relative_from(cs)` when the caller has it, `None` to compute it here
    /// (bit-identical).
    ///
    /// Errors: as [`Self::residual`].
    pub fn geometry<'a>(
        &'a self,
        kf_j: usize,
        obs_j: &TimedObs,
        j: &KeyframePose,
        cj: &'a CamFrame,
        rel_js: Option<(Mat3, Vec3)>,
    ) -> Result<InJ<'a>, Error> {
        if kf_j == self.kf_s {
            return Err(Error::Degenerate);
        }
        if !obs_j.is_finite() {
            return Err(Error::NonFinite);
        }
        let (cj, td_j) = if kf_j == self.kf_e {
            (self.ce, self.td_e)
        } else {
            if !all_finite_pose(j) {
                return Err(Error::NonFinite);
            }
            (cj, j.td)
        };
        let (r_js, t_js) = rel_js.unwrap_or_else(|| cj.relative_from(self.cs));
        let u_j = r_js * self.two.x_s;
        let p = u_j * self.dd + t_js * self.alpha;
        if !p.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        if p.z <= MIN_Z_REL * p.norm() {
            return Err(Error::Degenerate);
        }
        let w_depth = (self.depth_var > 0.0 && kf_j != self.kf_e).then(|| {
            let h = Mat2x2::from_diagonal(&self.sqrt_info) * d_pi(&p);
            let g = h * (u_j * self.alpha);
            let gg = g.norm_squared();
            let k = self.depth_var * gg;
            if !(k > 0.0 && k.is_finite()) {
                return Mat2x2::identity();
            }
            let c = (1.0 - 1.0 / libm::sqrt(1.0 + k)) / gg;
            Mat2x2::identity() - g * g.transpose() * c
        });
        Ok(InJ {
            cj,
            r_js,
            t_js,
            u_j,
            p,
            x_j: obs_j.corrected(td_j),
            w_depth,
            is_e: kf_j == self.kf_e,
        })
    }

    /// Whitened residual of an observation's geometry (unweighted by the robust kernel; with the
    /// depth-uncertainty whitening when set).
    pub fn whitened(&self, g: &InJ<'_>) -> Vec2 {
        let pi = Vec2::new(g.p.x / g.p.z, g.p.y / g.p.z);
        let r = (pi - g.x_j.xy()).component_mul(&self.sqrt_info);
        match &g.w_depth {
            Some(w) => w * r,
            None => r,
        }
    }

    /// `W_j W dpi(P~_j)` scaled by `w`: the whitened projection Jacobian.
    fn h_of(&self, g: &InJ<'_>, w: f64) -> SMatrix<f64, 2, 3> {
        let h = Mat2x2::from_diagonal(&(self.sqrt_info * w)) * d_pi(&g.p);
        match &g.w_depth {
            Some(wd) => wd * h,
            None => h,
        }
    }

    /// Whitened residual of observation `obs_j` in keyframe `kf_j` (pose `j`, camera frame `cj`;
    /// both ignored when `kf_j` is the anchor `e`).
    ///
    /// Errors: [`Error::Degenerate`] when `kf_j == kf_s` or the landmark is not in front of
    /// camera `j`; [`Error::NonFinite`] for non-finite input.
    pub fn residual(
        &self,
        kf_j: usize,
        obs_j: &TimedObs,
        j: &KeyframePose,
        cj: &CamFrame,
    ) -> Result<Vec2, Error> {
        let g = self.geometry(kf_j, obs_j, j, cj, None)?;
        Ok(self.whitened(&g))
    }

    /// Whitened residual and all Jacobians of observation `j` (see [`Self::residual`]). When
    /// `kf_j == kf_e` the shared pose's blocks are summed into `d_pose_e` / `d_td[1]`.
    ///
    /// Every block is formed with the two rows of `W dpi/dP~` applied first, so the chain runs
    /// on `2 x 3` rather than `3 x 3` matrices.
    pub fn evaluate(
        &self,
        kf_j: usize,
        obs_j: &TimedObs,
        j: &KeyframePose,
        cj: &CamFrame,
    ) -> Result<PoseOnlyJacobians, Error> {
        let g = self.geometry(kf_j, obs_j, j, cj, None)?;
        let (alpha, dd) = (self.alpha, self.dd);
        let h = self.h_of(&g, 1.0);
        let (hu, ht) = (h * g.u_j, h * g.t_js);
        // h M_a and h M_b with M_a = 2 t_js a^T - u_j b^T, M_b = -u_j a^T.
        let hm_a = ht * (self.two.a.transpose() * 2.0) - hu * self.two.b.transpose();
        let hm_b = -(hu * self.two.a.transpose());
        let pre = self
            .pre
            .get_or_init(|| AbChainPre::new(&self.two, &self.ce.r_wc.transpose()));
        let ab = pre.apply::<2>(&hm_a, &hm_b);

        // Terms through u_j and t_js; dd [u_j]x + alpha [t_js]x = [P~_j]x.
        let h_rjs = h * g.r_js;
        let h_rjw = h * g.cj.r_wc.transpose();
        let d_th_s = ab.d_th_s - h_rjs * skew(&self.two.x_s) * dd;
        let d_p_s = ab.d_p_s + h_rjw * alpha;
        let d_th_j = h * skew(&g.p);
        let d_p_j = -(h_rjw * alpha);
        let d_xs = ab.d_xs + h_rjs * dd;

        let (bs, es) = cam_to_body_ext::<2>(&d_p_s, &d_th_s, self.cs);
        let (be, ee) = cam_to_body_ext::<2>(&ab.d_p_e, &ab.d_th_e, self.ce);
        let (bj, ej) = cam_to_body_ext::<2>(&d_p_j, &d_th_j, g.cj);

        let d_td_s = d_xs * self.obs_s.d_corrected_d_td();
        let d_td_e = ab.d_xe * self.obs_e.d_corrected_d_td();
        // r contains -W_j W x_j' and d x_j'/d td_j = -v_j.
        let d_td_j = obs_j.vel.component_mul(&self.sqrt_info);
        let d_td_j = g.w_depth.map_or(d_td_j, |wd| wd * d_td_j);

        let (d_pose_e, d_pose_j, d_td) = if kf_j == self.kf_e {
            (
                be + bj,
                Matrix2x6::zeros(),
                [d_td_s, d_td_e + d_td_j, Vec2::zeros()],
            )
        } else {
            (be, bj, [d_td_s, d_td_e, d_td_j])
        };
        Ok(PoseOnlyJacobians {
            r: self.whitened(&g),
            d_pose_s: bs,
            d_pose_e,
            d_pose_j,
            d_ext: es + ee + ej,
            d_td,
        })
    }
}

impl PoseOnlyAnchors<'_> {
    /// The landmark-wide `E` (module docs): the Jacobian of observation `j != e` on the body pose
    /// of `e` is `q E` ([`PoseBlocks::q`]).
    pub fn shared_e(&self) -> Matrix2x6<f64> {
        self.shared_fe().1
    }

    fn shared_fe(&self) -> &(Matrix2x6<f64>, Matrix2x6<f64>) {
        self.shared.get_or_init(|| {
            let pre = self
                .pre
                .get_or_init(|| AbChainPre::new(&self.two, &self.ce.r_wc.transpose()));
            let (a, b) = (self.two.a.transpose(), self.two.b.transpose());
            let mut s_a = SMatrix::<f64, 2, 3>::zeros();
            s_a.set_row(0, &a);
            s_a.set_row(1, &b);
            let mut s_b = SMatrix::<f64, 2, 3>::zeros();
            s_b.set_row(1, &a);
            let ab = pre.apply::<2>(&s_a, &s_b);
            let (f, _) = cam_to_body_ext::<2>(&ab.d_p_s, &ab.d_th_s, self.cs);
            let (e, _) = cam_to_body_ext::<2>(&ab.d_p_e, &ab.d_th_e, self.ce);
            (f, e)
        })
    }

    /// Residual and body-pose Jacobians of an observation's geometry `g` in the rank-structured
    /// form, scaled by `w` (the robust weight's square root, see [`PoseBlocks`]). Agrees with
    /// [`Self::evaluate`]: `d_pose_s = w evaluate.d_pose_s`, `q E (+ d_pose_j when j == e) =
    /// w evaluate.d_pose_e`, `d_pose_j = w evaluate.d_pose_j` for `j != e`.
    pub fn pose_blocks(&self, g: &InJ<'_>, w: f64) -> PoseBlocks {
        let (alpha, dd) = (self.alpha, self.dd);
        let (f, _) = *self.shared_fe();
        let h = self.h_of(g, w);
        let (hu, ht) = (h * g.u_j, h * g.t_js);
        let q = Mat2x2::new(2.0 * ht.x, -hu.x, 2.0 * ht.y, -hu.y);
        let h_rjw = h * g.cj.r_wc.transpose();
        let h_rjs = h * g.r_js;
        let d_p = h_rjw * alpha;
        let g_s = body_of(&d_p, &(-(h_rjs * skew(&self.two.x_s) * dd)), self.cs);
        let d_pose_j = body_of(&(-d_p), &(h * skew(&g.p)), g.cj);
        PoseBlocks {
            r: self.whitened(g) * w,
            q,
            d_pose_s: q * f + g_s,
            d_pose_j,
        }
    }
}

impl PoseOnlyAnchors<'_> {
    /// Jacobians of the weighted residual of geometry `g` (observation `obs_j`, robust weight
    /// `w` as in [`Self::pose_blocks`]) with respect to the time delays of `s`, `e` and `j`, in
    /// the rank-structured form: the anchors act through `q (S_a da + S_b db)`, so the chain to
    /// `x_s` and `x_e` is one landmark-wide `2 x 3` pair. When `j == e` the third entry is zero
    /// and its term is in the second. Agrees with `w` [`Self::evaluate`]`.d_td`.
    pub fn td_jacobians(&self, g: &InJ<'_>, w: f64, obs_j: &TimedObs) -> [Vec2; 3] {
        let (xs, xe) = *self.shared_x.get_or_init(|| {
            let pre = self
                .pre
                .get_or_init(|| AbChainPre::new(&self.two, &self.ce.r_wc.transpose()));
            let (a, b) = (self.two.a.transpose(), self.two.b.transpose());
            let mut s_a = SMatrix::<f64, 2, 3>::zeros();
            s_a.set_row(0, &a);
            s_a.set_row(1, &b);
            let mut s_b = SMatrix::<f64, 2, 3>::zeros();
            s_b.set_row(1, &a);
            pre.observations::<2>(&s_a, &s_b)
        });
        let h = self.h_of(g, w);
        let (hu, ht) = (h * g.u_j, h * g.t_js);
        let q = Mat2x2::new(2.0 * ht.x, -hu.x, 2.0 * ht.y, -hu.y);
        let d_xs = q * xs + h * g.r_js * self.dd;
        let d_xe = q * xe;
        let d_td_s = d_xs * self.obs_s.d_corrected_d_td();
        let d_td_e = d_xe * self.obs_e.d_corrected_d_td();
        let d_td_j = obs_j.vel.component_mul(&self.sqrt_info) * w;
        let d_td_j = g.w_depth.map_or(d_td_j, |wd| wd * d_td_j);
        if g.is_e {
            [d_td_s, d_td_e + d_td_j, Vec2::zeros()]
        } else {
            [d_td_s, d_td_e, d_td_j]
        }
    }
}

/// The body-pose half of [`cam_to_body_ext`] (the extrinsic half is not needed when the
/// extrinsic is held fixed).
#[inline]
fn body_of(d_p: &SMatrix<f64, 2, 3>, d_th: &SMatrix<f64, 2, 3>, cam: &CamFrame) -> Matrix2x6<f64> {
    let mut body = Matrix2x6::zeros();
    body.fixed_columns_mut::<3>(0).copy_from(d_p);
    body.fixed_columns_mut::<3>(3)
        .copy_from(&(-(d_p * cam.r_wb_pbc_x) + d_th * cam.r_cb));
    body
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

    fn anchors<'f>(
        &self,
        (s, e): (&KeyframePose, &KeyframePose),
        ext: &CameraExtrinsic,
        frames: &'f [CamFrame; 3],
    ) -> Result<PoseOnlyAnchors<'f>, Error> {
        self.validate()?;
        let [cs, ce, _] = frames;
        PoseOnlyAnchors::new(
            (self.kf_s, self.kf_e),
            self.obs_s,
            self.obs_e,
            self.sqrt_info,
            (s, e),
            (cs, ce),
            ext,
            None,
        )
    }

    fn frames(kfs: [&KeyframePose; 3], ext: &CameraExtrinsic) -> [CamFrame; 3] {
        kfs.map(|k| CamFrame::new(k, ext))
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
        let frames = Self::frames([s, e, j], ext);
        let a = self.anchors((s, e), ext, &frames)?;
        a.residual(self.kf_j, &self.obs_j, j, &frames[2])
    }

    /// [`Self::residual`] with the camera frames of `s`, `e`, `j` precomputed (`CamFrame::new`
    /// of the same poses and extrinsic; bit-identical result).
    pub fn residual_with_frames(
        &self,
        kfs: [&KeyframePose; 3],
        frames: &[CamFrame; 3],
        ext: &CameraExtrinsic,
    ) -> Result<Vec2, Error> {
        let a = self.anchors((kfs[0], kfs[1]), ext, frames)?;
        a.residual(self.kf_j, &self.obs_j, kfs[2], &frames[2])
    }

    /// [`Self::evaluate`] with the camera frames precomputed (bit-identical result).
    pub fn evaluate_with_frames(
        &self,
        kfs: [&KeyframePose; 3],
        frames: &[CamFrame; 3],
        ext: &CameraExtrinsic,
    ) -> Result<PoseOnlyJacobians, Error> {
        let a = self.anchors((kfs[0], kfs[1]), ext, frames)?;
        a.evaluate(self.kf_j, &self.obs_j, kfs[2], &frames[2])
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
        let frames = Self::frames([s, e, j], ext);
        let a = self.anchors((s, e), ext, &frames)?;
        a.evaluate(self.kf_j, &self.obs_j, j, &frames[2])
    }
}

type Mat2x2 = nalgebra::Matrix2<f64>;

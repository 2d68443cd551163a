//! Pose-only depth of a landmark from two anchor views and its analytic uncertainty
//! (paper eq. 2–13, math notes sec. 1–2).
//!
//! Inputs are undistorted observations on the normalized plane (`x_s`, `x_e`, z = 1) of the
//! anchor cameras `s` (first / LiDAR frame) and `e` (largest parallax), and the relative pose of
//! `s` into `e`: `P_e = R_es P_s + t_es`. With `u_e = R_es x_s`,
//!
//! ```text
//! a = x_e x u_e              theta = |a|   (parallax measure)
//! b = x_e x t_es
//! d_s = -(a . b) / (a . a)   signed depth (z in camera s)
//! ```
//!
//! `d_s` is the least-squares solution of `d_s a = -b` (eq. 4); the paper's `|b|/|a|` equals
//! `|d_s|` but loses the sign, and the sign is what detects a landmark behind the cameras.
//!
//! Gradient of the signed form, with `alpha = a.a`:
//! `delta d_s = g_a . delta a + g_b . delta b`, `g_a = -(b + 2 d_s a)/alpha`, `g_b = -a/alpha`,
//! and `delta a = [x_e]x R_es delta x_s - [u_e]x delta x_e`, `delta b = -[t_es]x delta x_e`.
//! For consistent observations (`b = -d_s a`) this reduces to the math notes' magnitude form
//! (`dd/dx_s = -(beta/theta^3) a^T [x_e]x R`, ...). Only the first two columns matter because the
//! third coordinate of a normalized observation is fixed. The depth variance from pixel noise
//! `sigma_p` (px) is `J_s S J_s^T + J_e S J_e^T` with `S = diag((sigma_p/fx)^2, (sigma_p/fy)^2)`.

use crate::camera::{CameraPose, Vec2};
use crate::math::{skew, Mat3, Vec3};
use crate::Error;
use nalgebra::{RowVector2, SMatrix};

/// Suggested parallax gate for [`pose_only_depth`]: `theta ~ sin(parallax angle)`, so 1e-3 is
/// about half a pixel of parallax at a 460 px focal length.
pub const DEFAULT_MIN_THETA: f64 = 1e-3;

/// Intermediate quantities of the two-view (anchor `s`, anchor `e`) pose-only geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoView {
    /// Observation in camera `s`, normalized plane (z = 1).
    pub x_s: Vec3,
    /// Observation in camera `e`, normalized plane (z = 1).
    pub x_e: Vec3,
    /// Rotation camera `s` -> camera `e`.
    pub r_es: Mat3,
    /// `R_es x_s`: the bearing of the `s` observation expressed in camera `e`.
    pub u_e: Vec3,
    /// Position of camera `s` in camera `e`, m.
    pub t_es: Vec3,
    /// `x_e x u_e`.
    pub a: Vec3,
    /// `x_e x t_es`, m.
    pub b: Vec3,
}

/// Pose-only depth of a landmark in its anchor camera `s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseOnlyDepth {
    /// Signed depth (z in camera `s`), m; always `> 0` when returned.
    pub d_s: f64,
    /// Parallax measure `|x_e x R_es x_s|`.
    pub theta: f64,
}

/// Derivatives of a quantity that depends on the two-view geometry only through `a` and `b`,
/// pushed back to the camera poses (right perturbation `R_wc <- R_wc Exp(dtheta)`,
/// `p_wc <- p_wc + dp` in world) and to the two observations (3-D, z column included).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AbChain<const R: usize> {
    pub d_th_s: SMatrix<f64, R, 3>,
    pub d_p_s: SMatrix<f64, R, 3>,
    pub d_th_e: SMatrix<f64, R, 3>,
    pub d_p_e: SMatrix<f64, R, 3>,
    pub d_xs: SMatrix<f64, R, 3>,
    pub d_xe: SMatrix<f64, R, 3>,
}

impl TwoView {
    /// Geometry from the two observations and the relative pose `P_e = r_es P_s + t_es`.
    pub fn new(x_s: &Vec3, x_e: &Vec3, r_es: &Mat3, t_es: &Vec3) -> Self {
        let u_e = r_es * x_s;
        TwoView {
            x_s: *x_s,
            x_e: *x_e,
            r_es: *r_es,
            u_e,
            t_es: *t_es,
            a: x_e.cross(&u_e),
            b: x_e.cross(t_es),
        }
    }

    /// Parallax measure `theta = |a|`.
    #[inline]
    pub fn theta(&self) -> f64 {
        self.a.norm()
    }

    /// Signed depth `-(a.b)/(a.a)` without any gate (NaN/inf when `a = 0`).
    #[inline]
    pub fn signed_depth(&self) -> f64 {
        -self.a.dot(&self.b) / self.a.norm_squared()
    }

    /// Gradient `(g_a, g_b)` of the signed depth w.r.t. `a` and `b`.
    pub fn depth_grad_ab(&self) -> (Vec3, Vec3) {
        let alpha = self.a.norm_squared();
        let d = self.signed_depth();
        ((self.b + self.a * (2.0 * d)) / -alpha, self.a / -alpha)
    }

    /// Jacobians of the signed depth w.r.t. the first two coordinates of `x_s` and `x_e`.
    pub fn depth_jacobians(&self) -> (RowVector2<f64>, RowVector2<f64>) {
        let (g_a, g_b) = self.depth_grad_ab();
        let c = self.chain_ab(&g_a.transpose(), &g_b.transpose(), &Mat3::identity());
        (
            RowVector2::new(c.d_xs[0], c.d_xs[1]),
            RowVector2::new(c.d_xe[0], c.d_xe[1]),
        )
    }

    /// Chain `M_a delta a + M_b delta b` to the camera poses and observations. `r_ew` is
    /// `R_wc_e^T` (only the position blocks need it).
    pub(crate) fn chain_ab<const R: usize>(
        &self,
        m_a: &SMatrix<f64, R, 3>,
        m_b: &SMatrix<f64, R, 3>,
        r_ew: &Mat3,
    ) -> AbChain<R> {
        AbChainPre::new(self, r_ew).apply(m_a, m_b)
    }
}

/// The landmark-only 3x3 factors of [`TwoView::chain_ab`]. A landmark chains one `(M_a, M_b)`
/// pair per observation through the same geometry, so these are formed once per landmark and
/// each observation then costs a few `R x 3` by `3 x 3` products.
///
/// With `R_es = R_e^T R_s`: `R_s <- R_s Exp(dth)` moves `u_e` by `-R_es [x_s]x dth`;
/// `R_e <- R_e Exp(dth)` moves `u_e` by `[u_e]x dth` and `t_es` by `[t_es]x dth`; `p_wc_s`,
/// `p_wc_e` move `t_es` by `+-R_e^T dp`. With `delta a = [x_e]x delta u_e - [u_e]x delta x_e` and
/// `delta b = [x_e]x delta t_es - [t_es]x delta x_e` this gives the products below.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AbChainPre {
    /// `-[x_e]x R_es [x_s]x` (rotation of `s`, through `a`).
    th_s_a: Mat3,
    /// `[x_e]x R_ew` (position of `s`, through `b`; the position of `e` is its negative).
    p_s_b: Mat3,
    /// `[x_e]x [u_e]x` (rotation of `e`, through `a`).
    th_e_a: Mat3,
    /// `[x_e]x [t_es]x` (rotation of `e`, through `b`).
    th_e_b: Mat3,
    /// `[x_e]x R_es` (observation `x_s`, through `a`).
    xs_a: Mat3,
    /// `-[u_e]x` (observation `x_e`, through `a`).
    xe_a: Mat3,
    /// `-[t_es]x` (observation `x_e`, through `b`).
    xe_b: Mat3,
}

impl AbChainPre {
    /// The chain to the observations for a landmark-wide pair `(S_a, S_b)`: `(S_a xs_a,
    /// S_a xe_a + S_b xe_b)`, the derivatives with respect to `x_s` and `x_e`.
    pub(crate) fn observations<const R: usize>(
        &self,
        s_a: &SMatrix<f64, R, 3>,
        s_b: &SMatrix<f64, R, 3>,
    ) -> (SMatrix<f64, R, 3>, SMatrix<f64, R, 3>) {
        (s_a * self.xs_a, s_a * self.xe_a + s_b * self.xe_b)
    }

    /// Factors of `two`'s chain; `r_ew` is `R_wc_e^T`.
    pub(crate) fn new(two: &TwoView, r_ew: &Mat3) -> Self {
        let xe_x = skew(&two.x_e);
        let ue_x = skew(&two.u_e);
        let te_x = skew(&two.t_es);
        let xs_a = xe_x * two.r_es;
        AbChainPre {
            th_s_a: -(xs_a * skew(&two.x_s)),
            p_s_b: xe_x * r_ew,
            th_e_a: xe_x * ue_x,
            th_e_b: xe_x * te_x,
            xs_a,
            xe_a: -ue_x,
            xe_b: -te_x,
        }
    }

    /// `M_a delta a + M_b delta b` chained to the camera poses and observations.
    #[inline]
    pub(crate) fn apply<const R: usize>(
        &self,
        m_a: &SMatrix<f64, R, 3>,
        m_b: &SMatrix<f64, R, 3>,
    ) -> AbChain<R> {
        let d_p_s = m_b * self.p_s_b;
        AbChain {
            d_th_s: m_a * self.th_s_a,
            d_p_s,
            d_th_e: m_a * self.th_e_a + m_b * self.th_e_b,
            d_p_e: -d_p_s,
            d_xs: m_a * self.xs_a,
            d_xe: m_a * self.xe_a + m_b * self.xe_b,
        }
    }
}

/// Pose-only depth of a landmark in camera `s` (math notes sec. 1).
///
/// Errors: [`Error::NonFinite`] for non-finite input, [`Error::Degenerate`] when the parallax
/// `theta < min_theta` or the signed depth is not positive.
pub fn pose_only_depth(
    x_s: &Vec3,
    x_e: &Vec3,
    r_es: &Mat3,
    t_es: &Vec3,
    min_theta: f64,
) -> Result<PoseOnlyDepth, Error> {
    let g = TwoView::new(x_s, x_e, r_es, t_es);
    let theta = g.theta();
    let d_s = g.signed_depth();
    if !theta.is_finite() || !g.b.iter().all(|v| v.is_finite()) {
        return Err(Error::NonFinite);
    }
    // `!(x > y)` also rejects NaN (a zero parallax gives 0/0).
    let usable = theta >= min_theta && d_s > 0.0 && d_s.is_finite();
    if !usable {
        return Err(Error::Degenerate);
    }
    Ok(PoseOnlyDepth { d_s, theta })
}

/// Analytic standard deviation of the pose-only depth, m (paper eq. 9–13, corrected), from pixel
/// noise `sigma_px` on both observations and focal lengths `focal = (fx, fy)` px. Pose errors are
/// neglected, as in the paper.
///
/// Errors: [`Error::InvalidConfig`] for a non-positive focal length or negative noise,
/// [`Error::Degenerate`] for zero parallax, [`Error::NonFinite`] otherwise.
pub fn depth_std(g: &TwoView, sigma_px: f64, focal: &Vec2) -> Result<f64, Error> {
    if !(focal.x > 0.0 && focal.y > 0.0 && sigma_px >= 0.0) {
        return Err(Error::InvalidConfig);
    }
    if g.a.norm_squared() == 0.0 {
        return Err(Error::Degenerate);
    }
    let (j_s, j_e) = g.depth_jacobians();
    let sx = sigma_px / focal.x;
    let sy = sigma_px / focal.y;
    let var = (j_s[0] * j_s[0] + j_e[0] * j_e[0]) * sx * sx
        + (j_s[1] * j_s[1] + j_e[1] * j_e[1]) * sy * sy;
    if !var.is_finite() {
        return Err(Error::NonFinite);
    }
    Ok(libm::sqrt(var))
}

/// Picks the second anchor `e = argmax_k |x_k x R_ks x_s|` over `k != s` among the keyframes
/// observing a landmark. `poses[k]` is the camera pose of keyframe `k` and `obs[k]` its normalized
/// observation (z = 1). Returns `(e, theta_e)`; gating `theta_e` is the caller's job.
///
/// Errors: [`Error::InvalidConfig`] when the slices differ in length or `s` is out of range,
/// [`Error::NotEnoughData`] with fewer than two views, [`Error::Degenerate`] when no view gives a
/// finite parallax.
pub fn select_anchor(s: usize, poses: &[CameraPose], obs: &[Vec3]) -> Result<(usize, f64), Error> {
    if poses.len() != obs.len() {
        return Err(Error::InvalidConfig);
    }
    let (Some(pose_s), Some(x_s)) = (poses.get(s), obs.get(s)) else {
        return Err(Error::InvalidConfig);
    };
    if poses.len() < 2 {
        return Err(Error::NotEnoughData);
    }
    let mut best: Option<(usize, f64)> = None;
    for (k, (pose_k, x_k)) in poses.iter().zip(obs.iter()).enumerate() {
        if k == s {
            continue;
        }
        let (r_ks, _) = pose_k.relative_from(pose_s);
        let theta = x_k.cross(&(r_ks * x_s)).norm();
        if theta.is_finite() && best.is_none_or(|(_, t)| theta > t) {
            best = Some((k, theta));
        }
    }
    best.ok_or(Error::Degenerate)
}

//! LiDAR-depth measurements in pose-only form (paper eq. 24–30, math notes sec. 5).
//!
//! `d_r` is always the LiDAR depth of the landmark as the z-coordinate in the anchor camera `s`
//! (not the range), m, with standard deviation `sigma_dr`.
//!
//! **Direct LDM** (eq. 24, the ablation baseline): `r = (d_s(poses) - d_r) / sigma_dr` with the
//! signed pose-only depth of [`crate::landmarks::pose_only`]; Jacobians w.r.t. the body poses of
//! the anchors `s`, `e`, the extrinsic and the two time delays, chained through
//! `delta d_s = g_a . delta a + g_b . delta b`.
//!
//! **MSC-based LDM** (eq. 25–30): the inverse depth `tau` of the landmark in `s` is a nuisance
//! parameter eliminated per linearization.
//! 1. Stack the whitened inverse-depth reprojections of all observations `j != s`
//!    ([`super::inverse_depth_visual`]) and the depth row `(1/tau - d_r)/sigma_dr`:
//!    `e (m = 2n+1)`, `J_Y`, `J_tau`.
//! 2. Re-solve `tau*` = argmin |e(tau)|^2 for the current poses by 1-D Gauss–Newton from the last
//!    value, and linearize there (variable projection: the projection below is then exactly the
//!    Schur complement of `tau`, so LM converges to the same optimum as keeping `tau` a state).
//! 3. Left nullspace of `J_tau` by Givens rotations: the depth row is the pivot (its `J_tau =
//!    -1/(tau^2 sigma_dr)` is never zero) and each observation row, bottom-up, is rotated against
//!    it so its `J_tau` entry vanishes; the same rotations act on `e` and `J_Y`. The pivot row, the
//!    only one left with `J_tau`, is dropped. Any orthonormal basis of the left nullspace gives the
//!    same cost and normal equations; this one keeps the borrow structure trivial. Whitening
//!    happens before the rotations, so the `2n` kept rows have unit white noise.
//!
//! The kept rows' residual `e0` satisfies `|e0|^2 = |e(tau*)|^2 - (J_tau.e)^2/|J_tau|^2
//! = min_tau |e(tau)|^2` to first order (exactly at `tau*`, where `J_tau.e = 0`), and
//! `J0^T J0 = J_Y^T (I - J_tau J_tau^T/|J_tau|^2) J_Y` is the Schur-complement information.
//! Landmarks using this measurement get no separate visual factor; a robust kernel acts on the
//! block's total squared norm ([`MscLidarDepth::apply_sqrt_weight`]).

use super::inverse_depth_visual::InverseDepthVisualFactor;
use super::{all_finite_ext, all_finite_pose, cam_to_body_ext, CamFrame, KeyframePose, TimedObs};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::landmarks::TwoView;
use crate::Error;
use nalgebra::RowVector6;

/// Residual and Jacobians of the direct LiDAR-depth measurement (1-D).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectDepthJacobians {
    /// `(d_s - d_r) / sigma_dr`.
    pub r: f64,
    /// W.r.t. the body pose of anchor `s`, `[dp, dtheta]`.
    pub d_pose_s: RowVector6<f64>,
    /// W.r.t. the body pose of anchor `e`.
    pub d_pose_e: RowVector6<f64>,
    /// W.r.t. the extrinsic `[dp_bc, dtheta_bc]`.
    pub d_ext: RowVector6<f64>,
    /// W.r.t. the time delays of `s` and `e`, 1/s.
    pub d_td: [f64; 2],
}

/// Direct LiDAR-depth measurement of a landmark with anchors `s` (where the depth was associated)
/// and `e`. Used together with the landmark's visual factors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectLidarDepthFactor {
    /// Anchor keyframe carrying the LiDAR depth.
    pub kf_s: usize,
    /// Second anchor (largest parallax).
    pub kf_e: usize,
    /// Observation in `s`.
    pub obs_s: TimedObs,
    /// Observation in `e`.
    pub obs_e: TimedObs,
    /// LiDAR depth (z in camera `s`), m.
    pub d_r: f64,
    /// Its standard deviation, m.
    pub sigma_dr: f64,
}

impl DirectLidarDepthFactor {
    /// Residual and Jacobians.
    ///
    /// Errors: [`Error::Degenerate`] for `kf_s == kf_e`, zero parallax or a non-positive visual
    /// depth; [`Error::InvalidConfig`] for `sigma_dr <= 0`; [`Error::NonFinite`].
    pub fn evaluate(
        &self,
        s: &KeyframePose,
        e: &KeyframePose,
        ext: &CameraExtrinsic,
    ) -> Result<DirectDepthJacobians, Error> {
        if self.kf_s == self.kf_e {
            return Err(Error::Degenerate);
        }
        let sigma_ok = self.sigma_dr > 0.0 && self.sigma_dr.is_finite();
        if !sigma_ok {
            return Err(Error::InvalidConfig);
        }
        let finite = self.obs_s.is_finite()
            && self.obs_e.is_finite()
            && self.d_r.is_finite()
            && all_finite_pose(s)
            && all_finite_pose(e)
            && all_finite_ext(ext);
        if !finite {
            return Err(Error::NonFinite);
        }
        let (cs, ce) = (CamFrame::new(s, ext), CamFrame::new(e, ext));
        let (r_es, t_es) = ce.relative_from(&cs);
        let two = TwoView::new(
            &self.obs_s.corrected(s.td),
            &self.obs_e.corrected(e.td),
            &r_es,
            &t_es,
        );
        let d_s = two.signed_depth();
        // d_s is NaN for zero parallax (0/0), which fails `d_s > 0`.
        let in_front = d_s > 0.0 && d_s.is_finite();
        if !in_front {
            return Err(Error::Degenerate);
        }
        let (g_a, g_b) = two.depth_grad_ab();
        let ab = two.chain_ab::<1>(&g_a.transpose(), &g_b.transpose(), &ce.r_wc.transpose());
        let (bs, xs) = cam_to_body_ext::<1>(&ab.d_p_s, &ab.d_th_s, &cs);
        let (be, xe) = cam_to_body_ext::<1>(&ab.d_p_e, &ab.d_th_e, &ce);
        let w = 1.0 / self.sigma_dr;
        Ok(DirectDepthJacobians {
            r: (d_s - self.d_r) * w,
            d_pose_s: bs * w,
            d_pose_e: be * w,
            d_ext: (xs + xe) * w,
            d_td: [
                (ab.d_xs * self.obs_s.d_corrected_d_td())[0] * w,
                (ab.d_xe * self.obs_e.d_corrected_d_td())[0] * w,
            ],
        })
    }
}

/// One row of the (projected) MSC system: whitened residual and its Jacobian blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MscRow<const N: usize> {
    /// Residual (whitened, dimensionless).
    pub r: f64,
    /// W.r.t. the inverse depth `tau`; zero (to rounding) on every projected row.
    pub d_tau: f64,
    /// W.r.t. the anchor body pose `[dp, dtheta]`.
    pub d_pose_s: RowVector6<f64>,
    /// W.r.t. the body pose of observation `k` (in push order).
    pub d_pose_j: [RowVector6<f64>; N],
    /// W.r.t. the extrinsic `[dp_bc, dtheta_bc]`.
    pub d_ext: RowVector6<f64>,
    /// W.r.t. the anchor's time delay, 1/s.
    pub d_td_s: f64,
    /// W.r.t. the time delay of observation `k`'s keyframe, 1/s.
    pub d_td_j: [f64; N],
}

impl<const N: usize> MscRow<N> {
    fn zero() -> Self {
        MscRow {
            r: 0.0,
            d_tau: 0.0,
            d_pose_s: RowVector6::zeros(),
            d_pose_j: [RowVector6::zeros(); N],
            d_ext: RowVector6::zeros(),
            d_td_s: 0.0,
            d_td_j: [0.0; N],
        }
    }

    fn scale(&mut self, w: f64) {
        self.r *= w;
        self.d_tau *= w;
        self.d_pose_s *= w;
        for b in self.d_pose_j.iter_mut() {
            *b *= w;
        }
        self.d_ext *= w;
        self.d_td_s *= w;
        for t in self.d_td_j.iter_mut() {
            *t *= w;
        }
    }
}

/// Applies the Givens rotation `[c s; -s c]` to the row pair `(top, row)`.
fn rotate<const N: usize>(top: &mut MscRow<N>, row: &mut MscRow<N>, c: f64, s: f64) {
    let rot = |a: &mut f64, b: &mut f64| {
        let (x, y) = (*a, *b);
        *a = c * x + s * y;
        *b = -s * x + c * y;
    };
    rot(&mut top.r, &mut row.r);
    rot(&mut top.d_tau, &mut row.d_tau);
    rot(&mut top.d_td_s, &mut row.d_td_s);
    for (a, b) in top.d_pose_s.iter_mut().zip(row.d_pose_s.iter_mut()) {
        rot(a, b);
    }
    for (a, b) in top.d_ext.iter_mut().zip(row.d_ext.iter_mut()) {
        rot(a, b);
    }
    for (ta, tb) in top.d_pose_j.iter_mut().zip(row.d_pose_j.iter_mut()) {
        for (a, b) in ta.iter_mut().zip(tb.iter_mut()) {
            rot(a, b);
        }
    }
    for (a, b) in top.d_td_j.iter_mut().zip(row.d_td_j.iter_mut()) {
        rot(a, b);
    }
}

/// Iteration cap of the 1-D inverse-depth Gauss–Newton.
const MAX_TAU_ITERS: usize = 30;
/// Relative step at which the inverse-depth solve has converged.
const TAU_REL_TOL: f64 = 1e-13;

/// MSC-based LiDAR-depth measurement of one landmark with up to `N` observations besides its
/// anchor. Holds its own (caller-owned) storage: `2N + 1` rows of `6 (N + 2) + N + 3` values.
#[derive(Debug, Clone, PartialEq)]
pub struct MscLidarDepth<const N: usize> {
    /// Anchor keyframe (where the LiDAR depth was associated).
    pub kf_s: usize,
    /// Observation in the anchor.
    pub obs_s: TimedObs,
    /// LiDAR depth (z in camera `s`), m.
    pub d_r: f64,
    /// Its standard deviation, m.
    pub sigma_dr: f64,
    /// Whitening `f / sigma_p` of the visual rows.
    pub sqrt_info: Vec2,
    kf_j: [usize; N],
    obs_j: [TimedObs; N],
    n: usize,
    tau: f64,
    top: MscRow<N>,
    rows: [[MscRow<N>; 2]; N],
}

impl<const N: usize> MscLidarDepth<N> {
    /// A measurement with no observations yet; `tau` starts at `1/d_r`.
    ///
    /// Errors: [`Error::InvalidConfig`] unless `d_r`, `sigma_dr` and `sqrt_info` are positive
    /// and finite; [`Error::NonFinite`] for a non-finite anchor observation.
    pub fn new(
        kf_s: usize,
        obs_s: TimedObs,
        d_r: f64,
        sigma_dr: f64,
        sqrt_info: Vec2,
    ) -> Result<Self, Error> {
        let valid = d_r > 0.0
            && d_r.is_finite()
            && sigma_dr > 0.0
            && sigma_dr.is_finite()
            && sqrt_info.x > 0.0
            && sqrt_info.y > 0.0;
        if !valid {
            return Err(Error::InvalidConfig);
        }
        if !obs_s.is_finite() {
            return Err(Error::NonFinite);
        }
        Ok(MscLidarDepth {
            kf_s,
            obs_s,
            d_r,
            sigma_dr,
            sqrt_info,
            kf_j: [0; N],
            obs_j: [TimedObs::still(Vec2::zeros()); N],
            n: 0,
            tau: 1.0 / d_r,
            top: MscRow::zero(),
            rows: [[MscRow::zero(); 2]; N],
        })
    }

    /// Adds the observation of keyframe `kf_j`.
    ///
    /// Errors: [`Error::CapacityExceeded`] beyond `N`; [`Error::Degenerate`] for the anchor's own
    /// keyframe or a keyframe already added; [`Error::NonFinite`].
    pub fn push(&mut self, kf_j: usize, obs: TimedObs) -> Result<(), Error> {
        if kf_j == self.kf_s || self.keyframes().contains(&kf_j) {
            return Err(Error::Degenerate);
        }
        if !obs.is_finite() {
            return Err(Error::NonFinite);
        }
        let (Some(k), Some(o)) = (self.kf_j.get_mut(self.n), self.obs_j.get_mut(self.n)) else {
            return Err(Error::CapacityExceeded);
        };
        *k = kf_j;
        *o = obs;
        self.n += 1;
        Ok(())
    }

    /// Number of observations besides the anchor.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether no observation was added.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Keyframes of the observations, in push order (the order of `d_pose_j` / `d_td_j`).
    pub fn keyframes(&self) -> &[usize] {
        self.kf_j.get(..self.n).unwrap_or(&[])
    }

    /// Observations in push order.
    pub fn observations(&self) -> &[TimedObs] {
        self.obs_j.get(..self.n).unwrap_or(&[])
    }

    /// Current inverse depth, 1/m.
    pub fn tau(&self) -> f64 {
        self.tau
    }

    /// Overrides the starting inverse depth of the next solve (e.g. after re-anchoring).
    pub fn set_tau(&mut self, tau: f64) {
        self.tau = tau;
    }

    fn factor(&self, k: usize) -> Option<InverseDepthVisualFactor> {
        Some(InverseDepthVisualFactor {
            kf_s: self.kf_s,
            kf_j: *self.kf_j.get(k)?,
            obs_s: self.obs_s,
            obs_j: *self.obs_j.get(k)?,
            sqrt_info: self.sqrt_info,
        })
    }

    fn check_inputs(
        &self,
        s: &KeyframePose,
        poses_j: &[KeyframePose],
        ext: &CameraExtrinsic,
    ) -> Result<(), Error> {
        if poses_j.len() != self.n {
            return Err(Error::InvalidConfig);
        }
        if self.n == 0 {
            return Err(Error::NotEnoughData);
        }
        if !(all_finite_pose(s) && all_finite_ext(ext) && poses_j.iter().all(all_finite_pose)) {
            return Err(Error::NonFinite);
        }
        Ok(())
    }

    /// Whitened depth row `(1/tau - d_r)/sigma_dr` and its derivative w.r.t. `tau`.
    fn depth_row(&self, tau: f64) -> (f64, f64) {
        (
            (1.0 / tau - self.d_r) / self.sigma_dr,
            -1.0 / (tau * tau * self.sigma_dr),
        )
    }

    /// Stacked (unprojected) cost `|e(tau)|^2` at a given inverse depth.
    ///
    /// Errors: as [`Self::linearize`].
    pub fn stacked_cost(
        &self,
        s: &KeyframePose,
        poses_j: &[KeyframePose],
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<f64, Error> {
        self.check_inputs(s, poses_j, ext)?;
        let rd = self.depth_row(tau).0;
        let mut cost = rd * rd;
        for (k, pose) in poses_j.iter().enumerate() {
            let f = self.factor(k).ok_or(Error::InvalidConfig)?;
            cost += f.residual(s, pose, ext, tau)?.norm_squared();
        }
        Ok(cost)
    }

    /// Depth-only optimization (paper V.D): 1-D Gauss–Newton on the stacked cost from the current
    /// `tau`, poses fixed. Stores and returns `tau*`.
    ///
    /// Errors: as [`Self::linearize`]; [`Error::Degenerate`] if the solve does not converge.
    pub fn solve_tau(
        &mut self,
        s: &KeyframePose,
        poses_j: &[KeyframePose],
        ext: &CameraExtrinsic,
    ) -> Result<f64, Error> {
        self.check_inputs(s, poses_j, ext)?;
        let mut tau = if self.tau > 0.0 && self.tau.is_finite() {
            self.tau
        } else {
            1.0 / self.d_r
        };
        for _ in 0..MAX_TAU_ITERS {
            let (rd, jd) = self.depth_row(tau);
            let (mut g, mut h) = (jd * rd, jd * jd);
            for (k, pose) in poses_j.iter().enumerate() {
                let f = self.factor(k).ok_or(Error::InvalidConfig)?;
                let (r, j) = f.residual_and_d_tau(s, pose, ext, tau)?;
                g += j.dot(&r);
                h += j.norm_squared();
            }
            let usable = h > 0.0 && g.is_finite();
            if !usable {
                return Err(Error::NonFinite);
            }
            let step = -g / h;
            let next = tau + step;
            // Inverse depth must stay positive; halve toward zero instead of crossing it.
            tau = if next > 0.0 { next } else { 0.5 * tau };
            if libm::fabs(step) <= TAU_REL_TOL * tau {
                self.tau = tau;
                return Ok(tau);
            }
        }
        Err(Error::Degenerate)
    }

    /// Solves `tau*` for the given poses, stacks the whitened system there and projects it onto
    /// the left nullspace of `J_tau`. `poses_j[k]` is the pose of the keyframe pushed `k`-th.
    /// Afterwards [`Self::rows`] holds the `2n` projected rows.
    ///
    /// Errors: [`Error::InvalidConfig`] when `poses_j` does not match the pushed observations,
    /// [`Error::NotEnoughData`] without observations, [`Error::NonFinite`], and the errors of
    /// [`InverseDepthVisualFactor::evaluate`] (e.g. a point behind a camera).
    pub fn linearize(
        &mut self,
        s: &KeyframePose,
        poses_j: &[KeyframePose],
        ext: &CameraExtrinsic,
    ) -> Result<(), Error> {
        let tau = self.solve_tau(s, poses_j, ext)?;
        let (rd, jd) = self.depth_row(tau);
        self.top = MscRow::zero();
        self.top.r = rd;
        self.top.d_tau = jd;
        for (k, pose) in poses_j.iter().enumerate() {
            let f = self.factor(k).ok_or(Error::InvalidConfig)?;
            let jac = f.evaluate(s, pose, ext, tau)?;
            let pair = self.rows.get_mut(k).ok_or(Error::CapacityExceeded)?;
            for (i, row) in pair.iter_mut().enumerate() {
                *row = MscRow::zero();
                row.r = jac.r[i];
                row.d_tau = jac.d_tau[i];
                row.d_pose_s = jac.d_pose_s.row(i).into_owned();
                if let Some(b) = row.d_pose_j.get_mut(k) {
                    *b = jac.d_pose_j.row(i).into_owned();
                }
                row.d_ext = jac.d_ext.row(i).into_owned();
                row.d_td_s = jac.d_td[0][i];
                if let Some(t) = row.d_td_j.get_mut(k) {
                    *t = jac.d_td[1][i];
                }
            }
        }
        let n = self.n;
        let top = &mut self.top;
        for pair in self.rows.iter_mut().take(n).rev() {
            for row in pair.iter_mut().rev() {
                let (a, b) = (top.d_tau, row.d_tau);
                let rr = libm::hypot(a, b);
                if rr > 0.0 {
                    rotate(top, row, a / rr, b / rr);
                }
            }
        }
        Ok(())
    }

    /// The `2n` projected rows of the last [`Self::linearize`] (observation pairs in push order,
    /// though after the rotations each row mixes all observations).
    pub fn rows(&self) -> impl Iterator<Item = &MscRow<N>> {
        self.rows.iter().take(self.n).flatten()
    }

    /// The dropped pivot row (the only one carrying `J_tau`); for diagnostics.
    pub fn pivot_row(&self) -> &MscRow<N> {
        &self.top
    }

    /// `|e0|^2` of the projected rows.
    pub fn projected_cost(&self) -> f64 {
        self.rows().map(|r| r.r * r.r).sum()
    }

    /// Scales every projected row by `w` (robust-kernel sqrt weight on the whole block).
    pub fn apply_sqrt_weight(&mut self, w: f64) {
        let n = self.n;
        for pair in self.rows.iter_mut().take(n) {
            for row in pair.iter_mut() {
                row.scale(w);
            }
        }
    }
}

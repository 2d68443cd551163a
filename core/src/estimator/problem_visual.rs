//! Pose-only visual landmarks with the depth from all their observations
//! ([`super::VisualDepth::Eliminated`], the default).
//!
//! The paper's pose-only reprojection takes the landmark's depth from two anchor views `(s, e)`
//! and treats it as exact in every other residual. Measured on EuRoC-like simulated flights, that
//! two-view depth costs about a quarter of the accuracy the same observations give when the depth
//! is estimated from all of them (the inverse-depth baseline: 0.055 vs 0.075 m median ATE over ten
//! seeds): the depth's error enters every residual of the landmark alike, and a noisy second
//! anchor picks the depth. So the depth is eliminated instead, still without being a state: at
//! each evaluation the inverse depth `tau*` that minimizes the landmark's robust reprojection
//! cost is solved for the current poses (a few 1-D Gauss–Newton steps on the rays
//! `P_j ~ a_j + tau b_j`, from the last solution), and the linearization projects `tau` out by its
//! Schur complement (variable projection), exactly as the MSC-based LiDAR-depth measurement does
//! without its depth row (`estimator::problem_lidar`):
//!
//! ```text
//! H += sum_j J_j^T W_j J_j - v v^T / c,   v = sum_j J_j^T W_j g_j,   c = sum_j g_j^T W_j g_j
//! ```
//!
//! with `J_j` the residual's Jacobian on the poses (of `s` and `j` only) and `g_j` on `tau`,
//! `W_j` the observation's Huber weight. The measurement is a function of the poses alone: the
//! landmark has no state, its cost is `min_tau` of the reprojection cost, so the LM's gain ratio
//! compares what the linear model predicts.

use super::problem::Problem;
use super::problem_lidar::{add_inverse_depth_obs, TauLandmark};
use super::window::{Block, Layout};
use crate::camera::CameraExtrinsic;
use crate::factors::robust::Huber;
use crate::factors::{CamFrame, KeyframePose};
use crate::solver::NormalEquations;
use crate::Error;
use heapless::Vec as HVec;
use nalgebra::Vector6;

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    /// Landmark `li` with its inverse depth eliminated (module docs): robust cost and number of
    /// observations; with `ne`, also accumulates the projected block and stores `tau*`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn eliminated_landmark(
        &mut self,
        li: usize,
        ne: &mut Option<&mut NormalEquations<D>>,
        poses: &[KeyframePose; N],
        frames: &[CamFrame; N],
        ext: &CameraExtrinsic,
        huber: &Huber,
        est_td: bool,
        est_ext: bool,
    ) -> Result<(f64, u32), Error> {
        let count = self.window.len();
        let sqrt_info = self.sqrt_info();
        let lm = self
            .lms
            .landmarks()
            .get(li)
            .ok_or(Error::DimensionMismatch)?;
        let s = lm.anchor_s as usize;
        let m = TauLandmark::new(&lm.obs, s, None, sqrt_info, count).ok_or(Error::NotEnoughData)?;
        let rays = m.rays(poses, frames)?;
        // IRLS on the 1-D problem: each step re-weights the rays by the Huber weight of their
        // residual at the current tau.
        let tau = m.gauss_newton_tau(lm.inv_depth, |tau, mut g, mut h| {
            for ray in rays.iter() {
                let (r, jt) = ray.residual_and_d_tau(tau)?;
                let w2 = huber.rho(r.norm_squared())[1];
                g += w2 * jt.dot(&r);
                h += w2 * jt.norm_squared();
            }
            Ok((g, h))
        })?;
        let n_obs = m.obs.len() as u32;
        let Some(ne) = ne.as_deref_mut() else {
            let mut cost = 0.0;
            for ray in rays.iter() {
                cost += huber.rho(ray.residual_and_d_tau(tau)?.0.norm_squared())[0];
            }
            return Ok((cost, n_obs));
        };
        let ps = poses.get(s).ok_or(Error::DimensionMismatch)?;
        let l = self.layout;
        if !est_ext {
            let cost = accumulate_eliminated(&m, poses, ext, tau, huber, &l, ne)?;
            if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                lm.inv_depth = tau;
            }
            return Ok((cost, n_obs));
        }
        let sc = self.schur.get_mut(li).ok_or(Error::CapacityExceeded)?;
        sc.clear();
        let mut cost = 0.0;
        for (j, f) in m.obs.iter() {
            let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
            let jac = f.evaluate(ps, pj, ext, tau)?;
            let sq = jac.r.norm_squared();
            cost += huber.rho(sq)[0];
            add_inverse_depth_obs(
                sc,
                ne,
                &jac,
                huber.sqrt_weight(sq),
                s,
                *j,
                &l,
                est_td,
                est_ext,
            )?;
        }
        sc.fold_into(ne, 0.0)?;
        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
            lm.inv_depth = tau;
        }
        Ok((cost, n_obs))
    }
}

/// The landmark's linearization with `tau` eliminated, extrinsic fixed (module docs): every
/// observation's 2x6 pose blocks and delay columns go into `ne` as usual, and the landmark's
/// coupling to `tau` (`v`, `c`, `beta`) is folded in once at the end. Returns the robust cost.
fn accumulate_eliminated<const N: usize, const D: usize>(
    m: &TauLandmark<N>,
    poses: &[KeyframePose; N],
    ext: &CameraExtrinsic,
    tau: f64,
    huber: &Huber,
    l: &Layout<N>,
    ne: &mut NormalEquations<D>,
) -> Result<f64, Error> {
    let ps = poses.get(m.s).ok_or(Error::DimensionMismatch)?;
    let col = |k: usize| l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch);
    let td_col = |k: usize| l.col(Block::Td(k as u8));
    let (cs, ts) = (col(m.s)?, td_col(m.s));
    // `v = sum J^T g` on the anchor's pose and delay, and per observing keyframe.
    let mut v_s = Vector6::zeros();
    let mut v_ts = 0.0;
    let mut v_j: HVec<(usize, Vector6<f64>, Option<usize>, f64), N> = HVec::new();
    let (mut c, mut beta, mut cost) = (0.0, 0.0, 0.0);
    for (j, f) in m.obs.iter() {
        let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
        let jac = f.evaluate(ps, pj, ext, tau)?;
        let sq = jac.r.norm_squared();
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let (r, a, b, g) = (jac.r * w, jac.d_pose_s * w, jac.d_pose_j * w, jac.d_tau * w);
        let cj = col(*j)?;
        ne.add_2x6_blocks(&r, &[a, b], &[cs, cj])?;
        let tj = td_col(*j);
        let (t_s, t_j) = (jac.d_td[0] * w, jac.d_td[1] * w);
        if ts.is_some() {
            ne.add_scalar_columns(&r, &[(ts, t_s), (tj, t_j)], &[(cs, a), (cj, b)])?;
        }
        c += g.norm_squared();
        beta -= g.dot(&r);
        v_s += a.transpose() * g;
        v_ts += t_s.dot(&g);
        let _ = v_j.push((cj, b.transpose() * g, tj, t_j.dot(&g)));
    }
    if !(c > 1e-12 && c.is_finite() && beta.is_finite()) {
        return Ok(cost);
    }
    // The segments of v with their first columns: pose blocks (6 wide) and delays (1 wide).
    let mut segs: HVec<(usize, [f64; 6], usize), { 2 * 16 }> = HVec::new();
    let _ = segs.push((cs, v_s.into(), 6));
    for (cj, x, _, _) in v_j.iter() {
        let _ = segs.push((*cj, (*x).into(), 6));
    }
    if let Some(ts) = ts {
        let _ = segs.push((ts, [v_ts, 0.0, 0.0, 0.0, 0.0, 0.0], 1));
        for (_, _, tj, xt) in v_j.iter() {
            if let Some(tj) = tj {
                let _ = segs.push((*tj, [*xt, 0.0, 0.0, 0.0, 0.0, 0.0], 1));
            }
        }
    }
    if !segs.iter().all(|(_, x, _)| x.iter().all(|v| v.is_finite())) {
        return Err(Error::NonFinite);
    }
    fold_rank_one(ne, &segs, 1.0 / c, beta);
    Ok(cost)
}

/// `H -= v v^T / c` (upper triangle) and `b -= v beta / c` for `v` given as segments
/// `(first column, values, width)` on distinct, non-overlapping columns. Segment pair by segment
/// pair, each block row a contiguous run, so the work is the `(sum of widths)^2 / 2` products.
fn fold_rank_one<const D: usize>(
    ne: &mut NormalEquations<D>,
    segs: &[(usize, [f64; 6], usize)],
    inv_c: f64,
    beta: f64,
) {
    for (ia, &(ca, xa, wa)) in segs.iter().enumerate() {
        let xa = xa.get(..wa).unwrap_or(&[]);
        if let Some(b) = ne.b.get_mut(ca..ca + wa) {
            for (bi, x) in b.iter_mut().zip(xa) {
                *bi -= x * beta * inv_c;
            }
        }
        // The diagonal block: upper triangle.
        for (i, x) in xa.iter().enumerate() {
            let xi = x * inv_c;
            if let (Some(dst), Some(src)) = (
                ne.h.get_mut(ca + i)
                    .and_then(|row| row.get_mut(ca + i..ca + wa)),
                xa.get(i..),
            ) {
                for (h, y) in dst.iter_mut().zip(src) {
                    *h -= xi * y;
                }
            }
        }
        // Cross blocks with the later segments, into whichever triangle is upper.
        for &(cb, xb, wb) in segs.iter().skip(ia + 1) {
            let xb = xb.get(..wb).unwrap_or(&[]);
            let ((r0, xr), (c0, xc)) = if ca < cb {
                ((ca, xa), (cb, xb))
            } else {
                ((cb, xb), (ca, xa))
            };
            for (i, x) in xr.iter().enumerate() {
                let xi = x * inv_c;
                if let Some(dst) =
                    ne.h.get_mut(r0 + i)
                        .and_then(|row| row.get_mut(c0..c0 + xc.len()))
                {
                    for (h, y) in dst.iter_mut().zip(xc) {
                        *h -= xi * y;
                    }
                }
            }
        }
    }
}

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
//! cost is solved for the current poses (one or two 1-D Newton steps on the rays
//! `P_j ~ a_j + tau b_j`, from the last solution: [`newton_tau`]), and the linearization projects
//! `tau` out by its Schur complement (variable projection), exactly as the MSC-based LiDAR-depth
//! measurement does without its depth row (`estimator::problem::lidar`):
//!
//! ```text
//! H += sum_j J_j^T W_j J_j - v v^T / c,   v = sum_j J_j^T W_j g_j,   c = sum_j g_j^T W_j g_j
//! ```
//!
//! with `J_j` the residual's Jacobian on the poses (of `s` and `j` only) and `g_j` on `tau`,
//! `W_j` the observation's Huber weight. The measurement is a function of the poses alone: the
//! landmark has no state, its cost is `min_tau` of the reprojection cost, so the LM's gain ratio
//! compares what the linear model predicts.
#![deny(clippy::too_many_lines)]

use super::factor::{put_rows, LandmarkFactor, VisualSettings, WindowFactor, WindowVars};
use super::lidar::add_inverse_depth_obs;
use super::SCHUR_COLS;
use crate::estimator::tau_landmark::{Ray, TauLandmark};
use crate::estimator::window::{Block, Layout};
use crate::factors::inverse_depth_visual::WindowRotations;
use crate::factors::robust::Huber;
use crate::factors::KeyframePose;
use crate::landmarks::Landmark;
use crate::solver::{LandmarkSchur, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;
use nalgebra::Vector6;

/// The pose-only measurement of a landmark with its inverse depth eliminated (module docs).
pub struct EliminatedLandmark<'a, const N: usize> {
    vs: VisualSettings<'a>,
    lm: &'a Landmark<N>,
    /// Without the observation at position 0 (what stays of a re-anchored landmark after the
    /// marginalization, `FactorSet::OldestRest`).
    without_obs_zero: bool,
    /// `tau*` of a cost evaluation at the same state, for the linearization to take.
    cached_tau: Option<f64>,
    schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    tau: Option<f64>,
    n_obs: u32,
}

impl<'a, const N: usize> EliminatedLandmark<'a, N> {
    /// The measurement of `lm` (`without_obs_zero`: without its observation at position 0),
    /// with `schur` as its accumulator when the extrinsic is estimated. A linearization takes
    /// `cached_tau` as `tau*` when given (the state has not changed since the cost evaluation
    /// that solved for it: bit-identical).
    pub fn new(
        vs: VisualSettings<'a>,
        lm: &'a Landmark<N>,
        without_obs_zero: bool,
        cached_tau: Option<f64>,
        schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    ) -> Self {
        EliminatedLandmark {
            vs,
            lm,
            without_obs_zero,
            cached_tau,
            schur,
            tau: None,
            n_obs: 0,
        }
    }

    /// The landmark's reprojections in `tau` over the first `count` positions.
    #[inline(always)]
    fn tau_landmark(&self, count: usize) -> Result<TauLandmark<N>, Error> {
        let lm = self.lm;
        // What stays in the window after the marginalization: the factor without position 0.
        let skip = self.without_obs_zero.then_some(0);
        let (s, sqrt_info) = (lm.anchor_s as usize, self.vs.sqrt_info);
        TauLandmark::without(&lm.obs, s, skip, None, sqrt_info, count).ok_or(Error::NotEnoughData)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for EliminatedLandmark<'_, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        self.tau = None;
        let (lm, huber) = (self.lm, &self.vs.huber);
        let s = lm.anchor_s as usize;
        let m = self.tau_landmark(v.count)?;
        self.n_obs = m.obs.len() as u32;
        let tau = match (self.cached_tau, &ne) {
            (Some(tau), Some(_)) => tau,
            _ => {
                let mut rays = HVec::new();
                m.rays_into(&v.poses, &v.frames, &mut rays)?;
                let (tau, cost) = newton_tau(&rays, lm.inv_depth, huber)?;
                if ne.is_none() {
                    // The next solve (the linearization or the marginalization at this state,
                    // the next trial near it) starts from here; a rejected LM trial restores
                    // the depth with the state.
                    self.tau = Some(tau);
                    return Ok(cost);
                }
                tau
            }
        };
        let Some(ne) = ne else {
            return Err(Error::DimensionMismatch);
        };
        let poses = &v.poses;
        let ps = poses.get(s).ok_or(Error::DimensionMismatch)?;
        let l = &v.layout;
        if !v.est_ext {
            let cost = match v.rotations() {
                Some(rot) => accumulate_eliminated(&m, poses, rot, tau, huber, l, ne)?,
                None => {
                    let rot = WindowRotations::new(poses, v.count, v.ext);
                    accumulate_eliminated(&m, poses, &rot, tau, huber, l, ne)?
                }
            };
            self.tau = Some(tau);
            return Ok(cost);
        }
        let sc = &mut *self.schur;
        sc.clear();
        let mut cost = 0.0;
        for (j, f) in m.obs.iter() {
            let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
            let jac = f.evaluate(ps, pj, v.ext, tau)?;
            let sq = jac.r.norm_squared();
            cost += huber.rho(sq)[0];
            let (est_td, est_ext) = (v.est_td, v.est_ext);
            let w = huber.sqrt_weight(sq);
            add_inverse_depth_obs(sc, ne, &jac, w, s, *j, l, est_td, est_ext)?;
        }
        sc.fold_into(ne, 0.0)?;
        self.tau = Some(tau);
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let m = self.tau_landmark(v.count)?;
        let rays = m.rays(&v.poses, &v.frames)?;
        let tau = self.lm.inv_depth;
        let mut rows = 0;
        for ray in rays.iter() {
            let (r, _) = ray.residual_and_d_tau(tau)?;
            rows += put_rows(&[r.x, r.y], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        Ok(rows)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for EliminatedLandmark<'_, N> {
    fn observations(&self) -> u32 {
        self.n_obs
    }

    fn inverse_depth(&self) -> Option<f64> {
        self.tau
    }
}

/// Most passes over the rays of [`newton_tau`] (it stops long before: one or two from the last
/// solution; the Gauss–Newton fallback converges linearly).
const NEWTON_PASSES: usize = 60;
/// A Newton step of at most this fraction of `tau` is the last one: Newton converges
/// quadratically, so the error it leaves is of the order of `(step / tau)^2` times the ray's
/// relative curvature `tau b_z / q_z` (the baseline over the depth) and the Huber weights'
/// change: about 1e-8 of `tau` (1.6e-8 in the unit test with an outlier), under the 1e-7 the
/// linearly converging Gauss–Newton stopped at.
const NEWTON_LAST_STEP: f64 = 1e-4;
/// Relative step at which a Gauss–Newton step (the fallback where the cost is not clearly convex
/// in `tau`) is the last one.
const GN_LAST_STEP: f64 = 1e-7;

/// `tau*` of an eliminated landmark and its robust cost `sum_j rho(|r_j(tau*)|^2)`: Newton's
/// method on the 1-D robust cost from `tau0` (the last solution). Each pass over the rays forms
/// the cost, its derivative `2 g` and its exact second derivative `2 h` with the rays' curvature
/// (`r'' = -2 kappa r'`) and the Huber kernel's `rho''`:
///
/// ```text
/// g = sum rho' r.r',   h = sum rho' (|r'|^2 + r.r'') + 2 rho'' (r.r')^2
/// ```
///
/// (where `h` is not clearly positive, a Gauss–Newton step with `h_gn = sum rho' |r'|^2`). The
/// cost at the final `tau` is the last pass's cost plus its quadratic model's change over the
/// last step (exact to third order in a step of at most 1e-4 of `tau`), so no pass is spent on
/// it. Errors: [`Error::NotEnoughData`] without a positive start, [`Error::NonFinite`],
/// [`Error::Degenerate`] for a ray behind its camera.
pub(super) fn newton_tau(rays: &[Ray], tau0: f64, huber: &Huber) -> Result<(f64, f64), Error> {
    if !(tau0 > 0.0 && tau0.is_finite()) {
        return Err(Error::NotEnoughData);
    }
    let mut tau = tau0;
    for _ in 0..NEWTON_PASSES {
        let [cost, g, h, h_gn] = robust_pass(rays, tau, huber)?;
        let newton = h > 0.1 * h_gn;
        let step = -g / if newton { h } else { h_gn };
        let next = tau + step;
        if next <= 0.0 {
            // The inverse depth stays positive: halve toward zero instead of crossing it.
            tau *= 0.5;
            continue;
        }
        tau = next;
        let last = if newton {
            NEWTON_LAST_STEP
        } else {
            GN_LAST_STEP
        };
        if libm::fabs(step) <= last * tau {
            return Ok((tau, cost + step * (2.0 * g + h * step)));
        }
    }
    let mut cost = 0.0;
    for ray in rays {
        cost += huber.rho(ray.residual_and_d_tau(tau)?.0.norm_squared())[0];
    }
    Ok((tau, cost))
}

/// One pass over the rays at `tau`: `[cost, g, h, h_gn]` of [`newton_tau`] (half the cost's
/// first and second derivatives in `tau`, and the Gauss–Newton part of the latter).
fn robust_pass(rays: &[Ray], tau: f64, huber: &Huber) -> Result<[f64; 4], Error> {
    let (mut cost, mut g, mut h, mut h_gn) = (0.0, 0.0, 0.0, 0.0);
    for ray in rays {
        let (r, d, kappa) = ray.residual_d_tau_curvature(tau)?;
        let [rho, w, w2] = huber.rho(r.norm_squared());
        let (rd, dd) = (r.dot(&d), d.norm_squared());
        cost += rho;
        g += w * rd;
        h_gn += w * dd;
        h += w * (dd - 2.0 * kappa * rd) + 2.0 * w2 * rd * rd;
    }
    let finite = [cost, g, h, h_gn].iter().all(|v| v.is_finite());
    if !(h_gn > 0.0 && finite) {
        return Err(Error::NonFinite);
    }
    Ok([cost, g, h, h_gn])
}

/// The landmark's linearization with `tau` eliminated, extrinsic fixed (module docs): every
/// observation's 2x6 pose blocks and delay columns go into `ne` as usual, and the landmark's
/// coupling to `tau` (`v`, `c`, `beta`) is folded in once at the end. Returns the robust cost.
#[inline(never)]
fn accumulate_eliminated<const N: usize, const D: usize>(
    m: &TauLandmark<N>,
    poses: &[KeyframePose; N],
    rot: &WindowRotations<N>,
    tau: f64,
    huber: &Huber,
    l: &Layout<N>,
    ne: &mut NormalEquations<D>,
) -> Result<f64, Error> {
    let ps = poses.get(m.s).ok_or(Error::DimensionMismatch)?;
    // The anchor's side of the chain is the same for every observation (same `s`, `x_s`, `tau`).
    let (_, f0) = m.obs.first().ok_or(Error::NotEnoughData)?;
    let anchor = f0.anchor_point(ps, rot, tau);
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
        let jac = f.evaluate_poses(ps, pj, rot, &anchor)?;
        let sq = jac.r.norm_squared();
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let (r, a, b, g) = (jac.r * w, jac.d_pose_s * w, jac.d_pose_j * w, jac.d_tau * w);
        let cj = col(*j)?;
        let tj = td_col(*j);
        let (t_s, t_j) = (jac.d_td[0] * w, jac.d_td[1] * w);
        let delays = ts.map(|ts| [(Some(ts), t_s), (tj, t_j)]);
        ne.add_2x6_pair(&r, &a, &b, cs, cj, delays)?;
        c += g.norm_squared();
        beta -= g.dot(&r);
        v_s += a.transpose() * g;
        v_ts += t_s.dot(&g);
        let _ = v_j.push((cj, b.transpose() * g, tj, t_j.dot(&g)));
    }
    if !(c > 1e-12 && c.is_finite() && beta.is_finite()) {
        return Ok(cost);
    }
    // The segments of v in column order: pose blocks (6 wide) and delays (1 wide).
    let mut poses6: HVec<(usize, [f64; 6]), N> = HVec::new();
    let mut scalars: HVec<(usize, f64), N> = HVec::new();
    let _ = poses6.push((cs, v_s.into()));
    for (cj, x, _, _) in v_j.iter() {
        let _ = poses6.push((*cj, (*x).into()));
    }
    if let Some(ts) = ts {
        let _ = scalars.push((ts, v_ts));
        for (_, _, tj, xt) in v_j.iter() {
            if let Some(tj) = tj {
                let _ = scalars.push((*tj, *xt));
            }
        }
    }
    let finite = poses6.iter().all(|(_, x)| x.iter().all(|v| v.is_finite()))
        && scalars.iter().all(|(_, x)| x.is_finite());
    if !finite {
        return Err(Error::NonFinite);
    }
    poses6.sort_unstable_by_key(|p| p.0);
    scalars.sort_unstable_by_key(|p| p.0);
    ne.fold_rank_one(&poses6, &scalars, 1.0 / c, beta);
    Ok(cost)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraExtrinsic;
    use crate::camera::Vec2;
    use crate::factors::inverse_depth_visual::InverseDepthVisualFactor;
    use crate::factors::{CamFrame, TimedObs};
    use crate::math::{quat_exp, Vec3};

    /// A landmark 4 m away seen from four keyframes with pixel noise; with `outlier`, the last
    /// observation is 30 px off (outside the Huber threshold).
    fn tau_scene(outlier: bool) -> (HVec<Ray, 4>, f64) {
        let ext = CameraExtrinsic {
            p_bc: Vec3::new(0.05, -0.02, 0.01),
            q_bc: quat_exp(&Vec3::new(-1.5, 0.02, -1.55)),
        };
        let poses: [KeyframePose; 4] = core::array::from_fn(|k| {
            let t = k as f64;
            KeyframePose {
                p_wb: Vec3::new(0.25 * t, 0.05 * t * t, -0.01 * t),
                q_wb: quat_exp(&Vec3::new(0.01 * t, -0.02 * t, 0.04 * t)),
                td: 0.0,
            }
        });
        let frames: [CamFrame; 4] = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        let p_w = Vec3::new(4.0, 1.0, 0.5);
        let noise = [
            [0.0, 0.0],
            [0.002, -0.001],
            [-0.0015, 0.0025],
            [0.001, 0.0005],
        ];
        let mut obs: [Vec2; 4] = core::array::from_fn(|k| {
            let c = ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb);
            let p_c = c.q_wc.inverse() * (p_w - c.p_wc);
            Vec2::new(p_c.x / p_c.z + noise[k][0], p_c.y / p_c.z + noise[k][1])
        });
        if outlier {
            obs[3].x += 30.0 / 460.0;
        }
        let sqrt_info = Vec2::new(460.0, 460.0) / 1.5;
        let obs_s = TimedObs::still(obs[0]);
        let mut m = TauLandmark::<4> {
            s: 0,
            obs: HVec::new(),
            depth: None,
        };
        for (j, o) in obs.iter().enumerate().skip(1) {
            let f = InverseDepthVisualFactor {
                kf_s: 0,
                kf_j: j,
                obs_s,
                obs_j: TimedObs::still(*o),
                sqrt_info,
            };
            m.obs.push((j, f)).unwrap();
        }
        let c0 = ext.camera_pose(&poses[0].p_wb, &poses[0].q_wb);
        let tau_true = 1.0 / (c0.q_wc.inverse() * (p_w - c0.p_wc)).z;
        (m.rays(&poses, &frames).unwrap(), tau_true)
    }

    fn robust_cost(rays: &[Ray], tau: f64, huber: &Huber) -> f64 {
        rays.iter()
            .map(|r| huber.rho(r.residual_and_d_tau(tau).unwrap().0.norm_squared())[0])
            .sum()
    }

    #[test]
    fn newton_pass_derivatives_match_numerical_differentiation() {
        let huber = Huber::new(1.0).unwrap();
        for outlier in [false, true] {
            let (rays, tau_true) = tau_scene(outlier);
            for tau in [0.8 * tau_true, tau_true, 1.3 * tau_true] {
                let [cost, g, h, h_gn] = robust_pass(&rays, tau, &huber).unwrap();
                assert!((cost - robust_cost(&rays, tau, &huber)).abs() <= 1e-12 * cost);
                let e = 1e-5 * tau;
                let f = |t: f64| robust_cost(&rays, t, &huber);
                let d1 = (f(tau + e) - f(tau - e)) / (2.0 * e);
                let d2 = (f(tau + e) - 2.0 * cost + f(tau - e)) / (e * e);
                assert!(
                    (2.0 * g - d1).abs() <= 1e-6 * d1.abs().max(1.0),
                    "{g} vs {d1}"
                );
                assert!((2.0 * h - d2).abs() <= 1e-4 * d2.abs(), "{h} vs {d2}");
                assert!(h_gn > 0.0);
            }
        }
    }

    #[test]
    fn newton_tau_finds_the_robust_minimum_and_its_cost() {
        let huber = Huber::new(1.0).unwrap();
        for outlier in [false, true] {
            let (rays, tau_true) = tau_scene(outlier);
            // (Three rays of short baseline: with the outlier the minimum is far from the truth,
            // so only the minimum itself is checked.)
            let (tau, cost) = newton_tau(&rays, 0.6 * tau_true, &huber).unwrap();
            // From a start next to it: the same minimum.
            let (tau2, cost2) = newton_tau(&rays, tau * (1.0 + 1e-3), &huber).unwrap();
            // (Both stop after a Newton step of at most 1e-4 of `tau`: about 1e-8 left, 1.6e-8
            // here with the outlier's weight changing; the Gauss–Newton solve stopped at 1e-7.)
            assert!((tau - tau2).abs() <= 1e-7 * tau, "{tau} vs {tau2}");
            for (t, c) in [(tau, cost), (tau2, cost2)] {
                let exact = robust_cost(&rays, t, &huber);
                assert!((c - exact).abs() <= 1e-10 * exact, "{c} vs {exact}");
            }
            for d in [1e-4, -1e-4, 1e-3, -1e-3] {
                assert!(robust_cost(&rays, tau * (1.0 + d), &huber) > cost);
            }
        }
        let (rays, _) = tau_scene(false);
        assert_eq!(
            newton_tau(&rays, 0.0, &huber).err(),
            Some(Error::NotEnoughData)
        );
    }
}

//! Pose-only visual landmarks with the depth from all their observations
//! ([`super::VisualDepth::Eliminated`], the default).
//!
//! The paper's pose-only reprojection takes the landmark's depth from two anchor views `(s, e)`
//! and treats it as exact in every other residual. Measured on EuRoC-like simulated flights, that
//! two-view depth costs about a quarter of the accuracy the same observations give when the depth
//! is estimated from all of them (the inverse-depth baseline: 0.055 vs 0.075 m median ATE over ten
//! seeds): the depth's error enters every residual of the landmark alike, and a noisy second
//! anchor picks the depth. So the depth is eliminated instead, still without being a state.
//!
//! The same holds for the anchor's own observation: every residual `j != s` is predicted from
//! the anchor's bearing `x_s`, so taking `x_s` as exact puts the anchor's pixel error into all of
//! a track's residuals alike, counted once per observation instead of once. Measured on 15
//! simulated LiDAR flights (session 50, BENCHMARKS "The pixel noise against the NEES"), the
//! window's covariance was overconfident by about a factor 2 from it. So the anchor's bearing
//! is a nuisance parameter too: `x_s + (delta, 0)`, with the anchor's observation a residual
//! `r_s = W delta` like the others. The rays stay linear in the three parameters
//! `u = (delta.x, delta.y, tau)`: camera `j` sees the landmark along
//!
//! ```text
//! P_j ~ a_j + R_js (delta, 0) + tau b_j
//! ```
//!
//! At each evaluation the `u*` that minimizes the landmark's robust reprojection cost is solved
//! for the current poses (IRLS Gauss–Newton on the rays from the last solution, a few 3x3 solves:
//! [`solve_bearing_tau`]), and the linearization projects `u` out by its Schur complement
//! (variable projection), as the MSC-based LiDAR-depth measurement does with its depth alone
//! (`estimator::problem::lidar`):
//!
//! ```text
//! H += sum_j J_j^T W_j J_j - V C^-1 V^T,   V = sum_j J_j^T W_j G_j,   C = sum_j G_j^T W_j G_j
//! ```
//!
//! with `J_j` the residual's Jacobian on the window's variables (the poses of `s` and `j`, their
//! delays, the extrinsic), `G_j` (2x3) on `u` (the anchor's residual: `G_s = [W 0]`, no `J`),
//! `W_j` the observation's Huber weight; `V C^-1 V^T` is folded in as three rank-one updates of
//! `V L^-T` (`C = L L^T`). The measurement is a function of the window's variables alone: the
//! landmark has no state, its cost is `min_u` of the reprojection cost, so the LM's gain ratio
//! compares what the linear model predicts.
//!
//! **A LiDAR landmark** (the MSC-based LDM, [`LdmMode::Msc`](crate::lidar::LdmMode::Msc)) adds
//! its depth row `r_d = (1/tau - d_r) / sigma_dr` to these residuals: the depth is `z` in the
//! anchor camera, `1/tau` whatever `delta` (the anchor's ray is `(x_s + delta, 1) / tau`), so
//! the row has `G = (0, 0, dr_d/dtau)` and no window variable; its Huber weight is its own. This
//! is the paper's MSC measurement (`estimator::problem::lidar`: the reprojections and the depth
//! row with the inverse depth projected out) with the anchor's bearing freed as above and the
//! robust kernel per residual instead of on the stacked block, so that a LiDAR landmark's
//! reprojections count as much as a visual one's and a wrong depth loses its weight alone. The
//! paper's block stays for the two-view visual depth ([`super::LandmarkModel::MscLidar`]).
#![deny(clippy::too_many_lines)]

use super::factor::{
    lidar_depth, linearization_work, put_rows, row_major, LandmarkFactor, VisualSettings,
    WindowFactor, WindowVars,
};
use crate::camera::Vec2;
use crate::estimator::tau_landmark::{Ray, TauLandmark};
use crate::estimator::window::Block;
use crate::factors::inverse_depth_visual::{InverseDepthVisualFactor, WindowRotations};
use crate::factors::robust::Huber;
use crate::factors::{CamFrame, KeyframePose};
use crate::landmarks::{Landmark, LidarDepth};
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;
use nalgebra::Matrix2x6;

/// The pose-only measurement of a landmark with its inverse depth eliminated (module docs).
pub struct EliminatedLandmark<'a, const N: usize> {
    vs: VisualSettings<'a>,
    lm: &'a Landmark<N>,
    /// The LiDAR depth whose row joins the residuals (MSC-based LDM), if any.
    depth: Option<LidarDepth>,
    /// Without the observation at position 0 (what stays of a re-anchored landmark after the
    /// marginalization, `FactorSet::OldestRest`).
    without_obs_zero: bool,
    /// `(delta*, tau*)` of a cost evaluation at the same state, for the linearization to take.
    cached: Option<([f64; 2], f64)>,
    tau: Option<f64>,
    delta: Option<[f64; 2]>,
    n_obs: u32,
    /// The work of the last `add` ([`LandmarkFactor::work`]).
    work: u32,
}

impl<'a, const N: usize> EliminatedLandmark<'a, N> {
    /// The measurement of `lm` (`without_obs_zero`: without its observation at position 0). A
    /// linearization takes `cached` as `(delta*, tau*)` when given (the state has not changed
    /// since the cost evaluation that solved for them: bit-identical).
    pub fn new(
        vs: VisualSettings<'a>,
        lm: &'a Landmark<N>,
        without_obs_zero: bool,
        cached: Option<([f64; 2], f64)>,
    ) -> Self {
        EliminatedLandmark {
            vs,
            lm,
            depth: lidar_depth(vs.cfg, lm),
            without_obs_zero,
            cached,
            tau: None,
            delta: None,
            n_obs: 0,
            work: 0,
        }
    }

    /// `(delta*, tau*)` at `poses` (the measurement's own solve, from the landmark's last values):
    /// what the depth-only optimization (paper V.D) keeps under this model;
    /// [`Error::Degenerate`] where the solve does not converge.
    pub fn solve_at(
        &self,
        poses: &[KeyframePose; N],
        frames: &[CamFrame; N],
        count: usize,
    ) -> Result<([f64; 2], f64), Error> {
        let m = self.tau_landmark(count)?;
        let mut rays: HVec<Ray, N> = HVec::new();
        m.rays_into(poses, frames, &mut rays)?;
        let (lm, vs) = (self.lm, &self.vs);
        let depth = m.depth.as_ref();
        let s = solve_bearing_tau(
            &rays,
            vs.sqrt_info,
            depth,
            lm.bearing_delta,
            lm.inv_depth,
            &vs.huber,
        )?;
        if !s.converged {
            return Err(Error::Degenerate);
        }
        Ok((s.delta, s.tau))
    }

    /// The landmark's reprojections in `tau` over the first `count` positions.
    #[inline(always)]
    fn tau_landmark(&self, count: usize) -> Result<TauLandmark<N>, Error> {
        let lm = self.lm;
        // What stays in the window after the marginalization: the factor without position 0.
        let skip = self.without_obs_zero.then_some(0);
        let (s, sqrt_info) = (lm.anchor_s as usize, self.vs.sqrt_info);
        TauLandmark::without(&lm.obs, s, skip, self.depth, sqrt_info, count)
            .ok_or(Error::NotEnoughData)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for EliminatedLandmark<'_, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        (self.tau, self.delta, self.work) = (None, None, 0);
        let (lm, huber) = (self.lm, &self.vs.huber);
        let m = self.tau_landmark(v.count)?;
        self.n_obs = m.obs.len() as u32;
        // The rays at this state: for the solve and the linearization alike (built once).
        let mut rays: HVec<Ray, N> = HVec::new();
        m.rays_into(&v.poses, &v.frames, &mut rays)?;
        let (delta, tau) = match (self.cached, &ne) {
            (Some(c), Some(_)) => c,
            _ => {
                let w_s = self.vs.sqrt_info;
                let s = solve_bearing_tau(
                    &rays,
                    w_s,
                    m.depth.as_ref(),
                    lm.bearing_delta,
                    lm.inv_depth,
                    huber,
                )?;
                let rays_n = u32::try_from(rays.len()).unwrap_or(u32::MAX);
                self.work = s.passes.saturating_mul(rays_n);
                match (ne.is_none(), s.converged) {
                    // The next solve (the linearization or the marginalization at this state,
                    // the next trial near it) starts from here; a rejected LM trial restores
                    // them with the state.
                    (true, true) => {
                        (self.tau, self.delta) = (Some(s.tau), Some(s.delta));
                        return Ok(s.cost);
                    }
                    // Not the minimum: its cost bounds the measurement's from above (a trial
                    // is judged on it); nothing is kept, so the linearization solves again.
                    (true, false) => return Ok(s.cost),
                    // Linearized off its minimum the gradient would be wrong to first order:
                    // the landmark is left out of this solve (disabled and counted).
                    (false, false) => return Err(Error::Degenerate),
                    (false, true) => (s.delta, s.tau),
                }
            }
        };
        let Some(ne) = ne else {
            return Err(Error::DimensionMismatch);
        };
        let at = Solved {
            delta,
            tau,
            w_s: self.vs.sqrt_info,
        };
        let cost = match v.rotations() {
            Some(rot) => accumulate_eliminated(&m, &rays, v, rot, &at, huber, ne)?,
            None => {
                let rot = WindowRotations::new(&v.poses, v.count, v.ext);
                accumulate_eliminated(&m, &rays, v, &rot, &at, huber, ne)?
            }
        };
        (self.tau, self.delta) = (Some(tau), Some(delta));
        self.work = self.work.saturating_add(linearization_work(self.n_obs));
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let m = self.tau_landmark(v.count)?;
        let rays = m.rays(&v.poses, &v.frames)?;
        let (lm, w) = (self.lm, self.vs.sqrt_info);
        let delta = lm.bearing_delta;
        let mut rows = put_rows(&[w.x * delta[0], w.y * delta[1]], out)?;
        for ray in rays.iter() {
            let (r, _) = ray.residual_and_d_bearing_tau(delta, lm.inv_depth)?;
            rows += put_rows(&[r.x, r.y], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        if let Some(d) = &m.depth {
            let r = d.row(lm.inv_depth)[0];
            rows += put_rows(&[r], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        Ok(rows)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for EliminatedLandmark<'_, N> {
    fn observations(&self) -> u32 {
        self.n_obs
    }

    fn work(&self, _linearized: bool) -> u32 {
        self.work
    }

    fn depth_measurements(&self) -> u32 {
        u32::from(self.depth.is_some())
    }

    fn inverse_depth(&self) -> Option<f64> {
        self.tau
    }

    fn bearing_delta(&self) -> Option<[f64; 2]> {
        self.delta
    }
}

/// Most passes over the rays of [`solve_bearing_tau`] (it stops after one to three from the
/// last solution; the Gauss–Newton fallback converges linearly, a few landmarks in a thousand
/// need more than ten).
const BEARING_PASSES: usize = 60;
/// A Newton step of at most this fraction of `tau` (and of this many normalized units, about
/// 5e-5 px, in the bearing) is the last one: Newton converges quadratically, so what it leaves
/// is of the order of the step squared times the rays' curvature, far below the noise; the
/// cost returned is the last pass's plus the step's quadratic model (exact to third order).
const NEWTON_LAST_STEP: [f64; 2] = [1e-7, 1e-5];
/// The same for a Gauss–Newton step (where the cost is not clearly convex), which converges
/// linearly.
const GN_LAST_STEP: f64 = 1e-9;
/// A Gauss–Newton step rejected (uphill) is shortened fourfold; below this fraction of it no
/// descent is left at the cost's rounding: the point is the minimum.
const MIN_STEP_FRACTION: f64 = 1e-6;
/// After this many Gauss–Newton steps accepted in a row, each next one is twice as long (up to
/// [`MAX_STEP_FRACTION`] times the step): the run is crawling along a flat valley.
const GN_RUN_BEFORE_LONGER: u32 = 4;
/// The longest of those steps, in Gauss–Newton steps.
const MAX_STEP_FRACTION: f64 = 1024.0;
/// The smallest inverse depth (1/m, a depth of 1000 km) [`solve_bearing_tau`] goes to: a cost
/// still falling there has its minimum at infinite depth or behind the cameras (not
/// converged).
const MIN_INV_DEPTH: f64 = 1e-6;
/// Newton steps are taken where the Gauss–Newton step is at most this (bearing, fraction of
/// `tau`): near the minimum, as a warm start from the last solution is.
const NEWTON_FROM: [f64; 2] = [1e-3, 0.05];

/// Cholesky factor `L` (lower, `L L^T = h`) of a symmetric 3x3 matrix, and whether its last
/// pivot is positive (the first two must be: [`Error::NonFinite`] otherwise).
fn chol3(h: &[[f64; 3]; 3]) -> Result<([[f64; 3]; 3], bool), Error> {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let mut sum = h[i][j];
            for (a, b) in l[i].iter().zip(l[j].iter()).take(j) {
                sum -= a * b;
            }
            if i == j {
                if !(sum > 1e-12 && sum.is_finite()) {
                    if i == 2 && sum.is_finite() {
                        return Ok((l, false));
                    }
                    return Err(Error::NonFinite);
                }
                l[i][i] = libm::sqrt(sum);
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    Ok((l, true))
}

/// `L^-1 v` by forward substitution over the first `n` rows.
fn forward3(l: &[[f64; 3]; 3], v: [f64; 3], n: usize) -> [f64; 3] {
    let mut u = [0.0; 3];
    for i in 0..n {
        let mut sum = v[i];
        for k in 0..i {
            sum -= l[i][k] * u[k];
        }
        u[i] = sum / l[i][i];
    }
    u
}

/// The solution of `h x = v` for a full-rank Cholesky factor of `h` ([`chol3`]).
fn solve3(l: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    let y = forward3(l, v, 3);
    let mut x = [0.0; 3];
    for i in (0..3).rev() {
        let mut sum = y[i];
        for k in i + 1..3 {
            sum -= l[k][i] * x[k];
        }
        x[i] = sum / l[i][i];
    }
    x
}

/// What [`bearing_pass`] returns: `(cost, g, h, h_gn)`.
type BearingPass = (f64, [f64; 3], [[f64; 3]; 3], [[f64; 3]; 3]);

/// One pass of [`solve_bearing_tau`] at `(delta, tau)` in `u = (delta.x, delta.y, tau)`: the
/// robust cost, half its gradient `g`, half its exact Hessian `h` and the Gauss–Newton part
/// of the latter `h_gn` (the anchor's residual `w_s delta` included):
///
/// ```text
/// g = sum rho' J^T r,   h_gn = sum rho' J^T J,
/// h = sum rho' (J^T J + sum_c r_c d2r_c) + 2 rho'' (J^T r)(J^T r)^T
/// ```
///
/// with the rays' second derivatives from their curvatures ([`Ray::curvatures`]).
fn bearing_pass(
    rays: &[Ray],
    w_s: Vec2,
    depth: Option<&LidarDepth>,
    delta: [f64; 2],
    tau: f64,
    huber: &Huber,
) -> Result<BearingPass, Error> {
    let r_s = Vec2::new(w_s.x * delta[0], w_s.y * delta[1]);
    let [rho, w, w2] = huber.rho(r_s.norm_squared());
    let mut cost = rho;
    let mut g = [w * w_s.x * r_s.x, w * w_s.y * r_s.y, 0.0];
    let (mut h, mut h_gn) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
    h_gn[0][0] = w * w_s.x * w_s.x;
    h_gn[1][1] = w * w_s.y * w_s.y;
    for a in 0..2 {
        for b in 0..2 {
            h[a][b] = h_gn[a][b] + 2.0 * w2 * g[a] * g[b] / (w * w);
        }
    }
    for ray in rays {
        let (r, d) = ray.residual_and_d_bearing_tau(delta, tau)?;
        let kappa = ray.curvatures(delta, tau);
        let [rho, w, w2] = huber.rho(r.norm_squared());
        let rd = d.map(|dk| r.dot(&dk));
        cost += rho;
        for a in 0..3 {
            g[a] += w * rd[a];
            for b in 0..=a {
                let gn = d[a].dot(&d[b]);
                h_gn[a][b] += w * gn;
                let curv = -(rd[a] * kappa[b] + rd[b] * kappa[a]);
                h[a][b] += w * (gn + curv) + 2.0 * w2 * rd[a] * rd[b];
            }
        }
    }
    if let Some(d) = depth {
        // The depth row depends on `tau` alone.
        let [r, d1, d2] = d.row(tau);
        let [rho, w, w2] = huber.rho(r * r);
        cost += rho;
        g[2] += w * r * d1;
        h_gn[2][2] += w * d1 * d1;
        h[2][2] += w * (d1 * d1 + r * d2) + 2.0 * w2 * (r * d1) * (r * d1);
    }
    for a in 0..3 {
        for b in 0..a {
            h[b][a] = h[a][b];
            h_gn[b][a] = h_gn[a][b];
        }
    }
    let finite = cost.is_finite()
        && g.iter()
            .chain(h.iter().flatten())
            .chain(h_gn.iter().flatten())
            .all(|v| v.is_finite());
    if !finite {
        return Err(Error::NonFinite);
    }
    Ok((cost, g, h, h_gn))
}

/// `(delta*, tau*)` of an eliminated landmark with its anchor's bearing free (module docs) and
/// the robust cost `rho(|w_s delta|^2) + sum_j rho(|r_j(delta, tau)|^2)` there, from
/// `(delta0, tau0)` (the last solution): Newton's method on the exact Hessian of
/// [`bearing_pass`] near the minimum, Gauss–Newton steps farther away or where the Hessian is
/// not positive definite. A step is taken only downhill: an uphill Newton step (the exact
/// Hessian of a Huber-linear residual is flat along it, so the step can be huge) gives way to
/// the Gauss–Newton step, an uphill (or behind-the-camera) Gauss–Newton step is shortened.
/// Where the passes run out first (a flat, curved valley: two observations both past the Huber
/// threshold) or the cost falls toward infinite depth, the result says it has not converged
/// (its cost is then an upper bound of the minimum's): the variable projection's gradient holds
/// at the minimum only. Errors: [`Error::NotEnoughData`] without a positive `tau0`,
/// [`Error::Degenerate`] for a ray behind its camera at the start, [`Error::NonFinite`] for
/// non-finite input or where the depth is unobserved (no parallax).
pub(super) fn solve_bearing_tau(
    rays: &[Ray],
    w_s: Vec2,
    depth: Option<&LidarDepth>,
    delta0: [f64; 2],
    tau0: f64,
    huber: &Huber,
) -> Result<BearingTau, Error> {
    if !(tau0 > 0.0 && tau0.is_finite()) {
        return Err(Error::NotEnoughData);
    }
    let mut delta = if delta0.iter().all(|d| d.is_finite()) {
        delta0
    } else {
        [0.0; 2]
    };
    let mut tau = tau0;
    let mut at = bearing_pass(rays, w_s, depth, delta, tau, huber)?;
    let mut passes = 1;
    // After a rejected step: no Newton step until one is accepted, and the fraction of the
    // Gauss-Newton step taken; the Gauss-Newton steps accepted in a row.
    let (mut newton_ok, mut fraction, mut gn_run) = (true, 1.0, 0);
    for _ in 0..BEARING_PASSES {
        let (newton, step) = bearing_step(&at, tau, newton_ok)?;
        if let Some(done) = converged_at(&at, delta, tau, newton, step) {
            return Ok(BearingTau { passes, ..done });
        }
        let cost = at.0;
        // A shortened Gauss-Newton step after a rejection; the inverse depth at most halved (it
        // stays positive).
        let mut k = if newton { 1.0 } else { fraction };
        if tau + k * step[2] < 0.5 * tau {
            k = -0.5 * tau / step[2];
        }
        let next = (
            [delta[0] + k * step[0], delta[1] + k * step[1]],
            tau + k * step[2],
        );
        if next.1 < MIN_INV_DEPTH {
            // The cost falls toward infinite depth (or behind the cameras): no parallax holds
            // the depth, no minimum.
            break;
        }
        passes += 1;
        match bearing_pass(rays, w_s, depth, next.0, next.1, huber) {
            Ok(p) if p.0 <= cost => {
                (delta, tau, at) = (next.0, next.1, p);
                newton_ok = true;
                if newton {
                    (fraction, gn_run) = (1.0, 0);
                } else {
                    // A long run of accepted Gauss-Newton steps crawls along a flat valley
                    // (residuals past the Huber threshold pulling apart): longer steps.
                    gn_run += 1;
                    if gn_run >= GN_RUN_BEFORE_LONGER {
                        fraction = libm::fmin(2.0 * fraction, MAX_STEP_FRACTION);
                    }
                }
            }
            // Uphill, or a ray behind its camera: a Gauss-Newton step, then shorter ones.
            Ok(_) | Err(Error::Degenerate) => {
                if newton {
                    newton_ok = false;
                } else if fraction < MIN_STEP_FRACTION {
                    // No descent left at the rounding of the cost: a minimum.
                    return Ok(BearingTau {
                        delta,
                        tau,
                        cost,
                        converged: true,
                        passes,
                    });
                } else {
                    (fraction, gn_run) = (0.25 * libm::fmin(fraction, 1.0), 0);
                }
            }
            Err(e) => return Err(e),
        }
    }
    Ok(BearingTau {
        delta,
        tau,
        cost: at.0,
        converged: false,
        passes,
    })
}

/// The step of [`solve_bearing_tau`] from a pass `at` (at inverse depth `tau`): Newton's on the
/// exact Hessian near the minimum where it is positive definite (and `newton_ok`), Gauss–Newton's
/// otherwise; whether it is Newton's.
fn bearing_step(at: &BearingPass, tau: f64, newton_ok: bool) -> Result<(bool, [f64; 3]), Error> {
    let (_, g, h, h_gn) = at;
    let minus_g = [-g[0], -g[1], -g[2]];
    let (l_gn, full) = chol3(h_gn)?;
    if !full {
        return Err(Error::NonFinite);
    }
    let step_gn = solve3(&l_gn, minus_g);
    // Newton near the minimum only (far from it the exact Hessian can lead elsewhere).
    let near = libm::fabs(step_gn[2]) <= NEWTON_FROM[1] * tau
        && libm::fabs(step_gn[0]) <= NEWTON_FROM[0]
        && libm::fabs(step_gn[1]) <= NEWTON_FROM[0];
    Ok(match chol3(h) {
        Ok((l, true)) if near && newton_ok => (true, solve3(&l, minus_g)),
        _ => (false, step_gn),
    })
}

/// The converged solution when `step` (from the pass `at` at `(delta, tau)`) is small enough to
/// be the last ([`NEWTON_LAST_STEP`], [`GN_LAST_STEP`]): the step's end, its cost from the
/// step's quadratic model.
fn converged_at(
    at: &BearingPass,
    delta: [f64; 2],
    tau: f64,
    newton: bool,
    step: [f64; 3],
) -> Option<BearingTau> {
    let (cost, g, h, h_gn) = at;
    let [last_delta, last_tau] = if newton {
        NEWTON_LAST_STEP
    } else {
        [GN_LAST_STEP; 2]
    };
    let small = libm::fabs(step[2]) <= last_tau * tau
        && libm::fabs(step[0]) <= last_delta
        && libm::fabs(step[1]) <= last_delta;
    if !small {
        return None;
    }
    let hm = if newton { h } else { h_gn };
    let mut model = 0.0;
    for a in 0..3 {
        let hs: f64 = (0..3).map(|b| hm[a][b] * step[b]).sum();
        model += step[a] * (2.0 * g[a] + hs);
    }
    Some(BearingTau {
        delta: [delta[0] + step[0], delta[1] + step[1]],
        tau: tau + step[2],
        cost: cost + model,
        converged: true,
        passes: 0,
    })
}

/// What [`solve_bearing_tau`] found: the bearing correction and inverse depth, the robust cost
/// there, and whether it is the minimum (the pass cap [`BEARING_PASSES`] not reached).
#[derive(Clone, Copy, Debug)]
pub(super) struct BearingTau {
    pub delta: [f64; 2],
    pub tau: f64,
    pub cost: f64,
    pub converged: bool,
    /// Passes over the rays ([`bearing_pass`] evaluations) it took.
    pub passes: u32,
}

/// Where a landmark's linearization is taken: the solved bearing correction and inverse depth,
/// and the anchor observation's whitening.
struct Solved {
    delta: [f64; 2],
    tau: f64,
    w_s: Vec2,
}

/// Most columns of the fold's single-column list: the delays and, when it is estimated, the
/// extrinsic's six (a window of up to 58 keyframes; beyond, the landmark is refused with
/// [`Error::CapacityExceeded`]).
const FOLD_SCALARS: usize = 64;
/// The least fraction of a landmark's inverse-depth information left given its bearing
/// correction (the last Cholesky pivot squared over `C[2][2]`) its elimination is folded with;
/// below it the landmark is refused ([`Error::Degenerate`]: disabled for the solve, counted).
const MIN_DEPTH_INFORMATION: f64 = 1e-8;

/// One landmark's `(delta.x, delta.y, tau)` block accumulated over its residuals (module docs):
/// `C = sum G^T G`, `beta = -sum G^T r` and the couplings `V = sum J^T G` per keyframe pose
/// block (six rows each), per delay column and the extrinsic's six columns.
struct Elimination<const N: usize> {
    c: [[f64; 3]; 3],
    beta: [f64; 3],
    poses: HVec<(usize, [[f64; 3]; 6]), N>,
    scalars: HVec<(usize, [f64; 3]), FOLD_SCALARS>,
}

impl<const N: usize> Elimination<N> {
    /// The accumulator with the anchor's own residual `w_s delta` (no pose or delay in it) and
    /// its robust cost.
    fn new(at: &Solved, huber: &Huber) -> (Self, f64) {
        let r_s = Vec2::new(at.w_s.x * at.delta[0], at.w_s.y * at.delta[1]);
        let sq = r_s.norm_squared();
        let w = huber.weight(sq);
        let mut c = [[0.0; 3]; 3];
        c[0][0] = w * at.w_s.x * at.w_s.x;
        c[1][1] = w * at.w_s.y * at.w_s.y;
        let beta = [-c[0][0] * at.delta[0], -c[1][1] * at.delta[1], 0.0];
        let e = Elimination {
            c,
            beta,
            poses: HVec::new(),
            scalars: HVec::new(),
        };
        (e, huber.rho(sq)[0])
    }

    /// Adds one (weighted) residual `r` with derivatives `g` in `(delta, tau)`: to `C`, `beta`.
    fn add_residual(&mut self, r: &Vec2, g: &[Vec2; 3]) {
        for p in 0..3 {
            self.beta[p] -= g[p].dot(r);
            for q in 0..3 {
                self.c[p][q] += g[p].dot(&g[q]);
            }
        }
    }

    /// `V += J^T g` for a 2x6 block `jac` at column `col`.
    fn couple6(&mut self, col: usize, jac: &Matrix2x6<f64>, g: &[Vec2; 3]) -> Result<(), Error> {
        let idx = match self.poses.iter().position(|(c, _)| *c == col) {
            Some(i) => i,
            None => {
                self.poses
                    .push((col, [[0.0; 3]; 6]))
                    .map_err(|_| Error::CapacityExceeded)?;
                self.poses.len() - 1
            }
        };
        let Some((_, acc)) = self.poses.get_mut(idx) else {
            return Err(Error::DimensionMismatch);
        };
        for (i, row) in acc.iter_mut().enumerate() {
            let ji = Vec2::new(jac[(0, i)], jac[(1, i)]);
            for (x, gk) in row.iter_mut().zip(g) {
                *x += ji.dot(gk);
            }
        }
        Ok(())
    }

    /// `V += j^T g` for the single column `col` with derivative `j`.
    fn couple1(&mut self, col: usize, j: &Vec2, g: &[Vec2; 3]) -> Result<(), Error> {
        let add = g.map(|gk| j.dot(&gk));
        match self.scalars.iter_mut().find(|(c, _)| *c == col) {
            Some((_, x)) => x.iter_mut().zip(add).for_each(|(x, a)| *x += a),
            None => self
                .scalars
                .push((col, add))
                .map_err(|_| Error::CapacityExceeded)?,
        }
        Ok(())
    }

    /// `H -= V C^-1 V^T`, `b -= V C^-1 beta` into `ne`: three rank-one folds of the whitened
    /// couplings `U = V L^-T` (`C = L L^T`), two when the depth is unobserved.
    fn fold<const D: usize>(mut self, ne: &mut NormalEquations<D>) -> Result<(), Error> {
        let (lc, full) = chol3(&self.c)?;
        if full && lc[2][2] * lc[2][2] < MIN_DEPTH_INFORMATION * self.c[2][2] {
            // The depth is all but unobserved given the bearing (an anchor given up by a
            // landmark of two or three observations): its elimination would divide by the
            // rounding of the information, and the fold cancel catastrophically.
            return Err(Error::Degenerate);
        }
        let rank = if full { 3 } else { 2 };
        let beta_w = forward3(&lc, self.beta, rank);
        for (_, x) in self.poses.iter_mut() {
            for row in x.iter_mut() {
                *row = forward3(&lc, *row, rank);
            }
        }
        for (_, x) in self.scalars.iter_mut() {
            *x = forward3(&lc, *x, rank);
        }
        let finite = self
            .poses
            .iter()
            .all(|(_, x)| x.iter().flatten().all(|v| v.is_finite()))
            && self
                .scalars
                .iter()
                .all(|(_, x)| x.iter().all(|v| v.is_finite()))
            && beta_w.iter().all(|v| v.is_finite());
        if !finite {
            return Err(Error::NonFinite);
        }
        self.poses.sort_unstable_by_key(|p| p.0);
        self.scalars.sort_unstable_by_key(|p| p.0);
        for (k, beta) in beta_w.iter().enumerate().take(rank) {
            let p6: HVec<(usize, [f64; 6]), N> = self
                .poses
                .iter()
                .map(|(c, x)| (*c, x.map(|r| r[k])))
                .collect();
            let sc: HVec<(usize, f64), FOLD_SCALARS> =
                self.scalars.iter().map(|(c, x)| (*c, x[k])).collect();
            ne.fold_rank_one(&p6, &sc, 1.0, *beta);
        }
        Ok(())
    }
}

/// The landmark's linearization with its anchor bearing and depth eliminated (module docs):
/// every observation's pose blocks, delay and extrinsic columns go into `ne` as usual, and the
/// landmark's coupling to `(delta, tau)` is folded in at the end ([`Elimination::fold`]).
/// `rays` are `m`'s rays at `v` ([`TauLandmark::rays_into`]). Returns the robust cost.
#[inline(never)]
fn accumulate_eliminated<const N: usize, const D: usize>(
    m: &TauLandmark<N>,
    rays: &[Ray],
    v: &WindowVars<'_, N>,
    rot: &WindowRotations<N>,
    at: &Solved,
    huber: &Huber,
    ne: &mut NormalEquations<D>,
) -> Result<f64, Error> {
    let (poses, l) = (&v.poses, &v.layout);
    let ps = poses.get(m.s).ok_or(Error::DimensionMismatch)?;
    // The factors at the corrected anchor bearing `x_s + delta`.
    let shifted = |f: &InverseDepthVisualFactor| {
        let mut f = *f;
        f.obs_s.x_n += Vec2::new(at.delta[0], at.delta[1]);
        f
    };
    let (_, f0) = m.obs.first().ok_or(Error::NotEnoughData)?;
    let anchor = shifted(f0).anchor_point(ps, rot, at.tau);
    let col = |k: usize| l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch);
    let td_col = |k: usize| l.col(Block::Td(k as u8));
    let (cs, ts) = (col(m.s)?, td_col(m.s));
    let ext_col = l.col(Block::Ext);
    let (mut e, mut cost) = Elimination::<N>::new(at, huber);
    for ((j, f), ray) in m.obs.iter().zip(rays.iter()) {
        let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
        let (jac, d_ext) = match ext_col {
            None => (shifted(f).evaluate_poses(ps, pj, rot, &anchor)?, None),
            Some(_) => {
                let full = shifted(f).evaluate(ps, pj, v.ext, at.tau)?;
                (full.poses(), Some(full.d_ext))
            }
        };
        let (_, d) = ray.residual_and_d_bearing_tau(at.delta, at.tau)?;
        let sq = jac.r.norm_squared();
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let (r, a, b) = (jac.r * w, jac.d_pose_s * w, jac.d_pose_j * w);
        let g = d.map(|x| x * w);
        let (cj, tj) = (col(*j)?, td_col(*j));
        let (t_s, t_j) = (jac.d_td[0] * w, jac.d_td[1] * w);
        match (ext_col, d_ext) {
            (Some(cx), Some(d_ext)) => {
                let x = d_ext * w;
                add_with_extrinsic(
                    ne,
                    &r,
                    [(cs, &a), (cj, &b), (cx, &x)],
                    [(ts, t_s), (tj, t_j)],
                )?;
                for i in 0..6 {
                    e.couple1(cx + i, &x.column(i).into_owned(), &g)?;
                }
            }
            _ => {
                let delays = ts.map(|ts| [(Some(ts), t_s), (tj, t_j)]);
                ne.add_2x6_pair(&r, &a, &b, cs, cj, delays)?;
            }
        }
        e.add_residual(&r, &g);
        e.couple6(cs, &a, &g)?;
        e.couple6(cj, &b, &g)?;
        for (tc, t) in [(ts, &t_s), (tj, &t_j)] {
            if let Some(tc) = tc {
                e.couple1(tc, t, &g)?;
            }
        }
    }
    if let Some(d) = &m.depth {
        // The depth row: on `tau` alone, nothing of the window's variables.
        let [r, d1, _] = d.row(at.tau);
        let sq = r * r;
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let zero = Vec2::zeros();
        e.add_residual(
            &Vec2::new(r * w, 0.0),
            &[zero, zero, Vec2::new(d1 * w, 0.0)],
        );
    }
    e.fold(ne)?;
    Ok(cost)
}

/// Adds one weighted reprojection with its extrinsic block: the 2x6 blocks `(column, J)` and the
/// delays `(column, j)` (where the delays have columns) through [`NormalEquations::add_blocks`].
fn add_with_extrinsic<const D: usize>(
    ne: &mut NormalEquations<D>,
    r: &Vec2,
    blocks6: [(usize, &Matrix2x6<f64>); 3],
    delays: [(Option<usize>, Vec2); 2],
) -> Result<(), Error> {
    let mut rows = [[0.0; 12]; 3];
    for (out, (_, m)) in rows.iter_mut().zip(blocks6.iter()) {
        row_major(*m, out);
    }
    let tds = delays.map(|(_, t)| [t.x, t.y]);
    let mut blocks: HVec<JacobianBlock<'_>, 5> = HVec::new();
    for ((c, _), jac) in blocks6.iter().zip(rows.iter()) {
        let _ = blocks.push(JacobianBlock::new(*c, 6, jac));
    }
    for ((c, _), jac) in delays.iter().zip(tds.iter()) {
        if let Some(c) = c {
            let _ = blocks.push(JacobianBlock::new(*c, 1, jac));
        }
    }
    ne.add_blocks(&[r.x, r.y], &blocks)
}

#[cfg(test)]
#[path = "visual_tests.rs"]
mod tests;

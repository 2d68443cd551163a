//! The least-squares problem of the sliding window: every factor, assembled into the normal
//! equations of a [`Layout`], or evaluated for its cost only.
//!
//! Factors: the marginalization prior (or, before the first marginalization, diagonal priors on
//! the first keyframe, its time delay and the extrinsic), IMU preintegration between consecutive
//! keyframes, the time-delay random walk, and one visual measurement per observation `j != s` of
//! every usable landmark: pose-only (PO-VINS) or inverse-depth with the depth eliminated by Schur
//! complement (LE-VINS-WO). Visual residuals go through a Huber kernel (IRLS weights; the cost
//! uses `rho`, so the LM gain ratio sees the robust cost).

use super::config::{EstimatorConfig, VisualMode};
use super::prior::{ext_minus, kf_minus, LinPoint, MargPrior};
use super::problem_lidar::add_inverse_depth_obs;
use super::window::{Block, Layout, Window, KF_DIM};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::factors::inverse_depth_visual::{InverseDepthVisualFactor, WindowRotations};
use crate::factors::pose_only_visual::{InJ, PoseOnlyAnchors};
use crate::factors::robust::Huber;
use crate::factors::td::TdRandomWalk;
use crate::factors::{CamFrame, KeyframePose, TimedObs};
use crate::inertial::preintegration::{Mat15, Vec15};
use crate::inertial::NavState;
use crate::landmarks::{KfObs, LandmarkManager, MargPlan};
use crate::lidar::LdmMode;
use crate::math::{jr_inv_so3, quat_exp, Mat3, Vec3};
use crate::solver::{JacobianBlock, LandmarkSchur, LmProblem, NormalEquations, SharedBlock};
use crate::Error;
use heapless::Vec as HVec;
use nalgebra::Matrix2x6;

/// Pose columns a landmark can touch in the inverse-depth mode (`7 N + 6` for a window of `N`).
pub const SCHUR_COLS: usize = 128;

/// Capacity of the landmark id index (power of two, at least `L`).
pub const LANDMARK_INDEX: usize = 512;

/// Landmark store of the estimator.
pub type Landmarks<const N: usize, const L: usize> =
    LandmarkManager<N, L, LANDMARK_INDEX, { super::MAX_FEATURES }>;

/// Diagonal priors used until the first marginalization.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialPriors {
    /// Linearization point of the first keyframe.
    pub kf0: NavState,
    /// Standard deviations `[p, theta, v, bg, ba]` (each for 3 axes).
    pub kf0_sigma: [f64; 5],
    /// First time delay and its standard deviation, s.
    pub td0: (f64, f64),
    /// Extrinsic prior mean and standard deviations (translation m, rotation rad).
    pub ext: (CameraExtrinsic, f64, f64),
}

/// Which factors to visit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FactorSet {
    /// All factors of the window (the solve).
    All,
    /// Only those the oldest keyframe's marginalization needs: priors, the IMU and delay factors
    /// from position 0 to 1, and the visual factors of landmarks anchored at 0.
    Oldest,
    /// What stays in the window of the re-anchored landmarks whose depth is eliminated (their
    /// factor without the observation at 0), to be taken back from [`FactorSet::Oldest`]'s
    /// system, which holds their whole factor: the difference is exactly the information the
    /// observation at 0 adds given the others (`estimator::marginalize`).
    OldestRest,
}

/// Counts of what one assembly visited.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AssemblyCounts {
    /// Landmarks that contributed.
    pub landmarks: u32,
    /// Visual residuals (2-row observations).
    pub observations: u32,
    /// Landmarks disabled because a residual was degenerate at linearization.
    pub disabled: u32,
    /// LiDAR-depth measurements (MSC blocks or direct depth rows).
    pub ldm: u32,
}

/// Saved copy of the optimized variables (for LM trial steps).
#[derive(Clone)]
pub struct Saved<const N: usize, const L: usize> {
    states: [(NavState, f64); N],
    ext: CameraExtrinsic,
    inv_depth: [f64; L],
    /// Eliminated landmarks' `tau*` of the last cost evaluation (where `tau_ok`).
    pub(super) tau: [f64; L],
    pub(super) tau_ok: [bool; L],
}

impl<const N: usize, const L: usize> Saved<N, L> {
    /// Zeroed (all bits: states and extrinsic are written before they are read); `const` so it
    /// can initialize a `static`.
    pub const fn new() -> Self {
        Saved {
            states: [(NavState::ZERO, 0.0); N],
            ext: CameraExtrinsic {
                p_bc: crate::math::VEC3_ZERO,
                q_bc: NavState::ZERO.q_wb,
            },
            inv_depth: [0.0; L],
            tau: [0.0; L],
            tau_ok: [false; L],
        }
    }

    /// Back to the state [`Saved::new`] builds, in place.
    pub fn reset_to_new(&mut self) {
        self.states.fill((NavState::ZERO, 0.0));
        self.ext = CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: NavState::ZERO.q_wb,
        };
        self.inv_depth.fill(0.0);
        self.tau.fill(0.0);
        self.tau_ok.fill(false);
    }
}

impl<const N: usize, const L: usize> Default for Saved<N, L> {
    fn default() -> Self {
        Self::new()
    }
}

/// Borrowed view of everything the window's least-squares problem touches.
pub struct Problem<'a, const N: usize, const L: usize, const D: usize> {
    /// Configuration.
    pub cfg: &'a EstimatorConfig,
    /// Keyframes.
    pub window: &'a mut Window<N>,
    /// Landmarks.
    pub lms: &'a mut Landmarks<N, L>,
    /// Camera-IMU extrinsic (a variable when estimated).
    pub ext: &'a mut CameraExtrinsic,
    /// Marginalization prior.
    pub prior: &'a mut MargPrior<D, N>,
    /// Initial priors, until the first marginalization.
    pub initial: Option<&'a InitialPriors>,
    /// Column map.
    pub layout: Layout<N>,
    /// Which factors.
    pub set: FactorSet,
    /// Per-landmark Schur accumulators (inverse-depth mode).
    pub schur: &'a mut [LandmarkSchur<SCHUR_COLS>],
    /// Trial-step backup.
    pub saved: &'a mut Saved<N, L>,
    /// Counts of the last assembly.
    pub counts: AssemblyCounts,
    /// Hold every keyframe's delay at these values (a tight factor): too few landmarks to
    /// estimate it ([`EstimatorConfig::td_min_landmarks`]).
    pub td_hold: Option<[f64; N]>,
    /// The state has not changed since the last successful cost evaluation: its eliminated
    /// landmarks' `tau*` (in [`Saved`]) are the ones a linearization would compute (same state,
    /// same start `inv_depth`), so it takes them instead of solving again.
    pub tau_fresh: bool,
}

/// Pose-only landmark with only body poses estimated: the geometry of every observation first
/// (a landmark enters the system whole or not at all: `None` when one is degenerate, nothing
/// added), then each residual with its robust weight through a [`SharedBlock`] on anchor `e`.
/// With `only_j`, only that observation's residual (the marginalization of a re-anchored
/// landmark). Returns the robust cost and the number of observations.
fn add_pose_only_landmark<const N: usize, const D: usize>(
    anchors: &PoseOnlyAnchors<'_>,
    obs: &[Option<KfObs>; N],
    count: usize,
    (s, e): (usize, usize),
    (poses, frames, huber, l, rel_js): (
        &[KeyframePose; N],
        &[CamFrame; N],
        &Huber,
        &Layout<N>,
        &impl Fn(usize) -> Option<(Mat3, Vec3)>,
    ),
    only_j: Option<usize>,
    ne: &mut NormalEquations<D>,
) -> Result<Option<(f64, u32)>, Error> {
    let mut geo: HVec<(usize, InJ<'_>), N> = HVec::new();
    for (j, oj) in obs.iter().enumerate().take(count) {
        let (Some(oj), Some(pj), Some(fj)) = (oj, poses.get(j), frames.get(j)) else {
            continue;
        };
        if j == s || only_j.is_some_and(|o| o != j) {
            continue;
        }
        let Some(rel) = rel_js(j) else {
            return Ok(None);
        };
        match anchors.geometry(j, &timed(oj), pj, fj, Some(rel)) {
            Ok(g) => {
                let _ = geo.push((j, g));
            }
            Err(_) => return Ok(None),
        }
    }
    let col = |k: usize| l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch);
    let td_col = |k: usize| l.col(Block::Td(k as u8));
    let (cs, ce) = (col(s)?, col(e)?);
    let shared_e = anchors.shared_e();
    let mut acc = SharedBlock::new(ne, shared_e, cs, ce)?;
    let mut cost = 0.0;
    for (j, g) in geo.iter() {
        let sq = anchors.whitened(g).norm_squared();
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let pb = anchors.pose_blocks(g, w);
        let cj = col(*j)?;
        if *j == e {
            let on_e = pb.q * shared_e + pb.d_pose_j;
            ne.add_2x6_blocks(&pb.r, &[pb.d_pose_s, on_e], &[cs, ce])?;
        } else {
            acc.add(ne, &pb.r, &pb.q, &pb.d_pose_s, &pb.d_pose_j, cj)?;
        }
        // Delay columns (after every pose column in the solve layout).
        let (Some(ts), Some(te), Some(Some(oj))) = (td_col(s), td_col(e), obs.get(*j)) else {
            continue;
        };
        let t = anchors.td_jacobians(g, w, &timed(oj));
        let mut poses: HVec<(usize, Matrix2x6<f64>), 3> = HVec::new();
        let _ = poses.push((cs, pb.d_pose_s));
        if *j == e {
            let _ = poses.push((ce, pb.q * shared_e + pb.d_pose_j));
        } else {
            let _ = poses.push((ce, pb.q * shared_e));
            let _ = poses.push((cj, pb.d_pose_j));
        }
        let tj = if *j == e { None } else { td_col(*j) };
        let tds = [(Some(ts), t[0]), (Some(te), t[1]), (tj, t[2])];
        ne.add_scalar_columns(&pb.r, &tds, &poses)?;
    }
    acc.finish(ne);
    Ok(Some((cost, geo.len() as u32)))
}

/// The anchors' depth uncertainty for [`PoseOnlyAnchors::with_depth_std`] (0 when the weighting
/// is off or the uncertainty is undefined).
pub(super) fn anchor_depth_std(cfg: &EstimatorConfig, anchors: &PoseOnlyAnchors<'_>) -> f64 {
    if !cfg.depth_uncertainty_weighting {
        return 0.0;
    }
    let focal = Vec2::new(cfg.camera.fx, cfg.camera.fy);
    crate::landmarks::depth_std(anchors.two_view(), cfg.sigma_px, &focal).unwrap_or(0.0)
}

fn timed(o: &KfObs) -> TimedObs {
    TimedObs {
        x_n: Vec2::new(o.x_n[0], o.x_n[1]),
        vel: Vec2::new(o.vel[0], o.vel[1]),
        td0: o.td0_s,
    }
}

/// Copies a column-major nalgebra matrix into a row-major slice.
pub(super) fn row_major<const R: usize, const C: usize>(
    m: &nalgebra::SMatrix<f64, R, C>,
    out: &mut [f64],
) {
    for (r, row) in out.chunks_mut(C).take(R).enumerate() {
        for (c, o) in row.iter_mut().enumerate() {
            *o = m[(r, c)];
        }
    }
}

/// Accumulates a residual or only its cost.
fn sink<const D: usize>(
    ne: &mut Option<&mut NormalEquations<D>>,
    r: &[f64],
    blocks: &[JacobianBlock<'_>],
) -> Result<f64, Error> {
    let c: f64 = r.iter().map(|x| x * x).sum();
    if !c.is_finite() {
        return Err(Error::NonFinite);
    }
    if let Some(ne) = ne.as_deref_mut() {
        ne.add_blocks(r, blocks)?;
    }
    Ok(c)
}

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    pub(super) fn sqrt_info(&self) -> Vec2 {
        Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy) / self.cfg.sigma_px
    }

    /// Visits the factors of `self.set`, adding them to `ne` (or only summing their cost).
    /// Returns the (robust) cost. With `ne`, landmarks whose residual is degenerate are disabled
    /// (`usable = false`); without, such a landmark makes the evaluation fail, so an LM trial
    /// step that breaks a landmark's geometry is rejected instead of shedding its cost.
    pub fn assemble(&mut self, mut ne: Option<&mut NormalEquations<D>>) -> Result<f64, Error> {
        self.counts = AssemblyCounts::default();
        let mut cost = 0.0;
        let l = self.layout;
        let count = self.window.len();
        let est_td = l.col(Block::Td(0)).is_some();
        let est_ext = l.col(Block::Ext).is_some();
        if self.set == FactorSet::OldestRest {
            cost += self.pose_only_visual(&mut ne, est_td, est_ext)?;
            if let Some(ne) = ne {
                ne.cost = cost;
            }
            return Ok(cost);
        }

        // Priors.
        if self.prior.dim() > 0 {
            let (window, ext) = (&*self.window, *self.ext);
            let current = |b: Block| match b {
                Block::Kf(k) => window.get(k as usize).map(|kf| LinPoint::Kf(kf.state)),
                Block::Td(k) => window.get(k as usize).map(|kf| LinPoint::Td(kf.td_s)),
                Block::Ext => Some(LinPoint::Ext(ext)),
            };
            cost += self.prior.add_to(&l, current, ne.as_deref_mut())?;
        }
        if let Some(ip) = self.initial {
            cost += self.initial_priors(ip, &mut ne, est_td, est_ext)?;
        }

        // IMU preintegration and delay random walk between consecutive keyframes.
        let last_pair = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        let g = self.cfg.gravity_mps2;
        let mut r = Vec15::zeros();
        let mut ji = Mat15::zeros();
        let mut jj = Mat15::zeros();
        for k in 1..last_pair {
            let (Some(a), Some(b)) = (self.window.get(k - 1), self.window.get(k)) else {
                return Err(Error::NotEnoughData);
            };
            let pre = b.preint().ok_or(Error::NotEnoughData)?;
            if ne.is_none() {
                r = pre.residual_whitened(&a.state, &b.state, g)?;
                cost += sink(&mut ne, r.as_slice(), &[])?;
                if est_td {
                    let dt = pre.dt_s().max(1e-3);
                    let q = self.cfg.td_rw_s_per_sqrt_s * self.cfg.td_rw_s_per_sqrt_s;
                    let (rt, _) = TdRandomWalk::new(q, dt)?.evaluate(a.td_s, b.td_s)?;
                    cost += sink(&mut ne, &[rt], &[])?;
                }
                continue;
            }
            pre.evaluate(&a.state, &b.state, g, &mut r, &mut ji, &mut jj)?;
            let (ca, cb) = (
                l.col(Block::Kf((k - 1) as u8))
                    .ok_or(Error::DimensionMismatch)?,
                l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch)?,
            );
            let c: f64 = r.norm_squared();
            if !c.is_finite() {
                return Err(Error::NonFinite);
            }
            if let Some(ne) = ne.as_deref_mut() {
                ne.add_dense_pair(&r, &ji, &jj, ca, cb)?;
            }
            cost += c;
            if est_td {
                let dt = pre.dt_s().max(1e-3);
                let q = self.cfg.td_rw_s_per_sqrt_s * self.cfg.td_rw_s_per_sqrt_s;
                let (rt, [da, db]) = TdRandomWalk::new(q, dt)?.evaluate(a.td_s, b.td_s)?;
                let (ta, tb) = (
                    l.col(Block::Td((k - 1) as u8))
                        .ok_or(Error::DimensionMismatch)?,
                    l.col(Block::Td(k as u8)).ok_or(Error::DimensionMismatch)?,
                );
                cost += sink(
                    &mut ne,
                    &[rt],
                    &[
                        JacobianBlock::new(ta, 1, &[da]),
                        JacobianBlock::new(tb, 1, &[db]),
                    ],
                )?;
            }
        }

        cost += self.zupt_factors(&mut ne)?;
        // Never in the marginalization: the hold is about this solve, not information.
        let hold = self
            .td_hold
            .filter(|_| est_td && self.set == FactorSet::All);
        if let Some(hold) = hold {
            // 1 us: the delay stays where it is while it cannot be estimated.
            const HOLD_S: f64 = 1e-6;
            for k in 0..count {
                let (Some(kf), Some(t0)) = (self.window.get(k), hold.get(k)) else {
                    continue;
                };
                let c = l.col(Block::Td(k as u8)).ok_or(Error::DimensionMismatch)?;
                let r = (kf.td_s - t0) / HOLD_S;
                cost += sink(&mut ne, &[r], &[JacobianBlock::new(c, 1, &[1.0 / HOLD_S])])?;
            }
        }

        if self.set == FactorSet::Oldest && !self.cfg.marginalize_visual {
            if let Some(ne) = ne {
                ne.cost = cost;
            }
            return Ok(cost);
        }
        cost += match (self.cfg.mode, self.set) {
            (VisualMode::PoseOnly, _) => self.pose_only_visual(&mut ne, est_td, est_ext)?,
            (VisualMode::InverseDepth, FactorSet::All) => {
                self.inverse_depth_visual(&mut ne, est_td, est_ext)?
            }
            // Re-anchored landmarks leave their observation at 0 as a pose-only residual (the
            // pose-only form is the inverse-depth one with the depth eliminated by the anchors);
            // the others leave whole, their depth eliminated with them.
            (VisualMode::InverseDepth, FactorSet::Oldest | FactorSet::OldestRest) => {
                self.pose_only_visual(&mut ne, est_td, est_ext)?
                    + self.inverse_depth_visual(&mut ne, est_td, est_ext)?
            }
        };
        if let Some(ne) = ne {
            // The normal equations summed IRLS-weighted squares; the LM compares robust costs.
            ne.cost = cost;
        }
        Ok(cost)
    }

    /// Zero-velocity updates (keyframes the images show at rest): `v_k / sigma_v` on every such
    /// keyframe and, with the previous one, `(p_k - p_{k-1}) / sigma_p` and
    /// `Log(R_{k-1}^T R_k) / sigma_theta`. Right perturbations: with `e = Log(R_a^T R_b)`,
    /// `de/dtheta_b = Jr^-1(e)` and `de/dtheta_a = -Jr^-1(e) R_b^T R_a`.
    fn zupt_factors(&self, ne: &mut Option<&mut NormalEquations<D>>) -> Result<f64, Error> {
        let l = &self.layout;
        let count = self.window.len();
        let last = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        let sv = self.cfg.zupt_sigma_mps;
        let (sp, sr) = self.cfg.zupt_motion_sigma;
        let diag = |s: f64| {
            let mut m = [0.0; 9];
            for i in 0..3 {
                if let Some(x) = m.get_mut(i * 4) {
                    *x = 1.0 / s;
                }
            }
            m
        };
        let mut cost = 0.0;
        for k in 0..last {
            let kf = self.window.get(k).ok_or(Error::NotEnoughData)?;
            if !kf.at_rest {
                continue;
            }
            let c = l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch)?;
            // The marginalization takes only what involves keyframe 0.
            if self.set == FactorSet::All || k == 0 {
                let r: [f64; 3] = core::array::from_fn(|i| kf.state.v_wb[i] / sv);
                cost += sink(ne, &r, &[JacobianBlock::new(c + 6, 3, &diag(sv))])?;
            }
            let Some(prev) = k.checked_sub(1).and_then(|p| self.window.get(p)) else {
                continue;
            };
            let cp = l
                .col(Block::Kf((k - 1) as u8))
                .ok_or(Error::DimensionMismatch)?;
            let dp = kf.state.p_wb - prev.state.p_wb;
            let r: [f64; 3] = core::array::from_fn(|i| dp[i] / sp);
            let jp = diag(sp);
            let jm = diag(-sp);
            cost += sink(
                ne,
                &r,
                &[
                    JacobianBlock::new(cp, 3, &jm),
                    JacobianBlock::new(c, 3, &jp),
                ],
            )?;
            let (ra, rb) = (
                prev.state.q_wb.to_rotation_matrix().into_inner(),
                kf.state.q_wb.to_rotation_matrix().into_inner(),
            );
            let e = crate::math::log_so3(&(prev.state.q_wb.inverse() * kf.state.q_wb));
            let jr = jr_inv_so3(&e) / sr;
            let ja = -(jr * rb.transpose() * ra);
            let r: [f64; 3] = core::array::from_fn(|i| e[i] / sr);
            let (mut a, mut b) = ([0.0; 9], [0.0; 9]);
            row_major(&ja, &mut a);
            row_major(&jr, &mut b);
            cost += sink(
                ne,
                &r,
                &[
                    JacobianBlock::new(cp + 3, 3, &a),
                    JacobianBlock::new(c + 3, 3, &b),
                ],
            )?;
        }
        Ok(cost)
    }

    fn initial_priors(
        &self,
        ip: &InitialPriors,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        est_ext: bool,
    ) -> Result<f64, Error> {
        let l = &self.layout;
        let mut cost = 0.0;
        let kf0 = self.window.get(0).ok_or(Error::NotEnoughData)?;
        let mut e = [0.0; KF_DIM];
        kf_minus(&kf0.state, &ip.kf0, &mut e);
        let th = Vec3::new(e[3], e[4], e[5]);
        let jr = jr_inv_so3(&th);
        let mut jac = [0.0; KF_DIM * KF_DIM];
        for i in 0..KF_DIM {
            let s = ip.kf0_sigma.get(i / 3).copied().unwrap_or(1.0);
            if let Some(x) = e.get_mut(i) {
                *x /= s;
            }
            if (3..6).contains(&i) {
                for c in 3..6 {
                    if let Some(x) = jac.get_mut(i * KF_DIM + c) {
                        *x = jr[(i - 3, c - 3)] / s;
                    }
                }
            } else if let Some(x) = jac.get_mut(i * KF_DIM + i) {
                *x = 1.0 / s;
            }
        }
        let c0 = l.col(Block::Kf(0)).ok_or(Error::DimensionMismatch)?;
        cost += sink(ne, &e, &[JacobianBlock::new(c0, KF_DIM, &jac)])?;
        if est_td {
            let r = (kf0.td_s - ip.td0.0) / ip.td0.1;
            let c = l.col(Block::Td(0)).ok_or(Error::DimensionMismatch)?;
            cost += sink(ne, &[r], &[JacobianBlock::new(c, 1, &[1.0 / ip.td0.1])])?;
        }
        if est_ext {
            let (x0, st, sr) = ip.ext;
            let mut e6 = [0.0; 6];
            ext_minus(self.ext, &x0, &mut e6);
            let jr = jr_inv_so3(&Vec3::new(e6[3], e6[4], e6[5]));
            let mut j6 = [0.0; 36];
            for i in 0..6 {
                let s = if i < 3 { st } else { sr };
                if let Some(x) = e6.get_mut(i) {
                    *x /= s;
                }
                if i < 3 {
                    if let Some(x) = j6.get_mut(i * 6 + i) {
                        *x = 1.0 / s;
                    }
                } else {
                    for c in 3..6 {
                        if let Some(x) = j6.get_mut(i * 6 + c) {
                            *x = jr[(i - 3, c - 3)] / s;
                        }
                    }
                }
            }
            let c = l.col(Block::Ext).ok_or(Error::DimensionMismatch)?;
            cost += sink(ne, &e6, &[JacobianBlock::new(c, 6, &j6)])?;
        }
        Ok(cost)
    }

    fn pose_only_visual(
        &mut self,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        est_ext: bool,
    ) -> Result<f64, Error> {
        let huber = Huber::new(self.cfg.huber_delta)?;
        let sqrt_info = self.sqrt_info();
        let l = self.layout;
        let count = self.window.len();
        let ext = *self.ext;
        let poses = self.window.poses();
        // Camera frames once per keyframe rather than three times per residual.
        let frames: [CamFrame; N] = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        // Relative poses `(R_js, t_js)` once per keyframe pair rather than per observation,
        // formed on first use (landmarks whose depth is eliminated do not need them).
        let mut rel_cache: Option<[[(Mat3, Vec3); N]; N]> = None;
        let relative_poses = || -> [[(Mat3, Vec3); N]; N] {
            core::array::from_fn(|j| {
                core::array::from_fn(|s| match (frames.get(j), frames.get(s)) {
                    (Some(fj), Some(fs)) if j < count && s < count => fj.relative_from(fs),
                    _ => (Mat3::identity(), Vec3::zeros()),
                })
            })
        };
        let mut cost = 0.0;
        let linearize = ne.is_some();
        // The eliminated landmarks' linearization: rotations once per assembly, not per residual.
        let rot = (linearize && !est_ext && self.cfg.depth_eliminated())
            .then(|| WindowRotations::new(&poses, count, &ext));
        // Extrinsic not estimated: the landmark's products on anchor e go through the rank
        // structure (`add_pose_only_landmark`), the delays as scalar columns.
        let fast = linearize && !est_ext;
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if !lm.usable {
                continue;
            }
            // Marginalization: the landmarks the plan involves (in the inverse-depth mode only
            // the re-anchored ones: the others leave with their depth in `inverse_depth_visual`).
            let only_j = match (self.set, lm.marg, self.cfg.mode) {
                (FactorSet::All, _, _) => None,
                // The whole factor, less what stays (`FactorSet::OldestRest`).
                (
                    FactorSet::Oldest | FactorSet::OldestRest,
                    MargPlan::ObsZero,
                    VisualMode::PoseOnly,
                ) if self.cfg.depth_eliminated() => None,
                (FactorSet::Oldest, MargPlan::ObsZero, _) => Some(0),
                (FactorSet::Oldest, MargPlan::Whole | MargPlan::Reuse, VisualMode::PoseOnly) => {
                    None
                }
                _ => continue,
            };
            let lidar = lm.lidar.is_some() && self.cfg.lidar.enabled;
            if lidar && self.cfg.lidar.ldm == LdmMode::Msc {
                match self.msc_landmark(li, ne, &poses, &frames, &ext, &huber, est_td, est_ext) {
                    Ok((c, n)) => {
                        cost += c;
                        self.counts.landmarks += 1;
                        self.counts.observations += n;
                        self.counts.ldm += 1;
                    }
                    Err(_) if linearize => {
                        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                            lm.usable = false;
                        }
                        self.counts.disabled += 1;
                    }
                    Err(_) => return Err(Error::Degenerate),
                }
                continue;
            }
            if self.cfg.depth_eliminated() && only_j.is_none() {
                let er = (&ext, rot.as_ref());
                match self.eliminated_landmark(li, ne, &poses, &frames, er, &huber, est_td, est_ext)
                {
                    Ok((c, n)) => {
                        cost += c;
                        self.counts.landmarks += 1;
                        self.counts.observations += n;
                    }
                    Err(_) if linearize => {
                        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                            lm.usable = false;
                        }
                        self.counts.disabled += 1;
                    }
                    Err(_) => return Err(Error::Degenerate),
                }
                continue;
            }
            let (s, Some(e)) = (lm.anchor_s as usize, lm.anchor_e.map(usize::from)) else {
                continue;
            };
            let (Some(Some(os)), Some(Some(oe))) = (lm.obs.get(s), lm.obs.get(e)) else {
                continue;
            };
            let (Some(ps), Some(pe)) = (poses.get(s), poses.get(e)) else {
                continue;
            };
            let (Some(fs), Some(fe)) = (frames.get(s), frames.get(e)) else {
                continue;
            };
            let mut lm_cost = 0.0;
            let mut n_obs = 0;
            let mut failed = false;
            // Evaluate every observation first: a landmark enters the system whole or not at all.
            let mut jacs: HVec<(usize, crate::factors::pose_only_visual::PoseOnlyJacobians), N> =
                HVec::new();
            let rel = &*rel_cache.get_or_insert_with(relative_poses);
            let rel_js = |j: usize| rel.get(j).and_then(|row| row.get(s)).copied();
            let Some(rel_es) = rel_js(e) else {
                continue;
            };
            match PoseOnlyAnchors::new(
                (s, e),
                timed(os),
                timed(oe),
                sqrt_info,
                (ps, pe),
                (fs, fe),
                &ext,
                Some(rel_es),
            )
            .map(|a| {
                let sd = anchor_depth_std(self.cfg, &a);
                a.with_depth_std(sd)
            }) {
                Err(_) => failed = true,
                Ok(anchors) if fast => {
                    if let Some(ne_ref) = ne.as_deref_mut() {
                        let ctx = (&poses, &frames, &huber, &l, &rel_js);
                        let obs = &lm.obs;
                        match add_pose_only_landmark(
                            &anchors,
                            obs,
                            count,
                            (s, e),
                            ctx,
                            only_j,
                            ne_ref,
                        )? {
                            Some((c, n)) => {
                                lm_cost = c;
                                n_obs = n;
                            }
                            None => failed = true,
                        }
                    }
                }
                Ok(anchors) => {
                    for (j, oj) in lm.obs.iter().enumerate().take(count) {
                        let (Some(oj), Some(pj), Some(fj)) = (oj, poses.get(j), frames.get(j))
                        else {
                            continue;
                        };
                        if j == s || only_j.is_some_and(|o| o != j) {
                            continue;
                        }
                        let obs_j = timed(oj);
                        if linearize {
                            match anchors.evaluate(j, &obs_j, pj, fj) {
                                Ok(jac) => {
                                    let _ = jacs.push((j, jac));
                                }
                                Err(_) => failed = true,
                            }
                        } else {
                            let g = match rel_js(j) {
                                Some(rel) => anchors.geometry(j, &obs_j, pj, fj, Some(rel)),
                                None => Err(Error::DimensionMismatch),
                            };
                            match g.map(|g| anchors.whitened(&g)) {
                                Ok(r) => {
                                    lm_cost += huber.rho(r.norm_squared())[0];
                                    n_obs += 1;
                                }
                                Err(_) => failed = true,
                            }
                        }
                    }
                }
            }
            if let (false, false, Some(ne_ref)) = (failed, fast, ne.as_deref_mut()) {
                for (j, jac) in jacs.iter() {
                    let j = *j;
                    let sq = jac.r.norm_squared();
                    let w = huber.sqrt_weight(sq);
                    lm_cost += huber.rho(sq)[0];
                    n_obs += 1;
                    let r = [jac.r.x * w, jac.r.y * w];
                    let (mut a, mut b, mut c, mut x) = ([0.0; 12], [0.0; 12], [0.0; 12], [0.0; 12]);
                    row_major(&(jac.d_pose_s * w), &mut a);
                    row_major(&(jac.d_pose_e * w), &mut b);
                    row_major(&(jac.d_pose_j * w), &mut c);
                    row_major(&(jac.d_ext * w), &mut x);
                    let td = [jac.d_td[0] * w, jac.d_td[1] * w, jac.d_td[2] * w];
                    let tds = [[td[0].x, td[0].y], [td[1].x, td[1].y], [td[2].x, td[2].y]];
                    let mut blocks: HVec<JacobianBlock<'_>, 8> = HVec::new();
                    let col = |b: Block| l.col(b).ok_or(Error::DimensionMismatch);
                    let _ = blocks.push(JacobianBlock::new(col(Block::Kf(s as u8))?, 6, &a));
                    let _ = blocks.push(JacobianBlock::new(col(Block::Kf(e as u8))?, 6, &b));
                    if j != e {
                        let _ = blocks.push(JacobianBlock::new(col(Block::Kf(j as u8))?, 6, &c));
                    }
                    if est_ext {
                        let _ = blocks.push(JacobianBlock::new(col(Block::Ext)?, 6, &x));
                    }
                    if est_td {
                        let _ =
                            blocks.push(JacobianBlock::new(col(Block::Td(s as u8))?, 1, &tds[0]));
                        let _ =
                            blocks.push(JacobianBlock::new(col(Block::Td(e as u8))?, 1, &tds[1]));
                        if j != e {
                            let _ = blocks.push(JacobianBlock::new(
                                col(Block::Td(j as u8))?,
                                1,
                                &tds[2],
                            ));
                        }
                    }
                    ne_ref.add_blocks(&r, &blocks)?;
                }
            }
            if failed {
                if linearize {
                    if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                        lm.usable = false;
                    }
                    self.counts.disabled += 1;
                } else {
                    return Err(Error::Degenerate);
                }
            }
            if lidar && !failed {
                // Direct LDM beside the visual measurements; a degenerate depth geometry only
                // drops the depth measurement (the visual ones were fine).
                match self.direct_depth(li, ne, &poses, &ext, &huber, est_td, est_ext) {
                    Ok(c) => {
                        lm_cost += c;
                        self.counts.ldm += 1;
                    }
                    Err(_) if linearize => {}
                    Err(_) => return Err(Error::Degenerate),
                }
            }
            if n_obs > 0 {
                self.counts.landmarks += 1;
                self.counts.observations += n_obs;
            }
            cost += lm_cost;
        }
        Ok(cost)
    }

    fn inverse_depth_visual(
        &mut self,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        est_ext: bool,
    ) -> Result<f64, Error> {
        let huber = Huber::new(self.cfg.huber_delta)?;
        let sqrt_info = self.sqrt_info();
        let l = self.layout;
        let count = self.window.len();
        let ext = *self.ext;
        let poses = self.window.poses();
        let mut cost = 0.0;
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if let Some(sc) = self.schur.get_mut(li) {
                sc.clear();
            }
            if !lm.usable || lm.inv_depth <= 0.0 {
                continue;
            }
            let s = lm.anchor_s as usize;
            if self.set == FactorSet::Oldest
                && !matches!(lm.marg, MargPlan::Whole | MargPlan::Reuse)
            {
                continue;
            }
            let (Some(Some(os)), Some(ps)) = (lm.obs.get(s), poses.get(s)) else {
                continue;
            };
            let obs_s = timed(os);
            let tau = lm.inv_depth;
            let mut lm_cost = 0.0;
            let mut n_obs = 0;
            let mut failed = false;
            let mut jacs: HVec<
                (
                    usize,
                    crate::factors::inverse_depth_visual::InverseDepthJacobians,
                ),
                N,
            > = HVec::new();
            for (j, oj) in lm.obs.iter().enumerate().take(count) {
                let (Some(oj), Some(pj)) = (oj, poses.get(j)) else {
                    continue;
                };
                if j == s {
                    continue;
                }
                let f = InverseDepthVisualFactor {
                    kf_s: s,
                    kf_j: j,
                    obs_s,
                    obs_j: timed(oj),
                    sqrt_info,
                };
                if ne.is_some() {
                    match f.evaluate(ps, pj, &ext, tau) {
                        Ok(jac) => {
                            let _ = jacs.push((j, jac));
                        }
                        Err(_) => failed = true,
                    }
                } else {
                    match f.residual(ps, pj, &ext, tau) {
                        Ok(r) => {
                            lm_cost += huber.rho(r.norm_squared())[0];
                            n_obs += 1;
                        }
                        Err(_) => failed = true,
                    }
                }
            }
            if let (false, Some(ne_ref)) = (failed, ne.as_deref_mut()) {
                for (j, jac) in jacs.iter() {
                    let j = *j;
                    let sq = jac.r.norm_squared();
                    let w = huber.sqrt_weight(sq);
                    lm_cost += huber.rho(sq)[0];
                    n_obs += 1;
                    let sc = self.schur.get_mut(li).ok_or(Error::CapacityExceeded)?;
                    add_inverse_depth_obs(sc, ne_ref, jac, w, s, j, &l, est_td, est_ext)?;
                }
            }
            if failed {
                if ne.is_some() {
                    if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                        lm.usable = false;
                    }
                    self.counts.disabled += 1;
                } else {
                    return Err(Error::Degenerate);
                }
            }
            // LE-VINS: a LiDAR depth is a prior on the landmark's own inverse depth.
            let depth = self
                .lms
                .landmarks()
                .get(li)
                .and_then(|lm| lm.lidar)
                .filter(|_| self.cfg.lidar.enabled);
            if let (false, Some(d)) = (failed, depth) {
                let rd = (1.0 / tau - d.depth_m) / d.sigma_m;
                let jd = -1.0 / (tau * tau * d.sigma_m);
                lm_cost += huber.rho(rd * rd)[0];
                self.counts.ldm += 1;
                if let (Some(ne_ref), Some(sc)) = (ne.as_deref_mut(), self.schur.get_mut(li)) {
                    let w = huber.sqrt_weight(rd * rd);
                    sc.add_residual(ne_ref, &[rd * w], &[], &[jd * w])?;
                }
            }
            if let (false, Some(ne_ref), Some(sc)) = (failed, ne.as_deref_mut(), self.schur.get(li))
            {
                sc.fold_into(ne_ref, 0.0)?;
            }
            if n_obs > 0 {
                self.counts.landmarks += 1;
                self.counts.observations += n_obs;
            }
            cost += lm_cost;
        }
        Ok(cost)
    }
}

impl<const N: usize, const L: usize, const D: usize> LmProblem<D> for Problem<'_, N, L, D> {
    fn dim(&self) -> usize {
        self.layout.dim()
    }

    fn linearize(&mut self, ne: &mut NormalEquations<D>) -> Result<(), Error> {
        let res = self.assemble(Some(ne)).map(|_| ());
        self.tau_fresh = false;
        res
    }

    fn cost(&mut self) -> Result<f64, Error> {
        self.tau_fresh = false;
        self.saved.tau_ok = [false; L];
        let cost = self.assemble(None);
        self.tau_fresh = cost.is_ok();
        cost
    }

    fn apply(&mut self, dx: &[f64]) {
        self.tau_fresh = false;
        let l = self.layout;
        let get3 = |c: usize| -> Vec3 {
            Vec3::new(
                dx.get(c).copied().unwrap_or(0.0),
                dx.get(c + 1).copied().unwrap_or(0.0),
                dx.get(c + 2).copied().unwrap_or(0.0),
            )
        };
        for k in 0..self.window.len() {
            let Some(c) = l.col(Block::Kf(k as u8)) else {
                continue;
            };
            let tdc = l.col(Block::Td(k as u8));
            if let Some(kf) = self.window.get_mut(k) {
                let s = &mut kf.state;
                s.p_wb += get3(c);
                s.q_wb *= quat_exp(&get3(c + 3));
                s.v_wb += get3(c + 6);
                s.bg += get3(c + 9);
                s.ba += get3(c + 12);
                if let Some(t) = tdc {
                    kf.td_s += dx.get(t).copied().unwrap_or(0.0);
                }
            }
        }
        if let Some(c) = l.col(Block::Ext) {
            self.ext.p_bc += get3(c);
            self.ext.q_bc *= quat_exp(&get3(c + 3));
        }
        if self.cfg.mode == VisualMode::InverseDepth {
            for (lm, sc) in self.lms.landmarks_mut().iter_mut().zip(self.schur.iter()) {
                if lm.usable && lm.inv_depth > 0.0 {
                    if let Ok(dt) = sc.back_substitute(dx, 0.0) {
                        // A depth may not cross the camera plane in one step.
                        lm.inv_depth = (lm.inv_depth + dt).max(0.1 * lm.inv_depth);
                    }
                }
            }
        }
    }

    fn save(&mut self) {
        for k in 0..self.window.len() {
            if let (Some(kf), Some(slot)) = (self.window.get(k), self.saved.states.get_mut(k)) {
                *slot = (kf.state, kf.td_s);
            }
        }
        self.saved.ext = *self.ext;
        for (lm, s) in self
            .lms
            .landmarks()
            .iter()
            .zip(self.saved.inv_depth.iter_mut())
        {
            *s = lm.inv_depth;
        }
    }

    fn restore(&mut self) {
        self.tau_fresh = false;
        for k in 0..self.window.len() {
            if let (Some(kf), Some(slot)) = (self.window.get_mut(k), self.saved.states.get(k)) {
                kf.state = slot.0;
                kf.td_s = slot.1;
            }
        }
        *self.ext = self.saved.ext;
        for (lm, s) in self
            .lms
            .landmarks_mut()
            .iter_mut()
            .zip(self.saved.inv_depth.iter())
        {
            lm.inv_depth = *s;
        }
    }
}

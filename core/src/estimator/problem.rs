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
use super::window::{Block, Layout, Window, KF_DIM};
use crate::camera::{CameraExtrinsic, Vec2};
use crate::factors::pose_only_visual::PoseOnlyAnchors;
use crate::factors::TimedObs;
use crate::inertial::NavState;
use crate::landmarks::{KfObs, Landmark, LandmarkManager};
use crate::lidar::LdmMode;
use crate::math::{jr_inv_so3, quat_exp, Vec3};
use crate::solver::{JacobianBlock, LandmarkSchur, LmProblem, NormalEquations};
use crate::Error;

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

/// How a landmark's observations enter the window's problem. The one choice of a landmark's
/// measurement model: the assembly ([`Problem::assemble`]) linearizes the landmark under it and
/// the culling (`estimator::cull`) evaluates its residuals under it, so a landmark is never
/// culled under a model it was not solved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LandmarkModel {
    /// The paper's pose-only reprojections with the depth from the anchors `(s, e)`, exact in
    /// every residual ([`VisualDepth::TwoView`](super::VisualDepth::TwoView)).
    TwoView,
    /// [`LandmarkModel::TwoView`] with the direct LiDAR-depth measurement beside it (a LiDAR
    /// landmark with [`LdmMode::Direct`]).
    DirectLidar,
    /// Pose-only reprojections with the inverse depth that fits all observations eliminated
    /// ([`VisualDepth::Eliminated`](super::VisualDepth::Eliminated), `estimator::problem_visual`).
    Eliminated,
    /// The MSC-based LiDAR-depth measurement (a LiDAR landmark with [`LdmMode::Msc`],
    /// `estimator::problem_lidar`).
    MscLidar,
    /// The inverse depth as a state, eliminated by its Schur accumulator
    /// ([`VisualMode::InverseDepth`], `estimator::problem_inverse_depth`).
    InverseDepth,
}

impl LandmarkModel {
    /// The model of landmark `lm` under `cfg`: the inverse-depth mode takes every landmark as a
    /// state; otherwise a LiDAR landmark (with the LiDAR enabled) takes the configured LiDAR-depth
    /// measurement, and a visual one the configured pose-only depth (the direct LDM keeps the
    /// two-view form for all, see [`EstimatorConfig::depth_eliminated`]).
    pub fn of<const N: usize>(cfg: &EstimatorConfig, lm: &Landmark<N>) -> Self {
        if cfg.mode == VisualMode::InverseDepth {
            return LandmarkModel::InverseDepth;
        }
        let lidar = lm.lidar.is_some() && cfg.lidar.enabled;
        match (lidar, cfg.lidar.ldm) {
            (true, LdmMode::Msc) => LandmarkModel::MscLidar,
            (true, LdmMode::Direct) => LandmarkModel::DirectLidar,
            (false, _) if cfg.depth_eliminated() => LandmarkModel::Eliminated,
            (false, _) => LandmarkModel::TwoView,
        }
    }

    /// Whether the landmark's reprojections are the inverse-depth rays of its anchor `s` at the
    /// landmark's inverse depth (else the two-view form on its anchors `(s, e)`).
    pub fn uses_inverse_depth(self) -> bool {
        matches!(
            self,
            LandmarkModel::Eliminated | LandmarkModel::MscLidar | LandmarkModel::InverseDepth
        )
    }
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

/// The anchors' depth uncertainty for [`PoseOnlyAnchors::with_depth_std`] (0 when the weighting
/// is off or the uncertainty is undefined).
pub(super) fn anchor_depth_std(cfg: &EstimatorConfig, anchors: &PoseOnlyAnchors<'_>) -> f64 {
    if !cfg.depth_uncertainty_weighting {
        return 0.0;
    }
    let focal = Vec2::new(cfg.camera.fx, cfg.camera.fy);
    crate::landmarks::depth_std(anchors.two_view(), cfg.sigma_px, &focal).unwrap_or(0.0)
}

pub(super) fn timed(o: &KfObs) -> TimedObs {
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
pub(super) fn sink<const D: usize>(
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

        self.imu_factors(&mut ne, est_td, &mut cost)?;
        cost += self.zupt_factors(&mut ne)?;
        self.td_hold_factors(&mut ne, est_td, &mut cost)?;

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

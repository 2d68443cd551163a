//! The least-squares problem of the sliding window: every factor, assembled into the normal
//! equations of a [`Layout`], or evaluated for its cost only.
//!
//! Every factor is a [`WindowFactor`] (`factor`: its cost, its linearization into the
//! caller's normal equations, its residual rows). [`Problem::assemble`] visits the marginalization
//! prior (or, before the first marginalization, the diagonal priors on the first keyframe, its
//! time delay and the extrinsic: `priors`), IMU preintegration and the time-delay random
//! walk between consecutive keyframes, the zero-velocity updates and the delay hold
//! (`inertial`), then every usable landmark as the factor of its [`LandmarkModel`]
//! (`landmarks`): two-view pose-only (PO-VINS, `pose_only`), pose-only with the
//! depth eliminated (`visual`), MSC or direct LiDAR depth (`lidar`), or
//! inverse-depth with the depth eliminated by Schur complement (LE-VINS-WO,
//! `inverse_depth`). Visual residuals go through a Huber kernel (IRLS weights; the cost
//! uses `rho`, so the LM gain ratio sees the robust cost).
#![deny(clippy::too_many_lines)]

use super::config::{EstimatorConfig, VisualMode};
use super::prior::MargPrior;
use super::window::{Block, Layout, Window};
use crate::camera::CameraExtrinsic;
use crate::factors::inverse_depth_visual::WindowRotations;
use crate::inertial::NavState;
use crate::landmarks::LandmarkManager;
use crate::math::{quat_exp, Vec3};
use crate::solver::{LandmarkSchur, LmProblem, NormalEquations};
use crate::Error;
use landmarks::{LandmarkPass, Pass};

pub(super) mod factor;
mod inertial;
mod inverse_depth;
mod landmarks;
mod lidar;
mod pose_only;
mod priors;
mod visual;

pub use factor::{LandmarkFactor, LandmarkModel, VisualSettings, WindowFactor, WindowVars};
pub use inertial::{
    ImuFactor, TdHold, TdRandomWalkFactor, ZuptPosition, ZuptRotation, ZuptVelocity,
};
pub use inverse_depth::InverseDepthLandmark;
pub use lidar::{DirectDepth, DirectLidarLandmark, MscLandmark};
pub use pose_only::TwoViewLandmark;
pub use priors::{ExtPrior, FirstStatePrior, MargPriorFactor, TdPrior};
pub use visual::EliminatedLandmark;

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
    /// The landmarks' work ([`factor::LandmarkFactor::work`]).
    pub work: u32,
}

/// Saved copy of the optimized variables (for LM trial steps).
#[derive(Clone)]
pub struct Saved<const N: usize, const L: usize> {
    states: [(NavState, f64); N],
    ext: CameraExtrinsic,
    inv_depth: [(f64, [f64; 2]); L],
    /// Eliminated landmarks' `tau*` of the last cost evaluation (where `tau_ok`).
    pub(super) tau: [f64; L],
    /// ... and their anchor bearing corrections `delta*`.
    pub(super) delta: [[f64; 2]; L],
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
            inv_depth: [(0.0, [0.0; 2]); L],
            tau: [0.0; L],
            delta: [[0.0; 2]; L],
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
        self.inv_depth.fill((0.0, [0.0; 2]));
        self.tau.fill(0.0);
        self.delta.fill([0.0; 2]);
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
    /// The landmarks' work over every assembly so far ([`crate::solver::LmProblem::work`]).
    pub work: u32,
    /// Hold every keyframe's delay at these values (a tight factor): too little information to
    /// estimate it ([`super::TdConfig::min_info_per_s2`]).
    pub td_hold: Option<[f64; N]>,
    /// The state has not changed since the last successful cost evaluation: its eliminated
    /// landmarks' `tau*` (in [`Saved`]) are the ones a linearization would compute (same state,
    /// same start `inv_depth`), so it takes them instead of solving again.
    pub tau_fresh: bool,
}

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    /// Visits the factors of `self.set`, adding them to `ne` (or only summing their cost).
    /// Returns the (robust) cost. With `ne`, landmarks whose residual is degenerate are disabled
    /// (`usable = false`); without, such a landmark makes the evaluation fail, so an LM trial
    /// step that breaks a landmark's geometry is rejected instead of shedding its cost.
    pub fn assemble(&mut self, mut ne: Option<&mut NormalEquations<D>>) -> Result<f64, Error> {
        self.counts = AssemblyCounts::default();
        let mut cost = 0.0;
        // The eliminated depths' linearization with the extrinsic fixed: the window's rotations
        // once per assembly, not per residual.
        let l = self.layout;
        let rot = (ne.is_some() && l.col(Block::Ext).is_none() && self.cfg.depth_eliminated())
            .then(|| WindowRotations::new(&self.window.poses(), self.window.len(), &*self.ext));
        let v = WindowVars::new(&*self.window, &*self.ext, l, rot.as_ref());
        // The landmark passes: the marginalization in the inverse-depth mode takes the
        // re-anchored landmarks' observations at 0 as pose-only residuals (the pose-only form is
        // the inverse-depth one with the depth eliminated by the anchors); the others leave
        // whole, their depth eliminated with them.
        let passes: &[Pass] = match (self.cfg.mode, self.set) {
            (VisualMode::PoseOnly, _) | (VisualMode::InverseDepth, FactorSet::OldestRest) => {
                &[Pass::PoseOnly]
            }
            (VisualMode::InverseDepth, FactorSet::All) => &[Pass::InverseDepth],
            (VisualMode::InverseDepth, FactorSet::Oldest) => &[Pass::PoseOnly, Pass::InverseDepth],
        };
        let mut visual = true;
        if self.set != FactorSet::OldestRest {
            if self.prior.dim() > 0 {
                let mut prior = MargPriorFactor {
                    prior: &mut *self.prior,
                };
                cost += prior.add(&v, ne.as_deref_mut())?;
            }
            if let Some(ip) = self.initial {
                cost += initial_priors(ip, &v, &mut ne)?;
            }
            self.imu_factors(&v, &mut ne, &mut cost)?;
            cost += self.zupt_factors(&v, &mut ne)?;
            self.td_hold_factors(&v, &mut ne, &mut cost)?;
            visual = self.set != FactorSet::Oldest || self.cfg.marginalize_visual;
        }
        if visual {
            let mut lp = LandmarkPass {
                cfg: self.cfg,
                set: self.set,
                lms: &mut *self.lms,
                schur: &mut *self.schur,
                saved: &mut *self.saved,
                counts: &mut self.counts,
                tau_fresh: self.tau_fresh,
            };
            cost += match passes {
                [a, b] => lp.run(&v, &mut ne, *a)? + lp.run(&v, &mut ne, *b)?,
                [a] => lp.run(&v, &mut ne, *a)?,
                _ => 0.0,
            };
        }
        if let Some(ne) = ne {
            // The normal equations summed IRLS-weighted squares; the LM compares robust costs.
            ne.cost = cost;
        }
        self.work = self.work.saturating_add(self.counts.work);
        Ok(cost)
    }
}

/// The diagonal priors used until the first marginalization: the first keyframe's state, and
/// its delay and the extrinsic where they are estimated. Returns their cost.
fn initial_priors<const N: usize, const D: usize>(
    ip: &InitialPriors,
    v: &WindowVars<'_, N>,
    ne: &mut Option<&mut NormalEquations<D>>,
) -> Result<f64, Error> {
    let mut cost = 0.0;
    let mut kf0 = FirstStatePrior {
        kf0: ip.kf0,
        sigma: ip.kf0_sigma,
    };
    cost += kf0.add(v, ne.as_deref_mut())?;
    if v.est_td {
        let (td0_s, sigma_s) = ip.td0;
        cost += TdPrior { td0_s, sigma_s }.add(v, ne.as_deref_mut())?;
    }
    if v.est_ext {
        let (ext0, sigma_p_m, sigma_theta_rad) = ip.ext;
        let mut ext = ExtPrior {
            ext0,
            sigma_p_m,
            sigma_theta_rad,
        };
        cost += ext.add(v, ne.as_deref_mut())?;
    }
    Ok(cost)
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
            *s = (lm.inv_depth, lm.bearing_delta);
        }
    }

    fn work(&self) -> u32 {
        self.work
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
            (lm.inv_depth, lm.bearing_delta) = *s;
        }
    }
}

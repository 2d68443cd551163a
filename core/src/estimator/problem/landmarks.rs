//! The visual measurements of the window's problem: one pass over the usable landmarks, each
//! added as the factor of its [`LandmarkModel`] (or of the part of it the visited set takes).
//!
//! The marginalization of the oldest keyframe ([`FactorSet::Oldest`]) takes the landmarks its
//! plan involves ([`MargPlan`]): whole factors of the landmarks that leave or are re-used, and
//! of a re-anchored landmark only its observation at position 0, as a two-view residual on its
//! new anchors (the landmark's other residuals stay in the window) — except with the depth
//! eliminated, where the prior takes the whole factor less what stays in the window
//! ([`FactorSet::OldestRest`], see `estimator::marginalize`).
//!
//! A landmark whose factor fails is disabled for the solve when linearizing (`usable = false`,
//! counted); in a cost evaluation it fails the evaluation, so an LM trial step that breaks a
//! landmark's geometry is rejected instead of shedding its cost.
#![deny(clippy::too_many_lines)]

use super::factor::{LandmarkFactor, LandmarkModel, VisualSettings, WindowVars};
use super::inverse_depth::InverseDepthLandmark;
use super::lidar::{DirectLidarLandmark, MscLandmark};
use super::pose_only::TwoViewLandmark;
use super::visual::EliminatedLandmark;
use super::{AssemblyCounts, FactorSet, Landmarks, Saved, SCHUR_COLS};
use crate::estimator::config::EstimatorConfig;
use crate::landmarks::MargPlan;
use crate::solver::{LandmarkSchur, NormalEquations};
use crate::Error;

/// Which landmark factors a pass adds: the pose-only forms, or the inverse-depth states (the
/// marginalization in the inverse-depth mode runs both, in this order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Pass {
    /// Two-view, direct-LiDAR, eliminated and MSC landmarks, and the two-view residuals of
    /// re-anchored landmarks' observations at position 0.
    PoseOnly,
    /// Inverse-depth landmarks.
    InverseDepth,
}

/// The part of a landmark's factor the visited set takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Part {
    /// The whole factor.
    Whole,
    /// The factor without the observation at position 0 (what stays in the window).
    WithoutObsZero,
    /// Only the observation at position 0, as a two-view residual.
    ObsZero,
}

/// What a pass over the landmarks reads and updates: their state (usable flags, inverse
/// depths), their Schur accumulators, the eliminated depths of the last cost evaluation and the
/// counts.
pub(super) struct LandmarkPass<'p, const N: usize, const L: usize> {
    /// Configuration.
    pub cfg: &'p EstimatorConfig,
    /// The visited set.
    pub set: FactorSet,
    /// Landmarks.
    pub lms: &'p mut Landmarks<N, L>,
    /// Per-landmark Schur accumulators.
    pub schur: &'p mut [LandmarkSchur<SCHUR_COLS>],
    /// The eliminated depths of the last cost evaluation.
    pub saved: &'p mut Saved<N, L>,
    /// Counts of the assembly.
    pub counts: &'p mut AssemblyCounts,
    /// The state has not changed since the last successful cost evaluation
    /// ([`super::Problem::tau_fresh`]).
    pub tau_fresh: bool,
}

/// What one landmark's factor contributed.
struct Added {
    cost: f64,
    observations: u32,
    ldm: u32,
    inverse_depth: Option<f64>,
    bearing_delta: Option<[f64; 2]>,
    work: u32,
}

/// Adds `f` and reports what it contributed.
fn add<const N: usize, const D: usize>(
    mut f: impl LandmarkFactor<N, D>,
    v: &WindowVars<'_, N>,
    ne: Option<&mut NormalEquations<D>>,
) -> Result<Added, Error> {
    let linearized = ne.is_some();
    let cost = f.add(v, ne)?;
    Ok(Added {
        work: f.work(linearized),
        cost,
        observations: f.observations(),
        ldm: f.depth_measurements(),
        inverse_depth: f.inverse_depth(),
        bearing_delta: f.bearing_delta(),
    })
}

/// The part of the factor of a landmark of `model` with marginalization plan `marg` the visited
/// set takes (module docs), `None` for none.
fn part(set: FactorSet, model: LandmarkModel, marg: MargPlan) -> Option<Part> {
    let eliminated = model == LandmarkModel::Eliminated;
    Some(match (set, marg) {
        (FactorSet::All, _) | (FactorSet::Oldest, MargPlan::Whole | MargPlan::Reuse) => Part::Whole,
        (FactorSet::Oldest, MargPlan::ObsZero) if eliminated => Part::Whole,
        (FactorSet::OldestRest, MargPlan::ObsZero) if eliminated => Part::WithoutObsZero,
        (FactorSet::Oldest, MargPlan::ObsZero) => Part::ObsZero,
        _ => return None,
    })
}

impl<const N: usize, const L: usize> LandmarkPass<'_, N, L> {
    /// Visits the landmarks of `pass`, adding their factors to `ne` (or only summing their
    /// cost); returns the (robust) cost.
    pub fn run<const D: usize>(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: &mut Option<&mut NormalEquations<D>>,
        pass: Pass,
    ) -> Result<f64, Error> {
        let vs = VisualSettings::new(self.cfg)?;
        let linearize = ne.is_some();
        let mut cost = 0.0;
        for li in 0..self.lms.len() {
            let Some(sc) = self.schur.get_mut(li) else {
                break;
            };
            if pass == Pass::InverseDepth {
                sc.clear();
            }
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if !lm.usable {
                continue;
            }
            let model = LandmarkModel::of(self.cfg, lm);
            let Some(part) = part(self.set, model, lm.marg) else {
                continue;
            };
            let ne = ne.as_deref_mut();
            let added = match (pass, model, part) {
                (Pass::InverseDepth, LandmarkModel::InverseDepth, Part::Whole) => {
                    let Some(f) = InverseDepthLandmark::new(vs, lm, sc) else {
                        continue;
                    };
                    add(f, v, ne)
                }
                (Pass::InverseDepth, _, _) | (_, LandmarkModel::InverseDepth, Part::Whole) => {
                    continue
                }
                (_, LandmarkModel::MscLidar, Part::Whole) => {
                    add(MscLandmark::new(vs, lm, sc), v, ne)
                }
                (_, LandmarkModel::Eliminated, Part::Whole | Part::WithoutObsZero) => {
                    let cached = self.saved.tau_ok.get(li).copied().unwrap_or(false);
                    let saved = (self.saved.delta.get(li), self.saved.tau.get(li));
                    let cached = match (self.tau_fresh && linearize && cached, saved) {
                        (true, (Some(d), Some(t))) => Some((*d, *t)),
                        _ => None,
                    };
                    let rest = part == Part::WithoutObsZero;
                    add(EliminatedLandmark::new(vs, lm, rest, cached), v, ne)
                }
                (_, LandmarkModel::DirectLidar, Part::Whole) => {
                    let Some(f) = DirectLidarLandmark::new(vs, lm) else {
                        continue;
                    };
                    add(f, v, ne)
                }
                (_, _, part) => {
                    let only_j = (part == Part::ObsZero).then_some(0);
                    let Some(f) = TwoViewLandmark::new(vs, lm, only_j) else {
                        continue;
                    };
                    add(f, v, ne)
                }
            };
            match added {
                Ok(a) => {
                    cost += a.cost;
                    if a.observations > 0 {
                        self.counts.landmarks += 1;
                        self.counts.observations += a.observations;
                    }
                    self.counts.ldm += a.ldm;
                    self.counts.work = self.counts.work.saturating_add(a.work);
                    if let Some(tau) = a.inverse_depth {
                        let delta = a.bearing_delta.unwrap_or([0.0; 2]);
                        self.keep_inverse_depth(li, tau, delta, model, linearize);
                    }
                }
                Err(_) if linearize => {
                    if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                        lm.usable = false;
                    }
                    self.counts.disabled += 1;
                }
                Err(_) => return Err(Error::Degenerate),
            }
        }
        Ok(cost)
    }

    /// Landmark `li` keeps the inverse depth `tau` (and anchor bearing correction `delta`) its
    /// factor solved for; an eliminated depth of a cost evaluation is also kept for the
    /// linearization at the same state.
    fn keep_inverse_depth(
        &mut self,
        li: usize,
        tau: f64,
        delta: [f64; 2],
        model: LandmarkModel,
        linearize: bool,
    ) {
        if model == LandmarkModel::Eliminated && !linearize {
            let saved = &mut *self.saved;
            if let (Some(t), Some(d), Some(ok)) = (
                saved.tau.get_mut(li),
                saved.delta.get_mut(li),
                saved.tau_ok.get_mut(li),
            ) {
                (*t, *d, *ok) = (tau, delta, true);
            }
        }
        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
            lm.inv_depth = tau;
            lm.bearing_delta = delta;
        }
    }
}

//! Levenberg-Marquardt driver over an [`LmProblem`].
//!
//! Each outer iteration linearizes once; each inner trial solves the Marquardt-damped system
//! `(H + lambda * diag(H)) dx = b` (diagonal clamped to `[diag_min, diag_max]`) with the
//! pivot-floored [`Ldlt`], applies `dx`, and compares the actual decrease with the decrease the
//! linear model predicts,
//!
//! ```text
//! predicted = c - |r + J dx|^2 = 2 dx^T b - dx^T H dx,   rho = (c - c_new) / predicted.
//! ```
//!
//! A step is accepted when `rho > min_gain_ratio`; then Nielsen's update
//! `lambda *= max(1/3, 1 - (2 rho - 1)^3)`, `nu = 2`; otherwise the state is restored and
//! `lambda *= nu`, `nu *= 2`. Iterations and rejected trials per iteration are both bounded.
//!
//! Stops (see [`Termination`]): gradient `max |b_i| <= gradient_tolerance` (before solving),
//! step `|dx| <= step_tolerance` (nothing applied), relative cost decrease of an accepted step
//! `<= function_tolerance`, the iteration bound, the retry bound, `lambda > lambda_max`, or the
//! work budget (`max_trials` trial steps in the solve; with `max_iterations` it bounds the
//! linearizations and factorizations of a solve whatever the data; `max_work` bounds the work
//! the problem reports ([`LmProblem::work`]), which grows with the data: a trial or a
//! linearization is not started when the last one's work would pass it, so a solve does at most
//! `max_work` plus one trial's misprediction, or its first iteration). Every stop but an error
//! leaves the best state found: a step is applied only when it lowers the cost.

use super::ldlt::{FactorReport, Ldlt, PivotFloor};
use super::normal_equations::NormalEquations;
use crate::Error;

/// A nonlinear least-squares problem `min sum r(x)^T r(x)` over a manifold state with a
/// `dim()`-dimensional error state.
pub trait LmProblem<const D: usize> {
    /// Error-state dimension (`<= D`).
    fn dim(&self) -> usize;
    /// Adds every residual at the current state to `ne` (already reset to `dim()`); `ne.cost`
    /// must end up equal to what [`LmProblem::cost`] returns at the same state.
    fn linearize(&mut self, ne: &mut NormalEquations<D>) -> Result<(), Error>;
    /// Sum of squared residuals at the current state. An `Err` (e.g. a degenerate geometry
    /// after a wild step) rejects the trial step.
    fn cost(&mut self) -> Result<f64, Error>;
    /// `x <- x (+) dx` with `dx.len() == dim()`.
    fn apply(&mut self, dx: &[f64]);
    /// Remembers the current state (called before every trial step).
    fn save(&mut self);
    /// Returns to the state of the last [`LmProblem::save`].
    fn restore(&mut self);
    /// The work the problem's linearizations and cost evaluations have done so far, in its own
    /// units (a count that only grows; `max_work` of [`LmConfig`] is in the same units). The
    /// default, 0, leaves a solve unbounded by work.
    fn work(&self) -> u32 {
        0
    }
}

/// Tuning of [`LmWorkspace::solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct LmConfig {
    /// Maximum number of linearizations (outer iterations).
    pub max_iterations: usize,
    /// Maximum rejected trial steps within one iteration.
    pub max_retries: usize,
    /// Maximum trial steps (accepted and rejected, each a damped factorization and a cost
    /// evaluation) in the whole solve: with `max_iterations` a work budget
    /// ([`Termination::Budget`]). `u32::MAX`: no limit.
    pub max_trials: u32,
    /// Most work ([`LmProblem::work`]'s units) of the whole solve: a trial or a linearization
    /// (with the trial it needs) is not started when the work it is predicted to take (the last
    /// one's) would pass this ([`Termination::Budget`]); the first trial after the first
    /// linearization always runs. `u32::MAX`: no limit.
    pub max_work: u32,
    /// Initial damping `lambda` (relative to the clamped diagonal).
    pub initial_lambda: f64,
    /// Lower bound of `lambda` after successful steps.
    pub lambda_min: f64,
    /// Give up when rejections push `lambda` above this.
    pub lambda_max: f64,
    /// Lower clamp of `diag(H)` in the damping term.
    pub diag_min: f64,
    /// Upper clamp of `diag(H)` in the damping term.
    pub diag_max: f64,
    /// Stop when an accepted step decreases the cost by less than this fraction.
    pub function_tolerance: f64,
    /// Stop when `max |b_i|` is at most this.
    pub gradient_tolerance: f64,
    /// Stop when the step norm is at most this.
    pub step_tolerance: f64,
    /// Accept a step when the gain ratio exceeds this.
    pub min_gain_ratio: f64,
    /// Pivot floor of the damped factorization.
    pub pivot_floor: PivotFloor,
}

impl LmConfig {
    /// Ceres-like defaults.
    pub const DEFAULT: Self = Self {
        max_iterations: 10,
        max_retries: 10,
        max_trials: u32::MAX,
        max_work: u32::MAX,
        initial_lambda: 1e-4,
        lambda_min: 1e-12,
        lambda_max: 1e16,
        diag_min: 1e-6,
        diag_max: 1e32,
        function_tolerance: 1e-6,
        gradient_tolerance: 1e-10,
        step_tolerance: 1e-10,
        min_gain_ratio: 1e-3,
        pivot_floor: PivotFloor::DEFAULT,
    };

    fn validate(&self) -> Result<(), Error> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        let ok = pos(self.initial_lambda)
            && pos(self.lambda_min)
            && pos(self.lambda_max)
            && self.lambda_min <= self.lambda_max
            && nonneg(self.diag_min)
            && nonneg(self.diag_max)
            && self.diag_min <= self.diag_max
            && nonneg(self.function_tolerance)
            && nonneg(self.gradient_tolerance)
            && nonneg(self.step_tolerance)
            && nonneg(self.min_gain_ratio)
            && self.min_gain_ratio < 1.0;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

impl Default for LmConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Termination {
    /// `max |b_i| <= gradient_tolerance` at the current state.
    GradientTolerance,
    /// The damped step was shorter than `step_tolerance` (not applied).
    StepTolerance,
    /// An accepted step decreased the cost by less than `function_tolerance` (relative).
    CostTolerance,
    /// `max_iterations` linearizations were done.
    MaxIterations,
    /// `max_retries` trial steps in a row were rejected; the state is the last accepted one.
    RetriesExhausted,
    /// Rejections pushed `lambda` above `lambda_max`; the state is the last accepted one.
    DampingLimit,
    /// `max_trials` trial steps were made or the next step would pass `max_work` (the work
    /// budget ended); the state is the last accepted one.
    Budget,
}

/// Outcome of a solve, as data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmSummary {
    /// Outer iterations (linearizations followed by at least one trial).
    pub iterations: usize,
    /// Cost at the start.
    pub initial_cost: f64,
    /// Cost at the returned state.
    pub final_cost: f64,
    /// Accepted trial steps.
    pub accepted: usize,
    /// Rejected trial steps.
    pub rejected: usize,
    /// Diagnostics of the last damped factorization (`None` if none was needed).
    pub last_factor_report: Option<FactorReport>,
    /// Damping at exit.
    pub lambda: f64,
    /// Why it stopped.
    pub termination: Termination,
    /// Work done ([`LmProblem::work`]'s units), from the first linearization on.
    pub work: u32,
    /// The predicted work of the step `max_work` refused (0 when the solve ended otherwise):
    /// with `work`, a lower bound of what the solve would have taken without the budget.
    pub refused_work: u32,
}

/// Caller-owned buffers of the LM driver: normal equations, the damped factor and the step
/// (about `16 D^2` bytes; build in place).
#[derive(Clone)]
pub struct LmWorkspace<const D: usize> {
    /// Normal equations of the last linearization (kept across trials). After
    /// `MaxIterations`/`CostTolerance` the state has moved past it by one accepted step.
    pub ne: NormalEquations<D>,
    /// Damped factorization of the last trial.
    pub ldlt: Ldlt<D>,
    dx: [f64; D],
}

impl<const D: usize> Default for LmWorkspace<D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const D: usize> LmWorkspace<D> {
    /// Empty workspace; `const` so it can initialize a `static`.
    pub const fn new() -> Self {
        Self {
            ne: NormalEquations::new(),
            ldlt: Ldlt::new(),
            dx: [0.0; D],
        }
    }

    /// Back to the state [`LmWorkspace::new`] builds (every buffer zeroed), in place.
    pub fn reset_to_new(&mut self) {
        self.ne.reset_to_new();
        self.ldlt.reset_to_new();
        self.dx.fill(0.0);
    }

    /// Last trial step (active entries `0..ne.dim()`).
    pub fn last_step(&self) -> &[f64] {
        self.dx.get(..self.ne.dim()).unwrap_or(&[])
    }

    /// Minimizes `problem` from its current state. On `Ok` the problem holds the best state
    /// found; on `Err` (failed linearization, non-finite system, bad config) it holds the last
    /// accepted state.
    pub fn solve<P: LmProblem<D>>(
        &mut self,
        problem: &mut P,
        cfg: &LmConfig,
    ) -> Result<LmSummary, Error> {
        cfg.validate()?;
        let n = problem.dim();
        if n > D {
            return Err(Error::CapacityExceeded);
        }
        self.ne.reset(n)?;
        let work0 = problem.work();
        problem.linearize(&mut self.ne)?;
        // The work of the last linearization and of the last trial: the next ones' predictions.
        let mut lin_work = problem.work().saturating_sub(work0);
        let mut trial_work = lin_work;
        let spent = |p: &P| p.work().saturating_sub(work0);
        let mut cost = self.ne.cost;
        if !cost.is_finite() {
            return Err(Error::NonFinite);
        }
        let mut summary = LmSummary {
            iterations: 0,
            initial_cost: cost,
            final_cost: cost,
            accepted: 0,
            rejected: 0,
            last_factor_report: None,
            lambda: cfg.initial_lambda,
            termination: Termination::MaxIterations,
            work: 0,
            refused_work: 0,
        };
        let mut lambda = cfg.initial_lambda;
        let mut nu = 2.0_f64;
        let termination = 'outer: loop {
            if self.ne.gradient_max_abs() <= cfg.gradient_tolerance {
                break Termination::GradientTolerance;
            }
            if summary.iterations >= cfg.max_iterations {
                break Termination::MaxIterations;
            }
            summary.iterations += 1;
            let mut retries = 0;
            loop {
                let trials = summary.accepted + summary.rejected;
                if trials >= cfg.max_trials as usize {
                    break 'outer Termination::Budget;
                }
                if trials > 0 && spent(problem).saturating_add(trial_work) > cfg.max_work {
                    summary.refused_work = trial_work;
                    break 'outer Termination::Budget;
                }
                let dx = self.dx.get_mut(..n).ok_or(Error::CapacityExceeded)?;
                self.ldlt.load(&self.ne)?;
                self.ldlt
                    .add_marquardt_damping(lambda, cfg.diag_min, cfg.diag_max)?;
                summary.last_factor_report = Some(self.ldlt.factorize(cfg.pivot_floor)?);
                dx.copy_from_slice(self.ne.b.get(..n).ok_or(Error::CapacityExceeded)?);
                self.ldlt.solve_in_place(dx)?;
                let step_norm = libm::sqrt(dx.iter().map(|v| v * v).sum::<f64>());
                if step_norm <= cfg.step_tolerance {
                    break 'outer Termination::StepTolerance;
                }
                let predicted = 2.0 * self.ne.dot_b(dx)? - self.ne.quadratic_form(dx)?;
                problem.save();
                problem.apply(dx);
                let before = problem.work();
                let new_cost = problem.cost().ok().filter(|c| c.is_finite());
                trial_work = problem.work().saturating_sub(before);
                let gain = match new_cost {
                    Some(c) if predicted > 0.0 => (cost - c) / predicted,
                    _ => f64::NEG_INFINITY,
                };
                if let (Some(c), true) = (new_cost, gain > cfg.min_gain_ratio) {
                    let t = 2.0 * gain - 1.0;
                    lambda = (lambda * (1.0 / 3.0_f64).max(1.0 - t * t * t)).max(cfg.lambda_min);
                    nu = 2.0;
                    summary.accepted += 1;
                    let relative_decrease = if cost > 0.0 { (cost - c) / cost } else { 0.0 };
                    cost = c;
                    summary.final_cost = c;
                    if relative_decrease <= cfg.function_tolerance {
                        break 'outer Termination::CostTolerance;
                    }
                    break;
                }
                problem.restore();
                summary.rejected += 1;
                lambda *= nu;
                nu *= 2.0;
                if lambda > cfg.lambda_max {
                    break 'outer Termination::DampingLimit;
                }
                retries += 1;
                if retries > cfg.max_retries {
                    break 'outer Termination::RetriesExhausted;
                }
            }
            if summary.iterations >= cfg.max_iterations {
                break Termination::MaxIterations;
            }
            // No linearization the budget leaves no trial for.
            let next = lin_work.saturating_add(trial_work);
            if summary.accepted + summary.rejected >= cfg.max_trials as usize {
                break Termination::Budget;
            }
            if spent(problem).saturating_add(next) > cfg.max_work {
                summary.refused_work = next;
                break Termination::Budget;
            }
            self.ne.reset(n)?;
            let before = problem.work();
            problem.linearize(&mut self.ne)?;
            lin_work = problem.work().saturating_sub(before);
            if !self.ne.cost.is_finite() {
                return Err(Error::NonFinite);
            }
        };
        summary.lambda = lambda;
        summary.termination = termination;
        summary.work = spent(problem);
        log_debug!(
            "lm: {} it, cost {} -> {}",
            summary.iterations,
            summary.initial_cost,
            summary.final_cost
        );
        Ok(summary)
    }
}

//! The Levenberg-Marquardt driver of a keyframe (step 4 of the module docs of [`super`]): the
//! window's [`Problem`] borrowed beside the LM workspace, the passes (re-integration of
//! intervals whose bias moved, landmark preparation, pass 1, chi-square cull, pass 2 when the
//! cull removed enough), then the IMU noise scale, the depth-only optimization and the
//! reprojection cull ([`super::cull`]). Also the public single steps for benchmarks and
//! diagnostics ([`Estimator::lm_iteration`], [`Estimator::marginalize_oldest_now`],
//! [`Estimator::gradient_check`]).

use super::problem::{FactorSet, Problem};
use super::window::Layout;
use super::{now, Estimator, KeyframeReport, SolveBudget, VisualMode};
use crate::solver::{LmWorkspace, NormalEquations, Termination};
use crate::Error;

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// The window's least-squares problem over `layout`, beside the LM workspace and the
    /// marginalization system (disjoint borrows of the estimator).
    pub(super) fn split(
        &mut self,
        layout: Layout<N>,
        set: FactorSet,
    ) -> (
        Problem<'_, N, L, D>,
        &mut LmWorkspace<D>,
        &mut NormalEquations<D>,
    ) {
        let td_hold = self
            .td_hold
            .then(|| core::array::from_fn(|k| self.window.get(k).map_or(0.0, |kf| kf.td_s)));
        let problem = Problem {
            cfg: &self.cfg,
            window: &mut self.window,
            lms: &mut self.lms,
            ext: &mut self.ext,
            prior: &mut self.prior,
            initial: self.initial.as_ref(),
            layout,
            set,
            schur: &mut self.schur,
            saved: &mut self.saved,
            counts: Default::default(),
            work: 0,
            td_hold,
            tau_fresh: false,
        };
        (problem, &mut self.lm, &mut self.marg_ne)
    }

    pub(super) fn solve_layout(&self) -> Layout<N> {
        Layout::solve(
            self.window.len(),
            self.cfg.estimate_extrinsic,
            self.cfg.td.estimate,
        )
    }

    /// One LM pass with `cfg` limited to what is `left` of the keyframe's budget (spent here:
    /// linearizations, trial steps). False when the solve failed.
    fn run_lm(
        &mut self,
        pass: &crate::solver::LmConfig,
        left: &mut SolveBudget,
        report: &mut KeyframeReport,
        demand: &mut u32,
    ) -> bool {
        let cfg = crate::solver::LmConfig {
            max_iterations: pass
                .max_iterations
                .min(usize::try_from(left.max_linearizations).unwrap_or(usize::MAX)),
            max_trials: pass.max_trials.min(left.max_trials),
            max_work: pass.max_work.min(left.max_work),
            ..*pass
        };
        let layout = self.solve_layout();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        let res = lm.solve(&mut problem, &cfg);
        report.disabled_landmarks += problem.counts.disabled;
        report.landmarks_used = problem.counts.landmarks;
        report.ldm_count = problem.counts.ldm;
        report.observations_used = problem.counts.observations;
        match res {
            Ok(sum) => {
                if report.iterations == 0 {
                    report.cost.0 = sum.initial_cost;
                }
                report.cost.1 = sum.final_cost;
                report.iterations += sum.iterations as u32;
                report.termination = Some(sum.termination);
                let spend = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
                left.max_linearizations = left
                    .max_linearizations
                    .saturating_sub(spend(sum.iterations));
                left.max_trials = left
                    .max_trials
                    .saturating_sub(spend(sum.accepted + sum.rejected));
                left.max_work = left.max_work.saturating_sub(sum.work);
                report.solve_work = report.solve_work.saturating_add(sum.work);
                *demand = demand.saturating_add(sum.work.saturating_add(sum.refused_work));
                if sum.termination == Termination::Budget
                    || (sum.termination == Termination::MaxIterations
                        && cfg.max_iterations < pass.max_iterations)
                {
                    report.budget_hit = true;
                }
                true
            }
            Err(_) => {
                self.counters.solver_failures += 1;
                false
            }
        }
    }

    pub(super) fn optimize(&mut self, report: &mut KeyframeReport) {
        // Re-integrate intervals whose bias estimate moved far from the linearization point.
        for k in 1..self.window.len() {
            let (bg, ba) = match self.window.get(k - 1) {
                Some(a) => (a.state.bg, a.state.ba),
                None => continue,
            };
            if let Some(pre) = self.window.get_mut(k).and_then(|b| b.preint_mut()) {
                if pre.needs_reintegration(&bg, &ba) {
                    let _ = pre.reintegrate(bg, ba);
                    let _ = pre.cache_whitening();
                }
            }
        }
        let (rej, rej_ns, adm) = self.prepare_landmarks(true);
        report.depths_rejected = rej;
        report.rejection_ns = rej_ns;
        report.admission = adm;
        report.td_info_per_s2 = self.td_information();
        self.td_hold = report.td_info_per_s2 < self.cfg.td.min_info_per_s2;
        let mut left = self.cfg.solve_budget;
        left.max_work = self.work_limit();
        let first = self.cfg.lm_first;
        // What the solve would have taken without the budget, at least (the history's entry).
        let mut demand = 0;
        if !self.run_lm(&first, &mut left, report, &mut demand) {
            return;
        }
        self.second_pass(&mut left, report, &mut demand);
        self.remember_work(demand);
        if report.budget_hit {
            self.counters.solve_budget_hits += 1;
        }
        self.update_imu_noise_scale(&self.solve_layout());
        if self.cfg.lidar.enabled && self.cfg.lidar.depth_only_opt {
            let t0 = now(self.clock);
            self.depth_only_optimization();
            report.depth_opt_ns = now(self.clock).saturating_sub(t0);
        }
        let (obs, lms, rms) = self.reprojection_cull();
        report.culled_observations = obs;
        report.culled_landmarks = lms;
        report.residual_rms_px = rms;
    }

    /// The chi-square cull after the first pass, and the second pass when it culled enough and
    /// the budget leaves room.
    fn second_pass(
        &mut self,
        left: &mut SolveBudget,
        report: &mut KeyframeReport,
        demand: &mut u32,
    ) {
        report.culled_chi2 = self.chi2_cull();
        let min_culled =
            self.cfg.cull.second_pass_min_culled_frac * f64::from(report.observations_used);
        if report.culled_chi2 > 0 && f64::from(report.culled_chi2) >= min_culled {
            // The second pass's first iteration runs whatever its budget: it needs about what
            // the first pass's took.
            let per_iteration = report.solve_work / report.iterations.max(1);
            if left.max_linearizations == 0 || left.max_trials == 0 || left.max_work < per_iteration
            {
                // The budget is spent: the culled observations are out, the first pass's
                // state stays.
                report.budget_hit = true;
                *demand = demand.saturating_add(per_iteration);
            } else {
                self.prepare_landmarks(false);
                let second = self.cfg.lm_second;
                self.run_lm(&second, left, report, demand);
            }
        }
    }

    /// The work this keyframe's solve may take ([`SolveBudget::work_limit`] over the last
    /// keyframes' work).
    fn work_limit(&self) -> u32 {
        let mut h = [0u32; SolveBudget::HISTORY];
        let mut n = 0;
        for (d, s) in h.iter_mut().zip(self.work_history.iter()) {
            *d = *s;
            n += 1;
        }
        self.cfg.solve_budget.work_limit(h.get(..n).unwrap_or(&[]))
    }

    /// Adds what a keyframe's solve took, or would have taken at least without the budget, to
    /// the ring [`Self::work_limit`] reads (the work done would ratchet: a cut keyframe lowers
    /// the median, which cuts the next ones harder).
    fn remember_work(&mut self, work: u32) {
        if self.work_history.is_full() {
            self.work_history.pop_front();
        }
        let _ = self.work_history.push_back(work);
    }

    /// One Levenberg-Marquardt iteration on the current window (landmark preparation,
    /// linearization, damping, factorization, solve, evaluation of the step, accepted or not),
    /// with the first pass's settings. For benchmarks and diagnostics: a keyframe step runs a
    /// few of these per pass.
    pub fn lm_iteration(&mut self) -> Result<crate::solver::LmSummary, Error> {
        if self.window.len() < 2 {
            return Err(Error::NotEnoughData);
        }
        self.prepare_landmarks(false);
        let cfg = crate::solver::LmConfig {
            max_iterations: 1,
            ..self.cfg.lm_first
        };
        let layout = self.solve_layout();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        lm.solve(&mut problem, &cfg)
    }

    /// Marginalizes the oldest keyframe now, as the next keyframe of a full window would (Schur
    /// complement into the square-root prior, window shifted). For benchmarks and diagnostics.
    pub fn marginalize_oldest_now(&mut self) -> Result<(), Error> {
        if self.window.len() < 2 {
            return Err(Error::NotEnoughData);
        }
        self.marginalize_oldest()
    }

    /// Self-check of the assembled problem at the current state: compares the analytic gradient
    /// `-2 b` of the normal equations with central differences of the cost along every
    /// error-state column (step `h`), and returns the worst relative error. Restores the state.
    /// Meant for tests and diagnostics (it evaluates the cost `2 n` times).
    pub fn gradient_check(&mut self, h: f64) -> Result<f64, Error> {
        use crate::solver::LmProblem;
        self.prepare_landmarks(false);
        let layout = self.solve_layout();
        let n = layout.dim();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        lm.ne.reset(n)?;
        problem.linearize(&mut lm.ne)?;
        if problem.cfg.mode == VisualMode::InverseDepth {
            // The reduced system's b is the gradient of the cost minimized over the depths,
            // which central differences at fixed depths do not measure.
            return Err(Error::InvalidConfig);
        }
        let mut worst = 0.0f64;
        let mut dx = [0.0; D];
        for i in 0..n {
            let mut c = [0.0; 2];
            for (slot, sign) in c.iter_mut().zip([1.0, -1.0]) {
                problem.save();
                if let Some(d) = dx.get_mut(i) {
                    *d = sign * h;
                }
                problem.apply(dx.get(..n).unwrap_or(&[]));
                *slot = problem.cost()?;
                problem.restore();
                if let Some(d) = dx.get_mut(i) {
                    *d = 0.0;
                }
            }
            let g_num = (c[0] - c[1]) / (2.0 * h);
            let g_an = -2.0 * lm.ne.b.get(i).copied().unwrap_or(0.0);
            let err =
                libm::fabs(g_num - g_an) / (1.0 + libm::fmax(libm::fabs(g_num), libm::fabs(g_an)));
            worst = libm::fmax(worst, err);
        }
        Ok(worst)
    }

    /// The delay's information from the admitted landmarks' observations in the window
    /// ([`KeyframeReport::td_info_per_s2`]): the sum of their whitened delay Jacobians' squares,
    /// `|v * f| ^ 2 / sigma_px ^ 2`.
    fn td_information(&self) -> f64 {
        let count = self.window.len();
        let (fx, fy) = (self.cfg.camera.fx, self.cfg.camera.fy);
        let var_px = self.cfg.sigma_px * self.cfg.sigma_px;
        let mut info = 0.0;
        for lm in self.lms.landmarks().iter().filter(|lm| lm.usable) {
            for o in lm.obs.iter().take(count).flatten() {
                let (u, v) = (o.vel[0] * fx, o.vel[1] * fy);
                info += (u * u + v * v) / var_px;
            }
        }
        info
    }
}

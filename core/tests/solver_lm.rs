//! Levenberg-Marquardt on small nonlinear problems with known optima.
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
mod numdiff;
mod solver_support;

use numdiff::central_differences;
use povins_core::solver::{
    LmConfig, LmProblem, LmSummary, LmWorkspace, NormalEquations, Termination,
};
use povins_core::Error;
use solver_support::*;

const D: usize = 8;

type VecFn = fn(&[f64]) -> Vec<f64>;

/// Vector-space problem from a residual function and its analytic row-major Jacobian.
struct FnProblem {
    x: Vec<f64>,
    saved: Vec<f64>,
    residual: VecFn,
    jacobian: VecFn,
    linearizations: usize,
    /// Work units counted: 3 per linearization, 1 per cost evaluation.
    work: u32,
}

impl FnProblem {
    fn new(x0: &[f64], residual: VecFn, jacobian: VecFn) -> Self {
        Self {
            x: x0.to_vec(),
            saved: x0.to_vec(),
            residual,
            jacobian,
            linearizations: 0,
            work: 0,
        }
    }
}

impl LmProblem<D> for FnProblem {
    fn dim(&self) -> usize {
        self.x.len()
    }
    fn linearize(&mut self, ne: &mut NormalEquations<D>) -> Result<(), Error> {
        self.linearizations += 1;
        self.work += LINEARIZATION_WORK;
        let r = (self.residual)(&self.x);
        let j = (self.jacobian)(&self.x);
        let cols: Vec<usize> = (0..self.x.len()).collect();
        ne.add_residual(&r, &j, &cols, r.len(), cols.len())
    }
    fn cost(&mut self) -> Result<f64, Error> {
        self.work += TRIAL_WORK;
        let c: f64 = (self.residual)(&self.x).iter().map(|v| v * v).sum();
        if c.is_finite() {
            Ok(c)
        } else {
            Err(Error::Degenerate)
        }
    }
    fn apply(&mut self, dx: &[f64]) {
        self.x.iter_mut().zip(dx).for_each(|(x, d)| *x += d);
    }
    fn save(&mut self) {
        self.saved.clone_from(&self.x);
    }
    fn restore(&mut self) {
        self.x.clone_from(&self.saved);
    }
    fn work(&self) -> u32 {
        self.work
    }
}

/// [`FnProblem`]'s work units per linearization and per cost evaluation.
const LINEARIZATION_WORK: u32 = 3;
const TRIAL_WORK: u32 = 1;

fn rosenbrock(x: &[f64]) -> Vec<f64> {
    vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]
}
fn rosenbrock_jac(x: &[f64]) -> Vec<f64> {
    vec![-20.0 * x[0], 10.0, -1.0, 0.0]
}

const T: [f64; 12] = [0.0, 0.3, 0.7, 1.0, 1.5, 2.0, 2.6, 3.1, 3.9, 4.4, 5.2, 6.0];
/// Deterministic "noise" for the noisy fit (zero for the exact one).
const NOISE: [f64; 12] = [
    0.01, -0.02, 0.015, 0.0, -0.01, 0.02, -0.005, 0.01, -0.015, 0.005, 0.0, -0.01,
];

fn exp_model(p: &[f64], t: f64) -> f64 {
    p[0] * (p[1] * t).exp() + p[2]
}
fn exp_fit(p: &[f64]) -> Vec<f64> {
    let truth = [2.0, -0.7, 0.5];
    T.iter()
        .map(|&t| exp_model(p, t) - exp_model(&truth, t))
        .collect()
}
fn exp_fit_noisy(p: &[f64]) -> Vec<f64> {
    exp_fit(p).iter().zip(NOISE).map(|(r, n)| r - n).collect()
}
fn exp_fit_jac(p: &[f64]) -> Vec<f64> {
    T.iter()
        .flat_map(|&t| {
            let e = (p[1] * t).exp();
            [e, p[0] * t * e, 1.0]
        })
        .collect()
}

/// Depends only on s = x0 + x1 (a one-dimensional gauge) and not at all on x2.
fn gauge(x: &[f64]) -> Vec<f64> {
    let s = x[0] + x[1];
    vec![s * s - 4.0, s.sin() - 2.0_f64.sin()]
}
fn gauge_jac(x: &[f64]) -> Vec<f64> {
    let s = x[0] + x[1];
    vec![2.0 * s, 2.0 * s, 0.0, s.cos(), s.cos(), 0.0]
}

/// ln(x) - ln(3): undefined for x <= 0, so a full Gauss-Newton step from x = 20 must be rejected.
fn log_fit(x: &[f64]) -> Vec<f64> {
    vec![x[0].ln() - 3.0_f64.ln()]
}
fn log_fit_jac(x: &[f64]) -> Vec<f64> {
    vec![1.0 / x[0]]
}

#[test]
fn analytic_jacobians_match_central_differences() {
    let cases: [(VecFn, VecFn, Vec<f64>); 5] = [
        (rosenbrock, rosenbrock_jac, vec![-1.2, 1.0]),
        (exp_fit, exp_fit_jac, vec![1.3, -0.2, 0.1]),
        (exp_fit_noisy, exp_fit_jac, vec![1.3, -0.2, 0.1]),
        (gauge, gauge_jac, vec![0.3, 0.2, 5.0]),
        (log_fit, log_fit_jac, vec![2.5]),
    ];
    for (f, j, x) in cases {
        let at = |dx: &[f64]| -> Vec<f64> { x.iter().zip(dx).map(|(a, d)| a + d).collect() };
        let (_, num) = central_differences(x.len(), 1e-6, |dx| f(&at(dx)));
        let ana = j(&x);
        assert!(max_abs_diff(&num, &ana) < 1e-6, "{num:?} vs {ana:?}");
    }
}

#[test]
fn rosenbrock_reaches_the_known_minimum() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[-1.2, 1.0], rosenbrock, rosenbrock_jac);
    let cfg = LmConfig {
        max_iterations: 100,
        function_tolerance: 1e-12,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    eprintln!("rosenbrock: {s:?}");
    assert!(
        (p.x[0] - 1.0).abs() < 1e-6 && (p.x[1] - 1.0).abs() < 1e-6,
        "{:?} {s:?}",
        p.x
    );
    assert!((s.initial_cost - 24.2).abs() < 1e-12, "4.4^2 + 2.2^2");
    assert!(s.final_cost < 1e-12);
    assert!(s.iterations <= 100 && s.accepted >= 5, "{s:?}");
    assert!(matches!(
        s.termination,
        Termination::GradientTolerance | Termination::CostTolerance | Termination::StepTolerance
    ));
    let rep = s.last_factor_report.unwrap();
    assert!(rep.positive_definite && rep.n == 2);
}

#[test]
fn exact_exponential_fit_recovers_parameters() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[1.0, -0.1, 0.0], exp_fit, exp_fit_jac);
    let cfg = LmConfig {
        max_iterations: 50,
        function_tolerance: 1e-14,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    assert!(
        max_abs_diff(&p.x, &[2.0, -0.7, 0.5]) < 1e-7,
        "{:?} {s:?}",
        p.x
    );
    assert!(s.final_cost < 1e-14 && s.initial_cost > 1.0);
}

#[test]
fn noisy_exponential_fit_ends_at_a_stationary_point() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[1.0, -0.1, 0.0], exp_fit_noisy, exp_fit_jac);
    let cfg = LmConfig {
        max_iterations: 50,
        function_tolerance: 1e-15,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    // Gradient J^T r vanishes at the least-squares optimum...
    let r = exp_fit_noisy(&p.x);
    let j = exp_fit_jac(&p.x);
    let jt: Dense = (0..12).map(|i| j[3 * i..3 * i + 3].to_vec()).collect();
    let g = transpose_matvec(&jt, &r);
    assert!(max_abs(&g) < 1e-9, "gradient {g:?}");
    // ... which is close to the truth (noise is ~1%) and cheaper than the truth.
    assert!(max_abs_diff(&p.x, &[2.0, -0.7, 0.5]) < 0.05, "{:?}", p.x);
    let truth_cost: f64 = NOISE.iter().map(|n| n * n).sum();
    assert!(s.final_cost < truth_cost);
}

#[test]
fn rank_deficient_gauge_problem_does_not_blow_up() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[0.3, 0.2, 5.0], gauge, gauge_jac);
    let cfg = LmConfig {
        max_iterations: 60,
        function_tolerance: 1e-14,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    eprintln!("gauge: {s:?}");
    assert!(p.x.iter().all(|v| v.is_finite()));
    assert!((p.x[0] + p.x[1] - 2.0).abs() < 1e-7, "{:?} {s:?}", p.x);
    // The free direction x0 - x1 gets equal, bounded updates (symmetric problem) ...
    assert!((p.x[0] - p.x[1] - 0.1).abs() < 1e-9, "{:?}", p.x);
    // ... and the unobserved state never moves.
    assert_eq!(p.x[2], 5.0);
    assert!(s.final_cost < 1e-14);
    // Only the damping keeps the last solves regular: their smallest pivot is tiny.
    let rep = s.last_factor_report.unwrap();
    assert!(rep.min_pivot < 1e-6 * rep.max_pivot, "{rep:?}");
}

#[test]
fn steps_into_invalid_region_are_rejected_and_restored() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[20.0], log_fit, log_fit_jac);
    let cfg = LmConfig {
        max_iterations: 50,
        function_tolerance: 1e-15,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    assert!(s.rejected >= 1, "{s:?}");
    assert!((p.x[0] - 3.0).abs() < 1e-8, "{:?} {s:?}", p.x);
}

#[test]
fn iteration_and_retry_bounds_hold() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[-1.2, 1.0], rosenbrock, rosenbrock_jac);
    let cfg = LmConfig {
        max_iterations: 2,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    assert_eq!(s.termination, Termination::MaxIterations);
    assert_eq!(s.iterations, 2);
    assert_eq!(
        p.linearizations, 2,
        "no linearization is wasted after the last iteration"
    );
    assert!(s.final_cost < s.initial_cost);

    // A problem whose cost always fails: every trial is rejected, the state is kept.
    let mut p = FnProblem::new(&[20.0], log_fit, log_fit_jac);
    p.residual = |x| {
        if x[0] == 20.0 {
            log_fit(x)
        } else {
            vec![f64::NAN]
        }
    };
    let cfg = LmConfig {
        max_retries: 3,
        ..LmConfig::DEFAULT
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    assert_eq!(s.termination, Termination::RetriesExhausted);
    assert_eq!((s.accepted, s.rejected), (0, 4));
    assert_eq!(p.x, vec![20.0]);
    assert_eq!(s.final_cost, s.initial_cost);
}

#[test]
fn invalid_setups_are_errors() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[-1.2, 1.0], rosenbrock, rosenbrock_jac);
    let bad = LmConfig {
        initial_lambda: f64::NAN,
        ..LmConfig::DEFAULT
    };
    assert_eq!(ws.solve(&mut p, &bad), Err(Error::InvalidConfig));
    let mut big = FnProblem::new(&[0.0; 9], |_| vec![0.0], |_| vec![0.0; 9]);
    assert_eq!(
        ws.solve(&mut big, &LmConfig::DEFAULT),
        Err(Error::CapacityExceeded)
    );
    let mut nan = FnProblem::new(&[-1.0], log_fit, log_fit_jac);
    assert_eq!(
        ws.solve(&mut nan, &LmConfig::DEFAULT),
        Err(Error::NonFinite)
    );
}

#[test]
fn already_optimal_stops_on_gradient_without_iterating() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = FnProblem::new(&[1.0, 1.0], rosenbrock, rosenbrock_jac);
    let s = ws.solve(&mut p, &LmConfig::DEFAULT).unwrap();
    assert_eq!(s.termination, Termination::GradientTolerance);
    assert_eq!((s.iterations, s.final_cost), (0, 0.0));
}

/// A budget test's setting: Rosenbrock from its classic start, and a solve free to take 50
/// linearizations.
fn rosenbrock_start() -> FnProblem {
    FnProblem::new(&[-1.2, 1.0], rosenbrock, rosenbrock_jac)
}

const FREE: LmConfig = LmConfig {
    max_iterations: 50,
    ..LmConfig::DEFAULT
};

/// Checks a budgeted solve ended by its budget at its best state, the one it reports.
fn assert_ended_by_budget_at_best(s: &LmSummary, p: &FnProblem) {
    assert_eq!(s.termination, Termination::Budget, "{s:?}");
    assert!(s.final_cost <= s.initial_cost, "{s:?}");
    let cost: f64 = rosenbrock(&p.x).iter().map(|r| r * r).sum();
    assert_eq!(cost, s.final_cost, "the state is the one reported");
}

/// The work budget: at most `max_trials` trial steps in the solve, no linearization without a
/// trial left for it, and the best state found kept (the state a shorter solve reaches).
#[test]
fn the_trial_budget_ends_the_solve_at_its_best_state() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let unlimited = ws.solve(&mut rosenbrock_start(), &FREE).unwrap();
    assert!(unlimited.accepted + unlimited.rejected > 3, "{unlimited:?}");
    for budget in 1..=3u32 {
        let mut p = rosenbrock_start();
        let cfg = LmConfig {
            max_trials: budget,
            ..FREE
        };
        let s = ws.solve(&mut p, &cfg).unwrap();
        assert_ended_by_budget_at_best(&s, &p);
        assert_eq!(s.accepted + s.rejected, budget as usize, "{s:?}");
        assert_eq!(
            p.linearizations, s.iterations,
            "no linearization after the budget's last trial"
        );
    }
}

/// The work budget in the problem's own units: a step is not started when the last one's work
/// would pass `max_work`, the first iteration always runs, and the best state is kept. With
/// constant units the solve's work is therefore at most the budget, or one iteration's.
#[test]
fn the_work_budget_ends_the_solve_within_its_units() {
    let mut ws = Box::new(LmWorkspace::<D>::new());
    let mut p = rosenbrock_start();
    let unlimited = ws.solve(&mut p, &FREE).unwrap();
    assert_eq!(
        unlimited.work, p.work,
        "the summary's work is the problem's"
    );
    assert!(unlimited.work > 20, "{unlimited:?}");
    let first_iteration = LINEARIZATION_WORK + TRIAL_WORK;
    for budget in [1, 3, 4, 5, 7, 8, 9, 12, 20] {
        let mut p = rosenbrock_start();
        let cfg = LmConfig {
            max_work: budget,
            ..FREE
        };
        let s = ws.solve(&mut p, &cfg).unwrap();
        assert_ended_by_budget_at_best(&s, &p);
        assert_eq!(s.work, p.work);
        assert!(s.work <= budget.max(first_iteration), "{budget}: {s:?}");
        // Stopped because the next step would not fit: a trial (1) or a linearization and its
        // trial (4).
        assert!(
            s.work + LINEARIZATION_WORK + TRIAL_WORK > budget,
            "{budget}: stopped with room left: {s:?}"
        );
        assert!(
            s.accepted + s.rejected >= 1,
            "{budget}: the first trial runs"
        );
        assert!(s.final_cost <= s.initial_cost, "{s:?}");
        let cost: f64 = rosenbrock(&p.x).iter().map(|r| r * r).sum();
        assert_eq!(cost, s.final_cost, "the state is the one reported");
    }
    // A budget with room for every step the solve takes changes nothing.
    let mut p = rosenbrock_start();
    let cfg = LmConfig {
        max_work: unlimited.work + LINEARIZATION_WORK + TRIAL_WORK,
        ..FREE
    };
    let s = ws.solve(&mut p, &cfg).unwrap();
    assert_eq!(
        (s.termination, s.final_cost, s.work),
        (unlimited.termination, unlimited.final_cost, unlimited.work)
    );
}

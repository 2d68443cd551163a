//! The work budget of a keyframe's solve (`[solve_budget]`, `SolveBudget`): in units that grow
//! with the data (`KeyframeReport::solve_work`), it bounds each keyframe's solve, keeps the
//! typical keyframe's work, and leaves the estimate close to the unbudgeted one. Deterministic:
//! the budget counts work, not time.

mod common;

use common::*;
use povins::core::estimator::{EstimatorConfig, KeyframeReport, SolveBudget};
use povins::core::inertial::NavState;
use povins::host_tools::runner::config_for;
use povins::platform::dataset::Dataset;

/// Every keyframe's report of a simulated robot run (no LiDAR, ground-truth start), the final
/// states and the budget hits.
fn run(ds: &Dataset, budget: SolveBudget) -> (Vec<KeyframeReport>, Vec<NavState>, u64) {
    let mut cfg: EstimatorConfig = config_for(ds);
    cfg.solve_budget = budget;
    let (start, s0) = gt_start(ds, &mut cfg);
    let mut est = new_estimator(cfg);
    est.initialize(s0).expect("initial state");
    let (mut reports, mut states) = (Vec::new(), Vec::new());
    let frames = frames_of(ds);
    drive(&mut est, &ds.imu[start..], &frames, |_, _, o| {
        if let Some(r) = o.keyframe {
            reports.push(r);
        }
        if let Some(n) = o.nav {
            states.push(n);
        }
        true
    });
    (reports, states, est.counters().solve_budget_hits)
}

fn median(mut v: Vec<u32>) -> u32 {
    v.sort_unstable();
    v[v.len() / 2]
}

#[test]
fn the_work_budget_bounds_each_keyframe_and_keeps_the_estimate() {
    small_stack(|| {
        let ds = simulate_robot(1, 15.0);
        let (free, free_states, free_hits) = run(&ds, SolveBudget::UNLIMITED);
        assert_eq!(free_hits, 0);
        let work: Vec<u32> = free.iter().skip(1).map(|r| r.solve_work).collect();
        assert!(work.len() > 30, "{} keyframes", work.len());
        let (med, max) = (median(work.clone()), *work.iter().max().unwrap());
        assert!(med > 0);
        assert!(
            max as f64 > 1.8 * med as f64,
            "the test needs keyframes well above the median: max {max}, median {med}"
        );
        let limit = med + med / 2;
        let budget = SolveBudget {
            max_work: limit,
            ..SolveBudget::UNLIMITED
        };
        let (cut, cut_states, hits) = run(&ds, budget);
        assert!(hits > 0, "the budget ended some solves");
        let cut_work: Vec<u32> = cut.iter().skip(1).map(|r| r.solve_work).collect();
        let cut_max = *cut_work.iter().max().unwrap();
        // At most the budget plus one misprediction of a step (a linearization and its trial
        // take about the last one's work), or a first iteration alone.
        assert!(
            (cut_max as f64) < 1.35 * limit as f64,
            "max {cut_max} against a budget of {limit} (unbudgeted max {max})"
        );
        let cut_med = median(cut_work);
        assert!(
            cut_med as f64 >= 0.9 * med as f64,
            "the typical keyframe keeps its work: {cut_med} against {med}"
        );
        let (a, b) = (ate_m(&ds, &free_states), ate_m(&ds, &cut_states));
        assert!(a < 0.2, "unbudgeted ATE {a} m");
        assert!(b < 1.25 * a + 0.01, "budgeted ATE {b} m against {a} m");

        // The relative budget: about the same bound, from the run's own history.
        let ratio = SolveBudget {
            max_work_ratio: 1.5,
            ..SolveBudget::UNLIMITED
        };
        let (rel, rel_states, rel_hits) = run(&ds, ratio);
        assert!(rel_hits > 0);
        let rel_work: Vec<u32> = rel.iter().skip(1).map(|r| r.solve_work).collect();
        let rel_max = *rel_work.iter().max().unwrap();
        assert!(
            rel_max < max,
            "relative budget: max {rel_max} against {max}"
        );
        let c = ate_m(&ds, &rel_states);
        assert!(
            c < 1.25 * a + 0.01,
            "relative budget's ATE {c} m against {a} m"
        );

        // Deterministic: the same budget gives the same bits.
        let (_, again, _) = run(&ds, budget);
        assert_eq!(again.len(), cut_states.len());
        assert!(again
            .iter()
            .zip(&cut_states)
            .all(|(x, y)| state_bits(x) == state_bits(y)));
    });
}

//! `covariance = true`: the estimate is the same bit for bit, and the covariance handed out
//! with the IMU-rate state is there from the first solve (the second keyframe) on, symmetric, positive definite, and
//! propagated by the INS between keyframes (the biases' variances grow by their random walk). On the repository's EuRoC tracks.

mod common;

use common::*;
use povins::core::estimator::VisualMode;
use povins::core::inertial::Mat15;

#[test]
fn the_covariance_changes_no_estimate_and_is_a_covariance() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let frames = frames_of(&ds);
        let run = |covariance: bool| {
            let mut cfg = euroc_config(&ds, VisualMode::PoseOnly);
            cfg.covariance = covariance;
            let mut est = new_estimator(cfg);
            let mut out = Vec::new();
            drive(&mut est, &ds.imu, &frames, |e, _, o| {
                let keyframe = o.keyframe.is_some();
                out.push((o.nav, e.nav_covariance().map(|c| c.state_order()), keyframe));
                true
            });
            out
        };
        let (off, on) = (run(false), run(true));
        assert_eq!(off.len(), on.len());
        for (a, b) in off.iter().zip(&on) {
            assert_eq!(a.0.map(|s| state_bits(&s)), b.0.map(|s| state_bits(&s)));
            assert!(a.1.is_none());
        }
        // The first solve is at the second keyframe (the first has nothing to solve).
        let second_kf = on
            .iter()
            .enumerate()
            .filter(|(_, o)| o.2)
            .nth(1)
            .map(|(i, _)| i)
            .expect("two keyframes");
        let mut checked = 0;
        let mut prev: Option<Mat15> = None;
        for (nav, cov, keyframe) in &on[second_kf..] {
            let Some(p) = cov else {
                panic!(
                    "no covariance at {:?} after the first solve",
                    nav.map(|s| s.t_ns)
                );
            };
            assert_eq!(*p, p.transpose());
            let chol = p.cholesky().expect("positive definite");
            assert!(chol.l().diagonal().iter().all(|d| *d > 0.0));
            if let (Some(q), false) = (prev, *keyframe) {
                // Propagated: it moves with every sample, and the biases' variances grow by
                // their random walk (a position or velocity variance may shrink through its
                // correlations).
                assert_ne!(
                    *p,
                    q,
                    "the covariance did not move at {:?}",
                    nav.map(|s| s.t_ns)
                );
                for i in 9..15 {
                    assert!(p[(i, i)] > q[(i, i)], "bias variance {i} did not grow");
                }
            }
            prev = Some(*p);
            checked += 1;
        }
        assert!(checked > 4000, "{checked} states checked");
        // Standard deviations of a plausible size: mm to m in position, below 1 m/s.
        let p = prev.expect("a covariance");
        let sd = |i: usize| p[(i, i)].sqrt();
        assert!((1e-4..10.0).contains(&sd(0)), "position sd {}", sd(0));
        assert!((1e-5..1.0).contains(&sd(6)), "velocity sd {}", sd(6));
    });
}

//! Unit tests of `covariance`, compiled only with `#[cfg(test)]` (the parent declares the module so).

use super::*;
use crate::inertial::increment::{two_sample, two_sample_bias_jacobians, Increment};
use crate::inertial::{ImuSample, Ins, InsConfig, NavState};
use crate::math::{log_so3, quat_exp, Vec3};

const G: f64 = 9.81;

fn sample(t_ns: i64, w: [f64; 3], f: [f64; 3]) -> ImuSample {
    ImuSample {
        t_ns,
        gyro_rps: Vec3::from(w),
        accel_mps2: Vec3::from(f),
    }
}

fn samples() -> [ImuSample; 3] {
    [
        sample(0, [0.3, -0.2, 0.5], [1.0, 0.2, 9.6]),
        sample(5_000_000, [0.4, -0.1, 0.7], [1.3, -0.4, 9.9]),
        sample(9_000_000, [0.6, 0.1, 0.4], [0.7, -0.9, 10.4]),
    ]
}

fn start() -> NavState {
    let mut x = NavState::identity(0);
    x.p_wb = Vec3::new(1.0, -2.0, 0.5);
    x.v_wb = Vec3::new(0.8, 0.3, -0.2);
    x.q_wb = quat_exp(&Vec3::new(0.2, -0.4, 1.1));
    x.bg = Vec3::new(0.01, -0.02, 0.015);
    x.ba = Vec3::new(0.1, -0.05, 0.2);
    x
}

/// `x` moved by the error `d` in the step order `[dp, dv, dtheta, dbg, dba]`.
fn perturbed(x: &NavState, d: &[f64; 15]) -> NavState {
    let v = |o: usize| Vec3::new(d[o], d[o + 1], d[o + 2]);
    let mut y = *x;
    y.p_wb += v(RP);
    y.v_wb += v(RV);
    y.q_wb *= quat_exp(&v(RT));
    y.bg += v(RBG);
    y.ba += v(RBA);
    y
}

/// The error of `y` against `x` in the step order.
fn error(x: &NavState, y: &NavState) -> [f64; 15] {
    let mut e = [0.0; 15];
    let mut put = |o: usize, v: Vec3| e[o..o + 3].copy_from_slice(v.as_slice());
    put(RP, y.p_wb - x.p_wb);
    put(RV, y.v_wb - x.v_wb);
    put(RT, log_so3(&(x.q_wb.inverse() * y.q_wb)));
    put(RBG, y.bg - x.bg);
    put(RBA, y.ba - x.ba);
    e
}

/// The INS from `x` through the first `steps + 1` samples.
fn run(x: &NavState, steps: usize) -> NavState {
    let cfg = InsConfig {
        gravity_mps2: G,
        max_dt_s: 0.02,
    };
    let mut ins = Ins::new(cfg, *x).unwrap();
    for s in samples().iter().take(steps + 1) {
        ins.propagate(s).unwrap();
    }
    *ins.state()
}

/// The analytic transition of the INS's `steps` steps from `x`, chained.
fn analytic(x: &NavState, steps: usize) -> Mat15 {
    let s = samples();
    let (mut total, mut a) = (Mat15::identity(), Mat15::zeros());
    let mut state = *x;
    let mut prev: Option<Increment> = None;
    for k in 0..steps {
        let inc = Increment::from_samples(
            k.checked_sub(1).map(|i| &s[i]),
            &s[k],
            &s[k + 1],
            &x.bg,
            &x.ba,
        );
        let step = two_sample(prev.as_ref(), &inc);
        let jb = two_sample_bias_jacobians(prev.as_ref(), &inc);
        let dt = (s[k + 1].t_ns - s[k].t_ns) as f64 * 1e-9;
        let terms = StepTerms::new(state.q_wb.to_rotation_matrix().into_inner(), &step);
        transition(&mut a, &terms, &jb, dt, 1.0);
        total = a * total;
        state = run(x, k + 1);
        prev = Some(inc);
    }
    total
}

/// The INS's error transition against central differences of `Ins::propagate`, for one step
/// (trapezoidal increment) and two (the second with the quadratic increment and the
/// two-sample terms, whose bias Jacobians cover both increments).
#[test]
fn ins_transition_matches_numerical() {
    let x = start();
    for steps in [1, 2] {
        let a = analytic(&x, steps);
        let base = run(&x, steps);
        let h = 1e-6;
        let mut worst = 0.0f64;
        for j in 0..15 {
            let mut d = [0.0; 15];
            d[j] = h;
            let plus = error(&base, &run(&perturbed(&x, &d), steps));
            d[j] = -h;
            let minus = error(&base, &run(&perturbed(&x, &d), steps));
            for i in 0..15 {
                let num = (plus[i] - minus[i]) / (2.0 * h);
                let err = (num - a[(i, j)]).abs() / (1.0 + a[(i, j)].abs());
                worst = worst.max(err);
            }
        }
        assert!(
            worst < 1e-6,
            "{steps} step(s): worst relative error {worst:e}"
        );
    }
}

/// The INS propagates its covariance with every sample: from a state with no uncertainty the
/// white noise alone grows the velocity variance by `sa^2 t` (plus the rotation noise's tiny share); `set_state` drops it.
#[test]
fn the_ins_carries_its_covariance_and_drops_it_with_a_new_state() {
    let noise = ImuNoise {
        gyro_noise_density: 1e-3,
        accel_noise_density: 2e-2,
        gyro_bias_rw: 0.0,
        accel_bias_rw: 0.0,
        bias_corr_time_s: None,
    };
    let cfg = InsConfig {
        gravity_mps2: G,
        max_dt_s: 0.02,
    };
    let mut ins = Ins::new(cfg, start()).unwrap();
    ins.set_covariance(Some(InsCovariance::new(&Mat15::zeros(), noise).unwrap()));
    for s in samples() {
        ins.propagate(&s).unwrap();
    }
    let p = ins.covariance().unwrap().state_order();
    let t = 9e-3;
    for i in 6..9 {
        let want = noise.accel_noise_density.powi(2) * t;
        assert!(
            (p[(i, i)] - want).abs() < 1e-4 * want,
            "{} vs {want}",
            p[(i, i)]
        );
    }
    // Position: the velocity noise integrated (positive, smaller), rotation: the gyro's.
    assert!(p[(0, 0)] > 0.0 && p[(0, 0)] < p[(6, 6)]);
    assert!((p[(3, 3)] - noise.gyro_noise_density.powi(2) * t).abs() < 1e-3 * p[(3, 3)]);
    assert_eq!(p, p.transpose());
    let st = *ins.state();
    ins.set_state(st).unwrap();
    assert!(ins.covariance().is_none());
}

/// `new` and `state_order` are inverses (the block permutation), and bad input is refused.
#[test]
fn the_state_order_round_trips_and_bad_input_is_refused() {
    let noise = ImuNoise {
        gyro_noise_density: 1e-3,
        accel_noise_density: 2e-2,
        gyro_bias_rw: 1e-5,
        accel_bias_rw: 1e-4,
        bias_corr_time_s: None,
    };
    let mut p = Mat15::zeros();
    for i in 0..15 {
        for k in 0..15 {
            p[(i, k)] = if i == k {
                1.0 + i as f64
            } else {
                0.01 * (i + k) as f64
            };
        }
    }
    let c = InsCovariance::new(&p, noise).unwrap();
    assert_eq!(c.state_order(), p);
    // State block theta (3..6) is the step's dtheta (6..9).
    assert_eq!(c.p[(RT, RT)], p[(3, 3)]);
    assert_eq!(c.p[(RV + 1, RV + 1)], p[(7, 7)]);
    let mut bad = p;
    bad[(2, 2)] = f64::NAN;
    assert_eq!(InsCovariance::new(&bad, noise), Err(Error::NonFinite));
    bad[(2, 2)] = -1.0;
    assert_eq!(InsCovariance::new(&bad, noise), Err(Error::InvalidConfig));
}

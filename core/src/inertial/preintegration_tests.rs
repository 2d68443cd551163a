//! Unit tests of `preintegration`, compiled only with `#[cfg(test)]` (the parent declares the module so).

use super::*;
use crate::inertial::ins::{Ins, InsConfig};

const G: f64 = 9.81;
const NOISE: ImuNoise = ImuNoise::EUROC_ADIS16448;

/// Smooth, non-trivial motion: every gyro and accel axis varies.
fn sample(k: i64) -> ImuSample {
    let t = k as f64 * 0.005;
    ImuSample {
        t_ns: 1_000_000_000 + k * 5_000_000,
        gyro_rps: Vec3::new(
            0.5 * libm::sin(1.3 * t),
            0.3 * libm::cos(0.7 * t),
            0.8 * libm::sin(0.5 * t + 1.0),
        ),
        accel_mps2: Vec3::new(
            1.0 + libm::sin(t),
            0.5 * libm::cos(2.0 * t),
            G + 0.3 * libm::sin(3.0 * t),
        ),
    }
}

fn build(n: i64, bg0: Vec3, ba0: Vec3, noise: ImuNoise) -> Preintegration<256> {
    let mut p =
        Preintegration::<256>::new(noise, PreintConfig::DEFAULT, &sample(0), bg0, ba0).unwrap();
    for k in 1..=n {
        p.push(&sample(k)).unwrap();
    }
    p
}

/// A span over samples `k0..=k1` of [`sample`] with standard deviations `sa`, `sg` over
/// the whole span (rates `sigma^2 T`).
fn span(k0: i64, k1: i64, sa: f64, sg: f64) -> UnmeasuredSpan {
    let (t0_ns, t1_ns) = (sample(k0).t_ns, sample(k1).t_ns);
    let t = (t1_ns - t0_ns) as f64 * 1e-9;
    UnmeasuredSpan {
        t0_ns,
        t1_ns,
        accel_var_per_s: sa * sa * t,
        gyro_var_per_s: sg * sg * t,
    }
}

/// A span over the whole interval adds `sigma^2 T^2` per axis to the velocity and the
/// rotation variances (trace `3 sigma^2 T^2`: the rotations of the steps keep the trace; the
/// rotation block within 2%, `Jr` and `Exp(phi)^T` being near identity per step); declared
/// after the samples or before them gives the same covariance bit for bit, and so does a
/// re-integration or a truncation that keeps the span's samples.
#[test]
fn unmeasured_span_adds_its_variance_and_survives_reintegration() {
    let (n, sa, sg) = (40, 1.0, 0.3);
    let z = Vec3::zeros();
    let plain = build(n, z, z, NOISE);
    let t = (sample(n).t_ns - sample(0).t_ns) as f64 * 1e-9;
    let mut after = build(n, z, z, NOISE);
    after.add_unmeasured(span(0, n, sa, sg)).unwrap();
    let mut before =
        Preintegration::<256>::new(NOISE, PreintConfig::DEFAULT, &sample(0), z, z).unwrap();
    before.add_unmeasured(span(0, n, sa, sg)).unwrap();
    for k in 1..=n {
        before.push(&sample(k)).unwrap();
    }
    assert_eq!(after.covariance(), before.covariance());
    assert_eq!(after.delta_v(), plain.delta_v(), "deltas unchanged");
    let tr =
        |p: &Preintegration<256>, r: usize| (r..r + 3).map(|i| p.covariance()[(i, i)]).sum::<f64>();
    // One kind at a time (an attitude error also spreads into the velocity, through g).
    let mut accel_only = build(n, z, z, NOISE);
    accel_only.add_unmeasured(span(0, n, sa, 0.0)).unwrap();
    let dv = tr(&accel_only, RV) - tr(&plain, RV);
    let expect_v = 3.0 * sa * sa * t * t;
    assert!((dv - expect_v).abs() < 1e-9, "{dv} vs {expect_v}");
    assert_eq!(tr(&accel_only, RT), tr(&plain, RT));
    let mut gyro_only = build(n, z, z, NOISE);
    gyro_only.add_unmeasured(span(0, n, 0.0, sg)).unwrap();
    let dth = tr(&gyro_only, RT) - tr(&plain, RT);
    let expect_th = 3.0 * sg * sg * t * t;
    assert!((dth / expect_th - 1.0).abs() < 0.02, "{dth} vs {expect_th}");
    assert!(tr(&after, RV) > tr(&accel_only, RV));
    assert!(after.unmeasured_velocity_var() > 0.0);
    assert_eq!(plain.unmeasured_velocity_var(), 0.0);

    // Re-integration at other biases equals a fresh build at those biases with the span.
    let (bg, ba) = (Vec3::new(0.01, -0.02, 0.005), Vec3::new(0.1, 0.0, -0.1));
    after.reintegrate(bg, ba).unwrap();
    let mut fresh =
        Preintegration::<256>::new(NOISE, PreintConfig::DEFAULT, &sample(0), bg, ba).unwrap();
    fresh.add_unmeasured(span(0, n, sa, sg)).unwrap();
    for k in 1..=n {
        fresh.push(&sample(k)).unwrap();
    }
    assert_eq!(after.covariance(), fresh.covariance());

    // A span covering part of the interval adds in proportion to its overlap; outside the
    // interval, nothing.
    let mut half = build(n, z, z, NOISE);
    half.add_unmeasured(span(n / 2, n + 100, sa, 0.0)).unwrap();
    let full_span_rate = span(n / 2, n + 100, sa, 0.0).accel_var_per_s;
    let overlap = (sample(n).t_ns - sample(n / 2).t_ns) as f64 * 1e-9;
    let dv = tr(&half, RV) - tr(&plain, RV);
    assert!((dv - 3.0 * full_span_rate * overlap).abs() < 1e-9, "{dv}");
    let mut outside = build(n, z, z, NOISE);
    outside
        .add_unmeasured(span(n + 10, n + 20, sa, sg))
        .unwrap();
    assert_eq!(outside.covariance(), plain.covariance());
}

/// Bad spans are refused and change nothing; more than [`MAX_UNMEASURED`] do not fit; a
/// restart forgets the spans.
#[test]
fn unmeasured_spans_are_checked_bounded_and_cleared() {
    let z = Vec3::zeros();
    let mut p = build(10, z, z, NOISE);
    let cov = *p.covariance();
    let mut bad = span(0, 10, 1.0, 0.3);
    bad.accel_var_per_s = f64::NAN;
    assert_eq!(p.add_unmeasured(bad), Err(Error::InvalidConfig));
    let mut empty = span(0, 10, 1.0, 0.3);
    empty.t1_ns = empty.t0_ns;
    assert_eq!(p.add_unmeasured(empty), Err(Error::InvalidConfig));
    assert_eq!(*p.covariance(), cov);
    for k in 0..MAX_UNMEASURED as i64 {
        p.add_unmeasured(span(k, k + 1, 1.0, 0.3)).unwrap();
    }
    let full = *p.covariance();
    assert_eq!(
        p.add_unmeasured(span(5, 6, 1.0, 0.3)),
        Err(Error::CapacityExceeded)
    );
    assert_eq!(*p.covariance(), full);
    p.reset(&sample(10), z, z).unwrap();
    assert!(p.unmeasured().is_empty());
}

fn states() -> (NavState, NavState) {
    let xi = NavState {
        t_ns: 0,
        p_wb: Vec3::new(1.0, -2.0, 0.5),
        q_wb: quat_exp(&Vec3::new(0.3, -0.2, 1.0)),
        v_wb: Vec3::new(0.5, 0.2, -0.1),
        bg: Vec3::new(0.004, -0.003, 0.002),
        ba: Vec3::new(0.05, -0.04, 0.03),
    };
    let xj = NavState {
        t_ns: 0,
        p_wb: Vec3::new(1.3, -1.9, 0.45),
        q_wb: quat_exp(&Vec3::new(0.35, -0.1, 1.2)),
        v_wb: Vec3::new(0.6, 0.1, 0.0),
        bg: Vec3::new(0.0045, -0.0028, 0.0021),
        ba: Vec3::new(0.052, -0.041, 0.028),
    };
    (xi, xj)
}

#[test]
fn cached_whitening_is_bit_identical_and_invalidated_by_new_samples() {
    let mut p = build(50, Vec3::zeros(), Vec3::zeros(), NOISE);
    let (xi, xj) = states();
    let eval = |p: &Preintegration<256>| {
        let (mut r, mut a, mut b) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        p.evaluate(&xi, &xj, 9.81, &mut r, &mut a, &mut b).unwrap();
        (r, a, b)
    };
    let plain = eval(&p);
    p.cache_whitening().unwrap();
    assert_eq!(eval(&p), plain);
    // A new sample changes the covariance: the cache must not be used any more.
    p.push(&sample(51)).unwrap();
    let after_push = eval(&p);
    let mut q = p.clone();
    q.cache_whitening().unwrap();
    assert_eq!(eval(&q), after_push);
    assert_ne!(after_push.0, plain.0);
}

#[test]
fn bias_jacobians_match_reintegration() {
    let (bg0, ba0) = (Vec3::new(0.01, -0.02, 0.005), Vec3::new(0.1, -0.05, 0.2));
    let p = build(120, bg0, ba0, NOISE);
    let (jpg, jpa, jvg, jva, jrg) = p.bias_jacobians();
    let h = 1e-6;
    let mut q = p.clone();
    for c in 0..3 {
        let mut e = Vec3::zeros();
        e[c] = h;
        let mut diff = |dbg: Vec3, dba: Vec3| {
            q.reintegrate(bg0 + dbg, ba0 + dba).unwrap();
            let (pp, vp, rp) = (q.dp, q.dv, log_so3(&(p.dq.inverse() * q.dq)));
            q.reintegrate(bg0 - dbg, ba0 - dba).unwrap();
            let (pm, vm, rm) = (q.dp, q.dv, log_so3(&(p.dq.inverse() * q.dq)));
            (
                (pp - pm) / (2.0 * h),
                (vp - vm) / (2.0 * h),
                (rp - rm) / (2.0 * h),
            )
        };
        let (np, nv, nr) = diff(e, Vec3::zeros());
        assert!((np - jpg.column(c)).norm() < 1e-7, "dp/dbg col {c}");
        assert!((nv - jvg.column(c)).norm() < 1e-7, "dv/dbg col {c}");
        assert!((nr - jrg.column(c)).norm() < 1e-7, "dR/dbg col {c}");
        let (np, nv, nr) = diff(Vec3::zeros(), e);
        assert!((np - jpa.column(c)).norm() < 1e-7, "dp/dba col {c}");
        assert!((nv - jva.column(c)).norm() < 1e-7, "dv/dba col {c}");
        assert!(nr.norm() < 1e-9, "dR/dba col {c}");
    }
    // The rotation Jacobian is about -T I for small rotations: a gross sanity bound.
    assert!(jrg.trace() < -1.2 && jrg.trace() > -1.8, "{jrg:?}");
}

/// An INS run from `xi` with the same samples and biases lands exactly where the
/// preintegration predicts: the residual vanishes to rounding.
#[test]
fn residual_vanishes_on_ins_propagation() {
    let (mut xi, _) = states();
    xi.t_ns = sample(0).t_ns;
    let p = build(160, xi.bg, xi.ba, NOISE);
    let mut ins = Ins::new(
        InsConfig {
            gravity_mps2: G,
            max_dt_s: 0.05,
        },
        xi,
    )
    .unwrap();
    for k in 0..=160 {
        ins.propagate(&sample(k)).unwrap();
    }
    let xj = *ins.state();
    let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
    p.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj)
        .unwrap();
    assert!(r.norm() < 1e-12, "residual {r:?}");
    // The motion is real: the body moved and turned.
    assert!((xj.p_wb - xi.p_wb).norm() > 0.3);
    assert!(log_so3(p.delta_q()).norm() > 0.1);
}

#[test]
fn whitening_gives_mahalanobis_norm() {
    let p = build(100, Vec3::zeros(), Vec3::zeros(), NOISE);
    let (xi, xj) = states();
    let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
    p.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj)
        .unwrap();
    let (r0, ji0) = (r, ji);
    p.evaluate(&xi, &xj, G, &mut r, &mut ji, &mut jj).unwrap();
    let pinv = p.covariance().try_inverse().unwrap();
    let maha = (r0.transpose() * pinv * r0)[(0, 0)];
    assert!((r.norm_squared() - maha).abs() < 1e-8 * maha);
    let info = ji0.transpose() * pinv * ji0;
    let info_w = ji.transpose() * ji;
    assert!((info - info_w).norm() < 1e-7 * info.norm());
    // The cost-only path whitens the residual identically.
    assert_eq!(p.residual_whitened(&xi, &xj, G).unwrap(), r);
    // Covariance sanity: symmetric, velocity variance ~ sa^2 T.
    assert_eq!(*p.covariance(), p.covariance().transpose());
    let var_v = p.covariance()[(RV, RV)];
    let expect = NOISE.accel_noise_density * NOISE.accel_noise_density * 0.5;
    assert!(
        var_v > 0.9 * expect && var_v < 1.5 * expect,
        "{var_v} vs {expect}"
    );
}

#[test]
fn zero_noise_is_not_positive_definite() {
    let zero = ImuNoise {
        gyro_noise_density: 0.0,
        accel_noise_density: 0.0,
        gyro_bias_rw: 0.0,
        accel_bias_rw: 0.0,
        bias_corr_time_s: None,
    };
    let p = build(10, Vec3::zeros(), Vec3::zeros(), zero);
    let (xi, xj) = states();
    let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
    assert_eq!(
        p.evaluate(&xi, &xj, G, &mut r, &mut ji, &mut jj),
        Err(Error::NotPositiveDefinite)
    );
    // Nothing integrated yet: no measurement.
    let p0 = build(0, Vec3::zeros(), Vec3::zeros(), NOISE);
    assert_eq!(
        p0.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj),
        Err(Error::NotEnoughData)
    );
}

#[test]
fn capacity_exceeded_leaves_preintegration_intact() {
    let mut p = Preintegration::<8>::new(
        NOISE,
        PreintConfig::DEFAULT,
        &sample(0),
        Vec3::zeros(),
        Vec3::zeros(),
    )
    .unwrap();
    for k in 1..8 {
        p.push(&sample(k)).unwrap();
    }
    let (dp, cov, t_end) = (*p.delta_p(), *p.covariance(), p.t_end_ns());
    assert_eq!(p.push(&sample(8)), Err(Error::CapacityExceeded));
    assert_eq!(
        (*p.delta_p(), *p.covariance(), p.t_end_ns()),
        (dp, cov, t_end)
    );
    assert_eq!(p.len(), 8);
    // Re-integration of the full buffer reproduces the deltas bit for bit.
    p.reintegrate(Vec3::zeros(), Vec3::zeros()).unwrap();
    assert_eq!(*p.delta_p(), dp);
    assert_eq!(*p.covariance(), cov);
    // The caller starts the next keyframe at the last sample and continues.
    p.reset(&sample(7), Vec3::zeros(), Vec3::zeros()).unwrap();
    p.push(&sample(8)).unwrap();
    assert_eq!(p.t_start_ns(), sample(7).t_ns);
}

#[test]
fn rejects_bad_samples_and_reintegrates_past_threshold() {
    let mut p = build(20, Vec3::zeros(), Vec3::zeros(), NOISE);
    let (dp, cov) = (*p.delta_p(), *p.covariance());
    let mut bad = sample(21);
    bad.accel_mps2.y = f64::NAN;
    assert_eq!(p.push(&bad), Err(Error::NonFinite));
    assert_eq!(p.push(&sample(20)), Err(Error::TimeNotIncreasing));
    assert_eq!(p.push(&sample(40)), Err(Error::TimeGap));
    assert_eq!((*p.delta_p(), *p.covariance()), (dp, cov));

    let small = Vec3::new(5e-4, 0.0, 0.0);
    assert!(!p.update_linearization(&small, &Vec3::zeros()).unwrap());
    assert_eq!(p.linearization_bias().0, Vec3::zeros());
    let big = Vec3::new(2e-3, 0.0, 0.0);
    // Before re-integration the first-order correction predicts the new deltas closely.
    let (dp_c, _, _) = p.corrected(&big, &Vec3::zeros());
    assert!(p.update_linearization(&big, &Vec3::zeros()).unwrap());
    assert_eq!(p.linearization_bias().0, big);
    assert!((*p.delta_p() - dp_c).norm() < 1e-9);
    assert!((*p.delta_p() - dp).norm() > 1e-8);
}

//! Inverse-depth reprojection factor (BA baseline): exact-data zero residual, numerical Jacobians.

mod numdiff;
mod vision_common;

use nalgebra::{Matrix2x6, SMatrix};
use numdiff::num_jac;
use povins_core::camera::{CameraExtrinsic, Vec2};
use povins_core::factors::inverse_depth_visual::InverseDepthVisualFactor;
use povins_core::factors::{sqrt_info_from_pixels, KeyframePose, TimedObs};
use povins_core::math::Vec3;
use povins_core::Error;
use vision_common::*;

fn setup(
    rng: &mut Rng,
    noise: f64,
) -> (
    InverseDepthVisualFactor,
    KeyframePose,
    KeyframePose,
    CameraExtrinsic,
    f64,
) {
    let s = random_pose(rng, 0.003);
    let j = random_pose(rng, -0.004);
    let ext = euroc_extrinsic();
    let p_w = Vec3::new(
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
        rng.range(4.0, 9.0),
    );
    let mut mk = |kf: &KeyframePose| {
        let vel = Vec2::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5));
        let td0 = rng.range(-0.01, 0.01);
        let n = Vec2::new(rng.normal(), rng.normal()) * noise;
        TimedObs {
            x_n: observe(kf, &ext, &p_w) + vel * (kf.td - td0) + n,
            vel,
            td0,
        }
    };
    let f = InverseDepthVisualFactor {
        kf_s: 1,
        kf_j: 2,
        obs_s: mk(&s),
        obs_j: mk(&j),
        sqrt_info: sqrt_info_from_pixels(&Vec2::new(458.654, 457.296), 1.5).unwrap(),
    };
    let tau = 1.0 / depth_in(&s, &ext, &p_w);
    (f, s, j, ext, tau)
}

#[test]
fn residual_is_zero_for_exact_observations_and_true_depth() {
    let mut rng = Rng::new(20);
    for _ in 0..50 {
        let (f, s, j, ext, tau) = setup(&mut rng, 0.0);
        assert!(f.residual(&s, &j, &ext, tau).unwrap().amax() < 1e-8);
        // 10 % depth error is visible.
        assert!(f.residual(&s, &j, &ext, tau * 1.1).unwrap().amax() > 0.05);
    }
}

#[test]
fn jacobians_match_numerical() {
    let mut rng = Rng::new(21);
    let h = 1e-6;
    for _ in 0..30 {
        let (f, s, j, ext, tau) = setup(&mut rng, 3e-3);
        let tau = tau * 1.05;
        let jac = f.evaluate(&s, &j, &ext, tau).unwrap();
        let (r, dtau) = f.residual_and_d_tau(&s, &j, &ext, tau).unwrap();
        assert_eq!(r, jac.r);
        assert_eq!(dtau, jac.d_tau);
        let res = |s: &KeyframePose, j: &KeyframePose, x: &CameraExtrinsic, t: f64| {
            f.residual(s, j, x, t).unwrap()
        };
        let blocks: [(&str, Matrix2x6<f64>, Matrix2x6<f64>); 3] = [
            (
                "pose s",
                jac.d_pose_s,
                num_jac::<2, 6>(h, |d| res(&perturb_pose(&s, d), &j, &ext, tau)),
            ),
            (
                "pose j",
                jac.d_pose_j,
                num_jac::<2, 6>(h, |d| res(&s, &perturb_pose(&j, d), &ext, tau)),
            ),
            (
                "extrinsic",
                jac.d_ext,
                num_jac::<2, 6>(h, |d| res(&s, &j, &perturb_ext(&ext, d), tau)),
            ),
        ];
        for (name, a, n) in blocks {
            assert!(rel_err(&a, &n) < 1e-6, "{name}\n{a}\n{n}");
        }
        let n_tau: SMatrix<f64, 2, 1> = num_jac::<2, 1>(1e-7, |d| res(&s, &j, &ext, tau + d[0]));
        assert!(rel_err(&jac.d_tau, &n_tau) < 1e-6, "{} {n_tau}", jac.d_tau);
        let n_tds: SMatrix<f64, 2, 1> = num_jac::<2, 1>(h, |d| {
            let mut s2 = s;
            s2.td += d[0];
            res(&s2, &j, &ext, tau)
        });
        let n_tdj: SMatrix<f64, 2, 1> = num_jac::<2, 1>(h, |d| {
            let mut j2 = j;
            j2.td += d[0];
            res(&s, &j2, &ext, tau)
        });
        assert!(rel_err(&jac.d_td[0], &n_tds) < 1e-6);
        assert!(rel_err(&jac.d_td[1], &n_tdj) < 1e-6);
        assert!(jac.d_td[0].amax() > 1e-3 && jac.d_td[1].amax() > 1e-3);
    }
}

#[test]
fn misuse_is_an_error() {
    let mut rng = Rng::new(22);
    let (f, s, j, ext, tau) = setup(&mut rng, 0.0);
    let same = InverseDepthVisualFactor { kf_j: f.kf_s, ..f };
    assert_eq!(same.residual(&s, &j, &ext, tau), Err(Error::Degenerate));
    assert_eq!(f.residual(&s, &j, &ext, -tau), Err(Error::Degenerate));
    assert_eq!(f.residual(&s, &j, &ext, 0.0), Err(Error::Degenerate));
    assert_eq!(f.residual(&s, &j, &ext, f64::NAN), Err(Error::NonFinite));
}

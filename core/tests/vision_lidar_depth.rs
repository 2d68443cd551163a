//! LiDAR-depth measurements: direct LDM Jacobians; MSC-based LDM (tau* solve, nullspace
//! projection, Schur-complement equivalence, Jacobians of the whole projected residual).

mod numdiff;
mod vision_common;

use nalgebra::{RowVector6, SMatrix, SVector};
use numdiff::num_jac;
use povins_core::camera::{CameraExtrinsic, Vec2};
use povins_core::factors::inverse_depth_visual::InverseDepthVisualFactor;
use povins_core::factors::lidar_depth::{DirectLidarDepthFactor, MscLidarDepth};
use povins_core::factors::{sqrt_info_from_pixels, KeyframePose, TimedObs};
use povins_core::math::Vec3;
use povins_core::Error;
use vision_common::*;

const SIGMA_DR: f64 = 0.1;

fn sqrt_info() -> Vec2 {
    sqrt_info_from_pixels(&Vec2::new(458.654, 457.296), 1.5).unwrap()
}

fn obs(
    rng: &mut Rng,
    kf: &KeyframePose,
    ext: &CameraExtrinsic,
    p_w: &Vec3,
    noise: f64,
) -> TimedObs {
    let vel = Vec2::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5));
    let td0 = rng.range(-0.01, 0.01);
    let n = Vec2::new(rng.normal(), rng.normal()) * noise;
    TimedObs {
        x_n: observe(kf, ext, p_w) + vel * (kf.td - td0) + n,
        vel,
        td0,
    }
}

// ---------------------------------------------------------------- direct LDM

#[test]
fn direct_ldm_residual_and_jacobians() {
    let mut rng = Rng::new(30);
    let h = 1e-6;
    for i in 0..30 {
        let ext = euroc_extrinsic();
        let s = random_pose(&mut rng, 0.002);
        let e = random_pose(&mut rng, -0.003);
        let p_w = Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(4.0, 9.0),
        );
        let noise = if i == 0 { 0.0 } else { 2e-3 };
        let depth = depth_in(&s, &ext, &p_w);
        let f = DirectLidarDepthFactor {
            kf_s: 0,
            kf_e: 4,
            obs_s: obs(&mut rng, &s, &ext, &p_w, noise),
            obs_e: obs(&mut rng, &e, &ext, &p_w, noise),
            d_r: depth + 0.05,
            sigma_dr: SIGMA_DR,
        };
        let jac = f.evaluate(&s, &e, &ext).unwrap();
        if noise == 0.0 {
            assert!((jac.r - (-0.05 / SIGMA_DR)).abs() < 1e-8, "{}", jac.r);
        }
        let res = |s: &KeyframePose, e: &KeyframePose, x: &CameraExtrinsic| {
            SVector::<f64, 1>::new(f.evaluate(s, e, x).unwrap().r)
        };
        let ns = num_jac::<1, 6>(h, |d| res(&perturb_pose(&s, d), &e, &ext));
        let ne = num_jac::<1, 6>(h, |d| res(&s, &perturb_pose(&e, d), &ext));
        let nx = num_jac::<1, 6>(h, |d| res(&s, &e, &perturb_ext(&ext, d)));
        for (name, a, n) in [
            ("pose s", jac.d_pose_s, ns),
            ("pose e", jac.d_pose_e, ne),
            ("ext", jac.d_ext, nx),
        ] {
            assert!(rel_err(&a, &n) < 1e-6, "{name}\n{a}\n{n}");
        }
        let tds = num_jac::<1, 1>(h, |d| {
            let mut s2 = s;
            s2.td += d[0];
            res(&s2, &e, &ext)
        })[0];
        let tde = num_jac::<1, 1>(h, |d| {
            let mut e2 = e;
            e2.td += d[0];
            res(&s, &e2, &ext)
        })[0];
        assert!((jac.d_td[0] - tds).abs() < 1e-6 * tds.abs().max(1.0));
        assert!((jac.d_td[1] - tde).abs() < 1e-6 * tde.abs().max(1.0));
    }
}

#[test]
fn direct_ldm_errors() {
    let mut rng = Rng::new(31);
    let ext = euroc_extrinsic();
    let s = random_pose(&mut rng, 0.0);
    let e = random_pose(&mut rng, 0.0);
    let p_w = Vec3::new(0.2, 0.1, 6.0);
    let f = DirectLidarDepthFactor {
        kf_s: 0,
        kf_e: 0,
        obs_s: obs(&mut rng, &s, &ext, &p_w, 0.0),
        obs_e: obs(&mut rng, &e, &ext, &p_w, 0.0),
        d_r: 6.0,
        sigma_dr: SIGMA_DR,
    };
    assert_eq!(
        f.evaluate(&s, &e, &ext).map(|j| j.r),
        Err(Error::Degenerate)
    );
    let f = DirectLidarDepthFactor {
        kf_e: 1,
        sigma_dr: 0.0,
        ..f
    };
    assert_eq!(
        f.evaluate(&s, &e, &ext).map(|j| j.r),
        Err(Error::InvalidConfig)
    );
}

// ---------------------------------------------------------------- MSC LDM

const NOBS: usize = 3;
/// Capacity larger than used, so unused blocks are exercised too.
const CAP: usize = 5;
/// Columns: pose s (6), poses j (6 each), extrinsic (6), td_s, td_j.
const NCOL: usize = 6 + 6 * NOBS + 6 + 1 + NOBS;
const NROW: usize = 2 * NOBS;

#[derive(Clone, Copy)]
struct State {
    s: KeyframePose,
    js: [KeyframePose; NOBS],
    ext: CameraExtrinsic,
}

fn perturb(st: &State, d: &[f64; NCOL]) -> State {
    let six = |o: usize| -> [f64; 6] { core::array::from_fn(|i| d[o + i]) };
    let mut out = *st;
    out.s = perturb_pose(&st.s, &six(0));
    out.s.td += d[12 + 6 * NOBS];
    for k in 0..NOBS {
        out.js[k] = perturb_pose(&st.js[k], &six(6 + 6 * k));
        out.js[k].td += d[13 + 6 * NOBS + k];
    }
    out.ext = perturb_ext(&st.ext, &six(6 + 6 * NOBS));
    out
}

/// Projected Jacobian as a dense matrix in the column order above.
fn dense(m: &MscLidarDepth<CAP>) -> (SVector<f64, NROW>, SMatrix<f64, NROW, NCOL>) {
    let mut e = SVector::<f64, NROW>::zeros();
    let mut j = SMatrix::<f64, NROW, NCOL>::zeros();
    let rows: Vec<_> = m.rows().collect();
    assert_eq!(rows.len(), NROW);
    for (i, row) in rows.iter().enumerate() {
        e[i] = row.r;
        let put = |j: &mut SMatrix<f64, NROW, NCOL>, o: usize, b: &RowVector6<f64>| {
            for c in 0..6 {
                j[(i, o + c)] = b[c];
            }
        };
        put(&mut j, 0, &row.d_pose_s);
        for k in 0..NOBS {
            put(&mut j, 6 + 6 * k, &row.d_pose_j[k]);
            j[(i, 13 + 6 * NOBS + k)] = row.d_td_j[k];
        }
        for k in NOBS..CAP {
            assert_eq!(row.d_pose_j[k], RowVector6::zeros());
            assert_eq!(row.d_td_j[k], 0.0);
        }
        put(&mut j, 6 + 6 * NOBS, &row.d_ext);
        j[(i, 12 + 6 * NOBS)] = row.d_td_s;
    }
    (e, j)
}

fn scene(rng: &mut Rng, noise: f64, d_r_offset: f64) -> (State, MscLidarDepth<CAP>, f64) {
    let ext = euroc_extrinsic();
    let s = random_pose(rng, 0.002);
    let js: [KeyframePose; NOBS] = core::array::from_fn(|_| {
        let td = rng.range(-0.005, 0.005);
        random_pose(rng, td)
    });
    let p_w = Vec3::new(
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
        rng.range(4.0, 9.0),
    );
    let depth = depth_in(&s, &ext, &p_w);
    let obs_s = obs(rng, &s, &ext, &p_w, noise);
    let mut m =
        MscLidarDepth::<CAP>::new(0, obs_s, depth + d_r_offset, SIGMA_DR, sqrt_info()).unwrap();
    for (k, j) in js.iter().enumerate() {
        let o = obs(rng, j, &ext, &p_w, noise);
        m.push(10 + k, o).unwrap();
    }
    (State { s, js, ext }, m, depth)
}

fn linearized(m: &MscLidarDepth<CAP>, st: &State) -> MscLidarDepth<CAP> {
    let mut m2 = m.clone();
    m2.linearize(&st.s, &st.js, &st.ext).unwrap();
    m2
}

#[test]
fn msc_exact_data_solves_depth_and_has_zero_residual() {
    let mut rng = Rng::new(40);
    for _ in 0..20 {
        let (st, mut m, depth) = scene(&mut rng, 0.0, 0.0);
        m.set_tau(1.0 / (depth * 1.3)); // start 30 % off
        m.linearize(&st.s, &st.js, &st.ext).unwrap();
        assert!(
            (1.0 / m.tau() - depth).abs() < 1e-9 * depth,
            "{} vs {depth}",
            1.0 / m.tau()
        );
        assert!(m.projected_cost() < 1e-16, "{}", m.projected_cost());
    }
}

#[test]
fn msc_jacobians_match_numerical_including_tau_resolve() {
    // Exact observations and LiDAR depth, so e(tau*) = 0 and the projected Jacobian is the full
    // derivative of the projected residual (the change of the nullspace basis multiplies e).
    // The noisy case is covered by the gradient test below, which is exact for any residual.
    let mut rng = Rng::new(41);
    let h = 1e-6;
    for _ in 0..10 {
        let (st, m, _) = scene(&mut rng, 0.0, 0.0);
        let (_, ja) = dense(&linearized(&m, &st));
        let jn = num_jac::<NROW, NCOL>(h, |d| dense(&linearized(&m, &perturb(&st, d))).0);
        let err = rel_err(&ja, &jn);
        assert!(err < 1e-6, "rel err {err:e}\n{ja}\n{jn}");
        // Every pose block is informative.
        assert!(ja.columns(0, 6).amax() > 1.0);
        for k in 0..NOBS {
            assert!(ja.columns(6 + 6 * k, 6).amax() > 1.0);
        }
    }
}

/// Reduced cost `min_tau |e(tau)|^2` by golden-section search, independent of the GN solve.
fn brute_min_cost(m: &MscLidarDepth<CAP>, st: &State, tau0: f64) -> (f64, f64) {
    let cost = |t: f64| m.stacked_cost(&st.s, &st.js, &st.ext, t).unwrap();
    let (mut a, mut b) = (tau0 * 0.5, tau0 * 2.0);
    let g = (libm::sqrt(5.0) - 1.0) / 2.0;
    for _ in 0..200 {
        let c = b - g * (b - a);
        let d = a + g * (b - a);
        if cost(c) < cost(d) {
            b = d;
        } else {
            a = c;
        }
    }
    let t = 0.5 * (a + b);
    (t, cost(t))
}

#[test]
fn msc_projection_is_the_schur_complement() {
    let mut rng = Rng::new(42);
    for _ in 0..20 {
        // Pixel noise and a LiDAR depth 0.15 m off: the residual is far from zero.
        let (st, m, _) = scene(&mut rng, 2e-3, 0.15);
        let ml = linearized(&m, &st);
        let tau = ml.tau();
        let (e0, j0) = dense(&ml);

        // 1) |e0|^2 equals the minimum of the stacked cost over tau.
        let (tau_b, c_b) = brute_min_cost(&m, &st, tau);
        assert!((tau_b - tau).abs() < 1e-7 * tau, "{tau_b} vs {tau}");
        let c0 = e0.norm_squared();
        assert!(c0 > 1.0, "the test needs a real residual: {c0}");
        assert!((c0 - c_b).abs() < 1e-9 * c_b, "{c0} vs {c_b}");

        // 2) Rows are orthogonal to J_tau, the pivot row holds all of it, and the rotations are
        //    orthonormal (residual norm preserved; pivot residual = J_tau.e/|J_tau| = 0 at tau*).
        let pivot = ml.pivot_row();
        for row in ml.rows() {
            assert!(row.d_tau.abs() < 1e-12 * pivot.d_tau.abs(), "{}", row.d_tau);
        }
        let full = ml.stacked_cost(&st.s, &st.js, &st.ext, tau).unwrap();
        assert!((c0 + pivot.r * pivot.r - full).abs() < 1e-10 * full);
        assert!(pivot.r.abs() < 1e-6, "{}", pivot.r);

        // 3) J0^T J0 and J0^T e0 equal the Schur complement of tau in the stacked system built
        //    independently from the inverse-depth factor.
        let mut e = SVector::<f64, { NROW + 1 }>::zeros();
        let mut jy = SMatrix::<f64, { NROW + 1 }, NCOL>::zeros();
        let mut jt = SVector::<f64, { NROW + 1 }>::zeros();
        for k in 0..NOBS {
            let f = InverseDepthVisualFactor {
                kf_s: 0,
                kf_j: 10 + k,
                obs_s: m.obs_s,
                obs_j: obs_of(&m, &st, k),
                sqrt_info: sqrt_info(),
            };
            let jac = f.evaluate(&st.s, &st.js[k], &st.ext, tau).unwrap();
            for i in 0..2 {
                let r = 2 * k + i;
                e[r] = jac.r[i];
                jt[r] = jac.d_tau[i];
                for c in 0..6 {
                    jy[(r, c)] = jac.d_pose_s[(i, c)];
                    jy[(r, 6 + 6 * k + c)] = jac.d_pose_j[(i, c)];
                    jy[(r, 6 + 6 * NOBS + c)] = jac.d_ext[(i, c)];
                }
                jy[(r, 12 + 6 * NOBS)] = jac.d_td[0][i];
                jy[(r, 13 + 6 * NOBS + k)] = jac.d_td[1][i];
            }
        }
        e[NROW] = (1.0 / tau - m.d_r) / SIGMA_DR;
        jt[NROW] = -1.0 / (tau * tau * SIGMA_DR);
        let p = SMatrix::<f64, { NROW + 1 }, { NROW + 1 }>::identity()
            - jt * jt.transpose() / jt.norm_squared();
        let h_schur = jy.transpose() * p * jy;
        let g_schur = jy.transpose() * p * e;
        let h0 = j0.transpose() * j0;
        let g0 = j0.transpose() * e0;
        assert!(rel_err(&h0, &h_schur) < 1e-9, "H");
        assert!(rel_err(&g0, &g_schur) < 1e-9, "g");
    }
}

#[test]
fn msc_gradient_is_exact_for_the_reduced_cost_with_noise() {
    // Variable projection: d/dY [min_tau |e|^2 / 2] = J_Y^T e(tau*) = J0^T e0 exactly, even when
    // the residual is large (where J0 itself ignores the change of the nullspace basis).
    let mut rng = Rng::new(43);
    for _ in 0..10 {
        let (st, m, _) = scene(&mut rng, 2e-3, 0.15);
        let (e0, j0) = dense(&linearized(&m, &st));
        let g0 = j0.transpose() * e0;
        let gn = num_jac::<1, NCOL>(1e-6, |d| {
            SVector::<f64, 1>::new(0.5 * linearized(&m, &perturb(&st, d)).projected_cost())
        })
        .transpose();
        let err = rel_err(&g0, &gn);
        assert!(err < 1e-6, "rel err {err:e}\n{g0}\n{gn}");
        // For information: how far the plain Jacobian is from the full derivative here.
        let jn = num_jac::<NROW, NCOL>(1e-6, |d| dense(&linearized(&m, &perturb(&st, d))).0);
        println!(
            "noisy case: |J0 - dnum e0/dY|max / |J0|max = {:.2e}",
            rel_err(&j0, &jn)
        );
    }
}

#[test]
fn msc_misuse_is_an_error() {
    let mut rng = Rng::new(44);
    let (st, mut m, _) = scene(&mut rng, 0.0, 0.0);
    assert_eq!(m.push(0, m.obs_s), Err(Error::Degenerate));
    assert_eq!(m.push(10, m.obs_s), Err(Error::Degenerate));
    m.push(20, m.obs_s).unwrap();
    m.push(21, m.obs_s).unwrap();
    assert_eq!(m.push(22, m.obs_s), Err(Error::CapacityExceeded));
    assert_eq!(m.len(), CAP);
    assert_eq!(
        m.linearize(&st.s, &st.js, &st.ext),
        Err(Error::InvalidConfig)
    );
    assert!(MscLidarDepth::<CAP>::new(0, m.obs_s, -1.0, SIGMA_DR, sqrt_info()).is_err());
    let mut empty = MscLidarDepth::<CAP>::new(0, m.obs_s, 5.0, SIGMA_DR, sqrt_info()).unwrap();
    assert_eq!(
        empty.linearize(&st.s, &[], &st.ext),
        Err(Error::NotEnoughData)
    );
}

fn obs_of(m: &MscLidarDepth<CAP>, _st: &State, k: usize) -> TimedObs {
    m.observations()[k]
}

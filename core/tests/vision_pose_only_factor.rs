//! Pose-only visual reprojection factor: zero residual on exact data, every Jacobian block against
//! central differences (distinct j, j == e, time delays, extrinsic), scale-free vs explicit form.

mod numdiff;
mod vision_common;

use nalgebra::{Matrix2x6, SMatrix};
use numdiff::num_jac;
use povins_core::camera::{CameraExtrinsic, Vec2};
use povins_core::factors::pose_only_visual::{PoseOnlyAnchors, PoseOnlyVisualFactor};
use povins_core::factors::{sqrt_info_from_pixels, CamFrame, KeyframePose, TimedObs};
use povins_core::landmarks::pose_only_depth;
use povins_core::math::Vec3;
use povins_core::Error;
use vision_common::*;

const SIGMA_PX: f64 = 1.5;

fn sqrt_info() -> Vec2 {
    sqrt_info_from_pixels(&Vec2::new(458.654, 457.296), SIGMA_PX).unwrap()
}

struct Setup {
    s: KeyframePose,
    e: KeyframePose,
    j: KeyframePose,
    ext: CameraExtrinsic,
    p_w: Vec3,
}

fn setup(rng: &mut Rng) -> Setup {
    Setup {
        s: random_pose(rng, 0.004),
        e: random_pose(rng, -0.002),
        j: random_pose(rng, 0.001),
        ext: euroc_extrinsic(),
        p_w: Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(5.0, 9.0),
        ),
    }
}

/// Observation of `p_w` from `kf` that is exact after the time-delay correction at `kf.td`, with
/// feature velocity `vel` and extraction delay `td0`, plus optional noise (normalized units).
fn timed_obs(
    kf: &KeyframePose,
    ext: &CameraExtrinsic,
    p_w: &Vec3,
    vel: Vec2,
    td0: f64,
    noise: Vec2,
) -> TimedObs {
    let x = observe(kf, ext, p_w);
    TimedObs {
        x_n: x + vel * (kf.td - td0) + noise,
        vel,
        td0,
    }
}

fn factor(st: &Setup, rng: &mut Rng, noise: f64, j_is_e: bool) -> PoseOnlyVisualFactor {
    let mut mk = |kf: &KeyframePose| {
        let vel = Vec2::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5));
        let n = Vec2::new(rng.normal(), rng.normal()) * noise;
        timed_obs(kf, &st.ext, &st.p_w, vel, rng.range(-0.01, 0.01), n)
    };
    let obs_s = mk(&st.s);
    let obs_e = mk(&st.e);
    let obs_j = if j_is_e { obs_e } else { mk(&st.j) };
    PoseOnlyVisualFactor {
        kf_s: 3,
        kf_e: 7,
        kf_j: if j_is_e { 7 } else { 5 },
        obs_s,
        obs_e,
        obs_j,
        sqrt_info: sqrt_info(),
    }
}

#[test]
fn residual_is_zero_for_exact_observations() {
    let mut rng = Rng::new(10);
    for _ in 0..50 {
        let st = setup(&mut rng);
        for j_is_e in [false, true] {
            let f = factor(&st, &mut rng, 0.0, j_is_e);
            let r = f.residual(&st.s, &st.e, &st.j, &st.ext).unwrap();
            assert!(r.amax() < 1e-8, "{r}");
            // A wrong time delay on j must show up (velocity ~0.3/s, 20 ms -> ~6e-3 -> ~1.8 sigma).
            let mut j2 = if j_is_e { st.e } else { st.j };
            j2.td += 0.02;
            let (e2, jj) = if j_is_e { (j2, j2) } else { (st.e, j2) };
            let r2 = f.residual(&st.s, &e2, &jj, &st.ext).unwrap();
            assert!(r2.amax() > 1e-3, "{r2}");
        }
    }
}

#[test]
fn scale_free_form_equals_explicit_depth_form() {
    let mut rng = Rng::new(11);
    for _ in 0..50 {
        let st = setup(&mut rng);
        let f = factor(&st, &mut rng, 2e-3, false);
        let r = f.residual(&st.s, &st.e, &st.j, &st.ext).unwrap();
        // Explicit: d_s from the two anchors, then P_j = d_s R_js x_s + t_js.
        let cs = st.ext.camera_pose(&st.s.p_wb, &st.s.q_wb);
        let ce = st.ext.camera_pose(&st.e.p_wb, &st.e.q_wb);
        let cj = st.ext.camera_pose(&st.j.p_wb, &st.j.q_wb);
        let x_s = f.obs_s.corrected(st.s.td);
        let x_e = f.obs_e.corrected(st.e.td);
        let x_j = f.obs_j.corrected(st.j.td);
        let (r_es, t_es) = ce.relative_from(&cs);
        let (r_js, t_js) = cj.relative_from(&cs);
        let d = pose_only_depth(&x_s, &x_e, &r_es, &t_es, 0.0).unwrap();
        let p_j = r_js * x_s * d.d_s + t_js;
        let explicit =
            (Vec2::new(p_j.x / p_j.z, p_j.y / p_j.z) - x_j.xy()).component_mul(&sqrt_info());
        assert!((r - explicit).amax() < 1e-9, "{r} vs {explicit}");
        assert!(r.amax() > 0.1, "noise should give a visible residual: {r}");
    }
}

fn check(name: &str, a: &Matrix2x6<f64>, n: &Matrix2x6<f64>) {
    let err = rel_err(a, n);
    assert!(
        err < 1e-6,
        "{name}: rel err {err:e}\nanalytic {a}\nnumerical {n}"
    );
}

fn check_jacobians(j_is_e: bool, seed: u64) {
    let mut rng = Rng::new(seed);
    let h = 1e-6;
    for _ in 0..30 {
        let st = setup(&mut rng);
        let f = factor(&st, &mut rng, 3e-3, j_is_e);
        let j_pose = if j_is_e { st.e } else { st.j };
        let jac = f.evaluate(&st.s, &st.e, &j_pose, &st.ext).unwrap();
        let r0 = f.residual(&st.s, &st.e, &j_pose, &st.ext).unwrap();
        assert_eq!(jac.r, r0);
        // Precomputed camera frames give bit-identical results.
        let frames = [
            CamFrame::new(&st.s, &st.ext),
            CamFrame::new(&st.e, &st.ext),
            CamFrame::new(&j_pose, &st.ext),
        ];
        let kfs = [&st.s, &st.e, &j_pose];
        assert_eq!(f.residual_with_frames(kfs, &frames, &st.ext).unwrap(), r0);
        assert_eq!(f.evaluate_with_frames(kfs, &frames, &st.ext).unwrap(), jac);
        let res = |s: &KeyframePose, e: &KeyframePose, j: &KeyframePose, x: &CameraExtrinsic| {
            // With j == e the caller passes e in both slots.
            let j = if j_is_e { e } else { j };
            f.residual(s, e, j, x).unwrap()
        };
        let ns = num_jac::<2, 6>(h, |d| res(&perturb_pose(&st.s, d), &st.e, &j_pose, &st.ext));
        let ne = num_jac::<2, 6>(h, |d| res(&st.s, &perturb_pose(&st.e, d), &j_pose, &st.ext));
        let nx = num_jac::<2, 6>(h, |d| res(&st.s, &st.e, &j_pose, &perturb_ext(&st.ext, d)));
        check("pose s", &jac.d_pose_s, &ns);
        check("pose e", &jac.d_pose_e, &ne);
        check("extrinsic", &jac.d_ext, &nx);
        if j_is_e {
            assert_eq!(jac.d_pose_j, Matrix2x6::zeros());
            assert_eq!(jac.d_td[2], Vec2::zeros());
        } else {
            let nj = num_jac::<2, 6>(h, |d| res(&st.s, &st.e, &perturb_pose(&st.j, d), &st.ext));
            check("pose j", &jac.d_pose_j, &nj);
        }
        // The rank-structured blocks (weight w) against central differences: on e the Jacobian
        // is q E, plus the j role when j == e.
        let w = 0.7;
        let anchors = PoseOnlyAnchors::new(
            (f.kf_s, f.kf_e),
            f.obs_s,
            f.obs_e,
            f.sqrt_info,
            (&st.s, &st.e),
            (&frames[0], &frames[1]),
            &st.ext,
            None,
        )
        .unwrap();
        let g = anchors
            .geometry(f.kf_j, &f.obs_j, &j_pose, &frames[2], None)
            .unwrap();
        assert_eq!(anchors.whitened(&g), r0);
        // Precomputed relative poses give bit-identical results.
        let rel = Some(frames[2].relative_from(&frames[0]));
        let g_rel = anchors
            .geometry(f.kf_j, &f.obs_j, &j_pose, &frames[2], rel)
            .unwrap();
        assert_eq!(anchors.pose_blocks(&g_rel, w), anchors.pose_blocks(&g, w));
        let pb = anchors.pose_blocks(&g, w);
        assert!((pb.r - r0 * w).amax() < 1e-15);
        check("blocks: pose s", &pb.d_pose_s, &(ns * w));
        let on_e = pb.q * anchors.shared_e()
            + if j_is_e {
                pb.d_pose_j
            } else {
                Matrix2x6::zeros()
            };
        check("blocks: pose e", &on_e, &(ne * w));
        if !j_is_e {
            let nj = num_jac::<2, 6>(h, |d| res(&st.s, &st.e, &perturb_pose(&st.j, d), &st.ext));
            check("blocks: pose j", &pb.d_pose_j, &(nj * w));
        }
        // Time delays.
        let td = |k: usize, d: f64| {
            let (mut s, mut e, mut j) = (st.s, st.e, j_pose);
            match k {
                0 => s.td += d,
                1 => e.td += d,
                _ => j.td += d,
            }
            res(&s, &e, &j, &st.ext)
        };
        // The rank-structured delay Jacobians of the fast path agree with both.
        let tdj = anchors.td_jacobians(&g, w, &f.obs_j);
        #[allow(clippy::needless_range_loop)] // k also selects the anchor in `td(k, _)`
        for k in 0..(if j_is_e { 2 } else { 3 }) {
            let n: SMatrix<f64, 2, 1> = num_jac::<2, 1>(h, |d| td(k, d[0]));
            let a: SMatrix<f64, 2, 1> = jac.d_td[k];
            let err = rel_err(&a, &n);
            assert!(err < 1e-6, "td {k}: {a} vs {n}");
            assert!(
                a.amax() > 1e-3,
                "td {k} Jacobian should be non-trivial: {a}"
            );
            let b: SMatrix<f64, 2, 1> = tdj[k];
            assert!(
                rel_err(&b, &(n * w)) < 1e-6,
                "fast td {k}: {b} vs {}",
                n * w
            );
        }
        if j_is_e {
            assert_eq!(tdj[2], nalgebra::Vector2::zeros());
        }
    }
}

#[test]
fn jacobians_match_numerical_distinct_j() {
    check_jacobians(false, 12);
}

#[test]
fn jacobians_match_numerical_j_equals_e() {
    check_jacobians(true, 13);
}

#[test]
fn anchor_misuse_and_degenerate_geometry_are_errors() {
    let mut rng = Rng::new(14);
    let st = setup(&mut rng);
    let f = factor(&st, &mut rng, 0.0, false);
    let bad_e = PoseOnlyVisualFactor { kf_e: f.kf_s, ..f };
    assert_eq!(
        bad_e.residual(&st.s, &st.e, &st.j, &st.ext),
        Err(Error::Degenerate)
    );
    let bad_j = PoseOnlyVisualFactor { kf_j: f.kf_s, ..f };
    assert_eq!(
        bad_j.evaluate(&st.s, &st.e, &st.j, &st.ext).map(|j| j.r),
        Err(Error::Degenerate)
    );
    // e at the same place as s: no baseline, the depth is zero/undefined.
    let e_at_s = KeyframePose {
        td: st.e.td,
        ..st.s
    };
    assert_eq!(
        f.residual(&st.s, &e_at_s, &st.j, &st.ext),
        Err(Error::Degenerate)
    );
    let mut nan = st.j;
    nan.p_wb.x = f64::NAN;
    assert_eq!(
        f.residual(&st.s, &st.e, &nan, &st.ext),
        Err(Error::NonFinite)
    );
    let zero_info = PoseOnlyVisualFactor {
        sqrt_info: Vec2::zeros(),
        ..f
    };
    assert_eq!(
        zero_info.residual(&st.s, &st.e, &st.j, &st.ext),
        Err(Error::InvalidConfig)
    );
}

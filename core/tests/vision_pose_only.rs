//! Pose-only depth, its analytic uncertainty and the anchor selection.

mod vision_common;

use povins_core::camera::{CameraPose, Vec2};
use povins_core::landmarks::pose_only::DEFAULT_MIN_THETA;
use povins_core::landmarks::{depth_std, pose_only_depth, select_anchor, TwoView};
use povins_core::math::{quat_exp, skew, Mat3, Vec3};
use povins_core::Error;
use vision_common::Rng;

const F: Vec2 = Vec2::new(458.654, 457.296);

/// Camera s at the origin looking along +z, camera e displaced by `baseline` along x and rotated a
/// little; a landmark at depth `depth` in camera s.
struct Scene {
    x_s: Vec3,
    x_e: Vec3,
    r_es: Mat3,
    t_es: Vec3,
    depth: f64,
}

fn scene(depth: f64, baseline: f64, bearing: (f64, f64)) -> Scene {
    let p_s = Vec3::new(bearing.0, bearing.1, 1.0) * depth;
    // Pose of camera s in camera e.
    let r_es = quat_exp(&Vec3::new(0.02, -0.05, 0.01))
        .to_rotation_matrix()
        .into_inner();
    let t_es = Vec3::new(-baseline, 0.1 * baseline, 0.05 * baseline);
    let p_e = r_es * p_s + t_es;
    Scene {
        x_s: p_s / p_s.z,
        x_e: p_e / p_e.z,
        r_es,
        t_es,
        depth,
    }
}

#[test]
fn depth_is_exact_on_synthetic_geometry() {
    let mut rng = Rng::new(1);
    for _ in 0..200 {
        let depth = rng.range(0.5, 60.0);
        let sc = scene(
            depth,
            rng.range(0.05, 1.0),
            (rng.range(-0.6, 0.6), rng.range(-0.4, 0.4)),
        );
        let d = pose_only_depth(&sc.x_s, &sc.x_e, &sc.r_es, &sc.t_es, DEFAULT_MIN_THETA).unwrap();
        assert_eq!(sc.depth, depth);
        assert!(
            ((d.d_s - sc.depth) / sc.depth).abs() < 1e-12,
            "{} vs {depth}",
            d.d_s
        );
        // Paper's magnitude form |b|/|a| agrees for consistent observations.
        let g = TwoView::new(&sc.x_s, &sc.x_e, &sc.r_es, &sc.t_es);
        assert!((g.b.norm() / g.a.norm() - depth).abs() < 1e-9 * depth);
    }
}

#[test]
fn degenerate_cases_are_errors() {
    let sc = scene(5.0, 0.3, (0.1, 0.0));
    // Landmark behind camera s: flip the observation in e by moving it across the epipole.
    let p_behind = Vec3::new(0.1, 0.0, 1.0) * -5.0;
    let pe = sc.r_es * p_behind + sc.t_es;
    let x_e_behind = pe / pe.z;
    assert_eq!(
        pose_only_depth(&sc.x_s, &x_e_behind, &sc.r_es, &sc.t_es, 0.0),
        Err(Error::Degenerate)
    );
    // Pure rotation: zero baseline still has parallax from rotation but b = 0 -> d_s = 0.
    assert_eq!(
        pose_only_depth(&sc.x_s, &sc.x_e, &sc.r_es, &Vec3::zeros(), 0.0),
        Err(Error::Degenerate)
    );
    // Same bearing in both views (no parallax): a = 0.
    let ident = Mat3::identity();
    assert_eq!(
        pose_only_depth(&sc.x_s, &sc.x_s, &ident, &sc.t_es, DEFAULT_MIN_THETA),
        Err(Error::Degenerate)
    );
    // Parallax gate.
    let far = scene(500.0, 0.05, (0.1, 0.0));
    let d = pose_only_depth(&far.x_s, &far.x_e, &far.r_es, &far.t_es, 0.0).unwrap();
    assert!(d.theta < 2e-4);
    assert_eq!(
        pose_only_depth(&far.x_s, &far.x_e, &far.r_es, &far.t_es, DEFAULT_MIN_THETA),
        Err(Error::Degenerate)
    );
    let mut nan = sc.x_s;
    nan.x = f64::NAN;
    assert_eq!(
        pose_only_depth(&nan, &sc.x_e, &sc.r_es, &sc.t_es, 0.0),
        Err(Error::NonFinite)
    );
}

fn depth_of(x_s: &Vec3, x_e: &Vec3, r: &Mat3, t: &Vec3) -> f64 {
    TwoView::new(x_s, x_e, r, t).signed_depth()
}

#[test]
fn depth_jacobians_match_numerical_and_math_notes_form() {
    let mut rng = Rng::new(2);
    let h = 1e-7;
    for i in 0..100 {
        let sc = scene(
            rng.range(1.0, 30.0),
            rng.range(0.1, 1.0),
            (rng.range(-0.5, 0.5), rng.range(-0.4, 0.4)),
        );
        // Noisy observations (i odd) make b and a non-parallel, where the signed and magnitude
        // forms differ: the analytic Jacobian must match the function actually computed.
        let noise = if i % 2 == 1 { 3e-3 } else { 0.0 };
        let x_s = sc.x_s + Vec3::new(rng.normal(), rng.normal(), 0.0) * noise;
        let x_e = sc.x_e + Vec3::new(rng.normal(), rng.normal(), 0.0) * noise;
        let g = TwoView::new(&x_s, &x_e, &sc.r_es, &sc.t_es);
        let (js, je) = g.depth_jacobians();
        for k in 0..2 {
            let mut d = Vec3::zeros();
            d[k] = h;
            let ns = (depth_of(&(x_s + d), &x_e, &sc.r_es, &sc.t_es)
                - depth_of(&(x_s - d), &x_e, &sc.r_es, &sc.t_es))
                / (2.0 * h);
            let ne = (depth_of(&x_s, &(x_e + d), &sc.r_es, &sc.t_es)
                - depth_of(&x_s, &(x_e - d), &sc.r_es, &sc.t_es))
                / (2.0 * h);
            let scale = js.amax().max(je.amax());
            assert!(
                (js[k] - ns).abs() < 1e-6 * scale,
                "dd/dx_s[{k}] {} {ns}",
                js[k]
            );
            assert!(
                (je[k] - ne).abs() < 1e-6 * scale,
                "dd/dx_e[{k}] {} {ne}",
                je[k]
            );
        }
        if noise == 0.0 {
            // Math notes sec. 2 (magnitude form) at consistent geometry.
            let beta = g.b.norm();
            let theta = g.a.norm();
            let ms = -(beta / theta.powi(3)) * g.a.transpose() * skew(&x_e) * sc.r_es;
            let me = -(1.0 / (beta * theta)) * x_e.cross(&sc.t_es).transpose() * skew(&sc.t_es)
                + (beta / theta.powi(3)) * g.a.transpose() * skew(&(sc.r_es * x_s));
            for k in 0..2 {
                assert!((ms[k] - js[k]).abs() < 1e-8 * js.amax(), "{ms} vs {js}");
                assert!((me[k] - je[k]).abs() < 1e-8 * je.amax(), "{me} vs {je}");
            }
        }
    }
}

#[test]
fn sigma_grows_with_depth_and_shrinks_with_parallax() {
    let sigma = |depth: f64, baseline: f64| {
        let sc = scene(depth, baseline, (0.1, -0.05));
        depth_std(&TwoView::new(&sc.x_s, &sc.x_e, &sc.r_es, &sc.t_es), 1.5, &F).unwrap()
    };
    let mut prev = 0.0;
    for depth in [1.0, 2.0, 5.0, 10.0, 20.0, 50.0] {
        let s = sigma(depth, 0.3);
        assert!(s > prev, "sigma({depth}) = {s} not > {prev}");
        prev = s;
    }
    // Classic two-view law: sigma_d ~ d^2 sigma / (f * baseline) per noisy image, sqrt(2) for
    // noise in both, for small parallax.
    let s = sigma(20.0, 0.3);
    let approx = core::f64::consts::SQRT_2 * 20.0 * 20.0 * (1.5 / F.x) / 0.3;
    assert!((s / approx - 1.0).abs() < 0.05, "{s} vs {approx}");
    let mut prev = f64::INFINITY;
    for baseline in [0.05, 0.1, 0.2, 0.5, 1.0] {
        let s = sigma(10.0, baseline);
        assert!(s < prev, "sigma at baseline {baseline} = {s} not < {prev}");
        prev = s;
    }
}

#[test]
fn monte_carlo_depth_std_matches_analytic() {
    let mut rng = Rng::new(3);
    let sigma_px = 1.5;
    let n = 40_000;
    for (depth, baseline) in [(4.0, 0.5), (8.0, 1.0), (3.0, 0.2)] {
        let sc = scene(depth, baseline, (0.15, -0.1));
        let analytic = depth_std(
            &TwoView::new(&sc.x_s, &sc.x_e, &sc.r_es, &sc.t_es),
            sigma_px,
            &F,
        )
        .unwrap();
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..n {
            let ns = Vec3::new(
                rng.normal() * sigma_px / F.x,
                rng.normal() * sigma_px / F.y,
                0.0,
            );
            let ne = Vec3::new(
                rng.normal() * sigma_px / F.x,
                rng.normal() * sigma_px / F.y,
                0.0,
            );
            let d = depth_of(&(sc.x_s + ns), &(sc.x_e + ne), &sc.r_es, &sc.t_es);
            sum += d;
            sum2 += d * d;
        }
        let mean = sum / n as f64;
        let emp = libm::sqrt(sum2 / n as f64 - mean * mean);
        println!(
            "depth {depth} m baseline {baseline} m: analytic sigma_d {analytic:.4} m, Monte-Carlo {emp:.4} m"
        );
        assert!(
            (emp / analytic - 1.0).abs() < 0.1,
            "empirical {emp} vs analytic {analytic}"
        );
        // The test has teeth: sigma from one view only would be visibly off.
        assert!(analytic > 0.01 * depth / 10.0);
    }
}

#[test]
fn anchor_selection_picks_largest_parallax() {
    let p_w = Vec3::new(0.3, -0.2, 6.0);
    let mut poses = Vec::new();
    let mut obs = Vec::new();
    // Cameras along x, looking along +z; the farthest from camera 0 gives the largest parallax.
    for (k, x) in [0.0, 0.1, 0.6, 0.3, 0.05].iter().enumerate() {
        let pose = CameraPose {
            p_wc: Vec3::new(*x, 0.02 * k as f64, 0.0),
            q_wc: quat_exp(&Vec3::new(0.0, 0.01 * k as f64, 0.0)),
        };
        let p_c = pose.q_wc.inverse() * (p_w - pose.p_wc);
        obs.push(p_c / p_c.z);
        poses.push(pose);
    }
    let (e, theta) = select_anchor(0, &poses, &obs).unwrap();
    assert_eq!(e, 2);
    assert!(theta > 0.09 && theta < 0.11, "{theta}");
    // From anchor 2, the farthest is camera 0 (x = 0.0) vs 4 (x = 0.05): camera 0.
    assert_eq!(select_anchor(2, &poses, &obs).unwrap().0, 0);
    assert_eq!(
        select_anchor(0, &poses[..1], &obs[..1]),
        Err(Error::NotEnoughData)
    );
    assert_eq!(select_anchor(5, &poses, &obs), Err(Error::InvalidConfig));
    assert_eq!(
        select_anchor(0, &poses, &obs[..4]),
        Err(Error::InvalidConfig)
    );
}

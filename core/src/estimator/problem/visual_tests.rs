//! Tests of the eliminated landmark's inner solve and linearization (`visual.rs` includes this
//! file as its `#[cfg(test)]` module; the attribute below repeats that for readers of this file
//! alone).
#![cfg(test)]
use super::*;
use crate::camera::CameraExtrinsic;
use crate::camera::Vec2;
use crate::factors::{CamFrame, KeyframePose, TimedObs};
use crate::math::{quat_exp, Vec3};

/// A landmark 4 m away seen from four keyframes with pixel noise; with `outlier`, the last
/// observation is 30 px off (outside the Huber threshold).
fn tau_scene(outlier: bool) -> (HVec<Ray, 4>, f64) {
    let mut noise = [
        [0.0, 0.0],
        [0.002, -0.001],
        [-0.0015, 0.0025],
        [0.001, 0.0005],
    ];
    if outlier {
        noise[3][0] += 30.0 / 460.0;
    }
    scene(Vec3::new(4.0, 1.0, 0.5), &noise)
}

/// The rays of a landmark at `p_w` (behind the anchor camera where `p_w` is given as a point
/// behind it) seen from the first `noise.len()` of four keyframes, each observation moved by
/// its `noise` (normalized units), and the true inverse depth.
fn scene(p_w: Vec3, noise: &[[f64; 2]]) -> (HVec<Ray, 4>, f64) {
    let ext = CameraExtrinsic {
        p_bc: Vec3::new(0.05, -0.02, 0.01),
        q_bc: quat_exp(&Vec3::new(-1.5, 0.02, -1.55)),
    };
    let poses: [KeyframePose; 4] = core::array::from_fn(|k| {
        let t = k as f64;
        KeyframePose {
            p_wb: Vec3::new(0.25 * t, 0.05 * t * t, -0.01 * t),
            q_wb: quat_exp(&Vec3::new(0.01 * t, -0.02 * t, 0.04 * t)),
            td: 0.0,
        }
    });
    let frames: [CamFrame; 4] = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
    let obs: HVec<Vec2, 4> = noise
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let c = ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb);
            let p_c = c.q_wc.inverse() * (p_w - c.p_wc);
            Vec2::new(p_c.x / p_c.z + n[0], p_c.y / p_c.z + n[1])
        })
        .collect();
    let sqrt_info = Vec2::new(460.0, 460.0) / 1.5;
    let obs_s = TimedObs::still(obs[0]);
    let mut m = TauLandmark::<4> {
        s: 0,
        obs: HVec::new(),
        depth: None,
    };
    for (j, o) in obs.iter().enumerate().skip(1) {
        let f = InverseDepthVisualFactor {
            kf_s: 0,
            kf_j: j,
            obs_s,
            obs_j: TimedObs::still(*o),
            sqrt_info,
        };
        m.obs.push((j, f)).unwrap();
    }
    let c0 = ext.camera_pose(&poses[0].p_wb, &poses[0].q_wb);
    let tau_true = 1.0 / (c0.q_wc.inverse() * (p_w - c0.p_wc)).z;
    (m.rays(&poses, &frames).unwrap(), tau_true)
}

/// The LiDAR depths the tests run with beside none: one within the Huber threshold of the
/// true depth, one 4 sigma off (its `rho''` exercised).
fn depths(tau_true: f64) -> [Option<LidarDepth>; 3] {
    let d = |k: f64| {
        Some(LidarDepth {
            depth_m: 1.0 / tau_true + k * 0.05,
            sigma_m: 0.05,
        })
    };
    [None, d(0.4), d(4.0)]
}

/// The robust cost [`solve_bearing_tau`] minimizes, evaluated directly.
fn bearing_cost(
    rays: &[Ray],
    w_s: Vec2,
    depth: Option<&LidarDepth>,
    delta: [f64; 2],
    tau: f64,
    huber: &Huber,
) -> f64 {
    let depth_row = depth.map_or(0.0, |d| {
        let r = (1.0 / tau - d.depth_m) / d.sigma_m;
        huber.rho(r * r)[0]
    });
    let anchor = Vec2::new(w_s.x * delta[0], w_s.y * delta[1]).norm_squared();
    let rows: f64 = rays
        .iter()
        .map(|r| {
            let (r, _) = r.residual_and_d_bearing_tau(delta, tau).unwrap();
            huber.rho(r.norm_squared())[0]
        })
        .sum();
    huber.rho(anchor)[0] + rows + depth_row
}

#[test]
fn bearing_ray_derivatives_match_numerical_differentiation() {
    let (rays, tau_true) = tau_scene(false);
    let x0 = [3e-3, -2e-3, 1.1 * tau_true];
    let at = |x: [f64; 3]| move |ray: &Ray| ray.residual_and_d_bearing_tau([x[0], x[1]], x[2]);
    for ray in rays.iter() {
        let (r, d) = at(x0)(ray).unwrap();
        // The same residual as the depth-only form at delta = 0.
        let (r0, d0) = ray.residual_and_d_tau(x0[2]).unwrap();
        let (r1, d1) = at([0.0, 0.0, x0[2]])(ray).unwrap();
        assert!((r0 - r1).norm() <= 1e-12 && (d0 - d1[2]).norm() <= 1e-12 * d0.norm());
        assert!((r - r0).norm() > 1e-3, "delta moves the residual");
        for (k, dk) in d.iter().enumerate() {
            let h = 1e-6 * x0[k].abs().max(1e-3);
            let (mut xp, mut xm) = (x0, x0);
            xp[k] += h;
            xm[k] -= h;
            let num = (at(xp)(ray).unwrap().0 - at(xm)(ray).unwrap().0) / (2.0 * h);
            assert!(
                (num - dk).norm() <= 1e-6 * dk.norm().max(1.0),
                "{k}: {num} vs {dk}"
            );
        }
    }
}

#[test]
fn bearing_pass_derivatives_match_numerical_differentiation() {
    let huber = Huber::new(1.0).unwrap();
    // A bearing correction of 2 px on x: past the Huber threshold (1.5 px), so the anchor's
    // `rho''` term is exercised too.
    let w_s = Vec2::new(460.0, 460.0) / 1.5;
    for outlier in [false, true] {
        let (rays, tau_true) = tau_scene(outlier);
        let cases = [[3e-3, -1e-3, tau_true], [4e-3, 2e-3, 0.8 * tau_true]];
        for (x0, depth) in cases
            .into_iter()
            .flat_map(|x| depths(tau_true).map(|d| (x, d)))
        {
            let depth = depth.as_ref();
            let (cost, g, h, h_gn) =
                bearing_pass(&rays, w_s, depth, [x0[0], x0[1]], x0[2], &huber).unwrap();
            let f = |x: [f64; 3]| bearing_cost(&rays, w_s, depth, [x[0], x[1]], x[2], &huber);
            assert!((cost - f(x0)).abs() <= 1e-12 * cost);
            let e = [1e-6, 1e-6, 1e-5 * x0[2]];
            let at = |k: usize, sk: f64, l: usize, sl: f64| {
                let mut x = x0;
                x[k] += sk * e[k];
                x[l] += sl * e[l];
                f(x)
            };
            for k in 0..3 {
                let d1 = (at(k, 1.0, k, 0.0) - at(k, -1.0, k, 0.0)) / (2.0 * e[k]);
                assert!((2.0 * g[k] - d1).abs() <= 1e-6 * d1.abs().max(1.0), "g{k}");
                for l in 0..3 {
                    let d2 = (at(k, 1.0, l, 1.0) - at(k, 1.0, l, -1.0) - at(k, -1.0, l, 1.0)
                        + at(k, -1.0, l, -1.0))
                        / (4.0 * e[k] * e[l]);
                    // (The exact Hessian's diagonal can vanish on a Huber-linear row.)
                    let scale = (h_gn[k][k] * h_gn[l][l]).sqrt();
                    assert!(
                        (2.0 * h[k][l] - d2).abs() <= 1e-4 * scale,
                        "h{k}{l}: {} vs {d2}",
                        2.0 * h[k][l]
                    );
                    assert!(h_gn[k][l].is_finite());
                }
            }
        }
    }
}

#[test]
fn solve_bearing_tau_finds_the_robust_minimum_and_its_cost() {
    let huber = Huber::new(1.0).unwrap();
    let w_s = Vec2::new(460.0, 460.0) / 1.5;
    for (outlier, k) in [false, true]
        .into_iter()
        .flat_map(|o| (0..3).map(move |k| (o, k)))
    {
        let (rays, tau_true) = tau_scene(outlier);
        let depth = depths(tau_true)[k];
        let depth = depth.as_ref();
        let s = solve_bearing_tau(&rays, w_s, depth, [0.0; 2], 0.6 * tau_true, &huber).unwrap();
        let (delta, tau, cost) = (s.delta, s.tau, s.cost);
        // From another start: the same minimum.
        let s2 = solve_bearing_tau(&rays, w_s, depth, [1e-3, -1e-3], 1.2 * tau, &huber).unwrap();
        assert!(s.converged && s2.converged);
        let (d2, t2, c2) = (s2.delta, s2.tau, s2.cost);
        assert!(
            (tau - t2).abs() <= 1e-8 * tau,
            "{outlier}: {tau} vs {t2}, {delta:?} {d2:?} {cost} {c2} true {tau_true}"
        );
        assert!((delta[0] - d2[0]).abs() + (delta[1] - d2[1]).abs() <= 1e-8);
        for (d, t, c) in [(delta, tau, cost), (d2, t2, c2)] {
            let exact = bearing_cost(&rays, w_s, depth, d, t, &huber);
            assert!((c - exact).abs() <= 1e-10 * exact, "{c} vs {exact}");
        }
        // A minimum in each of the three directions, below the depth-only solve's cost
        // (which is this cost at delta = 0).
        for k in 0..3 {
            for e in [1e-5, -1e-5] {
                let mut x = [delta[0], delta[1], tau];
                x[k] += if k == 2 { e * tau } else { e };
                assert!(bearing_cost(&rays, w_s, depth, [x[0], x[1]], x[2], &huber) > cost);
            }
        }
        let exact_anchor = bearing_cost(&rays, w_s, depth, [0.0; 2], tau, &huber);
        assert!(cost < exact_anchor, "{cost} vs {exact_anchor}");
        assert!(
            delta.iter().any(|d| d.abs() > 1e-6),
            "the anchor's noise shows"
        );
    }
    let (rays, _) = tau_scene(false);
    assert_eq!(
        solve_bearing_tau(&rays, w_s, None, [0.0; 2], 0.0, &huber).err(),
        Some(Error::NotEnoughData)
    );
}

/// Two views whose observations disagree by 8.5-9 px (both residuals past the Huber
/// threshold of 1.5 px), with and without a LiDAR depth: the cost has a flat, curved valley
/// the Gauss–Newton steps crawl along (sixty of them do not reach its end); the solve still
/// reaches its minimum (a vanishing gradient).
#[test]
fn solve_bearing_tau_reaches_the_minimum_of_a_flat_valley() {
    let huber = Huber::new(1.0).unwrap();
    let w_s = Vec2::new(460.0, 460.0) / 1.5;
    let p_w = Vec3::new(4.0, 1.0, 0.5);
    for (shift, sigmas) in [
        ([-9.0, 0.0], None),
        ([-6.0, -6.0], Some(0.0)),
        ([0.0, -9.0], Some(3.0)),
    ] {
        let noise = [[0.0, 0.0], [shift[0] / 460.0, shift[1] / 460.0]];
        let (rays, tau_true) = scene(p_w, &noise);
        let depth = sigmas.map(|k: f64| LidarDepth {
            depth_m: 1.0 / tau_true + k * 0.05,
            sigma_m: 0.05,
        });
        let depth = depth.as_ref();
        let s = solve_bearing_tau(&rays, w_s, depth, [0.0; 2], tau_true, &huber).unwrap();
        assert!(s.converged, "{shift:?}: {s:?}");
        let f = |x: [f64; 3]| bearing_cost(&rays, w_s, depth, [x[0], x[1]], x[2], &huber);
        let x = [s.delta[0], s.delta[1], s.tau];
        assert!((f(x) - s.cost).abs() <= 1e-9 * s.cost, "{shift:?}: {s:?}");
        for k in 0..3 {
            let e = if k == 2 { 1e-6 * s.tau } else { 1e-7 };
            let (mut xp, mut xm) = (x, x);
            (xp[k], xm[k]) = (x[k] + e, x[k] - e);
            // The slope times a pixel's worth of that coordinate: a negligible cost change.
            let slope = (f(xp) - f(xm)) / (2.0 * e);
            let unit = if k == 2 { s.tau } else { 1.0 / 460.0 };
            assert!(
                (slope * unit).abs() <= 1e-5,
                "{shift:?} d{k}: {slope} at {s:?}"
            );
        }
    }
}

/// Two views whose second observation puts the point beyond infinity (behind the anchor
/// camera): the cost falls toward zero inverse depth; the solve stops there, not converged,
/// rather than error or halve the depth sixty times.
#[test]
fn solve_bearing_tau_says_a_point_beyond_infinity_has_not_converged() {
    let huber = Huber::new(1.0).unwrap();
    let w_s = Vec2::new(460.0, 460.0) / 1.5;
    // 20 m behind the anchor camera: seen in the second view through the mirrored ray.
    let (rays, tau) = scene(Vec3::new(-20.0, -4.0, -2.0), &[[0.0; 2], [0.0; 2]]);
    assert!(tau < 0.0, "{tau}");
    let s = solve_bearing_tau(&rays, w_s, None, [0.0; 2], 0.25, &huber).unwrap();
    assert!(!s.converged, "{s:?}");
    assert!(s.tau < 1e-5 && s.tau > 0.0, "{s:?}");
    // A LiDAR depth holds it: then it converges.
    let d = LidarDepth {
        depth_m: 4.0,
        sigma_m: 0.05,
    };
    let s = solve_bearing_tau(&rays, w_s, Some(&d), [0.0; 2], 0.25, &huber).unwrap();
    assert!(s.converged, "{s:?}");
}

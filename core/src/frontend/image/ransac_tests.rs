//! Tests of `ransac.rs` (included as its `#[cfg(test)]` module).
extern crate std;
use super::*;
use crate::math::{exp_so3, Vec3};
use std::vec::Vec;

const FOCAL: f64 = 450.0;

struct Scene {
    prev: Vec<[f64; 2]>,
    cur: Vec<[f64; 2]>,
    outlier: Vec<bool>,
    r: Mat3,
    t: Vec3,
}

impl Scene {
    /// True epipolar distance of point `i` in the current image, px.
    fn epi_px(&self, i: usize) -> f64 {
        let y = rotate(&self.r, &[self.prev[i][0], self.prev[i][1], 1.0]);
        let l = cross(&[self.t.x, self.t.y, self.t.z], &y);
        let c = [self.cur[i][0], self.cur[i][1], 1.0];
        libm::fabs(dot(&l, &c)) / libm::hypot(l[0], l[1]) * FOCAL
    }
}

/// `n` points 2-10 m ahead, camera motion `(rot, t)` (`P_cur = R P_prev + t`), pixel noise
/// uniform in +-0.5 px, every fifth point displaced by 5-30 px.
fn scene(n: usize, rot: Vec3, t: Vec3, seed: u64) -> Scene {
    let mut rng = XorShift64::new(seed);
    let mut u = move || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let r = exp_so3(&rot);
    let mut s = Scene {
        prev: Vec::new(),
        cur: Vec::new(),
        outlier: Vec::new(),
        r,
        t,
    };
    for i in 0..n {
        let z = 2.0 + 8.0 * u();
        let p = Vec3::new((u() - 0.5) * 1.2 * z, (u() - 0.5) * 0.9 * z, z);
        let c = r * p + t;
        let mut noise = |v: f64| v + (u() - 0.5) / FOCAL;
        let mut cn = [noise(c.x / c.z), noise(c.y / c.z)];
        let out = i % 5 == 3;
        if out {
            let (a, d) = (u() * core::f64::consts::TAU, (5.0 + 25.0 * u()) / FOCAL);
            cn = [cn[0] + d * libm::cos(a), cn[1] + d * libm::sin(a)];
        }
        s.prev.push([p.x / p.z, p.y / p.z]);
        s.cur.push(cn);
        s.outlier.push(out);
    }
    s
}

/// (outliers kept among those more than 3 px off their true epipolar line, inliers lost).
fn score(s: &Scene, inl: &[bool]) -> (usize, usize) {
    let kept_out = (0..s.prev.len())
        .filter(|&i| s.outlier[i] && inl[i] && s.epi_px(i) > 3.0)
        .count();
    let lost_in = s
        .outlier
        .iter()
        .zip(inl)
        .filter(|(o, i)| !**o && !**i)
        .count();
    (kept_out, lost_in)
}

fn run_two(s: &Scene, seed: u64) -> (Vec<bool>, RansacOutcome) {
    let n = s.prev.len();
    let (mut ys, mut ms, mut inl) = (
        std::vec![[0.0; 3]; n],
        std::vec![[0.0; 3]; n],
        std::vec![false; n],
    );
    let cfg = RansacConfig::default();
    let mut rng = XorShift64::new(seed);
    let o = two_point(
        &s.prev,
        &s.cur,
        &s.r,
        1.5 / FOCAL,
        &cfg,
        &mut rng,
        &mut ys,
        &mut ms,
        &mut inl,
    );
    (inl, o)
}

fn run_eight(s: &Scene, seed: u64) -> (Vec<bool>, RansacOutcome) {
    let mut inl = std::vec![false; s.prev.len()];
    let cfg = RansacConfig::default();
    let mut rng = XorShift64::new(seed);
    let o = eight_point(&s.prev, &s.cur, 1.5 / FOCAL, &cfg, &mut rng, &mut inl);
    (inl, o)
}

#[test]
fn both_models_reject_planted_outliers() {
    for seed in 1..=5u64 {
        let s = scene(
            150,
            Vec3::new(0.02, -0.03, 0.05),
            Vec3::new(0.2, 0.05, 0.1),
            seed,
        );
        let visible = (0..150)
            .filter(|&i| s.outlier[i] && s.epi_px(i) > 3.0)
            .count();
        assert!(visible >= 20, "{visible}");
        for (name, (inl, o)) in [("2-point", run_two(&s, 9)), ("8-point", run_eight(&s, 9))] {
            let (kept_out, lost_in) = score(&s, &inl);
            assert!(o.model_found, "{name}");
            // Outliers displaced along their epipolar line are invisible to any epipolar
            // model; every one more than 3 px off it must go.
            assert_eq!(
                kept_out, 0,
                "{name} seed {seed}: kept {kept_out} of {visible}"
            );
            assert!(lost_in <= 3, "{name} seed {seed}: lost {lost_in} inliers");
            assert_eq!(o.inliers + o.outliers, 150);
        }
    }
}

#[test]
fn deterministic_and_pure_rotation() {
    let s = scene(
        100,
        Vec3::new(0.01, 0.04, -0.02),
        Vec3::new(0.1, -0.02, 0.3),
        3,
    );
    assert_eq!(run_two(&s, 5), run_two(&s, 5));
    assert_eq!(run_eight(&s, 5), run_eight(&s, 5));
    // Pure rotation: the 2-point model keeps every inlier.
    let s = scene(100, Vec3::new(0.01, 0.04, -0.02), Vec3::zeros(), 4);
    let (inl, _) = run_two(&s, 5);
    let (_, lost_in) = score(&s, &inl);
    assert_eq!(lost_in, 0);
}

#[test]
fn too_few_points_keep_everything() {
    let s = scene(8, Vec3::zeros(), Vec3::new(0.1, 0.0, 0.0), 1);
    let (inl, o) = run_eight(&s, 1);
    assert!(inl.iter().all(|&b| b));
    assert!(!o.model_found);
    let s = scene(2, Vec3::zeros(), Vec3::new(0.1, 0.0, 0.0), 1);
    let (inl, o) = run_two(&s, 1);
    assert!(inl.iter().all(|&b| b) && !o.model_found);
    assert!(RansacConfig::default().validate().is_ok());
    let bad = RansacConfig {
        confidence: 1.0,
        ..RansacConfig::default()
    };
    assert_eq!(bad.validate(), Err(Error::InvalidConfig));
}

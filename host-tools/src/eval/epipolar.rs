//! Consistency of feature tracks with the gyro: every step of a track (its positions in two
//! consecutive images) must satisfy the epipolar constraint of the camera's motion between the
//! images, whose rotation the gyro gives (integrated over `[t0 + td, t1 + td]`, turned into
//! camera axes with `R_bc`) and whose translation direction is unknown. Per image pair the
//! translation direction is fitted robustly to all steps (2-point RANSAC with the rotation
//! fixed, then least squares on the inliers), and a step violates the constraint when its
//! current position lies farther than a threshold from its epipolar line (pixels, at the mean
//! focal length). With pure rotation every line passes through the derotated previous position,
//! so the check reduces to the derotated displacement.
//!
//! It needs no ground truth, so it compares front ends on real images (same images, same gyro).

use nalgebra::{Matrix3, SymmetricEigen};
use povins_core::camera::PinholeCamera;
use povins_core::inertial::ImuSample;
use povins_core::math::{Mat3, Vec3};
use povins_core::vio::{GyroIntegrator, GYRO_SAMPLES};
use povins_platform::dataset::FeatureFrame;
use std::collections::HashMap;

/// Thresholds reported, px.
pub const THRESHOLDS_PX: [f64; 3] = [1.0, 2.0, 4.0];

/// What [`check`] found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EpipolarReport {
    /// Image pairs checked (both with a gyro rotation and at least 8 common tracks).
    pub pairs: usize,
    /// Image pairs skipped (no gyro rotation, too few common tracks).
    pub pairs_skipped: usize,
    /// Track steps checked.
    pub steps: usize,
    /// Steps farther than each of [`THRESHOLDS_PX`] from their epipolar line.
    pub violations: [usize; 3],
    /// Tracks with at least one violating step, per threshold.
    pub tracks_violating: [usize; 3],
    /// Tracks with at least one checked step.
    pub tracks: usize,
    /// Median distance of a step from its epipolar line, px.
    pub median_px: f64,
}

impl EpipolarReport {
    /// Violating share of the steps at threshold `k` of [`THRESHOLDS_PX`].
    pub fn step_share(&self, k: usize) -> f64 {
        self.violations.get(k).map_or(0.0, |&v| v as f64) / self.steps.max(1) as f64
    }

    /// Share of the tracks with a violating step at threshold `k`.
    pub fn track_share(&self, k: usize) -> f64 {
        self.tracks_violating.get(k).map_or(0.0, |&v| v as f64) / self.tracks.max(1) as f64
    }
}

/// Distance of `x1` from the epipolar line `t x y` (normalized plane, z = 1 points), in units
/// of the normalized plane; `None` for a degenerate line.
fn line_distance(t: &Vec3, y: &Vec3, x1: &Vec3) -> Option<f64> {
    let l = t.cross(y);
    let n = l.x.hypot(l.y);
    (n > 1e-15).then(|| (l.dot(x1)).abs() / n)
}

/// Distances of every step from its epipolar line for the translation direction fitted to
/// them (see the module docs); `y` are the derotated previous positions `R x0`, `x1` the
/// current ones (normalized, z = 1).
fn distances(y: &[Vec3], x1: &[Vec3], fit_tol: f64) -> Vec<f64> {
    let m: Vec<Vec3> = y.iter().zip(x1).map(|(a, b)| a.cross(b)).collect();
    let n = m.len();
    // Pure rotation: the derotated displacement itself.
    let derot: Vec<f64> = y
        .iter()
        .zip(x1)
        .map(|(a, b)| (a.x / a.z - b.x).hypot(a.y / a.z - b.y))
        .collect();
    let mut best: Option<(usize, Vec3)> = None;
    // Deterministic sample pairs.
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    for _ in 0..300 {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let (i, j) = ((s % n as u64) as usize, ((s >> 32) % n as u64) as usize);
        if i == j {
            continue;
        }
        let t = m[i].cross(&m[j]);
        if t.norm() < 1e-15 {
            continue;
        }
        let t = t.normalize();
        let inl = (0..n)
            .filter(|&k| line_distance(&t, &y[k], &x1[k]).is_some_and(|d| d < fit_tol))
            .count();
        if best.as_ref().is_none_or(|b| inl > b.0) {
            best = Some((inl, t));
        }
    }
    let Some((_, mut t)) = best else {
        return derot;
    };
    // Least squares on the inliers: t minimizes sum (t . m_k)^2.
    let mut a = Matrix3::zeros();
    for k in 0..n {
        if line_distance(&t, &y[k], &x1[k]).is_some_and(|d| d < fit_tol) {
            a += m[k] * m[k].transpose();
        }
    }
    let eig = SymmetricEigen::new(a);
    let (mut kmin, mut vmin) = (0, f64::INFINITY);
    for (k, &v) in eig.eigenvalues.iter().enumerate() {
        if v < vmin {
            (kmin, vmin) = (k, v);
        }
    }
    let refined: Vec3 = eig.eigenvectors.column(kmin).into_owned();
    if refined.norm() > 0.5 {
        t = refined.normalize();
    }
    (0..n)
        .map(|k| line_distance(&t, &y[k], &x1[k]).map_or(derot[k], |d| d.min(derot[k])))
        .collect()
}

/// Checks the steps of `frames` (tracks in raw pixels of `cam`) against the gyro of `imu`
/// (`r_bc`: camera to body rotation, `td_s`: `t_imu = t_cam + td`). See the module docs.
pub fn check(
    frames: &[FeatureFrame],
    imu: &[ImuSample],
    cam: &PinholeCamera,
    r_bc: &Mat3,
    td_s: f64,
) -> EpipolarReport {
    let f = 0.5 * (cam.fx.abs() + cam.fy.abs());
    let td_ns = (td_s * 1e9).round() as i64;
    let mut gyro: Box<GyroIntegrator<GYRO_SAMPLES>> = Box::new(GyroIntegrator::new());
    let mut ii = 0usize;
    let mut rep = EpipolarReport {
        pairs: 0,
        pairs_skipped: 0,
        steps: 0,
        violations: [0; 3],
        tracks_violating: [0; 3],
        tracks: 0,
        median_px: f64::NAN,
    };
    let mut all = Vec::new();
    let mut worst: HashMap<u64, f64> = HashMap::new();
    for w in frames.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        // The gyro a little past the interval (offline: the whole interval is known).
        while let Some(s) = imu
            .get(ii)
            .filter(|s| s.t_ns <= b.t_ns.saturating_add(td_ns) + 10_000_000)
        {
            gyro.push(s.t_ns, &s.gyro_rps);
            ii += 1;
        }
        let Some(r) = gyro.camera_rotation(a.t_ns, b.t_ns, td_s, &Vec3::zeros(), r_bc) else {
            rep.pairs_skipped += 1;
            continue;
        };
        let prev: HashMap<u64, (f64, f64)> =
            a.obs.iter().map(|o| (o.id, (o.u_px, o.v_px))).collect();
        let (mut ids, mut y, mut x1) = (Vec::new(), Vec::new(), Vec::new());
        for o in &b.obs {
            let Some(&(u0, v0)) = prev.get(&o.id) else {
                continue;
            };
            let (Ok(p0), Ok(p1)) = (cam.undistort(u0, v0), cam.undistort(o.u_px, o.v_px)) else {
                continue;
            };
            ids.push(o.id);
            y.push(r * p0);
            x1.push(p1);
        }
        if ids.len() < 8 {
            rep.pairs_skipped += 1;
            continue;
        }
        rep.pairs += 1;
        let d = distances(&y, &x1, 1.0 / f);
        for (id, dk) in ids.iter().zip(&d) {
            let px = dk * f;
            rep.steps += 1;
            all.push(px);
            for (k, thr) in THRESHOLDS_PX.iter().enumerate() {
                rep.violations[k] += usize::from(px > *thr);
            }
            let e = worst.entry(*id).or_insert(0.0);
            *e = e.max(px);
        }
    }
    rep.tracks = worst.len();
    for (k, thr) in THRESHOLDS_PX.iter().enumerate() {
        rep.tracks_violating[k] = worst.values().filter(|&&v| v > *thr).count();
    }
    if !all.is_empty() {
        all.sort_by(f64::total_cmp);
        rep.median_px = all[all.len() / 2];
    }
    rep
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::{Distortion, FeatureObs};
    use povins_core::math::exp_so3;

    /// A camera translating along x and yawing (body = camera): true tracks pass, tracks
    /// displaced by 3 px across their epipolar line fail.
    #[test]
    fn true_steps_pass_and_displaced_steps_fail() {
        let cam = PinholeCamera {
            readout_s: 0.0,
            width: 640,
            height: 480,
            fx: 400.0,
            fy: 400.0,
            cx: 320.0,
            cy: 240.0,
            distortion: Distortion::None,
        };
        let rate = Vec3::new(0.0, 0.3, 0.0);
        let imu: Vec<ImuSample> = (0..400)
            .map(|k| ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: rate,
                accel_mps2: Vec3::new(0.0, 0.0, 9.81),
            })
            .collect();
        // World points at 3..8 m; camera k at x = 0.1 k m, rotated about y by 0.3 rad/s x 0.1 s.
        let pts: Vec<Vec3> = (0..60)
            .map(|i| {
                let i = f64::from(i);
                Vec3::new(
                    -2.0 + 0.07 * i,
                    -1.0 + 0.033 * (i * 1.7 % 60.0),
                    3.0 + (i % 5.0),
                )
            })
            .collect();
        let frames: Vec<FeatureFrame> = (0..8)
            .map(|k| {
                let t = f64::from(k) * 0.1;
                let r_wc = exp_so3(&(rate * t));
                let p_wc = Vec3::new(0.1 * f64::from(k), 0.0, 0.0);
                let obs = pts
                    .iter()
                    .enumerate()
                    .filter_map(|(i, p)| {
                        let pc = r_wc.transpose() * (p - p_wc);
                        let uv = cam.project(&pc)?;
                        // Tracks 0..5 are pushed 3 px off (across x) from frame 4 on.
                        let off = if i < 5 && k >= 4 { 3.0 } else { 0.0 };
                        Some(FeatureObs {
                            id: i as u64,
                            u_px: uv.x,
                            v_px: uv.y + off,
                        })
                    })
                    .collect();
                FeatureFrame {
                    t_ns: i64::from(k) * 100_000_000,
                    obs,
                }
            })
            .collect();
        let rep = check(&frames, &imu, &cam, &Mat3::identity(), 0.0);
        assert_eq!(rep.pairs, 7);
        assert!(rep.median_px < 1e-6, "{rep:?}");
        // Only the step into frame 4 of tracks 0..5 moves across the line.
        assert_eq!(rep.tracks_violating[1], 5, "{rep:?}");
        assert_eq!(rep.violations[1], 5, "{rep:?}");
    }
}

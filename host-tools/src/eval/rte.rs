//! Relative trajectory error over distance segments, as OpenVINS ov_eval
//! `ResultTrajectory::calculate_rpe` defines it, on matched poses after the global alignment:
//!
//! 1. `d_i` is the distance travelled along the matched ground truth up to pose `i`.
//! 2. For a segment length `L` and every start `i`, the end `j >= i` is the first pose with the
//!    smallest `|d_j - (d_i + L)|`; the segment exists only when that is below
//!    [`MAX_SEGMENT_LENGTH_ERROR_M`] (0.5 m, ov_eval's `max_dist_diff`).
//! 3. With `T_ab` the pose of `b` in `a`, the relative motions are
//!    `T_gt = T_w,gt_i^-1 T_w,gt_j` and `T_est = T_w,est_i^-1 T_w,est_j`, and the error is
//!    `E = T_gt^-1 T_est`: position error `|t_E|` (m), rotation error `|Log(R_E)|` (deg).
//!    ov_eval rotates `E` into the world before taking norms; norms do not change under that
//!    rotation, so we skip it.
//!
//! Expressing both motions in the frame of the segment's start pose is what "aligning each
//! segment at its start" means: the errors are free of the drift accumulated before `i`. Only
//! the global Sim3 scale (when fitted) changes them.
//!
//! Statistics use evo's definitions ([`super::stats`]), not ov_eval's sample `std`.

use super::ate::rotation_error_deg;
use super::stats::Stats;
use povins_platform::trajectory::StampedPose;

/// Largest allowed difference between a segment's travelled length and the requested one, m.
pub const MAX_SEGMENT_LENGTH_ERROR_M: f64 = 0.5;

/// RTE over all segments of one length.
#[derive(Debug, Clone, PartialEq)]
pub struct RteSegment {
    /// Requested segment length, m.
    pub segment_m: f64,
    /// Number of segments found.
    pub pairs: usize,
    /// Position error statistics, m (`None` when no segment of this length exists).
    pub pos_m: Option<Stats>,
    /// Rotation error statistics, degrees.
    pub rot_deg: Option<Stats>,
}

/// Cumulative distance along `poses`, starting at 0.
pub fn travelled_m(poses: &[StampedPose]) -> Vec<f64> {
    let mut out = Vec::with_capacity(poses.len());
    let mut d = 0.0;
    for (i, p) in poses.iter().enumerate() {
        if let Some(prev) = i.checked_sub(1).and_then(|k| poses.get(k)) {
            d += (p.p_wb - prev.p_wb).norm();
        }
        out.push(d);
    }
    out
}

/// End index of the segment of length `length_m` starting at `start` (ov_eval's rule: the first
/// pose with the smallest length error, if below the limit). `dist` must be non-decreasing.
pub fn segment_end(dist: &[f64], start: usize, length_m: f64) -> Option<usize> {
    let d0 = *dist.get(start)?;
    let tail = &dist[start..];
    let target = d0 + length_m;
    let above = start + tail.partition_point(|&d| d < target);
    let after = dist.get(above).map(|&d| (above, d - target));
    // The last pose below the target, moved back to the first pose with the same distance
    // (a stationary stretch), since ties go to the earliest index.
    let before = above.checked_sub(1).filter(|&b| b >= start).map(|b| {
        let db = dist[b];
        (start + tail.partition_point(|&d| d < db), target - db)
    });
    let best = match (before, after) {
        (Some(b), Some(a)) => Some(if b.1 <= a.1 { b } else { a }),
        (b, a) => b.or(a),
    }?;
    (best.1 < MAX_SEGMENT_LENGTH_ERROR_M).then_some(best.0)
}

/// Relative error of the motion from pose `i` to pose `j`: (position m, rotation deg).
fn relative_error(
    gt_i: &StampedPose,
    gt_j: &StampedPose,
    est_i: &StampedPose,
    est_j: &StampedPose,
) -> (f64, f64) {
    let q_gt = gt_i.q_wb.inverse() * gt_j.q_wb;
    let t_gt = gt_i.q_wb.inverse() * (gt_j.p_wb - gt_i.p_wb);
    let q_est = est_i.q_wb.inverse() * est_j.q_wb;
    let t_est = est_i.q_wb.inverse() * (est_j.p_wb - est_i.p_wb);
    // E = T_gt^-1 T_est = (R_gt^T R_est, R_gt^T (t_est - t_gt)); |R_gt^T x| = |x|.
    ((t_est - t_gt).norm(), rotation_error_deg(&q_gt, &q_est))
}

/// RTE for each length in `segments_m` over matched `gt[k]` / aligned `est[k]` pairs.
pub fn rte(gt: &[StampedPose], est: &[StampedPose], segments_m: &[f64]) -> Vec<RteSegment> {
    let dist = travelled_m(gt);
    segments_m
        .iter()
        .map(|&length_m| {
            let mut pos = Vec::new();
            let mut rot = Vec::new();
            for i in 0..gt.len().min(est.len()) {
                let Some(j) = segment_end(&dist, i, length_m) else {
                    continue;
                };
                let (Some(gj), Some(ej)) = (gt.get(j), est.get(j)) else {
                    continue;
                };
                let (e_p, e_r) = relative_error(&gt[i], gj, &est[i], ej);
                pos.push(e_p);
                rot.push(e_r);
            }
            RteSegment {
                segment_m: length_m,
                pairs: pos.len(),
                pos_m: Stats::from_values(&pos),
                rot_deg: Stats::from_values(&rot),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::testutil::Rng;
    use povins_core::math::{quat_exp, Quat, Vec3};

    /// ov_eval's O(n^2) search, verbatim in behaviour.
    fn segment_end_reference(dist: &[f64], start: usize, length_m: f64) -> Option<usize> {
        let mut best = None;
        let mut best_err = MAX_SEGMENT_LENGTH_ERROR_M;
        for (i, &d) in dist.iter().enumerate().skip(start) {
            let e = (d - (dist[start] + length_m)).abs();
            if e < best_err {
                best = Some(i);
                best_err = e;
            }
        }
        best
    }

    #[test]
    fn binary_search_end_matches_ov_eval_search() {
        let mut rng = Rng::new(5);
        let mut dist = vec![0.0];
        for k in 1..400 {
            // Stationary stretches (equal distances), exact quarter-metre steps (ties) and jumps.
            let step = match k % 7 {
                0 | 1 => 0.0,
                2 => 0.25,
                3 => 1.3,
                _ => 0.2 * (rng.next() + 1.0),
            };
            dist.push(dist[k - 1] + step);
        }
        for length in [0.5, 1.0, 2.0, 8.0, 16.0, 1000.0] {
            for start in 0..dist.len() {
                assert_eq!(
                    segment_end(&dist, start, length),
                    segment_end_reference(&dist, start, length),
                    "start {start} length {length}"
                );
            }
        }
    }

    fn pose(k: usize, p: Vec3, q: Quat) -> StampedPose {
        StampedPose {
            t_ns: k as i64 * 100_000_000,
            p_wb: p,
            q_wb: q,
        }
    }

    #[test]
    fn known_drift_gives_known_relative_errors() {
        // Straight line along x at 0.25 m per pose (exact in binary), facing along x.
        let n = 300;
        let gt: Vec<StampedPose> = (0..n)
            .map(|k| pose(k, Vec3::new(0.25 * k as f64, 0.0, 0.0), Quat::identity()))
            .collect();
        // Estimate: 1% too long and yawing 0.01 deg per pose (heading error, path still on x).
        let yaw = |k: usize| (0.01 * k as f64).to_radians();
        let est: Vec<StampedPose> = (0..n)
            .map(|k| {
                let q = quat_exp(&Vec3::new(0.0, 0.0, yaw(k)));
                pose(k, Vec3::new(0.2525 * k as f64, 0.0, 0.0), q)
            })
            .collect();
        let out = rte(&gt, &est, &[8.0, 100.0]);
        // 8 m = 32 poses. Starts 0..=267 end 32 poses later; start 268 ends at the last pose,
        // 0.25 m short (< 0.5 m is accepted); start 269 would be 0.5 m short (rejected).
        let ends: Vec<(usize, usize)> = (0..=268).map(|i| (i, (i + 32).min(n - 1))).collect();
        assert_eq!(out[0].pairs, ends.len());
        assert_eq!(out[1].pairs, 0);
        assert!(out[1].pos_m.is_none() && out[1].rot_deg.is_none());
        let pos: Vec<f64> = ends
            .iter()
            .map(|&(i, j)| {
                // The estimate's motion seen from its own (yawed) start frame vs gt's straight one.
                let (len_est, len_gt) = (0.2525 * (j - i) as f64, 0.25 * (j - i) as f64);
                let a = yaw(i);
                Vec3::new(len_est * a.cos() - len_gt, -len_est * a.sin(), 0.0).norm()
            })
            .collect();
        let rot: Vec<f64> = ends.iter().map(|&(i, j)| 0.01 * (j - i) as f64).collect();
        let (want_p, want_r) = (
            Stats::from_values(&pos).unwrap(),
            Stats::from_values(&rot).unwrap(),
        );
        let (got_p, got_r) = (out[0].pos_m.unwrap(), out[0].rot_deg.unwrap());
        for ((name, g), (_, w)) in got_p.named().iter().zip(want_p.named()) {
            assert!((g - w).abs() < 1e-9, "pos {name}: {g} vs {w}");
        }
        for ((name, g), (_, w)) in got_r.named().iter().zip(want_r.named()) {
            assert!((g - w).abs() < 1e-9, "rot {name}: {g} vs {w}");
        }
        assert!((got_r.max - 0.32).abs() < 1e-9 && (got_p.min - 0.08).abs() < 1e-9);
    }
}

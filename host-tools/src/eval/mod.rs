//! Trajectory evaluation: associate an estimate with ground truth by time, align it, and
//! measure absolute (ATE) and relative (RTE) errors.
//!
//! Pipeline ([`evaluate`]):
//! 1. [`associate`]: nearest-time matching within `t_max_diff_s`, exactly evo's rules.
//! 2. [`align`]: fit `p_w ~= s R_wv p_v + t_wv` on matched positions (posyaw, se3, sim3, none)
//!    and apply it to every matched estimate pose.
//! 3. [`ate`]: per-pose position and rotation errors, summarized with evo's statistics
//!    ([`stats`]).
//! 4. [`rte`]: OpenVINS-style relative errors over travelled-distance segments.
//!
//! [`lidar_assoc`] checks LiDAR-depth associations against the simulator's truth.
//!
//! Frames: the ground truth lives in world `w`, the estimate in its own world `v`; both give
//! the pose of the body `b` ([`StampedPose`]: `p_wb`, `q_wb`).

pub mod align;
pub mod associate;
pub mod ate;
pub mod epipolar;
pub mod lidar_assoc;
pub mod nees;
pub mod report;
pub mod rte;
pub mod stats;
pub mod streamed;
pub mod track_anatomy;
pub mod tracks;

pub use align::{Alignment, Sim3};
pub use report::{EvalReport, MatchedPose};

use anyhow::{bail, Result};
use povins_core::math::Vec3;
use povins_platform::trajectory::{seconds_to_ns, StampedPose};

/// Options of [`evaluate`].
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    /// Which transform to fit before measuring errors.
    pub alignment: Alignment,
    /// Largest stamp difference for a match, s (evo's `--t_max_diff`).
    pub t_max_diff_s: f64,
    /// Added to the estimate's stamps before matching, s (evo's `--t_offset`).
    pub t_offset_s: f64,
    /// RTE segment lengths along the ground truth, m.
    pub segments_m: Vec<f64>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            alignment: Alignment::PosYaw,
            t_max_diff_s: 0.01,
            t_offset_s: 0.0,
            segments_m: vec![8.0, 16.0, 24.0, 32.0, 40.0],
        }
    }
}

/// Count and first and last stamp of a trajectory whose stamps increase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Extent {
    pub(crate) n: usize,
    pub(crate) first: i64,
    pub(crate) last: i64,
}

impl Extent {
    /// Of the stamps `t_ns` of the trajectory `name`; an error when they do not increase or
    /// there are none.
    pub(crate) fn of(name: &str, t_ns: impl IntoIterator<Item = Result<i64>>) -> Result<Extent> {
        let mut e: Option<Extent> = None;
        for t in t_ns {
            let t = t?;
            e = Some(match e {
                None => Extent {
                    n: 1,
                    first: t,
                    last: t,
                },
                Some(e) if t > e.last => Extent {
                    n: e.n + 1,
                    last: t,
                    ..e
                },
                Some(e) => bail!(
                    "the {name} trajectory's stamps do not increase at pose {} ({t} ns after {} \
                     ns)",
                    e.n,
                    e.last
                ),
            });
        }
        e.ok_or_else(|| anyhow::anyhow!("the {name} trajectory has no poses"))
    }
}

fn secs(t_ns: i64) -> f64 {
    t_ns as f64 * 1e-9
}

impl EvalOptions {
    /// An error when an option is out of its range.
    fn check(&self) -> Result<()> {
        if !(self.t_max_diff_s.is_finite() && self.t_max_diff_s >= 0.0) {
            bail!(
                "t_max_diff must be a finite non-negative number of seconds, got {}",
                self.t_max_diff_s
            );
        }
        if !self.t_offset_s.is_finite() {
            bail!("t_offset must be finite, got {}", self.t_offset_s);
        }
        if let Some(bad) = self
            .segments_m
            .iter()
            .find(|&&l| !(l.is_finite() && l > 0.0))
        {
            bail!("RTE segment lengths must be positive metres, got {bad}");
        }
        Ok(())
    }

    /// The tolerance and the estimate's offset, ns.
    fn ns(&self) -> (i64, i64) {
        (
            seconds_to_ns(self.t_max_diff_s),
            seconds_to_ns(self.t_offset_s),
        )
    }

    /// An error when the trajectories cannot overlap in time.
    fn check_overlap(&self, gt: Extent, est: Extent) -> Result<()> {
        let (max_diff_ns, offset_ns) = self.ns();
        let (est0, est1) = (
            est.first.saturating_add(offset_ns),
            est.last.saturating_add(offset_ns),
        );
        if est1.saturating_add(max_diff_ns) < gt.first || est0.saturating_sub(max_diff_ns) > gt.last
        {
            bail!(
                "no overlap in time: ground truth covers [{:.3}, {:.3}] s, the estimate (offset {} \
                 s) covers [{:.3}, {:.3}] s; check the clocks or pass --t-offset",
                secs(gt.first),
                secs(gt.last),
                self.t_offset_s,
                secs(est0),
                secs(est1)
            );
        }
        Ok(())
    }

    /// An error when fewer than 3 poses matched.
    fn check_matched(&self, matched: usize, gt: Extent, est: Extent) -> Result<()> {
        if matched < 3 {
            bail!(
                "only {} pose(s) of {} estimated / {} ground truth matched within {} s (need at \
                 least 3); check the time offset or raise --t-max-diff",
                matched,
                est.n,
                gt.n,
                self.t_max_diff_s
            );
        }
        Ok(())
    }
}

/// Evaluates `est` against `gt`. Errors when the options are invalid, the trajectories do not
/// overlap in time, fewer than 3 poses match, or the alignment is degenerate.
pub fn evaluate(gt: &[StampedPose], est: &[StampedPose], opts: &EvalOptions) -> Result<EvalReport> {
    opts.check()?;
    let gt_ext = Extent::of("ground-truth", gt.iter().map(|p| Ok(p.t_ns)))?;
    let est_ext = Extent::of("estimated", est.iter().map(|p| Ok(p.t_ns)))?;
    opts.check_overlap(gt_ext, est_ext)?;
    let (max_diff_ns, offset_ns) = opts.ns();
    let gt_t: Vec<i64> = gt.iter().map(|p| p.t_ns).collect();
    let est_t: Vec<i64> = est.iter().map(|p| p.t_ns).collect();
    let pairs = associate::associate(&gt_t, &est_t, max_diff_ns, offset_ns);
    opts.check_matched(pairs.len(), gt_ext, est_ext)?;
    let gt_m: Vec<StampedPose> = pairs.iter().map(|p| gt[p.gt]).collect();
    let est_m: Vec<StampedPose> = pairs.iter().map(|p| est[p.est]).collect();
    let est_p: Vec<Vec3> = est_m.iter().map(|p| p.p_wb).collect();
    let gt_p: Vec<Vec3> = gt_m.iter().map(|p| p.p_wb).collect();
    let transform = align::align(opts.alignment, &est_p, &gt_p)?;
    let est_aligned: Vec<StampedPose> = est_m
        .iter()
        .map(|p| StampedPose {
            t_ns: p.t_ns,
            p_wb: transform.apply_position(&p.p_wb),
            q_wb: transform.apply_rotation(&p.q_wb),
        })
        .collect();
    let matches: Vec<MatchedPose> = gt_m
        .iter()
        .zip(&est_aligned)
        .map(|(g, e)| MatchedPose {
            gt: *g,
            est_aligned: *e,
            pos_err_m: ate::position_error_m(&g.p_wb, &e.p_wb),
            rot_err_deg: ate::rotation_error_deg(&g.q_wb, &e.q_wb),
        })
        .collect();
    let pos: Vec<f64> = matches.iter().map(|m| m.pos_err_m).collect();
    let rot: Vec<f64> = matches.iter().map(|m| m.rot_err_deg).collect();
    let (Some(ate_pos_m), Some(ate_rot_deg)) = (
        stats::Stats::from_values(&pos),
        stats::Stats::from_values(&rot),
    ) else {
        bail!("no matched poses");
    };
    Ok(EvalReport {
        alignment: opts.alignment,
        gt_poses: gt.len(),
        est_poses: est.len(),
        matched_poses: matches.len(),
        t_max_diff_s: opts.t_max_diff_s,
        t_offset_s: opts.t_offset_s,
        transform,
        ate_pos_m,
        ate_rot_deg,
        rte: rte::rte(&gt_m, &est_aligned, &opts.segments_m),
        matches,
    })
}

#[cfg(test)]
pub(crate) mod testutil {
    use povins_core::math::Vec3;

    /// Deterministic pseudo-random numbers in [-1, 1) (xorshift64), so tests need no rand crate.
    pub(crate) struct Rng(u64);
    impl Rng {
        pub(crate) fn new(seed: u64) -> Self {
            Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
        }
        pub(crate) fn next(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
        pub(crate) fn vec3(&mut self) -> Vec3 {
            Vec3::new(self.next(), self.next(), self.next())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::testutil::Rng;
    use super::*;
    use povins_core::math::{quat_exp, Quat};

    /// A 3D figure-eight with turning heading, 10 Hz, 60 s.
    fn figure_eight() -> Vec<StampedPose> {
        (0..600)
            .map(|k| {
                let t = k as f64 * 0.1;
                let a = t * 0.3;
                StampedPose {
                    t_ns: 1_000_000_000_000 + k as i64 * 100_000_000,
                    p_wb: Vec3::new(
                        5.0 * a.sin(),
                        3.0 * (2.0 * a).sin(),
                        1.0 + 0.5 * (0.7 * t).sin(),
                    ),
                    q_wb: quat_exp(&Vec3::new(0.1 * (0.5 * t).sin(), 0.05 * t.cos(), a)),
                }
            })
            .collect()
    }

    fn transformed(poses: &[StampedPose], t: &Sim3) -> Vec<StampedPose> {
        // The inverse map: the estimate lives in v, so p_v = R_wv^T (p_w - t) / s.
        poses
            .iter()
            .map(|p| StampedPose {
                t_ns: p.t_ns,
                p_wb: t.q_wv.inverse() * (p.p_wb - t.t_wv) / t.scale,
                q_wb: t.q_wv.inverse() * p.q_wb,
            })
            .collect()
    }

    fn opts(alignment: Alignment) -> EvalOptions {
        EvalOptions {
            alignment,
            ..EvalOptions::default()
        }
    }

    #[test]
    fn exact_copy_in_another_gauge_has_zero_error() {
        let gt = figure_eight();
        let gauge = Sim3 {
            q_wv: Quat::from_axis_angle(&Vec3::z_axis(), 1.2),
            t_wv: Vec3::new(3.0, -4.0, 0.5),
            scale: 1.0,
        };
        let est = transformed(&gt, &gauge);
        for a in [Alignment::PosYaw, Alignment::Se3, Alignment::Sim3] {
            let r = evaluate(&gt, &est, &opts(a)).unwrap();
            assert_eq!(r.matched_poses, 600);
            assert!(r.ate_pos_m.max < 1e-9, "{a:?} {:?}", r.ate_pos_m);
            assert!(r.ate_rot_deg.max < 1e-6, "{a:?} {:?}", r.ate_rot_deg);
            for s in &r.rte {
                assert!(s.pos_m.unwrap().max < 1e-9, "{a:?} {s:?}");
            }
        }
        // Without alignment the gauge itself is the error: every pose is off by the same
        // rotation angle, 1.2 rad.
        let r = evaluate(&gt, &est, &opts(Alignment::None)).unwrap();
        assert!((r.ate_rot_deg.min - 1.2f64.to_degrees()).abs() < 1e-9);
        assert!(r.ate_pos_m.rmse > 1.0, "{:?}", r.ate_pos_m);
    }

    #[test]
    fn known_translation_perturbation_gives_known_rmse() {
        let gt = figure_eight();
        // +-3 cm along z alternating: zero-mean, so no alignment can absorb it; rmse = 3 cm.
        let est: Vec<StampedPose> = gt
            .iter()
            .enumerate()
            .map(|(k, p)| StampedPose {
                p_wb: p.p_wb + Vec3::new(0.0, 0.0, if k % 2 == 0 { 0.03 } else { -0.03 }),
                ..*p
            })
            .collect();
        let r = evaluate(&gt, &est, &opts(Alignment::None)).unwrap();
        assert!((r.ate_pos_m.rmse - 0.03).abs() < 1e-12, "{:?}", r.ate_pos_m);
        assert!(r.ate_pos_m.std < 1e-12);
        // Posyaw's yaw and x-y shift cannot reduce a pure, zero-mean z error either.
        let r = evaluate(&gt, &est, &opts(Alignment::PosYaw)).unwrap();
        assert!((r.ate_pos_m.rmse - 0.03).abs() < 1e-9, "{:?}", r.ate_pos_m);
    }

    #[test]
    fn random_noise_rmse_matches_direct_computation() {
        let gt = figure_eight();
        let mut rng = Rng::new(42);
        let noise: Vec<Vec3> = gt.iter().map(|_| rng.vec3() * 0.05).collect();
        let est: Vec<StampedPose> = gt
            .iter()
            .zip(&noise)
            .map(|(p, n)| StampedPose {
                p_wb: p.p_wb + n,
                ..*p
            })
            .collect();
        let r = evaluate(&gt, &est, &opts(Alignment::None)).unwrap();
        let want =
            (noise.iter().map(|n| n.norm_squared()).sum::<f64>() / noise.len() as f64).sqrt();
        assert!((r.ate_pos_m.rmse - want).abs() < 1e-12);
        // Alignment may only reduce the error of a least-squares fit.
        let se3 = evaluate(&gt, &est, &opts(Alignment::Se3)).unwrap();
        let sim3 = evaluate(&gt, &est, &opts(Alignment::Sim3)).unwrap();
        assert!(se3.ate_pos_m.rmse < want && sim3.ate_pos_m.rmse <= se3.ate_pos_m.rmse + 1e-15);
    }

    #[test]
    fn posyaw_does_not_absorb_roll_or_pitch() {
        let gt = figure_eight();
        // The estimate's world is tilted by 2 deg roll: a gravity error a VIO must not hide.
        let tilt = Sim3 {
            q_wv: quat_exp(&Vec3::new(2f64.to_radians(), 0.0, 0.0)),
            t_wv: Vec3::zeros(),
            scale: 1.0,
        };
        let est = transformed(&gt, &tilt);
        let se3 = evaluate(&gt, &est, &opts(Alignment::Se3)).unwrap();
        assert!(se3.ate_pos_m.max < 1e-9 && se3.ate_rot_deg.max < 1e-6);
        let py = evaluate(&gt, &est, &opts(Alignment::PosYaw)).unwrap();
        assert!(py.ate_pos_m.rmse > 0.05, "{:?}", py.ate_pos_m);
        // Every orientation stays tilted by (about) the 2 deg roll.
        assert!(
            (py.ate_rot_deg.median - 2.0).abs() < 0.1,
            "{:?}",
            py.ate_rot_deg
        );
    }

    #[test]
    fn clear_errors_for_unusable_input() {
        let gt = figure_eight();
        let late: Vec<StampedPose> = gt
            .iter()
            .map(|p| StampedPose {
                t_ns: p.t_ns + 1_000_000_000_000,
                ..*p
            })
            .collect();
        let e = evaluate(&gt, &late, &EvalOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("no overlap in time"), "{e}");
        // Overlapping but interleaved stamps 50 ms apart: nothing within 10 ms.
        let shifted: Vec<StampedPose> = gt
            .iter()
            .map(|p| StampedPose {
                t_ns: p.t_ns + 50_000_000,
                ..*p
            })
            .collect();
        let e = evaluate(&gt, &shifted, &EvalOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("only 0 pose(s)") && e.contains("need at least 3"),
            "{e}"
        );
        // ... unless the offset is given.
        let mut o = EvalOptions {
            t_offset_s: -0.05,
            ..EvalOptions::default()
        };
        assert_eq!(evaluate(&gt, &shifted, &o).unwrap().matched_poses, 600);
        o.segments_m = vec![0.0];
        assert!(evaluate(&gt, &shifted, &o).is_err());
        assert!(evaluate(&gt, &[], &EvalOptions::default()).is_err());
        let mut unsorted = gt.clone();
        unsorted.swap(3, 4);
        let e = evaluate(&unsorted, &gt, &EvalOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("do not increase at pose 4"), "{e}");
    }

    #[test]
    fn same_input_gives_bit_identical_report() {
        let gt = figure_eight();
        let mut rng = Rng::new(9);
        let est: Vec<StampedPose> = gt
            .iter()
            .map(|p| StampedPose {
                p_wb: p.p_wb + rng.vec3() * 0.1,
                ..*p
            })
            .collect();
        let a =
            serde_json::to_string(&evaluate(&gt, &est, &EvalOptions::default()).unwrap()).unwrap();
        let b =
            serde_json::to_string(&evaluate(&gt, &est, &EvalOptions::default()).unwrap()).unwrap();
        assert_eq!(a, b);
    }
}

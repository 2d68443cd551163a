//! The ATE of trajectories read as streams, in passes, without holding them (an hour at
//! 200 Hz is 720,000 poses a side): what `povins run` reports, from its own output and the
//! recording's ground truth, in memory that does not grow with the run.
//!
//! The same rules and arithmetic as [`super::evaluate`] (the same association, the same
//! [`Moments`] in the same order, the same errors), so the figures are the same bits: a pass
//! for the extents (counts, spans, increasing stamps), then over the matched pairs one pass
//! for the means ([`Centering`]), one for the moments ([`Moments`]) and one for the errors.

use super::align::{Centering, Moments};
use super::associate::NearestMatch;
use super::{ate, EvalOptions, Extent};
use anyhow::Result;
use povins_core::math::Quat;
use povins_platform::trajectory::StampedPose;

/// One pass over a trajectory, in increasing time.
pub type PoseStream<'a> = Box<dyn Iterator<Item = Result<StampedPose>> + 'a>;

/// Opens a new pass over a trajectory.
pub type Opener<'o, 'a> = &'o dyn Fn() -> Result<PoseStream<'a>>;

/// What [`ate_rmse`] measures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AteRmse {
    /// Matched poses.
    pub matched: usize,
    /// Position RMSE after the alignment, m.
    pub pos_rmse_m: f64,
    /// Rotation RMSE after the alignment, degrees.
    pub rot_rmse_deg: f64,
    /// The alignment's rotation, from the estimate's world to the ground truth's.
    pub q_align: Quat,
}

/// The ATE RMSE of the estimate `est` against the ground truth `gt` with `opts`' alignment,
/// tolerance and offset (its RTE segments are not used), each opened once per pass. The same
/// errors as [`super::evaluate`], and any error of a stream.
pub fn ate_rmse(gt: Opener<'_, '_>, est: Opener<'_, '_>, opts: &EvalOptions) -> Result<AteRmse> {
    opts.check()?;
    let g = Extent::of("ground-truth", gt()?.map(|p| p.map(|p| p.t_ns)))?;
    let e = Extent::of("estimated", est()?.map(|p| p.map(|p| p.t_ns)))?;
    opts.check_overlap(g, e)?;
    let pass =
        |f: &mut dyn FnMut(&StampedPose, &StampedPose)| matched_pass(gt, est, (g, e), opts, f);
    let mut centering = Centering::default();
    let matched = pass(&mut |g, e| centering.push(&e.p_wb, &g.p_wb))?;
    opts.check_matched(matched, g, e)?;
    let mut moments: Moments = centering.moments();
    pass(&mut |g, e| moments.push(&e.p_wb, &g.p_wb))?;
    let transform = moments.fit(opts.alignment)?;
    let (mut pos_sse, mut rot_sse) = (0.0, 0.0);
    pass(&mut |g, e| {
        let p = ate::position_error_m(&g.p_wb, &transform.apply_position(&e.p_wb));
        let r = ate::rotation_error_deg(&g.q_wb, &transform.apply_rotation(&e.q_wb));
        pos_sse += p * p;
        rot_sse += r * r;
    })?;
    let n = matched as f64;
    Ok(AteRmse {
        matched,
        pos_rmse_m: (pos_sse / n).sqrt(),
        rot_rmse_deg: (rot_sse / n).sqrt(),
        q_align: transform.q_wv,
    })
}

/// One pass over the matched pairs `(ground truth, estimate)` in time order, by
/// [`super::associate::associate`]'s rules: the trajectory with fewer poses is iterated.
/// Returns the number of pairs.
fn matched_pass(
    gt: Opener<'_, '_>,
    est: Opener<'_, '_>,
    (g_ext, e_ext): (Extent, Extent),
    opts: &EvalOptions,
    f: &mut dyn FnMut(&StampedPose, &StampedPose),
) -> Result<usize> {
    let (max_diff_ns, offset_ns) = opts.ns();
    let (mut g_err, mut e_err) = (None, None);
    let g = gt()?
        .map_while(|r| r.map_err(|x| g_err = Some(x)).ok())
        .map(|p| (p.t_ns, p));
    let e = est()?
        .map_while(|r| r.map_err(|x| e_err = Some(x)).ok())
        .map(|p| (p.t_ns, p));
    let mut n = 0;
    if e_ext.n > g_ext.n {
        let span = (e_ext.first, e_ext.last);
        for (g, e) in NearestMatch::new(g, e, span, max_diff_ns, offset_ns) {
            f(&g, &e);
            n += 1;
        }
    } else {
        let span = (g_ext.first, g_ext.last);
        for (e, g) in NearestMatch::new(e, g, span, max_diff_ns, offset_ns.saturating_neg()) {
            f(&g, &e);
            n += 1;
        }
    }
    match g_err.or(e_err) {
        Some(err) => Err(err),
        None => Ok(n),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::testutil::Rng;
    use crate::eval::{evaluate, Alignment};
    use povins_core::math::{quat_exp, Vec3};

    fn trajectory(rng: &mut Rng, n: usize, t0_ns: i64, dt_ns: i64) -> Vec<StampedPose> {
        let mut p = Vec3::zeros();
        (0..n)
            .map(|k| {
                p += rng.vec3() * 0.3 + Vec3::new(0.1, 0.05, 0.0);
                StampedPose {
                    t_ns: t0_ns + k as i64 * dt_ns + (rng.next() * 1e6) as i64,
                    p_wb: p,
                    q_wb: quat_exp(&(rng.vec3() * 2.0)),
                }
            })
            .collect()
    }

    fn opener<'a>(v: &'a [StampedPose]) -> impl Fn() -> Result<PoseStream<'a>> + 'a {
        move || Ok(Box::new(v.iter().copied().map(Ok)) as PoseStream<'_>)
    }

    /// The same bits as the evaluation in memory, whichever side is iterated, with every
    /// alignment and an offset.
    #[test]
    fn the_passes_give_the_evaluation_s_figures_bit_for_bit() {
        let mut rng = Rng::new(3);
        let gt = trajectory(&mut rng, 400, 0, 5_000_000);
        let dense = trajectory(&mut rng, 700, 3_000_000, 2_500_000);
        let sparse = trajectory(&mut rng, 90, 1_000_000, 20_000_000);
        for est in [&dense, &sparse] {
            for alignment in [
                Alignment::PosYaw,
                Alignment::Se3,
                Alignment::Sim3,
                Alignment::None,
            ] {
                for t_offset_s in [0.0, 0.004] {
                    let opts = EvalOptions {
                        alignment,
                        t_offset_s,
                        ..EvalOptions::default()
                    };
                    let want = evaluate(&gt, est, &opts).expect("evaluation");
                    let got = ate_rmse(&opener(&gt), &opener(est), &opts).expect("passes");
                    assert_eq!(got.matched, want.matched_poses);
                    assert_eq!(got.pos_rmse_m.to_bits(), want.ate_pos_m.rmse.to_bits());
                    assert_eq!(got.rot_rmse_deg.to_bits(), want.ate_rot_deg.rmse.to_bits());
                }
            }
        }
    }

    /// The evaluation's errors, and a stream's own error.
    #[test]
    fn errors_are_the_evaluation_s_and_the_stream_s() {
        let mut rng = Rng::new(5);
        let gt = trajectory(&mut rng, 50, 0, 10_000_000);
        let late = trajectory(&mut rng, 50, 100_000_000_000, 10_000_000);
        let opts = EvalOptions::default();
        let want = format!("{:#}", evaluate(&gt, &late, &opts).unwrap_err());
        let got = format!(
            "{:#}",
            ate_rmse(&opener(&gt), &opener(&late), &opts).unwrap_err()
        );
        assert_eq!(got, want);
        assert!(got.contains("no overlap in time"), "{got}");
        let mut backwards = gt.clone();
        backwards.swap(7, 8);
        let want = format!("{:#}", evaluate(&gt, &backwards, &opts).unwrap_err());
        let got = format!(
            "{:#}",
            ate_rmse(&opener(&gt), &opener(&backwards), &opts).unwrap_err()
        );
        assert_eq!(got, want);
        let failing = || -> Result<PoseStream<'_>> {
            Ok(Box::new(
                gt.iter()
                    .copied()
                    .map(Ok)
                    .take(30)
                    .chain([Err(anyhow::anyhow!("row 31 is cut"))]),
            ))
        };
        let got = format!("{:#}", ate_rmse(&opener(&gt), &failing, &opts).unwrap_err());
        assert_eq!(got, "row 31 is cut");
    }
}

//! The pose-only visual measurements of the window's problem (PO-VINS): per usable landmark,
//! the MSC-based LiDAR-depth measurement (`estimator::problem_lidar`), the eliminated-depth
//! measurement (`estimator::problem_visual`), or the paper's two-anchor form with the depth
//! from anchors `(s, e)` (with a direct LiDAR-depth measurement beside it). The two-anchor form
//! is added through the rank structure of anchor `e` when the extrinsic is not estimated
//! ([`add_pose_only_landmark`]), else through dense Jacobian blocks.

use super::config::VisualMode;
use super::problem::{anchor_depth_std, row_major, timed, FactorSet, LandmarkModel, Problem};
use super::window::{Block, Layout};
use crate::factors::inverse_depth_visual::WindowRotations;
use crate::factors::pose_only_visual::{InJ, PoseOnlyAnchors};
use crate::factors::robust::Huber;
use crate::factors::{CamFrame, KeyframePose};
use crate::landmarks::{KfObs, MargPlan};
use crate::math::{Mat3, Vec3};
use crate::solver::{JacobianBlock, NormalEquations, SharedBlock};
use crate::Error;
use heapless::Vec as HVec;
use nalgebra::Matrix2x6;

/// The observations a pose-only landmark's residuals come from, in keyframe order: every
/// valid observation among the first `count` keyframes but the anchor `s`'s, with its keyframe's
/// pose and camera frame; with `only_j`, only that one.
fn residual_obs<'a, const N: usize>(
    obs: &'a [Option<KfObs>; N],
    count: usize,
    s: usize,
    only_j: Option<usize>,
    (poses, frames): (&'a [KeyframePose; N], &'a [CamFrame; N]),
) -> impl Iterator<Item = (usize, &'a KfObs, &'a KeyframePose, &'a CamFrame)> {
    obs.iter()
        .enumerate()
        .take(count)
        .filter(move |&(j, _)| j != s && only_j.is_none_or(|o| o == j))
        .filter_map(move |(j, oj)| Some((j, oj.as_ref()?, poses.get(j)?, frames.get(j)?)))
}

/// Pose-only landmark with only body poses estimated: the geometry of every observation first
/// (a landmark enters the system whole or not at all: `None` when one is degenerate, nothing
/// added), then each residual with its robust weight through a [`SharedBlock`] on anchor `e`.
/// With `only_j`, only that observation's residual (the marginalization of a re-anchored
/// landmark). Returns the robust cost and the number of observations.
fn add_pose_only_landmark<const N: usize, const D: usize>(
    anchors: &PoseOnlyAnchors<'_>,
    obs: &[Option<KfObs>; N],
    count: usize,
    (s, e): (usize, usize),
    (poses, frames, huber, l, rel_js): (
        &[KeyframePose; N],
        &[CamFrame; N],
        &Huber,
        &Layout<N>,
        &impl Fn(usize) -> Option<(Mat3, Vec3)>,
    ),
    only_j: Option<usize>,
    ne: &mut NormalEquations<D>,
) -> Result<Option<(f64, u32)>, Error> {
    let mut geo: HVec<(usize, InJ<'_>), N> = HVec::new();
    for (j, oj, pj, fj) in residual_obs(obs, count, s, only_j, (poses, frames)) {
        let Some(rel) = rel_js(j) else {
            return Ok(None);
        };
        match anchors.geometry(j, &timed(oj), pj, fj, Some(rel)) {
            Ok(g) => {
                let _ = geo.push((j, g));
            }
            Err(_) => return Ok(None),
        }
    }
    let col = |k: usize| l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch);
    let td_col = |k: usize| l.col(Block::Td(k as u8));
    let (cs, ce) = (col(s)?, col(e)?);
    let shared_e = anchors.shared_e();
    let mut acc = SharedBlock::new(ne, shared_e, cs, ce)?;
    let mut cost = 0.0;
    for (j, g) in geo.iter() {
        let sq = anchors.whitened(g).norm_squared();
        cost += huber.rho(sq)[0];
        let w = huber.sqrt_weight(sq);
        let pb = anchors.pose_blocks(g, w);
        let cj = col(*j)?;
        if *j == e {
            let on_e = pb.q * shared_e + pb.d_pose_j;
            ne.add_2x6_blocks(&pb.r, &[pb.d_pose_s, on_e], &[cs, ce])?;
        } else {
            acc.add(ne, &pb.r, &pb.q, &pb.d_pose_s, &pb.d_pose_j, cj)?;
        }
        // Delay columns (after every pose column in the solve layout).
        let (Some(ts), Some(te), Some(Some(oj))) = (td_col(s), td_col(e), obs.get(*j)) else {
            continue;
        };
        let t = anchors.td_jacobians(g, w, &timed(oj));
        let mut poses: HVec<(usize, Matrix2x6<f64>), 3> = HVec::new();
        let _ = poses.push((cs, pb.d_pose_s));
        if *j == e {
            let _ = poses.push((ce, pb.q * shared_e + pb.d_pose_j));
        } else {
            let _ = poses.push((ce, pb.q * shared_e));
            let _ = poses.push((cj, pb.d_pose_j));
        }
        let tj = if *j == e { None } else { td_col(*j) };
        let tds = [(Some(ts), t[0]), (Some(te), t[1]), (tj, t[2])];
        ne.add_scalar_columns(&pb.r, &tds, &poses)?;
    }
    acc.finish(ne);
    Ok(Some((cost, geo.len() as u32)))
}

/// Pose-only landmark through dense Jacobian blocks (the extrinsic estimated), or only its robust
/// cost without `ne`: every observation first (a landmark enters the system whole or not at all:
/// `None` when one is degenerate, nothing added), then each residual with its robust weight,
/// on the poses of `s`, `e` and `j`, the extrinsic and the delays as estimated. With `only_j`,
/// only that observation's residual. Returns the robust cost and the number of observations.
#[allow(clippy::too_many_arguments)]
fn add_pose_only_landmark_dense<const N: usize, const D: usize>(
    anchors: &PoseOnlyAnchors<'_>,
    obs: &[Option<KfObs>; N],
    count: usize,
    (s, e): (usize, usize),
    (poses, frames, huber, l, rel_js): (
        &[KeyframePose; N],
        &[CamFrame; N],
        &Huber,
        &Layout<N>,
        &impl Fn(usize) -> Option<(Mat3, Vec3)>,
    ),
    only_j: Option<usize>,
    (est_td, est_ext): (bool, bool),
    ne: Option<&mut NormalEquations<D>>,
) -> Result<Option<(f64, u32)>, Error> {
    let linearize = ne.is_some();
    let mut lm_cost = 0.0;
    let mut n_obs = 0;
    let mut failed = false;
    // Evaluate every observation first: a landmark enters the system whole or not at all.
    let mut jacs: HVec<(usize, crate::factors::pose_only_visual::PoseOnlyJacobians), N> =
        HVec::new();
    for (j, oj, pj, fj) in residual_obs(obs, count, s, only_j, (poses, frames)) {
        let obs_j = timed(oj);
        if linearize {
            match anchors.evaluate(j, &obs_j, pj, fj) {
                Ok(jac) => {
                    let _ = jacs.push((j, jac));
                }
                Err(_) => failed = true,
            }
        } else {
            let g = match rel_js(j) {
                Some(rel) => anchors.geometry(j, &obs_j, pj, fj, Some(rel)),
                None => Err(Error::DimensionMismatch),
            };
            match g.map(|g| anchors.whitened(&g)) {
                Ok(r) => {
                    lm_cost += huber.rho(r.norm_squared())[0];
                    n_obs += 1;
                }
                Err(_) => failed = true,
            }
        }
    }
    if failed {
        return Ok(None);
    }
    if let Some(ne_ref) = ne {
        for (j, jac) in jacs.iter() {
            let j = *j;
            let sq = jac.r.norm_squared();
            let w = huber.sqrt_weight(sq);
            lm_cost += huber.rho(sq)[0];
            n_obs += 1;
            let r = [jac.r.x * w, jac.r.y * w];
            let (mut a, mut b, mut c, mut x) = ([0.0; 12], [0.0; 12], [0.0; 12], [0.0; 12]);
            row_major(&(jac.d_pose_s * w), &mut a);
            row_major(&(jac.d_pose_e * w), &mut b);
            row_major(&(jac.d_pose_j * w), &mut c);
            row_major(&(jac.d_ext * w), &mut x);
            let td = [jac.d_td[0] * w, jac.d_td[1] * w, jac.d_td[2] * w];
            let tds = [[td[0].x, td[0].y], [td[1].x, td[1].y], [td[2].x, td[2].y]];
            let mut blocks: HVec<JacobianBlock<'_>, 8> = HVec::new();
            let col = |b: Block| l.col(b).ok_or(Error::DimensionMismatch);
            let _ = blocks.push(JacobianBlock::new(col(Block::Kf(s as u8))?, 6, &a));
            let _ = blocks.push(JacobianBlock::new(col(Block::Kf(e as u8))?, 6, &b));
            if j != e {
                let _ = blocks.push(JacobianBlock::new(col(Block::Kf(j as u8))?, 6, &c));
            }
            if est_ext {
                let _ = blocks.push(JacobianBlock::new(col(Block::Ext)?, 6, &x));
            }
            if est_td {
                let _ = blocks.push(JacobianBlock::new(col(Block::Td(s as u8))?, 1, &tds[0]));
                let _ = blocks.push(JacobianBlock::new(col(Block::Td(e as u8))?, 1, &tds[1]));
                if j != e {
                    let _ = blocks.push(JacobianBlock::new(col(Block::Td(j as u8))?, 1, &tds[2]));
                }
            }
            ne_ref.add_blocks(&r, &blocks)?;
        }
    }
    Ok(Some((lm_cost, n_obs)))
}

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    /// Which observations of a usable landmark with marginalization plan `marg` the visited
    /// set ([`Problem::set`]) takes: `Some(None)` all of them, `Some(Some(j))` only `j`, `None`
    /// none (the landmark is skipped).
    fn visited_obs(&self, marg: MargPlan) -> Option<Option<usize>> {
        // Marginalization: the landmarks the plan involves (in the inverse-depth mode only
        // the re-anchored ones: the others leave with their depth in `inverse_depth_visual`).
        Some(match (self.set, marg, self.cfg.mode) {
            (FactorSet::All, _, _) => None,
            // The whole factor, less what stays (`FactorSet::OldestRest`).
            (
                FactorSet::Oldest | FactorSet::OldestRest,
                MargPlan::ObsZero,
                VisualMode::PoseOnly,
            ) if self.cfg.depth_eliminated() => None,
            (FactorSet::Oldest, MargPlan::ObsZero, _) => Some(0),
            (FactorSet::Oldest, MargPlan::Whole | MargPlan::Reuse, VisualMode::PoseOnly) => None,
            _ => return None,
        })
    }

    pub(super) fn pose_only_visual(
        &mut self,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        est_ext: bool,
    ) -> Result<f64, Error> {
        let huber = Huber::new(self.cfg.huber_delta)?;
        let sqrt_info = self.sqrt_info();
        let l = self.layout;
        let count = self.window.len();
        let ext = *self.ext;
        let poses = self.window.poses();
        // Camera frames once per keyframe rather than three times per residual.
        let frames: [CamFrame; N] = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        // Relative poses `(R_js, t_js)` once per keyframe pair rather than per observation,
        // formed on first use (landmarks whose depth is eliminated do not need them).
        let mut rel_cache: Option<[[(Mat3, Vec3); N]; N]> = None;
        let relative_poses = || -> [[(Mat3, Vec3); N]; N] {
            core::array::from_fn(|j| {
                core::array::from_fn(|s| match (frames.get(j), frames.get(s)) {
                    (Some(fj), Some(fs)) if j < count && s < count => fj.relative_from(fs),
                    _ => (Mat3::identity(), Vec3::zeros()),
                })
            })
        };
        let mut cost = 0.0;
        let linearize = ne.is_some();
        // The eliminated landmarks' linearization: rotations once per assembly, not per residual.
        let rot = (linearize && !est_ext && self.cfg.depth_eliminated())
            .then(|| WindowRotations::new(&poses, count, &ext));
        // Extrinsic not estimated: the landmark's products on anchor e go through the rank
        // structure (`add_pose_only_landmark`), the delays as scalar columns.
        let fast = linearize && !est_ext;
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if !lm.usable {
                continue;
            }
            let Some(only_j) = self.visited_obs(lm.marg) else {
                continue;
            };
            let model = LandmarkModel::of(self.cfg, lm);
            let lidar = model == LandmarkModel::DirectLidar;
            if model == LandmarkModel::MscLidar {
                match self.msc_landmark(li, ne, &poses, &frames, &ext, &huber, est_td, est_ext) {
                    Ok((c, n)) => {
                        cost += c;
                        self.counts.landmarks += 1;
                        self.counts.observations += n;
                        self.counts.ldm += 1;
                    }
                    Err(_) if linearize => {
                        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                            lm.usable = false;
                        }
                        self.counts.disabled += 1;
                    }
                    Err(_) => return Err(Error::Degenerate),
                }
                continue;
            }
            if model == LandmarkModel::Eliminated && only_j.is_none() {
                let er = (&ext, rot.as_ref());
                match self.eliminated_landmark(li, ne, &poses, &frames, er, &huber, est_td, est_ext)
                {
                    Ok((c, n)) => {
                        cost += c;
                        self.counts.landmarks += 1;
                        self.counts.observations += n;
                    }
                    Err(_) if linearize => {
                        if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                            lm.usable = false;
                        }
                        self.counts.disabled += 1;
                    }
                    Err(_) => return Err(Error::Degenerate),
                }
                continue;
            }
            let (s, Some(e)) = (lm.anchor_s as usize, lm.anchor_e.map(usize::from)) else {
                continue;
            };
            let (Some(Some(os)), Some(Some(oe))) = (lm.obs.get(s), lm.obs.get(e)) else {
                continue;
            };
            let (Some(ps), Some(pe)) = (poses.get(s), poses.get(e)) else {
                continue;
            };
            let (Some(fs), Some(fe)) = (frames.get(s), frames.get(e)) else {
                continue;
            };
            let mut lm_cost = 0.0;
            let mut n_obs = 0;
            let mut failed = false;
            let rel = &*rel_cache.get_or_insert_with(relative_poses);
            let rel_js = |j: usize| rel.get(j).and_then(|row| row.get(s)).copied();
            let Some(rel_es) = rel_js(e) else {
                continue;
            };
            match PoseOnlyAnchors::new(
                (s, e),
                timed(os),
                timed(oe),
                sqrt_info,
                (ps, pe),
                (fs, fe),
                &ext,
                Some(rel_es),
            )
            .map(|a| {
                let sd = anchor_depth_std(self.cfg, &a);
                a.with_depth_std(sd)
            }) {
                Err(_) => failed = true,
                Ok(anchors) if fast => {
                    if let Some(ne_ref) = ne.as_deref_mut() {
                        let ctx = (&poses, &frames, &huber, &l, &rel_js);
                        let obs = &lm.obs;
                        match add_pose_only_landmark(
                            &anchors,
                            obs,
                            count,
                            (s, e),
                            ctx,
                            only_j,
                            ne_ref,
                        )? {
                            Some((c, n)) => {
                                lm_cost = c;
                                n_obs = n;
                            }
                            None => failed = true,
                        }
                    }
                }
                Ok(anchors) => {
                    let ctx = (&poses, &frames, &huber, &l, &rel_js);
                    match add_pose_only_landmark_dense(
                        &anchors,
                        &lm.obs,
                        count,
                        (s, e),
                        ctx,
                        only_j,
                        (est_td, est_ext),
                        ne.as_deref_mut(),
                    )? {
                        Some((c, n)) => {
                            lm_cost = c;
                            n_obs = n;
                        }
                        None => failed = true,
                    }
                }
            }
            if failed {
                if linearize {
                    if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                        lm.usable = false;
                    }
                    self.counts.disabled += 1;
                } else {
                    return Err(Error::Degenerate);
                }
            }
            if lidar && !failed {
                // Direct LDM beside the visual measurements; a degenerate depth geometry only
                // drops the depth measurement (the visual ones were fine).
                match self.direct_depth(li, ne, &poses, &ext, &huber, est_td, est_ext) {
                    Ok(c) => {
                        lm_cost += c;
                        self.counts.ldm += 1;
                    }
                    Err(_) if linearize => {}
                    Err(_) => return Err(Error::Degenerate),
                }
            }
            if n_obs > 0 {
                self.counts.landmarks += 1;
                self.counts.observations += n_obs;
            }
            cost += lm_cost;
        }
        Ok(cost)
    }
}

//! The paper's pose-only visual measurement of a landmark ([`TwoViewLandmark`], PO-VINS): every
//! observation `j != s` reprojected with the depth from the anchors `(s, e)`
//! ([`crate::factors::pose_only_visual`]), Huber on each. Added through the rank structure of
//! anchor `e` when the extrinsic is not estimated ([`add_pose_only_landmark`]), else through dense
//! Jacobian blocks. A landmark enters the system whole or not at all: one degenerate
//! observation makes the measurement an error.
#![deny(clippy::too_many_lines)]

use super::factor::{anchor_depth_std, row_major};
use super::factor::{put_rows, timed, LandmarkFactor, VisualSettings, WindowFactor, WindowVars};
use crate::estimator::window::{Block, Layout};
use crate::factors::pose_only_visual::{InJ, PoseOnlyAnchors};
use crate::factors::robust::Huber;
use crate::factors::{CamFrame, KeyframePose};
use crate::landmarks::{KfObs, Landmark};
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
#[inline(never)]
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
#[inline(never)]
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

/// The two-view pose-only measurement of a landmark (module docs): its observations `j != s`
/// (with `only_j`, only that one: the marginalization of a re-anchored landmark's observation at
/// position 0) against its anchors `(s, e)`.
pub struct TwoViewLandmark<'a, const N: usize> {
    vs: VisualSettings<'a>,
    obs: &'a [Option<KfObs>; N],
    s: usize,
    e: usize,
    only_j: Option<usize>,
    n_obs: u32,
}

impl<'a, const N: usize> TwoViewLandmark<'a, N> {
    /// The measurement of `lm`, or `None` without a second anchor or without the anchors'
    /// observations.
    pub fn new(vs: VisualSettings<'a>, lm: &'a Landmark<N>, only_j: Option<usize>) -> Option<Self> {
        let (s, e) = (lm.anchor_s as usize, usize::from(lm.anchor_e?));
        let (Some(Some(_)), Some(Some(_))) = (lm.obs.get(s), lm.obs.get(e)) else {
            return None;
        };
        Some(TwoViewLandmark {
            vs,
            obs: &lm.obs,
            s,
            e,
            only_j,
            n_obs: 0,
        })
    }

    /// The anchors' part of the measurement at `v` (with the depth-uncertainty weighting).
    fn anchors<'v>(&self, v: &'v WindowVars<'_, N>) -> Result<PoseOnlyAnchors<'v>, Error> {
        let (s, e) = (self.s, self.e);
        let (Some(Some(os)), Some(Some(oe))) = (self.obs.get(s), self.obs.get(e)) else {
            return Err(Error::NotEnoughData);
        };
        let (Some(ps), Some(pe)) = (v.poses.get(s), v.poses.get(e)) else {
            return Err(Error::DimensionMismatch);
        };
        let (Some(fs), Some(fe)) = (v.frames.get(s), v.frames.get(e)) else {
            return Err(Error::DimensionMismatch);
        };
        let rel_es = v.relative(e, s).ok_or(Error::DimensionMismatch)?;
        let anchors = PoseOnlyAnchors::new(
            (s, e),
            timed(os),
            timed(oe),
            self.vs.sqrt_info,
            (ps, pe),
            (fs, fe),
            v.ext,
            Some(rel_es),
        )?;
        let sd = anchor_depth_std(self.vs.cfg, &anchors);
        Ok(anchors.with_depth_std(sd))
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for TwoViewLandmark<'_, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        self.n_obs = 0;
        let anchors = self.anchors(v)?;
        let rel_js = |j: usize| v.relative(j, self.s);
        let ctx = (&v.poses, &v.frames, &self.vs.huber, &v.layout, &rel_js);
        let (s, e, count) = (self.s, self.e, v.count);
        let added = match ne {
            // Extrinsic not estimated: the landmark's products on anchor e go through the rank
            // structure, the delays as scalar columns.
            Some(ne) if !v.est_ext => {
                add_pose_only_landmark(&anchors, self.obs, count, (s, e), ctx, self.only_j, ne)?
            }
            ne => add_pose_only_landmark_dense(
                &anchors,
                self.obs,
                count,
                (s, e),
                ctx,
                self.only_j,
                (v.est_td, v.est_ext),
                ne,
            )?,
        };
        let (cost, n_obs) = added.ok_or(Error::Degenerate)?;
        self.n_obs = n_obs;
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let anchors = self.anchors(v)?;
        let mut rows = 0;
        let frames = (&v.poses, &v.frames);
        for (j, oj, pj, fj) in residual_obs(self.obs, v.count, self.s, self.only_j, frames) {
            let g = anchors.geometry(j, &timed(oj), pj, fj, v.relative(j, self.s))?;
            let r = anchors.whitened(&g);
            rows += put_rows(&[r.x, r.y], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        Ok(rows)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for TwoViewLandmark<'_, N> {
    fn observations(&self) -> u32 {
        self.n_obs
    }
}

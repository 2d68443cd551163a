//! Marginalization of the oldest keyframe into the square-root prior.
//!
//! Every landmark observed at position 0 (its anchor `s`) gets a plan first
//! ([`MargPlan`]): when another keyframe after 0 gives it a second anchor with parallax, it is
//! re-anchored on keyframes after 0 and only the residual of its observation at 0 goes into the
//! prior; its other residuals do not involve position 0 and stay in the window. So nothing is
//! counted twice (re-anchoring after the marginalization, as VINS-Mono does, uses residuals
//! that are already in the prior a second time) and nothing is lost (dropping the landmark with
//! its anchor loses everything its later observations say). Landmarks without such an anchor,
//! and LiDAR landmarks (their depth belongs to position 0), go into the prior whole and leave.
//!
//! With the depth eliminated (the pose-only default), the observation at 0 is not a residual of
//! its own: the prior takes the landmark's whole factor (depth eliminated over every observation)
//! less the factor that stays in the window (depth eliminated over the observations after 0),
//! both linearized at the same state, i.e. the information the observation at 0 adds given the
//! others (`FactorSet::OldestRest`). Two observations after 0 suffice; no parallax gate. Leaving
//! it as a two-view residual instead (depth from the new anchors, taken as exact) cost 2.5x on
//! EuRoC (0.100 vs 0.039 m) and 1.25x on the corridor.
//!
//! Both apply only with `reuse_marginalized_landmarks = false`; the default re-use (VINS-Mono)
//! folds the whole factor and keeps every observation, and is still the more accurate
//! (EuRoC 0.030 m, corridor 0.060 vs 0.125 m).

use super::prior::LinPoint;
use super::problem::FactorSet;
use super::slots::{max_parallax, relative_rotations};
use super::window::Block;
use super::window::Layout;
use super::{corrected_obs, Estimator, VisualMode};
use crate::landmarks::MargPlan;
use crate::solver::{schur_complement_in_place, sqrt_prior, PivotFloor};
use crate::Error;

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// Sets the marginalization plan of every landmark (module docs) and re-anchors the ones
    /// that stay. Positions are those before the window shifts.
    fn plan_marginalization(&mut self) {
        let count = self.window.len();
        let rel = relative_rotations(&self.window_cams(), count);
        let td: [f64; N] = core::array::from_fn(|k| self.window.get(k).map_or(0.0, |kf| kf.td_s));
        let min_par = self.cfg.min_parallax;
        let lidar_on = self.cfg.lidar.enabled;
        let reuse = self.cfg.reuse_marginalized_landmarks;
        let eliminated = self.cfg.depth_eliminated() && self.cfg.mode == VisualMode::PoseOnly;
        for lm in self.lms.landmarks_mut() {
            lm.marg = MargPlan::None;
            if !lm.usable || lm.anchor_s != 0 || lm.obs.first().is_none_or(|o| o.is_none()) {
                continue;
            }
            if reuse {
                lm.marg = MargPlan::Reuse;
                continue;
            }
            if lidar_on && lm.lidar.is_some() {
                lm.marg = MargPlan::Whole;
                continue;
            }
            let Some(s1) = (1..count).find(|&k| lm.obs.get(k).is_some_and(|o| o.is_some())) else {
                continue;
            };
            let obs_after_0 = |k: usize| {
                if k == 0 {
                    None
                } else {
                    corrected_obs(lm, k, td.get(k).copied().unwrap_or(0.0))
                }
            };
            // An eliminated depth needs no parallax gate: two observations after 0 keep it.
            let after_0 = (1..count)
                .filter(|&k| lm.obs.get(k).is_some_and(|o| o.is_some()))
                .count();
            let ok = |theta: f64| theta >= min_par || (eliminated && after_0 >= 2);
            match max_parallax(&rel, count, s1, obs_after_0) {
                Some((e1, theta, _)) if ok(theta) => {
                    lm.anchor_s = s1 as u8;
                    lm.bearing_delta = [0.0; 2];
                    lm.anchor_e = Some(e1 as u8);
                    // Depth state of the old anchor: re-initialized at the new one. An
                    // eliminated depth is solved again from the old value (a close start).
                    if !eliminated {
                        lm.inv_depth = 0.0;
                    }
                    lm.marg = MargPlan::ObsZero;
                }
                _ => lm.marg = MargPlan::Whole,
            }
        }
    }

    /// Schur complement of the oldest keyframe (and its delay; in the inverse-depth mode also
    /// the depths anchored there) into the square-root prior, then removal from the window.
    pub(super) fn marginalize_oldest(&mut self) -> Result<(), Error> {
        let count = self.window.len();
        let (ext, td) = (self.cfg.estimate_extrinsic, self.cfg.td.estimate);
        let layout = Layout::marginalize_oldest(count, ext, td);
        self.prepare_landmarks(false);
        self.plan_marginalization();
        self.marg_ne.reset(layout.dim())?;
        {
            let (mut problem, _, marg_ne) = self.split(layout, FactorSet::Oldest);
            problem.assemble(Some(marg_ne))?;
        }
        let rest = self.cfg.marginalize_visual
            && !self.cfg.reuse_marginalized_landmarks
            && self.cfg.depth_eliminated()
            && self.cfg.mode == VisualMode::PoseOnly
            && self
                .lms
                .landmarks()
                .iter()
                .any(|lm| lm.usable && lm.marg == MargPlan::ObsZero);
        if rest {
            // The re-anchored landmarks' factors without position 0 stay in the window: take
            // them back out of the whole factors (the LM's system is free until the next solve).
            let (mut problem, lm, marg_ne) = self.split(layout, FactorSet::OldestRest);
            lm.ne.reset(layout.dim())?;
            problem.assemble(Some(&mut lm.ne))?;
            marg_ne.subtract(&lm.ne)?;
        }
        let m = Layout::<N>::marginalized_dim(td);
        let floor = PivotFloor {
            relative: 1e-10,
            absolute: 1e-12,
        };
        let marg_report = schur_complement_in_place(&mut self.marg_ne, m, floor)?;
        let p = self.marg_ne.dim();
        // New blocks (positions still pre-shift) with their linearization points.
        self.prior.blocks.clear();
        for k in 1..count {
            let st = self.window.get(k).ok_or(Error::NotEnoughData)?.state;
            self.prior
                .blocks
                .push((Block::Kf(k as u8), LinPoint::Kf(st)))
                .map_err(|_| Error::CapacityExceeded)?;
        }
        if ext {
            self.prior
                .blocks
                .push((Block::Ext, LinPoint::Ext(self.ext)))
                .map_err(|_| Error::CapacityExceeded)?;
        }
        if td {
            for k in 1..count {
                let t = self.window.get(k).ok_or(Error::NotEnoughData)?.td_s;
                self.prior
                    .blocks
                    .push((Block::Td(k as u8), LinPoint::Td(t)))
                    .map_err(|_| Error::CapacityExceeded)?;
            }
        }
        let r0 = self.prior.r0.get_mut(..p).ok_or(Error::CapacityExceeded)?;
        let prior_report = sqrt_prior(
            &self.marg_ne,
            floor,
            &mut self.marg_ldlt,
            &mut self.prior.j0,
            r0,
        )?;
        self.last_marg = Some((
            (marg_report.n - marg_report.rank) as u32,
            (prior_report.n - prior_report.rank) as u32,
        ));
        self.prior.set_dim(p, &self.marg_ne)?;
        self.prior.shift_positions()?;
        self.initial = None;
        let _ = self.window.drop_oldest();
        if self.cfg.marginalize_visual {
            // Every residual of these is in the prior now.
            while let Some(li) = self
                .lms
                .landmarks()
                .iter()
                .position(|lm| lm.marg == MargPlan::Whole)
            {
                self.lms.remove_marginalized(li);
            }
        }
        self.lms.shift_out_oldest();
        Ok(())
    }
}

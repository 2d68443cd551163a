//! The inverse-depth visual measurements of the window's problem (the LE-VINS-WO baseline,
//! [`super::VisualMode::InverseDepth`]): every observation `j != s` of a usable landmark as an
//! inverse-depth reprojection, the landmark's inverse depth eliminated by its Schur accumulator,
//! and a LiDAR depth as a prior on the landmark's own inverse depth (LE-VINS).

use super::problem::{timed, FactorSet, Problem};
use super::problem_lidar::add_inverse_depth_obs;
use crate::factors::inverse_depth_visual::{InverseDepthJacobians, InverseDepthVisualFactor};
use crate::factors::robust::Huber;
use crate::landmarks::MargPlan;
use crate::solver::NormalEquations;
use crate::Error;
use heapless::Vec as HVec;

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    pub(super) fn inverse_depth_visual(
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
        let mut cost = 0.0;
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if let Some(sc) = self.schur.get_mut(li) {
                sc.clear();
            }
            if !lm.usable || lm.inv_depth <= 0.0 {
                continue;
            }
            let s = lm.anchor_s as usize;
            if self.set == FactorSet::Oldest
                && !matches!(lm.marg, MargPlan::Whole | MargPlan::Reuse)
            {
                continue;
            }
            let (Some(Some(os)), Some(ps)) = (lm.obs.get(s), poses.get(s)) else {
                continue;
            };
            let obs_s = timed(os);
            let tau = lm.inv_depth;
            let mut lm_cost = 0.0;
            let mut n_obs = 0;
            let mut failed = false;
            let mut jacs: HVec<(usize, InverseDepthJacobians), N> = HVec::new();
            for (j, oj) in lm.obs.iter().enumerate().take(count) {
                let (Some(oj), Some(pj)) = (oj, poses.get(j)) else {
                    continue;
                };
                if j == s {
                    continue;
                }
                let f = InverseDepthVisualFactor {
                    kf_s: s,
                    kf_j: j,
                    obs_s,
                    obs_j: timed(oj),
                    sqrt_info,
                };
                if ne.is_some() {
                    match f.evaluate(ps, pj, &ext, tau) {
                        Ok(jac) => {
                            let _ = jacs.push((j, jac));
                        }
                        Err(_) => failed = true,
                    }
                } else {
                    match f.residual(ps, pj, &ext, tau) {
                        Ok(r) => {
                            lm_cost += huber.rho(r.norm_squared())[0];
                            n_obs += 1;
                        }
                        Err(_) => failed = true,
                    }
                }
            }
            if let (false, Some(ne_ref)) = (failed, ne.as_deref_mut()) {
                for (j, jac) in jacs.iter() {
                    let j = *j;
                    let sq = jac.r.norm_squared();
                    let w = huber.sqrt_weight(sq);
                    lm_cost += huber.rho(sq)[0];
                    n_obs += 1;
                    let sc = self.schur.get_mut(li).ok_or(Error::CapacityExceeded)?;
                    add_inverse_depth_obs(sc, ne_ref, jac, w, s, j, &l, est_td, est_ext)?;
                }
            }
            if failed {
                if ne.is_some() {
                    if let Some(lm) = self.lms.landmarks_mut().get_mut(li) {
                        lm.usable = false;
                    }
                    self.counts.disabled += 1;
                } else {
                    return Err(Error::Degenerate);
                }
            }
            // LE-VINS: a LiDAR depth is a prior on the landmark's own inverse depth.
            if !failed {
                if let Some(c) = self.lidar_depth_prior(li, tau, &huber, ne)? {
                    lm_cost += c;
                }
            }
            if let (false, Some(ne_ref), Some(sc)) = (failed, ne.as_deref_mut(), self.schur.get(li))
            {
                sc.fold_into(ne_ref, 0.0)?;
            }
            if n_obs > 0 {
                self.counts.landmarks += 1;
                self.counts.observations += n_obs;
            }
            cost += lm_cost;
        }
        Ok(cost)
    }

    /// LE-VINS: the LiDAR depth of landmark `li` (with the LiDAR enabled) as a prior on its own
    /// inverse depth `tau`, added to the landmark's Schur accumulator with `ne`. Returns the
    /// prior's robust cost (`None` without a depth).
    fn lidar_depth_prior(
        &mut self,
        li: usize,
        tau: f64,
        huber: &Huber,
        ne: &mut Option<&mut NormalEquations<D>>,
    ) -> Result<Option<f64>, Error> {
        let depth = self
            .lms
            .landmarks()
            .get(li)
            .and_then(|lm| lm.lidar)
            .filter(|_| self.cfg.lidar.enabled);
        let Some(d) = depth else {
            return Ok(None);
        };
        let rd = (1.0 / tau - d.depth_m) / d.sigma_m;
        let jd = -1.0 / (tau * tau * d.sigma_m);
        let cost = huber.rho(rd * rd)[0];
        self.counts.ldm += 1;
        if let (Some(ne_ref), Some(sc)) = (ne.as_deref_mut(), self.schur.get_mut(li)) {
            let w = huber.sqrt_weight(rd * rd);
            sc.add_residual(ne_ref, &[rd * w], &[], &[jd * w])?;
        }
        Ok(Some(cost))
    }
}

//! The inverse-depth visual measurement of a landmark ([`InverseDepthLandmark`], the LE-VINS-WO
//! baseline, [`super::VisualMode::InverseDepth`]): every observation `j != s` as an
//! inverse-depth reprojection at the landmark's inverse depth `tau` (a state of the problem),
//! Huber on each, and a LiDAR depth as a prior `(1/tau - d_r) / sigma_dr` on `tau` (LE-VINS).
//! The linearization eliminates `tau` by the landmark's Schur accumulator (the LM recovers its
//! step by back-substitution).
#![deny(clippy::too_many_lines)]

use super::factor::{put_rows, timed, LandmarkFactor, VisualSettings, WindowFactor, WindowVars};
use super::lidar::add_inverse_depth_obs;
use super::SCHUR_COLS;
use crate::factors::inverse_depth_visual::{InverseDepthJacobians, InverseDepthVisualFactor};
use crate::factors::KeyframePose;
use crate::landmarks::{Landmark, LidarDepth};
use crate::solver::{LandmarkSchur, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;

/// The reprojection factors of a landmark's observations `j != s`, with the pose of `j`.
type Reprojections<'v, const N: usize> =
    HVec<(usize, InverseDepthVisualFactor, &'v KeyframePose), N>;

/// The inverse-depth measurement of a landmark (module docs).
pub struct InverseDepthLandmark<'a, const N: usize> {
    vs: VisualSettings<'a>,
    lm: &'a Landmark<N>,
    /// The LiDAR depth taken as the prior on `tau`, if any.
    depth: Option<LidarDepth>,
    schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    n_obs: u32,
    ldm: u32,
}

impl<'a, const N: usize> InverseDepthLandmark<'a, N> {
    /// The measurement of `lm` at its inverse depth, with `schur` as its accumulator, or `None`
    /// without a positive inverse depth or without the anchor's observation.
    pub fn new(
        vs: VisualSettings<'a>,
        lm: &'a Landmark<N>,
        schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    ) -> Option<Self> {
        if lm.inv_depth <= 0.0 {
            return None;
        }
        lm.obs.get(lm.anchor_s as usize)?.as_ref()?;
        Some(InverseDepthLandmark {
            vs,
            lm,
            depth: lm.lidar.filter(|_| vs.cfg.lidar.enabled),
            schur,
            n_obs: 0,
            ldm: 0,
        })
    }

    /// The reprojection factors `j != s` among the first `count` positions, with the poses.
    fn factors<'v>(
        &self,
        v: &'v WindowVars<'_, N>,
    ) -> Result<(&'v KeyframePose, Reprojections<'v, N>), Error> {
        let lm = self.lm;
        let s = lm.anchor_s as usize;
        let (Some(Some(os)), Some(ps)) = (lm.obs.get(s), v.poses.get(s)) else {
            return Err(Error::NotEnoughData);
        };
        let obs_s = timed(os);
        let mut out = HVec::new();
        for (j, oj) in lm.obs.iter().enumerate().take(v.count) {
            let (Some(oj), Some(pj)) = (oj, v.poses.get(j)) else {
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
                sqrt_info: self.vs.sqrt_info,
            };
            let _ = out.push((j, f, pj));
        }
        Ok((ps, out))
    }

    /// The LiDAR prior's whitened residual and its derivative in `tau`.
    fn prior_row(d: &LidarDepth, tau: f64) -> (f64, f64) {
        let rd = (1.0 / tau - d.depth_m) / d.sigma_m;
        let jd = -1.0 / (tau * tau * d.sigma_m);
        (rd, jd)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for InverseDepthLandmark<'_, N> {
    #[inline(never)]
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        (self.n_obs, self.ldm) = (0, 0);
        self.schur.clear();
        let (ps, factors) = self.factors(v)?;
        let (huber, tau, s) = (&self.vs.huber, self.lm.inv_depth, self.lm.anchor_s as usize);
        let mut cost = 0.0;
        let mut n_obs = 0;
        let mut jacs: HVec<(usize, InverseDepthJacobians), N> = HVec::new();
        // Every observation first: a landmark enters the system whole or not at all.
        for (j, f, pj) in factors.iter() {
            if ne.is_some() {
                let _ = jacs.push((*j, f.evaluate(ps, pj, v.ext, tau)?));
            } else {
                let r = f.residual(ps, pj, v.ext, tau)?;
                cost += huber.rho(r.norm_squared())[0];
                n_obs += 1;
            }
        }
        if let Some(ne) = ne.as_deref_mut() {
            for (j, jac) in jacs.iter() {
                let sq = jac.r.norm_squared();
                let w = huber.sqrt_weight(sq);
                cost += huber.rho(sq)[0];
                n_obs += 1;
                let (l, est) = (&v.layout, (v.est_td, v.est_ext));
                add_inverse_depth_obs(&mut *self.schur, ne, jac, w, s, *j, l, est.0, est.1)?;
            }
        }
        // LE-VINS: a LiDAR depth is a prior on the landmark's own inverse depth.
        if let Some(d) = self.depth {
            let (rd, jd) = Self::prior_row(&d, tau);
            cost += huber.rho(rd * rd)[0];
            self.ldm = 1;
            if let Some(ne) = ne.as_deref_mut() {
                let w = huber.sqrt_weight(rd * rd);
                self.schur.add_residual(ne, &[rd * w], &[], &[jd * w])?;
            }
        }
        if let Some(ne) = ne {
            self.schur.fold_into(ne, 0.0)?;
        }
        self.n_obs = n_obs;
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let (ps, factors) = self.factors(v)?;
        let tau = self.lm.inv_depth;
        let mut rows = 0;
        for (_, f, pj) in factors.iter() {
            let r = f.residual(ps, pj, v.ext, tau)?;
            rows += put_rows(&[r.x, r.y], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        if let Some(d) = self.depth {
            rows += put_rows(
                &[Self::prior_row(&d, tau).0],
                out.get_mut(rows..).unwrap_or(&mut []),
            )?;
        }
        Ok(rows)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for InverseDepthLandmark<'_, N> {
    fn observations(&self) -> u32 {
        self.n_obs
    }

    fn depth_measurements(&self) -> u32 {
        self.ldm
    }
}

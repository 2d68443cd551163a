//! Outlier culling after a solve: the whitened residuals of a landmark's observations at the
//! current state under the model it was solved with ([`LandmarkModel`]: the two-view anchors,
//! or the inverse-depth rays at the landmark's inverse depth), the chi-square cull between the LM passes, and the reprojection cull of paper V.E
//! (whole landmarks by mean error, single observations above a threshold), with the anchors
//! fixed up after observations are removed.
#![deny(clippy::too_many_lines)]

use super::problem::factor::{anchor_depth_std, LandmarkModel};
use super::tau_landmark::TauLandmark;
use super::{DepthEvent, DepthEventKind, Estimator};
use crate::factors::pose_only_visual::PoseOnlyAnchors;
use crate::factors::{CamFrame, KeyframePose, TimedObs};
use heapless::Vec as HVec;

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
    /// Body poses and camera frames of the window, computed once for a pass over landmarks.
    pub(super) fn window_frames(&self) -> ([KeyframePose; N], [CamFrame; N]) {
        let poses = self.window.poses();
        let ext = self.ext;
        let frames = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        (poses, frames)
    }

    /// Whitened residuals of the observations `j != s` of landmark `li` (`None` where not
    /// defined), with the anchors' geometry formed once for all of them.
    fn landmark_residuals(
        &self,
        li: usize,
        wf: &([KeyframePose; N], [CamFrame; N]),
    ) -> [Option<crate::camera::Vec2>; N] {
        let mut out = [None; N];
        let (poses, frames) = wf;
        let Some(lm) = self.lms.landmarks().get(li) else {
            return out;
        };
        let s = lm.anchor_s as usize;
        let to = |o: &crate::landmarks::KfObs| TimedObs {
            x_n: crate::camera::Vec2::new(o.x_n[0], o.x_n[1]),
            vel: crate::camera::Vec2::new(o.vel[0], o.vel[1]),
            td0: o.td0_s,
        };
        let (Some(Some(os)), Some(ps), Some(fs)) = (lm.obs.get(s), poses.get(s), frames.get(s))
        else {
            return out;
        };
        let obs_s = to(os);
        let sqrt_info =
            crate::camera::Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy) / self.cfg.sigma_px;
        let observed = lm
            .obs
            .iter()
            .zip(poses.iter().zip(frames.iter()))
            .enumerate()
            .take(self.window.len())
            .filter(|(j, _)| *j != s)
            .filter_map(|(j, (o, pf))| o.as_ref().map(|o| (j, to(o), pf)));
        // Under the model the landmark was solved with. The inverse-depth residuals on the
        // landmark's rays at its inverse depth and anchor bearing correction (the last solve's,
        // zero where it keeps the bearing exact; or for a LiDAR landmark the depth-only
        // optimization's, paper V.D): the anchor's ray formed once, a few flops per observation
        // instead of the whole factor chain.
        if LandmarkModel::of(&self.cfg, lm).uses_inverse_depth() {
            let m = TauLandmark::new(&lm.obs, s, None, sqrt_info, self.window.len());
            let mut rays = heapless::Vec::new();
            let ok = m.as_ref().map(|m| m.rays_into(poses, frames, &mut rays));
            if let (Some(m), Some(Ok(()))) = (m, ok) {
                for ((j, _), ray) in m.obs.iter().zip(rays.iter()) {
                    if let Some(o) = out.get_mut(*j) {
                        let (delta, tau) = (lm.bearing_delta, lm.inv_depth);
                        *o = ray
                            .residual_and_d_bearing_tau(delta, tau)
                            .ok()
                            .map(|(r, _)| r);
                    }
                }
            }
            return out;
        }
        let Some(e) = lm.anchor_e.map(usize::from) else {
            return out;
        };
        let (Some(Some(oe)), Some(pe), Some(fe)) = (lm.obs.get(e), poses.get(e), frames.get(e))
        else {
            return out;
        };
        let Ok(anchors) = PoseOnlyAnchors::new(
            (s, e),
            obs_s,
            to(oe),
            sqrt_info,
            (ps, pe),
            (fs, fe),
            &self.ext,
            None,
        ) else {
            return out;
        };
        let sd = anchor_depth_std(&self.cfg, &anchors);
        let anchors = anchors.with_depth_std(sd);
        for (j, obs_j, (pj, fj)) in observed {
            if let Some(o) = out.get_mut(j) {
                *o = anchors.residual(j, &obs_j, pj, fj).ok();
            }
        }
        out
    }

    /// Removes observations whose whitened squared residual exceeds the chi-square threshold.
    pub(super) fn chi2_cull(&mut self) -> u32 {
        let count = self.window.len();
        let wf = self.window_frames();
        let mut culled = 0;
        for li in 0..self.lms.len() {
            let usable = self.lms.landmarks().get(li).is_some_and(|l| l.usable);
            if !usable {
                continue;
            }
            let s = self
                .lms
                .landmarks()
                .get(li)
                .map_or(0, |l| l.anchor_s as usize);
            let res = self.landmark_residuals(li, &wf);
            for (j, r) in res.iter().enumerate().take(count) {
                if j == s {
                    continue;
                }
                let bad = r.is_some_and(|r| r.norm_squared() > self.cfg.cull.chi2_threshold);
                if bad && self.lms.invalidate_obs(li, j) {
                    culled += 1;
                }
            }
        }
        self.fix_anchors();
        culled
    }

    /// After removing observations: re-anchor `s` at the first remaining observation (dropping
    /// depth state that was expressed in the old anchor) and drop unobserved landmarks.
    fn fix_anchors(&mut self) {
        for lm in self.lms.landmarks_mut() {
            if let Some(s) = lm.first_obs() {
                if s != lm.anchor_s as usize {
                    lm.anchor_s = s as u8;
                    lm.inv_depth = 0.0;
                    lm.bearing_delta = [0.0; 2];
                    lm.lidar = None;
                }
            }
            if lm
                .anchor_e
                .is_some_and(|e| lm.obs.get(e as usize).is_none_or(|o| o.is_none()))
            {
                lm.anchor_e = None;
            }
        }
        self.lms.retain(|lm| lm.first_obs().is_some(), true);
    }

    /// Paper V.E: drop landmarks whose mean reprojection error exceeds `cull.mean_px`, otherwise
    /// single observations above `cull.obs_px`. Returns (observations, landmarks, rms px).
    pub(super) fn reprojection_cull(&mut self) -> (u32, u32, f64) {
        let count = self.window.len();
        let wf = self.window_frames();
        let sigma = self.cfg.sigma_px;
        let (mut n_obs, mut n_lm) = (0u32, 0u32);
        let (mut sq_sum, mut sq_n) = (0.0, 0u32);
        let mut drop_lm: HVec<u64, L> = HVec::new();
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if !lm.usable {
                continue;
            }
            let (id, s) = (lm.id, lm.anchor_s as usize);
            let mut errs = [0.0f64; N];
            let (mut sum, mut n) = (0.0, 0u32);
            let res = self.landmark_residuals(li, &wf);
            for (j, (e, r)) in errs.iter_mut().zip(res.iter()).enumerate().take(count) {
                if j == s {
                    continue;
                }
                if let Some(r) = r {
                    *e = libm::sqrt(r.norm_squared()) * sigma;
                    sum += *e;
                    n += 1;
                    sq_sum += r.norm_squared() * sigma * sigma;
                    sq_n += 2;
                }
            }
            if n == 0 {
                continue;
            }
            // A track with one gross observation is a wrong track from there on (a tracker that
            // jumps stays on what it jumped to): with `cull.whole_tracks` it goes whole.
            let gross = self.cfg.cull.whole_tracks
                && errs
                    .iter()
                    .enumerate()
                    .take(count)
                    .any(|(j, e)| j != s && *e > self.cfg.cull.obs_px);
            if gross || sum / f64::from(n) > self.cfg.cull.mean_px {
                let _ = drop_lm.push(id);
                if let Some(d) = self.lms.landmarks().get(li).and_then(|l| l.lidar) {
                    let _ = self.events.push(DepthEvent {
                        id,
                        kind: DepthEventKind::Culled,
                        depth_m: d.depth_m,
                    });
                }
                continue;
            }
            for (j, e) in errs.iter().enumerate().take(count) {
                if j != s && *e > self.cfg.cull.obs_px && self.lms.invalidate_obs(li, j) {
                    n_obs += 1;
                }
            }
        }
        if !drop_lm.is_empty() {
            for &id in drop_lm.iter() {
                self.lms.ban(id);
            }
            n_lm = self.lms.retain(|lm| !drop_lm.contains(&lm.id), true) as u32;
        }
        self.fix_anchors();
        let rms = if sq_n > 0 {
            libm::sqrt(sq_sum / f64::from(sq_n))
        } else {
            0.0
        };
        (n_obs, n_lm, rms)
    }
}

//! The estimator's LiDAR steps (paper III, IV.C, V.D): sweep intake, depth association at a
//! keyframe, the uncertainty-based rejection test and the depth-only optimization.
//!
//! Rejection (paper eq. 14-15, see [`crate::lidar::rejection`]): the pose-only depth `d_v` of the
//! landmark from its anchors `(s, e)` and its analytic standard deviation `sigma_dv` (paper eq. 13,
//! evaluated with `rejection_sigma_px`) are compared with the LiDAR depth `d_r` in inverse depth,
//! `|1/d_v - 1/d_r| > k sqrt((sigma_dv/d_v^2)^2 + (sigma_dr/d_r^2)^2)` (`k = 3`). The test runs at
//! every solve while the landmark lives (its parallax, hence its power, grows as the window
//! moves); a landmark without parallax yet cannot be tested and keeps its depth. A rejected depth
//! is dropped for good; the visual feature stays.

use super::{DepthEvent, DepthEventKind, Estimator, KeyframeReport};
use crate::camera::Vec2;
use crate::inertial::NavState;
use crate::landmarks::LidarDepth;

use super::problem::{EliminatedLandmark, LandmarkModel, VisualSettings};
use super::tau_landmark::TauLandmark;

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
    /// LiDAR-depth events of the last keyframe step.
    pub fn lidar_events(&self) -> &[DepthEvent] {
        &self.events
    }

    pub(super) fn push_event(&mut self, id: u64, kind: DepthEventKind, depth_m: f64) {
        // Capacity covers one association per feature plus one rejection or cull per landmark.
        let _ = self.events.push(DepthEvent { id, kind, depth_m });
    }

    /// Buffers the INS state of a propagated sample for de-skewing and feature prediction.
    pub(super) fn record_ins(&mut self, st: &NavState) {
        let _ = self.ins_window.push(*st);
    }

    /// The INS restarts from the optimized keyframe `to` (it was at `from`): move the buffered
    /// INS states with it so sweeps straddling the keyframe de-skew on a continuous path.
    pub(super) fn correct_ins_window(&mut self, from: &NavState, to: &NavState) {
        self.ins_window.apply_correction(from, to);
    }

    /// Associates LiDAR depths with the tracks that start at the new keyframe `pos` (their first
    /// observation, the anchor they get as landmarks), in the keyframe camera at the INS pose
    /// `nav`.
    // Not inlined: its list of depths (8 kB) must not sit in the keyframe step's frame during
    // the solve.
    #[inline(never)]
    pub(super) fn associate_depths(
        &mut self,
        pos: usize,
        nav: &NavState,
        report: &mut KeyframeReport,
    ) {
        if !self.cfg.lidar.enabled || self.points.is_empty() {
            return;
        }
        let t0 = super::now(self.clock);
        let cfg = self.cfg.lidar;
        let cam = self.ext.camera_pose(&nav.p_wb, &nav.q_wb);
        let t_l_ns = nav
            .t_ns
            .saturating_sub(libm::round(cfg.td_l_s * 1e9) as i64);
        let gs = self
            .grid
            .build(&self.points, &cam.p_wc, &cam.q_wc, t_l_ns, &cfg.association);
        report.lidar_points = gs.points;
        // Every track that starts at this keyframe may get a slot later: its depth is kept with
        // its observation in the store, and a landmark anchored here takes it on promotion.
        let mut n = 0u32;
        let prev = pos.checked_sub(1);
        let mut found: heapless::Vec<(u64, f64, f64), { super::MAX_FEATURES }> =
            heapless::Vec::new();
        for o in self.lms.store().at(pos) {
            if prev.is_some_and(|p| self.lms.store().find(p, o.id).is_some()) {
                continue;
            }
            let x_n = Vec2::new(o.obs.x_n[0], o.obs.x_n[1]);
            if let Ok(d) = self.grid.associate(&x_n, &cfg.association) {
                let _ = found.push((o.id, d.depth_m, cfg.sigma_dr(d.depth_m, d.incidence_cos)));
            }
        }
        for &(id, depth_m, sigma_m) in found.iter() {
            let depth = LidarDepth { depth_m, sigma_m };
            self.lms.set_lidar(pos, id, depth);
            self.push_event(id, DepthEventKind::Associated, depth_m);
            n += 1;
        }
        report.depths_associated = n;
        report.association_ns = super::now(self.clock).saturating_sub(t0);
    }

    /// Depth-only optimization (paper V.D): the inverse depth of every LiDAR landmark re-solved
    /// for the optimized poses (poses and extrinsic fixed), under the landmark's model: with
    /// the depth eliminated, its measurement's own solve (the anchor's bearing correction with
    /// it, [`EliminatedLandmark::solve_at`]); the paper's MSC form, the bearing exact.
    pub(super) fn depth_only_optimization(&mut self) {
        let count = self.window.len();
        let (poses, frames) = self.window_frames();
        let sqrt_info = Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy) / self.cfg.sigma_px;
        let cfg = &self.cfg;
        let vs = VisualSettings::new(cfg).ok();
        for lm in self.lms.landmarks_mut() {
            let (Some(d), true) = (lm.lidar, lm.usable) else {
                continue;
            };
            if let (LandmarkModel::Eliminated, Some(vs)) = (LandmarkModel::of(cfg, lm), vs) {
                let solved =
                    EliminatedLandmark::new(vs, lm, false, None).solve_at(&poses, &frames, count);
                if let Ok((delta, tau)) = solved {
                    (lm.inv_depth, lm.bearing_delta) = (tau, delta);
                }
                continue;
            }
            let Some(m) =
                TauLandmark::<N>::new(&lm.obs, lm.anchor_s as usize, Some(d), sqrt_info, count)
            else {
                continue;
            };
            if let Ok((tau, _)) = m.solve(&poses, &frames, lm.inv_depth) {
                // (Solved with the anchor's bearing exact, as the LiDAR measurements take it.)
                (lm.inv_depth, lm.bearing_delta) = (tau, [0.0; 2]);
            }
        }
    }
}

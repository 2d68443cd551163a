//! Landmark preparation before each solve (step 3 of the module docs of [`super`]): the anchor
//! `e` of largest parallax, the pose-only depth from `(s, e)` and its analytic uncertainty, the
//! parallax, depth-range and depth-uncertainty gates (counted in [`super::Admission`]), the
//! initial inverse depth of the modes that keep one, and the uncertainty-based rejection of
//! LiDAR depths (paper IV.C, [`crate::lidar::rejection`]).
#![deny(clippy::too_many_lines)]

use super::config::EstimatorConfig;
use super::window::Window;
use super::{corrected_obs, slots, Admission, DepthEvent, DepthEventKind, Estimator, VisualMode};
use crate::landmarks::{depth_std, Landmark, LidarDepth, TwoView};
use crate::lidar::LdmMode;
use crate::math::{Mat3, Vec3};

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
    /// Chooses anchors and gates every landmark for the coming solve. With `reject`, also runs
    /// the uncertainty-based test on LiDAR depths (see [`crate::lidar::rejection`]); returns (depths rejected,
    /// time spent on the test in ns).
    pub(super) fn prepare_landmarks(&mut self, reject: bool) -> (u32, u64, Admission) {
        let count = self.window.len();
        let ext = self.ext;
        let poses = self.window.poses();
        let cams: [crate::camera::CameraPose; N] =
            core::array::from_fn(|k| ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb));
        // Relative rotations once per camera pair, not per landmark and pair.
        let rel = slots::relative_rotations(&cams, count);
        let (dmin, dmax) = self.cfg.depth_range_m;
        let min_par = self.cfg.min_parallax;
        let max_rel = self.cfg.max_rel_depth_std;
        let sigma_px = self.cfg.sigma_px;
        let focal = crate::camera::Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy);
        let mode = self.cfg.mode;
        // Modes that keep an inverse depth per landmark (a state, or the eliminated one's last
        // solution as the next solve's start).
        let depth_state = mode == VisualMode::InverseDepth || self.cfg.depth_eliminated();
        let lc = self.cfg.lidar;
        let test_depths = reject && lc.enabled && lc.depth_outlier_rejection;
        let clock = self.clock;
        let (mut rejected, mut reject_ns) = (0u32, 0u64);
        let mut adm = Admission::default();
        for lm in self.lms.landmarks_mut() {
            lm.usable = false;
            if !lc.enabled {
                // PO-VINS-WO: depths may exist (associated before a switch) but are never used.
                lm.lidar = None;
            }
            let s = lm.anchor_s as usize;
            let td_s = self.window.get(s).map_or(0.0, |k| k.td_s);
            let (Some(x_s), Some(cs)) = (corrected_obs(lm, s, td_s), cams.get(s)) else {
                continue;
            };
            let best = second_anchor(lm, s, x_s, &rel, &self.window, count);
            let Some((e, theta, x_e)) = best else {
                lm.anchor_e = None;
                adm.single_view += 1;
                continue;
            };
            lm.anchor_e = Some(e as u8);
            let Some(ce) = cams.get(e) else { continue };
            let (r_es, t_es) = ce.relative_from(cs);
            // The pose-only depth from (s, e) and its analytic uncertainty (paper IV.A-B).
            let two = TwoView::new(&x_s, &x_e, &r_es, &t_es);
            let d_v = two.signed_depth();
            let visual = (d_v > 0.0 && d_v.is_finite()).then_some((d_v, two));

            if let (true, Some(ld), Some((d_v, two))) = (test_depths, lm.lidar, visual.as_ref()) {
                let t0 = clock.map_or(0, |c| c());
                if lidar_depth_outlier(&self.cfg, &ld, *d_v, two, theta) {
                    lm.lidar = None;
                    lm.inv_depth = 0.0;
                    rejected += 1;
                    let _ = self.events.push(DepthEvent {
                        id: lm.id,
                        kind: DepthEventKind::Rejected,
                        depth_m: ld.depth_m,
                    });
                }
                reject_ns += clock.map_or(0, |c| c()).saturating_sub(t0);
            }

            if let Some(ld) = lm.lidar {
                let in_range = ld.depth_m >= dmin && ld.depth_m <= dmax;
                // MSC (and the inverse-depth baseline) take the depth from the LiDAR: no
                // parallax needed. The direct LDM rides on the pose-only visual measurements,
                // so it needs their gates.
                if in_range && (lc.ldm == LdmMode::Msc || mode == VisualMode::InverseDepth) {
                    lm.usable = true;
                    adm.admitted += 1;
                    if !(lm.inv_depth > 0.0 && lm.inv_depth.is_finite()) {
                        lm.inv_depth = 1.0 / ld.depth_m;
                    }
                    continue;
                }
            }
            if theta < min_par {
                adm.low_parallax += 1;
                continue;
            }
            let Some((d_s, two)) = visual else {
                adm.bad_depth += 1;
                continue;
            };
            if !(d_s >= dmin && d_s <= dmax) {
                adm.bad_depth += 1;
                continue;
            }
            // The two-view residuals treat the depth from (s, e) as exact: admit a landmark only
            // once its analytic depth uncertainty (paper IV.B) is a small fraction of the depth.
            // (An eliminated depth carries its own uncertainty: no such gate.)
            let two_view = mode == VisualMode::PoseOnly && !depth_state;
            if two_view && !depth_std(&two, sigma_px, &focal).is_ok_and(|sd| sd <= max_rel * d_s) {
                adm.uncertain_depth += 1;
                continue;
            }
            lm.usable = true;
            adm.admitted += 1;
            if depth_state && (lm.inv_depth.is_nan() || lm.inv_depth <= 0.0) {
                lm.inv_depth = 1.0 / d_s;
            }
        }
        (rejected, reject_ns, adm)
    }
}

/// The second anchor `e` of landmark `lm` (anchor `s`, delay-corrected observation `x_s`): the
/// observation among the first `count` positions of largest parallax `|x_k x R_ks x_s|`, with
/// that parallax and its delay-corrected observation; `None` without a finite one. `rel` holds
/// the window's [`slots::relative_rotations`].
fn second_anchor<const N: usize>(
    lm: &Landmark<N>,
    s: usize,
    x_s: Vec3,
    rel: &[[Mat3; N]; N],
    window: &Window<N>,
    count: usize,
) -> Option<(usize, f64, Vec3)> {
    let mut best: Option<(usize, f64, Vec3)> = None;
    for (k, row) in rel.iter().enumerate().take(count) {
        if k == s {
            continue;
        }
        let td_k = window.get(k).map_or(0.0, |kf| kf.td_s);
        let (Some(x_k), Some(r_ks)) = (corrected_obs(lm, k, td_k), row.get(s)) else {
            continue;
        };
        let theta = x_k.cross(&(r_ks * x_s)).norm();
        if theta.is_finite() && best.is_none_or(|(_, t, _)| theta > t) {
            best = Some((k, theta, x_k));
        }
    }
    best
}

/// The uncertainty-based test (paper IV.C, [`crate::lidar::rejection`]) of LiDAR depth `ld`
/// against the pose-only depth `d_v` of the anchors' geometry `two` with parallax `theta`: true
/// for an outlier, i.e. testable (parallax and `d_v` within the gates) and inconsistent.
fn lidar_depth_outlier(
    cfg: &EstimatorConfig,
    ld: &LidarDepth,
    d_v: f64,
    two: &TwoView,
    theta: f64,
) -> bool {
    let (dmin, dmax) = cfg.depth_range_m;
    let min_par = cfg.min_parallax;
    let focal = crate::camera::Vec2::new(cfg.camera.fx, cfg.camera.fy);
    let lc = cfg.lidar;
    let sd_v = depth_std(two, lc.rejection_sigma_px, &focal).unwrap_or(f64::INFINITY);
    let pair = crate::lidar::DepthPair {
        d_v_m: d_v,
        sigma_dv_m: sd_v,
        d_r_m: ld.depth_m,
        sigma_dr_m: ld.sigma_m,
    };
    // In inverse depth the test gates itself at low parallax (large sigma);
    // the range check keeps degenerate geometry out.
    let testable = theta >= min_par && d_v >= dmin && d_v <= dmax;
    testable && pair.is_outlier(lc.rejection_sigmas)
}

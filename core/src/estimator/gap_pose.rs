//! The pose after a bridged IMU gap, from the images. Across a gap the INS follows the line
//! between the samples around it; where the motion turned inside the gap (a hand-held camera:
//! the gyro stepping by 2 rad/s), the line misses the rotation and the INS leaves the gap tilted
//! and fast, and the window, started from there, can settle on the wrong velocity (BENCHMARKS.md,
//! "The pose after a short gap, from the images"). At the first frame after the gap the camera
//! pose is fitted to the window's landmarks that frame sees ([`crate::landmarks::resection`]).
//! When the images contradict the INS (its pose explains fewer than half as many of those
//! observations, within [`crate::landmarks::resection::INLIER_PX`], as the fit's), the INS is
//! moved to the images' state:
//! - attitude and position: the fit's;
//! - velocity: the pre-gap state `(p0, v0)` at `t0` carried to the fit's position `p_f` at
//!   `t_f` (`T = t_f - t0`) with the world acceleration linear between its two ends (`a0` from
//!   the last sample before the gap at the pre-gap attitude, `a_f` from the frame's sample at
//!   the fit's attitude) plus the constant `c` that closes the position:
//!   `p_f = p0 + v0 T + a0 T^2/3 + a_f T^2/6 + c T^2/2`, `v_f = v0 + (a0 + a_f) T/2 + c T`;
//! - biases and covariance: unchanged.
//!
//! The window's next keyframe starts from that state; the gap's interval keeps its inflated
//! covariance. Where the line held (the INS's pose explains the frame as well as the fit), nothing
//! changes. Counted in `counters.imu_gap_poses_from_images`.

use super::predict::predictor;
use super::Estimator;
use crate::inertial::{ImuSample, NavState};
use crate::landmarks::resection::{fit_camera_pose, inliers_at};
use crate::math::Vec3;
use heapless::Vec as HVec;

/// The images' pose is taken when it explains this many times the observations the INS's pose
/// explains (within [`crate::landmarks::resection::INLIER_PX`]).
const CONTRADICTION: usize = 2;
/// Largest inlier RMS of a fit that is used, px.
const MAX_FIT_RMS_PX: f64 = 2.5;

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
    /// At the first frame after a bridged gap (`nav`: the INS state at the frame's sample
    /// `sample`), moves the INS to the images' state when they contradict it (module docs).
    /// Returns the INS state to use.
    pub(super) fn pose_after_gap(&mut self, nav: NavState, sample: &ImuSample) -> NavState {
        let Some(g) = self.gap else {
            return nav;
        };
        // The first frame at or after the gap's end: the previous one was before it.
        let first = nav.t_ns >= g.t1_ns && nav.t_ns.saturating_sub(self.frame_dt_ns) < g.t1_ns;
        if !first {
            return nav;
        }
        let Some(to) = self.images_pose(&nav, sample, &g) else {
            return nav;
        };
        let Some(ins) = self.ins.as_mut() else {
            return nav;
        };
        let cov = ins.covariance().copied();
        if ins.set_state(to).is_err() {
            return nav;
        }
        ins.set_covariance(cov);
        self.correct_ins_window(&nav, &to);
        self.counters.imu_gap_poses_from_images += 1;
        to
    }

    /// The state the images give at `nav`'s time, when they contradict `nav` (module docs).
    /// Not inlined: its list of points (40 bytes per landmark) must not sit in the frame step's
    /// stack frame.
    #[inline(never)]
    fn images_pose(
        &self,
        nav: &NavState,
        sample: &ImuSample,
        g: &crate::inertial::preintegration::UnmeasuredSpan,
    ) -> Option<NavState> {
        let pred = predictor!(self);
        let cams = pred.window_cameras();
        let mut pts: HVec<(Vec3, [f64; 2]), L> = HVec::new();
        for o in self.frame_obs.iter() {
            let Some((p_w, _)) = self.lms.get(o.id).and_then(|lm| pred.landmark_w(lm, &cams))
            else {
                continue;
            };
            if pts.push((p_w, o.x_n)).is_err() {
                break;
            }
        }
        let init = self.ext.camera_pose(&nav.p_wb, &nav.q_wb);
        let fit = fit_camera_pose(&pts, &init, self.focal_px())?;
        if fit.rms_px > MAX_FIT_RMS_PX {
            return None;
        }
        // The images contradict the INS: its pose explains fewer than half the observations the
        // images' pose explains.
        let (ins_inliers, _) = inliers_at(&pts, &init, self.focal_px());
        if ins_inliers.saturating_mul(CONTRADICTION) >= fit.inliers {
            return None;
        }
        let q_wb = fit.pose.q_wc * self.ext.q_bc.inverse();
        let p_wb = fit.pose.p_wc - q_wb * self.ext.p_bc;
        // The pre-gap state and specific force.
        let (_, s0, _) = self.ins_window.bracket(g.t0_ns, 0).ok()?;
        let f0 = self
            .open()?
            .samples()
            .iter()
            .find(|x| x.t_ns == g.t0_ns)?
            .accel_mps2;
        if s0.t_ns != g.t0_ns {
            return None;
        }
        let t = nav.t_ns.saturating_sub(g.t0_ns) as f64 * 1e-9;
        if t <= 0.0 {
            return None;
        }
        let g_w = Vec3::new(0.0, 0.0, -self.cfg.gravity_mps2);
        let a0 = s0.q_wb * (f0 - s0.ba) + g_w;
        let a_f = q_wb * (sample.accel_mps2 - nav.ba) + g_w;
        let c = (p_wb - s0.p_wb - s0.v_wb * t - a0 * (t * t / 3.0) - a_f * (t * t / 6.0))
            * (2.0 / (t * t));
        let v_wb = s0.v_wb + (a0 + a_f) * (t * 0.5) + c * t;
        let to = NavState {
            p_wb,
            q_wb,
            v_wb,
            ..*nav
        };
        let finite = p_wb.iter().chain(v_wb.iter()).all(|x| x.is_finite());
        finite.then_some(to)
    }
}

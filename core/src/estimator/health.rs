//! Health monitor: notices when the window breaks down and falls back to the INS.
//!
//! After every keyframe solve the newest keyframe is checked against limits no healthy solution
//! reaches: non-finite or implausibly fast states, biases beyond the sensor's physical range, a
//! velocity correction far beyond what the INS could have drifted since the last keyframe, and
//! visual residuals that stay many sigmas large (the window no longer explains its own
//! measurements). On a breakdown the window, its landmarks and its prior are dropped and the INS
//! continues alone from its own prediction of the keyframe state (INS-only, as between
//! keyframes); the next frame starts a new window from that state with a wide prior
//! ([`super::HealthConfig::reinit_prior`]); after a camera dropout, which breaks nothing, the
//! new window starts from the dropped one's covariance propagated over the dropout instead
//! (`imu_step`). Each re-initialization is counted
//! ([`super::Counters::reinitializations`]) and reported with its reason
//! ([`super::KeyframeReport::breakdown`]). Only when the INS itself is no longer finite does the
//! estimator fall back to waiting for a static initialization.

use super::report::Breakdown;
use super::Estimator;
use crate::inertial::NavState;

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
    /// Checks the window after a solve (`predicted`: the INS state the newest keyframe started
    /// from; `report`: the solve's residuals, landmarks and window correction; `window_path_m`:
    /// the path the window spanned before the solve). Returns the breakdown, if any.
    pub(super) fn check_health(
        &mut self,
        predicted: &NavState,
        report: &super::KeyframeReport,
        window_path_m: f64,
    ) -> Option<Breakdown> {
        let h = self.cfg.health;
        if !h.enabled {
            return None;
        }
        let st = self.window.last()?.state;
        let finite = st
            .p_wb
            .iter()
            .chain(st.v_wb.iter())
            .chain(st.bg.iter())
            .chain(st.ba.iter())
            .chain(st.q_wb.coords.iter())
            .all(|x| x.is_finite());
        if !finite || st.v_wb.amax() > self.cfg.max_speed_mps {
            return Some(Breakdown::State);
        }
        if st.bg.amax() > h.max_gyro_bias_rps || st.ba.amax() > h.max_accel_bias_mps2 {
            return Some(Breakdown::Bias);
        }
        // While the window holds a bridged IMU gap, the INS predictions after it start from
        // states that the gap left uncertain: allow that uncertainty (3 sigma).
        let gap_var = self
            .keyframes()
            .filter_map(|k| k.preint())
            .map(|p| p.unmeasured_velocity_var())
            .fold(0.0, f64::max);
        let allowed = h.max_velocity_correction_mps + 3.0 * libm::sqrt(3.0 * gap_var);
        if (st.v_wb - predicted.v_wb).norm() > allowed {
            return Some(Breakdown::VelocityJump);
        }
        let limit = h.max_window_correction_m + h.max_window_correction_rel * window_path_m;
        // A NaN correction is a breakdown too.
        let c = report.window_correction_m;
        if c.is_nan() || c > limit {
            return Some(Breakdown::WindowJump);
        }
        let bad = report.landmarks_used >= 10
            && report.residual_rms_px > h.max_residual_sigmas * self.cfg.sigma_px;
        self.bad_keyframes = if bad { self.bad_keyframes + 1 } else { 0 };
        (self.bad_keyframes >= h.bad_keyframes).then_some(Breakdown::Residuals)
    }

    /// Largest position change of the keyframes but the newest against `before` (the window's
    /// poses before the solve), m, and the path `before` spans (the limit's scale), m.
    pub(super) fn window_correction(
        &self,
        before: &[crate::factors::KeyframePose; N],
    ) -> (f64, f64) {
        let n = self.window.len().min(N);
        let span = before.get(..n).unwrap_or(&[]);
        let pairs = span.iter().zip(span.iter().skip(1));
        let path_m = pairs.map(|(a, b)| (b.p_wb - a.p_wb).norm()).sum();
        let correction = (0..n.saturating_sub(1))
            .filter_map(|k| Some((self.window.get(k)?.state.p_wb - before.get(k)?.p_wb).norm()))
            // Not `f64::max`, which drops a NaN: a non-finite keyframe must fail the check.
            .fold(0.0, |m, x| if x.is_nan() || x > m { x } else { m });
        (correction, path_m)
    }

    /// Drops the window and continues INS-only from `predicted` (the INS's own state at the
    /// newest keyframe); the next keyframe starts a new window with the wide prior. A
    /// non-finite INS state resets the estimator instead.
    pub(super) fn reinitialize_from(&mut self, predicted: NavState) {
        let keep = super::Reinit {
            td_s: self.current_td(),
            ext: self.ext,
        };
        self.reset_window();
        self.bad_keyframes = 0;
        self.counters.reinitializations += 1;
        let ok = self
            .ins
            .as_mut()
            .is_some_and(|ins| ins.set_state(predicted).is_ok());
        if !ok {
            self.reset();
            return;
        }
        self.ext = keep.ext;
        self.reinit = Some(keep);
    }
}

//! A continuous IMU-rate output for control ([`OutputSmoother`]).
//!
//! The exact output (the estimator's INS, or a [`super::FastPath`]) jumps when an update
//! restarts the INS from a keyframe's optimized state: the whole correction lands in one IMU
//! step. A controller's filter sees such a step as an innovation. The smoother publishes
//! instead `exact ⊕ offset`, where the offset takes each jump as it happens (so the output
//! does not move at the update) and then falls linearly to zero over the horizon
//! `horizon_s` after the newest update:
//!
//! - at an update, with `before` the exact state at the newest sample just before it and
//!   `after` the same sample's state after it:
//!   `δp += p_before - p_after`, `δv += v_before - v_after`,
//!   `δR = R_before R_afterᵀ δR_prev-composed` (world-frame, left: `R_out = δR R_exact`);
//! - at every published sample, `Δt` after the previous one, with `r` the horizon's time
//!   left (`horizon_s` at an update): `a = 1 - Δt / r` (0 once `r <= Δt`), raised so that
//!   the position offset falls by at most `max_rate_mps Δt` in the step; `r ← r - Δt`, and
//!   `δp ← a δp`, `δv ← a δv`, `δR ← Exp(a Log δR)`;
//! - the output: `p = p_exact + δp`, `v = v_exact + δv`, `R = δR R_exact`; biases and time
//!   are the exact state's.
//!
//! So a step of the output departs from the motion the IMU measured (the exact output's step
//! without its jump) by `(1 - a) |offset|` = `Δt / r |offset|`: at most `Δt / horizon_s` of
//! the outstanding correction, 5% with 5 ms samples and the default 0.1 s horizon (5 mm of a
//! 10 cm correction), and never more than `max_rate_mps Δt` (5 mm at the default 1 m/s: a
//! 1 m correction of a car's estimate takes 1 s). The output equals the exact one `horizon_s` after the newest update; it
//! lags by the correction meanwhile, on average half of it over the horizon (the accuracy
//! cost: a linear fall costs half an exponential decay with the same largest step). A reset
//! (the estimator publishes nothing) clears the offset.
//!
//! Frames: as [`NavState`] (`p_wb`, `q_wb`, `v_wb` of the IMU body in the world `w`).

use super::state::NavState;
use crate::math::so3::log_so3;
use crate::math::{Quat, Vec3};

/// See the module docs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputSmoother {
    /// The horizon over which a correction is spread, s.
    pub horizon_s: f64,
    /// The fastest the position offset is taken back, m/s (a large correction then takes
    /// longer than the horizon).
    pub max_rate_mps: f64,
    /// Time left of the horizon, s.
    left_s: f64,
    dp_w: Vec3,
    dv_w: Vec3,
    dq_w: Quat,
    last_t_ns: Option<i64>,
    last_step_m: f64,
}

/// The default horizon, s.
pub const DEFAULT_HORIZON_S: f64 = 0.1;
/// The default fastest rate at which a position offset is taken back, m/s (5 mm per 5 ms
/// step).
pub const DEFAULT_MAX_RATE_MPS: f64 = 1.0;

impl Default for OutputSmoother {
    fn default() -> Self {
        Self::new(DEFAULT_HORIZON_S)
    }
}

impl OutputSmoother {
    /// A smoother spreading each correction over `horizon_s` (> 0; a non-positive or
    /// non-finite one makes the output exact).
    pub fn new(horizon_s: f64) -> Self {
        OutputSmoother {
            horizon_s,
            max_rate_mps: DEFAULT_MAX_RATE_MPS,
            left_s: 0.0,
            dp_w: Vec3::zeros(),
            dv_w: Vec3::zeros(),
            dq_w: Quat::identity(),
            last_t_ns: None,
            last_step_m: 0.0,
        }
    }

    /// An update moved the exact state at one sample from `before` to `after` (same time);
    /// `after` `None` (a reset) clears the offset. States at different times are ignored (the
    /// update came before the fast path had a state to jump from).
    pub fn on_update(&mut self, before: Option<&NavState>, after: Option<&NavState>) {
        let Some(after) = after else {
            *self = OutputSmoother {
                max_rate_mps: self.max_rate_mps,
                ..Self::new(self.horizon_s)
            };
            return;
        };
        let Some(before) = before else { return };
        if before.t_ns != after.t_ns || !(self.horizon_s.is_finite() && self.horizon_s > 0.0) {
            return;
        }
        self.left_s = self.horizon_s;
        self.dp_w += before.p_wb - after.p_wb;
        self.dv_w += before.v_wb - after.v_wb;
        self.dq_w = before.q_wb * after.q_wb.inverse() * self.dq_w;
    }

    /// The published state for the exact state `exact` (the offset first reduced for the time
    /// since the previous output).
    pub fn output(&mut self, exact: &NavState) -> NavState {
        if let Some(t0) = self.last_t_ns {
            let dt_s = (exact.t_ns - t0).max(0) as f64 * 1e-9;
            let mut a = if self.left_s > dt_s {
                1.0 - dt_s / self.left_s
            } else {
                0.0
            };
            let dp = self.dp_w.norm();
            let cap_m = self.max_rate_mps * dt_s;
            if (1.0 - a) * dp > cap_m && cap_m > 0.0 {
                a = 1.0 - cap_m / dp;
            }
            self.left_s = (self.left_s - dt_s).max(0.0);
            if a.is_finite() {
                self.last_step_m = (1.0 - a) * self.dp_w.norm();
                self.dp_w *= a;
                self.dv_w *= a;
                self.dq_w = Quat::from_scaled_axis(log_so3(&self.dq_w) * a);
            }
        }
        self.last_t_ns = Some(exact.t_ns);
        NavState {
            p_wb: exact.p_wb + self.dp_w,
            v_wb: exact.v_wb + self.dv_w,
            q_wb: self.dq_w * exact.q_wb,
            ..*exact
        }
    }

    /// How far the newest output's step departed from the exact output's step without its
    /// jumps (the motion the IMU measured), m: the offset's decay over that step.
    pub fn last_step_m(&self) -> f64 {
        self.last_step_m
    }

    /// The outstanding position offset, m.
    pub fn offset_m(&self) -> f64 {
        self.dp_w.norm()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(t_ns: i64, x: f64, yaw: f64) -> NavState {
        NavState {
            t_ns,
            p_wb: Vec3::new(x, 0.0, 1.0),
            q_wb: Quat::from_euler_angles(0.0, 0.0, yaw),
            v_wb: Vec3::new(1.0, 0.0, 0.0),
            bg: Vec3::zeros(),
            ba: Vec3::zeros(),
        }
    }

    #[test]
    fn a_jump_is_absorbed_then_decays_to_the_exact_output() {
        let mut s = OutputSmoother::new(0.1);
        let dt = 5_000_000;
        // Moving at 1 m/s; at sample 10 an update moves the state back 10 cm and yaws 1°.
        let mut prev = s.output(&state(0, 0.0, 0.0));
        let mut max_step_departure: f64 = 0.0;
        for k in 1..400 {
            let x = k as f64 * 0.005;
            let (jx, jyaw) = if k >= 10 { (-0.1, 0.0175) } else { (0.0, 0.0) };
            if k == 10 {
                s.on_update(
                    Some(&state(k * dt, x, 0.0)),
                    Some(&state(k * dt, x + jx, jyaw)),
                );
            }
            let out = s.output(&state(k * dt, x + jx, jyaw));
            // The IMU measured 5 mm per step.
            let dep = ((out.p_wb.x - prev.p_wb.x) - 0.005).abs();
            max_step_departure = max_step_departure.max(dep);
            prev = out;
        }
        // 10 cm over 0.1 s: 5 mm per 5 ms step, gone 20 steps after the update.
        assert!(max_step_departure < 0.005 + 1e-9, "{max_step_departure}");
        assert!(max_step_departure > 0.005 - 1e-9, "{max_step_departure}");
        assert_eq!(s.offset_m(), 0.0);
        assert!((prev.p_wb.x - (399.0 * 0.005 - 0.1)).abs() < 1e-12);
        let (_, _, yaw) = prev.q_wb.euler_angles();
        assert!((yaw - 0.0175).abs() < 1e-12);
    }

    #[test]
    fn a_large_correction_is_taken_back_at_the_capped_rate() {
        let mut s = OutputSmoother::new(0.1);
        s.output(&state(0, 0.0, 0.0));
        s.on_update(Some(&state(0, 0.0, 0.0)), Some(&state(0, 1.0, 0.0)));
        let mut steps = 0;
        while s.offset_m() > 0.0 {
            steps += 1;
            let before = s.offset_m();
            s.output(&state(steps * 5_000_000, 1.0, 0.0));
            assert!(before - s.offset_m() <= 0.005 + 1e-12);
        }
        // 1 m at 5 mm per step.
        assert_eq!(steps, 200);
    }

    #[test]
    fn at_the_update_the_output_does_not_move_and_a_reset_clears() {
        let mut s = OutputSmoother::new(0.1);
        let before = state(10, 1.0, 0.3);
        let after = state(10, 1.2, 0.1);
        s.on_update(Some(&before), Some(&after));
        let out = s.output(&after);
        assert!((out.p_wb - before.p_wb).norm() < 1e-12);
        assert!(out.q_wb.angle_to(&before.q_wb) < 1e-12);
        assert!((out.v_wb - before.v_wb).norm() < 1e-12);
        s.on_update(Some(&after), None);
        assert_eq!(s.output(&after), after);
    }
}

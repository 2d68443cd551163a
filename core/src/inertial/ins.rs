//! Strapdown INS mechanization at IMU rate in a local, non-rotating world frame `w` (z up,
//! gravity `g_w = (0, 0, -g)`; Earth rotation is neglected).
//!
//! Each accepted sample `k` closes the interval `[t_{k-1}, t_k]` and applies the two-sample step
//! of [`super::increment`] (`phi_k`, `dv'_k`, resolved in `b_{k-1}`):
//!
//! ```text
//! v_k = v_{k-1} + R_{k-1} dv'_k + g_w dt
//! p_k = p_{k-1} + (v_{k-1} + v_k)/2 dt
//! q_k = q_{k-1} Exp(phi_k)
//! ```
//!
//! The velocity update is exact for the increment model; the trapezoidal position update is the
//! same one the preintegration uses, so an INS run and a preintegrated window from the same state
//! agree to rounding. Biases in the [`NavState`] are held constant.

use super::covariance::{InsCovariance, MaybeCovariance};
use super::imu::{check_sample, ImuSample};
use super::increment::{two_sample, two_sample_bias_jacobians, Increment};
use super::state::{renormalize, state_from_full, NavState};
use crate::math::{quat_exp, Vec3};
use crate::Error;

/// INS configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct InsConfig {
    /// Gravity magnitude, m/s^2 (acts along `-z` of the world).
    pub gravity_mps2: f64,
    /// Largest accepted spacing of consecutive samples, s; larger gaps return [`Error::TimeGap`].
    pub max_dt_s: f64,
}

impl InsConfig {
    /// 9.81 m/s^2 and gaps up to 50 ms.
    pub const DEFAULT: InsConfig = InsConfig {
        gravity_mps2: 9.81,
        max_dt_s: 0.05,
    };

    /// True when gravity is finite and positive and the maximum gap finite and positive.
    pub fn is_valid(&self) -> bool {
        self.gravity_mps2.is_finite()
            && self.gravity_mps2 > 0.0
            && self.max_dt_s.is_finite()
            && self.max_dt_s > 0.0
    }

    /// Gravity vector in the world frame.
    pub fn gravity_w(&self) -> Vec3 {
        Vec3::new(0.0, 0.0, -self.gravity_mps2)
    }
}

/// The INS: current navigation state plus the previous sample and increment the two-sample
/// scheme needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ins {
    cfg: InsConfig,
    state: NavState,
    /// The sample at `state.t_ns`, when known.
    prev_sample: Option<ImuSample>,
    /// The sample before `prev_sample`, when known (for the quadratic increment).
    older_sample: Option<ImuSample>,
    /// The increment of the interval that ended at `state.t_ns`, when known.
    prev_inc: Option<Increment>,
    /// The state's error covariance, propagated with every sample when set.
    cov: MaybeCovariance,
}

impl Ins {
    /// Starts the INS from a full state (see [`state_from_full`] for validation).
    pub fn new(cfg: InsConfig, state: NavState) -> Result<Self, Error> {
        if !cfg.is_valid() {
            return Err(Error::InvalidConfig);
        }
        let state = state_from_full(&state)?;
        Ok(Ins {
            cfg,
            state,
            prev_sample: None,
            older_sample: None,
            prev_inc: None,
            cov: MaybeCovariance::NONE,
        })
    }

    /// Storage for an INS that has not started: every number zero (not a usable INS; the
    /// estimator keeps it beside a flag).
    pub(crate) const fn blank() -> Self {
        Ins {
            cfg: InsConfig {
                gravity_mps2: 0.0,
                max_dt_s: 0.0,
            },
            state: NavState::ZERO,
            prev_sample: None,
            older_sample: None,
            prev_inc: None,
            cov: MaybeCovariance::NONE,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &InsConfig {
        &self.cfg
    }

    /// The current state.
    pub fn state(&self) -> &NavState {
        &self.state
    }

    /// The state's error covariance ([`InsCovariance`]), when the owner set one: propagated
    /// with every sample from then on, dropped by [`Ins::set_state`].
    pub fn covariance(&self) -> Option<&InsCovariance> {
        self.cov.get()
    }

    /// Sets (or clears) the covariance of the current state.
    pub fn set_covariance(&mut self, cov: Option<InsCovariance>) {
        self.cov = MaybeCovariance::new(cov);
    }

    /// The same INS on a clock `dt_ns` later: its state's and stored samples' times moved by
    /// `dt_ns` (a clock jump seen by the estimator, `estimator::clock_jump`).
    pub fn time_shifted(&self, dt_ns: i64) -> Ins {
        let mv = |s: ImuSample| ImuSample {
            t_ns: s.t_ns.saturating_add(dt_ns),
            ..s
        };
        let mut ins = *self;
        ins.state.t_ns = ins.state.t_ns.saturating_add(dt_ns);
        ins.prev_sample = ins.prev_sample.map(mv);
        ins.older_sample = ins.older_sample.map(mv);
        ins
    }

    /// Replaces the state (e.g. after an estimator update). The previous sample is kept only if
    /// it was taken at the new state's time; the two-sample history restarts either way, because
    /// the correction changed the biases the increments were formed with. The covariance is
    /// dropped (it described the old state): set the new one with [`Ins::set_covariance`].
    pub fn set_state(&mut self, state: NavState) -> Result<(), Error> {
        let state = state_from_full(&state)?;
        self.cov = MaybeCovariance::NONE;
        if self.prev_sample.is_some_and(|s| s.t_ns != state.t_ns) {
            self.prev_sample = None;
            self.older_sample = None;
        }
        self.prev_inc = None;
        self.state = state;
        Ok(())
    }

    /// Propagates to `s.t_ns`. A sample at exactly the state's time (only before the first
    /// propagation) is stored as the interval start. Without a stored sample the first interval
    /// holds `s` constant; without the sample before it the increment is trapezoidal. Rejected samples leave the INS untouched:
    /// [`Error::NonFinite`], [`Error::TimeNotIncreasing`], [`Error::TimeGap`].
    pub fn propagate(&mut self, s: &ImuSample) -> Result<&NavState, Error> {
        if self.prev_sample.is_none() && s.t_ns == self.state.t_ns {
            if !s.is_finite() {
                return Err(Error::NonFinite);
            }
            self.prev_sample = Some(*s);
            return Ok(&self.state);
        }
        let dt_s = check_sample(s, self.state.t_ns, self.cfg.max_dt_s)?;
        // Without a stored start sample, hold `s` constant over the interval: the start sample
        // must carry the state's time, or the increment would span zero seconds.
        let start = self.prev_sample.unwrap_or(ImuSample {
            t_ns: self.state.t_ns,
            ..*s
        });
        let inc = Increment::from_samples(
            self.older_sample.as_ref(),
            &start,
            s,
            &self.state.bg,
            &self.state.ba,
        );
        let step = two_sample(self.prev_inc.as_ref(), &inc);
        if let Some(cov) = self.cov.get_mut() {
            let jb = two_sample_bias_jacobians(self.prev_inc.as_ref(), &inc);
            let r_wb = self.state.q_wb.to_rotation_matrix().into_inner();
            cov.step(r_wb, &step, &jb, dt_s);
        }

        let st = &mut self.state;
        let v_new = st.v_wb + st.q_wb * step.dv + self.cfg.gravity_w() * dt_s;
        st.p_wb += (st.v_wb + v_new) * (0.5 * dt_s);
        st.v_wb = v_new;
        st.q_wb = renormalize(st.q_wb * quat_exp(&step.phi));
        st.t_ns = s.t_ns;

        self.older_sample = self.prev_sample;
        self.prev_sample = Some(*s);
        self.prev_inc = Some(inc);
        Ok(&self.state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{log_so3, Quat};
    use nalgebra::Quaternion;

    const G: f64 = 9.81;

    fn cfg() -> InsConfig {
        InsConfig {
            gravity_mps2: G,
            max_dt_s: 0.02,
        }
    }

    fn sample(t_ns: i64, w: Vec3, f: Vec3) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rps: w,
            accel_mps2: f,
        }
    }

    #[test]
    fn constant_rate_rotation_is_exact() {
        let w = Vec3::new(0.3, -0.5, 1.1);
        let mut ins = Ins::new(cfg(), NavState::identity(0)).unwrap();
        // At rest otherwise: the specific force must cancel gravity in every attitude, so feed the
        // body-frame image of +g computed from the true attitude.
        let dt_ns = 5_000_000;
        for k in 0..=2000i64 {
            let t = k as f64 * 5e-3;
            let q_true = quat_exp(&(w * t));
            let f = q_true.inverse() * Vec3::new(0.0, 0.0, G);
            ins.propagate(&sample(k * dt_ns, w, f)).unwrap();
        }
        let st = *ins.state();
        let q_true = quat_exp(&(w * 10.0));
        let att_err = log_so3(&(q_true.inverse() * st.q_wb)).norm();
        assert!(att_err < 1e-10, "attitude error {att_err}");
        // The specific force rotates within each interval. Without rotation compensation the
        // velocity would drift by |w x g| h T / 2 ~ 0.14 m/s; the two-sample scheme leaves only
        // its third-order term, constant in the world for a fixed rotation axis:
        // dv = -(w x (w x g_up)) h^2 T / 6.
        let g_up = Vec3::new(0.0, 0.0, G);
        let predicted = -w.cross(&w.cross(&g_up)) * (0.005 * 0.005 * 10.0 / 6.0);
        let rel = (st.v_wb - predicted).norm() / predicted.norm();
        assert!(
            rel < 0.02,
            "velocity {:?} vs predicted {:?}",
            st.v_wb,
            predicted
        );
        assert!(st.v_wb.norm() < 4e-4);
        assert!(st.p_wb.norm() < 2.5e-3, "position {:?}", st.p_wb);
    }

    #[test]
    fn constant_acceleration_closed_form() {
        // Tilted, non-rotating body with constant world acceleration a_w.
        let q = quat_exp(&Vec3::new(0.2, -0.1, 0.7));
        let a_w = Vec3::new(0.5, -0.25, 0.1);
        let v0 = Vec3::new(1.0, 2.0, -0.5);
        let mut st = NavState::identity(0);
        st.q_wb = q;
        st.v_wb = v0;
        let f_b = q.inverse() * (a_w + Vec3::new(0.0, 0.0, G));
        let mut ins = Ins::new(cfg(), st).unwrap();
        for k in 0..=1000i64 {
            ins.propagate(&sample(k * 10_000_000, Vec3::zeros(), f_b))
                .unwrap();
        }
        let t = 10.0;
        let st = ins.state();
        let p_true = v0 * t + a_w * (0.5 * t * t);
        let v_true = v0 + a_w * t;
        assert!((st.p_wb - p_true).norm() < 1e-9, "{:?}", st.p_wb - p_true);
        assert!((st.v_wb - v_true).norm() < 1e-10);
        assert_eq!(st.t_ns, 10_000_000_000);
    }

    /// Starting without a sample at the state's time (e.g. after `set_state`) must still
    /// integrate the specific force over the first interval, not only gravity.
    #[test]
    fn first_interval_without_start_sample_integrates_specific_force() {
        let f_b = Vec3::new(0.0, 0.0, G);
        let mut ins = Ins::new(cfg(), NavState::identity(0)).unwrap();
        for k in 1..=100i64 {
            ins.propagate(&sample(k * 5_000_000, Vec3::zeros(), f_b))
                .unwrap();
        }
        let st = ins.state();
        assert!(st.v_wb.norm() < 1e-12, "at rest, velocity {:?}", st.v_wb);
        assert!(st.p_wb.norm() < 1e-12, "at rest, position {:?}", st.p_wb);
    }

    /// Classic coning: the body axis precesses on a cone of half angle `beta` at rate `omega`,
    /// `q(t) = [cos(beta/2), sin(beta/2) (cos wt, sin wt, 0)]`; `w_b = 2 Im(q^* dq/dt)`.
    /// The attitude has no net rotation about the cone axis in inertial space, but a one-sample
    /// integrator accumulates a spurious drift that the coning term removes.
    #[test]
    fn coning_two_sample_beats_one_sample() {
        let (beta, omega) = (0.1_f64, 2.0 * core::f64::consts::PI * 4.0);
        let (s, c) = (libm::sin(0.5 * beta), libm::cos(0.5 * beta));
        let q_at = |t: f64| {
            Quat::new_unchecked(Quaternion::new(
                c,
                s * libm::cos(omega * t),
                s * libm::sin(omega * t),
                0.0,
            ))
        };
        let w_at = |t: f64| {
            let dq = Quaternion::new(
                0.0,
                -s * omega * libm::sin(omega * t),
                s * omega * libm::cos(omega * t),
                0.0,
            );
            (q_at(t).into_inner().conjugate() * dq).imag() * 2.0
        };
        let dt = 0.005;
        let n = 2000i64; // 10 s
        let mut ins = Ins::new(
            cfg(),
            NavState {
                q_wb: q_at(0.0),
                ..NavState::identity(0)
            },
        )
        .unwrap();
        // One-sample reference: the same (quadratic) increments, no coning term.
        let mut q_one = q_at(0.0);
        for k in 0..=n {
            let t = k as f64 * dt;
            let w = w_at(t);
            let f = q_at(t).inverse() * Vec3::new(0.0, 0.0, G);
            ins.propagate(&sample(k * 5_000_000, w, f)).unwrap();
            if k > 0 {
                let older =
                    (k >= 2).then(|| sample((k - 2) * 5_000_000, w_at((k - 2) as f64 * dt), f));
                let prev = sample((k - 1) * 5_000_000, w_at((k - 1) as f64 * dt), f);
                let cur = sample(k * 5_000_000, w, f);
                let z = Vec3::zeros();
                let inc = Increment::from_samples(older.as_ref(), &prev, &cur, &z, &z);
                q_one = renormalize(q_one * quat_exp(&inc.dtheta));
            }
        }
        let q_true = q_at(n as f64 * dt);
        let e_two = log_so3(&(q_true.inverse() * ins.state().q_wb)).norm();
        let e_one = log_so3(&(q_true.inverse() * q_one)).norm();
        assert!(
            e_one > 1e-4,
            "one-sample error {e_one} too small to compare"
        );
        assert!(
            e_two < 0.05 * e_one,
            "two-sample {e_two} vs one-sample {e_one}"
        );
    }

    #[test]
    fn rejects_bad_samples_without_corrupting_state() {
        let mut ins = Ins::new(cfg(), NavState::identity(0)).unwrap();
        let f = Vec3::new(0.0, 0.0, G);
        ins.propagate(&sample(0, Vec3::zeros(), f)).unwrap();
        ins.propagate(&sample(5_000_000, Vec3::new(0.1, 0.0, 0.0), f))
            .unwrap();
        let before = ins;
        let bad = [
            (
                sample(10_000_000, Vec3::new(f64::NAN, 0.0, 0.0), f),
                Error::NonFinite,
            ),
            (
                sample(
                    10_000_000,
                    Vec3::zeros(),
                    Vec3::new(0.0, f64::INFINITY, 0.0),
                ),
                Error::NonFinite,
            ),
            (
                sample(5_000_000, Vec3::zeros(), f),
                Error::TimeNotIncreasing,
            ),
            (
                sample(1_000_000, Vec3::zeros(), f),
                Error::TimeNotIncreasing,
            ),
            (sample(30_000_000, Vec3::zeros(), f), Error::TimeGap),
            (sample(i64::MAX, Vec3::zeros(), f), Error::TimeGap),
        ];
        for (s, e) in bad {
            assert_eq!(ins.propagate(&s).err(), Some(e));
            assert_eq!(ins, before);
        }
        // A good sample after the rejections continues normally.
        assert_eq!(
            ins.propagate(&sample(10_000_000, Vec3::zeros(), f))
                .unwrap()
                .t_ns,
            10_000_000
        );
    }

    #[test]
    fn rejects_invalid_config_and_state() {
        let bad_cfg = InsConfig {
            gravity_mps2: f64::NAN,
            max_dt_s: 0.01,
        };
        assert_eq!(
            Ins::new(bad_cfg, NavState::identity(0)).err(),
            Some(Error::InvalidConfig)
        );
        let mut st = NavState::identity(0);
        st.v_wb.x = f64::NAN;
        assert_eq!(Ins::new(cfg(), st).err(), Some(Error::NonFinite));
    }
}

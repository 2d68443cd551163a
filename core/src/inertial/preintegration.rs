//! IMU preintegration between two keyframes `i` and `j` (paper eq. 18, math-notes section 8).
//!
//! ## Deltas
//! Starting from the sample at `t_i`, every further sample applies the two-sample step of
//! [`super::increment`] (the first step has no earlier sample: trapezoid, no coning/sculling) (`phi_k`, `dv'_k` in `b_{k-1}`, formed with the linearization biases
//! `bg0`, `ba0`), exactly as the INS does but without gravity:
//!
//! ```text
//! dp <- dp + dv dt + 1/2 dR dv'_k dt       dv <- dv + dR dv'_k       dR <- dR Exp(phi_k)
//! ```
//!
//! ## Error state, covariance and bias Jacobians
//! The 15-dim error `[dp, dv, dth, dbg, dba]` (true = measured + error for `p`, `v`;
//! `dR_true = dR Exp(dth)`; bias errors relative to the bias at `i`) propagates with
//!
//! ```text
//! dth' = Exp(phi)^T dth + Jr(phi) (Phi_bg dbg + n_th)
//! dv'  = dv - dR [dv'_k]x dth + dR (V_bg dbg + V_ba dba + n_v)
//! dp'  = dp + dt dv + dt/2 (-dR [dv'_k]x dth + dR (V_bg dbg + V_ba dba + n_v))
//! db'  = rho db + n_b,   rho = exp(-dt/T) (Gauss-Markov) or 1 (random walk)
//! ```
//!
//! with `Phi_bg`, `V_bg`, `V_ba` the step's exact bias Jacobians, `n_th ~ N(0, sg^2 dt)`,
//! `n_v ~ N(0, sa^2 dt)` (continuous white-noise densities), and `n_b ~ N(0, sb^2 dt)` for a random
//! walk or `N(0, sb^2 T/2 (1 - rho^2))` for Gauss-Markov. The same recursion with the noise
//! dropped gives the bias Jacobians of the deltas, which are therefore exact derivatives of the
//! discrete scheme (numerically tested). The first-order corrected deltas for biases `bg`, `ba` are
//! `dR Exp(J_R_bg (bg - bg0))`, `dv + J_v_bg (bg - bg0) + J_v_ba (ba - ba0)`, likewise `dp`.
//!
//! ## Residual
//! Order `[r_p, r_v, r_th, r_bg, r_ba]`, `g_w = (0, 0, -g)`, `T = t_j - t_i`:
//!
//! ```text
//! r_p  = R_i^T (p_j - p_i - v_i T - 1/2 g_w T^2) - dp_c
//! r_v  = R_i^T (v_j - v_i - g_w T) - dv_c
//! r_th = Log(dR_c^T R_i^T R_j)
//! r_bg = bg_j - rho_T bg_i,   r_ba = ba_j - rho_T ba_i   (rho_T = 1 for a random walk)
//! ```
//!
//! The paper writes the rotation row as `Log(q_j^-1 q_i dq)`, the negative of `r_th` above. The
//! form used here has the same sign as the position and velocity rows (measurement error enters
//! all three as `-error`), so the propagated covariance (including its cross terms) is the
//! covariance of this residual. Jacobians are w.r.t. the keyframe error states
//! `[p, th, v, bg, ba]` with `p <- p + dp`, `R <- R Exp(dth)`, `v <- v + dv`, `b <- b + db`.
//!
//! ## Capacity and re-integration
//! All raw samples (including the start sample) are kept so the deltas can be re-integrated
//! when the bias estimate moves further than the configured thresholds from `bg0`, `ba0`.
//! When `M` samples are stored, [`Preintegration::push`] returns [`Error::CapacityExceeded`] and
//! leaves the preintegration unchanged: the caller must close the keyframe interval there (start
//! a new keyframe), so re-integration is always available and exact.
//!
//! ## Unmeasured spans (bridged IMU gaps)
//! Across an IMU gap the caller feeds samples interpolated between the samples around it and
//! declares the span ([`Preintegration::add_unmeasured`]) with the variance rates of the
//! unmeasured specific force and angular rate about that line. Every step overlapping the span
//! by `d` seconds adds `q_a d` to `n_v`'s and `q_g d` to `n_th`'s variance; with
//! `q = sigma^2 T_gap` the whole gap adds `sigma^2 T_gap^2` to the velocity and rotation
//! variances: the error of a wrong but constant specific force over the gap. The spans are
//! kept with the samples, so re-integration and truncation give the same covariance.

use super::imu::{check_sample, ImuNoise, ImuSample};
use super::increment::{span_s, two_sample, two_sample_bias_jacobians, Increment};
use super::state::{renormalize, NavState};
use crate::math::{exp_so3, jr_inv_so3, jr_so3, log_so3, quat_exp, skew, Mat3, Quat, Vec3};
use crate::Error;
use heapless::Vec as HVec;

pub use super::covariance::{Mat15, Vec15};

/// Zero matrices and the noise, configuration and (non-unit) quaternion of
/// [`Preintegration::empty`]: all bits zero.
const Z3: Mat3 = Mat3::from_array_storage(nalgebra::ArrayStorage([[0.0; 3]; 3]));
const Z15: Mat15 = Mat15::from_array_storage(nalgebra::ArrayStorage([[0.0; 15]; 15]));
const ZERO_NOISE: ImuNoise = ImuNoise {
    gyro_noise_density: 0.0,
    accel_noise_density: 0.0,
    gyro_bias_rw: 0.0,
    accel_bias_rw: 0.0,
    bias_corr_time_s: None,
};
const ZERO_CONFIG: PreintConfig = PreintConfig {
    max_dt_s: 0.0,
    reint_bg_rps: 0.0,
    reint_ba_mps2: 0.0,
};
const ZERO_QUAT: Quat = Quat::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));

/// Residual block offsets (`[dp, dv, dtheta, dbg, dba]`).
use super::covariance::{self, bias_step, StepNoise, StepTerms, RBA, RBG, RP, RT, RV};
/// Keyframe error-state offsets (`[p, theta, v, bg, ba]`).
const XP: usize = 0;
const XT: usize = 3;
const XV: usize = 6;
const XBG: usize = 9;
const XBA: usize = 12;

/// Unmeasured spans one interval holds ([`Preintegration::add_unmeasured`]).
pub const MAX_UNMEASURED: usize = 4;

/// A span without IMU measurements (a bridged gap), `t0_ns..t1_ns` (IMU time), with the
/// variance rates its steps add: `accel_var_per_s`, (m/s^2)^2 s per s of overlap, and
/// `gyro_var_per_s`, (rad/s)^2 s per s (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnmeasuredSpan {
    /// Start (the last sample before the gap), ns.
    pub t0_ns: i64,
    /// End (the first sample after the gap), ns.
    pub t1_ns: i64,
    /// Specific-force variance rate, m^2/s^4 (variance density times the gap).
    pub accel_var_per_s: f64,
    /// Angular-rate variance rate, rad^2/s^2.
    pub gyro_var_per_s: f64,
}

/// Preintegration settings.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct PreintConfig {
    /// Largest accepted sample spacing, s ([`Error::TimeGap`] beyond).
    pub max_dt_s: f64,
    /// Re-integrate when `|bg - bg0|` exceeds this, rad/s.
    pub reint_bg_rps: f64,
    /// Re-integrate when `|ba - ba0|` exceeds this, m/s^2.
    pub reint_ba_mps2: f64,
}

impl PreintConfig {
    /// 50 ms gaps, re-integration beyond 1e-3 rad/s or 0.05 m/s^2 of bias change.
    pub const DEFAULT: PreintConfig = PreintConfig {
        max_dt_s: 0.05,
        reint_bg_rps: 1e-3,
        reint_ba_mps2: 0.05,
    };

    fn is_valid(&self) -> bool {
        [self.max_dt_s, self.reint_bg_rps, self.reint_ba_mps2]
            .iter()
            .all(|x| x.is_finite() && *x > 0.0)
    }
}

/// Preintegrated IMU measurement between keyframes `i` (its first sample) and `j` (its last),
/// storing up to `M` raw samples for re-integration. Deltas are in the body frame at `i`.
#[derive(Debug, Clone)]
pub struct Preintegration<const M: usize> {
    noise: ImuNoise,
    cfg: PreintConfig,
    bg0: Vec3,
    ba0: Vec3,
    t0_ns: i64,
    dt_s: f64,
    dp: Vec3,
    dv: Vec3,
    dq: Quat,
    /// Bias Jacobians of the deltas.
    j_p_bg: Mat3,
    j_p_ba: Mat3,
    j_v_bg: Mat3,
    j_v_ba: Mat3,
    j_r_bg: Mat3,
    /// Product of the per-step Gauss-Markov decays (1 for a random walk).
    bias_decay: f64,
    cov: Mat15,
    /// Scratch for the covariance propagation, kept here so it is not on the stack.
    a: Mat15,
    tmp: Mat15,
    prev_inc: Option<Increment>,
    samples: HVec<ImuSample, M>,
    /// Spans without IMU measurements ([`Preintegration::add_unmeasured`]).
    unmeasured: HVec<UnmeasuredSpan, MAX_UNMEASURED>,
    /// Cholesky factor of `cov`, once [`Preintegration::cache_whitening`] ran since the last
    /// change of the covariance (an estimator evaluates a closed interval many times).
    chol_l: Option<Mat15>,
}

impl<const M: usize> Preintegration<M> {
    /// Starts a preintegration at sample `first` (time of keyframe `i`) with linearization
    /// biases `bg0`, `ba0`. Errors: [`Error::InvalidConfig`] (bad noise/config or `M == 0`),
    /// [`Error::NonFinite`].
    pub fn new(
        noise: ImuNoise,
        cfg: PreintConfig,
        first: &ImuSample,
        bg0: Vec3,
        ba0: Vec3,
    ) -> Result<Self, Error> {
        let mut p = Self::empty();
        p.restart_with(noise, cfg, first, bg0, ba0)?;
        Ok(p)
    }

    /// Storage for a preintegration: no samples, every number zero (the noise and configuration
    /// too, so it cannot integrate until [`Preintegration::restart_with`]). `const` so it can
    /// initialize a `static` (its bytes are all zero).
    pub const fn empty() -> Self {
        Preintegration {
            noise: ZERO_NOISE,
            cfg: ZERO_CONFIG,
            bg0: crate::math::VEC3_ZERO,
            ba0: crate::math::VEC3_ZERO,
            t0_ns: 0,
            dt_s: 0.0,
            dp: crate::math::VEC3_ZERO,
            dv: crate::math::VEC3_ZERO,
            dq: ZERO_QUAT,
            j_p_bg: Z3,
            j_p_ba: Z3,
            j_v_bg: Z3,
            j_v_ba: Z3,
            j_r_bg: Z3,
            bias_decay: 0.0,
            cov: Z15,
            a: Z15,
            tmp: Z15,
            prev_inc: None,
            samples: HVec::new(),
            unmeasured: HVec::new(),
            chol_l: None,
        }
    }

    /// Back to [`Preintegration::empty`], in place.
    pub fn reset_to_empty(&mut self) {
        self.samples.clear();
        self.restart(Vec3::zeros(), Vec3::zeros());
        self.noise = ZERO_NOISE;
        self.cfg = ZERO_CONFIG;
        self.t0_ns = 0;
        self.dq = ZERO_QUAT;
        self.bias_decay = 0.0;
        self.a = Z15;
        self.tmp = Z15;
    }

    /// Restarts in place (no copy of the sample buffer) with a new noise model and configuration:
    /// the state [`Preintegration::new`] builds from the same arguments, with the same errors
    /// (and then the preintegration is unchanged).
    pub fn restart_with(
        &mut self,
        noise: ImuNoise,
        cfg: PreintConfig,
        first: &ImuSample,
        bg0: Vec3,
        ba0: Vec3,
    ) -> Result<(), Error> {
        if !noise.is_valid() || !cfg.is_valid() || M == 0 {
            return Err(Error::InvalidConfig);
        }
        if !first.is_finite() || !bg0.iter().chain(ba0.iter()).all(|x| x.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.noise = noise;
        self.cfg = cfg;
        self.t0_ns = first.t_ns;
        // The scratch of the covariance propagation, as a new preintegration has it.
        self.a = Mat15::identity();
        self.tmp = Mat15::zeros();
        self.reset(first, bg0, ba0)
    }

    /// Restarts in place (no copy of the sample buffer) at `first` with new linearization biases.
    /// On error the preintegration is unchanged.
    pub fn reset(&mut self, first: &ImuSample, bg0: Vec3, ba0: Vec3) -> Result<(), Error> {
        if !self.noise.is_valid() || !self.cfg.is_valid() || M == 0 {
            return Err(Error::InvalidConfig);
        }
        if !first.is_finite() || !bg0.iter().chain(ba0.iter()).all(|x| x.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.samples.clear();
        self.unmeasured.clear();
        self.samples
            .push(*first)
            .map_err(|_| Error::CapacityExceeded)?;
        self.restart(bg0, ba0);
        Ok(())
    }

    /// Declares `span` unmeasured (see the module docs): the steps overlapping it, those
    /// integrated already included (re-integrated here), take its extra noise.
    /// [`Error::CapacityExceeded`] (nothing changed) when [`MAX_UNMEASURED`] spans are held;
    /// [`Error::InvalidConfig`] for a negative or non-finite rate or an empty span.
    pub fn add_unmeasured(&mut self, span: UnmeasuredSpan) -> Result<(), Error> {
        let rate_ok = |q: f64| q.is_finite() && q >= 0.0;
        if !(rate_ok(span.accel_var_per_s) && rate_ok(span.gyro_var_per_s))
            || span.t1_ns <= span.t0_ns
        {
            return Err(Error::InvalidConfig);
        }
        self.unmeasured
            .push(span)
            .map_err(|_| Error::CapacityExceeded)?;
        if self.samples.last().is_some_and(|s| s.t_ns > span.t0_ns) {
            let (bg0, ba0) = (self.bg0, self.ba0);
            self.reintegrate(bg0, ba0)?;
        }
        Ok(())
    }

    /// The unmeasured spans declared since the interval started.
    pub fn unmeasured(&self) -> &[UnmeasuredSpan] {
        &self.unmeasured
    }

    /// Velocity variance the unmeasured spans add over the whole interval, (m/s)^2 per axis.
    pub fn unmeasured_velocity_var(&self) -> f64 {
        let t1_ns = self.samples.last().map_or(self.t0_ns, |s| s.t_ns);
        self.unmeasured_var(self.t0_ns, t1_ns).0
    }

    /// Extra variances `(accel, gyro)` of the step from `t0_ns` to `t1_ns` from the unmeasured
    /// spans it overlaps.
    fn unmeasured_var(&self, t0_ns: i64, t1_ns: i64) -> (f64, f64) {
        self.unmeasured.iter().fold((0.0, 0.0), |(qa, qg), u| {
            let d_ns = t1_ns.min(u.t1_ns).saturating_sub(t0_ns.max(u.t0_ns));
            let d_s = d_ns.max(0) as f64 * 1e-9;
            (qa + u.accel_var_per_s * d_s, qg + u.gyro_var_per_s * d_s)
        })
    }

    fn restart(&mut self, bg0: Vec3, ba0: Vec3) {
        self.chol_l = None;
        self.bg0 = bg0;
        self.ba0 = ba0;
        self.t0_ns = self.samples.first().map_or(self.t0_ns, |s| s.t_ns);
        self.dt_s = 0.0;
        self.dp = Vec3::zeros();
        self.dv = Vec3::zeros();
        self.dq = Quat::identity();
        self.j_p_bg = Mat3::zeros();
        self.j_p_ba = Mat3::zeros();
        self.j_v_bg = Mat3::zeros();
        self.j_v_ba = Mat3::zeros();
        self.j_r_bg = Mat3::zeros();
        self.bias_decay = 1.0;
        self.cov = Mat15::zeros();
        self.prev_inc = None;
    }

    /// Adds the next sample. Rejected samples leave everything unchanged: [`Error::NonFinite`],
    /// [`Error::TimeNotIncreasing`], [`Error::TimeGap`], and [`Error::CapacityExceeded`] when `M`
    /// samples are stored (close the interval and start a new keyframe).
    pub fn push(&mut self, s: &ImuSample) -> Result<(), Error> {
        let last = *self.samples.last().ok_or(Error::NotInitialized)?;
        let dt_s = check_sample(s, last.t_ns, self.cfg.max_dt_s)?;
        if self.samples.is_full() {
            return Err(Error::CapacityExceeded);
        }
        let older = self
            .samples
            .len()
            .checked_sub(2)
            .and_then(|i| self.samples.get(i))
            .copied();
        self.samples.push(*s).map_err(|_| Error::CapacityExceeded)?;
        self.integrate(older.as_ref(), &last, s, dt_s);
        Ok(())
    }

    /// One step of deltas, bias Jacobians and covariance.
    fn integrate(&mut self, older: Option<&ImuSample>, prev: &ImuSample, cur: &ImuSample, dt: f64) {
        self.chol_l = None;
        let inc = Increment::from_samples(older, prev, cur, &self.bg0, &self.ba0);
        let step = two_sample(self.prev_inc.as_ref(), &inc);
        let jb = two_sample_bias_jacobians(self.prev_inc.as_ref(), &inc);

        let terms = StepTerms::new(self.dq.to_rotation_matrix().into_inner(), &step);
        let (r, exp_t, jr, r_dvx) = (&terms.r, &terms.exp_t, &terms.jr, &terms.r_dvx);
        let half_dt = 0.5 * dt;

        let (rho, q_bg, q_ba) = bias_step(&self.noise, dt);
        // Error-state transition A, then P <- A P A^T + G Q G^T.
        covariance::transition(&mut self.a, &terms, &jb, dt, rho);
        let (qa_gap, qg_gap) = self.unmeasured_var(prev.t_ns, cur.t_ns);
        let noise = StepNoise {
            qg: self.noise.gyro_noise_density * self.noise.gyro_noise_density * dt + qg_gap,
            qa: self.noise.accel_noise_density * self.noise.accel_noise_density * dt + qa_gap,
            q_bg,
            q_ba,
        };
        covariance::propagate(&mut self.cov, &self.a, &mut self.tmp, jr, &noise, dt);

        // Bias Jacobians: the same recursion, noise-free.
        self.j_p_bg += self.j_v_bg * dt + (-r_dvx * self.j_r_bg + r * jb.dv_bg) * half_dt;
        self.j_p_ba += self.j_v_ba * dt + r * jb.dv_ba * half_dt;
        self.j_v_bg += -r_dvx * self.j_r_bg + r * jb.dv_bg;
        self.j_v_ba += r * jb.dv_ba;
        self.j_r_bg = exp_t * self.j_r_bg + jr * jb.phi_bg;

        // Deltas last: the Jacobians above use dR at the start of the step.
        self.dp += self.dv * dt + r * step.dv * half_dt;
        self.dv += r * step.dv;
        self.dq = renormalize(self.dq * quat_exp(&step.phi));
        self.dt_s += dt;
        self.bias_decay *= rho;
        self.prev_inc = Some(inc);
    }

    /// True when `bg`, `ba` moved beyond the re-integration thresholds from `bg0`, `ba0`.
    pub fn needs_reintegration(&self, bg: &Vec3, ba: &Vec3) -> bool {
        (bg - self.bg0).norm() > self.cfg.reint_bg_rps
            || (ba - self.ba0).norm() > self.cfg.reint_ba_mps2
    }

    /// Re-integrates every stored sample with new linearization biases.
    pub fn reintegrate(&mut self, bg0: Vec3, ba0: Vec3) -> Result<(), Error> {
        if !bg0.iter().chain(ba0.iter()).all(|x| x.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.restart(bg0, ba0);
        for k in 1..self.samples.len() {
            let (Some(prev), Some(cur)) = (self.samples.get(k - 1), self.samples.get(k)) else {
                return Err(Error::NotEnoughData);
            };
            let (prev, cur) = (*prev, *cur);
            let older = k.checked_sub(2).and_then(|i| self.samples.get(i)).copied();
            self.integrate(older.as_ref(), &prev, &cur, span_s(prev.t_ns, cur.t_ns));
        }
        Ok(())
    }

    /// The stored raw samples, the start sample first.
    pub fn samples(&self) -> &[ImuSample] {
        &self.samples
    }

    /// Ends the interval at `last` (a sample at a time between the start and the newest stored
    /// sample, e.g. interpolated): drops the samples at or after its time, appends it and
    /// re-integrates at the current linearization biases. [`Error::OutOfRange`] (nothing changed)
    /// unless `last` lies strictly after the start.
    pub fn truncate_at(&mut self, last: &ImuSample) -> Result<(), Error> {
        if !last.is_finite() {
            return Err(Error::NonFinite);
        }
        if last.t_ns <= self.t0_ns {
            return Err(Error::OutOfRange);
        }
        let keep = self
            .samples
            .iter()
            .take_while(|s| s.t_ns < last.t_ns)
            .count();
        self.samples.truncate(keep);
        self.samples
            .push(*last)
            .map_err(|_| Error::CapacityExceeded)?;
        let (bg0, ba0) = (self.bg0, self.ba0);
        self.reintegrate(bg0, ba0)
    }

    /// Re-integrates with `bg`, `ba` when [`Self::needs_reintegration`]; returns whether it did.
    pub fn update_linearization(&mut self, bg: &Vec3, ba: &Vec3) -> Result<bool, Error> {
        if self.needs_reintegration(bg, ba) {
            self.reintegrate(*bg, *ba)?;
            Ok(true)
        } else {
            Ok(false)
        }
    }

    /// Noise densities the covariance was propagated with.
    pub fn noise(&self) -> &ImuNoise {
        &self.noise
    }

    /// Time of keyframe `i`, ns.
    pub fn t_start_ns(&self) -> i64 {
        self.t0_ns
    }
    /// Time of the last sample (keyframe `j`), ns.
    pub fn t_end_ns(&self) -> i64 {
        self.samples.last().map_or(self.t0_ns, |s| s.t_ns)
    }
    /// Integrated time, s.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }
    /// Number of stored samples (including the start sample).
    pub fn len(&self) -> usize {
        self.samples.len()
    }
    /// True when only the start sample is stored (nothing integrated yet).
    pub fn is_empty(&self) -> bool {
        self.samples.len() < 2
    }
    /// Linearization biases `(bg0, ba0)`.
    pub fn linearization_bias(&self) -> (Vec3, Vec3) {
        (self.bg0, self.ba0)
    }
    /// Position delta at the linearization biases, m (in `b_i`).
    pub fn delta_p(&self) -> &Vec3 {
        &self.dp
    }
    /// Velocity delta at the linearization biases, m/s (in `b_i`).
    pub fn delta_v(&self) -> &Vec3 {
        &self.dv
    }
    /// Rotation delta `q_{b_i b_j}` at the linearization biases.
    pub fn delta_q(&self) -> &Quat {
        &self.dq
    }
    /// Covariance of `[dp, dv, dtheta, dbg, dba]`.
    pub fn covariance(&self) -> &Mat15 {
        &self.cov
    }
    /// Bias Jacobians `(dp/dbg, dp/dba, dv/dbg, dv/dba, dtheta/dbg)`.
    pub fn bias_jacobians(&self) -> (&Mat3, &Mat3, &Mat3, &Mat3, &Mat3) {
        (
            &self.j_p_bg,
            &self.j_p_ba,
            &self.j_v_bg,
            &self.j_v_ba,
            &self.j_r_bg,
        )
    }

    /// First-order bias-corrected deltas `(dp, dv, dq)` for biases `bg`, `ba`.
    pub fn corrected(&self, bg: &Vec3, ba: &Vec3) -> (Vec3, Vec3, Quat) {
        let (dbg, dba) = (bg - self.bg0, ba - self.ba0);
        (
            self.dp + self.j_p_bg * dbg + self.j_p_ba * dba,
            self.dv + self.j_v_bg * dbg + self.j_v_ba * dba,
            self.dq * quat_exp(&(self.j_r_bg * dbg)),
        )
    }

    /// Unwhitened residual and its Jacobians w.r.t. the error states of `xi` and `xj`.
    /// `gravity_mps2` is the magnitude (gravity along `-z` of the world).
    pub fn evaluate_raw(
        &self,
        xi: &NavState,
        xj: &NavState,
        gravity_mps2: f64,
        r: &mut Vec15,
        j_i: &mut Mat15,
        j_j: &mut Mat15,
    ) -> Result<(), Error> {
        if self.is_empty() {
            return Err(Error::NotEnoughData);
        }
        let t = self.dt_s;
        let g_w = Vec3::new(0.0, 0.0, -gravity_mps2);
        let ri = xi.q_wb.to_rotation_matrix().into_inner();
        let rj = xj.q_wb.to_rotation_matrix().into_inner();
        let rit = ri.transpose();
        let dbg = xi.bg - self.bg0;
        let (dp_c, dv_c, dq_c) = self.corrected(&xi.bg, &xi.ba);

        let pw = xj.p_wb - xi.p_wb - xi.v_wb * t - g_w * (0.5 * t * t);
        let vw = xj.v_wb - xi.v_wb - g_w * t;
        let pb = rit * pw;
        let vb = rit * vw;
        let r_th = log_so3(&(dq_c.inverse() * xi.q_wb.inverse() * xj.q_wb));
        let rho = self.bias_decay;

        r.fixed_rows_mut::<3>(RP).copy_from(&(pb - dp_c));
        r.fixed_rows_mut::<3>(RV).copy_from(&(vb - dv_c));
        r.fixed_rows_mut::<3>(RT).copy_from(&r_th);
        r.fixed_rows_mut::<3>(RBG).copy_from(&(xj.bg - xi.bg * rho));
        r.fixed_rows_mut::<3>(RBA).copy_from(&(xj.ba - xi.ba * rho));

        let jr_inv = jr_inv_so3(&r_th);
        let eye = Mat3::identity();
        j_i.fill(0.0);
        j_j.fill(0.0);
        // Position row.
        j_i.fixed_view_mut::<3, 3>(RP, XP).copy_from(&(-rit));
        j_i.fixed_view_mut::<3, 3>(RP, XT).copy_from(&skew(&pb));
        j_i.fixed_view_mut::<3, 3>(RP, XV).copy_from(&(-rit * t));
        j_i.fixed_view_mut::<3, 3>(RP, XBG)
            .copy_from(&(-self.j_p_bg));
        j_i.fixed_view_mut::<3, 3>(RP, XBA)
            .copy_from(&(-self.j_p_ba));
        j_j.fixed_view_mut::<3, 3>(RP, XP).copy_from(&rit);
        // Velocity row.
        j_i.fixed_view_mut::<3, 3>(RV, XT).copy_from(&skew(&vb));
        j_i.fixed_view_mut::<3, 3>(RV, XV).copy_from(&(-rit));
        j_i.fixed_view_mut::<3, 3>(RV, XBG)
            .copy_from(&(-self.j_v_bg));
        j_i.fixed_view_mut::<3, 3>(RV, XBA)
            .copy_from(&(-self.j_v_ba));
        j_j.fixed_view_mut::<3, 3>(RV, XV).copy_from(&rit);
        // Rotation row.
        let rjt_ri = rj.transpose() * ri;
        j_i.fixed_view_mut::<3, 3>(RT, XT)
            .copy_from(&(-jr_inv * rjt_ri));
        let exp_r_t = exp_so3(&r_th).transpose();
        let jb = jr_so3(&(self.j_r_bg * dbg)) * self.j_r_bg;
        j_i.fixed_view_mut::<3, 3>(RT, XBG)
            .copy_from(&(-jr_inv * exp_r_t * jb));
        j_j.fixed_view_mut::<3, 3>(RT, XT).copy_from(&jr_inv);
        // Bias rows.
        j_i.fixed_view_mut::<3, 3>(RBG, XBG)
            .copy_from(&(-eye * rho));
        j_i.fixed_view_mut::<3, 3>(RBA, XBA)
            .copy_from(&(-eye * rho));
        j_j.fixed_view_mut::<3, 3>(RBG, XBG).copy_from(&eye);
        j_j.fixed_view_mut::<3, 3>(RBA, XBA).copy_from(&eye);
        Ok(())
    }

    /// Whitened residual and Jacobians: `L^-1 r`, `L^-1 J` with `P = L L^T` (Cholesky of the
    /// covariance), so `|r_w|^2` is the Mahalanobis norm. [`Error::NotPositiveDefinite`] if `P`
    /// is not (e.g. zero noise densities).
    pub fn evaluate(
        &self,
        xi: &NavState,
        xj: &NavState,
        gravity_mps2: f64,
        r: &mut Vec15,
        j_i: &mut Mat15,
        j_j: &mut Mat15,
    ) -> Result<(), Error> {
        self.evaluate_raw(xi, xj, gravity_mps2, r, j_i, j_j)?;
        self.whiten(r, j_i, j_j)
    }

    /// Whitened residual only (`L^-1 r`), for cost evaluations: the Jacobians are formed by the
    /// shared code path but never whitened, which is where the cost of [`Self::evaluate`] lies.
    pub fn residual_whitened(
        &self,
        xi: &NavState,
        xj: &NavState,
        gravity_mps2: f64,
    ) -> Result<Vec15, Error> {
        let (mut r, mut j_i, mut j_j) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        self.evaluate_raw(xi, xj, gravity_mps2, &mut r, &mut j_i, &mut j_j)?;
        self.solve_with_factor(|l| l.solve_lower_triangular_mut(&mut r))?;
        if !r.iter().all(|x| x.is_finite()) {
            return Err(Error::NonFinite);
        }
        Ok(r)
    }

    /// Runs `solve` with the Cholesky factor (the cached one, else computed now);
    /// [`Error::NotPositiveDefinite`] when there is none or `solve` reports a singular factor.
    fn solve_with_factor(&self, solve: impl FnOnce(&Mat15) -> bool) -> Result<(), Error> {
        let ok = match &self.chol_l {
            Some(l) => solve(l),
            None => solve(&self.cholesky()?),
        };
        if ok {
            Ok(())
        } else {
            Err(Error::NotPositiveDefinite)
        }
    }

    /// Cholesky factor `L` of the covariance (`P = L L^T`), checked to be usable.
    fn cholesky(&self) -> Result<Mat15, Error> {
        let chol = nalgebra::Cholesky::new(self.cov).ok_or(Error::NotPositiveDefinite)?;
        let l = chol.l_dirty().clone_owned();
        // Reject a factor whose diagonal underflowed: the solves would divide by ~0.
        if !(0..15).all(|i| l[(i, i)] > 1e-150) {
            return Err(Error::NotPositiveDefinite);
        }
        Ok(l)
    }

    /// Computes and keeps the Cholesky factor of the current covariance, so that later
    /// [`Preintegration::whiten`] calls skip the factorization (until the next sample or
    /// re-integration). Results are bit-identical either way.
    pub fn cache_whitening(&mut self) -> Result<(), Error> {
        self.chol_l = Some(self.cholesky()?);
        Ok(())
    }

    /// Applies `L^-1` (Cholesky factor of the covariance) to a residual and two Jacobians.
    pub fn whiten(&self, r: &mut Vec15, j_i: &mut Mat15, j_j: &mut Mat15) -> Result<(), Error> {
        self.solve_with_factor(|l| {
            l.solve_lower_triangular_mut(r)
                && l.solve_lower_triangular_mut(j_i)
                && l.solve_lower_triangular_mut(j_j)
        })?;
        if !r.iter().all(|x| x.is_finite()) {
            return Err(Error::NonFinite);
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "preintegration_tests.rs"]
mod tests;

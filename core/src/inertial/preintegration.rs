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
mod tests {
    use super::*;
    use crate::inertial::ins::{Ins, InsConfig};

    const G: f64 = 9.81;
    const NOISE: ImuNoise = ImuNoise::EUROC_ADIS16448;

    /// Smooth, non-trivial motion: every gyro and accel axis varies.
    fn sample(k: i64) -> ImuSample {
        let t = k as f64 * 0.005;
        ImuSample {
            t_ns: 1_000_000_000 + k * 5_000_000,
            gyro_rps: Vec3::new(
                0.5 * libm::sin(1.3 * t),
                0.3 * libm::cos(0.7 * t),
                0.8 * libm::sin(0.5 * t + 1.0),
            ),
            accel_mps2: Vec3::new(
                1.0 + libm::sin(t),
                0.5 * libm::cos(2.0 * t),
                G + 0.3 * libm::sin(3.0 * t),
            ),
        }
    }

    fn build(n: i64, bg0: Vec3, ba0: Vec3, noise: ImuNoise) -> Preintegration<256> {
        let mut p =
            Preintegration::<256>::new(noise, PreintConfig::DEFAULT, &sample(0), bg0, ba0).unwrap();
        for k in 1..=n {
            p.push(&sample(k)).unwrap();
        }
        p
    }

    /// A span over samples `k0..=k1` of [`sample`] with standard deviations `sa`, `sg` over
    /// the whole span (rates `sigma^2 T`).
    fn span(k0: i64, k1: i64, sa: f64, sg: f64) -> UnmeasuredSpan {
        let (t0_ns, t1_ns) = (sample(k0).t_ns, sample(k1).t_ns);
        let t = (t1_ns - t0_ns) as f64 * 1e-9;
        UnmeasuredSpan {
            t0_ns,
            t1_ns,
            accel_var_per_s: sa * sa * t,
            gyro_var_per_s: sg * sg * t,
        }
    }

    /// A span over the whole interval adds `sigma^2 T^2` per axis to the velocity and the
    /// rotation variances (trace `3 sigma^2 T^2`: the rotations of the steps keep the trace; the
    /// rotation block within 2%, `Jr` and `Exp(phi)^T` being near identity per step); declared
    /// after the samples or before them gives the same covariance bit for bit, and so does a
    /// re-integration or a truncation that keeps the span's samples.
    #[test]
    fn unmeasured_span_adds_its_variance_and_survives_reintegration() {
        let (n, sa, sg) = (40, 1.0, 0.3);
        let z = Vec3::zeros();
        let plain = build(n, z, z, NOISE);
        let t = (sample(n).t_ns - sample(0).t_ns) as f64 * 1e-9;
        let mut after = build(n, z, z, NOISE);
        after.add_unmeasured(span(0, n, sa, sg)).unwrap();
        let mut before =
            Preintegration::<256>::new(NOISE, PreintConfig::DEFAULT, &sample(0), z, z).unwrap();
        before.add_unmeasured(span(0, n, sa, sg)).unwrap();
        for k in 1..=n {
            before.push(&sample(k)).unwrap();
        }
        assert_eq!(after.covariance(), before.covariance());
        assert_eq!(after.delta_v(), plain.delta_v(), "deltas unchanged");
        let tr = |p: &Preintegration<256>, r: usize| {
            (r..r + 3).map(|i| p.covariance()[(i, i)]).sum::<f64>()
        };
        // One kind at a time (an attitude error also spreads into the velocity, through g).
        let mut accel_only = build(n, z, z, NOISE);
        accel_only.add_unmeasured(span(0, n, sa, 0.0)).unwrap();
        let dv = tr(&accel_only, RV) - tr(&plain, RV);
        let expect_v = 3.0 * sa * sa * t * t;
        assert!((dv - expect_v).abs() < 1e-9, "{dv} vs {expect_v}");
        assert_eq!(tr(&accel_only, RT), tr(&plain, RT));
        let mut gyro_only = build(n, z, z, NOISE);
        gyro_only.add_unmeasured(span(0, n, 0.0, sg)).unwrap();
        let dth = tr(&gyro_only, RT) - tr(&plain, RT);
        let expect_th = 3.0 * sg * sg * t * t;
        assert!((dth / expect_th - 1.0).abs() < 0.02, "{dth} vs {expect_th}");
        assert!(tr(&after, RV) > tr(&accel_only, RV));
        assert!(after.unmeasured_velocity_var() > 0.0);
        assert_eq!(plain.unmeasured_velocity_var(), 0.0);

        // Re-integration at other biases equals a fresh build at those biases with the span.
        let (bg, ba) = (Vec3::new(0.01, -0.02, 0.005), Vec3::new(0.1, 0.0, -0.1));
        after.reintegrate(bg, ba).unwrap();
        let mut fresh =
            Preintegration::<256>::new(NOISE, PreintConfig::DEFAULT, &sample(0), bg, ba).unwrap();
        fresh.add_unmeasured(span(0, n, sa, sg)).unwrap();
        for k in 1..=n {
            fresh.push(&sample(k)).unwrap();
        }
        assert_eq!(after.covariance(), fresh.covariance());

        // A span covering part of the interval adds in proportion to its overlap; outside the
        // interval, nothing.
        let mut half = build(n, z, z, NOISE);
        half.add_unmeasured(span(n / 2, n + 100, sa, 0.0)).unwrap();
        let full_span_rate = span(n / 2, n + 100, sa, 0.0).accel_var_per_s;
        let overlap = (sample(n).t_ns - sample(n / 2).t_ns) as f64 * 1e-9;
        let dv = tr(&half, RV) - tr(&plain, RV);
        assert!((dv - 3.0 * full_span_rate * overlap).abs() < 1e-9, "{dv}");
        let mut outside = build(n, z, z, NOISE);
        outside
            .add_unmeasured(span(n + 10, n + 20, sa, sg))
            .unwrap();
        assert_eq!(outside.covariance(), plain.covariance());
    }

    /// Bad spans are refused and change nothing; more than [`MAX_UNMEASURED`] do not fit; a
    /// restart forgets the spans.
    #[test]
    fn unmeasured_spans_are_checked_bounded_and_cleared() {
        let z = Vec3::zeros();
        let mut p = build(10, z, z, NOISE);
        let cov = *p.covariance();
        let mut bad = span(0, 10, 1.0, 0.3);
        bad.accel_var_per_s = f64::NAN;
        assert_eq!(p.add_unmeasured(bad), Err(Error::InvalidConfig));
        let mut empty = span(0, 10, 1.0, 0.3);
        empty.t1_ns = empty.t0_ns;
        assert_eq!(p.add_unmeasured(empty), Err(Error::InvalidConfig));
        assert_eq!(*p.covariance(), cov);
        for k in 0..MAX_UNMEASURED as i64 {
            p.add_unmeasured(span(k, k + 1, 1.0, 0.3)).unwrap();
        }
        let full = *p.covariance();
        assert_eq!(
            p.add_unmeasured(span(5, 6, 1.0, 0.3)),
            Err(Error::CapacityExceeded)
        );
        assert_eq!(*p.covariance(), full);
        p.reset(&sample(10), z, z).unwrap();
        assert!(p.unmeasured().is_empty());
    }

    fn states() -> (NavState, NavState) {
        let xi = NavState {
            t_ns: 0,
            p_wb: Vec3::new(1.0, -2.0, 0.5),
            q_wb: quat_exp(&Vec3::new(0.3, -0.2, 1.0)),
            v_wb: Vec3::new(0.5, 0.2, -0.1),
            bg: Vec3::new(0.004, -0.003, 0.002),
            ba: Vec3::new(0.05, -0.04, 0.03),
        };
        let xj = NavState {
            t_ns: 0,
            p_wb: Vec3::new(1.3, -1.9, 0.45),
            q_wb: quat_exp(&Vec3::new(0.35, -0.1, 1.2)),
            v_wb: Vec3::new(0.6, 0.1, 0.0),
            bg: Vec3::new(0.0045, -0.0028, 0.0021),
            ba: Vec3::new(0.052, -0.041, 0.028),
        };
        (xi, xj)
    }

    #[test]
    fn cached_whitening_is_bit_identical_and_invalidated_by_new_samples() {
        let mut p = build(50, Vec3::zeros(), Vec3::zeros(), NOISE);
        let (xi, xj) = states();
        let eval = |p: &Preintegration<256>| {
            let (mut r, mut a, mut b) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
            p.evaluate(&xi, &xj, 9.81, &mut r, &mut a, &mut b).unwrap();
            (r, a, b)
        };
        let plain = eval(&p);
        p.cache_whitening().unwrap();
        assert_eq!(eval(&p), plain);
        // A new sample changes the covariance: the cache must not be used any more.
        p.push(&sample(51)).unwrap();
        let after_push = eval(&p);
        let mut q = p.clone();
        q.cache_whitening().unwrap();
        assert_eq!(eval(&q), after_push);
        assert_ne!(after_push.0, plain.0);
    }

    #[test]
    fn bias_jacobians_match_reintegration() {
        let (bg0, ba0) = (Vec3::new(0.01, -0.02, 0.005), Vec3::new(0.1, -0.05, 0.2));
        let p = build(120, bg0, ba0, NOISE);
        let (jpg, jpa, jvg, jva, jrg) = p.bias_jacobians();
        let h = 1e-6;
        let mut q = p.clone();
        for c in 0..3 {
            let mut e = Vec3::zeros();
            e[c] = h;
            let mut diff = |dbg: Vec3, dba: Vec3| {
                q.reintegrate(bg0 + dbg, ba0 + dba).unwrap();
                let (pp, vp, rp) = (q.dp, q.dv, log_so3(&(p.dq.inverse() * q.dq)));
                q.reintegrate(bg0 - dbg, ba0 - dba).unwrap();
                let (pm, vm, rm) = (q.dp, q.dv, log_so3(&(p.dq.inverse() * q.dq)));
                (
                    (pp - pm) / (2.0 * h),
                    (vp - vm) / (2.0 * h),
                    (rp - rm) / (2.0 * h),
                )
            };
            let (np, nv, nr) = diff(e, Vec3::zeros());
            assert!((np - jpg.column(c)).norm() < 1e-7, "dp/dbg col {c}");
            assert!((nv - jvg.column(c)).norm() < 1e-7, "dv/dbg col {c}");
            assert!((nr - jrg.column(c)).norm() < 1e-7, "dR/dbg col {c}");
            let (np, nv, nr) = diff(Vec3::zeros(), e);
            assert!((np - jpa.column(c)).norm() < 1e-7, "dp/dba col {c}");
            assert!((nv - jva.column(c)).norm() < 1e-7, "dv/dba col {c}");
            assert!(nr.norm() < 1e-9, "dR/dba col {c}");
        }
        // The rotation Jacobian is about -T I for small rotations: a gross sanity bound.
        assert!(jrg.trace() < -1.2 && jrg.trace() > -1.8, "{jrg:?}");
    }

    /// An INS run from `xi` with the same samples and biases lands exactly where the
    /// preintegration predicts: the residual vanishes to rounding.
    #[test]
    fn residual_vanishes_on_ins_propagation() {
        let (mut xi, _) = states();
        xi.t_ns = sample(0).t_ns;
        let p = build(160, xi.bg, xi.ba, NOISE);
        let mut ins = Ins::new(
            InsConfig {
                gravity_mps2: G,
                max_dt_s: 0.05,
            },
            xi,
        )
        .unwrap();
        for k in 0..=160 {
            ins.propagate(&sample(k)).unwrap();
        }
        let xj = *ins.state();
        let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        p.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj)
            .unwrap();
        assert!(r.norm() < 1e-12, "residual {r:?}");
        // The motion is real: the body moved and turned.
        assert!((xj.p_wb - xi.p_wb).norm() > 0.3);
        assert!(log_so3(p.delta_q()).norm() > 0.1);
    }

    #[test]
    fn whitening_gives_mahalanobis_norm() {
        let p = build(100, Vec3::zeros(), Vec3::zeros(), NOISE);
        let (xi, xj) = states();
        let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        p.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj)
            .unwrap();
        let (r0, ji0) = (r, ji);
        p.evaluate(&xi, &xj, G, &mut r, &mut ji, &mut jj).unwrap();
        let pinv = p.covariance().try_inverse().unwrap();
        let maha = (r0.transpose() * pinv * r0)[(0, 0)];
        assert!((r.norm_squared() - maha).abs() < 1e-8 * maha);
        let info = ji0.transpose() * pinv * ji0;
        let info_w = ji.transpose() * ji;
        assert!((info - info_w).norm() < 1e-7 * info.norm());
        // The cost-only path whitens the residual identically.
        assert_eq!(p.residual_whitened(&xi, &xj, G).unwrap(), r);
        // Covariance sanity: symmetric, velocity variance ~ sa^2 T.
        assert_eq!(*p.covariance(), p.covariance().transpose());
        let var_v = p.covariance()[(RV, RV)];
        let expect = NOISE.accel_noise_density * NOISE.accel_noise_density * 0.5;
        assert!(
            var_v > 0.9 * expect && var_v < 1.5 * expect,
            "{var_v} vs {expect}"
        );
    }

    #[test]
    fn zero_noise_is_not_positive_definite() {
        let zero = ImuNoise {
            gyro_noise_density: 0.0,
            accel_noise_density: 0.0,
            gyro_bias_rw: 0.0,
            accel_bias_rw: 0.0,
            bias_corr_time_s: None,
        };
        let p = build(10, Vec3::zeros(), Vec3::zeros(), zero);
        let (xi, xj) = states();
        let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        assert_eq!(
            p.evaluate(&xi, &xj, G, &mut r, &mut ji, &mut jj),
            Err(Error::NotPositiveDefinite)
        );
        // Nothing integrated yet: no measurement.
        let p0 = build(0, Vec3::zeros(), Vec3::zeros(), NOISE);
        assert_eq!(
            p0.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj),
            Err(Error::NotEnoughData)
        );
    }

    #[test]
    fn capacity_exceeded_leaves_preintegration_intact() {
        let mut p = Preintegration::<8>::new(
            NOISE,
            PreintConfig::DEFAULT,
            &sample(0),
            Vec3::zeros(),
            Vec3::zeros(),
        )
        .unwrap();
        for k in 1..8 {
            p.push(&sample(k)).unwrap();
        }
        let (dp, cov, t_end) = (*p.delta_p(), *p.covariance(), p.t_end_ns());
        assert_eq!(p.push(&sample(8)), Err(Error::CapacityExceeded));
        assert_eq!(
            (*p.delta_p(), *p.covariance(), p.t_end_ns()),
            (dp, cov, t_end)
        );
        assert_eq!(p.len(), 8);
        // Re-integration of the full buffer reproduces the deltas bit for bit.
        p.reintegrate(Vec3::zeros(), Vec3::zeros()).unwrap();
        assert_eq!(*p.delta_p(), dp);
        assert_eq!(*p.covariance(), cov);
        // The caller starts the next keyframe at the last sample and continues.
        p.reset(&sample(7), Vec3::zeros(), Vec3::zeros()).unwrap();
        p.push(&sample(8)).unwrap();
        assert_eq!(p.t_start_ns(), sample(7).t_ns);
    }

    #[test]
    fn rejects_bad_samples_and_reintegrates_past_threshold() {
        let mut p = build(20, Vec3::zeros(), Vec3::zeros(), NOISE);
        let (dp, cov) = (*p.delta_p(), *p.covariance());
        let mut bad = sample(21);
        bad.accel_mps2.y = f64::NAN;
        assert_eq!(p.push(&bad), Err(Error::NonFinite));
        assert_eq!(p.push(&sample(20)), Err(Error::TimeNotIncreasing));
        assert_eq!(p.push(&sample(40)), Err(Error::TimeGap));
        assert_eq!((*p.delta_p(), *p.covariance()), (dp, cov));

        let small = Vec3::new(5e-4, 0.0, 0.0);
        assert!(!p.update_linearization(&small, &Vec3::zeros()).unwrap());
        assert_eq!(p.linearization_bias().0, Vec3::zeros());
        let big = Vec3::new(2e-3, 0.0, 0.0);
        // Before re-integration the first-order correction predicts the new deltas closely.
        let (dp_c, _, _) = p.corrected(&big, &Vec3::zeros());
        assert!(p.update_linearization(&big, &Vec3::zeros()).unwrap());
        assert_eq!(p.linearization_bias().0, big);
        assert!((*p.delta_p() - dp_c).norm() < 1e-9);
        assert!((*p.delta_p() - dp).norm() > 1e-8);
    }
}

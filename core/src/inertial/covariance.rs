//! The error-state covariance step shared by the preintegration and the INS, and the INS's
//! covariance ([`InsCovariance`]).
//!
//! One IMU step (two-sample increment `phi`, `dv'` resolved in the body at the step's start,
//! rotation `R` of that body: `dR` of the interval for the preintegration, `R_wb` for the INS)
//! moves the 15-dim error `[dp, dv, dth, dbg, dba]` (true = estimate + error for `p`, `v` and the
//! biases, `R_true = R Exp(dth)`) by
//!
//! ```text
//! dth' = Exp(phi)^T dth + Jr(phi) (Phi_bg dbg + n_th)
//! dv'  = dv - R [dv']x dth + R (V_bg dbg + V_ba dba + n_v)
//! dp'  = dp + dt dv + dt/2 (-R [dv']x dth + R (V_bg dbg + V_ba dba + n_v))
//! db'  = rho db + n_b
//! ```
//!
//! (see [`super::preintegration`] for the noise model). The INS's update `v' = v + R dv' + g dt`,
//! `p' = p + (v + v') dt / 2`, `R' = R Exp(phi)` has exactly this error recursion in the world
//! frame (gravity adds no error), so the same code propagates both; `tests::ins_transition_matches_numerical`
//! checks it against central differences of [`super::Ins::propagate`].

use super::imu::ImuNoise;
use super::increment::{Step, StepBiasJacobians};
use crate::math::{exp_so3, jr_so3, skew, Mat3};
use crate::Error;

/// 15x15 matrix (covariance, Jacobians).
pub type Mat15 = nalgebra::SMatrix<f64, 15, 15>;
/// 15-vector (residual).
pub type Vec15 = nalgebra::SVector<f64, 15>;

/// Error block offsets (`[dp, dv, dtheta, dbg, dba]`), the preintegration's residual order.
pub(crate) const RP: usize = 0;
pub(crate) const RV: usize = 3;
pub(crate) const RT: usize = 6;
pub(crate) const RBG: usize = 9;
pub(crate) const RBA: usize = 12;

/// What one step needs besides the covariance: the rotation at its start and the terms of the
/// transition built from it.
pub(crate) struct StepTerms {
    /// Rotation at the start of the step.
    pub r: Mat3,
    /// `Exp(phi)^T`.
    pub exp_t: Mat3,
    /// `Jr(phi)`.
    pub jr: Mat3,
    /// `R [dv']x`.
    pub r_dvx: Mat3,
}

impl StepTerms {
    pub(crate) fn new(r: Mat3, step: &Step) -> Self {
        StepTerms {
            exp_t: exp_so3(&step.phi).transpose(),
            jr: jr_so3(&step.phi),
            r_dvx: r * skew(&step.dv),
            r,
        }
    }
}

/// Variances one step adds: white noise of the angle and velocity increments (`qg`, `qa`, gap
/// terms included) and of the biases (`q_bg`, `q_ba`).
pub(crate) struct StepNoise {
    pub qg: f64,
    pub qa: f64,
    pub q_bg: f64,
    pub q_ba: f64,
}

/// Per-step bias decay and discrete bias-noise variances `(rho, q_bg, q_ba)` of `noise` over
/// `dt` seconds.
pub(crate) fn bias_step(noise: &ImuNoise, dt: f64) -> (f64, f64, f64) {
    let (sg, sa) = (noise.gyro_bias_rw, noise.accel_bias_rw);
    match noise.bias_corr_time_s {
        None => (1.0, sg * sg * dt, sa * sa * dt),
        Some(tau) => {
            let rho = libm::exp(-dt / tau);
            let k = 0.5 * tau * (1.0 - rho * rho);
            (rho, sg * sg * k, sa * sa * k)
        }
    }
}

/// The step's error-state transition `A` (module docs) into `a`.
pub(crate) fn transition(a: &mut Mat15, t: &StepTerms, jb: &StepBiasJacobians, dt: f64, rho: f64) {
    let half_dt = 0.5 * dt;
    let r = &t.r;
    a.fill_with_identity();
    a.fixed_view_mut::<3, 3>(RP, RV).fill_diagonal(dt);
    a.fixed_view_mut::<3, 3>(RP, RT)
        .copy_from(&(-t.r_dvx * half_dt));
    a.fixed_view_mut::<3, 3>(RP, RBG)
        .copy_from(&(r * jb.dv_bg * half_dt));
    a.fixed_view_mut::<3, 3>(RP, RBA)
        .copy_from(&(r * jb.dv_ba * half_dt));
    a.fixed_view_mut::<3, 3>(RV, RT).copy_from(&(-t.r_dvx));
    a.fixed_view_mut::<3, 3>(RV, RBG).copy_from(&(r * jb.dv_bg));
    a.fixed_view_mut::<3, 3>(RV, RBA).copy_from(&(r * jb.dv_ba));
    a.fixed_view_mut::<3, 3>(RT, RT).copy_from(&t.exp_t);
    a.fixed_view_mut::<3, 3>(RT, RBG)
        .copy_from(&(t.jr * jb.phi_bg));
    a.fixed_view_mut::<3, 3>(RBG, RBG).fill_diagonal(rho);
    a.fixed_view_mut::<3, 3>(RBA, RBA).fill_diagonal(rho);
}

/// `P <- A P A^T + G Q G^T` (through `tmp`), then `P` made exactly symmetric.
pub(crate) fn propagate(
    cov: &mut Mat15,
    a: &Mat15,
    tmp: &mut Mat15,
    jr: &Mat3,
    q: &StepNoise,
    dt: f64,
) {
    let half_dt = 0.5 * dt;
    // P symmetric: A P A^T = A (A P)^T.
    tmp.gemm(1.0, a, cov, 0.0);
    tmp.transpose_mut();
    cov.gemm(1.0, a, tmp, 0.0);
    let (qa, qg) = (q.qa, q.qg);
    let jjt = jr * jr.transpose() * qg;
    for i in 0..3 {
        cov[(RP + i, RP + i)] += qa * half_dt * half_dt;
        cov[(RP + i, RV + i)] += qa * half_dt;
        cov[(RV + i, RP + i)] += qa * half_dt;
        cov[(RV + i, RV + i)] += qa;
        cov[(RBG + i, RBG + i)] += q.q_bg;
        cov[(RBA + i, RBA + i)] += q.q_ba;
        for k in 0..3 {
            cov[(RT + i, RT + k)] += jjt[(i, k)];
        }
    }
    // Exactly symmetric, so results do not depend on which triangle is read.
    for i in 0..15 {
        for k in (i + 1)..15 {
            let m = 0.5 * (cov[(i, k)] + cov[(k, i)]);
            cov[(i, k)] = m;
            cov[(k, i)] = m;
        }
    }
}

/// From the keyframe error-state order `[p, theta, v, bg, ba]` (the estimator's columns) to the
/// step's order `[dp, dv, dtheta, dbg, dba]`: `STEP_OF_STATE[block]` is the step block of the
/// state block.
const STEP_OF_STATE: [usize; 5] = [RP, RT, RV, RBG, RBA];

fn reorder(m: &Mat15, to_step: bool) -> Mat15 {
    let mut out = Mat15::zeros();
    for (bi, &si) in STEP_OF_STATE.iter().enumerate() {
        for (bj, &sj) in STEP_OF_STATE.iter().enumerate() {
            let (src, dst) = if to_step {
                ((3 * bi, 3 * bj), (si, sj))
            } else {
                ((si, sj), (3 * bi, 3 * bj))
            };
            out.fixed_view_mut::<3, 3>(dst.0, dst.1)
                .copy_from(&m.fixed_view::<3, 3>(src.0, src.1));
        }
    }
    out
}

/// The covariance of an [`super::Ins`]'s error state, propagated with every sample it takes.
///
/// Frames: the error of [`super::NavState`] as the estimator perturbs it: `p_wb + dp`,
/// `v_wb + dv` in the world `w` (z up), `R_wb Exp(dtheta)` (a rotation error in the body `b`),
/// `bg + dbg`, `ba + dba`. Units: m^2, rad^2, (m/s)^2, (rad/s)^2, (m/s^2)^2 and their products.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsCovariance {
    /// In the step order `[dp, dv, dtheta, dbg, dba]`.
    p: Mat15,
    noise: ImuNoise,
}

impl InsCovariance {
    /// All zero bits (noise zero): the storage of [`MaybeCovariance`] when unset.
    const BLANK: Self = InsCovariance {
        p: Mat15::from_array_storage(nalgebra::ArrayStorage([[0.0; 15]; 15])),
        noise: ImuNoise {
            gyro_noise_density: 0.0,
            accel_noise_density: 0.0,
            gyro_bias_rw: 0.0,
            accel_bias_rw: 0.0,
            bias_corr_time_s: None,
        },
    };

    /// `p` in the keyframe error-state order `[p, theta, v, bg, ba]`; `noise` the densities the
    /// INS's samples are propagated with. [`Error::NonFinite`] for a non-finite entry,
    /// [`Error::InvalidConfig`] for invalid noise or a negative variance.
    pub fn new(p: &Mat15, noise: ImuNoise) -> Result<Self, Error> {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        if !noise.is_valid() || (0..15).any(|i| p[(i, i)] < 0.0) {
            return Err(Error::InvalidConfig);
        }
        let mut s = reorder(p, true);
        for i in 0..15 {
            for k in (i + 1)..15 {
                let m = 0.5 * (s[(i, k)] + s[(k, i)]);
                s[(i, k)] = m;
                s[(k, i)] = m;
            }
        }
        Ok(InsCovariance { p: s, noise })
    }

    /// The covariance in the keyframe error-state order `[p, theta, v, bg, ba]`.
    pub fn state_order(&self) -> Mat15 {
        reorder(&self.p, false)
    }

    /// The noise densities of the propagation.
    pub fn noise(&self) -> &ImuNoise {
        &self.noise
    }

    /// One INS step from the body rotation `r_wb` at its start (module docs).
    pub(crate) fn step(&mut self, r_wb: Mat3, step: &Step, jb: &StepBiasJacobians, dt: f64) {
        let terms = StepTerms::new(r_wb, step);
        let (rho, q_bg, q_ba) = bias_step(&self.noise, dt);
        let (sg, sa) = (
            self.noise.gyro_noise_density,
            self.noise.accel_noise_density,
        );
        let q = StepNoise {
            qg: sg * sg * dt,
            qa: sa * sa * dt,
            q_bg,
            q_ba,
        };
        let (mut a, mut tmp) = (Mat15::zeros(), Mat15::zeros());
        transition(&mut a, &terms, jb, dt, rho);
        propagate(&mut self.p, &a, &mut tmp, &terms.jr, &q, dt);
    }
}

/// An optional [`InsCovariance`] whose unset value is all zero bits (an `Option` of it is not:
/// its `None` takes a niche in the noise's `Option<f64>`), so a `const` estimator stays in
/// `.bss`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct MaybeCovariance {
    cov: InsCovariance,
    set: bool,
}

impl MaybeCovariance {
    pub(crate) const NONE: Self = MaybeCovariance {
        cov: InsCovariance::BLANK,
        set: false,
    };

    pub(crate) fn new(c: Option<InsCovariance>) -> Self {
        match c {
            Some(cov) => MaybeCovariance { cov, set: true },
            None => Self::NONE,
        }
    }

    pub(crate) fn get(&self) -> Option<&InsCovariance> {
        self.set.then_some(&self.cov)
    }

    pub(crate) fn get_mut(&mut self) -> Option<&mut InsCovariance> {
        if self.set {
            Some(&mut self.cov)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests;

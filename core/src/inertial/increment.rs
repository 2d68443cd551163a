//! Two-sample (Savage) attitude and velocity increments, shared by the INS and the
//! preintegration so both integrate the IMU identically.
//!
//! The IMU delivers rate samples `w_k`, `f_k`, so the increments over `[t_{k-1}, t_k]` (length
//! `h2`, previous spacing `h1`) are integrals of the quadratic through the samples at
//! `t_{k-2}, t_{k-1}, t_k`:
//!
//! ```text
//! dth_k = c0 w_{k-2} + c1 w_{k-1} + c2 w_k - bg h2       (likewise dv_k with f and ba)
//! c0 = -h2^3 / (6 h1 (h1 + h2)),  c1 = h2 (h2 + 3 h1) / (6 h1),  c2 = h2 (2 h2 + 3 h1) / (6 (h1 + h2))
//! ```
//!
//! (`(-1, 8, 5) h/12` for uniform spacing). A trapezoid would leave an `O(h^2)` relative error in
//! the increments that is as large as the coning correction itself (it rescales oscillating
//! rates), so the two-sample scheme would gain only a factor two; with the quadratic the gain is
//! about 100x in the coning test. The very first interval (no `t_{k-2}` sample) uses the
//! trapezoid. With the previous interval's increments
//! (`dth_{k-1}`, `dv_{k-1}`) the two-sample scheme is
//!
//! ```text
//! phi_k = dth_k + 1/12 dth_{k-1} x dth_k                         (coning)
//! dv'_k = dv_k + 1/2 dth_k x dv_k                                (rotation compensation)
//!              + 1/12 (dth_{k-1} x dv_k + dv_{k-1} x dth_k)      (sculling)
//! ```
//!
//! so `R_{b_{k-1} b_k} = Exp(phi_k)` and `dv'_k` is the specific-force velocity change resolved
//! in `b_{k-1}`. Without a previous interval (first step after a reset) the cross terms are zero.
//!
//! The bias Jacobians below are exact derivatives of these formulas (both increments depend on
//! the bias through `- b dt`), so the preintegration's bias Jacobians are exact for its scheme.

use super::imu::ImuSample;
use crate::math::{skew, Mat3, Vec3};

/// Bias-corrected trapezoidal increments of one sample interval, in the body frame at its start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Increment {
    /// Interval length, s.
    pub dt_s: f64,
    /// Angle increment, rad.
    pub dtheta: Vec3,
    /// Specific-force velocity increment, m/s.
    pub dvel: Vec3,
}

impl Increment {
    /// Increment over `[prev.t_ns, cur.t_ns]` with biases removed: quadratic through `older`,
    /// `prev`, `cur` when `older` is given, else the trapezoid. Times must be strictly increasing
    /// (the callers check).
    pub fn from_samples(
        older: Option<&ImuSample>,
        prev: &ImuSample,
        cur: &ImuSample,
        bg: &Vec3,
        ba: &Vec3,
    ) -> Self {
        let h2 = span_s(prev.t_ns, cur.t_ns);
        let (w, f) = match older {
            Some(o) => {
                let h1 = span_s(o.t_ns, prev.t_ns);
                let c0 = -h2 * h2 * h2 / (6.0 * h1 * (h1 + h2));
                let c1 = h2 * (h2 + 3.0 * h1) / (6.0 * h1);
                let c2 = h2 * (2.0 * h2 + 3.0 * h1) / (6.0 * (h1 + h2));
                (
                    o.gyro_rps * c0 + prev.gyro_rps * c1 + cur.gyro_rps * c2,
                    o.accel_mps2 * c0 + prev.accel_mps2 * c1 + cur.accel_mps2 * c2,
                )
            }
            None => (
                (prev.gyro_rps + cur.gyro_rps) * (0.5 * h2),
                (prev.accel_mps2 + cur.accel_mps2) * (0.5 * h2),
            ),
        };
        Increment {
            dt_s: h2,
            dtheta: w - bg * h2,
            dvel: f - ba * h2,
        }
    }
}

/// Seconds between two nanosecond stamps (`i128` so extreme stamps cannot overflow).
pub(crate) fn span_s(t0_ns: i64, t1_ns: i64) -> f64 {
    (t1_ns as i128 - t0_ns as i128) as f64 * 1e-9
}

/// One compensated step: attitude change and velocity increment over `[t_{k-1}, t_k]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// Rotation vector of `R_{b_{k-1} b_k}`, rad.
    pub phi: Vec3,
    /// Velocity increment resolved in `b_{k-1}`, m/s.
    pub dv: Vec3,
}

/// Jacobians of a [`Step`] with respect to the biases used to form both increments.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepBiasJacobians {
    /// `d phi / d bg`.
    pub phi_bg: Mat3,
    /// `d dv / d bg`.
    pub dv_bg: Mat3,
    /// `d dv / d ba`.
    pub dv_ba: Mat3,
}

/// Applies the two-sample coning, rotation and sculling compensation.
pub fn two_sample(prev: Option<&Increment>, cur: &Increment) -> Step {
    let mut phi = cur.dtheta;
    let mut dv = cur.dvel + cur.dtheta.cross(&cur.dvel) * 0.5;
    if let Some(p) = prev {
        phi += p.dtheta.cross(&cur.dtheta) * (1.0 / 12.0);
        dv += (p.dtheta.cross(&cur.dvel) + p.dvel.cross(&cur.dtheta)) * (1.0 / 12.0);
    }
    Step { phi, dv }
}

/// Exact bias Jacobians of [`two_sample`] (`d inc / d b = -dt I` for both increments).
pub fn two_sample_bias_jacobians(prev: Option<&Increment>, cur: &Increment) -> StepBiasJacobians {
    let dt = cur.dt_s;
    let eye = Mat3::identity();
    let mut phi_bg = -eye * dt;
    let mut dv_bg = skew(&cur.dvel) * (0.5 * dt);
    let mut dv_ba = -(eye + skew(&cur.dtheta) * 0.5) * dt;
    if let Some(p) = prev {
        let dtp = p.dt_s;
        let k = 1.0 / 12.0;
        phi_bg += (skew(&cur.dtheta) * dtp - skew(&p.dtheta) * dt) * k;
        dv_bg += (skew(&cur.dvel) * dtp - skew(&p.dvel) * dt) * k;
        dv_ba += (skew(&cur.dtheta) * dtp - skew(&p.dtheta) * dt) * k;
    }
    StepBiasJacobians {
        phi_bg,
        dv_bg,
        dv_ba,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_ns: i64, w: [f64; 3], f: [f64; 3]) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rps: Vec3::from(w),
            accel_mps2: Vec3::from(f),
        }
    }

    /// The analytic bias Jacobians against central differences of the whole step.
    #[test]
    fn bias_jacobians_match_numerical() {
        let s0 = sample(0, [0.3, -0.2, 0.5], [1.0, 0.2, 9.6]);
        let s1 = sample(5_000_000, [0.4, -0.1, 0.7], [1.3, -0.4, 9.9]);
        let s2 = sample(9_000_000, [0.6, 0.1, 0.4], [0.7, -0.9, 10.4]);
        let step = |bg: &Vec3, ba: &Vec3| {
            let p = Increment::from_samples(None, &s0, &s1, bg, ba);
            let c = Increment::from_samples(Some(&s0), &s1, &s2, bg, ba);
            two_sample(Some(&p), &c)
        };
        let bg = Vec3::new(0.01, -0.02, 0.03);
        let ba = Vec3::new(0.1, 0.05, -0.2);
        let p = Increment::from_samples(None, &s0, &s1, &bg, &ba);
        let c = Increment::from_samples(Some(&s0), &s1, &s2, &bg, &ba);
        let j = two_sample_bias_jacobians(Some(&p), &c);
        let h = 1e-5;
        for i in 0..3 {
            let mut e = Vec3::zeros();
            e[i] = h;
            let (gp, gm) = (step(&(bg + e), &ba), step(&(bg - e), &ba));
            let (ap, am) = (step(&bg, &(ba + e)), step(&bg, &(ba - e)));
            let num_phi_bg = (gp.phi - gm.phi) / (2.0 * h);
            let num_dv_bg = (gp.dv - gm.dv) / (2.0 * h);
            let num_dv_ba = (ap.dv - am.dv) / (2.0 * h);
            assert!((num_phi_bg - j.phi_bg.column(i)).norm() < 1e-10);
            assert!((num_dv_bg - j.dv_bg.column(i)).norm() < 1e-10);
            assert!((num_dv_ba - j.dv_ba.column(i)).norm() < 1e-10);
            // The ba derivative of phi is exactly zero.
            assert_eq!(ap.phi, am.phi);
        }
        // The cross terms must matter, else the test above would not check them.
        assert!((j.dv_ba + Mat3::identity() * 0.004).norm() > 1e-6);
    }

    /// The quadratic increment integrates a quadratic rate exactly, on uneven spacing.
    #[test]
    fn quadratic_increment_is_exact_for_quadratic_rates() {
        let w = |t: f64| Vec3::new(1.0 + 2.0 * t - 30.0 * t * t, -0.5 * t * t, 0.3);
        let integral = |t: f64| Vec3::new(t + t * t - 10.0 * t * t * t, -t * t * t / 6.0, 0.3 * t);
        let s = |t_ns: i64| {
            let t = t_ns as f64 * 1e-9;
            sample(t_ns, w(t).into(), [0.0; 3])
        };
        let (a, b, c) = (s(10_000_000), s(17_000_000), s(21_000_000));
        let z = Vec3::zeros();
        let inc = Increment::from_samples(Some(&a), &b, &c, &z, &z);
        let exact = integral(0.021) - integral(0.017);
        assert!(
            (inc.dtheta - exact).norm() < 1e-15,
            "{:?}",
            inc.dtheta - exact
        );
        let trap = Increment::from_samples(None, &b, &c, &z, &z);
        assert!((trap.dtheta - exact).norm() > 1e-8);
        assert!((inc.dt_s - 0.004).abs() < 1e-18);
    }
}

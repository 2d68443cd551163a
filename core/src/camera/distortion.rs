//! Lens models on the normalized plane: forward map `x_n -> x_d` with its 2x2 Jacobian, and the
//! iterative inverse.
//!
//! Radial-tangential (Kalibr `radtan`), with `r^2 = x^2 + y^2`,
//! `rad = 1 + k1 r^2 + k2 r^4`:
//!
//! ```text
//! x_d = x rad + 2 p1 x y + p2 (r^2 + 2 x^2)
//! y_d = y rad + p1 (r^2 + 2 y^2) + 2 p2 x y
//! ```
//!
//! Equidistant (Kalibr `equidistant`), with `r = |x_n|`, `theta = atan(r)`:
//! `theta_d = theta (1 + k0 theta^2 + k1 theta^4 + k2 theta^6 + k3 theta^8)`,
//! `x_d = (theta_d / r) x_n`. Writing `s(r) = theta_d / r`, the Jacobian is
//! `s I + (s'(r)/r) x_n x_n^T`; both `s` and `s'(r)/r` have finite limits at `r = 0`
//! (`1` and `2 (k0 - 1/3)`), used below a small radius so the optical axis is exact.
//!
//! Inversion: radtan is solved by Gauss–Newton on the forward model (2-D, with step halving so a
//! strongly distorted corner cannot diverge); equidistant reduces to the scalar equation
//! `theta_d(theta) = |x_d|`, solved by Newton, then `r = tan(theta)`. Both stop when the forward
//! model reproduces `x_d` to [`UNDISTORT_TOL`] and give up after a fixed number of iterations.

use super::{Distortion, Mat2, Vec2};
use crate::Error;

/// Convergence tolerance of the inverse lens model: `|distort(x_n) - x_d|` on the normalized
/// plane (dimensionless; 1e-12 is ~5e-10 px for a 500 px focal length).
pub const UNDISTORT_TOL: f64 = 1e-12;

/// Iteration cap of the inverse lens model.
const MAX_ITERS: usize = 40;

/// Step halvings per Gauss–Newton iteration before the radtan inverse gives up.
const MAX_HALVINGS: usize = 20;

/// Below this radius the equidistant model uses its series expansion at `r = 0`.
const SMALL_R: f64 = 1e-7;

/// Largest incidence angle accepted by the equidistant inverse (rays at or beyond 90 degrees have
/// no point on the `z = 1` plane).
const MAX_THETA: f64 = core::f64::consts::FRAC_PI_2 - 1e-6;

impl Distortion {
    /// Distorted normalized coordinates `x_d` of the undistorted normalized point `x_n`.
    pub fn distort_normalized(&self, x_n: &Vec2) -> Vec2 {
        self.distort_normalized_with_jacobian(x_n).0
    }

    /// `x_d` and its Jacobian `d x_d / d x_n`.
    pub fn distort_normalized_with_jacobian(&self, x_n: &Vec2) -> (Vec2, Mat2) {
        match *self {
            Distortion::None => (*x_n, Mat2::identity()),
            Distortion::RadTan { k1, k2, p1, p2 } => radtan(x_n, k1, k2, p1, p2),
            Distortion::Equidistant { k } => equidistant(x_n, &k),
        }
    }

    /// Inverse lens model: the undistorted normalized point whose distortion is `x_d`.
    ///
    /// Errors: [`Error::NonFinite`] for a non-finite input, [`Error::Degenerate`] when the
    /// iteration does not reach [`UNDISTORT_TOL`] (outside the invertible domain of the model, or
    /// an equidistant ray at 90 degrees or more from the optical axis).
    pub fn undistort_normalized(&self, x_d: &Vec2) -> Result<Vec2, Error> {
        if !(x_d.x.is_finite() && x_d.y.is_finite()) {
            return Err(Error::NonFinite);
        }
        match *self {
            Distortion::None => Ok(*x_d),
            Distortion::RadTan { .. } => self.undistort_gauss_newton(x_d),
            Distortion::Equidistant { k } => undistort_equidistant(x_d, &k),
        }
    }

    fn undistort_gauss_newton(&self, x_d: &Vec2) -> Result<Vec2, Error> {
        let mut x = *x_d;
        let (f0, mut jac) = self.distort_normalized_with_jacobian(&x);
        let mut res = f0 - x_d;
        let mut cost = res.norm_squared();
        for _ in 0..MAX_ITERS {
            if !cost.is_finite() {
                return Err(Error::NonFinite);
            }
            if cost <= UNDISTORT_TOL * UNDISTORT_TOL {
                return Ok(x);
            }
            let step = jac.try_inverse().ok_or(Error::Degenerate)? * (-res);
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..MAX_HALVINGS {
                let cand = x + step * alpha;
                let (f, j) = self.distort_normalized_with_jacobian(&cand);
                let r = f - x_d;
                let c = r.norm_squared();
                if c < cost {
                    x = cand;
                    res = r;
                    cost = c;
                    jac = j;
                    accepted = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !accepted {
                // No decrease along the Gauss–Newton direction: either converged to rounding
                // level or stuck; the final tolerance check decides.
                break;
            }
        }
        if cost <= UNDISTORT_TOL * UNDISTORT_TOL {
            Ok(x)
        } else {
            Err(Error::Degenerate)
        }
    }
}

fn radtan(x_n: &Vec2, k1: f64, k2: f64, p1: f64, p2: f64) -> (Vec2, Mat2) {
    let (x, y) = (x_n.x, x_n.y);
    let r2 = x * x + y * y;
    let rad = 1.0 + k1 * r2 + k2 * r2 * r2;
    // d rad / d(r^2)
    let drad = k1 + 2.0 * k2 * r2;
    let xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    let j = Mat2::new(
        rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x,
        2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y,
        2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y,
        rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x,
    );
    (Vec2::new(xd, yd), j)
}

/// `theta_d(theta)` and its derivative.
fn equidistant_theta_d(theta: f64, k: &[f64; 4]) -> (f64, f64) {
    let t2 = theta * theta;
    let poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
    let dpoly_dt2 = k[0] + t2 * (2.0 * k[1] + t2 * (3.0 * k[2] + t2 * 4.0 * k[3]));
    (theta * poly, poly + 2.0 * t2 * dpoly_dt2)
}

fn equidistant(x_n: &Vec2, k: &[f64; 4]) -> (Vec2, Mat2) {
    let r2 = x_n.norm_squared();
    let r = libm::sqrt(r2);
    let (s, ds_over_r) = if r < SMALL_R {
        // theta ~ r - r^3/3, theta_d ~ theta + k0 theta^3  =>  s ~ 1 + (k0 - 1/3) r^2.
        let c = k[0] - 1.0 / 3.0;
        (1.0 + c * r2, 2.0 * c)
    } else {
        let theta = libm::atan(r);
        let (td, dtd_dtheta) = equidistant_theta_d(theta, k);
        let dtheta_dr = 1.0 / (1.0 + r2);
        let s = td / r;
        let ds_dr = (dtd_dtheta * dtheta_dr * r - td) / r2;
        (s, ds_dr / r)
    };
    let j = Mat2::identity() * s + (x_n * x_n.transpose()) * ds_over_r;
    (x_n * s, j)
}

fn undistort_equidistant(x_d: &Vec2, k: &[f64; 4]) -> Result<Vec2, Error> {
    let theta_d = x_d.norm();
    if theta_d == 0.0 {
        return Ok(Vec2::zeros());
    }
    let mut theta = theta_d;
    let mut converged = false;
    for _ in 0..MAX_ITERS {
        let (f, df) = equidistant_theta_d(theta, k);
        let res = f - theta_d;
        if libm::fabs(res) <= UNDISTORT_TOL * 1e-2 {
            converged = true;
            break;
        }
        if !(df > 0.0 && df.is_finite()) {
            // The model folds over here: no unique inverse.
            return Err(Error::Degenerate);
        }
        let next = theta - res / df;
        if !next.is_finite() {
            return Err(Error::NonFinite);
        }
        // Keep the iterate in the physical range; a negative angle means the model folded.
        theta = if next < 0.0 { 0.5 * theta } else { next };
    }
    if !converged || theta >= MAX_THETA {
        return Err(Error::Degenerate);
    }
    let r = libm::tan(theta);
    let x = x_d * (r / theta_d);
    // Final check on the same quantity the radtan inverse uses.
    let back = equidistant(&x, k).0;
    if (back - x_d).norm() <= UNDISTORT_TOL {
        Ok(x)
    } else {
        Err(Error::Degenerate)
    }
}

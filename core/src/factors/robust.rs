//! Huber robust kernel on a squared residual norm.
//!
//! For `s = |r|^2` (whitened) and threshold `delta` (in whitened units):
//! `rho(s) = s` for `s <= delta^2`, else `2 delta sqrt(s) - delta^2`;
//! `rho'(s) = min(1, delta / sqrt(s))`, `rho''(s) = 0` inside, `-delta / (2 s^{3/2})` outside.
//! The factor cost is `rho(s) / 2`.
//!
//! Chosen rescaling: plain IRLS. Residual and Jacobian are both multiplied by `sqrt(rho'(s))`, so
//! the Gauss–Newton block `J^T rho' J` stays positive semi-definite and the gradient
//! `rho' J^T r` is exact. The Triggs correction (Ceres) adds the `rho''` curvature term; for Huber
//! `rho'' <= 0` and that term can only reduce the Hessian, which buys little and costs robustness,
//! so it is left out. Note `|sqrt(rho') r|^2 = rho' s != rho(s)` outside the threshold: use
//! [`Huber::rho`] for costs (e.g. the LM gain ratio), not the norm of the rescaled residual.

use crate::Error;
use nalgebra::SMatrix;

/// Huber kernel with threshold `delta` on the whitened residual norm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Huber {
    /// Threshold, in whitened units (e.g. 1.0 = one sigma).
    delta: f64,
}

impl Huber {
    /// Errors: [`Error::InvalidConfig`] unless `delta` is positive and finite.
    pub fn new(delta: f64) -> Result<Self, Error> {
        if delta > 0.0 && delta.is_finite() {
            Ok(Huber { delta })
        } else {
            Err(Error::InvalidConfig)
        }
    }

    /// The threshold.
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// `[rho(s), rho'(s), rho''(s)]` for the squared norm `s >= 0`.
    pub fn rho(&self, s: f64) -> [f64; 3] {
        let d2 = self.delta * self.delta;
        if s <= d2 {
            [s, 1.0, 0.0]
        } else {
            let r = libm::sqrt(s);
            [
                2.0 * self.delta * r - d2,
                self.delta / r,
                -self.delta / (2.0 * s * r),
            ]
        }
    }

    /// IRLS weight `rho'(s)`.
    pub fn weight(&self, s: f64) -> f64 {
        self.rho(s)[1]
    }

    /// `sqrt(rho'(s))`: the factor applied to residual and Jacobian rows.
    pub fn sqrt_weight(&self, s: f64) -> f64 {
        libm::sqrt(self.weight(s))
    }

    /// Rescales a residual and one of its Jacobian blocks in place by [`Self::sqrt_weight`] of
    /// the given squared norm (pass the norm of the *whole* residual when rescaling several
    /// blocks of one factor) and returns the weight used.
    pub fn rescale<const R: usize, const C: usize>(
        &self,
        squared_norm: f64,
        r: &mut SMatrix<f64, R, 1>,
        jac: &mut SMatrix<f64, R, C>,
    ) -> f64 {
        let w = self.sqrt_weight(squared_norm);
        *r *= w;
        *jac *= w;
        w
    }
}

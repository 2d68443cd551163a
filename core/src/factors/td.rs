//! Random-walk prior on the camera–IMU time delay between consecutive keyframes (math notes
//! sec. 4, LE-VINS): `r = (td_k - td_{k+1}) / sqrt(q dt)` with `q` the random-walk power spectral
//! density (s^2/s, e.g. `(1e-4 s/sqrt(s))^2`) and `dt` the keyframe interval (s).

use crate::Error;

/// Time-delay random-walk factor between keyframes `k` and `k+1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdRandomWalk {
    /// `1 / sqrt(q dt)`, 1/s.
    sqrt_info: f64,
}

impl TdRandomWalk {
    /// Errors: [`Error::InvalidConfig`] unless `q_s2_per_s > 0` and `dt_s > 0` (finite).
    pub fn new(q_s2_per_s: f64, dt_s: f64) -> Result<Self, Error> {
        let var = q_s2_per_s * dt_s;
        if !(q_s2_per_s > 0.0 && dt_s > 0.0 && var.is_finite()) {
            return Err(Error::InvalidConfig);
        }
        Ok(TdRandomWalk {
            sqrt_info: 1.0 / libm::sqrt(var),
        })
    }

    /// Whitened residual and its derivatives `[d/d td_k, d/d td_{k+1}]`.
    ///
    /// Errors: [`Error::NonFinite`] for a non-finite delay.
    pub fn evaluate(&self, td_k: f64, td_k1: f64) -> Result<(f64, [f64; 2]), Error> {
        if !(td_k.is_finite() && td_k1.is_finite()) {
            return Err(Error::NonFinite);
        }
        Ok((
            (td_k - td_k1) * self.sqrt_info,
            [self.sqrt_info, -self.sqrt_info],
        ))
    }
}

//! Online scale of the IMU's white-noise densities (variance component estimation).
//!
//! A datasheet or a `sensor.yaml` gives the noise densities of the IMU *at rest*. On a vehicle the
//! measurement error in motion is larger (rotor and engine vibration, scale-factor and
//! misalignment errors, small clock errors), and preintegration factors built from the static
//! densities are over-confident: the window then trusts the IMU over the camera, and the longer the
//! keyframe intervals, the worse (EuRoC V1_01 with its `sensor.yaml`: 0.041 m, with densities
//! raised ~10x: 0.021 m).
//!
//! The window's own solution shows how large the IMU error really is. For a factor with whitened
//! residual `r` (computed with the covariance it was built with) and whitened Jacobian `A`, in a
//! least-squares solution with normal matrix `S`,
//!
//! ```text
//! E[|r|^2] = s^2 * (m - tr(A S^-1 A^T))
//! ```
//!
//! where `m` is the residual's dimension, the bracket is the factor's *redundancy* (its share of
//! the degrees of freedom the other measurements do not take up) and `s^2` the ratio of the true
//! variance to the assumed one (Helmert/Foerstner variance component estimation). With
//! `S = U^T D U` the factored reduced system of the last solve (landmarks eliminated; the IMU
//! factor does not touch them), `a^T S^-1 a = |D^-1/2 U^-T a|^2` costs one forward substitution
//! per row.
//!
//! Each IMU factor is measured once, when the window is full and it is the oldest one (about to be
//! marginalized, so at its best-informed estimate). Only its first nine rows are used: the residual
//! is ordered `[p, v, theta, bg, ba]` and whitened by a lower-triangular factor, so the first nine
//! whitened rows depend only on the preintegrated deltas and their marginal covariance (the white
//! noise), not on the bias random walk. The sums over factors decay geometrically
//! ([`ImuNoiseAdapt::forgetting`]), and the variance ratio is kept in
//! `[1, max_density_scale^2]`: the static densities are a floor, never lowered. New keyframe
//! intervals are preintegrated with the gyro and accelerometer white-noise densities multiplied by
//! `s`; the bias random walks keep their configured values. A factor's chi-square is referred back
//! to the unscaled densities (`|r|^2 * s_used^2`), so the estimate converges to a fixed point
//! instead of compounding.

use super::window::{Block, Layout};
use super::Estimator;
use crate::inertial::imu::ImuNoise;
use crate::inertial::preintegration::{Mat15, Vec15};

/// Rows of the IMU residual that measure the white noise (`[p, v, theta]`).
const NOISE_ROWS: usize = 9;

/// Settings of the online IMU noise scale.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ImuNoiseAdapt {
    /// Estimate the scale at all (off: the configured densities are used as they are).
    pub enabled: bool,
    /// Largest factor on the white-noise densities (the variance ratio is capped at its square).
    pub max_density_scale: f64,
    /// Weight of the earlier factors' sums at each new factor (`0 < f < 1`; 0.97 remembers about
    /// 33 factors, 10-15 s of keyframes).
    pub forgetting: f64,
    /// Summed redundancy needed before the scale moves off 1.
    pub min_redundancy: f64,
    /// Variance ratio the window shows with an exactly known IMU, from its own approximations
    /// (visual errors that are not independent, the linearized prior): only the excess over it is
    /// attributed to the IMU. Measured with the simulators' exact noise: 1.3-1.9.
    pub tolerance: f64,
}

impl ImuNoiseAdapt {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: ImuNoiseAdapt = ImuNoiseAdapt {
        enabled: true,
        max_density_scale: 30.0,
        forgetting: 0.97,
        min_redundancy: 5.0,
        tolerance: 2.0,
    };
}

impl Default for ImuNoiseAdapt {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl ImuNoiseAdapt {
    /// The range checks (`[imu_noise_adapt]`).
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        let scale = self.max_density_scale;
        r.check(
            "imu_noise_adapt.max_density_scale",
            scale,
            ">= 1",
            scale.is_finite() && scale >= 1.0,
        );
        let f = self.forgetting;
        r.check(
            "imu_noise_adapt.forgetting",
            f,
            "0 < x < 1",
            f > 0.0 && f < 1.0,
        );
        r.non_negative("imu_noise_adapt.min_redundancy", self.min_redundancy);
        r.positive("imu_noise_adapt.tolerance", self.tolerance);
    }
}

/// Running variance component of one group of rows.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Component {
    /// Decayed sum of the rows' chi-square referred to the unscaled densities.
    chi2: f64,
    /// Decayed sum of their redundancies.
    redundancy: f64,
    /// Current factor on the group's density (>= 1), or 0 before the first update (factor 1:
    /// zero keeps a new component's bits all zero). See [`Component::factor`].
    scale: f64,
}

impl Component {
    const fn new() -> Self {
        Component {
            chi2: 0.0,
            redundancy: 0.0,
            scale: 0.0,
        }
    }

    /// Current factor on the group's density (>= 1).
    fn factor(&self) -> f64 {
        if self.scale == 0.0 {
            1.0
        } else {
            self.scale
        }
    }

    /// Adds one factor's chi-square (already referred to the unscaled density) and redundancy.
    fn add(&mut self, cfg: &ImuNoiseAdapt, chi2_unscaled: f64, redundancy: f64) {
        if !(chi2_unscaled.is_finite() && redundancy.is_finite() && redundancy > 0.0) {
            return;
        }
        self.chi2 = cfg.forgetting * self.chi2 + chi2_unscaled;
        self.redundancy = cfg.forgetting * self.redundancy + redundancy;
        if self.redundancy >= cfg.min_redundancy {
            let ratio = self.chi2 / (self.redundancy * cfg.tolerance);
            let max2 = cfg.max_density_scale * cfg.max_density_scale;
            self.scale = libm::sqrt(ratio.clamp(1.0, max2));
        }
    }
}

/// Running variance component of the IMU white noise (gyro and accelerometer together: their
/// errors mix in every row, and separate components converge more slowly on fewer rows; measured
/// on EuRoC V1_01 separately they gave 0.040 m, together 0.028 m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ImuNoiseScale(Component);

impl ImuNoiseScale {
    pub(super) const fn new() -> Self {
        ImuNoiseScale(Component::new())
    }

    /// Factor on both white-noise densities.
    pub(super) fn density_scale(&self) -> f64 {
        self.0.factor()
    }

    /// `noise` with its white-noise densities multiplied by the current scale.
    pub(super) fn apply(&self, noise: ImuNoise) -> ImuNoise {
        ImuNoise {
            gyro_noise_density: noise.gyro_noise_density * self.0.factor(),
            accel_noise_density: noise.accel_noise_density * self.0.factor(),
            ..noise
        }
    }
}

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
    /// Measures the oldest IMU factor of a full window against the last solve's factored normal
    /// matrix and updates the noise scales. Does nothing unless the window is full, adaptation is
    /// on and the factorization matches `layout`.
    pub(super) fn update_imu_noise_scale(&mut self, layout: &Layout<N>) {
        let adapt = self.cfg.imu_noise_adapt;
        if !adapt.enabled || self.window.len() < N || self.lm.ldlt.dim() != layout.dim() {
            return;
        }
        if let Some((chi2, redundancy)) = self.oldest_imu_variance_component(layout) {
            self.imu_scale.0.add(&adapt, chi2, redundancy);
        }
    }

    /// `(chi-square referred to the unscaled densities, redundancy)` of the white-noise rows of
    /// the IMU factor between keyframes 0 and 1.
    fn oldest_imu_variance_component(&self, layout: &Layout<N>) -> Option<(f64, f64)> {
        let (a, b) = (self.window.get(0)?, self.window.get(1)?);
        let pre = b.preint()?;
        let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        pre.evaluate(
            &a.state,
            &b.state,
            self.cfg.gravity_mps2,
            &mut r,
            &mut ji,
            &mut jj,
        )
        .ok()?;
        let (ca, cb) = (layout.col(Block::Kf(0))?, layout.col(Block::Kf(1))?);
        let n = layout.dim();
        let ldlt = &self.lm.ldlt;
        let mut y = [0.0; D];
        let y = y.get_mut(..n)?;
        // Both densities carry the same scale: the accelerometer's ratio is the factor's.
        let used = pre.noise().accel_noise_density / self.cfg.imu_noise.accel_noise_density;
        let (mut chi2, mut redundancy) = (0.0, 0.0);
        for m in 0..NOISE_ROWS {
            y.fill(0.0);
            for c in 0..15 {
                *y.get_mut(ca + c)? = ji[(m, c)];
                *y.get_mut(cb + c)? = jj[(m, c)];
            }
            redundancy += 1.0 - ldlt.inverse_quadratic_form(y).ok()?;
            chi2 += r[m] * r[m] * used * used;
        }
        Some((chi2, redundancy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_is_the_root_of_the_variance_ratio_within_its_bounds() {
        let cfg = ImuNoiseAdapt {
            forgetting: 0.5,
            min_redundancy: 1.0,
            max_density_scale: 10.0,
            tolerance: 1.0,
            ..ImuNoiseAdapt::default()
        };
        let mut c = Component::new();
        // Too little redundancy yet: stays at 1.
        c.add(&cfg, 50.0, 0.5);
        assert_eq!(c.factor(), 1.0);
        // chi2 25 per unit redundancy -> scale 5 once enough has been seen.
        let mut c = Component::new();
        for _ in 0..40 {
            c.add(&cfg, 100.0, 4.0);
        }
        assert!((c.factor() - 5.0).abs() < 1e-9, "{}", c.factor());
        // The tolerance is the ratio attributed to the rest of the window: 25 / 4 -> 2.5.
        let mut t = Component::new();
        for _ in 0..40 {
            t.add(
                &ImuNoiseAdapt {
                    tolerance: 4.0,
                    ..cfg
                },
                100.0,
                4.0,
            );
        }
        assert!((t.factor() - 2.5).abs() < 1e-9, "{}", t.factor());
        // Consistent factors (ratio < 1) never lower the densities below the configured ones.
        for _ in 0..40 {
            c.add(&cfg, 1.0, 4.0);
        }
        assert_eq!(c.factor(), 1.0);
        // Capped.
        for _ in 0..40 {
            c.add(&cfg, 1e6, 1.0);
        }
        assert_eq!(c.factor(), 10.0);
        // Non-finite or non-positive redundancy is ignored.
        let before = c;
        c.add(&cfg, f64::NAN, 1.0);
        c.add(&cfg, 1.0, -1.0);
        assert_eq!(c, before);
        // Both white-noise densities scale; the bias random walks are kept.
        let s = ImuNoiseScale(c);
        let n = s.apply(ImuNoise::EUROC_ADIS16448);
        let e = ImuNoise::EUROC_ADIS16448;
        assert_eq!(n.accel_noise_density, 10.0 * e.accel_noise_density);
        assert_eq!(n.gyro_noise_density, 10.0 * e.gyro_noise_density);
        assert_eq!(
            (n.gyro_bias_rw, n.accel_bias_rw),
            (e.gyro_bias_rw, e.accel_bias_rw)
        );
        assert_eq!(s.density_scale(), 10.0);
    }
}

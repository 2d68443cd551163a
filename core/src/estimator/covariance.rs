//! The newest keyframe's marginal covariance after each solve
//! ([`super::EstimatorConfig::covariance`]), handed to the INS, which propagates it at IMU rate
//! ([`crate::inertial::InsCovariance`]): the uncertainty an autopilot fuses the output with.
//!
//! The solve's last linearization `H` (whitened Gauss-Newton information of the window: the
//! marginalization prior, the IMU factors, the visual factors with their depths eliminated, the
//! LiDAR depths) is factored without damping, and the newest keyframe's `15 x 15` block of
//! `H^-1` is read off the factor ([`crate::solver::Ldlt::inverse_block`]): the newest keyframe
//! comes last among the keyframes in the solve layout, so this costs one factorization and
//! `15 (n - c)^2` more operations (`c` its first column). `H` is the one of the last LM
//! iteration, whose state the accepted step moved by less than the solve's tolerances.
//!
//! The covariance is that of the estimator's own model: a sliding window whose marginalization
//! prior fixes the gauge (position and yaw drift are counted as far as the prior carries them),
//! the configured pixel noise, the IMU noise with its online scale. It is `None` (unknown) when
//! the factorization drops a pivot at or after the newest keyframe, until the first solve, and
//! after a reset.

use super::report::ExtrinsicSd;
use super::window::{Block, EXT_DIM};
use super::Estimator;
use crate::inertial::{InsCovariance, Mat15};
use crate::solver::PivotFloor;

/// Pivots dropped when factoring for the covariance: only those that are not positive. The
/// solve's relative floor ([`PivotFloor::DEFAULT`], `1e-12` of the largest diagonal) suits a
/// step but not a covariance: a tight factor (a held delay, a zero-velocity update) makes the
/// largest diagonal so large that well-determined directions fall under it (measured: the
/// newest keyframe's velocity on the simulated vehicle, 53 of 285 keyframes without a
/// covariance).
const COVARIANCE_FLOOR: PivotFloor = PivotFloor {
    relative: 0.0,
    absolute: f64::MIN_POSITIVE,
};

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
    /// The newest keyframe's marginal covariance from the solve's last linearization (module
    /// docs), with the IMU noise the INS propagates it with; `None` when off or unavailable.
    /// Uses the marginalization's workspaces (free between keyframes).
    /// With the extrinsic's standard deviations when it is estimated ([`ExtrinsicSd`]: its
    /// `6 x 6` block, read off the same factorization).
    pub(super) fn newest_covariance(&mut self) -> (Option<InsCovariance>, Option<ExtrinsicSd>) {
        if !self.cfg.covariance && !self.cfg.estimate_extrinsic {
            return (None, None);
        }
        if self.factor_window().is_none() {
            return (None, None);
        }
        let cov = self.cfg.covariance.then(|| self.newest_block()).flatten();
        (cov, self.extrinsic_block())
    }

    /// [`Self::newest_covariance`] whether asked for or not: also what a camera dropout's new
    /// window starts from (`imu_step`), where the solve's last linearization is still the one
    /// of the current window (no keyframe since).
    pub(super) fn window_covariance(&mut self) -> Option<InsCovariance> {
        self.factor_window()?;
        self.newest_block()
    }

    /// Factors the solve's last linearization (without damping) into the marginalization's
    /// workspace; `None` when it is not the current window's or not factorable.
    fn factor_window(&mut self) -> Option<()> {
        let layout = self.solve_layout();
        if self.lm.ne.dim() != layout.dim() {
            return None;
        }
        self.marg_ldlt.load(&self.lm.ne).ok()?;
        self.marg_ldlt.factorize(COVARIANCE_FLOOR).ok().map(|_| ())
    }

    /// The newest keyframe's block of the factored window's inverse ([`Self::factor_window`]).
    fn newest_block(&mut self) -> Option<InsCovariance> {
        let newest = u8::try_from(self.window.len().checked_sub(1)?).ok()?;
        let c = self.solve_layout().col(Block::Kf(newest))?;
        let mut block = [[0.0; 15]; 15];
        self.marg_ldlt
            .inverse_block(c, &mut self.marg_ne.h, &mut block)
            .ok()?;
        let p = Mat15::from_fn(|i, j| block[i][j]);
        InsCovariance::new(&p, self.imu_scale.apply(self.cfg.imu_noise)).ok()
    }

    /// The extrinsic's standard deviations from the factored window ([`Self::factor_window`]);
    /// `None` when it is not estimated.
    fn extrinsic_block(&mut self) -> Option<ExtrinsicSd> {
        let c = self.solve_layout().col(Block::Ext)?;
        let mut block = [[0.0; EXT_DIM]; EXT_DIM];
        self.marg_ldlt
            .inverse_block(c, &mut self.marg_ne.h, &mut block)
            .ok()?;
        let sd = |i: usize| {
            let v = block
                .get(i)
                .and_then(|r| r.get(i))
                .copied()
                .unwrap_or(f64::NAN);
            libm::sqrt(v)
        };
        let out = ExtrinsicSd {
            p_bc_m: [sd(0), sd(1), sd(2)],
            r_bc_rad: [sd(3), sd(4), sd(5)],
        };
        let finite = out
            .p_bc_m
            .iter()
            .chain(&out.r_bc_rad)
            .all(|x| x.is_finite());
        finite.then_some(out)
    }
}

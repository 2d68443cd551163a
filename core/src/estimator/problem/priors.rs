//! The priors of the window's problem as [`WindowFactor`]s: the marginalization prior
//! ([`MargPriorFactor`], see [`crate::estimator::prior`]) and, until the first marginalization, the
//! diagonal priors on the first keyframe ([`FirstStatePrior`]), its delay ([`TdPrior`]) and the
//! extrinsic ([`ExtPrior`]).
//!
//! A diagonal prior on a state with a rotation whitens its error `x [-] x0` (rotation part
//! `e = Log(R0^T R)`) by the standard deviations; the rotation rows' Jacobian w.r.t. the right
//! perturbation is `Jr^-1(e) / sigma`, the others `1 / sigma`.
#![deny(clippy::too_many_lines)]

use super::factor::{put_rows, sink, WindowFactor, WindowVars};
use crate::camera::CameraExtrinsic;
use crate::estimator::prior::{ext_minus, kf_minus, LinPoint, MargPrior};
use crate::estimator::window::{Block, KF_DIM};
use crate::inertial::NavState;
use crate::math::{jr_inv_so3, Vec3};
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;

/// Diagonal prior on the first keyframe's state (position 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstStatePrior {
    /// The prior's mean.
    pub kf0: NavState,
    /// Standard deviations `[p, theta, v, bg, ba]` (each for 3 axes).
    pub sigma: [f64; 5],
}

impl FirstStatePrior {
    /// Whitened error and its row-major Jacobian on the keyframe's error state.
    fn whitened(&self, x: &NavState) -> ([f64; KF_DIM], [f64; KF_DIM * KF_DIM]) {
        let mut e = [0.0; KF_DIM];
        kf_minus(x, &self.kf0, &mut e);
        let th = Vec3::new(e[3], e[4], e[5]);
        let jr = jr_inv_so3(&th);
        let mut jac = [0.0; KF_DIM * KF_DIM];
        for i in 0..KF_DIM {
            let s = self.sigma.get(i / 3).copied().unwrap_or(1.0);
            if let Some(x) = e.get_mut(i) {
                *x /= s;
            }
            if (3..6).contains(&i) {
                for c in 3..6 {
                    if let Some(x) = jac.get_mut(i * KF_DIM + c) {
                        *x = jr[(i - 3, c - 3)] / s;
                    }
                }
            } else if let Some(x) = jac.get_mut(i * KF_DIM + i) {
                *x = 1.0 / s;
            }
        }
        (e, jac)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for FirstStatePrior {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let kf0 = v.window.get(0).ok_or(Error::NotEnoughData)?;
        let (e, jac) = self.whitened(&kf0.state);
        let c0 = v.col(Block::Kf(0))?;
        sink(&mut ne, &e, &[JacobianBlock::new(c0, KF_DIM, &jac)])
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let kf0 = v.window.get(0).ok_or(Error::NotEnoughData)?;
        put_rows(&self.whitened(&kf0.state).0, out)
    }
}

/// Prior on the first keyframe's delay: `(td_0 - mean) / sigma`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdPrior {
    /// The prior's mean, s.
    pub td0_s: f64,
    /// Its standard deviation, s.
    pub sigma_s: f64,
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for TdPrior {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let kf0 = v.window.get(0).ok_or(Error::NotEnoughData)?;
        let r = (kf0.td_s - self.td0_s) / self.sigma_s;
        let c = v.col(Block::Td(0))?;
        sink(
            &mut ne,
            &[r],
            &[JacobianBlock::new(c, 1, &[1.0 / self.sigma_s])],
        )
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let kf0 = v.window.get(0).ok_or(Error::NotEnoughData)?;
        put_rows(&[(kf0.td_s - self.td0_s) / self.sigma_s], out)
    }
}

/// Prior on the extrinsic: translation and rotation standard deviations (m, rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtPrior {
    /// The prior's mean.
    pub ext0: CameraExtrinsic,
    /// Translation standard deviation, m.
    pub sigma_p_m: f64,
    /// Rotation standard deviation, rad.
    pub sigma_theta_rad: f64,
}

impl ExtPrior {
    /// Whitened error and its row-major Jacobian on the extrinsic's error state.
    fn whitened(&self, x: &CameraExtrinsic) -> ([f64; 6], [f64; 36]) {
        let (st, sr) = (self.sigma_p_m, self.sigma_theta_rad);
        let mut e6 = [0.0; 6];
        ext_minus(x, &self.ext0, &mut e6);
        let jr = jr_inv_so3(&Vec3::new(e6[3], e6[4], e6[5]));
        let mut j6 = [0.0; 36];
        for i in 0..6 {
            let s = if i < 3 { st } else { sr };
            if let Some(x) = e6.get_mut(i) {
                *x /= s;
            }
            if i < 3 {
                if let Some(x) = j6.get_mut(i * 6 + i) {
                    *x = 1.0 / s;
                }
            } else {
                for c in 3..6 {
                    if let Some(x) = j6.get_mut(i * 6 + c) {
                        *x = jr[(i - 3, c - 3)] / s;
                    }
                }
            }
        }
        (e6, j6)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for ExtPrior {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let (e6, j6) = self.whitened(v.ext);
        let c = v.col(Block::Ext)?;
        sink(&mut ne, &e6, &[JacobianBlock::new(c, 6, &j6)])
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&self.whitened(v.ext).0, out)
    }
}

/// The square-root marginalization prior `r = r0 + J0 (x [-] x0)` ([`MargPrior`]).
pub struct MargPriorFactor<'a, const D: usize, const N: usize> {
    /// The prior.
    pub prior: &'a mut MargPrior<D, N>,
}

/// The current value of a prior block.
fn current<const N: usize>(v: &WindowVars<'_, N>, b: Block) -> Option<LinPoint> {
    match b {
        Block::Kf(k) => v.window.get(k as usize).map(|kf| LinPoint::Kf(kf.state)),
        Block::Td(k) => v.window.get(k as usize).map(|kf| LinPoint::Td(kf.td_s)),
        Block::Ext => Some(LinPoint::Ext(*v.ext)),
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for MargPriorFactor<'_, D, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        self.prior.add_to(&v.layout, |b| current(v, b), ne)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        self.prior.residual(&v.layout, |b| current(v, b), out)
    }
}

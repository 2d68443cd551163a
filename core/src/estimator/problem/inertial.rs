//! The window's factors on the keyframe states other than the priors and the visual ones, as
//! [`WindowFactor`]s: IMU preintegration ([`ImuFactor`]) and the time-delay random walk
//! ([`TdRandomWalkFactor`]) between consecutive keyframes, zero-velocity updates on keyframes
//! the images show at rest ([`ZuptVelocity`], [`ZuptPosition`], [`ZuptRotation`]), and the delay
//! hold of a solve with too few landmarks to estimate the delay ([`TdHold`]).
//!
//! Zero-velocity updates: `v_k / sigma_v` on every such keyframe and, with the previous one,
//! `(p_k - p_{k-1}) / sigma_p` and `Log(R_{k-1}^T R_k) / sigma_theta`. Right perturbations: with
//! `e = Log(R_a^T R_b)`, `de/dtheta_b = Jr^-1(e)` and `de/dtheta_a = -Jr^-1(e) R_b^T R_a`.
#![deny(clippy::too_many_lines)]

use super::factor::{put_rows, row_major, sink, WindowFactor, WindowVars};
use super::{FactorSet, Problem};
use crate::estimator::window::{Block, Keyframe};
use crate::factors::td::TdRandomWalk;
use crate::inertial::preintegration::{Mat15, Vec15};
use crate::math::{jr_inv_so3, Vec3};
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;

/// The keyframes at positions `k - 1` and `k`.
fn pair<'a, const N: usize>(
    v: &'a WindowVars<'_, N>,
    k: usize,
) -> Result<(&'a Keyframe, &'a Keyframe), Error> {
    let (Some(a), Some(b)) = (
        k.checked_sub(1).and_then(|p| v.window.get(p)),
        v.window.get(k),
    ) else {
        return Err(Error::NotEnoughData);
    };
    Ok((a, b))
}

/// IMU preintegration from keyframe `k - 1` to `k` (the preintegration stored with `k`),
/// whitened by its covariance (`inertial::preintegration`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuFactor {
    /// Position of the later keyframe (`>= 1`).
    pub k: usize,
    /// Gravity, m/s^2.
    pub gravity_mps2: f64,
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for ImuFactor {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let (a, b) = pair(v, self.k)?;
        let pre = b.preint().ok_or(Error::NotEnoughData)?;
        let g = self.gravity_mps2;
        let Some(ne) = ne.as_deref_mut() else {
            let r = pre.residual_whitened(&a.state, &b.state, g)?;
            return sink(&mut ne, r.as_slice(), &[]);
        };
        let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
        pre.evaluate(&a.state, &b.state, g, &mut r, &mut ji, &mut jj)?;
        let (ca, cb) = (
            v.col(Block::Kf((self.k - 1) as u8))?,
            v.col(Block::Kf(self.k as u8))?,
        );
        let c: f64 = r.norm_squared();
        if !c.is_finite() {
            return Err(Error::NonFinite);
        }
        ne.add_dense_pair(&r, &ji, &jj, ca, cb)?;
        Ok(c)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let (a, b) = pair(v, self.k)?;
        let pre = b.preint().ok_or(Error::NotEnoughData)?;
        let r = pre.residual_whitened(&a.state, &b.state, self.gravity_mps2)?;
        put_rows(r.as_slice(), out)
    }
}

/// Random walk of the delay from keyframe `k - 1` to `k` over their interval
/// ([`TdRandomWalk`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdRandomWalkFactor {
    /// Position of the later keyframe (`>= 1`).
    pub k: usize,
    /// Random-walk density, s/sqrt(s).
    pub rw_s_per_sqrt_s: f64,
}

impl TdRandomWalkFactor {
    /// Residual and derivatives `[d/d td_{k-1}, d/d td_k]`.
    fn evaluate<const N: usize>(&self, v: &WindowVars<'_, N>) -> Result<(f64, [f64; 2]), Error> {
        let (a, b) = pair(v, self.k)?;
        let pre = b.preint().ok_or(Error::NotEnoughData)?;
        let dt = pre.dt_s().max(1e-3);
        let q = self.rw_s_per_sqrt_s * self.rw_s_per_sqrt_s;
        TdRandomWalk::new(q, dt)?.evaluate(a.td_s, b.td_s)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for TdRandomWalkFactor {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let (rt, [da, db]) = self.evaluate(v)?;
        if ne.is_none() {
            return sink(&mut ne, &[rt], &[]);
        }
        let (ta, tb) = (
            v.col(Block::Td((self.k - 1) as u8))?,
            v.col(Block::Td(self.k as u8))?,
        );
        let (ja, jb) = ([da], [db]);
        let blocks = [
            JacobianBlock::new(ta, 1, &ja),
            JacobianBlock::new(tb, 1, &jb),
        ];
        sink(&mut ne, &[rt], &blocks)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&[self.evaluate(v)?.0], out)
    }
}

/// The delay of keyframe `k` held at `td0_s` by a tight factor (1 us).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdHold {
    /// Keyframe position.
    pub k: usize,
    /// The value held, s.
    pub td0_s: f64,
}

/// Standard deviation of [`TdHold`]: the delay stays where it is while it cannot be estimated.
const HOLD_S: f64 = 1e-6;

impl<const N: usize, const D: usize> WindowFactor<N, D> for TdHold {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let kf = v.window.get(self.k).ok_or(Error::NotEnoughData)?;
        let c = v.col(Block::Td(self.k as u8))?;
        let r = (kf.td_s - self.td0_s) / HOLD_S;
        sink(&mut ne, &[r], &[JacobianBlock::new(c, 1, &[1.0 / HOLD_S])])
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let kf = v.window.get(self.k).ok_or(Error::NotEnoughData)?;
        put_rows(&[(kf.td_s - self.td0_s) / HOLD_S], out)
    }
}

/// Row-major `diag(1 / s)` of a 3-vector.
fn diag(s: f64) -> [f64; 9] {
    let mut m = [0.0; 9];
    for i in 0..3 {
        if let Some(x) = m.get_mut(i * 4) {
            *x = 1.0 / s;
        }
    }
    m
}

/// Zero velocity of keyframe `k`: `v_k / sigma_v`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZuptVelocity {
    /// Keyframe position.
    pub k: usize,
    /// Velocity standard deviation, m/s.
    pub sigma_mps: f64,
}

impl ZuptVelocity {
    fn residual<const N: usize>(&self, v: &WindowVars<'_, N>) -> Result<[f64; 3], Error> {
        let kf = v.window.get(self.k).ok_or(Error::NotEnoughData)?;
        Ok(core::array::from_fn(|i| kf.state.v_wb[i] / self.sigma_mps))
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for ZuptVelocity {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let r = self.residual(v)?;
        let c = v.col(Block::Kf(self.k as u8))?;
        let j = diag(self.sigma_mps);
        sink(&mut ne, &r, &[JacobianBlock::new(c + 6, 3, &j)])
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&self.residual(v)?, out)
    }
}

/// No motion from keyframe `k - 1` to `k`: `(p_k - p_{k-1}) / sigma_p`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZuptPosition {
    /// Position of the later keyframe (`>= 1`).
    pub k: usize,
    /// Position standard deviation, m.
    pub sigma_m: f64,
}

impl ZuptPosition {
    fn residual<const N: usize>(&self, v: &WindowVars<'_, N>) -> Result<[f64; 3], Error> {
        let (prev, kf) = pair(v, self.k)?;
        let dp = kf.state.p_wb - prev.state.p_wb;
        Ok(core::array::from_fn(|i| dp[i] / self.sigma_m))
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for ZuptPosition {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let r = self.residual(v)?;
        let (cp, c) = (
            v.col(Block::Kf((self.k - 1) as u8))?,
            v.col(Block::Kf(self.k as u8))?,
        );
        let (jp, jm) = (diag(self.sigma_m), diag(-self.sigma_m));
        let blocks = [
            JacobianBlock::new(cp, 3, &jm),
            JacobianBlock::new(c, 3, &jp),
        ];
        sink(&mut ne, &r, &blocks)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&self.residual(v)?, out)
    }
}

/// No rotation from keyframe `k - 1` to `k`: `Log(R_{k-1}^T R_k) / sigma_theta`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZuptRotation {
    /// Position of the later keyframe (`>= 1`).
    pub k: usize,
    /// Rotation standard deviation, rad.
    pub sigma_rad: f64,
}

impl ZuptRotation {
    fn residual<const N: usize>(&self, v: &WindowVars<'_, N>) -> Result<(Vec3, [f64; 3]), Error> {
        let (prev, kf) = pair(v, self.k)?;
        let e = crate::math::log_so3(&(prev.state.q_wb.inverse() * kf.state.q_wb));
        Ok((e, core::array::from_fn(|i| e[i] / self.sigma_rad)))
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for ZuptRotation {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let (prev, kf) = pair(v, self.k)?;
        let (cp, c) = (
            v.col(Block::Kf((self.k - 1) as u8))?,
            v.col(Block::Kf(self.k as u8))?,
        );
        let (ra, rb) = (
            prev.state.q_wb.to_rotation_matrix().into_inner(),
            kf.state.q_wb.to_rotation_matrix().into_inner(),
        );
        let (e, r) = self.residual(v)?;
        let jr = jr_inv_so3(&e) / self.sigma_rad;
        let ja = -(jr * rb.transpose() * ra);
        let (mut a, mut b) = ([0.0; 9], [0.0; 9]);
        row_major(&ja, &mut a);
        row_major(&jr, &mut b);
        let blocks = [
            JacobianBlock::new(cp + 3, 3, &a),
            JacobianBlock::new(c + 3, 3, &b),
        ];
        sink(&mut ne, &r, &blocks)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&self.residual(v)?.1, out)
    }
}

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    /// IMU preintegration and delay random walk between consecutive keyframes (with
    /// [`FactorSet::Oldest`], only from position 0 to 1), added to `cost` factor by factor.
    pub(super) fn imu_factors(
        &self,
        v: &WindowVars<'_, N>,
        ne: &mut Option<&mut NormalEquations<D>>,
        cost: &mut f64,
    ) -> Result<(), Error> {
        let count = v.count;
        let last_pair = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        for k in 1..last_pair {
            let mut imu = ImuFactor {
                k,
                gravity_mps2: self.cfg.gravity_mps2,
            };
            *cost += imu.add(v, ne.as_deref_mut())?;
            if v.est_td {
                let rw_s_per_sqrt_s = self.cfg.td.rw_s_per_sqrt_s;
                let mut td = TdRandomWalkFactor { k, rw_s_per_sqrt_s };
                *cost += td.add(v, ne.as_deref_mut())?;
            }
        }
        Ok(())
    }

    /// The delay hold ([`Problem::td_hold`]): every keyframe's delay held at its value by a
    /// tight factor while too few landmarks estimate it, added to `cost` factor by factor.
    pub(super) fn td_hold_factors(
        &self,
        v: &WindowVars<'_, N>,
        ne: &mut Option<&mut NormalEquations<D>>,
        cost: &mut f64,
    ) -> Result<(), Error> {
        // Never in the marginalization: the hold is about this solve, not information.
        let hold = self
            .td_hold
            .filter(|_| v.est_td && self.set == FactorSet::All);
        if let Some(hold) = hold {
            for k in 0..v.count {
                let (Some(_), Some(&td0_s)) = (v.window.get(k), hold.get(k)) else {
                    continue;
                };
                *cost += TdHold { k, td0_s }.add(v, ne.as_deref_mut())?;
            }
        }
        Ok(())
    }

    /// Zero-velocity updates on the keyframes at rest (module docs); returns their cost.
    pub(super) fn zupt_factors(
        &self,
        v: &WindowVars<'_, N>,
        ne: &mut Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let count = v.count;
        let last = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        let sigma_mps = self.cfg.zupt.sigma_mps;
        let (sigma_m, sigma_rad) = (self.cfg.zupt.motion_sigma_m, self.cfg.zupt.motion_sigma_rad);
        let mut cost = 0.0;
        for k in 0..last {
            let kf = v.window.get(k).ok_or(Error::NotEnoughData)?;
            if !kf.at_rest {
                continue;
            }
            // The marginalization takes only what involves keyframe 0.
            if self.set == FactorSet::All || k == 0 {
                cost += ZuptVelocity { k, sigma_mps }.add(v, ne.as_deref_mut())?;
            }
            if k == 0 {
                continue;
            }
            cost += ZuptPosition { k, sigma_m }.add(v, ne.as_deref_mut())?;
            cost += ZuptRotation { k, sigma_rad }.add(v, ne.as_deref_mut())?;
        }
        Ok(cost)
    }
}

//! The window's factors on the keyframe states other than the priors and the visual ones: IMU
//! preintegration and the time-delay random walk between consecutive keyframes, zero-velocity
//! updates on keyframes the images show at rest, and the delay hold of a solve with too few
//! landmarks to estimate the delay.

use super::problem::{row_major, sink, FactorSet, Problem};
use super::window::Block;
use crate::factors::td::TdRandomWalk;
use crate::inertial::preintegration::{Mat15, Vec15};
use crate::math::jr_inv_so3;
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;

impl<const N: usize, const L: usize, const D: usize> Problem<'_, N, L, D> {
    /// IMU preintegration and delay random walk between consecutive keyframes (with
    /// [`FactorSet::Oldest`], only from position 0 to 1), added to `cost` factor by factor.
    pub(super) fn imu_factors(
        &self,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        cost: &mut f64,
    ) -> Result<(), Error> {
        let l = self.layout;
        let count = self.window.len();
        let last_pair = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        let g = self.cfg.gravity_mps2;
        let mut r = Vec15::zeros();
        let mut ji = Mat15::zeros();
        let mut jj = Mat15::zeros();
        for k in 1..last_pair {
            let (Some(a), Some(b)) = (self.window.get(k - 1), self.window.get(k)) else {
                return Err(Error::NotEnoughData);
            };
            let pre = b.preint().ok_or(Error::NotEnoughData)?;
            if ne.is_none() {
                r = pre.residual_whitened(&a.state, &b.state, g)?;
                *cost += sink(ne, r.as_slice(), &[])?;
                if est_td {
                    let dt = pre.dt_s().max(1e-3);
                    let q = self.cfg.td_rw_s_per_sqrt_s * self.cfg.td_rw_s_per_sqrt_s;
                    let (rt, _) = TdRandomWalk::new(q, dt)?.evaluate(a.td_s, b.td_s)?;
                    *cost += sink(ne, &[rt], &[])?;
                }
                continue;
            }
            pre.evaluate(&a.state, &b.state, g, &mut r, &mut ji, &mut jj)?;
            let (ca, cb) = (
                l.col(Block::Kf((k - 1) as u8))
                    .ok_or(Error::DimensionMismatch)?,
                l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch)?,
            );
            let c: f64 = r.norm_squared();
            if !c.is_finite() {
                return Err(Error::NonFinite);
            }
            if let Some(ne) = ne.as_deref_mut() {
                ne.add_dense_pair(&r, &ji, &jj, ca, cb)?;
            }
            *cost += c;
            if est_td {
                let dt = pre.dt_s().max(1e-3);
                let q = self.cfg.td_rw_s_per_sqrt_s * self.cfg.td_rw_s_per_sqrt_s;
                let (rt, [da, db]) = TdRandomWalk::new(q, dt)?.evaluate(a.td_s, b.td_s)?;
                let (ta, tb) = (
                    l.col(Block::Td((k - 1) as u8))
                        .ok_or(Error::DimensionMismatch)?,
                    l.col(Block::Td(k as u8)).ok_or(Error::DimensionMismatch)?,
                );
                *cost += sink(
                    ne,
                    &[rt],
                    &[
                        JacobianBlock::new(ta, 1, &[da]),
                        JacobianBlock::new(tb, 1, &[db]),
                    ],
                )?;
            }
        }
        Ok(())
    }

    /// The delay hold ([`Problem::td_hold`]): every keyframe's delay held at its value by a
    /// tight factor while too few landmarks estimate it, added to `cost` factor by factor.
    pub(super) fn td_hold_factors(
        &self,
        ne: &mut Option<&mut NormalEquations<D>>,
        est_td: bool,
        cost: &mut f64,
    ) -> Result<(), Error> {
        let l = self.layout;
        let count = self.window.len();
        // Never in the marginalization: the hold is about this solve, not information.
        let hold = self
            .td_hold
            .filter(|_| est_td && self.set == FactorSet::All);
        if let Some(hold) = hold {
            // 1 us: the delay stays where it is while it cannot be estimated.
            const HOLD_S: f64 = 1e-6;
            for k in 0..count {
                let (Some(kf), Some(t0)) = (self.window.get(k), hold.get(k)) else {
                    continue;
                };
                let c = l.col(Block::Td(k as u8)).ok_or(Error::DimensionMismatch)?;
                let r = (kf.td_s - t0) / HOLD_S;
                *cost += sink(ne, &[r], &[JacobianBlock::new(c, 1, &[1.0 / HOLD_S])])?;
            }
        }
        Ok(())
    }

    /// Zero-velocity updates (keyframes the images show at rest): `v_k / sigma_v` on every such
    /// keyframe and, with the previous one, `(p_k - p_{k-1}) / sigma_p` and
    /// `Log(R_{k-1}^T R_k) / sigma_theta`. Right perturbations: with `e = Log(R_a^T R_b)`,
    /// `de/dtheta_b = Jr^-1(e)` and `de/dtheta_a = -Jr^-1(e) R_b^T R_a`.
    pub(super) fn zupt_factors(
        &self,
        ne: &mut Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let l = &self.layout;
        let count = self.window.len();
        let last = if self.set == FactorSet::Oldest {
            2.min(count)
        } else {
            count
        };
        let sv = self.cfg.zupt_sigma_mps;
        let (sp, sr) = self.cfg.zupt_motion_sigma;
        let diag = |s: f64| {
            let mut m = [0.0; 9];
            for i in 0..3 {
                if let Some(x) = m.get_mut(i * 4) {
                    *x = 1.0 / s;
                }
            }
            m
        };
        let mut cost = 0.0;
        for k in 0..last {
            let kf = self.window.get(k).ok_or(Error::NotEnoughData)?;
            if !kf.at_rest {
                continue;
            }
            let c = l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch)?;
            // The marginalization takes only what involves keyframe 0.
            if self.set == FactorSet::All || k == 0 {
                let r: [f64; 3] = core::array::from_fn(|i| kf.state.v_wb[i] / sv);
                cost += sink(ne, &r, &[JacobianBlock::new(c + 6, 3, &diag(sv))])?;
            }
            let Some(prev) = k.checked_sub(1).and_then(|p| self.window.get(p)) else {
                continue;
            };
            let cp = l
                .col(Block::Kf((k - 1) as u8))
                .ok_or(Error::DimensionMismatch)?;
            let dp = kf.state.p_wb - prev.state.p_wb;
            let r: [f64; 3] = core::array::from_fn(|i| dp[i] / sp);
            let jp = diag(sp);
            let jm = diag(-sp);
            cost += sink(
                ne,
                &r,
                &[
                    JacobianBlock::new(cp, 3, &jm),
                    JacobianBlock::new(c, 3, &jp),
                ],
            )?;
            let (ra, rb) = (
                prev.state.q_wb.to_rotation_matrix().into_inner(),
                kf.state.q_wb.to_rotation_matrix().into_inner(),
            );
            let e = crate::math::log_so3(&(prev.state.q_wb.inverse() * kf.state.q_wb));
            let jr = jr_inv_so3(&e) / sr;
            let ja = -(jr * rb.transpose() * ra);
            let r: [f64; 3] = core::array::from_fn(|i| e[i] / sr);
            let (mut a, mut b) = ([0.0; 9], [0.0; 9]);
            row_major(&ja, &mut a);
            row_major(&jr, &mut b);
            cost += sink(
                ne,
                &r,
                &[
                    JacobianBlock::new(cp + 3, 3, &a),
                    JacobianBlock::new(c + 3, 3, &b),
                ],
            )?;
        }
        Ok(cost)
    }
}

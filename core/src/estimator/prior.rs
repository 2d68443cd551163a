//! The marginalization prior in square-root form, `r = r0 + J0 (x [-] x0)`, over a list of state
//! blocks at fixed linearization points `x0`.
//!
//! `x [-] x0` per block: keyframe `[p - p0, Log(R0^T R), v - v0, bg - bg0, ba - ba0]`, extrinsic
//! `[p - p0, Log(R0^T R)]`, delay `td - td0`, matching the right-perturbation error states.

use super::window::{Block, Layout};
use crate::camera::CameraExtrinsic;
use crate::inertial::NavState;
use crate::math::{jr_inv_so3, log_so3, Vec3};
use crate::solver::{add_prior, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;

/// Linearization point of one prior block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinPoint {
    /// A keyframe state.
    Kf(NavState),
    /// The extrinsic.
    Ext(CameraExtrinsic),
    /// A time delay, s.
    Td(f64),
}

/// Error of a keyframe state w.r.t. a linearization point, written into `out[..15]`.
pub fn kf_minus(x: &NavState, x0: &NavState, out: &mut [f64]) {
    let th = log_so3(&(x0.q_wb.inverse() * x.q_wb));
    let parts = [
        x.p_wb - x0.p_wb,
        th,
        x.v_wb - x0.v_wb,
        x.bg - x0.bg,
        x.ba - x0.ba,
    ];
    for (chunk, v) in out.chunks_mut(3).zip(parts.iter()) {
        for (o, e) in chunk.iter_mut().zip(v.iter()) {
            *o = *e;
        }
    }
}

/// Error of an extrinsic w.r.t. a linearization point, written into `out[..6]`.
pub fn ext_minus(x: &CameraExtrinsic, x0: &CameraExtrinsic, out: &mut [f64]) {
    let th = log_so3(&(x0.q_bc.inverse() * x.q_bc));
    let parts = [x.p_bc - x0.p_bc, th];
    for (chunk, v) in out.chunks_mut(3).zip(parts.iter()) {
        for (o, e) in chunk.iter_mut().zip(v.iter()) {
            *o = *e;
        }
    }
}

/// Most blocks a prior can span (`2 N + 1` for a window of `N`).
pub const MAX_PRIOR_BLOCKS: usize = 64;

/// The square-root marginalization prior of a window of `N` keyframes, capacity `D` dimensions.
#[derive(Clone)]
pub struct MargPrior<const D: usize, const N: usize> {
    /// `J0` (upper triangular, rows/columns `0..dim`).
    pub j0: [[f64; D]; D],
    /// `r0`.
    pub r0: [f64; D],
    /// `J0` with its rotation columns mapped through `Jr^-1` of the current rotation error
    /// (scratch of [`MargPrior::add_to`]).
    j_eff: [[f64; D]; D],
    /// Blocks in prior order with their linearization points.
    pub blocks: HVec<(Block, LinPoint), MAX_PRIOR_BLOCKS>,
    dim: usize,
}

impl<const D: usize, const N: usize> Default for MargPrior<D, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const D: usize, const N: usize> MargPrior<D, N> {
    /// No prior.
    pub const fn new() -> Self {
        MargPrior {
            j0: [[0.0; D]; D],
            r0: [0.0; D],
            j_eff: [[0.0; D]; D],
            blocks: HVec::new(),
            dim: 0,
        }
    }

    /// Dimension (0 = inactive).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Drops the prior.
    pub fn clear(&mut self) {
        self.dim = 0;
        self.blocks.clear();
    }

    /// Sets the dimension after `j0`, `r0` and `blocks` were written.
    pub fn set_dim(&mut self, dim: usize) -> Result<(), Error> {
        let total: usize = self.blocks.iter().map(|(b, _)| b.dim()).sum();
        if dim > D || total != dim {
            return Err(Error::DimensionMismatch);
        }
        self.dim = dim;
        Ok(())
    }

    /// Renames every block after the oldest keyframe left the window (positions shift by one).
    /// Fails if the prior still refers to position 0.
    pub fn shift_positions(&mut self) -> Result<(), Error> {
        for (b, _) in self.blocks.iter_mut() {
            *b = match *b {
                Block::Kf(0) | Block::Td(0) => return Err(Error::Degenerate),
                Block::Kf(k) => Block::Kf(k - 1),
                Block::Td(k) => Block::Td(k - 1),
                Block::Ext => Block::Ext,
            };
        }
        Ok(())
    }

    /// Computes `dx = x [-] x0` block by block with the current state given by `current`,
    /// and the column of each prior entry in `layout`, then adds `r0 + J0 dx` to `ne` (or only
    /// its cost when `ne` is `None`). Returns the prior's cost `|r|^2`.
    ///
    /// The rotation part of `dx` is `Log(R0^T R)`, whose derivative w.r.t. the right
    /// perturbation of `R` is `Jr^-1(Log(R0^T R))`: the Jacobian added is `J0` with those columns
    /// multiplied by it, so the gradient stays exact when the window rotates away from the
    /// linearization point (a yaw drift of the gauge, for instance).
    pub fn add_to(
        &mut self,
        layout: &Layout<N>,
        current: impl Fn(Block) -> Option<LinPoint>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        if self.dim == 0 {
            return Ok(0.0);
        }
        let mut dx = [0.0; D];
        let mut cols = [0usize; D];
        let mut at = 0;
        for (b, lin) in self.blocks.iter() {
            let w = b.dim();
            let c0 = layout.col(*b).ok_or(Error::DimensionMismatch)?;
            let out = dx.get_mut(at..at + w).ok_or(Error::DimensionMismatch)?;
            match (current(*b), lin) {
                (Some(LinPoint::Kf(x)), LinPoint::Kf(x0)) => kf_minus(&x, x0, out),
                (Some(LinPoint::Ext(x)), LinPoint::Ext(x0)) => ext_minus(&x, x0, out),
                (Some(LinPoint::Td(x)), LinPoint::Td(x0)) => {
                    if let Some(o) = out.first_mut() {
                        *o = x - x0;
                    }
                }
                _ => return Err(Error::DimensionMismatch),
            }
            for (i, c) in cols
                .get_mut(at..at + w)
                .ok_or(Error::DimensionMismatch)?
                .iter_mut()
                .enumerate()
            {
                *c = c0 + i;
            }
            at += w;
        }
        let p = self.dim;
        let (dx, cols, r0) = (
            dx.get(..p).ok_or(Error::DimensionMismatch)?,
            cols.get(..p).ok_or(Error::DimensionMismatch)?,
            self.r0.get(..p).ok_or(Error::DimensionMismatch)?,
        );
        match ne {
            Some(ne) => {
                // Rotation columns of J0 times Jr^-1 of their block's rotation error.
                for (row_eff, row) in self.j_eff.iter_mut().zip(self.j0.iter()).take(p) {
                    row_eff.copy_from_slice(row);
                }
                let mut at = 0;
                for (b, _) in self.blocks.iter() {
                    let rot = match b {
                        Block::Kf(_) | Block::Ext => Some(at + 3),
                        Block::Td(_) => None,
                    };
                    if let Some(c) = rot {
                        let th = Vec3::new(
                            dx.get(c).copied().unwrap_or(0.0),
                            dx.get(c + 1).copied().unwrap_or(0.0),
                            dx.get(c + 2).copied().unwrap_or(0.0),
                        );
                        let m = jr_inv_so3(&th);
                        for (row_eff, row) in self.j_eff.iter_mut().zip(self.j0.iter()).take(p) {
                            let (Some(src), Some(dst)) =
                                (row.get(c..c + 3), row_eff.get_mut(c..c + 3))
                            else {
                                continue;
                            };
                            for (k, d) in dst.iter_mut().enumerate() {
                                *d = src[0] * m[(0, k)] + src[1] * m[(1, k)] + src[2] * m[(2, k)];
                            }
                        }
                    }
                    at += b.dim();
                }
                let before = ne.cost;
                // r = r0 + J0 dx, linearized with the mapped Jacobian: add_prior forms the
                // residual from its matrix, so pass the residual's offset explicitly.
                let mut r_lin = [0.0; D];
                for ((ri, row), (row_eff, r0i)) in r_lin
                    .iter_mut()
                    .zip(self.j0.iter())
                    .zip(self.j_eff.iter().zip(r0))
                    .take(p)
                {
                    let r_true = r0i + row.iter().zip(dx).map(|(j, d)| j * d).sum::<f64>();
                    let r_eff = row_eff.iter().zip(dx).map(|(j, d)| j * d).sum::<f64>();
                    *ri = r_true - r_eff;
                }
                let r_lin = r_lin.get(..p).ok_or(Error::DimensionMismatch)?;
                add_prior(ne, &self.j_eff, r_lin, dx, cols)?;
                Ok(ne.cost - before)
            }
            None => {
                let mut cost = 0.0;
                for (row, r0i) in self.j0.iter().zip(r0) {
                    let ri = r0i + row.iter().zip(dx).map(|(j, d)| j * d).sum::<f64>();
                    cost += ri * ri;
                }
                Ok(cost)
            }
        }
    }
}

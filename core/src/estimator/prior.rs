//! The marginalization prior in square-root form, `r = r0 + J0 (x [-] x0)`, over a list of state
//! blocks at fixed linearization points `x0`.
//!
//! `x [-] x0` per block: keyframe `[p - p0, Log(R0^T R), v - v0, bg - bg0, ba - ba0]`, extrinsic
//! `[p - p0, Log(R0^T R)]`, delay `td - td0`, matching the right-perturbation error states.

use super::window::{Block, Layout};
use crate::camera::CameraExtrinsic;
use crate::inertial::NavState;
use crate::math::{jr_inv_so3, log_so3, Vec3};
use crate::solver::NormalEquations;
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
    /// `H0 = J0^T J0` (full symmetric), `g0 = J0^T r0`, `c0 = r0^T r0`: the prior's quadratic
    /// model, so that evaluating it costs `O(p^2)` instead of `O(p^3)`.
    h0: [[f64; D]; D],
    g0: [f64; D],
    c0: f64,
    /// Scratch of [`MargPrior::add_to`]: `H0` mapped through `Jr^-1` on rotation blocks.
    h_eff: [[f64; D]; D],
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
            h0: [[0.0; D]; D],
            g0: [0.0; D],
            c0: 0.0,
            h_eff: [[0.0; D]; D],
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

    /// Back to the state [`MargPrior::new`] builds (every buffer zeroed), in place.
    pub fn reset_to_new(&mut self) {
        self.clear();
        for row in self
            .j0
            .iter_mut()
            .chain(self.h0.iter_mut())
            .chain(self.h_eff.iter_mut())
        {
            row.fill(0.0);
        }
        self.r0.fill(0.0);
        self.g0.fill(0.0);
        self.c0 = 0.0;
    }

    /// Activates the prior after `j0`, `r0` and `blocks` were written, with `h_star` the
    /// marginal system they came from (`J0^T J0 = H*`, `J0^T r0 = -b*`, upper triangle of `H*`).
    pub fn set_dim(&mut self, dim: usize, h_star: &NormalEquations<D>) -> Result<(), Error> {
        let total: usize = self.blocks.iter().map(|(b, _)| b.dim()).sum();
        if dim > D || total != dim || h_star.dim() != dim {
            return Err(Error::DimensionMismatch);
        }
        for i in 0..dim {
            for j in i..dim {
                let v = h_star
                    .h
                    .get(i)
                    .and_then(|r| r.get(j))
                    .copied()
                    .unwrap_or(0.0);
                if let Some(x) = self.h0.get_mut(i).and_then(|r| r.get_mut(j)) {
                    *x = v;
                }
                if let Some(x) = self.h0.get_mut(j).and_then(|r| r.get_mut(i)) {
                    *x = v;
                }
            }
        }
        for (g, b) in self.g0.iter_mut().zip(h_star.b.iter()).take(dim) {
            *g = -b;
        }
        self.c0 = self.r0.iter().take(dim).map(|r| r * r).sum();
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
    /// and the column of each prior entry in `layout`, then adds the residual `r0 + J0 dx` to
    /// `ne` (or only its cost when `ne` is `None`), through its quadratic model
    /// (`H0`, `g0`, `c0`): `O(p^2)`. Returns the prior's cost `|r|^2`.
    ///
    /// The rotation part of `dx` is `Log(R0^T R)`, whose derivative w.r.t. the right
    /// perturbation of `R` is `Jr^-1(Log(R0^T R))`: the system added is `M^T H0 M` with those
    /// blocks of `M` equal to it, so the gradient stays exact when the window rotates away from
    /// the linearization point (a yaw drift of the gauge, for instance).
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
        let (dx, cols) = (
            dx.get(..p).ok_or(Error::DimensionMismatch)?,
            cols.get(..p).ok_or(Error::DimensionMismatch)?,
        );
        // |r0 + J0 dx|^2 = c0 + dx . (g0 + q) with q = g0 + H0 dx; the gradient w.r.t. dx is 2 q.
        let mut q = [0.0; D];
        for ((qi, row), gi) in q.iter_mut().zip(self.h0.iter()).zip(self.g0.iter()).take(p) {
            *qi = gi + row.iter().zip(dx).map(|(h, d)| h * d).sum::<f64>();
        }
        let cost = self.c0
            + dx.iter()
                .zip(q.iter().zip(self.g0.iter()))
                .map(|(d, (qi, gi))| d * (gi + qi))
                .sum::<f64>();
        if !cost.is_finite() {
            return Err(Error::NonFinite);
        }
        let Some(ne) = ne else { return Ok(cost) };
        if cols.iter().any(|&c| c >= ne.dim()) {
            return Err(Error::DimensionMismatch);
        }
        // Mapped system M^T H0 M, -M^T q, with M = I except Jr^-1 on the rotation blocks.
        for (row_eff, row) in self.h_eff.iter_mut().zip(self.h0.iter()).take(p) {
            if let (Some(dst), Some(src)) = (row_eff.get_mut(..p), row.get(..p)) {
                dst.copy_from_slice(src);
            }
        }
        let mut b_eff = [0.0; D];
        for (be, qi) in b_eff.iter_mut().zip(q.iter()).take(p) {
            *be = -qi;
        }
        let mut at = 0;
        for (blk, _) in self.blocks.iter() {
            let c = at + 3;
            at += blk.dim();
            if matches!(blk, Block::Td(_)) {
                continue;
            }
            let th = Vec3::new(
                dx.get(c).copied().unwrap_or(0.0),
                dx.get(c + 1).copied().unwrap_or(0.0),
                dx.get(c + 2).copied().unwrap_or(0.0),
            );
            let m = jr_inv_so3(&th);
            for row in self.h_eff.iter_mut().take(p) {
                if let Some(v) = row.get_mut(c..c + 3) {
                    let x = [v[0], v[1], v[2]];
                    for (k, o) in v.iter_mut().enumerate() {
                        *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                    }
                }
            }
            for j in 0..p {
                let x: [f64; 3] = core::array::from_fn(|i| {
                    self.h_eff
                        .get(c + i)
                        .and_then(|r| r.get(j))
                        .copied()
                        .unwrap_or(0.0)
                });
                for k in 0..3 {
                    if let Some(o) = self.h_eff.get_mut(c + k).and_then(|r| r.get_mut(j)) {
                        *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                    }
                }
            }
            if let Some(v) = b_eff.get_mut(c..c + 3) {
                let x = [v[0], v[1], v[2]];
                for (k, o) in v.iter_mut().enumerate() {
                    *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                }
            }
        }
        if !b_eff.iter().take(p).all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        // The prior's columns are runs of consecutive state columns (whole blocks, in layout
        // order), so each row is added run by run as contiguous slices.
        let mut runs: HVec<(usize, usize), MAX_PRIOR_BLOCKS> = HVec::new();
        let mut start = 0;
        for k in 1..=p {
            let breaks = k == p || cols.get(k).copied() != cols.get(k - 1).map(|c| c + 1);
            if breaks {
                runs.push((start, k)).map_err(|_| Error::CapacityExceeded)?;
                start = k;
            }
        }
        let ascending = cols.windows(2).all(|w| w[0] < w[1]);
        for (i, (&ci, row)) in cols.iter().zip(self.h_eff.iter()).enumerate() {
            if let Some(b) = ne.b.get_mut(ci) {
                *b += b_eff.get(i).copied().unwrap_or(0.0);
            }
            if !ascending {
                for (&cj, &v) in cols.iter().zip(row.iter()).skip(i) {
                    let (r, c) = if ci <= cj { (ci, cj) } else { (cj, ci) };
                    if let Some(h) = ne.h.get_mut(r).and_then(|h| h.get_mut(c)) {
                        *h += v;
                    }
                }
                continue;
            }
            let Some(hrow) = ne.h.get_mut(ci) else {
                continue;
            };
            for &(a, b) in runs.iter() {
                if b <= i {
                    continue;
                }
                let a = a.max(i);
                let Some(&c0) = cols.get(a) else { continue };
                if let (Some(dst), Some(src)) = (hrow.get_mut(c0..c0 + (b - a)), row.get(a..b)) {
                    for (h, v) in dst.iter_mut().zip(src) {
                        *h += v;
                    }
                }
            }
        }
        ne.cost += cost;
        Ok(cost)
    }
}

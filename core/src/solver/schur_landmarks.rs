//! Schur elimination of one landmark's scalar parameter (inverse depth `tau`) for the
//! conventional inverse-depth bundle-adjustment mode.
//!
//! For a landmark with Jacobians `J_p` (pose states) and `j_l` (its inverse depth), the joint
//! normal equations are
//!
//! ```text
//! [ H_pp  H_pl ] [dx  ]   [ b_p ]      H_ll = sum j_l^T j_l,  H_lp = sum j_l^T J_p,
//! [ H_lp  H_ll ] [dtau] = [ b_l ],     b_l  = -sum j_l^T r.
//! ```
//!
//! `H_pp`, `b_p` go straight into the [`NormalEquations`]; this struct keeps `H_ll`, `b_l` and the
//! sparse row `H_lp` (at most `P` touched pose columns). Eliminating `dtau`:
//!
//! ```text
//! H_pp -= H_pl H_lp / H_ll,   b_p -= H_pl b_l / H_ll,   dtau = (b_l - H_lp dx) / H_ll.
//! ```
//!
//! By Cauchy-Schwarz `|H_lp,j|^2 <= H_ll (H_pp)_jj`, so the update stays bounded however small
//! `H_ll > 0` is; only `H_ll == 0` (a landmark whose depth no residual sees, hence `H_lp == 0`)
//! is skipped. An optional Levenberg-Marquardt damping `lambda` uses `H_ll (1 + lambda)`.
//!
//! Inside [`crate::solver::LmProblem`]: `linearize` accumulates and folds every landmark (keeping
//! the accumulators), the driver damps and solves the reduced pose system, and `apply` recovers
//! each `dtau` with [`LandmarkSchur::back_substitute`] before updating the inverse depths.

use super::normal_equations::{all_finite, JacobianBlock, NormalEquations};
use crate::Error;

/// Widest pose block [`LandmarkSchur::add_residual`] takes (a keyframe state is 15).
pub const MAX_BLOCK_WIDTH: usize = 16;

/// Where a Jacobian block's columns are stored in the accumulator.
#[derive(Debug, Clone, Copy)]
enum Slot {
    /// Contiguously from this index.
    Existing(usize),
    /// Not yet: appended contiguously.
    New,
    /// Some columns present, not as one run: per-column search.
    Partial,
}

/// Accumulator of one landmark's `H_ll`, `b_l` and sparse `H_lp` over at most `P` pose columns.
#[derive(Debug, Clone)]
pub struct LandmarkSchur<const P: usize> {
    h_ll: f64,
    b_l: f64,
    cols: [usize; P],
    h_lp: [f64; P],
    len: usize,
}

impl<const P: usize> Default for LandmarkSchur<P> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const P: usize> LandmarkSchur<P> {
    /// Empty accumulator.
    pub const fn new() -> Self {
        Self {
            h_ll: 0.0,
            b_l: 0.0,
            cols: [0; P],
            h_lp: [0.0; P],
            len: 0,
        }
    }

    /// Back to the state [`LandmarkSchur::new`] builds (every buffer zeroed), in place.
    pub fn reset_to_new(&mut self) {
        self.clear();
        self.cols.fill(0);
        self.h_lp.fill(0.0);
    }

    /// Forgets everything (next landmark).
    pub fn clear(&mut self) {
        self.h_ll = 0.0;
        self.b_l = 0.0;
        self.len = 0;
    }

    /// `H_ll` accumulated so far.
    pub fn h_ll(&self) -> f64 {
        self.h_ll
    }

    /// `b_l` accumulated so far.
    pub fn b_l(&self) -> f64 {
        self.b_l
    }

    /// Touched pose columns and their `H_lp` entries.
    pub fn coupling(&self) -> (&[usize], &[f64]) {
        (
            self.cols.get(..self.len).unwrap_or(&[]),
            self.h_lp.get(..self.len).unwrap_or(&[]),
        )
    }

    fn find(&self, col: usize) -> Option<usize> {
        self.cols.iter().take(self.len).position(|&c| c == col)
    }

    /// Adds one residual `r` of this landmark: the pose part (`pose_blocks`, as in
    /// [`NormalEquations::add_blocks`]) goes into `ne` (with the cost), the inverse-depth column
    /// `j_l` (`r.len()` entries) into this accumulator. Nothing is accumulated on `Err`.
    pub fn add_residual<const D: usize>(
        &mut self,
        ne: &mut NormalEquations<D>,
        r: &[f64],
        pose_blocks: &[JacobianBlock<'_>],
        j_l: &[f64],
    ) -> Result<(), Error> {
        if j_l.len() != r.len() || pose_blocks.iter().any(|b| b.width > MAX_BLOCK_WIDTH) {
            return Err(Error::DimensionMismatch);
        }
        if !all_finite(j_l) {
            return Err(Error::NonFinite);
        }
        // Where each block's columns live: a block seen before sits contiguously from the index
        // of its first column (blocks are inserted whole); a new block is appended whole. Only a
        // block that partly overlaps earlier ones needs the per-column search.
        let mut new_cols = 0usize;
        for blk in pose_blocks {
            match self.block_start(blk.col, blk.width) {
                Slot::Existing(_) => {}
                Slot::New => new_cols += blk.width,
                Slot::Partial => {
                    new_cols += (blk.col..blk.col.saturating_add(blk.width))
                        .filter(|&c| self.find(c).is_none())
                        .count();
                }
            }
        }
        if self.len + new_cols > P {
            return Err(Error::CapacityExceeded);
        }
        ne.add_blocks(r, pose_blocks)?;
        for (&jl, &ri) in j_l.iter().zip(r) {
            self.h_ll += jl * jl;
            self.b_l -= jl * ri;
        }
        for blk in pose_blocks {
            // H_lp,col = sum_rows j_l[row] * J[row][i]
            let mut v = [0.0; MAX_BLOCK_WIDTH];
            for (i, vi) in v.iter_mut().enumerate().take(blk.width) {
                *vi = j_l
                    .iter()
                    .enumerate()
                    .map(|(row, jl)| jl * blk.jac.get(row * blk.width + i).copied().unwrap_or(0.0))
                    .sum();
            }
            self.add_h_lp(blk.col, v.get(..blk.width).unwrap_or(&[]));
        }
        Ok(())
    }

    /// [`Self::add_residual`] for the commonest residual: two rows over two 6-wide pose blocks
    /// (an inverse-depth reprojection without time-delay or extrinsic columns), accumulated
    /// with [`NormalEquations::add_2x6_blocks`].
    pub fn add_residual_2x6<const D: usize>(
        &mut self,
        ne: &mut NormalEquations<D>,
        r: &nalgebra::Vector2<f64>,
        jacs: &[nalgebra::Matrix2x6<f64>; 2],
        cols: [usize; 2],
        j_l: &nalgebra::Vector2<f64>,
    ) -> Result<(), Error> {
        if !j_l.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        let new_cols: usize = cols
            .iter()
            .map(|&c| match self.block_start(c, 6) {
                Slot::Existing(_) => 0,
                Slot::New => 6,
                Slot::Partial => (c..c + 6).filter(|&k| self.find(k).is_none()).count(),
            })
            .sum();
        if self.len + new_cols > P {
            return Err(Error::CapacityExceeded);
        }
        ne.add_2x6_blocks(r, jacs, &cols)?;
        self.h_ll += j_l.x * j_l.x + j_l.y * j_l.y;
        self.b_l -= j_l.x * r.x + j_l.y * r.y;
        for (jac, &c) in jacs.iter().zip(cols.iter()) {
            let v: [f64; 6] = core::array::from_fn(|i| j_l.x * jac[(0, i)] + j_l.y * jac[(1, i)]);
            self.add_h_lp(c, &v);
        }
        Ok(())
    }

    /// `H_lp[col + i] += v[i]`, appending the columns this landmark has not touched yet (the
    /// caller checked the capacity).
    fn add_h_lp(&mut self, col0: usize, v: &[f64]) {
        let slot = self.block_start(col0, v.len());
        for (i, &vi) in v.iter().enumerate() {
            let col = col0 + i;
            let found = match slot {
                Slot::Existing(start) => Some(start + i),
                Slot::New => None,
                Slot::Partial => self.find(col),
            };
            let idx = match found {
                Some(idx) => idx,
                None => {
                    let idx = self.len;
                    if let Some(c) = self.cols.get_mut(idx) {
                        *c = col;
                    }
                    if let Some(h) = self.h_lp.get_mut(idx) {
                        *h = 0.0;
                    }
                    self.len += 1;
                    idx
                }
            };
            if let Some(h) = self.h_lp.get_mut(idx) {
                *h += vi;
            }
        }
    }

    /// Where the columns `col..col + width` are stored (see [`Self::add_residual`]).
    fn block_start(&self, col: usize, width: usize) -> Slot {
        if width == 0 {
            return Slot::Existing(0);
        }
        let last = col.saturating_add(width - 1);
        match self.find(col) {
            Some(start) if self.cols.get(start + width - 1) == Some(&last) => Slot::Existing(start),
            Some(_) => Slot::Partial,
            None if self.find(last).is_none() => Slot::New,
            None => Slot::Partial,
        }
    }

    fn effective_h_ll(&self, lambda: f64) -> Option<f64> {
        let h = self.h_ll * (1.0 + lambda);
        (h > 0.0 && h.is_finite()).then_some(h)
    }

    /// Eliminates the inverse depth from `ne`: `H -= H_pl H_lp / H_ll`, `b -= H_pl b_l / H_ll`
    /// (upper triangle only), with `H_ll` damped by `(1 + lambda)`. Returns `Ok(false)` and
    /// changes nothing when `H_ll == 0` (the depth is unobserved and decoupled).
    pub fn fold_into<const D: usize>(
        &self,
        ne: &mut NormalEquations<D>,
        lambda: f64,
    ) -> Result<bool, Error> {
        if !(lambda.is_finite() && lambda >= 0.0) {
            return Err(Error::InvalidConfig);
        }
        let (cols, h_lp) = self.coupling();
        if cols.iter().any(|&c| c >= ne.dim()) {
            return Err(Error::DimensionMismatch);
        }
        let Some(h_ll) = self.effective_h_ll(lambda) else {
            return Ok(false);
        };
        for (&ca, &ha) in cols.iter().zip(h_lp) {
            let f = ha / h_ll;
            if let Some(b) = ne.b.get_mut(ca) {
                *b -= f * self.b_l;
            }
            let Some(hrow) = ne.h.get_mut(ca) else {
                continue;
            };
            for (&cb, &hb) in cols.iter().zip(h_lp) {
                if ca <= cb {
                    if let Some(v) = hrow.get_mut(cb) {
                        *v -= f * hb;
                    }
                }
            }
        }
        Ok(true)
    }

    /// Inverse-depth step `dtau = (b_l - H_lp dx) / (H_ll (1 + lambda))` from the solved pose
    /// step `dx` (indexed by state); 0 for an unobserved depth.
    pub fn back_substitute(&self, dx: &[f64], lambda: f64) -> Result<f64, Error> {
        let (cols, h_lp) = self.coupling();
        let mut acc = self.b_l;
        for (&c, &h) in cols.iter().zip(h_lp) {
            acc -= h * dx.get(c).copied().ok_or(Error::DimensionMismatch)?;
        }
        Ok(match self.effective_h_ll(lambda) {
            Some(h_ll) => acc / h_ll,
            None => 0.0,
        })
    }
}

//! Dense normal equations `H dx = b` of a least-squares problem, assembled residual by residual.
//!
//! Each (whitened) residual `r` (m rows) with Jacobian `J` over some state columns adds
//! `H += J^T J`, `b -= J^T r`, `cost += r^T r`. With that sign of `b` the Gauss-Newton step is the
//! solution of `H dx = b` (see the module docs of [`crate::solver`]).
//!
//! Only the upper triangle `h[i][j]`, `i <= j`, of the active `n x n` block is accumulated: a
//! Jacobian entry pair `(a, b)` whose state columns satisfy `cols[a] <= cols[b]` lands in
//! `h[cols[a]][cols[b]]`, the mirrored pair is skipped. Duplicate columns are therefore handled
//! correctly (both orders land on the diagonal). Entries outside the active block and below the
//! diagonal are never read; [`NormalEquations::symmetrize`] mirrors the triangle when a full
//! matrix is needed.
//!
//! Every `add_*` validates shapes, indices and finiteness of everything it was given *before*
//! touching the accumulators: on `Err` nothing has been added.

use crate::Error;

/// One contiguous block of a residual Jacobian: columns `col .. col + width` of the state,
/// `jac` row-major `m x width` (`m` = residual dimension).
#[derive(Debug, Clone, Copy)]
pub struct JacobianBlock<'a> {
    /// First state index of the block.
    pub col: usize,
    /// Number of state columns of the block.
    pub width: usize,
    /// Row-major `m x width` Jacobian entries.
    pub jac: &'a [f64],
}

impl<'a> JacobianBlock<'a> {
    /// Block over states `col .. col + width` with the row-major `m x width` entries `jac`.
    pub const fn new(col: usize, width: usize, jac: &'a [f64]) -> Self {
        Self { col, width, jac }
    }

    fn row(&self, row: usize) -> &'a [f64] {
        let start = row.saturating_mul(self.width);
        self.jac
            .get(start..start.saturating_add(self.width))
            .unwrap_or(&[])
    }
}

/// Caller-owned dense normal equations of capacity `D` with active dimension `n <= D`.
///
/// `h` holds the upper triangle of `H = sum J^T J`, `b = -sum J^T r`, `cost = sum r^T r`.
/// About `8 D^2` bytes: construct it in place (`Box::new(NormalEquations::new())` on the host, a
/// `static` on a microcontroller), never by value on a small stack.
/// `Clone` copies by value (a `D x D` temporary): for big `D` prefer copying into an existing
/// buffer (e.g. [`NormalEquations::copy_from`]).
#[derive(Clone)]
pub struct NormalEquations<const D: usize> {
    /// Upper triangle of `H` (rows/columns `0..n` are active).
    pub h: [[f64; D]; D],
    /// Right-hand side `b = -J^T r` (entries `0..n` are active).
    pub b: [f64; D],
    /// Sum of squared residuals accumulated so far.
    pub cost: f64,
    n: usize,
}

impl<const D: usize> Default for NormalEquations<D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const D: usize> NormalEquations<D> {
    /// All-zero system of dimension 0. `const` so it can initialize a `static` (placed in `.bss`).
    pub const fn new() -> Self {
        Self {
            h: [[0.0; D]; D],
            b: [0.0; D],
            cost: 0.0,
            n: 0,
        }
    }

    /// Back to the state [`NormalEquations::new`] builds (every entry zeroed, dimension 0), in
    /// place.
    pub fn reset_to_new(&mut self) {
        for row in self.h.iter_mut() {
            row.fill(0.0);
        }
        self.b.fill(0.0);
        self.cost = 0.0;
        self.n = 0;
    }

    /// Active dimension `n`.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Zeroes the active `n x n` block, `b` and the cost and sets the dimension to `n`.
    pub fn reset(&mut self, n: usize) -> Result<(), Error> {
        if n > D {
            return Err(Error::CapacityExceeded);
        }
        self.n = n;
        for row in self.h.iter_mut().take(n) {
            for v in row.iter_mut().take(n) {
                *v = 0.0;
            }
        }
        for v in self.b.iter_mut().take(n) {
            *v = 0.0;
        }
        self.cost = 0.0;
        Ok(())
    }

    /// Copies the active upper triangle, `b`, the cost and the dimension of `other`.
    pub fn copy_from(&mut self, other: &Self) {
        let n = other.n.min(D);
        for (i, (dst, src)) in self.h.iter_mut().zip(other.h.iter()).enumerate().take(n) {
            if let (Some(dst), Some(src)) = (dst.get_mut(i..n), src.get(i..n)) {
                dst.copy_from_slice(src);
            }
        }
        if let (Some(dst), Some(src)) = (self.b.get_mut(..n), other.b.get(..n)) {
            dst.copy_from_slice(src);
        }
        self.cost = other.cost;
        self.n = n;
    }

    /// `H -= H_other`, `b -= b_other`, `cost -= cost_other` over the active upper triangle (both
    /// of the same dimension): takes back a part of the system assembled separately.
    pub fn subtract(&mut self, other: &Self) -> Result<(), Error> {
        let n = self.n;
        if other.n != n {
            return Err(Error::DimensionMismatch);
        }
        for (i, (dst, src)) in self.h.iter_mut().zip(other.h.iter()).enumerate().take(n) {
            if let (Some(dst), Some(src)) = (dst.get_mut(i..n), src.get(i..n)) {
                for (d, s) in dst.iter_mut().zip(src) {
                    *d -= s;
                }
            }
        }
        if let (Some(dst), Some(src)) = (self.b.get_mut(..n), other.b.get(..n)) {
            for (d, s) in dst.iter_mut().zip(src) {
                *d -= s;
            }
        }
        self.cost -= other.cost;
        Ok(())
    }

    /// Shrinks the active dimension without touching the buffers (`n <= dim()`).
    pub(crate) fn truncate(&mut self, n: usize) {
        self.n = n.min(self.n);
    }

    /// Symmetric read: `H[i][j]` taken from the upper triangle; `None` outside the active block.
    pub fn get(&self, i: usize, j: usize) -> Option<f64> {
        if i >= self.n || j >= self.n {
            return None;
        }
        let (r, c) = if i <= j { (i, j) } else { (j, i) };
        self.h.get(r).and_then(|row| row.get(c)).copied()
    }

    /// Copies the upper triangle of the active block into the lower one.
    pub fn symmetrize(&mut self) {
        let n = self.n.min(D);
        for i in 1..n {
            let (top, bottom) = self.h.split_at_mut(i);
            if let Some(row_i) = bottom.first_mut() {
                for (j, upper_row) in top.iter().enumerate() {
                    if let (Some(dst), Some(&src)) = (row_i.get_mut(j), upper_row.get(i)) {
                        *dst = src;
                    }
                }
            }
        }
    }

    /// Adds `value` to `H[index][index]` (e.g. a gauge anchor or a diagonal prior).
    pub fn add_to_diagonal(&mut self, index: usize, value: f64) -> Result<(), Error> {
        if !value.is_finite() {
            return Err(Error::NonFinite);
        }
        if index >= self.n {
            return Err(Error::DimensionMismatch);
        }
        let v = self
            .h
            .get_mut(index)
            .and_then(|row| row.get_mut(index))
            .ok_or(Error::DimensionMismatch)?;
        *v += value;
        Ok(())
    }

    /// `max_i |b_i|` over the active entries (the infinity norm of the half-gradient).
    pub fn gradient_max_abs(&self) -> f64 {
        self.b
            .iter()
            .take(self.n)
            .fold(0.0_f64, |acc, v| acc.max(libm::fabs(*v)))
    }

    /// `x^T H x` for the symmetric `H` whose upper triangle is stored; `x` has `n` entries.
    pub fn quadratic_form(&self, x: &[f64]) -> Result<f64, Error> {
        if x.len() != self.n {
            return Err(Error::DimensionMismatch);
        }
        let mut acc = 0.0;
        for (i, (row, &xi)) in self.h.iter().zip(x).enumerate() {
            let diag = row.get(i).copied().unwrap_or(0.0);
            let off: f64 = row
                .get(i + 1..self.n)
                .unwrap_or(&[])
                .iter()
                .zip(x.get(i + 1..).unwrap_or(&[]))
                .map(|(h, xj)| h * xj)
                .sum();
            acc += xi * (diag * xi + 2.0 * off);
        }
        Ok(acc)
    }

    /// `x^T b` over the active entries; `x` has `n` entries.
    pub fn dot_b(&self, x: &[f64]) -> Result<f64, Error> {
        if x.len() != self.n {
            return Err(Error::DimensionMismatch);
        }
        Ok(x.iter().zip(self.b.iter()).map(|(a, b)| a * b).sum())
    }

    /// Adds a residual `r` (`m` rows) with a dense row-major `m x k` Jacobian `jac` whose column
    /// `a` is the derivative w.r.t. state `cols[a]` (any order; duplicates allowed).
    ///
    /// Runs a contiguous fast path when `cols` is `c0, c0+1, ...`. Prefer
    /// [`NormalEquations::add_blocks`] for factors made of a few contiguous state blocks.
    pub fn add_residual(
        &mut self,
        r: &[f64],
        jac: &[f64],
        cols: &[usize],
        m: usize,
        k: usize,
    ) -> Result<(), Error> {
        if r.len() != m || cols.len() != k || Some(jac.len()) != m.checked_mul(k) {
            return Err(Error::DimensionMismatch);
        }
        if cols.iter().any(|&c| c >= self.n) {
            return Err(Error::DimensionMismatch);
        }
        if !all_finite(r) || !all_finite(jac) {
            return Err(Error::NonFinite);
        }
        if k == 0 {
            self.cost += r.iter().map(|v| v * v).sum::<f64>();
            return Ok(());
        }
        let first = cols.first().copied().unwrap_or(0);
        if cols.iter().enumerate().all(|(a, &c)| c == first + a) {
            self.accumulate_blocks(r, &[JacobianBlock::new(first, k, jac)]);
            return Ok(());
        }
        self.cost += r.iter().map(|v| v * v).sum::<f64>();
        let col = |row: usize, a: usize| jac.get(row * k + a).copied().unwrap_or(0.0);
        for (a, &ca) in cols.iter().enumerate() {
            if let Some(bc) = self.b.get_mut(ca) {
                *bc -= r
                    .iter()
                    .enumerate()
                    .map(|(row, ri)| col(row, a) * ri)
                    .sum::<f64>();
            }
            let Some(hrow) = self.h.get_mut(ca) else {
                continue;
            };
            for (bb, &cb) in cols.iter().enumerate() {
                if ca <= cb {
                    if let Some(v) = hrow.get_mut(cb) {
                        *v += (0..m).map(|row| col(row, a) * col(row, bb)).sum::<f64>();
                    }
                }
            }
        }
        Ok(())
    }

    /// Adds a residual `r` (`m = r.len()` rows) whose Jacobian is non-zero only on the given
    /// contiguous, pairwise non-overlapping state blocks (e.g. 2-3 pose blocks of width 6 or 15).
    ///
    /// Faster than [`NormalEquations::add_residual`]: whole block rows of `H` are updated with
    /// contiguous slices and the lower triangle is skipped block-wise.
    pub fn add_blocks(&mut self, r: &[f64], blocks: &[JacobianBlock<'_>]) -> Result<(), Error> {
        let m = r.len();
        for (p, blk) in blocks.iter().enumerate() {
            let end = blk.col.checked_add(blk.width);
            if Some(blk.jac.len()) != m.checked_mul(blk.width) || end.is_none_or(|e| e > self.n) {
                return Err(Error::DimensionMismatch);
            }
            let overlaps = blocks.iter().skip(p + 1).any(|q| {
                blk.width > 0
                    && q.width > 0
                    && blk.col < q.col.saturating_add(q.width)
                    && q.col < blk.col.saturating_add(blk.width)
            });
            if overlaps {
                return Err(Error::DimensionMismatch);
            }
        }
        if !all_finite(r) || blocks.iter().any(|blk| !all_finite(blk.jac)) {
            return Err(Error::NonFinite);
        }
        self.accumulate_blocks(r, blocks);
        Ok(())
    }

    /// Column-first accumulation over validated blocks: for each state column `c` of block `p`
    /// and each block `q` right of it, the short slice `h[c][q]` stays in L1 while all residual
    /// rows are summed into it (one pass over `H` per factor, not one per residual row).
    fn accumulate_blocks(&mut self, r: &[f64], blocks: &[JacobianBlock<'_>]) {
        self.cost += r.iter().map(|v| v * v).sum::<f64>();
        for p in blocks {
            for i in 0..p.width {
                let c = p.col + i;
                let jp_col = |row: usize| p.jac.get(row * p.width + i).copied().unwrap_or(0.0);
                if let Some(bc) = self.b.get_mut(c) {
                    *bc -= r
                        .iter()
                        .enumerate()
                        .map(|(row, ri)| jp_col(row) * ri)
                        .sum::<f64>();
                }
                let Some(hrow) = self.h.get_mut(c) else {
                    continue;
                };
                for q in blocks.iter().filter(|q| q.col >= p.col) {
                    // Inside the own block only the upper part j >= i is stored.
                    let start = if q.col == p.col { i } else { 0 };
                    let Some(dst) = hrow.get_mut(q.col + start..q.col + q.width) else {
                        continue;
                    };
                    for row in 0..r.len() {
                        let a = jp_col(row);
                        if a != 0.0 {
                            axpy(Some(&mut *dst), a, q.row(row).get(start..));
                        }
                    }
                }
            }
        }
    }
}

/// `dst += alpha * src` elementwise over the common length (no-op if either is missing).
#[inline(always)]
pub(crate) fn axpy(dst: Option<&mut [f64]>, alpha: f64, src: Option<&[f64]>) {
    if let (Some(dst), Some(src)) = (dst, src) {
        for (d, s) in dst.iter_mut().zip(src) {
            *d += alpha * s;
        }
    }
}

pub(crate) fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// One Jacobian row over states `c0 .. c0 + row.len()` (indices validated by the caller).
#[inline]
pub(crate) fn accumulate_row_contiguous<const D: usize>(
    h: &mut [[f64; D]; D],
    b: &mut [f64; D],
    c0: usize,
    row: &[f64],
    ri: f64,
) {
    let end = c0 + row.len();
    for (i, &ji) in row.iter().enumerate() {
        if ji == 0.0 {
            continue;
        }
        let c = c0 + i;
        if let Some(bc) = b.get_mut(c) {
            *bc -= ji * ri;
        }
        if let Some(hrow) = h.get_mut(c) {
            axpy(hrow.get_mut(c..end), ji, row.get(i..));
        }
    }
}

/// One Jacobian row over arbitrary state columns (indices validated by the caller).
#[inline]
pub(crate) fn accumulate_row_indexed<const D: usize>(
    h: &mut [[f64; D]; D],
    b: &mut [f64; D],
    cols: &[usize],
    row: &[f64],
    ri: f64,
) {
    for (&ja, &ca) in row.iter().zip(cols) {
        if ja == 0.0 {
            continue;
        }
        if let Some(bc) = b.get_mut(ca) {
            *bc -= ja * ri;
        }
        let Some(hrow) = h.get_mut(ca) else {
            continue;
        };
        for (&jb, &cb) in row.iter().zip(cols) {
            if ca <= cb {
                if let Some(v) = hrow.get_mut(cb) {
                    *v += ja * jb;
                }
            }
        }
    }
}

impl<const D: usize> NormalEquations<D> {
    /// Adds the terms of a 2-row residual `r` that involve its single-column states: `cols[k]`
    /// (`None`: not estimated) with Jacobian column `cols[k].1`, against each other and against
    /// the 6-wide pose blocks `poses` (whose own products the caller adds elsewhere). The scalar
    /// columns must be distinct and outside the pose blocks. The cost is not touched; nothing is
    /// added on `Err`.
    pub fn add_scalar_columns(
        &mut self,
        r: &nalgebra::Vector2<f64>,
        cols: &[(Option<usize>, nalgebra::Vector2<f64>)],
        poses: &[(usize, nalgebra::Matrix2x6<f64>)],
    ) -> Result<(), Error> {
        let n = self.n;
        let distinct = cols
            .iter()
            .enumerate()
            .all(|(a, (ca, _))| ca.is_none() || cols.iter().skip(a + 1).all(|(cb, _)| cb != ca));
        let in_pose = |c: usize| poses.iter().any(|(p, _)| (*p..p + 6).contains(&c));
        if !distinct
            || cols
                .iter()
                .any(|c| c.0.is_some_and(|c| c >= n || in_pose(c)))
            || poses.iter().any(|(c, _)| c + 6 > n)
        {
            return Err(Error::DimensionMismatch);
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !finite(r.as_slice())
            || !cols.iter().all(|c| finite(c.1.as_slice()))
            || !poses.iter().all(|p| finite(p.1.as_slice()))
        {
            return Err(Error::NonFinite);
        }
        for (a, (ca, ja)) in cols.iter().enumerate() {
            let Some(ca) = *ca else { continue };
            if let Some(b) = self.b.get_mut(ca) {
                *b -= ja.dot(r);
            }
            for (pc, pj) in poses {
                let x = pj.transpose() * ja;
                for (i, xi) in x.iter().enumerate() {
                    let (lo, hi) = if pc + i < ca {
                        (pc + i, ca)
                    } else {
                        (ca, pc + i)
                    };
                    if let Some(h) = self.h.get_mut(lo).and_then(|row| row.get_mut(hi)) {
                        *h += xi;
                    }
                }
            }
            for (cb, jb) in cols.iter().skip(a) {
                let Some(cb) = *cb else { continue };
                let (lo, hi) = if ca <= cb { (ca, cb) } else { (cb, ca) };
                if let Some(h) = self.h.get_mut(lo).and_then(|row| row.get_mut(hi)) {
                    *h += ja.dot(jb);
                }
            }
        }
        Ok(())
    }
}

/// Fast path of [`NormalEquations::add_blocks`] for the commonest visual residual: 2 rows over
/// up to three distinct 6-wide pose blocks. The 6x6 products are formed with fixed-size
/// arithmetic and added block by block, so there is no per-entry bookkeeping.
impl<const D: usize> NormalEquations<D> {
    /// Adds `r` (2 rows) with Jacobian blocks `jacs[k]` (2x6) at state columns
    /// `cols[k]..cols[k] + 6`. Blocks must not overlap. Nothing is accumulated on `Err`.
    pub fn add_2x6_blocks(
        &mut self,
        r: &nalgebra::Vector2<f64>,
        jacs: &[nalgebra::Matrix2x6<f64>],
        cols: &[usize],
    ) -> Result<(), Error> {
        if jacs.len() != cols.len() || jacs.len() > 3 {
            return Err(Error::DimensionMismatch);
        }
        for (a, &ca) in cols.iter().enumerate() {
            if ca.checked_add(6).is_none_or(|e| e > self.n) {
                return Err(Error::DimensionMismatch);
            }
            if cols
                .iter()
                .skip(a + 1)
                .any(|&cb| ca < cb + 6 && cb < ca + 6)
            {
                return Err(Error::DimensionMismatch);
            }
        }
        if !r.iter().all(|v| v.is_finite()) || !jacs.iter().all(|j| j.iter().all(|v| v.is_finite()))
        {
            return Err(Error::NonFinite);
        }
        self.cost += r.norm_squared();
        // Column-major storage: column i of a 2x6 block is [row 0, row 1].
        for (a, (ja, &ca)) in jacs.iter().zip(cols).enumerate() {
            let xa = &ja.data.0;
            if let Some(b) = self.b.get_mut(ca..ca + 6) {
                for (bi, c) in b.iter_mut().zip(xa) {
                    *bi -= c[0] * r.x + c[1] * r.y;
                }
            }
            for (jb, &cb) in jacs.iter().zip(cols).skip(a) {
                // Upper triangle: the block with the smaller column range is the row block.
                let (x, y, r0, c0) = if ca <= cb {
                    (xa, &jb.data.0, ca, cb)
                } else {
                    (&jb.data.0, xa, cb, ca)
                };
                for (i, xi) in x.iter().enumerate() {
                    let Some(row) = self.h.get_mut(r0 + i).and_then(|h| h.get_mut(c0..c0 + 6))
                    else {
                        continue;
                    };
                    for (h, yk) in row.iter_mut().zip(y) {
                        *h += xi[0] * yk[0] + xi[1] * yk[1];
                    }
                }
            }
        }
        Ok(())
    }
}

/// Fast path for a dense residual over two equally wide blocks: the IMU preintegration factor
/// (15 whitened rows, two 15-wide keyframe states). The three block products are formed with
/// fixed-size arithmetic and added once each.
impl<const D: usize> NormalEquations<D> {
    /// Adds `r` (`R` rows) with Jacobian blocks `ja`, `jb` (`R x W`) at state columns
    /// `ca..ca + W` and `cb..cb + W`. The blocks must not overlap. Nothing is accumulated on
    /// `Err`.
    pub fn add_dense_pair<const R: usize, const W: usize>(
        &mut self,
        r: &nalgebra::SVector<f64, R>,
        ja: &nalgebra::SMatrix<f64, R, W>,
        jb: &nalgebra::SMatrix<f64, R, W>,
        ca: usize,
        cb: usize,
    ) -> Result<(), Error> {
        let fits = |c: usize| c.checked_add(W).is_some_and(|e| e <= self.n);
        if !(fits(ca) && fits(cb) && (ca + W <= cb || cb + W <= ca)) {
            return Err(Error::DimensionMismatch);
        }
        let finite = r
            .iter()
            .chain(ja.iter())
            .chain(jb.iter())
            .all(|v| v.is_finite());
        if !finite {
            return Err(Error::NonFinite);
        }
        self.cost += r.norm_squared();
        for (c, g) in [(ca, ja.tr_mul(r)), (cb, jb.tr_mul(r))] {
            if let Some(b) = self.b.get_mut(c..c + W) {
                for (bi, gi) in b.iter_mut().zip(g.iter()) {
                    *bi -= gi;
                }
            }
        }
        // Diagonal blocks: upper triangle only (the lower one is never read), each entry the
        // column dot product `tr_mul` would form for it (bit-identical, half the products).
        for (c, m) in [(ca, ja), (cb, jb)] {
            for i in 0..W {
                if let Some(row) = self.h.get_mut(c + i).and_then(|h| h.get_mut(c + i..c + W)) {
                    let mi = m.column(i);
                    for (k, h) in row.iter_mut().enumerate() {
                        *h += mi.dot(&m.column(i + k));
                    }
                }
            }
        }
        let (r0, c0, m) = if ca < cb {
            (ca, cb, ja.tr_mul(jb))
        } else {
            (cb, ca, jb.tr_mul(ja))
        };
        for i in 0..W {
            if let Some(row) = self.h.get_mut(r0 + i).and_then(|h| h.get_mut(c0..c0 + W)) {
                for (k, h) in row.iter_mut().enumerate() {
                    *h += m[(i, k)];
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dense_pair_diagonal_is_bit_identical_to_tr_mul() {
        let mut rnd = crate::solver::test_rng(11);
        let r = nalgebra::SVector::<f64, 15>::from_fn(|_, _| rnd());
        let ja = nalgebra::SMatrix::<f64, 15, 15>::from_fn(|_, _| rnd());
        let jb = nalgebra::SMatrix::<f64, 15, 15>::from_fn(|_, _| rnd());
        let mut ne = NormalEquations::<40>::new();
        ne.reset(35).unwrap();
        ne.add_dense_pair(&r, &ja, &jb, 2, 20).unwrap();
        for (c, m) in [(2, ja.tr_mul(&ja)), (20, jb.tr_mul(&jb))] {
            for i in 0..15 {
                for j in i..15 {
                    assert_eq!(ne.h[c + i][c + j].to_bits(), m[(i, j)].to_bits());
                }
            }
        }
    }

    #[test]
    fn dense_pair_equals_the_block_path() {
        let mut rnd = crate::solver::test_rng(5);
        let r = nalgebra::SVector::<f64, 4>::from_fn(|_, _| rnd());
        let ja = nalgebra::SMatrix::<f64, 4, 3>::from_fn(|_, _| rnd());
        let jb = nalgebra::SMatrix::<f64, 4, 3>::from_fn(|_, _| rnd());
        let rm = |m: &nalgebra::SMatrix<f64, 4, 3>| -> [f64; 12] {
            core::array::from_fn(|k| m[(k / 3, k % 3)])
        };
        let (a_rm, b_rm) = (rm(&ja), rm(&jb));
        // Second block before the first in column order: the cross block lands transposed.
        let (ca, cb) = (5, 1);
        let mut fast = NormalEquations::<9>::new();
        let mut general = NormalEquations::<9>::new();
        fast.reset(9).unwrap();
        general.reset(9).unwrap();
        fast.add_dense_pair(&r, &ja, &jb, ca, cb).unwrap();
        general
            .add_blocks(
                r.as_slice(),
                &[
                    JacobianBlock::new(ca, 3, &a_rm),
                    JacobianBlock::new(cb, 3, &b_rm),
                ],
            )
            .unwrap();
        for i in 0..9 {
            assert!((fast.b[i] - general.b[i]).abs() < 1e-14, "b[{i}]");
            for j in i..9 {
                assert!(
                    (fast.h[i][j] - general.h[i][j]).abs() < 1e-14,
                    "h[{i}][{j}]"
                );
            }
            for j in 0..i {
                assert_eq!(fast.h[i][j], 0.0, "lower triangle written at ({i},{j})");
            }
        }
        assert!((fast.cost - general.cost).abs() < 1e-14);
        assert_eq!(
            fast.add_dense_pair(&r, &ja, &jb, 2, 4),
            Err(Error::DimensionMismatch)
        );
    }

    #[test]
    fn block_and_dense_paths_agree_and_skip_lower_triangle() {
        let mut a = NormalEquations::<8>::new();
        let mut b = NormalEquations::<8>::new();
        a.reset(8).unwrap();
        b.reset(8).unwrap();
        // 2 x (2 + 3) Jacobian on states {5,6} and {1,2,3}.
        let j1 = [1.0, 2.0, 3.0, 4.0];
        let j2 = [0.5, -1.0, 2.0, 1.5, 0.0, -2.0];
        let r = [0.3, -0.7];
        a.add_blocks(
            &r,
            &[JacobianBlock::new(5, 2, &j1), JacobianBlock::new(1, 3, &j2)],
        )
        .unwrap();
        let dense = [1.0, 2.0, 0.5, -1.0, 2.0, 3.0, 4.0, 1.5, 0.0, -2.0];
        b.add_residual(&r, &dense, &[5, 6, 1, 2, 3], 2, 5).unwrap();
        for i in 0..8 {
            for j in 0..8 {
                if i <= j {
                    assert_eq!(a.h[i][j], b.h[i][j], "({i},{j})");
                } else {
                    assert_eq!(a.h[i][j], 0.0);
                    assert_eq!(b.h[i][j], 0.0);
                }
            }
            assert_eq!(a.b[i], b.b[i]);
        }
        // H[1][5] = J[:,2]^T J[:,0] = 0.5*1 + 1.5*3 = 5.0; b[5] = -(1*0.3 + 3*-0.7) = 1.8
        assert_eq!(a.h[1][5], 5.0);
        assert!((a.b[5] - 1.8).abs() < 1e-15);
        assert!((a.cost - 0.58).abs() < 1e-15);
    }

    #[test]
    fn scalar_columns_complete_the_pose_blocks() {
        // Two pose blocks (one before, one after the scalars) plus two scalar columns, as the
        // marginalization layout places a delay between keyframe blocks.
        let mut rnd = crate::solver::test_rng(9);
        let r = nalgebra::Vector2::new(rnd(), rnd());
        let p0 = nalgebra::Matrix2x6::<f64>::from_fn(|_, _| rnd());
        let p1 = nalgebra::Matrix2x6::<f64>::from_fn(|_, _| rnd());
        let t0 = nalgebra::Vector2::new(rnd(), rnd());
        let t1 = nalgebra::Vector2::new(rnd(), rnd());
        let (c0, c1, s0, s1) = (0, 8, 6, 15);
        let mut split = NormalEquations::<16>::new();
        let mut whole = NormalEquations::<16>::new();
        split.reset(16).unwrap();
        whole.reset(16).unwrap();
        split.add_2x6_blocks(&r, &[p0, p1], &[c0, c1]).unwrap();
        split
            .add_scalar_columns(
                &r,
                &[(Some(s0), t0), (None, t1), (Some(s1), t1)],
                &[(c0, p0), (c1, p1)],
            )
            .unwrap();
        let rm = |m: &nalgebra::Matrix2x6<f64>| -> [f64; 12] {
            core::array::from_fn(|k| m[(k / 6, k % 6)])
        };
        let (a, b) = (rm(&p0), rm(&p1));
        let (ta, tb) = ([t0.x, t0.y], [t1.x, t1.y]);
        whole
            .add_blocks(
                r.as_slice(),
                &[
                    JacobianBlock::new(c0, 6, &a),
                    JacobianBlock::new(c1, 6, &b),
                    JacobianBlock::new(s0, 1, &ta),
                    JacobianBlock::new(s1, 1, &tb),
                ],
            )
            .unwrap();
        // Upper triangles (the 2x6 path also writes inside its diagonal blocks' lower halves).
        for i in 0..16 {
            assert!((split.b[i] - whole.b[i]).abs() < 1e-14, "b[{i}]");
            for j in i..16 {
                assert!(
                    (split.h[i][j] - whole.h[i][j]).abs() < 1e-14,
                    "h[{i}][{j}] {} vs {}",
                    split.h[i][j],
                    whole.h[i][j]
                );
            }
        }
        // A scalar inside a pose block, or repeated, is refused untouched.
        let before = split.clone();
        assert_eq!(
            split.add_scalar_columns(&r, &[(Some(3), t0)], &[(c0, p0)]),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(
            split.add_scalar_columns(&r, &[(Some(6), t0), (Some(6), t1)], &[]),
            Err(Error::DimensionMismatch)
        );
        assert!(split.h == before.h && split.b == before.b);
    }

    #[test]
    fn invalid_input_accumulates_nothing() {
        let mut ne = NormalEquations::<4>::new();
        ne.reset(3).unwrap();
        let j = [1.0, 2.0];
        assert_eq!(
            ne.add_residual(&[1.0], &j, &[0, 3], 1, 2),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(
            ne.add_residual(&[f64::NAN], &j, &[0, 1], 1, 2),
            Err(Error::NonFinite)
        );
        assert_eq!(
            ne.add_blocks(
                &[1.0],
                &[JacobianBlock::new(0, 2, &j), JacobianBlock::new(1, 2, &j)]
            ),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(ne.reset(5), Err(Error::CapacityExceeded));
        assert_eq!(ne.cost, 0.0);
        assert!(ne.h.iter().flatten().all(|v| *v == 0.0));
    }
}

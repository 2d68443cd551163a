//! In-place `LDL^T` factorization of a symmetric matrix given by its upper triangle, with a pivot
//! floor, in a caller-owned buffer (so `H` survives for Levenberg-Marquardt retries).
//!
//! We factor `A = U^T D U` with `U = L^T` unit upper triangular: that is the same `LDL^T`, written
//! so every inner loop runs along a contiguous row of the row-major upper triangle. Step `k`
//! (right-looking Gaussian elimination, no square roots):
//!
//! ```text
//! d_k = a_kk
//! a_ij -= a_ki a_kj / d_k        for k < i <= j < n
//! u_kj  = a_kj / d_k             for j > k
//! ```
//!
//! **Pivot floor.** A pivot `d_k <= floor` (tiny, zero or negative: rank deficiency or an
//! indefinite matrix) is *dropped*: `d_k := 0`, row `k` of `U` is zeroed and the step updates
//! nothing. Solving then yields `x_k = 0` and exactly the solution of the system with state `k`
//! removed (held at its linearization point), so a gauge freedom or an unobserved state can never
//! blow the step up. The floor is `max(absolute, relative * max_i |a_ii|)`.
//!
//! After `m` steps the trailing block `a[m..n][m..n]` is the Schur complement
//! `A_rr - A_rm A_mm^-1 A_mr`; [`crate::solver::marginalization`] reuses the kernel for that.

use super::normal_equations::{all_finite, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;

/// Threshold under which a pivot is dropped: `max(absolute, relative * max_i |a_ii|)`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct PivotFloor {
    /// Fraction of the largest diagonal magnitude (scale-free part of the floor).
    pub relative: f64,
    /// Absolute lower bound of the floor.
    pub absolute: f64,
}

impl PivotFloor {
    /// `relative = 1e-12`, `absolute = 0`: drops only numerically singular directions.
    pub const DEFAULT: Self = Self {
        relative: 1e-12,
        absolute: 0.0,
    };

    pub(crate) fn threshold(&self, max_abs_diag: f64) -> f64 {
        let rel = self.relative * max_abs_diag;
        if rel > self.absolute {
            rel
        } else {
            self.absolute
        }
    }

    pub(crate) fn validate(&self) -> Result<(), Error> {
        if self.relative.is_finite()
            && self.absolute.is_finite()
            && self.relative >= 0.0
            && self.absolute >= 0.0
        {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

impl Default for PivotFloor {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Diagnostics of one factorization, returned as data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FactorReport {
    /// Dimension that was factored.
    pub n: usize,
    /// Number of pivots above the floor (kept).
    pub rank: usize,
    /// Smallest raw pivot seen (before the floor; 0 when `n == 0`).
    pub min_pivot: f64,
    /// Largest raw pivot seen (0 when `n == 0`).
    pub max_pivot: f64,
    /// Pivots below `-floor` (evidence of an indefinite matrix, not just rank deficiency).
    pub negative_pivots: usize,
    /// Every pivot was kept (`rank == n`).
    pub positive_definite: bool,
}

/// Running pivot statistics of an elimination.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PivotStats {
    n: usize,
    rank: usize,
    min: f64,
    max: f64,
    negative: usize,
}

impl PivotStats {
    pub(crate) const fn new() -> Self {
        Self {
            n: 0,
            rank: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            negative: 0,
        }
    }

    pub(crate) fn report(&self) -> FactorReport {
        let (min_pivot, max_pivot) = if self.n == 0 {
            (0.0, 0.0)
        } else {
            (self.min, self.max)
        };
        FactorReport {
            n: self.n,
            rank: self.rank,
            min_pivot,
            max_pivot,
            negative_pivots: self.negative,
            positive_definite: self.rank == self.n,
        }
    }
}

/// `max |a_ii|` over `range` of the diagonal.
pub(crate) fn max_abs_diag<const D: usize>(
    a: &[[f64; D]; D],
    range: core::ops::Range<usize>,
) -> f64 {
    range
        .filter_map(|i| a.get(i).and_then(|row| row.get(i)))
        .fold(0.0_f64, |acc, v| acc.max(libm::fabs(*v)))
}

/// Pivots per panel of the blocked elimination: the trailing rows are read and written once per
/// panel instead of once per pivot, and the panel's rows stay in L1.
pub(crate) const PANEL: usize = 4;

/// Runs elimination steps `steps` on the upper triangle of the active `n x n` block of `a`
/// (see module docs), storing kept pivots in `d` (0 for dropped ones) and the unit-upper factor
/// rows in place. Errors only on a non-finite pivot.
///
/// Blocked by [`PANEL`] pivots: a panel is eliminated among its own rows first, then every
/// trailing entry subtracts the panel's terms in pivot order, and only then are the panel rows
/// normalized. Each entry therefore sees exactly the operations of one-pivot-at-a-time
/// elimination in the same order (bit-identical results), with a quarter of the memory traffic.
///
/// `panel` is the number of pivots per panel, clamped to `1..=PANEL`: callers pass [`PANEL`];
/// 1 is the textbook one-pivot order the tests compare against.
pub(crate) fn eliminate<const D: usize>(
    a: &mut [[f64; D]; D],
    d: &mut [f64; D],
    n: usize,
    steps: core::ops::Range<usize>,
    floor: f64,
    stats: &mut PivotStats,
    panel: usize,
) -> Result<(), Error> {
    let n = n.min(D);
    let end = steps.end.min(n);
    let panel = panel.clamp(1, PANEL);
    let mut k0 = steps.start;
    while k0 < end {
        let k1 = (k0 + panel).min(end);
        // 1/d of each panel pivot, 0 for a dropped one (its row is zeroed: it updates nothing).
        let mut inv = [0.0; PANEL];
        for k in k0..k1 {
            let (top, below) = a.split_at_mut(k + 1);
            let Some(row_k) = top.last_mut() else {
                continue;
            };
            let pivot = row_k.get(k).copied().unwrap_or(0.0);
            if !pivot.is_finite() {
                return Err(Error::NonFinite);
            }
            stats.n += 1;
            stats.min = stats.min.min(pivot);
            stats.max = stats.max.max(pivot);
            let tail = row_k.get_mut(k + 1..n).unwrap_or(&mut []);
            if pivot <= floor {
                if pivot < -floor {
                    stats.negative += 1;
                }
                if let Some(dk) = d.get_mut(k) {
                    *dk = 0.0;
                }
                tail.fill(0.0);
                continue;
            }
            stats.rank += 1;
            if let Some(dk) = d.get_mut(k) {
                *dk = pivot;
            }
            let inv_k = 1.0 / pivot;
            if let Some(slot) = inv.get_mut(k - k0) {
                *slot = inv_k;
            }
            // Rows of the same panel: a_ij -= (a_ki / d_k) a_kj for j in i..n.
            for (off, row_i) in below.iter_mut().take(k1 - k - 1).enumerate() {
                let a_ki = tail.get(off).copied().unwrap_or(0.0);
                if a_ki == 0.0 {
                    continue;
                }
                let f = a_ki * inv_k;
                let i = k + 1 + off;
                if let (Some(dst), Some(src)) = (row_i.get_mut(i..n), tail.get(off..)) {
                    for (x, s) in dst.iter_mut().zip(src) {
                        *x -= f * s;
                    }
                }
            }
        }
        let (top, trailing) = a.split_at_mut(k1);
        let panel = top.get_mut(k0..).unwrap_or(&mut []);
        let runs = nonzero_runs(panel, k1, n);
        update_trailing(panel, &inv, k1, trailing, &runs);
        for (k, row_k) in (k0..k1).zip(panel.iter_mut()) {
            let inv_k = inv.get(k - k0).copied().unwrap_or(0.0);
            if inv_k != 0.0 {
                for v in row_k.get_mut(k + 1..n).unwrap_or(&mut []) {
                    *v *= inv_k;
                }
            }
        }
        k0 = k1;
    }
    Ok(())
}

/// Most column runs [`nonzero_runs`] lists (a window of 10 keyframes has about 12); a panel
/// with more is updated as one run over everything, i.e. without the column skip.
const MAX_RUNS: usize = 32;

/// The column runs `[c0, c1)` of `from..n` (ascending) where some row of `panel` is nonzero.
///
/// By symmetry they are also the trailing rows with a nonzero multiplier: every other entry
/// `a_ij` of the trailing block would only subtract `f * 0` or `0 * a_kj` terms, which change no
/// value (at most the sign of a zero), so [`update_trailing`] skips them. The window's system is
/// block sparse (a keyframe's velocity and biases couple only to its neighbours until the
/// elimination reaches them), so this skips most of the trailing block of the early panels.
fn nonzero_runs<const D: usize>(
    panel: &[[f64; D]],
    from: usize,
    n: usize,
) -> HVec<(usize, usize), MAX_RUNS> {
    let mut runs: HVec<(usize, usize), MAX_RUNS> = HVec::new();
    for j in from..n.min(D) {
        if !panel
            .iter()
            .any(|row| row.get(j).is_some_and(|v| *v != 0.0))
        {
            continue;
        }
        match runs.last_mut() {
            Some((_, c1)) if *c1 == j => *c1 = j + 1,
            _ => {
                if runs.push((j, j + 1)).is_err() {
                    runs.clear();
                    let _ = runs.push((from, n.min(D)));
                    return runs;
                }
            }
        }
    }
    runs
}

/// Trailing update of one panel (rows `panel`, unnormalized, pivots `k0..k1` with `1/d` in
/// `inv`): for each row `i >= k1`, `a_ij -= (a_ki / d_k) a_kj` for the panel's `k` in order,
/// over the rows and columns of `runs` ([`nonzero_runs`]) only.
fn update_trailing<const D: usize>(
    panel: &[[f64; D]],
    inv: &[f64; PANEL],
    k1: usize,
    trailing: &mut [[f64; D]],
    runs: &[(usize, usize)],
) {
    for (ir, &(r0, r1)) in runs.iter().enumerate() {
        let cols = runs.get(ir..).unwrap_or(&[]);
        for i in r0..r1 {
            let Some(row_i) = i.checked_sub(k1).and_then(|off| trailing.get_mut(off)) else {
                continue;
            };
            let mut f = [0.0; PANEL];
            for ((fm, row_m), im) in f.iter_mut().zip(panel).zip(inv) {
                *fm = row_m.get(i).copied().unwrap_or(0.0) * im;
            }
            for &(c0, c1) in cols {
                let c0 = c0.max(i);
                if let Some(dst) = row_i.get_mut(c0..c1) {
                    subtract_panel(dst, panel, &f, c0);
                }
            }
        }
    }
}

/// `row[c0..c0 + 6]` as an array.
#[inline(always)]
fn six<const D: usize>(row: &[f64; D], c0: usize) -> Option<&[f64; 6]> {
    row.get(c0..c0 + 6)
        .and_then(|u| <&[f64; 6]>::try_from(u).ok())
}

/// `dst[j] -= f_m * panel[m][c0 + j]` for the panel's rows `m` in order (one subtraction per
/// pivot: the unblocked rounding); zero multipliers are skipped, as the unblocked loop skips them.
#[inline(always)]
fn subtract_panel<const D: usize>(
    dst: &mut [f64],
    panel: &[[f64; D]],
    f: &[f64; PANEL],
    c0: usize,
) {
    let c1 = c0 + dst.len();
    if let ([r0, r1, r2, r3], &[f0, f1, f2, f3]) = (panel, f) {
        if f.iter().all(|v| *v != 0.0) {
            // A pose block (6 wide, the common run): fixed-size operands, fully unrolled.
            if let (Ok(d), Some(u0), Some(u1), Some(u2), Some(u3)) = (
                <&mut [f64; 6]>::try_from(&mut *dst),
                six(r0, c0),
                six(r1, c0),
                six(r2, c0),
                six(r3, c0),
            ) {
                for ((((x, a0), a1), a2), a3) in d.iter_mut().zip(u0).zip(u1).zip(u2).zip(u3) {
                    *x = (((*x - f0 * a0) - f1 * a1) - f2 * a2) - f3 * a3;
                }
                return;
            }
            let (u0, u1, u2, u3) = (
                r0.get(c0..c1).unwrap_or(&[]),
                r1.get(c0..c1).unwrap_or(&[]),
                r2.get(c0..c1).unwrap_or(&[]),
                r3.get(c0..c1).unwrap_or(&[]),
            );
            for ((((x, a0), a1), a2), a3) in dst.iter_mut().zip(u0).zip(u1).zip(u2).zip(u3) {
                *x = (((*x - f0 * a0) - f1 * a1) - f2 * a2) - f3 * a3;
            }
            return;
        }
    }
    for (row_m, &fm) in panel.iter().zip(f) {
        if fm == 0.0 {
            continue;
        }
        for (x, s) in dst.iter_mut().zip(row_m.get(c0..c1).unwrap_or(&[])) {
            *x -= fm * s;
        }
    }
}

/// `y <- U^-T y` over the steps `steps` (forward substitution with the unit-upper rows of `a`).
pub(crate) fn forward_substitute<const D: usize>(
    a: &[[f64; D]; D],
    n: usize,
    steps: core::ops::Range<usize>,
    y: &mut [f64],
) {
    let n = n.min(D).min(y.len());
    for k in steps.start..steps.end.min(n) {
        let (head, tail) = y.split_at_mut(k + 1);
        let yk = head.last().copied().unwrap_or(0.0);
        if yk == 0.0 {
            continue;
        }
        if let Some(u) = a.get(k).and_then(|row| row.get(k + 1..n)) {
            for (t, u) in tail.iter_mut().zip(u) {
                *t -= u * yk;
            }
        }
    }
}

/// Caller-owned `LDL^T` workspace of capacity `D` (about `8 D^2` bytes; build in place).
#[derive(Clone)]
pub struct Ldlt<const D: usize> {
    /// Upper triangle of the loaded matrix, then the unit-upper factor `U` above the diagonal.
    a: [[f64; D]; D],
    /// Kept pivots (0 for dropped ones).
    d: [f64; D],
    n: usize,
    factored: bool,
}

impl<const D: usize> Default for Ldlt<D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const D: usize> Ldlt<D> {
    /// Empty workspace; `const` so it can initialize a `static`.
    pub const fn new() -> Self {
        Self {
            a: [[0.0; D]; D],
            d: [0.0; D],
            n: 0,
            factored: false,
        }
    }

    /// Back to the state [`Ldlt::new`] builds (every buffer zeroed), in place.
    pub fn reset_to_new(&mut self) {
        for row in self.a.iter_mut() {
            row.fill(0.0);
        }
        self.d.fill(0.0);
        self.n = 0;
        self.factored = false;
    }

    /// Dimension of the loaded matrix.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Whether [`Ldlt::factorize`] has run on the loaded matrix.
    pub fn is_factored(&self) -> bool {
        self.factored
    }

    /// Copies the upper triangle of the active block of `ne.h`.
    pub fn load(&mut self, ne: &NormalEquations<D>) -> Result<(), Error> {
        self.load_upper(&ne.h, ne.dim())
    }

    /// Copies the upper triangle of the leading `n x n` block of `h` (lower triangle ignored).
    pub fn load_upper(&mut self, h: &[[f64; D]; D], n: usize) -> Result<(), Error> {
        if n > D {
            return Err(Error::CapacityExceeded);
        }
        for (i, row) in h.iter().enumerate().take(n) {
            if !all_finite(row.get(i..n).unwrap_or(&[])) {
                return Err(Error::NonFinite);
            }
        }
        for (i, (dst, src)) in self.a.iter_mut().zip(h.iter()).enumerate().take(n) {
            if let (Some(dst), Some(src)) = (dst.get_mut(i..n), src.get(i..n)) {
                dst.copy_from_slice(src);
            }
        }
        self.n = n;
        self.factored = false;
        Ok(())
    }

    /// Marquardt damping of the loaded matrix: `a_ii += lambda * clamp(a_ii, diag_min, diag_max)`.
    /// The clamp keeps states with a (near-)zero diagonal dampable and huge ones bounded.
    pub fn add_marquardt_damping(
        &mut self,
        lambda: f64,
        diag_min: f64,
        diag_max: f64,
    ) -> Result<(), Error> {
        let valid = lambda.is_finite()
            && lambda >= 0.0
            && diag_min.is_finite()
            && diag_max.is_finite()
            && diag_min >= 0.0
            && diag_min <= diag_max;
        if !valid || self.factored {
            return Err(Error::InvalidConfig);
        }
        for (i, row) in self.a.iter_mut().enumerate().take(self.n) {
            if let Some(v) = row.get_mut(i) {
                *v += lambda * v.clamp(diag_min, diag_max);
            }
        }
        Ok(())
    }

    /// Factors the loaded matrix in place. Rank deficiency and indefiniteness are reported in
    /// the [`FactorReport`], not as errors; `Err` only for a non-finite pivot or a bad floor.
    pub fn factorize(&mut self, floor: PivotFloor) -> Result<FactorReport, Error> {
        floor.validate()?;
        let n = self.n;
        let threshold = floor.threshold(max_abs_diag(&self.a, 0..n));
        let mut stats = PivotStats::new();
        self.factored = false;
        eliminate(
            &mut self.a,
            &mut self.d,
            n,
            0..n,
            threshold,
            &mut stats,
            PANEL,
        )?;
        self.factored = true;
        Ok(stats.report())
    }

    /// Solves `A x = rhs` in place (`x` holds `rhs` on entry, `n` entries). Dropped pivots give
    /// `x_k = 0` (see module docs). `Err(NonFinite)` if the result overflowed.
    pub fn solve_in_place(&self, x: &mut [f64]) -> Result<(), Error> {
        if !self.factored {
            return Err(Error::NotInitialized);
        }
        let n = self.n;
        if x.len() != n {
            return Err(Error::DimensionMismatch);
        }
        forward_substitute(&self.a, n, 0..n, x);
        for (xk, &dk) in x.iter_mut().zip(self.d.iter()) {
            *xk = if dk > 0.0 { *xk / dk } else { 0.0 };
        }
        for k in (0..n).rev() {
            let (head, tail) = x.split_at_mut(k + 1);
            let dot: f64 = self
                .a
                .get(k)
                .and_then(|row| row.get(k + 1..n))
                .unwrap_or(&[])
                .iter()
                .zip(tail.iter())
                .map(|(u, t)| u * t)
                .sum();
            if let Some(xk) = head.last_mut() {
                *xk -= dot;
            }
        }
        if all_finite(x) {
            Ok(())
        } else {
            Err(Error::NonFinite)
        }
    }

    /// Kept pivot `d_k` (0 if dropped); `None` outside the factored dimension.
    pub fn pivot(&self, k: usize) -> Option<f64> {
        if self.factored && k < self.n {
            self.d.get(k).copied()
        } else {
            None
        }
    }

    /// Row `k` of the unit-upper factor `U` (entries `k+1..n`; the unit diagonal is implicit).
    pub fn factor_row(&self, k: usize) -> Option<&[f64]> {
        if self.factored && k < self.n {
            self.a.get(k).and_then(|row| row.get(k + 1..self.n))
        } else {
            None
        }
    }

    /// `a^T A^-1 a` of the factored matrix, for `a` given in `y` (`n` entries; overwritten with
    /// `U^-T a`): one forward substitution, `sum_k y_k^2 / d_k` over the kept pivots (a dropped
    /// pivot's direction counts as unconstrained by `A`, as in [`Ldlt::solve_in_place`]).
    pub fn inverse_quadratic_form(&self, y: &mut [f64]) -> Result<f64, Error> {
        self.forward_substitute(y)?;
        let q = y
            .iter()
            .zip(self.d.iter())
            .filter(|(_, &dk)| dk > 0.0)
            .map(|(yk, dk)| yk * yk / dk)
            .sum::<f64>();
        if q.is_finite() {
            Ok(q)
        } else {
            Err(Error::NonFinite)
        }
    }

    /// The `W x W` block of `A^-1` at rows and columns `start .. start + W` of the factored
    /// matrix, into `out` (a marginal covariance when `A` is an information matrix). With
    /// `A = U^T D U`, the block is `Z^T D^-1 Z` for `Z = U^-T E` (`E` the block's unit columns);
    /// `Z` is zero above `start`, so the cost is `W (n - start)^2`, not `W n^2`: the block should
    /// sit near the end of the ordering. `scratch` holds `Z` (at least `W` rows).
    /// [`Error::NotPositiveDefinite`] when a pivot at or after `start` was dropped (a direction
    /// the matrix does not constrain: no finite covariance).
    pub fn inverse_block<const W: usize>(
        &self,
        start: usize,
        scratch: &mut [[f64; D]],
        out: &mut [[f64; W]; W],
    ) -> Result<(), Error> {
        if !self.factored {
            return Err(Error::NotInitialized);
        }
        let n = self.n;
        if start.saturating_add(W) > n || scratch.len() < W {
            return Err(Error::DimensionMismatch);
        }
        let pivots = self.d.get(start..n).unwrap_or(&[]);
        if pivots.iter().any(|&d| d <= 0.0) {
            return Err(Error::NotPositiveDefinite);
        }
        for (j, z) in scratch.iter_mut().take(W).enumerate() {
            let z = z.get_mut(..n).ok_or(Error::DimensionMismatch)?;
            z.fill(0.0);
            if let Some(e) = z.get_mut(start + j) {
                *e = 1.0;
            }
            forward_substitute(&self.a, n, start + j..n, z);
        }
        for i in 0..W {
            for j in i..W {
                let (Some(zi), Some(zj)) = (scratch.get(i), scratch.get(j)) else {
                    return Err(Error::DimensionMismatch);
                };
                let k0 = start + j;
                let v: f64 = zi
                    .get(k0..n)
                    .unwrap_or(&[])
                    .iter()
                    .zip(zj.get(k0..n).unwrap_or(&[]))
                    .zip(self.d.get(k0..n).unwrap_or(&[]))
                    .map(|((a, b), d)| a * b / d)
                    .sum();
                if !v.is_finite() {
                    return Err(Error::NonFinite);
                }
                if let Some(row) = out.get_mut(i) {
                    if let Some(x) = row.get_mut(j) {
                        *x = v;
                    }
                }
                if let Some(row) = out.get_mut(j) {
                    if let Some(x) = row.get_mut(i) {
                        *x = v;
                    }
                }
            }
        }
        Ok(())
    }

    /// `y <- U^-T y` (first half of a solve), `y` with `n` entries.
    pub fn forward_substitute(&self, y: &mut [f64]) -> Result<(), Error> {
        if !self.factored {
            return Err(Error::NotInitialized);
        }
        if y.len() != self.n {
            return Err(Error::DimensionMismatch);
        }
        forward_substitute(&self.a, self.n, 0..self.n, y);
        Ok(())
    }
}

#[cfg(test)]
#[path = "ldlt_tests.rs"]
mod tests;

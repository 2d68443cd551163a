//! Marginalization: Schur complement of the first `m` states and the square-root prior.
//!
//! The estimator orders the error state so the states to marginalize come first (`x = [x_m, x_r]`).
//! Minimizing the quadratic model `c - 2 x^T b + x^T H x` over `x_m` leaves
//!
//! ```text
//! H* = H_rr - H_rm H_mm^-1 H_mr,   b* = b_r - H_rm H_mm^-1 b_m,   c* = c - b_m^T H_mm^-1 b_m.
//! ```
//!
//! `H_mm^-1` is never formed: the first `m` steps of the pivot-floored `LDL^T` of
//! [`crate::solver::ldlt`] leave exactly `H*` in the trailing block (and forward substitution of
//! `b` leaves `b*`). A dropped pivot (unobservable direction of `x_m`, e.g. a gauge) acts as a
//! generalized inverse that holds that direction fixed instead of injecting `1/eps` information.
//!
//! The prior is kept in square-root form: with `H* = U^T D U` (pivot-floored again),
//! `J0 = sqrt(D) U` (upper triangular) and `r0 = -sqrt(D)^-1 U^-T b*`, so that
//! `J0^T J0 = H*` and `J0^T r0 = -b*` (the sign matches `b = -J^T r` of the normal equations),
//! and `|r0 + J0 dx|^2` reproduces the quadratic model of `x_r` up to a constant. Rows of `J0`
//! whose pivot was dropped are zero. [`add_prior`] adds that residual at `dx = x (-) x0`.

use super::ldlt::{
    eliminate, forward_substitute, max_abs_diag, FactorReport, Ldlt, PivotFloor, PivotStats, PANEL,
};
use super::normal_equations::{
    accumulate_row_contiguous, accumulate_row_indexed, all_finite, NormalEquations,
};
use crate::Error;

/// Replaces the system in `ne` (dimension `n`) by its Schur complement onto states `m..n`,
/// re-indexed to `0..n-m` (dimension `n - m`); `ne.cost` becomes `c*`.
///
/// Returns the diagnostics of the `m` eliminated pivots (floor relative to `max |diag(H_mm)|`).
/// On `Err` (non-finite input, `m > n`, bad floor) `ne` is unchanged, except for a pivot that
/// overflows during elimination, after which `ne` is unspecified.
pub fn schur_complement_in_place<const D: usize>(
    ne: &mut NormalEquations<D>,
    m: usize,
    floor: PivotFloor,
) -> Result<FactorReport, Error> {
    let n = ne.dim();
    if m > n {
        return Err(Error::DimensionMismatch);
    }
    floor.validate()?;
    let finite =
        ne.h.iter()
            .enumerate()
            .take(n)
            .all(|(i, row)| all_finite(row.get(i..n).unwrap_or(&[])))
            && all_finite(ne.b.get(..n).unwrap_or(&[]));
    if !finite || !ne.cost.is_finite() {
        return Err(Error::NonFinite);
    }
    let threshold = floor.threshold(max_abs_diag(&ne.h, 0..m));
    let mut d = [0.0; D];
    let mut stats = PivotStats::new();
    eliminate(&mut ne.h, &mut d, n, 0..m, threshold, &mut stats, PANEL)?;
    let b = ne.b.get_mut(..n).ok_or(Error::CapacityExceeded)?;
    forward_substitute(&ne.h, n, 0..m, b);
    // c* = c - sum_k y_k^2 / d_k with y = U^-T b over the eliminated steps.
    let explained: f64 = b
        .iter()
        .zip(d.iter())
        .take(m)
        .filter(|(_, &dk)| dk > 0.0)
        .map(|(y, dk)| y * y / dk)
        .sum();
    ne.cost -= explained;
    b.copy_within(m.., 0);
    let r = n - m;
    if m > 0 {
        // Move the trailing upper triangle to the top-left: row i+m is read before it can be
        // overwritten (only rows < i+m are written at step i).
        for i in 0..r {
            let (top, bottom) = ne.h.split_at_mut(i + m);
            if let (Some(dst), Some(src)) = (
                top.get_mut(i).and_then(|row| row.get_mut(i..r)),
                bottom.first().and_then(|row| row.get(i + m..n)),
            ) {
                dst.copy_from_slice(src);
            }
        }
    }
    ne.truncate(r);
    Ok(stats.report())
}

/// Schur complement of `src` onto its states `m..n`, written to `out` (see
/// [`schur_complement_in_place`]); `src` is untouched.
pub fn schur_complement<const D: usize>(
    src: &NormalEquations<D>,
    m: usize,
    floor: PivotFloor,
    out: &mut NormalEquations<D>,
) -> Result<FactorReport, Error> {
    if m > src.dim() {
        return Err(Error::DimensionMismatch);
    }
    out.copy_from(src);
    schur_complement_in_place(out, m, floor)
}

/// Square-root form of the marginal system `h_star` (`H*`, `b*`, dimension `p`): writes
/// `J0` into rows/columns `0..p` of `j0` (upper triangular) and `r0` (`p` entries) such that
/// `J0^T J0 = H*` and `J0^T r0 = -b*` on every kept pivot. `ws` is the factorization scratch.
pub fn sqrt_prior<const D: usize>(
    h_star: &NormalEquations<D>,
    floor: PivotFloor,
    ws: &mut Ldlt<D>,
    j0: &mut [[f64; D]; D],
    r0: &mut [f64],
) -> Result<FactorReport, Error> {
    let p = h_star.dim();
    if r0.len() != p {
        return Err(Error::DimensionMismatch);
    }
    if !all_finite(h_star.b.get(..p).unwrap_or(&[])) {
        return Err(Error::NonFinite);
    }
    ws.load(h_star)?;
    let report = ws.factorize(floor)?;
    r0.copy_from_slice(h_star.b.get(..p).ok_or(Error::CapacityExceeded)?);
    ws.forward_substitute(r0)?;
    for (i, (row, ri)) in j0.iter_mut().zip(r0.iter_mut()).enumerate().take(p) {
        let dk = ws.pivot(i).unwrap_or(0.0);
        let row = row.get_mut(..p).unwrap_or(&mut []);
        row.fill(0.0);
        if dk <= 0.0 {
            *ri = 0.0;
            continue;
        }
        let s = libm::sqrt(dk);
        *ri = -*ri / s;
        if let Some(diag) = row.get_mut(i) {
            *diag = s;
        }
        let u = ws.factor_row(i).unwrap_or(&[]);
        for (dst, u) in row.get_mut(i + 1..).unwrap_or(&mut []).iter_mut().zip(u) {
            *dst = s * u;
        }
    }
    Ok(report)
}

/// Adds the prior residual `r = r0 + J0 dx` (`p = cols.len()` rows, `J0` = rows/columns `0..p`
/// of `j0`, `dx = x (-) x0` the error of the current state w.r.t. the prior's linearization
/// point) to `ne`, prior variable `i` being state `cols[i]`.
///
/// Zero entries of `J0` are skipped, so the upper-triangular `J0` of [`sqrt_prior`] costs about
/// `p^3 / 6` multiply-adds. Nothing is accumulated on `Err`.
pub fn add_prior<const D: usize>(
    ne: &mut NormalEquations<D>,
    j0: &[[f64; D]; D],
    r0: &[f64],
    dx: &[f64],
    cols: &[usize],
) -> Result<(), Error> {
    let p = cols.len();
    if p > D || r0.len() != p || dx.len() != p || cols.iter().any(|&c| c >= ne.dim()) {
        return Err(Error::DimensionMismatch);
    }
    if !all_finite(r0)
        || !all_finite(dx)
        || j0
            .iter()
            .take(p)
            .any(|row| !all_finite(row.get(..p).unwrap_or(&[])))
    {
        return Err(Error::NonFinite);
    }
    let mut r = [0.0; D];
    for ((ri, row), r0i) in r.iter_mut().zip(j0.iter()).zip(r0) {
        *ri = r0i + row.iter().zip(dx).map(|(j, d)| j * d).sum::<f64>();
    }
    if !all_finite(r.get(..p).unwrap_or(&[])) {
        return Err(Error::NonFinite);
    }
    let first = cols.first().copied().unwrap_or(0);
    let contiguous = cols.iter().enumerate().all(|(a, &c)| c == first + a);
    for (row, &ri) in j0.iter().zip(r.iter()).take(p) {
        ne.cost += ri * ri;
        let row = row.get(..p).unwrap_or(&[]);
        if contiguous {
            accumulate_row_contiguous(&mut ne.h, &mut ne.b, first, row, ri);
        } else {
            accumulate_row_indexed(&mut ne.h, &mut ne.b, cols, row, ri);
        }
    }
    Ok(())
}

//! Normal-equation products of a group of 2-row residuals whose Jacobian on one state block
//! factors through one shared `2 x 6` matrix (the pose-only landmark's second anchor `e`, see
//! [`crate::factors::pose_only_visual`]).
//!
//! Residual `k` of the group has the whitened Jacobian `[A_k | Q_k E | C_k]` on three distinct
//! 6-wide column blocks `s`, `e`, `j_k` (`A_k`, `C_k` are `2 x 6`, `Q_k` is `2 x 2`, `E` is shared).
//! Its products on `e` are then
//!
//! ```text
//! H_ee += E^T (sum_k Q_k^T Q_k) E      H_se += (sum_k A_k^T Q_k) E      b_e -= E^T sum_k Q_k^T r_k
//! ```
//!
//! so each residual only adds `2 x 2` and `6 x 2` sums for them, and the `6 x 6` products are
//! formed once per group ([`SharedBlock::finish`]). `H_ss`, `H_sj`, `H_jj` and `H_ej` are added
//! per residual as usual.

use super::normal_equations::NormalEquations;
use crate::Error;
use nalgebra::{Matrix2, Matrix2x6, Matrix6x2, Vector2};

/// Accumulator of one group (see module docs). Built per group, consumed by
/// [`SharedBlock::finish`]; on `Err` from [`SharedBlock::add`] nothing of that residual was added.
#[derive(Debug, Clone)]
pub struct SharedBlock {
    e: Matrix2x6<f64>,
    col_s: usize,
    col_e: usize,
    /// `sum Q^T Q`.
    qq: Matrix2<f64>,
    /// `sum A^T Q`.
    aq: Matrix6x2<f64>,
    /// `sum Q^T r`.
    qr: Vector2<f64>,
}

fn overlap(a: usize, b: usize) -> bool {
    a < b + 6 && b < a + 6
}

impl SharedBlock {
    /// Group with shared factor `e` on column block `col_e` and the common block `col_s`.
    ///
    /// Errors: [`Error::DimensionMismatch`] when a block leaves the active dimension of `ne` or
    /// the two overlap, [`Error::NonFinite`] for a non-finite `e`.
    pub fn new<const D: usize>(
        ne: &NormalEquations<D>,
        e: Matrix2x6<f64>,
        col_s: usize,
        col_e: usize,
    ) -> Result<Self, Error> {
        let fits = |c: usize| c.checked_add(6).is_some_and(|end| end <= ne.dim());
        if !(fits(col_s) && fits(col_e)) || overlap(col_s, col_e) {
            return Err(Error::DimensionMismatch);
        }
        if !e.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        Ok(Self {
            e,
            col_s,
            col_e,
            qq: Matrix2::zeros(),
            aq: Matrix6x2::zeros(),
            qr: Vector2::zeros(),
        })
    }

    /// Adds residual `r` with Jacobian `[a | q E | c]` on blocks `s`, `e`, `col_j`.
    ///
    /// Errors: [`Error::DimensionMismatch`] when `col_j` leaves `ne` or overlaps `s` or `e`,
    /// [`Error::NonFinite`] for non-finite input.
    pub fn add<const D: usize>(
        &mut self,
        ne: &mut NormalEquations<D>,
        r: &Vector2<f64>,
        q: &Matrix2<f64>,
        a: &Matrix2x6<f64>,
        c: &Matrix2x6<f64>,
        col_j: usize,
    ) -> Result<(), Error> {
        if overlap(col_j, self.col_e) {
            return Err(Error::DimensionMismatch);
        }
        if !q.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        // Validates r, a, c, col_j against ne and s; adds H_ss, H_sj, H_jj, b_s, b_j, cost.
        ne.add_2x6_blocks(r, &[*a, *c], &[self.col_s, col_j])?;
        add_cross(ne, &(q * self.e), self.col_e, c, col_j);
        self.qq += q.transpose() * q;
        self.aq += a.transpose() * q;
        self.qr += q.transpose() * r;
        Ok(())
    }

    /// Adds the group's products on `e`: `H_ee`, `H_se`, `b_e`.
    pub fn finish<const D: usize>(self, ne: &mut NormalEquations<D>) {
        let ee = self.e.transpose() * self.qq * self.e;
        let se = self.aq * self.e;
        add_block(ne, self.col_e, self.col_e, |i, k| ee[(i, k)]);
        if self.col_s < self.col_e {
            add_block(ne, self.col_s, self.col_e, |i, k| se[(i, k)]);
        } else {
            add_block(ne, self.col_e, self.col_s, |i, k| se[(k, i)]);
        }
        let g = self.e.transpose() * self.qr;
        if let Some(b) = ne.b.get_mut(self.col_e..self.col_e + 6) {
            for (bi, gi) in b.iter_mut().zip(g.iter()) {
                *bi -= gi;
            }
        }
    }
}

/// `H += X^T Y` for `X` on block `cx`, `Y` on block `cy` (distinct blocks), into the upper triangle.
fn add_cross<const D: usize>(
    ne: &mut NormalEquations<D>,
    x: &Matrix2x6<f64>,
    cx: usize,
    y: &Matrix2x6<f64>,
    cy: usize,
) {
    let (x, y, r0, c0) = if cx < cy {
        (x, y, cx, cy)
    } else {
        (y, x, cy, cx)
    };
    let p = x.transpose() * y;
    add_block(ne, r0, c0, |i, k| p[(i, k)]);
}

/// `h[r0 + i][c0 + k] += v(i, k)` for a 6x6 block.
fn add_block<const D: usize>(
    ne: &mut NormalEquations<D>,
    r0: usize,
    c0: usize,
    v: impl Fn(usize, usize) -> f64,
) {
    for i in 0..6 {
        let Some(row) = ne.h.get_mut(r0 + i).and_then(|h| h.get_mut(c0..c0 + 6)) else {
            continue;
        };
        for (k, h) in row.iter_mut().enumerate() {
            *h += v(i, k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::test_rng;

    fn rand_mat<const R: usize, const C: usize>(
        rng: &mut impl FnMut() -> f64,
    ) -> nalgebra::SMatrix<f64, R, C> {
        nalgebra::SMatrix::<f64, R, C>::from_fn(|_, _| rng())
    }

    /// The grouped products equal adding every residual's full Jacobian, for `s` before and
    /// after `e` in the column order.
    #[test]
    fn grouped_products_equal_the_full_jacobians() {
        let mut rng = test_rng(7);
        for (cs, ce, cjs) in [(0, 12, [6, 18, 24]), (18, 6, [0, 12, 24])] {
            let mut grouped: NormalEquations<30> = NormalEquations::new();
            let mut full: NormalEquations<30> = NormalEquations::new();
            grouped.reset(30).unwrap();
            full.reset(30).unwrap();
            let e = rand_mat::<2, 6>(&mut rng);
            let mut acc = SharedBlock::new(&grouped, e, cs, ce).unwrap();
            for cj in cjs {
                let r = rand_mat::<2, 1>(&mut rng);
                let q = rand_mat::<2, 2>(&mut rng);
                let a = rand_mat::<2, 6>(&mut rng);
                let c = rand_mat::<2, 6>(&mut rng);
                acc.add(&mut grouped, &r, &q, &a, &c, cj).unwrap();
                full.add_2x6_blocks(&r, &[a, q * e, c], &[cs, ce, cj])
                    .unwrap();
            }
            acc.finish(&mut grouped);
            assert_eq!(grouped.cost, full.cost);
            for i in 0..30 {
                assert!((grouped.b[i] - full.b[i]).abs() < 1e-12, "b[{i}]");
                for k in i..30 {
                    let (g, f) = (grouped.h[i][k], full.h[i][k]);
                    assert!((g - f).abs() < 1e-12, "h[{i}][{k}]: {g} vs {f}");
                }
            }
        }
    }

    #[test]
    fn bad_blocks_and_values_are_rejected_untouched() {
        let mut ne: NormalEquations<24> = NormalEquations::new();
        ne.reset(24).unwrap();
        let e = Matrix2x6::from_element(1.0);
        assert_eq!(
            SharedBlock::new(&ne, e, 0, 3).map(|_| ()),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(
            SharedBlock::new(&ne, e, 0, 20).map(|_| ()),
            Err(Error::DimensionMismatch)
        );
        let mut bad_e = e;
        bad_e[(1, 2)] = f64::NAN;
        assert_eq!(
            SharedBlock::new(&ne, bad_e, 0, 6).map(|_| ()),
            Err(Error::NonFinite)
        );
        let mut acc = SharedBlock::new(&ne, e, 0, 6).unwrap();
        let (r, q, a) = (Vector2::new(1.0, 2.0), Matrix2::identity(), e);
        assert_eq!(
            acc.add(&mut ne, &r, &q, &a, &a, 8),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(
            acc.add(&mut ne, &r, &q, &a, &a, 2),
            Err(Error::DimensionMismatch)
        );
        let mut bad_q = q;
        bad_q[(0, 1)] = f64::INFINITY;
        assert_eq!(
            acc.add(&mut ne, &r, &bad_q, &a, &a, 12),
            Err(Error::NonFinite)
        );
        assert!(ne.h.iter().flatten().all(|v| *v == 0.0));
        assert_eq!(ne.cost, 0.0);
    }
}

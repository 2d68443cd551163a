//! Fixed 6-wide kernels of the visual factors' normal equations: the fused 2-row residual over
//! two pose blocks and their delays ([`NormalEquations::add_2x6_pair`], the eliminated-depth
//! landmarks' observations) and the rank-one fold of an eliminated inverse depth
//! ([`NormalEquations::fold_rank_one`]). Both update the upper triangle of 6x6 diagonal blocks
//! through one row dispatcher with a constant length per row, and whole 6-wide row segments with
//! the operands as locals, so there is no per-entry bookkeeping.

use super::normal_equations::NormalEquations;
use crate::Error;
use heapless::Vec as HVec;

/// `0.0` when every value is finite, NaN otherwise (branch-free: `x * 0` is NaN for inf/NaN).
#[inline(always)]
fn nonfinite_probe(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |acc, x| acc + x * 0.0)
}

/// A kernel over the tail `row[c + I..c + 6]` of row `I` of a 6x6 diagonal block's upper
/// triangle, `I` a constant ([`tri_row6`]).
trait TriRow6 {
    fn apply<const I: usize>(&self, dst: &mut [f64]);
}

/// Runs `kernel` on row `i` of the 6x6 diagonal block's upper triangle at column `c` of `row`
/// (`row[c + i..c + 6]`), with a constant length per `i` so every row is a fixed kernel. The
/// one row dispatcher of the rank-two update of [`NormalEquations::add_2x6_pair`] and the
/// rank-one fold of [`NormalEquations::fold_rank_one`].
#[inline(always)]
fn tri_row6(i: usize, row: &mut [f64], c: usize, kernel: &impl TriRow6) {
    #[inline(always)]
    fn fixed<const I: usize>(row: &mut [f64], c: usize, kernel: &impl TriRow6) {
        if let Some(dst) = row.get_mut(c + I..c + 6) {
            kernel.apply::<I>(dst);
        }
    }
    match i {
        0 => fixed::<0>(row, c, kernel),
        1 => fixed::<1>(row, c, kernel),
        2 => fixed::<2>(row, c, kernel),
        3 => fixed::<3>(row, c, kernel),
        4 => fixed::<4>(row, c, kernel),
        _ => fixed::<5>(row, c, kernel),
    }
}

/// `dst += x0 y0[I..] + x1 y1[I..]`: a 2-row residual's products.
struct RankTwo<'a> {
    x: (f64, f64),
    y: (&'a [f64; 6], &'a [f64; 6]),
}

impl TriRow6 for RankTwo<'_> {
    #[inline(always)]
    fn apply<const I: usize>(&self, dst: &mut [f64]) {
        let (x, y) = (self.x, self.y);
        if let (Some(y0), Some(y1)) = (y.0.get(I..), y.1.get(I..)) {
            for ((h, a0), a1) in dst.iter_mut().zip(y0).zip(y1) {
                *h += x.0 * a0 + x.1 * a1;
            }
        }
    }
}

/// `dst -= x y[I..]`: a rank-one fold's products.
struct RankOneSub<'a> {
    x: f64,
    y: &'a [f64; 6],
}

impl TriRow6 for RankOneSub<'_> {
    #[inline(always)]
    fn apply<const I: usize>(&self, dst: &mut [f64]) {
        if let Some(src) = self.y.get(I..) {
            for (h, v) in dst.iter_mut().zip(src) {
                *h -= self.x * v;
            }
        }
    }
}

/// `dst[..6] += x0 y0 + x1 y1` (the operands as locals).
#[inline(always)]
fn add_pair6(dst: &mut [f64], (x0, x1): (f64, f64), (y0, y1): (&[f64; 6], &[f64; 6])) {
    if let Ok(d) = <&mut [f64; 6]>::try_from(dst) {
        let ([a0, a1, a2, a3, a4, a5], [b0, b1, b2, b3, b4, b5]) = (*y0, *y1);
        let [d0, d1, d2, d3, d4, d5] = d;
        *d0 += x0 * a0 + x1 * b0;
        *d1 += x0 * a1 + x1 * b1;
        *d2 += x0 * a2 + x1 * b2;
        *d3 += x0 * a3 + x1 * b3;
        *d4 += x0 * a4 + x1 * b4;
        *d5 += x0 * a5 + x1 * b5;
    }
}

impl<const D: usize> NormalEquations<D> {
    /// Exactly [`NormalEquations::add_2x6_blocks`]`(r, &[ja, jb], &[ca, cb])` followed, with
    /// `delays = Some([(ta, da), (tb, db)])`, by [`NormalEquations::add_scalar_columns`]`(r,
    /// &[(ta, da), (tb, db)], &[(ca, ja), (cb, jb)])`: every entry receives the same value
    /// computed the same way (bit-identical), checked and added part by part as those two do.
    /// Only the upper triangles of the diagonal blocks are written.
    pub fn add_2x6_pair(
        &mut self,
        r: &nalgebra::Vector2<f64>,
        ja: &nalgebra::Matrix2x6<f64>,
        jb: &nalgebra::Matrix2x6<f64>,
        ca: usize,
        cb: usize,
        delays: Option<[(Option<usize>, nalgebra::Vector2<f64>); 2]>,
    ) -> Result<(), Error> {
        let n = self.dim();
        let fits = |c: usize| c.checked_add(6).is_some_and(|e| e <= n);
        if !(fits(ca) && fits(cb) && (ca + 6 <= cb || cb + 6 <= ca)) {
            return Err(Error::DimensionMismatch);
        }
        let probe = nonfinite_probe(r.as_slice())
            + nonfinite_probe(ja.as_slice())
            + nonfinite_probe(jb.as_slice());
        if probe != 0.0 {
            return Err(Error::NonFinite);
        }
        self.cost += r.norm_squared();
        // Rows of the 2x6 blocks as arrays (the kernels run along the 6 columns).
        let rows = |m: &nalgebra::Matrix2x6<f64>| -> [[f64; 6]; 2] {
            [
                core::array::from_fn(|k| m[(0, k)]),
                core::array::from_fn(|k| m[(1, k)]),
            ]
        };
        let (a, b) = (rows(ja), rows(jb));
        for (c, [m0, m1]) in [(ca, &a), (cb, &b)] {
            if let Some(dst) = self.b.get_mut(c..c + 6) {
                for ((bi, x0), x1) in dst.iter_mut().zip(m0).zip(m1) {
                    *bi -= x0 * r.x + x1 * r.y;
                }
            }
        }
        // The block with the smaller columns is the row block of the cross product.
        let ((lo, l), (hi, u)) = if ca < cb {
            ((ca, &a), (cb, &b))
        } else {
            ((cb, &b), (ca, &a))
        };
        let ([l0, l1], [u0, u1]) = (l, u);
        if let Some(rows) = self.h.get_mut(lo..lo + 6) {
            for (i, (row, (&x0, &x1))) in rows.iter_mut().zip(l0.iter().zip(l1)).enumerate() {
                tri_row6(
                    i,
                    row,
                    lo,
                    &RankTwo {
                        x: (x0, x1),
                        y: (l0, l1),
                    },
                );
                if let Some(dst) = row.get_mut(hi..hi + 6) {
                    add_pair6(dst, (x0, x1), (u0, u1));
                }
            }
        }
        if let Some(rows) = self.h.get_mut(hi..hi + 6) {
            for (i, (row, (&x0, &x1))) in rows.iter_mut().zip(u0.iter().zip(u1)).enumerate() {
                tri_row6(
                    i,
                    row,
                    hi,
                    &RankTwo {
                        x: (x0, x1),
                        y: (u0, u1),
                    },
                );
            }
        }
        let Some(cols) = delays else {
            return Ok(());
        };
        let in_pose = |c: usize| (ca..ca + 6).contains(&c) || (cb..cb + 6).contains(&c);
        let [(ta, da), (tb, db)] = cols;
        let distinct = ta.is_none() || ta != tb;
        let bad_col = |t: Option<usize>| t.is_some_and(|c| c >= n || in_pose(c));
        if !distinct || bad_col(ta) || bad_col(tb) {
            return Err(Error::DimensionMismatch);
        }
        if nonfinite_probe(da.as_slice()) + nonfinite_probe(db.as_slice()) != 0.0 {
            return Err(Error::NonFinite);
        }
        for (k, (t, dt)) in [(ta, da), (tb, db)].into_iter().enumerate() {
            let Some(t) = t else { continue };
            if let Some(bt) = self.b.get_mut(t) {
                *bt -= dt.x * r.x + dt.y * r.y;
            }
            for (pc, [m0, m1]) in [(ca, &a), (cb, &b)] {
                // `(J_pose^T d)_i`, as nalgebra's `transpose() * d` forms it.
                let mut x = [0.0; 6];
                for ((xi, a0), a1) in x.iter_mut().zip(m0).zip(m1) {
                    *xi = a0 * dt.x + a1 * dt.y;
                }
                if t > pc {
                    // Column `t` of the pose block's rows.
                    if let Some(rows) = self.h.get_mut(pc..pc + 6) {
                        for (row, xi) in rows.iter_mut().zip(x) {
                            if let Some(h) = row.get_mut(t) {
                                *h += xi;
                            }
                        }
                    }
                } else if let Some(dst) = self.h.get_mut(t).and_then(|row| row.get_mut(pc..pc + 6))
                {
                    for (h, xi) in dst.iter_mut().zip(x) {
                        *h += xi;
                    }
                }
            }
            for (t2, d2) in [(ta, da), (tb, db)].into_iter().skip(k) {
                let Some(t2) = t2 else { continue };
                let (lo, hi) = if t <= t2 { (t, t2) } else { (t2, t) };
                if let Some(h) = self.h.get_mut(lo).and_then(|row| row.get_mut(hi)) {
                    *h += dt.x * d2.x + dt.y * d2.y;
                }
            }
        }
        Ok(())
    }
}

impl<const D: usize> NormalEquations<D> {
    /// `H -= v v^T / c` (upper triangle) and `b -= v beta / c` for `v` given as 6-wide pose
    /// segments and single delay columns, each list in ascending column order, all on distinct,
    /// non-overlapping columns. Every entry `(r, c)`, `r <= c`, gets `h -= (v_r / c) v_c` computed as
    /// `(v_r * inv_c) * v_c`, once: the order of the entries does not change any value. Pose rows are
    /// updated block pair by block pair with fixed 6-wide kernels, delays as runs of consecutive
    /// columns.
    pub fn fold_rank_one<const N: usize>(
        &mut self,
        poses: &[(usize, [f64; 6])],
        scalars: &HVec<(usize, f64), N>,
        inv_c: f64,
        beta: f64,
    ) {
        for &(ca, xa) in poses {
            if let Some(b) = self.b.get_mut(ca..ca + 6) {
                for (bi, x) in b.iter_mut().zip(xa.iter()) {
                    *bi -= x * beta * inv_c;
                }
            }
        }
        for &(ct, xt) in scalars {
            if let Some(bi) = self.b.get_mut(ct) {
                *bi -= xt * beta * inv_c;
            }
        }
        // Delays as runs of consecutive columns (a track seen in consecutive keyframes: one run).
        let mut tv = [0.0; N];
        let mut runs: HVec<(usize, usize, usize), N> = HVec::new();
        for (k, &(ct, xt)) in scalars.iter().enumerate() {
            if let Some(v) = tv.get_mut(k) {
                *v = xt;
            }
            match runs.last_mut() {
                Some((c0, _, w)) if *c0 + *w == ct => *w += 1,
                _ => {
                    let _ = runs.push((ct, k, 1));
                }
            }
        }
        let h = &mut self.h;
        for (ia, &(ca, xa)) in poses.iter().enumerate() {
            let later = poses.get(ia + 1..).unwrap_or(&[]);
            let first_run = runs.iter().position(|r| r.0 > ca).unwrap_or(runs.len());
            let Some(rows) = h.get_mut(ca..ca + 6) else {
                continue;
            };
            let xs: [f64; 6] = xa.map(|x| x * inv_c);
            // The diagonal block: upper triangle, a fixed-length kernel per row.
            for (i, (row, xi)) in rows.iter_mut().zip(xs).enumerate() {
                tri_row6(i, row, ca, &RankOneSub { x: xi, y: &xa });
            }
            // Cross blocks pair by pair: the later block's values stay in registers over the rows.
            for &(cb, xb) in later {
                for (row, xi) in rows.iter_mut().zip(xs) {
                    if let Some(dst) = row.get_mut(cb..cb + 6) {
                        sub_scaled6(dst, xi, xb);
                    }
                }
            }
            for &(c0, k0, w) in runs.get(first_run..).unwrap_or(&[]) {
                let Some(src) = tv.get(k0..k0 + w) else {
                    continue;
                };
                for (row, xi) in rows.iter_mut().zip(xs) {
                    if let Some(dst) = row.get_mut(c0..c0 + w) {
                        for (h, y) in dst.iter_mut().zip(src) {
                            *h -= xi * y;
                        }
                    }
                }
            }
        }
        // Delay rows, run by run: pose blocks to their right (none in the solve layout), the rest of
        // the run and the later runs.
        for (ir, &(c0, k0, w)) in runs.iter().enumerate() {
            let first_pose = poses.iter().position(|p| p.0 > c0).unwrap_or(poses.len());
            let right = poses.get(first_pose..).unwrap_or(&[]);
            let later = runs.get(ir + 1..).unwrap_or(&[]);
            for u in 0..w {
                let (Some(row), Some(&xt)) = (h.get_mut(c0 + u), tv.get(k0 + u)) else {
                    continue;
                };
                let xi = xt * inv_c;
                for &(cb, xb) in right {
                    if let Some(dst) = row.get_mut(cb..cb + 6) {
                        sub_scaled6(dst, xi, xb);
                    }
                }
                if let (Some(dst), Some(src)) =
                    (row.get_mut(c0 + u..c0 + w), tv.get(k0 + u..k0 + w))
                {
                    for (h, y) in dst.iter_mut().zip(src) {
                        *h -= xi * y;
                    }
                }
                for &(c1, k1, w1) in later {
                    if let (Some(dst), Some(src)) = (row.get_mut(c1..c1 + w1), tv.get(k1..k1 + w1))
                    {
                        for (h, y) in dst.iter_mut().zip(src) {
                            *h -= xi * y;
                        }
                    }
                }
            }
        }
    }
}

/// `dst[..6] -= x * y` (the operands as locals: two-wide products, no reloads).
#[inline(always)]
fn sub_scaled6(dst: &mut [f64], x: f64, y: [f64; 6]) {
    if let Ok(d) = <&mut [f64; 6]>::try_from(dst) {
        let [y0, y1, y2, y3, y4, y5] = y;
        let [d0, d1, d2, d3, d4, d5] = d;
        *d0 -= x * y0;
        *d1 -= x * y1;
        *d2 -= x * y2;
        *d3 -= x * y3;
        *d4 -= x * y4;
        *d5 -= x * y5;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fused_pair_is_bit_identical_to_the_two_paths() {
        let mut rnd = crate::solver::test_rng(23);
        // (pose a, pose b, delay a, delay b): solve layout, a before b and after it; the
        // marginalization layout with a delay between pose blocks; no delay of b.
        let cases: [(usize, usize, Option<usize>, Option<usize>); 4] = [
            (0, 30, Some(45), Some(47)),
            (30, 6, Some(47), Some(46)),
            (16, 0, Some(15), Some(40)),
            (0, 16, Some(15), None),
        ];
        for (ca, cb, ta, tb) in cases {
            for with_delays in [false, true] {
                let mut old = NormalEquations::<50>::new();
                old.reset(48).unwrap();
                for i in 0..48 {
                    old.b[i] = rnd();
                    for j in i..48 {
                        old.h[i][j] = rnd();
                    }
                }
                let mut new = old.clone();
                let r = nalgebra::Vector2::new(rnd(), rnd());
                let ja = nalgebra::Matrix2x6::<f64>::from_fn(|_, _| rnd());
                let jb = nalgebra::Matrix2x6::<f64>::from_fn(|_, _| rnd());
                let (da, db) = (
                    nalgebra::Vector2::new(rnd(), rnd()),
                    nalgebra::Vector2::new(rnd(), rnd()),
                );
                old.add_2x6_blocks(&r, &[ja, jb], &[ca, cb]).unwrap();
                if with_delays {
                    old.add_scalar_columns(&r, &[(ta, da), (tb, db)], &[(ca, ja), (cb, jb)])
                        .unwrap();
                }
                let delays = with_delays.then_some([(ta, da), (tb, db)]);
                new.add_2x6_pair(&r, &ja, &jb, ca, cb, delays).unwrap();
                assert_eq!(old.cost.to_bits(), new.cost.to_bits());
                for i in 0..48 {
                    assert_eq!(old.b[i].to_bits(), new.b[i].to_bits(), "b[{i}]");
                    for j in i..48 {
                        assert_eq!(old.h[i][j].to_bits(), new.h[i][j].to_bits(), "h[{i}][{j}]");
                    }
                }
            }
        }
        let mut ne = NormalEquations::<50>::new();
        ne.reset(48).unwrap();
        let z = nalgebra::Matrix2x6::<f64>::zeros();
        let mut bad = z;
        bad[(1, 3)] = f64::INFINITY;
        let r = nalgebra::Vector2::new(1.0, 2.0);
        assert_eq!(
            ne.add_2x6_pair(&r, &z, &bad, 0, 6, None),
            Err(Error::NonFinite)
        );
        assert_eq!(
            ne.add_2x6_pair(&r, &z, &z, 0, 3, None),
            Err(Error::DimensionMismatch)
        );
        assert_eq!(
            ne.add_2x6_pair(&r, &z, &z, 0, 43, None),
            Err(Error::DimensionMismatch)
        );
        let d = nalgebra::Vector2::new(1.0, 2.0);
        let overlapping = Some([(Some(7), d), (None, d)]);
        assert_eq!(
            ne.add_2x6_pair(&r, &z, &z, 0, 6, overlapping),
            Err(Error::DimensionMismatch)
        );
    }

    /// The generic segment-pair form the fold had before its 6-wide kernels.
    /// `H -= v v^T / c` (upper triangle) and `b -= v beta / c` for `v` given as segments
    /// `(first column, values, width)` on distinct, non-overlapping columns. Segment pair by segment
    /// pair, each block row a contiguous run, so the work is the `(sum of widths)^2 / 2` products.
    fn fold_reference<const D: usize>(
        ne: &mut NormalEquations<D>,
        segs: &[(usize, [f64; 6], usize)],
        inv_c: f64,
        beta: f64,
    ) {
        for (ia, &(ca, xa, wa)) in segs.iter().enumerate() {
            let xa = xa.get(..wa).unwrap_or(&[]);
            if let Some(b) = ne.b.get_mut(ca..ca + wa) {
                for (bi, x) in b.iter_mut().zip(xa) {
                    *bi -= x * beta * inv_c;
                }
            }
            // The diagonal block: upper triangle.
            for (i, x) in xa.iter().enumerate() {
                let xi = x * inv_c;
                if let (Some(dst), Some(src)) = (
                    ne.h.get_mut(ca + i)
                        .and_then(|row| row.get_mut(ca + i..ca + wa)),
                    xa.get(i..),
                ) {
                    for (h, y) in dst.iter_mut().zip(src) {
                        *h -= xi * y;
                    }
                }
            }
            // Cross blocks with the later segments, into whichever triangle is upper.
            for &(cb, xb, wb) in segs.iter().skip(ia + 1) {
                let xb = xb.get(..wb).unwrap_or(&[]);
                let ((r0, xr), (c0, xc)) = if ca < cb {
                    ((ca, xa), (cb, xb))
                } else {
                    ((cb, xb), (ca, xa))
                };
                for (i, x) in xr.iter().enumerate() {
                    let xi = x * inv_c;
                    if let Some(dst) =
                        ne.h.get_mut(r0 + i)
                            .and_then(|row| row.get_mut(c0..c0 + xc.len()))
                    {
                        for (h, y) in dst.iter_mut().zip(xc) {
                            *h -= xi * y;
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn rank_one_row_is_the_plain_loop() {
        let mut rnd = crate::solver::test_rng(5);
        let y: [f64; 6] = core::array::from_fn(|_| rnd());
        for i in 0..6 {
            let row: [f64; 16] = core::array::from_fn(|_| rnd());
            let x = rnd();
            let (mut a, mut b) = (row, row);
            for (h, v) in a[3 + i..9].iter_mut().zip(&y[i..]) {
                *h -= x * v;
            }
            tri_row6(i, &mut b, 3, &RankOneSub { x, y: &y });
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
        }
    }

    #[test]
    fn fold_is_bit_identical_to_the_segment_pair_form() {
        let mut rnd = crate::solver::test_rng(17);
        // Solve layout (delays after every pose) and marginalization layout (delay 0 at 15).
        let layouts: [(&[usize], &[usize]); 2] = [
            (&[0, 15, 45, 60, 120], &[150, 151, 153, 154, 158]),
            (&[0, 16, 46, 61], &[15, 140, 142, 143]),
        ];
        for (pcols, tcols) in layouts {
            let mut a = NormalEquations::<166>::new();
            a.reset(160).unwrap();
            for i in 0..160 {
                a.b[i] = rnd();
                for j in i..160 {
                    a.h[i][j] = rnd();
                }
            }
            let mut b = a.clone();
            let poses: HVec<(usize, [f64; 6]), 10> = pcols
                .iter()
                .map(|&c| (c, core::array::from_fn(|_| rnd())))
                .collect();
            let scalars: HVec<(usize, f64), 10> = tcols.iter().map(|&c| (c, rnd())).collect();
            let (inv_c, beta) = (1.0 / (1.0 + rnd().abs()), rnd());
            // The old order: anchor, observations, then the delays, unsorted pairs.
            let mut segs: HVec<(usize, [f64; 6], usize), 32> = HVec::new();
            for &(c, x) in poses.iter().rev() {
                let _ = segs.push((c, x, 6));
            }
            for &(c, x) in scalars.iter().rev() {
                let _ = segs.push((c, [x, 0.0, 0.0, 0.0, 0.0, 0.0], 1));
            }
            fold_reference(&mut a, &segs, inv_c, beta);
            b.fold_rank_one(&poses, &scalars, inv_c, beta);
            for i in 0..160 {
                assert_eq!(a.b[i].to_bits(), b.b[i].to_bits(), "b[{i}]");
                for j in i..160 {
                    assert_eq!(a.h[i][j].to_bits(), b.h[i][j].to_bits(), "h[{i}][{j}]");
                }
            }
        }
    }
}

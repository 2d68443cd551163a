//! Unit tests of `ldlt`, compiled only with `#[cfg(test)]` (the parent declares the module so).

use super::*;

#[test]
fn blocked_elimination_is_bit_identical_to_one_pivot_at_a_time() {
    // Dense SPD, sparse (zero multipliers), rank-deficient and indefinite matrices, full
    // factorizations and partial (Schur) step ranges not aligned to the panel.
    const NN: usize = 23;
    let mut rnd = crate::solver::test_rng(11);
    for case in 0..24 {
        let mut a = [[0.0; NN]; NN];
        let m = 6 + case % 5;
        let mut g = [[0.0; NN]; NN];
        for row in g.iter_mut().take(m) {
            for v in row.iter_mut() {
                *v = rnd();
            }
        }
        for i in 0..NN {
            for j in i..NN {
                let sparse = case % 3 == 1 && (i * 7 + j * 3) % 4 == 0 && i != j;
                let mut v: f64 = (0..m).map(|k| g[k][i] * g[k][j]).sum();
                if i == j && case % 4 != 2 {
                    v += 0.5; // full rank unless case % 4 == 2 (rank m: dropped pivots)
                }
                if case % 6 == 5 && i == j && i % 5 == 3 {
                    v = -1.0; // indefinite
                }
                a[i][j] = if sparse { 0.0 } else { v };
            }
        }
        let n = NN - case % 4;
        let steps = if case % 2 == 0 {
            0..n
        } else {
            1..(5 + case % 7)
        };
        let floor = 1e-9;
        let (mut a1, mut a2) = (a, a);
        let (mut d1, mut d2) = ([0.0; NN], [0.0; NN]);
        let (mut s1, mut s2) = (PivotStats::new(), PivotStats::new());
        eliminate(&mut a1, &mut d1, n, steps.clone(), floor, &mut s1, PANEL).unwrap();
        // Panels of one pivot: the textbook order, through the general (short-panel) path.
        eliminate(&mut a2, &mut d2, n, steps, floor, &mut s2, 1).unwrap();
        for i in 0..NN {
            assert_eq!(d1[i].to_bits(), d2[i].to_bits(), "case {case} d[{i}]");
            for j in i..NN {
                assert_eq!(
                    a1[i][j].to_bits(),
                    a2[i][j].to_bits(),
                    "case {case} a[{i}][{j}]: {} vs {}",
                    a1[i][j],
                    a2[i][j]
                );
            }
        }
        assert_eq!(s1.report(), s2.report(), "case {case}");
    }
}

/// Textbook right-looking elimination, one pivot at a time, every `a_ij -= f a_kj` done
/// (no zero skipped): the reference of the skipping kernels, written as the formula reads.
#[allow(clippy::needless_range_loop)]
fn eliminate_reference<const D: usize>(
    a: &mut [[f64; D]; D],
    d: &mut [f64; D],
    n: usize,
    steps: core::ops::Range<usize>,
    floor: f64,
) {
    for k in steps {
        let pivot = a[k][k];
        if pivot <= floor {
            d[k] = 0.0;
            for j in k + 1..n {
                a[k][j] = 0.0;
            }
            continue;
        }
        d[k] = pivot;
        let inv = 1.0 / pivot;
        for i in k + 1..n {
            let f = a[k][i] * inv;
            for j in i..n {
                a[i][j] -= f * a[k][j];
            }
        }
        for j in k + 1..n {
            a[k][j] *= inv;
        }
    }
}

/// `J^T J` of a window-shaped problem: `kfs` keyframes of 15 columns (pose 6, velocity and
/// biases 9), then one delay column each. Factors: a prior on keyframe 0's state and every
/// pose, IMU factors on consecutive keyframes' states, landmarks on random pose subsets and
/// their delays. `dead` leaves one column without information (a dropped pivot).
fn window_system<const D: usize>(
    kfs: usize,
    rnd: &mut impl FnMut() -> f64,
    dead: Option<usize>,
) -> [[f64; D]; D] {
    let n = 16 * kfs;
    let mut h = [[0.0; D]; D];
    let add = |cols: &[usize], h: &mut [[f64; D]; D], rnd: &mut dyn FnMut() -> f64| {
        let row: [f64; D] = core::array::from_fn(|c| {
            if cols.contains(&c) && Some(c) != dead {
                rnd()
            } else {
                0.0
            }
        });
        for i in 0..n {
            for j in i..n {
                h[i][j] += row[i] * row[j];
            }
        }
    };
    let pose = |k: usize| 15 * k..15 * k + 6;
    for _ in 0..20 {
        let cols: HVec<usize, 256> = (0..15).chain((1..kfs).flat_map(pose)).collect();
        add(&cols, &mut h, rnd);
    }
    for k in 1..kfs {
        for _ in 0..16 {
            let cols: HVec<usize, 256> = (15 * (k - 1)..15 * (k + 1)).collect();
            add(&cols, &mut h, rnd);
        }
    }
    for _ in 0..40 {
        let (a, b) = (
            (rnd().abs() * 1e3) as usize % kfs,
            (rnd().abs() * 1e3) as usize % kfs,
        );
        let td = 15 * kfs;
        let cols: HVec<usize, 256> = pose(a).chain(pose(b)).chain([td + a, td + b]).collect();
        for _ in 0..2 {
            add(&cols, &mut h, rnd);
        }
    }
    h
}

#[test]
fn skipping_zero_blocks_matches_the_textbook_elimination() {
    // Window-shaped systems (16 columns per keyframe) with damping, a dead column (dropped
    // pivot), a nearly singular direction, and partial (Schur) step ranges.
    const NN: usize = 96;
    let mut rnd = crate::solver::test_rng(23);
    for case in 0..8 {
        let kfs = 6;
        let n = 16 * kfs;
        let dead = (case % 4 == 1).then_some(20 + case);
        let mut a: [[f64; NN]; NN] = window_system(kfs, &mut rnd, dead);
        if case % 4 == 2 {
            // Nearly singular: one state with almost no information (`S H S`, still SPD);
            // undamped its pivot falls under the floor.
            for (i, row) in a.iter_mut().enumerate().take(n) {
                for (j, v) in row.iter_mut().enumerate().take(n) {
                    if i == 40 || j == 40 {
                        *v *= 1e-7;
                    }
                }
            }
        }
        if case % 2 == 0 {
            for (i, row) in a.iter_mut().enumerate().take(n) {
                row[i] += 1e-3 * row[i].clamp(1e-6, 1e32);
            }
        }
        let steps = if case % 4 == 3 { 0..16 } else { 0..n };
        let floor = 1e-12 * max_abs_diag(&a, 0..n);
        let (mut a1, mut a2) = (a, a);
        let (mut d1, mut d2) = ([0.0; NN], [0.0; NN]);
        let mut stats = PivotStats::new();
        eliminate(&mut a1, &mut d1, n, steps.clone(), floor, &mut stats, PANEL).unwrap();
        eliminate_reference(&mut a2, &mut d2, n, steps, floor);
        for i in 0..NN {
            // `==`: equal values (a skipped `x - 0 * y` may only differ in a zero's sign).
            assert!(d1[i] == d2[i], "case {case} d[{i}]");
            for j in i..NN {
                assert!(
                    a1[i][j] == a2[i][j],
                    "case {case} a[{i}][{j}]: {} vs {}",
                    a1[i][j],
                    a2[i][j]
                );
            }
        }
        if dead.is_some() {
            assert!(!stats.report().positive_definite, "case {case}");
        }
    }
    // The runs: the nonzero columns of a panel, contiguous pieces merged.
    let mut p = [[0.0; 12]; 2];
    p[0][3] = 1.0;
    p[1][4] = -2.0;
    p[1][7] = 1.0;
    p[0][11] = 3.0;
    assert_eq!(&nonzero_runs(&p, 2, 12)[..], &[(3, 5), (7, 8), (11, 12)]);
    assert_eq!(&nonzero_runs(&p, 4, 11)[..], &[(4, 5), (7, 8)]);
    // More runs than MAX_RUNS: one run over everything (the update without the skip).
    let mut q = [[0.0; 100]; 1];
    for j in (0..100).step_by(2) {
        q[0][j] = 1.0;
    }
    assert_eq!(&nonzero_runs(&q, 1, 99)[..], &[(1, 99)]);
    assert_eq!(nonzero_runs(&q, 0, 60).len(), 30);
}

#[test]
fn block_sparse_factorization_matches_a_dense_reference() {
    // Arrow-plus-band SPD matrix (the window's shape: banded blocks and a dense tail).
    const NN: usize = 40;
    let mut ne = NormalEquations::<NN>::new();
    ne.reset(NN).unwrap();
    let mut full = nalgebra::SMatrix::<f64, NN, NN>::zeros();
    let mut rnd = crate::solver::test_rng(7);
    for i in 0..NN {
        for j in i..NN {
            let band = j - i < 5 && (i / 5 == j / 5 || j - i < 3);
            let tail = j >= NN - 8;
            if band || tail {
                let v = if i == j { 10.0 + rnd() } else { rnd() };
                full[(i, j)] = v;
                full[(j, i)] = v;
            }
        }
    }
    for i in 0..NN {
        for j in i..NN {
            ne.h[i][j] = full[(i, j)];
        }
    }
    let x_true: [f64; NN] = core::array::from_fn(|i| libm::sin(i as f64 * 0.37));
    let b = full * nalgebra::SVector::<f64, NN>::from_column_slice(&x_true);
    let mut f = Ldlt::<NN>::new();
    f.load(&ne).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!(rep.rank, NN);
    let mut x: [f64; NN] = core::array::from_fn(|i| b[i]);
    f.solve_in_place(&mut x).unwrap();
    for (got, want) in x.iter().zip(x_true.iter()) {
        assert!((got - want).abs() < 1e-10, "{got} vs {want}");
    }
    // a^T A^-1 a against the dense inverse, for a sparse a (a factor's row) and a dense one.
    let inv = full.try_inverse().unwrap();
    for a in [
        core::array::from_fn::<f64, NN, _>(|i| if (10..16).contains(&i) { rnd() } else { 0.0 }),
        core::array::from_fn::<f64, NN, _>(|_| rnd()),
    ] {
        let av = nalgebra::SVector::<f64, NN>::from_column_slice(&a);
        let want = av.dot(&(inv * av));
        let mut y = a;
        let got = f.inverse_quadratic_form(&mut y).unwrap();
        assert!(
            (got - want).abs() < 1e-10 * want.abs().max(1.0),
            "{got} vs {want}"
        );
    }
}

#[test]
fn factors_and_solves_a_3x3_closed_form() {
    // A = U^T D U with U = [[1,2,3],[0,1,4],[0,0,1]], D = diag(2,3,5).
    let mut ne = NormalEquations::<4>::new();
    ne.reset(3).unwrap();
    ne.h[0][0] = 2.0;
    ne.h[0][1] = 4.0;
    ne.h[0][2] = 6.0;
    ne.h[1][1] = 11.0;
    ne.h[1][2] = 24.0;
    ne.h[2][2] = 71.0;
    ne.h[2][0] = f64::NAN; // the lower triangle must never be read
    let mut f = Ldlt::<4>::new();
    f.load(&ne).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!(rep.rank, 3);
    assert!(rep.positive_definite);
    assert_eq!(rep.min_pivot, 2.0);
    assert_eq!(rep.max_pivot, 5.0);
    assert_eq!(f.pivot(1), Some(3.0));
    assert_eq!(f.factor_row(0), Some(&[2.0, 3.0][..]));
    assert_eq!(f.factor_row(1), Some(&[4.0][..]));
    // x = (1, -1, 2): A x = (2-4+12, 4-11+48, 6-24+142) = (10, 41, 124)
    let mut x = [10.0, 41.0, 124.0];
    f.solve_in_place(&mut x).unwrap();
    for (got, want) in x.iter().zip([1.0, -1.0, 2.0]) {
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }
}

#[test]
fn indefinite_and_singular_are_reported_not_panicked() {
    let mut f = Ldlt::<3>::new();
    let mut h = [[0.0; 3]; 3];
    h[0][0] = 1.0;
    h[0][1] = 2.0;
    h[1][1] = 1.0; // pivot 2 = 1 - 4 = -3
    h[2][2] = 0.0; // singular
    f.load_upper(&h, 3).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!(rep.rank, 1);
    assert_eq!(rep.negative_pivots, 1);
    assert_eq!(rep.min_pivot, -3.0);
    assert!(!rep.positive_definite);
    let mut x = [1.0, 1.0, 1.0];
    f.solve_in_place(&mut x).unwrap();
    assert_eq!(x, [1.0, 0.0, 0.0]);
    h[1][1] = f64::INFINITY;
    let mut fresh = Ldlt::<3>::new();
    assert_eq!(fresh.load_upper(&h, 3), Err(Error::NonFinite));
    assert_eq!(fresh.solve_in_place(&mut x), Err(Error::NotInitialized));
}

/// A block of the inverse against nalgebra's inverse of the whole matrix, at the end and in
/// the middle of the ordering; a dropped pivot in the block's range is refused.
#[test]
fn inverse_block_matches_the_full_inverse() {
    const NN: usize = 20;
    let mut rnd = crate::solver::test_rng(5);
    let mut g = nalgebra::SMatrix::<f64, NN, NN>::zeros();
    for v in g.iter_mut() {
        *v = rnd();
    }
    let a = g * g.transpose() + nalgebra::SMatrix::<f64, NN, NN>::identity() * 0.1;
    let inv = a.try_inverse().unwrap();
    let mut h = [[0.0; NN]; NN];
    for (i, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[(i, j)];
        }
    }
    let mut f = Ldlt::<NN>::new();
    f.load_upper(&h, NN).unwrap();
    f.factorize(PivotFloor::DEFAULT).unwrap();
    let mut scratch = [[0.0; NN]; 4];
    let mut out = [[0.0; 4]; 4];
    for start in [NN - 4, 7, 0] {
        f.inverse_block(start, &mut scratch, &mut out).unwrap();
        for i in 0..4 {
            for j in 0..4 {
                let want = inv[(start + i, start + j)];
                assert!(
                    (out[i][j] - want).abs() < 1e-9 * (1.0 + want.abs()),
                    "{start}: ({i},{j}) {} vs {want}",
                    out[i][j]
                );
            }
        }
    }
    assert_eq!(
        f.inverse_block(NN - 3, &mut scratch, &mut out),
        Err(Error::DimensionMismatch)
    );
    // A singular last direction: its pivot is dropped, no covariance.
    h[NN - 1] = [0.0; NN];
    for row in h.iter_mut() {
        row[NN - 1] = 0.0;
    }
    f.load_upper(&h, NN).unwrap();
    f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!(
        f.inverse_block(NN - 4, &mut scratch, &mut out),
        Err(Error::NotPositiveDefinite)
    );
}

//! LDLT against an independent dense reference (Gaussian elimination with partial pivoting).
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
mod solver_support;

use povins_core::solver::{Ldlt, NormalEquations, PivotFloor};
use povins_core::Error;
use solver_support::*;

const D: usize = 166;

#[test]
fn random_spd_solves_match_reference_up_to_window_size() {
    let mut rng = Rng::new(7);
    let mut ne = Box::new(NormalEquations::<D>::new());
    let mut f = Box::new(Ldlt::<D>::new());
    for &n in &[1usize, 2, 3, 6, 15, 31, 64, 100, 166] {
        let h = random_spd(&mut rng, n, n + 5, 1e-3);
        let x_true: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
        let b = matvec(&h, &x_true);
        load_ne(&mut ne, &h, &b);
        f.load(&ne).unwrap();
        let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
        assert!(rep.positive_definite, "n={n}: {rep:?}");
        assert_eq!(rep.rank, n);
        assert_eq!(rep.negative_pivots, 0);
        assert!(rep.min_pivot > 0.0 && rep.min_pivot <= rep.max_pivot);
        let mut x = b.clone();
        f.solve_in_place(&mut x).unwrap();
        let reference = gauss_solve(&h, &b);
        let err_ref = max_abs_diff(&x, &reference);
        let err_true = max_abs_diff(&x, &x_true);
        assert!(
            err_ref < 1e-8 * (1.0 + max_abs(&reference)),
            "n={n} {err_ref}"
        );
        assert!(err_true < 1e-7, "n={n} {err_true}");
        // Residual |H x - b| at machine precision relative to |H||x|.
        let res = max_abs_diff(&matvec(&h, &x), &b);
        assert!(res < 1e-10, "n={n} residual {res}");
        // H must survive the factorization (LM retries reuse it).
        for i in 0..n {
            for j in i..n {
                assert_eq!(ne.h[i][j], h[i][j]);
            }
        }
    }
}

#[test]
fn pivots_are_the_ratios_of_leading_minors() {
    // d_k = det(A_1..k) / det(A_1..k-1): check on a 2x2 closed form [[4, 2], [2, 5]]: d = (4, 4).
    let mut h = [[0.0; 2]; 2];
    h[0][0] = 4.0;
    h[0][1] = 2.0;
    h[1][1] = 5.0;
    let mut f = Ldlt::<2>::new();
    f.load_upper(&h, 2).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!((f.pivot(0), f.pivot(1)), (Some(4.0), Some(4.0)));
    assert_eq!(f.factor_row(0), Some(&[0.5][..]));
    assert_eq!((rep.min_pivot, rep.max_pivot), (4.0, 4.0));
}

#[test]
fn rank_deficient_matrix_drops_pivot_and_solves_reduced_system() {
    // H = A^T A with A of rank n-1 (state 4 is a copy of state 2: a gauge-like freedom).
    let mut rng = Rng::new(11);
    let n = 8;
    let mut a = random(&mut rng, 20, n);
    for row in a.iter_mut() {
        row[4] = row[2];
    }
    let h = ata(&a);
    let b: Vec<f64> = transpose_matvec(&a, &(0..20).map(|_| rng.uniform()).collect::<Vec<_>>());
    let mut ne = NormalEquations::<8>::new();
    load_ne(&mut ne, &h, &b);
    let mut f = Ldlt::<8>::new();
    f.load(&ne).unwrap();
    let rep = f
        .factorize(PivotFloor {
            relative: 1e-10,
            absolute: 0.0,
        })
        .unwrap();
    assert_eq!(rep.rank, n - 1);
    assert!(!rep.positive_definite);
    let mut x = b.clone();
    f.solve_in_place(&mut x).unwrap();
    assert_eq!(x[4], 0.0, "the dropped state is held at zero");
    // Reference: remove state 4 and solve the remaining full-rank system.
    let keep: Vec<usize> = (0..n).filter(|&i| i != 4).collect();
    let hr: Dense = keep
        .iter()
        .map(|&i| keep.iter().map(|&j| h[i][j]).collect())
        .collect();
    let br: Vec<f64> = keep.iter().map(|&i| b[i]).collect();
    let xr = gauss_solve(&hr, &br);
    let x_kept: Vec<f64> = keep.iter().map(|&i| x[i]).collect();
    assert!(max_abs_diff(&x_kept, &xr) < 1e-9, "{x_kept:?} vs {xr:?}");
    // Still a least-squares solution: H x == b because b lies in the range of H.
    assert!(max_abs_diff(&matvec(&h, &x), &b) < 1e-9);
}

#[test]
fn zero_matrix_and_bad_shapes_are_data_or_errors() {
    let mut f = Ldlt::<4>::new();
    let h = [[0.0; 4]; 4];
    f.load_upper(&h, 4).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert_eq!(rep.rank, 0);
    assert_eq!((rep.min_pivot, rep.max_pivot), (0.0, 0.0));
    let mut x = [1.0, 2.0, 3.0, 4.0];
    f.solve_in_place(&mut x).unwrap();
    assert_eq!(x, [0.0; 4]);
    assert_eq!(f.solve_in_place(&mut x[..3]), Err(Error::DimensionMismatch));
    assert_eq!(f.load_upper(&h, 5), Err(Error::CapacityExceeded));
    f.load_upper(&h, 0).unwrap();
    let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
    assert!(rep.positive_definite && rep.n == 0);
    assert_eq!(
        f.factorize(PivotFloor {
            relative: -1.0,
            absolute: 0.0
        }),
        Err(Error::InvalidConfig)
    );
}

#[test]
fn marquardt_damping_scales_the_clamped_diagonal() {
    let mut h = [[0.0; 3]; 3];
    h[0][0] = 4.0;
    h[1][1] = 0.0; // clamped up to diag_min
    h[2][2] = 1e40; // clamped down to diag_max
    let mut f = Ldlt::<3>::new();
    f.load_upper(&h, 3).unwrap();
    f.add_marquardt_damping(0.5, 1e-6, 1e32).unwrap();
    f.factorize(PivotFloor {
        relative: 0.0,
        absolute: 0.0,
    })
    .unwrap();
    assert_eq!(f.pivot(0), Some(6.0));
    assert_eq!(f.pivot(1), Some(0.5e-6));
    assert_eq!(f.pivot(2), Some(1e40 + 0.5e32));
    assert_eq!(
        f.add_marquardt_damping(0.5, 1e-6, 1e32),
        Err(Error::InvalidConfig),
        "damping a factored matrix would be silently wrong"
    );
}

#[test]
fn deterministic_bitwise() {
    let mut rng = Rng::new(3);
    let n = 50;
    let h = random_spd(&mut rng, n, 60, 0.1);
    let b: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
    let mut ne = Box::new(NormalEquations::<64>::new());
    load_ne(&mut ne, &h, &b);
    let solve = |ne: &NormalEquations<64>| {
        let mut f = Box::new(Ldlt::<64>::new());
        f.load(ne).unwrap();
        f.factorize(PivotFloor::DEFAULT).unwrap();
        let mut x = b.clone();
        f.solve_in_place(&mut x).unwrap();
        x
    };
    let (x1, x2) = (solve(&ne), solve(&ne));
    assert!(x1.iter().zip(&x2).all(|(a, b)| a.to_bits() == b.to_bits()));
}

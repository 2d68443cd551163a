//! Normal-equation assembly against dense `J^T J` / `-J^T r` of the stacked Jacobian.
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
mod solver_support;

use povins_core::solver::{JacobianBlock, NormalEquations};
use povins_core::Error;
use solver_support::*;

const D: usize = 166;

/// Window-like layout: 10 keyframes x 15 states, then 6 extrinsic, then 10 time delays.
fn pose_col(k: usize) -> usize {
    15 * k
}

#[test]
fn block_assembly_equals_dense_stacked_jacobian() {
    let mut rng = Rng::new(5);
    let n = D;
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(n).unwrap();
    // Stacked dense Jacobian of every residual, for the reference.
    let mut j_all: Dense = Vec::new();
    let mut r_all: Vec<f64> = Vec::new();
    for f in 0..300 {
        let m = 2 + f % 2;
        let k1 = f % 10;
        let k2 = (f * 7 + 3) % 10;
        let k2 = if k2 == k1 { (k1 + 1) % 10 } else { k2 };
        // Three blocks: pose of k1 (6), pose of k2 (6), extrinsic (6) -- in scrambled order.
        let cols = [pose_col(k2), 150, pose_col(k1)];
        let widths = [6, 6, 6];
        let jacs: Vec<Vec<f64>> = widths
            .iter()
            .map(|&w| (0..m * w).map(|_| rng.uniform()).collect())
            .collect();
        let r: Vec<f64> = (0..m).map(|_| rng.uniform()).collect();
        let blocks: Vec<JacobianBlock> = (0..3)
            .map(|b| JacobianBlock::new(cols[b], widths[b], &jacs[b]))
            .collect();
        ne.add_blocks(&r, &blocks).unwrap();
        for row in 0..m {
            let mut full = vec![0.0; n];
            for b in 0..3 {
                for i in 0..widths[b] {
                    full[cols[b] + i] += jacs[b][row * widths[b] + i];
                }
            }
            j_all.push(full);
            r_all.push(r[row]);
        }
    }
    // A 15-wide IMU-like factor between consecutive keyframes through the dense path, with
    // scattered (non-contiguous) columns including a time-delay state.
    for k in 0..9 {
        let m = 15;
        let mut cols: Vec<usize> = (0..15).map(|i| pose_col(k) + i).collect();
        cols.extend((0..15).map(|i| pose_col(k + 1) + i));
        cols.push(156 + k);
        let kk = cols.len();
        let jac: Vec<f64> = (0..m * kk).map(|_| rng.uniform()).collect();
        let r: Vec<f64> = (0..m).map(|_| rng.uniform()).collect();
        ne.add_residual(&r, &jac, &cols, m, kk).unwrap();
        for row in 0..m {
            let mut full = vec![0.0; n];
            for (a, &c) in cols.iter().enumerate() {
                full[c] += jac[row * kk + a];
            }
            j_all.push(full);
            r_all.push(r[row]);
        }
    }
    let h_ref = ata(&j_all);
    let b_ref: Vec<f64> = transpose_matvec(&j_all, &r_all)
        .iter()
        .map(|v| -v)
        .collect();
    let cost_ref: f64 = r_all.iter().map(|v| v * v).sum();
    let mut worst = 0.0_f64;
    for i in 0..n {
        for j in i..n {
            worst = worst.max((ne.h[i][j] - h_ref[i][j]).abs());
        }
    }
    assert!(worst < 1e-12, "H mismatch {worst}");
    assert!(max_abs_diff(&ne.b[..n], &b_ref) < 1e-12);
    assert!((ne.cost - cost_ref).abs() < 1e-10 * cost_ref);
    // The lower triangle was never written (reset zeroed it) ...
    assert!((1..n).all(|i| (0..i).all(|j| ne.h[i][j] == 0.0)));
    // ... until symmetrize mirrors it.
    ne.symmetrize();
    for i in 0..n {
        for j in 0..n {
            assert_eq!(ne.h[i][j], ne.h[j.min(i)][j.max(i)]);
        }
    }
    // Quadratic form and dot with b match the dense reference.
    let x: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
    let q_ref: f64 = x.iter().zip(matvec(&h_ref, &x)).map(|(a, b)| a * b).sum();
    assert!((ne.quadratic_form(&x).unwrap() - q_ref).abs() < 1e-9 * q_ref.abs());
    let d_ref: f64 = x.iter().zip(&b_ref).map(|(a, b)| a * b).sum();
    assert!((ne.dot_b(&x).unwrap() - d_ref).abs() < 1e-10);
}

#[test]
fn duplicate_columns_add_like_the_summed_jacobian() {
    // J = [1, 2] on columns [3, 3] is the scalar Jacobian 3 on state 3: H33 = 9, b3 = -3 r.
    let mut ne = NormalEquations::<4>::new();
    ne.reset(4).unwrap();
    ne.add_residual(&[2.0], &[1.0, 2.0], &[3, 3], 1, 2).unwrap();
    assert_eq!(ne.h[3][3], 9.0);
    assert_eq!(ne.b[3], -6.0);
    assert_eq!(ne.cost, 4.0);
}

#[test]
fn every_invalid_input_is_rejected_without_side_effects() {
    let mut ne = NormalEquations::<6>::new();
    ne.reset(5).unwrap();
    let j = [1.0; 6];
    let bad = [
        ne.clone()
            .add_blocks(&[1.0, 2.0], &[JacobianBlock::new(0, 2, &j)]), // 2x2 needs 4
        ne.clone()
            .add_blocks(&[1.0], &[JacobianBlock::new(4, 2, &j[..2])]), // past n
        ne.clone()
            .add_blocks(&[1.0], &[JacobianBlock::new(usize::MAX, 2, &j[..2])]),
        ne.clone()
            .add_blocks(&[f64::INFINITY], &[JacobianBlock::new(0, 2, &j[..2])]),
        ne.clone().add_residual(&[1.0], &j[..2], &[0, 5], 1, 2),
        ne.clone().add_residual(&[1.0], &j[..3], &[0, 1], 1, 2),
        ne.clone()
            .add_residual(&[1.0], &[f64::NAN, 1.0], &[0, 1], 1, 2),
        ne.clone().add_to_diagonal(5, 1.0),
        ne.clone().quadratic_form(&[0.0; 4]).map(|_| ()),
    ];
    assert_eq!(
        bad,
        [
            Err(Error::DimensionMismatch),
            Err(Error::DimensionMismatch),
            Err(Error::DimensionMismatch),
            Err(Error::NonFinite),
            Err(Error::DimensionMismatch),
            Err(Error::DimensionMismatch),
            Err(Error::NonFinite),
            Err(Error::DimensionMismatch),
            Err(Error::DimensionMismatch),
        ]
    );
    // Failing calls on the real object leave it untouched.
    let jn = [1.0, f64::NAN];
    assert!(ne
        .add_blocks(
            &[1.0],
            &[
                JacobianBlock::new(0, 2, &j[..2]),
                JacobianBlock::new(2, 2, &jn)
            ]
        )
        .is_err());
    assert!(ne.h.iter().flatten().all(|v| *v == 0.0) && ne.b.iter().all(|v| *v == 0.0));
    assert_eq!(ne.cost, 0.0);
    assert_eq!(ne.get(0, 5), None);
}

/// The 2x6 fast path accumulates exactly what the general block path does (any column order,
/// two or three blocks), and rejects overlapping or out-of-range blocks without side effects.
#[test]
fn fast_2x6_path_equals_general_block_path() {
    let mut rng = Rng::new(77);
    let mut fast: Box<NormalEquations<40>> = Box::new(NormalEquations::new());
    let mut slow: Box<NormalEquations<40>> = Box::new(NormalEquations::new());
    fast.reset(40).unwrap();
    slow.reset(40).unwrap();
    let col_sets: [&[usize]; 4] = [&[0, 12, 30], &[30, 6, 18], &[24, 3], &[10, 34, 20]];
    for cols in col_sets {
        let r = nalgebra::Vector2::new(rng.uniform(), rng.uniform());
        let jacs: Vec<nalgebra::Matrix2x6<f64>> = cols
            .iter()
            .map(|_| nalgebra::Matrix2x6::from_fn(|_, _| rng.uniform()))
            .collect();
        fast.add_2x6_blocks(&r, &jacs, cols).unwrap();
        let rows: Vec<Vec<f64>> = jacs
            .iter()
            .map(|j| {
                (0..2)
                    .flat_map(|i| (0..6).map(move |k| j[(i, k)]))
                    .collect()
            })
            .collect();
        let blocks: Vec<JacobianBlock<'_>> = cols
            .iter()
            .zip(&rows)
            .map(|(&c, j)| JacobianBlock::new(c, 6, j))
            .collect();
        slow.add_blocks(r.as_slice(), &blocks).unwrap();
    }
    for i in 0..40 {
        for j in i..40 {
            assert!((fast.h[i][j] - slow.h[i][j]).abs() < 1e-12, "h[{i}][{j}]");
        }
        assert!((fast.b[i] - slow.b[i]).abs() < 1e-12, "b[{i}]");
    }
    assert!((fast.cost - slow.cost).abs() < 1e-12);
    let before = fast.cost;
    let r = nalgebra::Vector2::new(1.0, 2.0);
    let j = nalgebra::Matrix2x6::from_element(1.0);
    assert_eq!(
        fast.add_2x6_blocks(&r, &[j, j], &[0, 3]),
        Err(Error::DimensionMismatch)
    );
    assert_eq!(
        fast.add_2x6_blocks(&r, &[j], &[36]),
        Err(Error::DimensionMismatch)
    );
    assert_eq!(
        fast.add_2x6_blocks(&nalgebra::Vector2::new(f64::NAN, 0.0), &[j], &[0]),
        Err(Error::NonFinite)
    );
    assert_eq!(fast.cost, before);
}

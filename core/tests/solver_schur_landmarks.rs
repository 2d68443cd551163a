//! Inverse-depth Schur elimination equals solving the joint pose + landmark system.
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
mod solver_support;

use povins_core::solver::{JacobianBlock, LandmarkSchur, Ldlt, NormalEquations, PivotFloor};
use povins_core::Error;
use solver_support::*;

const D: usize = 64;

#[test]
fn folded_system_and_back_substitution_equal_the_joint_solve() {
    let mut rng = Rng::new(33);
    let n_pose = 5 * 6 + 6; // 5 poses of 6 + an extrinsic block
    let n_lm = 12;
    let n = n_pose + n_lm;
    // Joint system over [poses | inverse depths], via the stacked dense Jacobian.
    let mut j_all: Dense = Vec::new();
    let mut r_all = Vec::new();
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(n_pose).unwrap();
    let mut landmarks: Vec<LandmarkSchur<30>> = Vec::new();
    for l in 0..n_lm {
        let mut lm = LandmarkSchur::<30>::new();
        let host = l % 5;
        for obs in 0..3 {
            let target = (host + 1 + obs) % 5;
            let blocks_cols = [6 * target, 6 * host, 30];
            let jacs: Vec<Vec<f64>> = (0..3)
                .map(|_| (0..12).map(|_| rng.uniform()).collect())
                .collect();
            let jl: Vec<f64> = (0..2).map(|_| rng.uniform()).collect();
            let r: Vec<f64> = (0..2).map(|_| rng.uniform()).collect();
            let blocks: Vec<JacobianBlock> = (0..3)
                .map(|b| JacobianBlock::new(blocks_cols[b], 6, &jacs[b]))
                .collect();
            lm.add_residual(&mut ne, &r, &blocks, &jl).unwrap();
            for row in 0..2 {
                let mut full = vec![0.0; n];
                for b in 0..3 {
                    for i in 0..6 {
                        full[blocks_cols[b] + i] += jacs[b][row * 6 + i];
                    }
                }
                full[n_pose + l] = jl[row];
                j_all.push(full);
                r_all.push(r[row]);
            }
        }
        // host + 3 targets (distinct from host) + extrinsic
        assert_eq!(lm.coupling().0.len(), 6 * 4 + 6);
        landmarks.push(lm);
    }
    // A weak prior on every pose state fixes the gauge of the joint problem.
    for i in 0..n_pose {
        let mut full = vec![0.0; n];
        full[i] = 0.1;
        j_all.push(full);
        r_all.push(0.0);
        ne.add_residual(&[0.0], &[0.1], &[i], 1, 1).unwrap();
    }
    let h = ata(&j_all);
    let b: Vec<f64> = transpose_matvec(&j_all, &r_all)
        .iter()
        .map(|v| -v)
        .collect();
    let x = gauss_solve(&h, &b);

    for lm in &landmarks {
        assert!(lm.fold_into(&mut ne, 0.0).unwrap());
    }
    let mut f = Box::new(Ldlt::<D>::new());
    f.load(&ne).unwrap();
    assert!(f.factorize(PivotFloor::DEFAULT).unwrap().positive_definite);
    let mut dx = ne.b[..n_pose].to_vec();
    f.solve_in_place(&mut dx).unwrap();
    assert!(
        max_abs_diff(&dx, &x[..n_pose]) < 1e-9 * (1.0 + max_abs(&x)),
        "poses differ"
    );
    for (l, lm) in landmarks.iter().enumerate() {
        let dtau = lm.back_substitute(&dx, 0.0).unwrap();
        assert!(
            (dtau - x[n_pose + l]).abs() < 1e-9 * (1.0 + max_abs(&x)),
            "landmark {l}"
        );
    }
    // The reduced H equals the dense Schur complement H_pp - H_pl H_ll^-1 H_lp (H_ll diagonal).
    for i in 0..n_pose {
        for k in i..n_pose {
            let mut s = h[i][k];
            for l in n_pose..n {
                s -= h[i][l] * h[l][k] / h[l][l];
            }
            assert!(
                (ne.h[i][k] - s).abs() < 1e-12 * (1.0 + s.abs()),
                "({i},{k})"
            );
        }
    }
}

#[test]
fn unobserved_depth_is_skipped_and_capacity_is_enforced() {
    let mut ne = NormalEquations::<12>::new();
    ne.reset(12).unwrap();
    let mut lm = LandmarkSchur::<6>::new();
    let jp = [1.0; 12];
    // j_l = 0: the depth is invisible -> H_lp = 0 and nothing to fold.
    lm.add_residual(
        &mut ne,
        &[1.0, 2.0],
        &[JacobianBlock::new(0, 6, &jp)],
        &[0.0, 0.0],
    )
    .unwrap();
    let before = ne.clone();
    assert!(!lm.fold_into(&mut ne, 0.0).unwrap());
    assert_eq!(ne.h, before.h);
    assert_eq!(lm.back_substitute(&[0.0; 12], 0.0), Ok(0.0));
    // A second pose block would exceed the 6 columns of capacity: nothing is added anywhere.
    let cost = ne.cost;
    assert_eq!(
        lm.add_residual(
            &mut ne,
            &[1.0, 2.0],
            &[JacobianBlock::new(6, 6, &jp)],
            &[1.0, 1.0]
        ),
        Err(Error::CapacityExceeded)
    );
    assert_eq!((ne.cost, lm.h_ll()), (cost, 0.0));
    assert_eq!(
        lm.add_residual(&mut ne, &[1.0], &[], &[1.0, 1.0]),
        Err(Error::DimensionMismatch)
    );
    assert_eq!(
        lm.back_substitute(&[0.0; 3], 0.0),
        Err(Error::DimensionMismatch)
    );
}

#[test]
fn damping_scales_the_landmark_diagonal() {
    let mut ne = NormalEquations::<2>::new();
    ne.reset(2).unwrap();
    let mut lm = LandmarkSchur::<2>::new();
    // r = 1, J_p = [1, 0], j_l = 2: H_ll = 4, H_lp = [2, 0], b_l = -2.
    lm.add_residual(
        &mut ne,
        &[1.0],
        &[JacobianBlock::new(0, 2, &[1.0, 0.0])],
        &[2.0],
    )
    .unwrap();
    assert_eq!((lm.h_ll(), lm.b_l()), (4.0, -2.0));
    lm.fold_into(&mut ne, 1.0).unwrap(); // H_ll -> 8
    assert_eq!(ne.h[0][0], 1.0 - 2.0 * 2.0 / 8.0);
    assert_eq!(ne.b[0], -1.0 - 2.0 * -2.0 / 8.0);
    assert_eq!(
        lm.back_substitute(&[0.5, 0.0], 1.0),
        Ok((-2.0 - 2.0 * 0.5) / 8.0)
    );
}

#[test]
fn two_block_fast_path_equals_the_general_path() {
    let mut rng = Rng::new(71);
    let mut general = Box::new(NormalEquations::<D>::new());
    let mut fast = Box::new(NormalEquations::<D>::new());
    general.reset(36).unwrap();
    fast.reset(36).unwrap();
    let (mut lg, mut lf) = (LandmarkSchur::<30>::new(), LandmarkSchur::<30>::new());
    // A host block and three targets, the host sometimes after the target (column order).
    for (host, target) in [(12, 0), (12, 24), (12, 30), (12, 24)] {
        let a: Vec<f64> = (0..12).map(|_| rng.uniform()).collect();
        let c: Vec<f64> = (0..12).map(|_| rng.uniform()).collect();
        let r = [rng.uniform(), rng.uniform()];
        let jl = [rng.uniform(), rng.uniform()];
        lg.add_residual(
            &mut general,
            &r,
            &[
                JacobianBlock::new(host, 6, &a),
                JacobianBlock::new(target, 6, &c),
            ],
            &jl,
        )
        .unwrap();
        let m = |v: &[f64]| nalgebra::Matrix2x6::from_row_slice(v);
        lf.add_residual_2x6(
            &mut fast,
            &nalgebra::Vector2::new(r[0], r[1]),
            &[m(&a), m(&c)],
            [host, target],
            &nalgebra::Vector2::new(jl[0], jl[1]),
        )
        .unwrap();
    }
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + x.abs());
    assert!(close(lg.h_ll(), lf.h_ll()) && close(lg.b_l(), lf.b_l()));
    assert_eq!(lg.coupling().0, lf.coupling().0);
    for (x, y) in lg.coupling().1.iter().zip(lf.coupling().1) {
        assert!(close(*x, *y));
    }
    for i in 0..36 {
        assert!(close(general.b[i], fast.b[i]), "b[{i}]");
        for j in i..36 {
            assert!(close(general.h[i][j], fast.h[i][j]), "h[{i}][{j}]");
        }
    }
    // A fifth block does not fit a 30-column accumulator: refused, nothing added.
    let mut small = LandmarkSchur::<12>::new();
    let z = nalgebra::Matrix2x6::from_element(1.0);
    let v = nalgebra::Vector2::new(1.0, 1.0);
    small
        .add_residual_2x6(&mut fast, &v, &[z, z], [0, 6], &v)
        .unwrap();
    let before = fast.h;
    assert_eq!(
        small.add_residual_2x6(&mut fast, &v, &[z, z], [18, 24], &v),
        Err(Error::CapacityExceeded)
    );
    assert_eq!(fast.h, before);
}

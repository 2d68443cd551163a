//! Marginalization: Schur complement, square-root prior, and re-adding the prior.
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
mod solver_support;

use povins_core::solver::{
    add_prior, schur_complement, schur_complement_in_place, sqrt_prior, Ldlt, NormalEquations,
    PivotFloor,
};
use povins_core::Error;
use solver_support::*;

const D: usize = 166;

/// Linear-Gaussian problem `min |J x + r|^2` with a banded, window-like random `J`.
fn window_problem(rng: &mut Rng, n: usize, rows: usize) -> (Dense, Vec<f64>) {
    let mut j = zeros(rows, n);
    for (i, row) in j.iter_mut().enumerate() {
        let c0 = (i * 7) % n;
        for c in 0..24 {
            row[(c0 + c) % n] = rng.uniform();
        }
    }
    let r: Vec<f64> = (0..rows).map(|_| rng.uniform()).collect();
    (j, r)
}

fn normal_equations(j: &Dense, r: &[f64], ne: &mut NormalEquations<D>) {
    let n = j[0].len();
    ne.reset(n).unwrap();
    let cols: Vec<usize> = (0..n).collect();
    for (row, &ri) in j.iter().zip(r) {
        ne.add_residual(&[ri], row, &cols, 1, n).unwrap();
    }
}

#[test]
fn marginal_solution_equals_full_solution_and_prior_reproduces_h_star() {
    let mut rng = Rng::new(21);
    for &(n, m) in &[(6usize, 2usize), (40, 15), (166, 16), (166, 0), (30, 30)] {
        let (j, r) = window_problem(&mut rng, n, 3 * n);
        let mut ne = Box::new(NormalEquations::<D>::new());
        normal_equations(&j, &r, &mut ne);
        let h = ne_dense(&ne);
        let b = ne.b[..n].to_vec();
        let x_full = gauss_solve(&h, &b);

        let mut star = Box::new(NormalEquations::<D>::new());
        let rep = schur_complement(&ne, m, PivotFloor::DEFAULT, &mut star).unwrap();
        assert_eq!((rep.n, rep.rank), (m, m));
        let p = n - m;
        assert_eq!(star.dim(), p);
        // Reference Schur complement with dense inverse-free solves.
        let hs = ne_dense(&star);
        let x_marg = gauss_solve(&hs, &star.b[..p]);
        assert!(
            max_abs_diff(&x_marg, &x_full[m..]) < 1e-9 * (1.0 + max_abs(&x_full)),
            "n={n} m={m}"
        );
        // c* is the minimum over x_m of the quadratic model at x_r = 0.
        if m > 0 {
            let hmm: Dense = (0..m).map(|i| h[i][..m].to_vec()).collect();
            let xm = gauss_solve(&hmm, &b[..m]);
            let c_star = ne.cost - xm.iter().zip(&b[..m]).map(|(a, b)| a * b).sum::<f64>();
            assert!(
                (star.cost - c_star).abs() < 1e-9 * ne.cost,
                "{} {}",
                star.cost,
                c_star
            );
        }

        // Square-root prior.
        let mut ws = Box::new(Ldlt::<D>::new());
        let mut j0 = Box::new([[0.0; D]; D]);
        let mut r0 = vec![0.0; p];
        let rep = sqrt_prior(&star, PivotFloor::DEFAULT, &mut ws, &mut j0, &mut r0).unwrap();
        assert!(rep.positive_definite);
        let j0d: Dense = (0..p).map(|i| j0[i][..p].to_vec()).collect();
        for i in 0..p {
            for k in 0..i {
                assert_eq!(j0d[i][k], 0.0, "J0 is upper triangular");
            }
        }
        let jtj = ata(&j0d);
        let scale = hs.iter().flatten().fold(0.0_f64, |a, v| a.max(v.abs()));
        for i in 0..p {
            assert!(
                max_abs_diff(&jtj[i], &hs[i]) < 1e-12 * scale,
                "J0^T J0 != H*"
            );
        }
        let jtr = transpose_matvec(&j0d, &r0);
        let minus_b: Vec<f64> = star.b[..p].iter().map(|v| -v).collect();
        assert!(max_abs_diff(&jtr, &minus_b) < 1e-10 * (1.0 + max_abs(&minus_b)));

        // The prior at dx = 0 rebuilds (H*, b*); at dx != 0 the gradient moves by -H* dx.
        let cols: Vec<usize> = (0..p).collect();
        let mut again = Box::new(NormalEquations::<D>::new());
        again.reset(p).unwrap();
        add_prior(&mut again, &j0, &r0, &vec![0.0; p], &cols).unwrap();
        assert!(max_abs_diff(&again.b[..p], &star.b[..p]) < 1e-10 * (1.0 + max_abs(&minus_b)));
        let dx: Vec<f64> = (0..p).map(|_| 0.01 * rng.uniform()).collect();
        again.reset(p).unwrap();
        add_prior(&mut again, &j0, &r0, &dx, &cols).unwrap();
        let hdx = matvec(&hs, &dx);
        let want: Vec<f64> = star.b[..p].iter().zip(&hdx).map(|(b, hd)| b - hd).collect();
        assert!(max_abs_diff(&again.b[..p], &want) < 1e-10 * (1.0 + max_abs(&want)));
        for i in 0..p {
            for k in i..p {
                assert!((again.h[i][k] - hs[i][k]).abs() < 1e-12 * scale);
            }
        }
        // Solving the prior alone gives the same remaining-state solution.
        again.reset(p).unwrap();
        add_prior(&mut again, &j0, &r0, &vec![0.0; p], &cols).unwrap();
        let x_prior = gauss_solve(&ne_dense(&again), &again.b[..p]);
        assert!(max_abs_diff(&x_prior, &x_full[m..]) < 1e-8 * (1.0 + max_abs(&x_full)));
    }
}

#[test]
fn in_place_and_copying_variants_agree_bitwise() {
    let mut rng = Rng::new(4);
    let (j, r) = window_problem(&mut rng, 50, 150);
    let mut ne = Box::new(NormalEquations::<D>::new());
    normal_equations(&j, &r, &mut ne);
    let mut out = Box::new(NormalEquations::<D>::new());
    schur_complement(&ne, 15, PivotFloor::DEFAULT, &mut out).unwrap();
    schur_complement_in_place(&mut ne, 15, PivotFloor::DEFAULT).unwrap();
    assert_eq!(ne.dim(), 35);
    for i in 0..35 {
        for k in i..35 {
            assert_eq!(ne.h[i][k].to_bits(), out.h[i][k].to_bits());
        }
        assert_eq!(ne.b[i].to_bits(), out.b[i].to_bits());
    }
}

#[test]
fn gauge_in_marginalized_block_is_floored_not_amplified() {
    // States 0 and 1 only ever appear as x0 + x1 (a gauge); marginalizing them must not inject
    // 1/eps information into the remaining states.
    let mut rng = Rng::new(9);
    let n = 10;
    let (mut j, r) = window_problem(&mut rng, n, 40);
    for row in j.iter_mut() {
        row[1] = row[0];
    }
    let mut ne = Box::new(NormalEquations::<D>::new());
    normal_equations(&j, &r, &mut ne);
    let mut out = Box::new(NormalEquations::<D>::new());
    let rep = schur_complement(
        &ne,
        2,
        PivotFloor {
            relative: 1e-9,
            absolute: 0.0,
        },
        &mut out,
    )
    .unwrap();
    assert_eq!(rep.rank, 1);
    assert!(!rep.positive_definite);
    // Reference: the same problem with the duplicate column removed (x1 := 0).
    let jr: Dense = j
        .iter()
        .map(|row| [&row[..1], &row[2..]].concat())
        .collect();
    let mut ner = Box::new(NormalEquations::<D>::new());
    normal_equations(&jr, &r, &mut ner);
    let mut outr = Box::new(NormalEquations::<D>::new());
    schur_complement(&ner, 1, PivotFloor::DEFAULT, &mut outr).unwrap();
    let (a, b) = (ne_dense(&out), ne_dense(&outr));
    for i in 0..8 {
        assert!(
            max_abs_diff(&a[i], &b[i]) < 1e-9,
            "{:?} vs {:?}",
            a[i],
            b[i]
        );
    }
    assert!(max_abs_diff(&out.b[..8], &outr.b[..8]) < 1e-9);
}

#[test]
fn invalid_inputs_are_errors() {
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(4).unwrap();
    let mut out = Box::new(NormalEquations::<D>::new());
    assert_eq!(
        schur_complement(&ne, 5, PivotFloor::DEFAULT, &mut out),
        Err(Error::DimensionMismatch)
    );
    ne.h[1][2] = f64::NAN;
    assert_eq!(
        schur_complement_in_place(&mut ne, 1, PivotFloor::DEFAULT),
        Err(Error::NonFinite)
    );
    assert_eq!(ne.dim(), 4, "unchanged on error");
    let j0 = Box::new([[0.0; D]; D]);
    assert_eq!(
        add_prior(&mut ne, &j0, &[0.0; 2], &[0.0; 2], &[3, 4]),
        Err(Error::DimensionMismatch)
    );
    assert_eq!(
        add_prior(&mut ne, &j0, &[f64::NAN, 0.0], &[0.0; 2], &[2, 3]),
        Err(Error::NonFinite)
    );
    let mut ws = Box::new(Ldlt::<D>::new());
    let mut j0m = Box::new([[0.0; D]; D]);
    assert_eq!(
        sqrt_prior(&out, PivotFloor::DEFAULT, &mut ws, &mut j0m, &mut [0.0; 3]),
        Err(Error::DimensionMismatch)
    );
}

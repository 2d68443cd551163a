//! The one numerical differentiation of the core's tests: central differences. Every analytic
//! Jacobian the tests check (the factor conformance suite, the camera, the LiDAR-depth
//! measurements, the solver's test problems) is checked against [`central_differences`].
#![allow(dead_code)]

use nalgebra::SMatrix;

/// The `m x n` Jacobian (row-major) of `f` at the origin of its perturbation `dx` (length `n`)
/// by central differences with step `h`: column `c` is `(f(h e_c) - f(-h e_c)) / (2 h)`. Returns
/// `m` (the length of `f`'s value, the same at every perturbation) and the Jacobian.
pub fn central_differences(
    n: usize,
    h: f64,
    mut f: impl FnMut(&[f64]) -> Vec<f64>,
) -> (usize, Vec<f64>) {
    let mut m = 0;
    let mut jac = Vec::new();
    let mut dx = vec![0.0; n];
    for c in 0..n {
        dx[c] = h;
        let plus = f(&dx);
        dx[c] = -h;
        let minus = f(&dx);
        dx[c] = 0.0;
        assert_eq!(plus.len(), minus.len(), "the function's length changed");
        if c == 0 {
            m = plus.len();
            jac = vec![0.0; m * n];
        }
        assert_eq!(plus.len(), m, "the function's length changed");
        for (r, (p, q)) in plus.iter().zip(&minus).enumerate() {
            jac[r * n + c] = (p - q) / (2.0 * h);
        }
    }
    (m, jac)
}

/// [`central_differences`] of a function with a fixed-size value and perturbation.
pub fn num_jac<const R: usize, const C: usize>(
    h: f64,
    mut f: impl FnMut(&[f64; C]) -> SMatrix<f64, R, 1>,
) -> SMatrix<f64, R, C> {
    let (m, jac) = central_differences(C, h, |dx| {
        let dx: &[f64; C] = dx.try_into().expect("perturbation of C entries");
        f(dx).iter().copied().collect()
    });
    assert_eq!(m, R);
    SMatrix::from_row_slice(&jac)
}

//! Huber kernel and time-delay random-walk factor.

use nalgebra::{SMatrix, SVector};
use povins_core::factors::robust::Huber;
use povins_core::factors::td::TdRandomWalk;
use povins_core::Error;

#[test]
fn huber_values_and_derivatives() {
    let k = Huber::new(1.5).unwrap();
    assert_eq!(k.rho(1.0), [1.0, 1.0, 0.0]);
    // Outside: rho = 2 delta sqrt(s) - delta^2.
    let [r, r1, r2] = k.rho(16.0);
    assert!((r - (2.0 * 1.5 * 4.0 - 2.25)).abs() < 1e-12);
    assert!((r1 - 1.5 / 4.0).abs() < 1e-15);
    assert!((r2 - (-1.5 / (2.0 * 64.0))).abs() < 1e-15);
    // Continuity of rho and rho' at the threshold.
    let d2 = 2.25;
    let (a, b) = (k.rho(d2 * (1.0 - 1e-12)), k.rho(d2 * (1.0 + 1e-12)));
    assert!((a[0] - b[0]).abs() < 1e-10 && (a[1] - b[1]).abs() < 1e-10);
    // rho' and rho'' against central differences, both sides.
    for s in [0.3, 1.7, 5.0, 40.0] {
        let h = 1e-6 * s;
        let num1 = (k.rho(s + h)[0] - k.rho(s - h)[0]) / (2.0 * h);
        let num2 = (k.rho(s + h)[1] - k.rho(s - h)[1]) / (2.0 * h);
        assert!((num1 - k.rho(s)[1]).abs() < 1e-7, "rho' at {s}");
        assert!((num2 - k.rho(s)[2]).abs() < 1e-7, "rho'' at {s}");
    }
    assert!(Huber::new(0.0).is_err() && Huber::new(f64::NAN).is_err());
}

#[test]
fn huber_irls_rescaling() {
    let k = Huber::new(1.0).unwrap();
    let mut r = SVector::<f64, 2>::new(3.0, 4.0);
    let mut j = SMatrix::<f64, 2, 3>::from_element(2.0);
    let s = r.norm_squared();
    let w = k.rescale(s, &mut r, &mut j);
    // rho' = 1/5, sqrt = 0.4472...
    assert!((w - libm::sqrt(0.2)).abs() < 1e-15);
    assert!((r.norm_squared() - 0.2 * 25.0).abs() < 1e-12);
    assert!((j[(0, 0)] - 2.0 * libm::sqrt(0.2)).abs() < 1e-15);
    // IRLS gradient J^T (w r) equals rho'(s) J^T r, the exact gradient of rho(|r|^2)/2.
    let mut r_in = SVector::<f64, 2>::new(0.3, 0.4);
    let mut j_in = SMatrix::<f64, 2, 3>::from_element(1.0);
    assert_eq!(k.rescale(r_in.norm_squared(), &mut r_in, &mut j_in), 1.0);
    assert_eq!(r_in, SVector::<f64, 2>::new(0.3, 0.4));
}

#[test]
fn td_random_walk() {
    let q = 1e-4 * 1e-4;
    let f = TdRandomWalk::new(q, 0.25).unwrap();
    let (r, j) = f.evaluate(0.003, 0.001).unwrap();
    let sigma = libm::sqrt(q * 0.25); // 5e-5 s
    assert!((r - 0.002 / sigma).abs() < 1e-9, "{r}");
    let h = 1e-7;
    let n0 = (f.evaluate(0.003 + h, 0.001).unwrap().0 - f.evaluate(0.003 - h, 0.001).unwrap().0)
        / (2.0 * h);
    let n1 = (f.evaluate(0.003, 0.001 + h).unwrap().0 - f.evaluate(0.003, 0.001 - h).unwrap().0)
        / (2.0 * h);
    assert!((j[0] - n0).abs() < 1e-6 * n0.abs() && (j[1] - n1).abs() < 1e-6 * n1.abs());
    assert_eq!(TdRandomWalk::new(q, 0.0), Err(Error::InvalidConfig));
    assert_eq!(TdRandomWalk::new(-q, 0.1), Err(Error::InvalidConfig));
    assert_eq!(f.evaluate(f64::NAN, 0.0), Err(Error::NonFinite));
}

//! Equal-angle cell index of a tangent without an `atan` per point.
//!
//! An axis of `N` cells of `c` rad centred on 0 has lower boundaries `a_i = (i - N/2) c`. Cell
//! `i` holds the angles in `[a_i, a_(i+1))`, i.e. the tangents `u` in `[tan a_i, tan a_(i+1))`
//! (tangent is increasing on `(-pi/2, pi/2)`; boundaries beyond are `-inf`/`+inf`). The index is
//! guessed from a polynomial `atan` (max error 1e-5 rad, far below a cell) and then corrected
//! against the tabulated boundaries, so the answer is exactly the cell of the table whatever the
//! approximation's error, and bit-reproducible (only `+ - * /` and comparisons).

use core::f64::consts::FRAC_PI_2;

/// Fills `lower[i] = tan((i - N/2) c)` and returns `tan((N - N/2) c)`, the upper bound of the
/// last cell (`N = lower.len()`).
pub(crate) fn fill_tan_table(lower: &mut [f64], cell_rad: f64) -> f64 {
    let half = lower.len() as f64 * 0.5;
    let tan_at = |i: f64| {
        let a = (i - half) * cell_rad;
        if a <= -FRAC_PI_2 {
            f64::NEG_INFINITY
        } else if a >= FRAC_PI_2 {
            f64::INFINITY
        } else {
            libm::tan(a)
        }
    };
    for (i, t) in lower.iter_mut().enumerate() {
        *t = tan_at(i as f64);
    }
    tan_at(lower.len() as f64)
}

/// Cell of tangent `u` on the axis tabulated by [`fill_tan_table`]; `None` outside (and NaN).
/// `inv_cell = 1 / c`, `half = N / 2`.
#[inline]
pub(crate) fn cell_of(
    u: f64,
    lower: &[f64],
    upper: f64,
    inv_cell: f64,
    half: f64,
) -> Option<usize> {
    let first = *lower.first()?;
    if !(u >= first && u < upper) {
        return None;
    }
    let n = lower.len();
    // Saturating cast: negative guesses become 0.
    let mut i = ((atan_approx(u) * inv_cell + half) as usize).min(n - 1);
    while i > 0 && lower.get(i).is_some_and(|&b| u < b) {
        i -= 1;
    }
    while lower.get(i + 1).is_some_and(|&b| u >= b) {
        i += 1;
    }
    Some(i)
}

/// `atan(u)` within 1e-5 rad for any finite `u`: an odd minimax polynomial on `[-1, 1]` and
/// `atan(u) = sign(u) pi/2 - atan(1/u)` outside.
#[inline]
pub(crate) fn atan_approx(u: f64) -> f64 {
    let (x, flip) = if u.abs() > 1.0 {
        (1.0 / u, true)
    } else {
        (u, false)
    };
    let x2 = x * x;
    let p = x
        * (0.999_977_26
            + x2 * (-0.332_623_47
                + x2 * (0.193_543_46
                    + x2 * (-0.116_432_87 + x2 * (0.052_653_32 + x2 * -0.011_721_20)))));
    if !flip {
        p
    } else if u > 0.0 {
        FRAC_PI_2 - p
    } else {
        -FRAC_PI_2 - p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atan_approx_is_within_1e5_rad() {
        let mut worst = 0.0f64;
        for k in -20000..=20000 {
            let u = libm::tan(k as f64 * 7.85e-5); // angles across (-pi/2, pi/2)
            worst = worst.max((atan_approx(u) - libm::atan(u)).abs());
        }
        assert!(worst < 1e-5, "worst {worst}");
        assert!(worst > 1e-8, "not an approximation? {worst}");
    }

    #[test]
    fn cell_of_equals_floor_of_exact_angle_over_cell() {
        // 0.5 deg cells, 256 of them (+-64 deg), and a coarse axis wider than pi.
        for (n, c) in [(256usize, 0.5f64.to_radians()), (7, 0.6)] {
            let mut lower = [0.0; 256];
            let lower = &mut lower[..n];
            let upper = fill_tan_table(lower, c);
            let half = n as f64 * 0.5;
            let mut hits = 0;
            for k in -30000..=30000 {
                let a = k as f64 * 5.1e-5 + 1e-7; // not on a boundary
                let u = libm::tan(a);
                let exact = libm::floor(a / c + half);
                let got = cell_of(u, lower, upper, 1.0 / c, half);
                if exact >= 0.0 && exact < n as f64 {
                    assert_eq!(got, Some(exact as usize), "n {n} a {a}");
                    hits += 1;
                } else {
                    assert_eq!(got, None, "n {n} a {a}");
                }
            }
            assert!(hits > 1000);
        }
        let mut lower = [0.0; 4];
        let upper = fill_tan_table(&mut lower, 0.1);
        for u in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300] {
            assert_eq!(cell_of(u, &lower, upper, 10.0, 2.0), None);
        }
        assert_eq!(cell_of(0.0, &[], 1.0, 10.0, 0.0), None);
    }
}

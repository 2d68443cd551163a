//! Least-squares plane through a few points: centroid `c` and unit normal `n`, the eigenvector
//! of the smallest eigenvalue of the scatter `S = sum (p_i - c)(p_i - c)^T` (total least
//! squares: it minimizes `sum (n . (p_i - c))^2`, which is that eigenvalue).

use crate::math::{Mat3, Vec3};
use nalgebra::SymmetricEigen;

/// A fitted plane `n . (p - c) = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Plane {
    pub(crate) centroid: Vec3,
    /// Unit normal.
    pub(crate) normal: Vec3,
    /// Largest `|n . (p_i - c)|`, m.
    pub(crate) max_dist_m: f64,
    /// `sqrt(mean (n . (p_i - c))^2)`, m.
    pub(crate) rms_m: f64,
}

/// The second-largest scatter eigenvalue must exceed this fraction of the largest: below, the
/// points are (nearly) collinear and the normal is not determined. 1e-4 = a spread across the
/// line of 1% of the spread along it.
const MIN_PLANARITY: f64 = 1e-4;

/// Fits a plane; `None` for fewer than 3 points, coincident or collinear points, or an
/// eigen-solver that does not converge.
pub(crate) fn fit_plane(pts: &[Vec3]) -> Option<Plane> {
    if pts.len() < 3 {
        return None;
    }
    let inv_n = 1.0 / pts.len() as f64;
    let c = pts.iter().fold(Vec3::zeros(), |a, p| a + p) * inv_n;
    let s = pts.iter().fold(Mat3::zeros(), |a, p| {
        let d = p - c;
        a + d * d.transpose()
    });
    let eig = SymmetricEigen::try_new(s, f64::EPSILON, 100)?;
    let ev = eig.eigenvalues;
    // Sort the three indices by eigenvalue (deterministic ties: lower index first).
    let mut idx = [0usize, 1, 2];
    idx.sort_unstable_by(|&a, &b| ev[a].total_cmp(&ev[b]).then(a.cmp(&b)));
    let [i_min, i_mid, i_max] = idx;
    if !(ev[i_max] > 0.0 && ev[i_mid] > MIN_PLANARITY * ev[i_max]) {
        return None;
    }
    let normal = eig
        .eigenvectors
        .column(i_min)
        .into_owned()
        .try_normalize(0.0)?;
    let (mut max_d, mut sum2) = (0.0f64, 0.0);
    for p in pts {
        let d = normal.dot(&(p - c));
        max_d = max_d.max(d.abs());
        sum2 += d * d;
    }
    let plane = Plane {
        centroid: c,
        normal,
        max_dist_m: max_d,
        rms_m: libm::sqrt(sum2 * inv_n),
    };
    plane.normal.iter().all(|v| v.is_finite()).then_some(plane)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_tilted_plane_and_reports_distances() {
        let n_true = Vec3::new(0.3, -0.4, 0.866).normalize();
        let u = n_true.cross(&Vec3::x()).normalize();
        let v = n_true.cross(&u);
        let c0 = Vec3::new(1.0, 2.0, 5.0);
        let offs = [0.01, -0.01, 0.0, 0.02, -0.02];
        let mut pts = [Vec3::zeros(); 5];
        for (k, p) in pts.iter_mut().enumerate() {
            let a = k as f64 * 1.3;
            *p = c0 + u * libm::cos(a) * 0.2 + v * libm::sin(a) * 0.1 + n_true * offs[k];
        }
        let pl = fit_plane(&pts).unwrap();
        assert!(pl.normal.dot(&n_true).abs() > 1.0 - 1e-3);
        // Offsets are symmetric and small: the fit is close to the true plane.
        assert!((pl.max_dist_m - 0.02).abs() < 0.005, "{}", pl.max_dist_m);
        assert!(
            (pl.rms_m - libm::sqrt(0.001 / 5.0)).abs() < 0.003,
            "{}",
            pl.rms_m
        );
        // Exact points: zero residual.
        let exact: [Vec3; 4] = [c0, c0 + u, c0 + v, c0 + u * 0.3 - v * 2.0];
        let pl = fit_plane(&exact).unwrap();
        assert!(pl.normal.dot(&n_true).abs() > 1.0 - 1e-12);
        assert!(pl.max_dist_m < 1e-12);
    }

    #[test]
    fn rejects_degenerate_sets() {
        let a = Vec3::new(1.0, 2.0, 3.0);
        let d = Vec3::new(0.1, 0.2, -0.3);
        assert!(fit_plane(&[a, a + d]).is_none());
        assert!(fit_plane(&[a, a, a, a]).is_none());
        assert!(fit_plane(&[a, a + d, a + d * 2.0, a - d * 0.7]).is_none());
        // Almost collinear: 0.1% across the line.
        let e = Vec3::new(0.3, 0.0, 0.1) * 1e-3;
        assert!(fit_plane(&[a, a + d, a + d * 2.0 + e, a - d]).is_none());
        assert!(fit_plane(&[a, a + d, Vec3::new(f64::NAN, 0.0, 0.0)]).is_none());
    }
}

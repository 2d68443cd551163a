//! Geometric outlier rejection between two frames on undistorted normalized points (`z = 1`),
//! with a deterministic generator (xorshift64*, seeded per frame), so results are reproducible.
//!
//! - [`two_point`]: the rotation `R_cur_prev` is known (gyro), only the translation direction
//!   `t` is unknown. With `y = R x_prev`, the epipolar constraint is
//!   `x_cur . (t x y) = t . (y x x_cur) = 0`, so `t` is orthogonal to every `m = y x x_cur`, and
//!   two points give `t = m1 x m2`. A point is an inlier when its distance to the epipolar line
//!   `l = t x y` in the current image, `|t . m| / |(l_x, l_y)|`, times the focal length is below
//!   the threshold. Pure rotation (`m ~ 0` for all points) keeps every point, as it should.
//! - [`eight_point`]: the fundamental matrix of normalized points (the essential matrix without
//!   its internal constraints) from 8 points, null vector of the 8x9 system by Gaussian
//!   elimination with full pivoting; inliers by Sampson distance. Hypotheses are scored without
//!   rank-2 enforcement. Degenerate with little translation: use the 2-point model then.
//!
//! Both stop adaptively at the iteration count that reaches `confidence` for the best inlier
//! ratio so far (and at `max_iterations`), classify every point with the best hypothesis, then
//! refit the model by least squares on its inliers (smallest eigenvector by cyclic Jacobi: of
//! `sum m m^T` for the 2-point model, of the Hartley-normalized 8-point system otherwise) and
//! re-classify, twice, keeping a refit only if it does not lose inliers.

use crate::math::Mat3;
use crate::Error;

/// Which geometric model rejects outliers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum RansacModel {
    /// No geometric check.
    Off,
    /// The 8-point model; where it is degenerate (median parallax below
    /// `eight_point_min_flow_px`: the image motion, derotated by the gyro rotation when given),
    /// the 2-point model if the gyro rotation is given, else none (default). On the real rolling-shutter DM-VIO sequence the 2-point model with the gyro
    /// rotation rejects 6.9% of the tracks at 1.5 px (11.5% with the camera delay ignored) where
    /// the 8-point model rejects 1.9%: its rejections there are mostly gyro-model error.
    #[default]
    Auto,
    /// Always the 8-point fundamental matrix.
    EightPoint,
    /// The 2-point model with the gyro rotation (no check when no rotation is given).
    TwoPoint,
}

/// RANSAC parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct RansacConfig {
    /// Model choice.
    pub model: RansacModel,
    /// Inlier threshold of the 8-point model, px (Sampson distance scaled by the mean focal
    /// length; LE-VINS: 1.5).
    pub threshold_px: f64,
    /// Inlier threshold of the 2-point model, px (epipolar distance). Larger than the 8-point's
    /// because the gyro rotation is held fixed: on the real rolling-shutter DM-VIO sequence the
    /// 2-point model rejects 6.9% of the tracks at 1.5 px and 1.6% at 3 px, the 8-point model
    /// 1.9% at 1.5 px.
    pub two_point_threshold_px: f64,
    /// Probability of drawing at least one all-inlier sample, for the adaptive stop.
    pub confidence: f64,
    /// Iteration cap.
    pub max_iterations: u32,
    /// Generator seed (mixed with the frame index).
    pub seed: u64,
    /// The 8-point model is skipped when the median parallax (the image motion, derotated by the
    /// gyro rotation when given) is below this, px: with little translation it is degenerate and
    /// would reject good tracks (see [`RansacModel::Auto`] for what runs instead).
    pub eight_point_min_flow_px: f64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            model: RansacModel::Auto,
            threshold_px: 1.5,
            two_point_threshold_px: 3.0,
            confidence: 0.99,
            max_iterations: 200,
            seed: 0x5eed_f00d_cafe_d00d,
            eight_point_min_flow_px: 3.0,
        }
    }
}

impl RansacConfig {
    /// Checks every parameter's range ([`Error::InvalidConfig`] otherwise).
    pub fn validate(&self) -> Result<(), Error> {
        let ok = self.threshold_px > 0.0
            && self.threshold_px <= 100.0
            && self.two_point_threshold_px > 0.0
            && self.two_point_threshold_px <= 100.0
            && self.confidence > 0.0
            && self.confidence < 1.0
            && (1..=100_000).contains(&self.max_iterations)
            && (0.0..=1000.0).contains(&self.eight_point_min_flow_px);
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

/// The outcome of one RANSAC run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RansacOutcome {
    /// Hypotheses drawn.
    pub iterations: u32,
    /// Points kept.
    pub inliers: u32,
    /// Points rejected.
    pub outliers: u32,
    /// Whether a model was found (otherwise every point was kept).
    pub model_found: bool,
}

/// xorshift64* generator (Vigna), deterministic on every target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct XorShift64(u64);

impl XorShift64 {
    /// A generator from `seed` (a zero seed is replaced by a fixed constant).
    pub fn new(seed: u64) -> Self {
        XorShift64(if seed == 0 {
            0x9e37_79b9_7f4a_7c15
        } else {
            seed
        })
    }

    /// Next 64-bit value.
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform integer in `0..n` (`n > 0`; multiply-shift, no modulo).
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * (n as u64 & 0xffff_ffff)) >> 32) as usize
    }
}

/// Draws `K` distinct indices below `n` (`n >= K`).
fn sample<const K: usize>(rng: &mut XorShift64, n: usize) -> [usize; K] {
    let mut idx = [0usize; K];
    let mut k = 0;
    let mut guard = 0;
    while k < K && guard < 64 * K {
        guard += 1;
        let i = rng.below(n);
        if !idx.iter().take(k).any(|&j| j == i) {
            if let Some(s) = idx.get_mut(k) {
                *s = i;
            }
            k += 1;
        }
    }
    idx
}

/// Iterations needed so that an all-inlier sample of `s` points was drawn with `confidence`,
/// given inlier ratio `ratio`.
fn needed_iterations(confidence: f64, ratio: f64, s: i32, cap: u32) -> u32 {
    let p = libm::pow(ratio, f64::from(s));
    if p >= 1.0 {
        return 1;
    }
    if p <= 0.0 {
        return cap;
    }
    let n = libm::log(1.0 - confidence) / libm::log(1.0 - p);
    if !(n.is_finite()) || n >= f64::from(cap) {
        cap
    } else {
        (libm::ceil(n) as u32).max(1)
    }
}

#[inline]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `R x` for the 3x3 matrix `r` (row-major evaluation order).
#[inline]
pub(crate) fn rotate(r: &Mat3, x: &[f64; 3]) -> [f64; 3] {
    let row = |i: usize| r[(i, 0)] * x[0] + r[(i, 1)] * x[1] + r[(i, 2)] * x[2];
    [row(0), row(1), row(2)]
}

/// 2-point RANSAC with the known rotation `r_cur_prev`. `prev_n`, `cur_n`: normalized points;
/// `thr_n`: threshold on the normalized plane (px / focal). Writes `inliers` (same length) and
/// uses `ys`, `ms` as scratch (as long as the points; extra points are ignored).
#[allow(clippy::too_many_arguments)]
pub fn two_point(
    prev_n: &[[f64; 2]],
    cur_n: &[[f64; 2]],
    r_cur_prev: &Mat3,
    thr_n: f64,
    cfg: &RansacConfig,
    rng: &mut XorShift64,
    ys: &mut [[f64; 3]],
    ms: &mut [[f64; 3]],
    inliers: &mut [bool],
) -> RansacOutcome {
    let n = prev_n
        .len()
        .min(cur_n.len())
        .min(inliers.len())
        .min(ys.len())
        .min(ms.len());
    let mut out = RansacOutcome::default();
    inliers.iter_mut().for_each(|b| *b = true);
    if n < 3 {
        out.inliers = n as u32;
        return out;
    }
    let (ys, ms) = (&mut ys[..n], &mut ms[..n]);
    for (((y, m), p), c) in ys.iter_mut().zip(ms.iter_mut()).zip(prev_n).zip(cur_n) {
        *y = rotate(r_cur_prev, &[p[0], p[1], 1.0]);
        *m = cross(y, &[c[0], c[1], 1.0]);
    }
    let thr2 = thr_n * thr_n;
    let is_inlier = |t: &[f64; 3], y: &[f64; 3], m: &[f64; 3]| {
        let e = dot(t, m);
        let lx = t[1] * y[2] - t[2] * y[1];
        let ly = t[2] * y[0] - t[0] * y[2];
        e * e <= thr2 * (lx * lx + ly * ly)
    };
    let mut best: Option<([f64; 3], usize)> = None;
    let mut needed = cfg.max_iterations;
    let mut it = 0u32;
    while it < needed.min(cfg.max_iterations) {
        it += 1;
        let [i, j] = sample::<2>(rng, n);
        let (Some(mi), Some(mj)) = (ms.get(i), ms.get(j)) else {
            continue;
        };
        let t = cross(mi, mj);
        let norm = libm::sqrt(dot(&t, &t));
        if norm.is_nan() || norm <= 1e-12 {
            continue;
        }
        let t = [t[0] / norm, t[1] / norm, t[2] / norm];
        let count = ys
            .iter()
            .zip(ms.iter())
            .filter(|(y, m)| is_inlier(&t, y, m))
            .count();
        if best.is_none_or(|(_, c)| count > c) {
            best = Some((t, count));
            needed = needed_iterations(
                cfg.confidence,
                count as f64 / n as f64,
                2,
                cfg.max_iterations,
            );
        }
    }
    out.iterations = it;
    // Without a model every sample was degenerate (all m ~ zero or parallel: pure rotation),
    // and every point is kept.
    if let Some((mut t, mut count)) = best {
        out.model_found = true;
        let inl = &mut inliers[..n];
        for ((b, y), m) in inl.iter_mut().zip(ys.iter()).zip(ms.iter()) {
            *b = is_inlier(&t, y, m);
        }
        for _ in 0..REFIT_ROUNDS {
            let Some(t2) = refit_two_point(ms, inl) else {
                break;
            };
            let c2 = ys
                .iter()
                .zip(ms.iter())
                .filter(|(y, m)| is_inlier(&t2, y, m))
                .count();
            if c2 < count {
                break;
            }
            (t, count) = (t2, c2);
            for ((b, y), m) in inl.iter_mut().zip(ys.iter()).zip(ms.iter()) {
                *b = is_inlier(&t, y, m);
            }
        }
    }
    out.inliers = inliers.iter().take(n).filter(|&&b| b).count() as u32;
    out.outliers = n as u32 - out.inliers;
    out
}

/// Unit eigenvector of the smallest eigenvalue of the symmetric `N x N` matrix `a` (cyclic
/// Jacobi, fixed sweep order, at most 50 sweeps).
#[allow(clippy::needless_range_loop)] // symmetric-matrix index arithmetic
fn smallest_eigenvector<const N: usize>(mut a: [[f64; N]; N]) -> Option<[f64; N]> {
    let mut v = [[0.0f64; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..50 {
        let mut off = 0.0;
        let mut diag = 0.0;
        for i in 0..N {
            diag += a[i][i] * a[i][i];
            for j in i + 1..N {
                off += a[i][j] * a[i][j];
            }
        }
        if !(off.is_finite() && diag.is_finite()) {
            return None;
        }
        if off <= 1e-30 * diag || off == 0.0 {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                let apq = a[p][q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                let t = if theta >= 0.0 {
                    1.0 / (theta + libm::sqrt(1.0 + theta * theta))
                } else {
                    -1.0 / (-theta + libm::sqrt(1.0 + theta * theta))
                };
                let c = 1.0 / libm::sqrt(1.0 + t * t);
                let s = t * c;
                for k in 0..N {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..N {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let mut best = 0;
    for i in 1..N {
        if a[i][i] < a[best][best] {
            best = i;
        }
    }
    let mut x = [0.0f64; N];
    for (xi, row) in x.iter_mut().zip(v.iter()) {
        *xi = row[best];
    }
    x.iter().all(|e| e.is_finite()).then_some(x)
}

/// Least-squares translation direction from the inliers: smallest eigenvector of `sum m m^T`.
fn refit_two_point(ms: &[[f64; 3]], inliers: &[bool]) -> Option<[f64; 3]> {
    let mut a = [[0.0f64; 3]; 3];
    let mut n = 0;
    for (m, _) in ms.iter().zip(inliers).filter(|(_, &b)| b) {
        for i in 0..3 {
            for j in 0..3 {
                a[i][j] += m[i] * m[j];
            }
        }
        n += 1;
    }
    if n < 3 {
        return None;
    }
    smallest_eigenvector(a)
}

/// Hartley normalization of the selected points: `(centroid, scale)` so that the mean distance
/// to the centroid becomes `sqrt(2)`.
fn hartley(pts: &[[f64; 2]], sel: &[bool]) -> Option<([f64; 2], f64)> {
    let (mut cx, mut cy, mut n) = (0.0, 0.0, 0.0);
    for (p, _) in pts.iter().zip(sel).filter(|(_, &b)| b) {
        cx += p[0];
        cy += p[1];
        n += 1.0;
    }
    if n < 1.0 {
        return None;
    }
    let c = [cx / n, cy / n];
    let mut d = 0.0;
    for (p, _) in pts.iter().zip(sel).filter(|(_, &b)| b) {
        d += libm::hypot(p[0] - c[0], p[1] - c[1]);
    }
    let mean = d / n;
    (mean > 0.0).then(|| (c, core::f64::consts::SQRT_2 / mean))
}

/// Least-squares fundamental matrix of the inliers (Hartley-normalized 8-point, no rank-2
/// enforcement), in the original coordinates.
fn refit_eight_point(
    prev_n: &[[f64; 2]],
    cur_n: &[[f64; 2]],
    inliers: &[bool],
) -> Option<[f64; 9]> {
    let count = inliers.iter().filter(|&&b| b).count();
    if count < 8 {
        return None;
    }
    let (cp, sp) = hartley(prev_n, inliers)?;
    let (cc, sc) = hartley(cur_n, inliers)?;
    let mut ata = [[0.0f64; 9]; 9];
    for ((p, c), _) in prev_n.iter().zip(cur_n).zip(inliers).filter(|(_, &b)| b) {
        let (px, py) = ((p[0] - cp[0]) * sp, (p[1] - cp[1]) * sp);
        let (qx, qy) = ((c[0] - cc[0]) * sc, (c[1] - cc[1]) * sc);
        let row = [qx * px, qx * py, qx, qy * px, qy * py, qy, px, py, 1.0];
        for i in 0..9 {
            for j in 0..9 {
                ata[i][j] += row[i] * row[j];
            }
        }
    }
    let f = smallest_eigenvector(ata)?;
    // F = Tc^T Fhat Tp with T = [[s, 0, -s cx], [0, s, -s cy], [0, 0, 1]].
    let tp = [
        [sp, 0.0, -sp * cp[0]],
        [0.0, sp, -sp * cp[1]],
        [0.0, 0.0, 1.0],
    ];
    let tc = [
        [sc, 0.0, -sc * cc[0]],
        [0.0, sc, -sc * cc[1]],
        [0.0, 0.0, 1.0],
    ];
    let fh = [[f[0], f[1], f[2]], [f[3], f[4], f[5]], [f[6], f[7], f[8]]];
    let mut tmp = [[0.0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            tmp[i][j] = fh[i][0] * tp[0][j] + fh[i][1] * tp[1][j] + fh[i][2] * tp[2][j];
        }
    }
    let mut out = [0.0f64; 9];
    for i in 0..3 {
        for j in 0..3 {
            out[3 * i + j] = tc[0][i] * tmp[0][j] + tc[1][i] * tmp[1][j] + tc[2][i] * tmp[2][j];
        }
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// Rounds of least-squares refit and re-classification after the sampling.
const REFIT_ROUNDS: usize = 2;

/// Null vector of the 8x9 system by Gaussian elimination with full pivoting, or `None` when a
/// pivot is negligible (degenerate sample).
fn null_vector_8x9(a: &mut [[f64; 9]; 8]) -> Option<[f64; 9]> {
    let mut perm = [0usize, 1, 2, 3, 4, 5, 6, 7, 8];
    let mut scale = 0.0f64;
    for row in a.iter() {
        for v in row {
            scale = scale.max(libm::fabs(*v));
        }
    }
    if scale.is_nan() || scale <= 0.0 {
        return None;
    }
    for k in 0..8 {
        // Full pivot search over rows k.. and (permuted) columns k..
        let (mut pr, mut pc, mut pv) = (k, k, 0.0f64);
        for (r, row) in a.iter().enumerate().skip(k) {
            for c in k..9 {
                let v = libm::fabs(row[perm[c]]);
                if v > pv {
                    (pr, pc, pv) = (r, c, v);
                }
            }
        }
        if pv.is_nan() || pv <= 1e-10 * scale {
            return None;
        }
        a.swap(k, pr);
        perm.swap(k, pc);
        let pivot_row = a[k];
        let piv = pivot_row[perm[k]];
        for row in a.iter_mut().skip(k + 1) {
            let f = row[perm[k]] / piv;
            if f != 0.0 {
                for c in k..9 {
                    row[perm[c]] -= f * pivot_row[perm[c]];
                }
            }
        }
    }
    let mut x = [0.0f64; 9];
    x[perm[8]] = 1.0;
    for k in (0..8).rev() {
        let mut s = 0.0;
        for c in k + 1..9 {
            s += a[k][perm[c]] * x[perm[c]];
        }
        x[perm[k]] = -s / a[k][perm[k]];
    }
    let norm = libm::sqrt(x.iter().map(|v| v * v).fold(0.0, |acc, v| acc + v));
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    for v in x.iter_mut() {
        *v /= norm;
    }
    Some(x)
}

/// Sampson test of `x_cur^T F x_prev = 0` against `thr2` (normalized units squared).
#[inline]
fn sampson_inlier(f: &[f64; 9], p: &[f64; 2], c: &[f64; 2], thr2: f64) -> bool {
    let fx = [
        f[0] * p[0] + f[1] * p[1] + f[2],
        f[3] * p[0] + f[4] * p[1] + f[5],
        f[6] * p[0] + f[7] * p[1] + f[8],
    ];
    let ftx = [
        f[0] * c[0] + f[3] * c[1] + f[6],
        f[1] * c[0] + f[4] * c[1] + f[7],
    ];
    let e = c[0] * fx[0] + c[1] * fx[1] + fx[2];
    e * e <= thr2 * (fx[0] * fx[0] + fx[1] * fx[1] + ftx[0] * ftx[0] + ftx[1] * ftx[1])
}

/// 8-point RANSAC (see the module documentation). Arguments as [`two_point`].
pub fn eight_point(
    prev_n: &[[f64; 2]],
    cur_n: &[[f64; 2]],
    thr_n: f64,
    cfg: &RansacConfig,
    rng: &mut XorShift64,
    inliers: &mut [bool],
) -> RansacOutcome {
    let n = prev_n.len().min(cur_n.len()).min(inliers.len());
    let mut out = RansacOutcome::default();
    inliers.iter_mut().for_each(|b| *b = true);
    if n < 9 {
        out.inliers = n as u32;
        return out;
    }
    let thr2 = thr_n * thr_n;
    let mut best: Option<([f64; 9], usize)> = None;
    let mut needed = cfg.max_iterations;
    let mut it = 0u32;
    while it < needed.min(cfg.max_iterations) {
        it += 1;
        let idx = sample::<8>(rng, n);
        let mut a = [[0.0f64; 9]; 8];
        for (row, &i) in a.iter_mut().zip(idx.iter()) {
            let (Some(p), Some(c)) = (prev_n.get(i), cur_n.get(i)) else {
                continue;
            };
            *row = [
                c[0] * p[0],
                c[0] * p[1],
                c[0],
                c[1] * p[0],
                c[1] * p[1],
                c[1],
                p[0],
                p[1],
                1.0,
            ];
        }
        let Some(f) = null_vector_8x9(&mut a) else {
            continue;
        };
        let count = prev_n
            .iter()
            .zip(cur_n)
            .take(n)
            .filter(|(p, c)| sampson_inlier(&f, p, c, thr2))
            .count();
        if best.is_none_or(|(_, c)| count > c) {
            best = Some((f, count));
            needed = needed_iterations(
                cfg.confidence,
                count as f64 / n as f64,
                8,
                cfg.max_iterations,
            );
        }
    }
    out.iterations = it;
    if let Some((mut f, mut count)) = best {
        out.model_found = true;
        let (prev_n, cur_n, inl) = (&prev_n[..n], &cur_n[..n], &mut inliers[..n]);
        for ((b, p), c) in inl.iter_mut().zip(prev_n).zip(cur_n) {
            *b = sampson_inlier(&f, p, c, thr2);
        }
        for _ in 0..REFIT_ROUNDS {
            let Some(f2) = refit_eight_point(prev_n, cur_n, inl) else {
                break;
            };
            let c2 = prev_n
                .iter()
                .zip(cur_n)
                .filter(|(p, c)| sampson_inlier(&f2, p, c, thr2))
                .count();
            if c2 < count {
                break;
            }
            (f, count) = (f2, c2);
            for ((b, p), c) in inl.iter_mut().zip(prev_n).zip(cur_n) {
                *b = sampson_inlier(&f, p, c, thr2);
            }
        }
    }
    out.inliers = inliers.iter().take(n).filter(|&&b| b).count() as u32;
    out.outliers = n as u32 - out.inliers;
    out
}

#[cfg(test)]
#[path = "ransac_tests.rs"]
mod tests;

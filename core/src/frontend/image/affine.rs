//! Inverse-compositional affine Lucas-Kanade of one window against a stored reference patch
//! (the anchored refinement of [`super::reference`]).
//!
//! The warp maps a window offset `x` (px from the reference point) to `A x + q` in the target
//! image. The template (bilinear samples of the reference patch around its point) and its
//! central-difference gradients are computed once; each iteration samples the target at the
//! warped offsets (bilinear, border pixels replicated), accumulates the 6-vector
//! `b = sum SD^T (I(W(x)) - T(x))` with the steepest-descent images
//! `SD = [gx x, gx y, gy x, gy y, gx, gy]`, solves `H dp = b` with the 6x6 Gauss-Newton
//! Hessian (Cholesky, computed once) and composes the warp with the inverse increment.
//!
//! Plain `f64` in a fixed order without fused multiply-add: bit-identical on every IEEE
//! platform.

use super::view::ImageView;

/// Largest window side handled, px.
pub const MAX_AFFINE_WINDOW: usize = super::lk::MAX_WINDOW;
const MAX_N: usize = MAX_AFFINE_WINDOW * MAX_AFFINE_WINDOW;
/// Template grid side (window plus a one-pixel border for the gradients).
const MAX_G: usize = MAX_AFFINE_WINDOW + 2;

/// An affine warp: window offset `x` -> `a x + q`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// Linear part, row-major `[[a00, a01], [a10, a11]]`.
    pub a: [f64; 4],
    /// Translation: the tracked point in the target image, px.
    pub q: [f64; 2],
}

impl Affine {
    /// The identity linear part at `q`.
    pub const fn at(q: [f64; 2]) -> Self {
        Affine {
            a: [1.0, 0.0, 0.0, 1.0],
            q,
        }
    }

    fn det(&self) -> f64 {
        self.a[0] * self.a[3] - self.a[1] * self.a[2]
    }
}

/// Result of [`refine_affine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AffineFit {
    /// The final warp.
    pub warp: Affine,
    /// Mean absolute photometric error over the window at the final warp, grey levels.
    pub residual: f64,
    /// Whether the last step moved the window's corners less than `eps_px`.
    pub converged: bool,
    /// Iterations run.
    pub iterations: u32,
}

/// Scratch of one affine refinement (template values and steepest-descent images).
#[derive(Clone)]
pub struct AffineScratch {
    grid: [f64; MAX_G * MAX_G],
    t: [f64; MAX_N],
    sd: [[f64; 6]; MAX_N],
}

impl Default for AffineScratch {
    fn default() -> Self {
        Self::new()
    }
}

impl AffineScratch {
    /// Zeroed scratch.
    pub const fn new() -> Self {
        AffineScratch {
            grid: [0.0; MAX_G * MAX_G],
            t: [0.0; MAX_N],
            sd: [[0.0; 6]; MAX_N],
        }
    }
}

/// Bilinear sample of `img` at `(x, y)`, border pixels replicated; `None` if non-finite or far
/// outside.
#[inline]
fn sample(img: &ImageView, x: f64, y: f64) -> Option<f64> {
    let (fx, fy) = (libm::floor(x), libm::floor(y));
    if !(fx.is_finite() && fy.is_finite()) || fx.abs() > 1e6 || fy.abs() > 1e6 {
        return None;
    }
    let (ax, ay) = (x - fx, y - fy);
    let (ix, iy) = (fx as isize, fy as isize);
    let p = |dx: isize, dy: isize| f64::from(img.clamped(ix + dx, iy + dy));
    let top = p(0, 0) + ax * (p(1, 0) - p(0, 0));
    let bot = p(0, 1) + ax * (p(1, 1) - p(0, 1));
    Some(top + ay * (bot - top))
}

/// Bilinear sample at `(x, y)` known to have its 2x2 neighbourhood inside the image (`data`
/// with `stride`); same arithmetic as [`sample`].
#[inline(always)]
fn sample_inside(data: &[u8], stride: usize, x: f64, y: f64) -> Option<f64> {
    // Non-negative: truncation is the floor.
    let (ix, iy) = (x as usize, y as usize);
    let (ax, ay) = (x - ix as f64, y - iy as f64);
    let o = iy * stride + ix;
    let r0: &[u8; 2] = data.get(o..o + 2)?.try_into().ok()?;
    let r1: &[u8; 2] = data.get(o + stride..o + stride + 2)?.try_into().ok()?;
    let p = |v: u8| f64::from(v);
    let top = p(r0[0]) + ax * (p(r0[1]) - p(r0[0]));
    let bot = p(r1[0]) + ax * (p(r1[1]) - p(r1[0]));
    Some(top + ay * (bot - top))
}

/// In-place Cholesky of the 6x6 `h` (lower triangle); `None` if not positive definite.
#[allow(clippy::needless_range_loop)] // fixed 6x6 indices, clearer than iterators
fn cholesky(h: &mut [[f64; 6]; 6]) -> Option<()> {
    for j in 0..6 {
        let mut d = h[j][j];
        for k in 0..j {
            d -= h[j][k] * h[j][k];
        }
        if d.is_nan() || d <= 0.0 {
            return None;
        }
        let d = libm::sqrt(d);
        h[j][j] = d;
        for i in j + 1..6 {
            let mut s = h[i][j];
            for k in 0..j {
                s -= h[i][k] * h[j][k];
            }
            h[i][j] = s / d;
        }
    }
    Some(())
}

/// Solves `L L^T x = b` with the factor of [`cholesky`].
#[allow(clippy::needless_range_loop)]
fn solve(l: &[[f64; 6]; 6], b: [f64; 6]) -> [f64; 6] {
    let mut y = [0.0; 6];
    for i in 0..6 {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; 6];
    for i in (0..6).rev() {
        let mut s = y[i];
        for k in i + 1..6 {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// Template values and steepest-descent images of the `win x win` window around `at` in
/// `reference` (into `s`), and the lower triangle of their Gauss-Newton Hessian.
fn template(
    reference: &ImageView,
    at: [f64; 2],
    win: usize,
    s: &mut AffineScratch,
) -> Option<[[f64; 6]; 6]> {
    let half = (win / 2) as isize;
    let g = win + 2;
    // Template grid with a one-pixel border, then values and steepest-descent images.
    for (k, v) in s.grid.iter_mut().take(g * g).enumerate() {
        let (dx, dy) = ((k % g) as isize - half - 1, (k / g) as isize - half - 1);
        *v = sample(reference, at[0] + dx as f64, at[1] + dy as f64)?;
    }
    let mut h = [[0.0f64; 6]; 6];
    let n = win * win;
    for k in 0..n {
        let (c, r) = (k % win + 1, k / win + 1);
        let gv = |cc: usize, rr: usize| s.grid.get(rr * g + cc).copied().unwrap_or(0.0);
        let gx = 0.5 * (gv(c + 1, r) - gv(c - 1, r));
        let gy = 0.5 * (gv(c, r + 1) - gv(c, r - 1));
        let (x, y) = (
            (c as isize - 1 - half) as f64,
            (r as isize - 1 - half) as f64,
        );
        let sd = [gx * x, gx * y, gy * x, gy * y, gx, gy];
        for i in 0..6 {
            for j in 0..=i {
                h[i][j] += sd[i] * sd[j];
            }
        }
        if let (Some(t), Some(o)) = (s.t.get_mut(k), s.sd.get_mut(k)) {
            *t = gv(c, r);
            *o = sd;
        }
    }
    Some(h)
}

/// Refines `init` (the warp from the reference point `at` in `reference` to the target `img`)
/// with a `win x win` window (odd, `5..=MAX_AFFINE_WINDOW`), at most `max_iter` iterations,
/// stopping when the window's corners move less than `eps_px`. `None` for a bad window, a
/// singular template, or a degenerate or non-finite warp.
#[allow(clippy::too_many_arguments)]
pub fn refine_affine(
    reference: &ImageView,
    at: [f64; 2],
    img: &ImageView,
    init: Affine,
    win: usize,
    max_iter: u32,
    eps_px: f64,
    s: &mut AffineScratch,
) -> Option<AffineFit> {
    if win.is_multiple_of(2) || !(5..=MAX_AFFINE_WINDOW).contains(&win) {
        return None;
    }
    let half = (win / 2) as isize;
    let n = win * win;
    let mut h = template(reference, at, win, s)?;
    cholesky(&mut h)?;
    let mut w = init;
    let corner2 = (half * half) as f64;
    let mut fit = AffineFit {
        warp: w,
        residual: 0.0,
        converged: false,
        iterations: 0,
    };
    for _ in 0..max_iter {
        let mut b = [0.0f64; 6];
        let mut abs_sum = 0.0f64;
        // The window's extent in the target: direct reads when its bounding box is inside.
        let hf = half as f64;
        let ext_u = (libm::fabs(w.a[0]) + libm::fabs(w.a[1])) * hf;
        let ext_v = (libm::fabs(w.a[2]) + libm::fabs(w.a[3])) * hf;
        let inside = w.q[0] - ext_u >= 0.0
            && w.q[1] - ext_v >= 0.0
            && w.q[0] + ext_u < (img.width() as f64) - 1.0
            && w.q[1] + ext_v < (img.height() as f64) - 1.0;
        let (data, stride) = (img.data(), img.stride());
        for (k, (t, sd)) in s.t.iter().zip(s.sd.iter()).take(n).enumerate() {
            let (x, y) = ((k % win) as isize - half, (k / win) as isize - half);
            let (x, y) = (x as f64, y as f64);
            let u = w.a[0] * x + w.a[1] * y + w.q[0];
            let v = w.a[2] * x + w.a[3] * y + w.q[1];
            let val = if inside {
                sample_inside(data, stride, u, v)?
            } else {
                sample(img, u, v)?
            };
            let e = val - t;
            abs_sum += libm::fabs(e);
            for (bi, si) in b.iter_mut().zip(sd) {
                *bi += si * e;
            }
        }
        fit.iterations += 1;
        fit.residual = abs_sum / n as f64;
        let dp = solve(&h, b);
        // W <- W o W(dp)^-1, W(dp): x -> (I + D) x + d.
        let (d00, d01, d10, d11) = (1.0 + dp[0], dp[1], dp[2], 1.0 + dp[3]);
        let det = d00 * d11 - d01 * d10;
        if !(det.is_finite() && libm::fabs(det) > 1e-6) {
            return None;
        }
        let inv = [d11 / det, -d01 / det, -d10 / det, d00 / det];
        let a = w.a;
        let na = [
            a[0] * inv[0] + a[1] * inv[2],
            a[0] * inv[1] + a[1] * inv[3],
            a[2] * inv[0] + a[3] * inv[2],
            a[2] * inv[1] + a[3] * inv[3],
        ];
        let nq = [
            w.q[0] - (na[0] * dp[4] + na[1] * dp[5]),
            w.q[1] - (na[2] * dp[4] + na[3] * dp[5]),
        ];
        // How far the window's corner moves: translation plus the linear change at `half`.
        let (du, dv) = (nq[0] - w.q[0], nq[1] - w.q[1]);
        let lin = (na[0] - a[0]) * (na[0] - a[0])
            + (na[1] - a[1]) * (na[1] - a[1])
            + (na[2] - a[2]) * (na[2] - a[2])
            + (na[3] - a[3]) * (na[3] - a[3]);
        w = Affine { a: na, q: nq };
        if !(w.q[0].is_finite() && w.q[1].is_finite() && (0.25..=4.0).contains(&w.det())) {
            return None;
        }
        if du * du + dv * dv + lin * corner2 <= eps_px * eps_px {
            fit.converged = true;
            break;
        }
    }
    fit.warp = w;
    Some(fit)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::super::testutil::{render, texture};
    use super::*;

    const W: usize = 160;
    const H: usize = 120;

    /// The texture warped by `a` about `c` and moved by `s`: `b(c + s + a x) = tex(c + x)`.
    fn warped(a: [f64; 4], c: [f64; 2], s: [f64; 2]) -> std::vec::Vec<u8> {
        let det = a[0] * a[3] - a[1] * a[2];
        render(W, H, 0.0, 0.0, |x, y| {
            let (dx, dy) = (x - c[0] - s[0], y - c[1] - s[1]);
            let u = (a[3] * dx - a[1] * dy) / det;
            let v = (-a[2] * dx + a[0] * dy) / det;
            texture(c[0] + u, c[1] + v)
        })
    }

    #[test]
    fn recovers_rotation_scale_and_shift() {
        let c = [80.3, 60.7];
        let reference = render(W, H, 0.0, 0.0, texture);
        let rv = ImageView::new(&reference, W, H, W).unwrap();
        let mut s = std::boxed::Box::new(AffineScratch::new());
        let (th, k) = (0.14f64, 1.06);
        let a = [
            k * libm::cos(th),
            -k * libm::sin(th),
            k * libm::sin(th),
            k * libm::cos(th),
        ];
        for &sh in &[[0.0, 0.0], [3.4, -2.2], [-0.37, 0.81]] {
            let img = warped(a, c, sh);
            let iv = ImageView::new(&img, W, H, W).unwrap();
            let truth = [c[0] + sh[0], c[1] + sh[1]];
            let init = Affine::at([truth[0] + 0.6, truth[1] - 0.5]);
            let fit = refine_affine(&rv, c, &iv, init, 21, 30, 0.01, &mut s).unwrap();
            let e = libm::hypot(fit.warp.q[0] - truth[0], fit.warp.q[1] - truth[1]);
            assert!(fit.converged && e < 0.03, "{sh:?}: {fit:?} error {e}");
            for (x, y) in fit.warp.a.iter().zip(&a) {
                assert!(libm::fabs(x - y) < 0.01, "{:?} vs {a:?}", fit.warp.a);
            }
            assert!(fit.residual < 2.0, "{fit:?}");
        }
        // Bad windows and a flat reference.
        let img = warped(a, c, [0.0, 0.0]);
        let iv = ImageView::new(&img, W, H, W).unwrap();
        assert!(refine_affine(&rv, c, &iv, Affine::at(c), 20, 10, 0.01, &mut s).is_none());
        assert!(refine_affine(&rv, c, &iv, Affine::at(c), 33, 10, 0.01, &mut s).is_none());
        let flat = std::vec![90u8; W * H];
        let fv = ImageView::new(&flat, W, H, W).unwrap();
        assert!(refine_affine(&fv, c, &iv, Affine::at(c), 21, 10, 0.01, &mut s).is_none());
        let nan = Affine::at([f64::NAN, 1.0]);
        assert!(refine_affine(&rv, c, &iv, nan, 21, 10, 0.01, &mut s).is_none());
    }
}

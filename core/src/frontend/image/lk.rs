//! Pyramidal Lucas-Kanade for one point, inverse-compositional for a translation (the template's
//! gradients and Hessian are computed once per level), in OpenCV's fixed-point arithmetic.
//!
//! Per level, from the coarsest to level 0:
//! - The template is the `(W + 2)^2` patch around the previous position, bilinearly interpolated
//!   with 14-bit weights to 5 fractional bits (`0..=8160`), its 3x3 Scharr gradients rounded to
//!   the same scale (`32 x grey / px`), and the 2x2 Hessian `A = sum g g^T` (exact `i64`).
//!   A template whose smallest eigenvalue of `A / N` is below `min_eigen` `(grey/px)^2` fails.
//! - Each iteration samples the `W^2` window at the current guess `q` (same interpolation),
//!   accumulates `b = sum (J(q + x) - T(x)) g(x)` and `sum |J - T|` exactly in integers (per-row
//!   `i32` partial sums: `|diff * g| <= 8160 * 4080`, 31 of them fit), and steps
//!   `q -= A^-1 b` (`f64`, fixed order). It stops when the step is below `epsilon_px` (level
//!   pixels), when it oscillates (OpenCV's half-step rule), or after `max_iterations`.
//! - The guess carries to the next finer level through the pyramid's coordinate map.
//!
//! Windows that reach outside the image read replicated border pixels (copied into a small
//! patch first); a window that leaves the image entirely fails. The photometric residual is the
//! mean `|J - T|` of the last iteration at level 0, in grey levels.

use super::pyramid::{Pyramid, PyramidFilter};
use super::view::ImageView;
use crate::Error;

/// Largest LK window side, px.
pub const MAX_WINDOW: usize = 31;
const MAX_PATCH: usize = MAX_WINDOW + 2;
const MAX_SRC: usize = MAX_WINDOW + 3;
/// Fixed-point bits of the bilinear weights.
const W_BITS: u32 = 14;
/// Fractional bits kept in interpolated intensities.
const FRAC_BITS: u32 = 5;
const DESCALE: u32 = W_BITS - FRAC_BITS;

/// Lucas-Kanade parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LkConfig {
    /// Window side, px (odd, `5..=MAX_WINDOW`).
    pub window: usize,
    /// Iteration cap per level.
    pub max_iterations: u32,
    /// Convergence threshold on the step, level px.
    pub epsilon_px: f32,
    /// Smallest accepted eigenvalue of the template's mean gradient outer product,
    /// `(grey / px)^2` (OpenCV's `minEigThreshold = 1e-4` is about 0.1 here).
    pub min_eigen: f32,
    /// Largest accepted mean absolute photometric error over the window at level 0, grey levels.
    pub max_residual: f32,
}

impl Default for LkConfig {
    fn default() -> Self {
        LkConfig {
            window: 21,
            max_iterations: 30,
            epsilon_px: 0.01,
            min_eigen: 0.1,
            max_residual: 30.0,
        }
    }
}

impl LkConfig {
    /// Checks every parameter's range ([`Error::InvalidConfig`] otherwise).
    pub fn validate(&self) -> Result<(), Error> {
        let ok = self.window % 2 == 1
            && (5..=MAX_WINDOW).contains(&self.window)
            && (1..=1000).contains(&self.max_iterations)
            && self.epsilon_px > 0.0
            && self.epsilon_px <= 10.0
            && (0.0..=1.0e6).contains(&self.min_eigen)
            && self.max_residual > 0.0
            && self.max_residual <= 256.0;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

/// Why a point was not tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LkFailure {
    /// The template has too little texture (small eigenvalue or singular Hessian).
    SmallEigen,
    /// The window left the image, or the pyramid lacks a level.
    OutOfImage,
    /// The final photometric residual was too large.
    Residual,
    /// A position became non-finite.
    NonFinite,
}

/// A tracked point.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LkTrack {
    /// Position in the target image, level-0 px.
    pub pos: [f64; 2],
    /// Mean absolute photometric error at level 0, grey levels.
    pub residual: f32,
    /// Iterations over all levels.
    pub iterations: u32,
    /// Whether level 0 stopped on the convergence test (not on the iteration cap).
    pub converged: bool,
}

#[derive(Clone)]
struct Template {
    t: [i16; MAX_WINDOW * MAX_WINDOW],
    gx: [i16; MAX_WINDOW * MAX_WINDOW],
    gy: [i16; MAX_WINDOW * MAX_WINDOW],
    a11: f64,
    a12: f64,
    a22: f64,
}

/// Scratch of one LK track (about 14 KiB): the template and the border patch.
#[derive(Clone)]
pub struct LkScratch {
    tmpl: Template,
    interp: [i32; MAX_PATCH * MAX_PATCH],
    patch: [u8; MAX_SRC * MAX_SRC],
}

impl Default for LkScratch {
    fn default() -> Self {
        Self::new()
    }
}

impl LkScratch {
    /// Zeroed scratch.
    pub const fn new() -> Self {
        LkScratch {
            tmpl: Template {
                t: [0; MAX_WINDOW * MAX_WINDOW],
                gx: [0; MAX_WINDOW * MAX_WINDOW],
                gy: [0; MAX_WINDOW * MAX_WINDOW],
                a11: 0.0,
                a12: 0.0,
                a22: 0.0,
            },
            interp: [0; MAX_PATCH * MAX_PATCH],
            patch: [0; MAX_SRC * MAX_SRC],
        }
    }
}

/// Bilinear weights `(w00, w01, w10, w11)` of the fractional offsets, summing to `2^14`.
#[inline]
fn weights(ax: f64, ay: f64) -> [i32; 4] {
    let one = f64::from(1u32 << W_BITS);
    let w00 = ((1.0 - ax) * (1.0 - ay) * one + 0.5) as i32;
    let w01 = (ax * (1.0 - ay) * one + 0.5) as i32;
    let w10 = ((1.0 - ax) * ay * one + 0.5) as i32;
    [w00, w01, w10, (1 << W_BITS) - w00 - w01 - w10]
}

/// The `n x n` source block at integer top-left `(ix, iy)`: the image itself when inside,
/// otherwise a border-replicated copy in `patch`. Returns the data, its stride and the offset
/// of the block's first pixel.
fn source_block<'a>(
    img: &ImageView<'a>,
    ix: i64,
    iy: i64,
    n: usize,
    patch: &'a mut [u8; MAX_SRC * MAX_SRC],
) -> (&'a [u8], usize, usize) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    if ix >= 0 && iy >= 0 && ix + n as i64 <= w && iy + n as i64 <= h {
        let off = iy as usize * img.stride() + ix as usize;
        return (img.data(), img.stride(), off);
    }
    for (r, row) in patch.chunks_exact_mut(n).take(n).enumerate() {
        for (c, px) in row.iter_mut().enumerate() {
            *px = img.clamped((ix + c as i64) as isize, (iy + r as i64) as isize);
        }
    }
    (&patch[..], n, 0)
}

impl Template {
    /// Builds the template of window `win` around level coordinates `(x, y)` in `img`.
    fn build(
        &mut self,
        img: &ImageView,
        x: f64,
        y: f64,
        win: usize,
        interp: &mut [i32; MAX_PATCH * MAX_PATCH],
        patch: &mut [u8; MAX_SRC * MAX_SRC],
    ) -> Result<(), LkFailure> {
        let half = (win / 2) as f64;
        let p = win + 2;
        let (xt, yt) = (x - half - 1.0, y - half - 1.0);
        let (fx, fy) = (libm::floor(xt), libm::floor(yt));
        if !(fx.is_finite() && fy.is_finite()) {
            return Err(LkFailure::NonFinite);
        }
        let (ix, iy) = (fx as i64, fy as i64);
        let (w, h) = (img.width() as i64, img.height() as i64);
        if ix + p as i64 <= 0 || iy + p as i64 <= 0 || ix >= w || iy >= h {
            return Err(LkFailure::OutOfImage);
        }
        let [w00, w01, w10, w11] = weights(xt - fx, yt - fy);
        let (src, stride, off) = source_block(img, ix, iy, p + 1, patch);
        // Interpolated (W+2)^2 patch, 5 fractional bits.
        for (r, out) in interp.chunks_exact_mut(p).take(p).enumerate() {
            let o0 = off + r * stride;
            let (Some(s0), Some(s1)) = (
                src.get(o0..o0 + p + 1),
                src.get(o0 + stride..o0 + stride + p + 1),
            ) else {
                return Err(LkFailure::OutOfImage);
            };
            interp_row(s0, s1, [w00, w01, w10, w11], out);
        }
        // Template values and Scharr gradients of the interior.
        let (mut a11, mut a12, mut a22) = (0i64, 0i64, 0i64);
        let rows = self
            .t
            .chunks_exact_mut(win)
            .zip(self.gx.chunks_exact_mut(win))
            .zip(self.gy.chunks_exact_mut(win))
            .take(win);
        for (r, ((t, gx), gy)) in rows.enumerate() {
            let (Some(p0), Some(p1), Some(p2)) = (
                interp.get(r * p..r * p + p),
                interp.get((r + 1) * p..(r + 1) * p + p),
                interp.get((r + 2) * p..(r + 2) * p + p),
            ) else {
                return Err(LkFailure::OutOfImage);
            };
            let (s11, s12, s22) = scharr_row(p0, p1, p2, t, gx, gy);
            a11 += i64::from(s11);
            a12 += i64::from(s12);
            a22 += i64::from(s22);
        }
        self.a11 = a11 as f64;
        self.a12 = a12 as f64;
        self.a22 = a22 as f64;
        Ok(())
    }

    /// Smallest eigenvalue of `A / N`, `(grey / px)^2`.
    fn min_eigen(&self, win: usize) -> f64 {
        let (a, b, c) = (self.a11, self.a12, self.a22);
        let d = a - c;
        let l = 0.5 * ((a + c) - libm::sqrt(d * d + 4.0 * (b * b)));
        l / ((win * win) as f64 * 1024.0)
    }
}

/// One interpolated row: `out[c] = (w00 s0[c] + w01 s0[c+1] + w10 s1[c] + w11 s1[c+1]) >> 9`.
#[inline(always)]
fn interp_row(s0: &[u8], s1: &[u8], w: [i32; 4], out: &mut [i32]) {
    let n = out.len();
    let (Some(a), Some(b), Some(c), Some(d)) =
        (s0.get(..n), s0.get(1..n + 1), s1.get(..n), s1.get(1..n + 1))
    else {
        return;
    };
    let [w00, w01, w10, w11] = w;
    let round = 1 << (DESCALE - 1);
    for ((((o, &a), &b), &c), &d) in out.iter_mut().zip(a).zip(b).zip(c).zip(d) {
        let s = w00 * i32::from(a) + w01 * i32::from(b) + w10 * i32::from(c) + w11 * i32::from(d);
        *o = (s + round) >> DESCALE;
    }
}

/// Template row and its Scharr gradients from three interpolated rows; returns the row's
/// Hessian sums `(sum gx^2, sum gx gy, sum gy^2)`.
#[inline(always)]
fn scharr_row(
    p0: &[i32],
    p1: &[i32],
    p2: &[i32],
    t: &mut [i16],
    gx: &mut [i16],
    gy: &mut [i16],
) -> (i32, i32, i32) {
    let n = t.len();
    let (Some(a0), Some(a1), Some(a2)) = (p0.get(..n), p0.get(1..n + 1), p0.get(2..n + 2)) else {
        return (0, 0, 0);
    };
    let (Some(b0), Some(b1), Some(b2)) = (p1.get(..n), p1.get(1..n + 1), p1.get(2..n + 2)) else {
        return (0, 0, 0);
    };
    let (Some(c0), Some(c1), Some(c2)) = (p2.get(..n), p2.get(1..n + 1), p2.get(2..n + 2)) else {
        return (0, 0, 0);
    };
    let (mut s11, mut s12, mut s22) = (0i32, 0i32, 0i32);
    let it = t
        .iter_mut()
        .zip(gx.iter_mut())
        .zip(gy.iter_mut())
        .zip(a0.iter().zip(a1).zip(a2))
        .zip(b0.iter().zip(b1).zip(b2))
        .zip(c0.iter().zip(c1).zip(c2));
    for (((((ot, ox), oy), ((&a0, &a1), &a2)), ((&b0, &b1), &b2)), ((&c0, &c1), &c2)) in it {
        let x = (3 * (a2 - a0) + 10 * (b2 - b0) + 3 * (c2 - c0) + 16) >> FRAC_BITS;
        let y = (3 * (c0 - a0) + 10 * (c1 - a1) + 3 * (c2 - a2) + 16) >> FRAC_BITS;
        *ot = b1 as i16;
        *ox = x as i16;
        *oy = y as i16;
        s11 += x * x;
        s12 += x * y;
        s22 += y * y;
    }
    (s11, s12, s22)
}

/// One iteration's sums over the window at integer top-left `(ix, iy)` with `weights`:
/// `(sum diff gx, sum diff gy, sum |diff|)`.
#[inline(always)]
fn window_sums(
    src: &[u8],
    stride: usize,
    off: usize,
    w: [i32; 4],
    tmpl: &Template,
    win: usize,
) -> Option<(i64, i64, i64)> {
    let (mut bx, mut by, mut be) = (0i64, 0i64, 0i64);
    let [w00, w01, w10, w11] = w;
    let round = 1 << (DESCALE - 1);
    let rows = tmpl
        .t
        .chunks_exact(win)
        .zip(tmpl.gx.chunks_exact(win))
        .zip(tmpl.gy.chunks_exact(win))
        .take(win);
    for (r, ((t, gx), gy)) in rows.enumerate() {
        let o0 = off + r * stride;
        let s0 = src.get(o0..o0 + win + 1)?;
        let s1 = src.get(o0 + stride..o0 + stride + win + 1)?;
        let (a, b) = (s0.get(..win)?, s0.get(1..win + 1)?);
        let (c, d) = (s1.get(..win)?, s1.get(1..win + 1)?);
        let (mut sx, mut sy, mut se) = (0i32, 0i32, 0i32);
        let it = a.iter().zip(b).zip(c).zip(d).zip(t.iter().zip(gx).zip(gy));
        for ((((&a, &b), &c), &d), ((&t, &gx), &gy)) in it {
            let s =
                w00 * i32::from(a) + w01 * i32::from(b) + w10 * i32::from(c) + w11 * i32::from(d);
            let diff = ((s + round) >> DESCALE) - i32::from(t);
            sx += diff * i32::from(gx);
            sy += diff * i32::from(gy);
            se += diff.abs();
        }
        bx += i64::from(sx);
        by += i64::from(sy);
        be += i64::from(se);
    }
    Some((bx, by, be))
}

/// Tracks level-0 point `p0` of `from` into `to`, starting the search at `seed` (level-0 px),
/// through levels `max_level..=0` (clamped to the levels both pyramids have). Both pyramids must
/// use the same filter.
pub fn track_point<const B: usize, const L: usize>(
    from: &Pyramid<B, L>,
    to: &Pyramid<B, L>,
    p0: [f64; 2],
    seed: [f64; 2],
    max_level: usize,
    cfg: &LkConfig,
    scratch: &mut LkScratch,
) -> Result<LkTrack, LkFailure> {
    let win = cfg.window;
    if win % 2 == 0 || !(3..=MAX_WINDOW).contains(&win) {
        return Err(LkFailure::OutOfImage);
    }
    if !(p0[0].is_finite() && p0[1].is_finite() && seed[0].is_finite() && seed[1].is_finite()) {
        return Err(LkFailure::NonFinite);
    }
    let levels = from.levels().min(to.levels());
    if levels == 0 {
        return Err(LkFailure::OutOfImage);
    }
    let top = max_level.min(levels - 1);
    let filter: PyramidFilter = from.filter();
    let half = (win / 2) as f64;
    let n_px = (win * win) as f64;
    let eps2 = f64::from(cfg.epsilon_px) * f64::from(cfg.epsilon_px);
    let mut q = [filter.to_level(seed[0], top), filter.to_level(seed[1], top)];
    let mut iterations = 0u32;
    let mut residual = 0.0f32;
    let mut converged = false;
    for level in (0..=top).rev() {
        let (Some(img_from), Some(img_to)) = (from.level(level), to.level(level)) else {
            return Err(LkFailure::OutOfImage);
        };
        let p = [filter.to_level(p0[0], level), filter.to_level(p0[1], level)];
        let LkScratch {
            tmpl,
            interp,
            patch,
        } = scratch;
        tmpl.build(&img_from, p[0], p[1], win, interp, patch)?;
        if tmpl.min_eigen(win) < f64::from(cfg.min_eigen) {
            return Err(LkFailure::SmallEigen);
        }
        let det = tmpl.a11 * tmpl.a22 - tmpl.a12 * tmpl.a12;
        if det.is_nan() || det <= 0.0 {
            return Err(LkFailure::SmallEigen);
        }
        let inv_det = 1.0 / det;
        let (wl, hl) = (img_to.width() as f64, img_to.height() as f64);
        let mut prev = [0.0f64; 2];
        converged = false;
        for it in 0..cfg.max_iterations {
            if !(q[0].is_finite() && q[1].is_finite()) {
                return Err(LkFailure::NonFinite);
            }
            if q[0] < -half || q[1] < -half || q[0] > wl - 1.0 + half || q[1] > hl - 1.0 + half {
                return Err(LkFailure::OutOfImage);
            }
            let (xt, yt) = (q[0] - half, q[1] - half);
            let (fx, fy) = (libm::floor(xt), libm::floor(yt));
            let wgt = weights(xt - fx, yt - fy);
            let (src, stride, off) = source_block(&img_to, fx as i64, fy as i64, win + 1, patch);
            let (bx, by, be) =
                window_sums(src, stride, off, wgt, tmpl, win).ok_or(LkFailure::OutOfImage)?;
            iterations += 1;
            residual = (be as f64 / (n_px * 32.0)) as f32;
            let (bx, by) = (bx as f64, by as f64);
            let d = [
                (tmpl.a22 * bx - tmpl.a12 * by) * inv_det,
                (tmpl.a11 * by - tmpl.a12 * bx) * inv_det,
            ];
            q = [q[0] - d[0], q[1] - d[1]];
            if d[0] * d[0] + d[1] * d[1] <= eps2 {
                converged = true;
                break;
            }
            if it > 0 && libm::fabs(d[0] + prev[0]) < 0.01 && libm::fabs(d[1] + prev[1]) < 0.01 {
                // Oscillating between two points: settle in the middle.
                q = [q[0] + 0.5 * d[0], q[1] + 0.5 * d[1]];
                converged = true;
                break;
            }
            prev = d;
        }
        if level > 0 {
            q = [filter.up_one(q[0]), filter.up_one(q[1])];
        }
    }
    if !(q[0].is_finite() && q[1].is_finite()) {
        return Err(LkFailure::NonFinite);
    }
    if residual > cfg.max_residual {
        return Err(LkFailure::Residual);
    }
    Ok(LkTrack {
        pos: q,
        residual,
        iterations,
        converged,
    })
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::super::equalize::Equalization;
    use super::super::pyramid::pyramid_bytes;
    use super::super::testutil::{render, texture};
    use super::*;

    const W: usize = 320;
    const H: usize = 240;
    type Pyr = Pyramid<{ pyramid_bytes(W, H, 4) }, 4>;

    fn pyr(img: &[u8], filter: PyramidFilter) -> std::boxed::Box<Pyr> {
        let mut p = std::boxed::Box::new(Pyr::new());
        let v = ImageView::new(img, W, H, W).unwrap();
        p.build(&v, 4, filter, Equalization::Off).unwrap();
        p
    }

    /// Largest tracking error over a grid of points for a known sub-pixel shift.
    fn max_error(dx: f64, dy: f64, filter: PyramidFilter, seeded: bool) -> (f64, u32) {
        let a = render(W, H, 0.0, 0.0, texture);
        let b = render(W, H, dx, dy, texture);
        let (pa, pb) = (pyr(&a, filter), pyr(&b, filter));
        let cfg = LkConfig::default();
        let mut s = std::boxed::Box::new(LkScratch::new());
        let mut worst = 0.0f64;
        let mut iters = 0;
        for y in (40..=200).step_by(40) {
            for x in (40..=280).step_by(40) {
                let p = [x as f64 + 0.37, y as f64 - 0.21];
                let (seed, levels) = if seeded {
                    ([p[0] + dx + 0.8, p[1] + dy - 0.6], 0)
                } else {
                    (p, 3)
                };
                let t = track_point(&pa, &pb, p, seed, levels, &cfg, &mut s).unwrap();
                let e = libm::hypot(t.pos[0] - p[0] - dx, t.pos[1] - p[1] - dy);
                worst = worst.max(e);
                iters += t.iterations;
                assert!(t.residual < 2.0, "residual {}", t.residual);
            }
        }
        (worst, iters)
    }

    /// Max error 0.0145 px, mean 0.005 px over 35 points x 5 shifts x 2 filters when written;
    /// the Gaussian pyramid needs 8-10 iterations per point (4 levels), the box 10-14.
    #[test]
    fn recovers_known_subpixel_shifts() {
        for filter in [PyramidFilter::Gaussian5, PyramidFilter::Box2] {
            for &(dx, dy) in &[
                (0.3, -0.7),
                (2.25, 1.5),
                (-5.6, 3.3),
                (12.4, -9.8),
                (0.0, 0.0),
            ] {
                let (e, _) = max_error(dx, dy, filter, false);
                assert!(
                    e < 0.02,
                    "{filter:?} shift ({dx}, {dy}): max error {e:.4} px"
                );
            }
        }
    }

    #[test]
    fn seeded_single_level_converges() {
        let (e, iters) = max_error(3.7, -2.2, PyramidFilter::Gaussian5, true);
        assert!(e < 0.02, "max error {e:.4} px");
        // 35 points, one level: a few iterations each.
        assert!(iters < 35 * 10, "{iters} iterations");
    }

    #[test]
    fn flat_template_and_bad_input_fail() {
        let flat = std::vec![30u8; W * H];
        let tex = render(W, H, 0.0, 0.0, texture);
        let (pf, pt) = (
            pyr(&flat, PyramidFilter::Gaussian5),
            pyr(&tex, PyramidFilter::Gaussian5),
        );
        let cfg = LkConfig::default();
        let mut s = std::boxed::Box::new(LkScratch::new());
        assert_eq!(
            track_point(&pf, &pt, [100.0, 100.0], [100.0, 100.0], 3, &cfg, &mut s),
            Err(LkFailure::SmallEigen)
        );
        assert_eq!(
            track_point(&pt, &pt, [f64::NAN, 1.0], [1.0, 1.0], 3, &cfg, &mut s),
            Err(LkFailure::NonFinite)
        );
        assert_eq!(
            track_point(&pt, &pt, [100.0, 100.0], [1e6, 1.0], 0, &cfg, &mut s),
            Err(LkFailure::OutOfImage)
        );
        // Texture vs a flat target: converges nowhere useful; the residual check rejects it.
        let r = track_point(&pt, &pf, [100.0, 100.0], [100.0, 100.0], 0, &cfg, &mut s);
        assert!(r.is_err(), "{r:?}");
        // A point at the image corner uses replicated borders and still tracks a zero shift.
        let t = track_point(&pt, &pt, [1.0, 2.0], [1.0, 2.0], 3, &cfg, &mut s).unwrap();
        assert!(libm::hypot(t.pos[0] - 1.0, t.pos[1] - 2.0) < 0.01, "{t:?}");
        // An empty pyramid.
        let empty = std::boxed::Box::new(Pyr::new());
        assert_eq!(
            track_point(&empty, &pt, [10.0, 10.0], [10.0, 10.0], 3, &cfg, &mut s),
            Err(LkFailure::OutOfImage)
        );
    }
}

//! Pyramidal Lucas-Kanade for one point, inverse-compositional for a translation (the template's
//! gradients and Hessian are computed once per level), in exact integer arithmetic laid out for
//! auto-vectorization (16-bit lanes).
//!
//! Per level, from the coarsest to level 0:
//! - The template is the `(W + 2)^2` patch around the previous position, bilinearly interpolated
//!   with 8-bit weights (`sum w I <= 256 * 255` is exact in `u16`) to 3 fractional bits
//!   (`8 x grey`), its 3x3 Scharr gradients scaled to `8 x grey / px` (`|g| <= 1020`), and the
//!   Hessian `A = sum g g^T`, exact in `i32`.
//!   A template whose smallest eigenvalue of `A / N` is below `min_eigen` `(grey/px)^2` fails.
//! - Each iteration samples the window at the current guess `q` the same way (`8 x grey`,
//!   `|J - T| <= 2040`) and accumulates `b = sum (J(q + x) - T(x)) g(x)` in `i32`, which cannot
//!   overflow (`2040 * 1020 * 31 * 32 < 2^31`), then steps `q -= A^-1 b` (`f64`, fixed order). It
//!   stops when the step is below `epsilon_px` (level pixels), when it oscillates (OpenCV's
//!   half-step rule), or after `max_iterations`.
//! - The guess carries to the next finer level through the pyramid's coordinate map.
//!
//! Rows are padded to a multiple of 8 pixels with zero template gradients (so the padding adds
//! nothing), which lets the per-row kernels run whole 16-bit vectors; the sums are flat dot
//! products that compile to multiply-add instructions (`pmaddwd` on x86-64, `smlal` on
//! aarch64). 8-bit weights quantize the sampling position to 1/256 px (bias below 0.002 px).
//!
//! Windows that reach outside the image read replicated border pixels (copied into a small
//! patch first). As in OpenCV, a weak template or a window entirely off the image at a coarse
//! level only skips that level; at level 0 it fails the point. The photometric residual is the
//! mean `|J - T|` over the window in the last iteration at level 0 (less than one step from the
//! final position), in grey levels.

use super::pyramid::{Pyramid, PyramidFilter};
use super::view::ImageView;
use crate::Error;

/// Largest LK window side, px.
pub const MAX_WINDOW: usize = 31;
/// Padded row length of the largest window.
const MAX_WP: usize = 32;
const MAX_PATCH_W: usize = MAX_WP + 2;
const MAX_PATCH_H: usize = MAX_WINDOW + 2;
const MAX_SRC_W: usize = MAX_PATCH_W + 1;
const MAX_SRC_H: usize = MAX_PATCH_H + 1;
/// Bilinear weights sum to `2^WEIGHT_BITS`.
const WEIGHT_BITS: u32 = 8;

/// Lucas-Kanade parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct LkConfig {
    /// Window side at level 0, px (odd, `5..=MAX_WINDOW`).
    pub window: usize,
    /// Window side at the coarser levels, px (odd, `5..=MAX_WINDOW`). They only bring the guess
    /// into level 0's basin; OpenCV uses `window` everywhere.
    pub coarse_window: usize,
    /// Iteration cap per level.
    pub max_iterations: u32,
    /// Convergence threshold on the step at level 0, px.
    pub epsilon_px: f32,
    /// Convergence threshold on the step at the coarser levels, level px (they only need to
    /// land the guess inside the next level's basin; OpenCV uses `epsilon_px` everywhere).
    pub coarse_epsilon_px: f32,
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
            coarse_window: 15,
            max_iterations: 10,
            epsilon_px: 0.03,
            coarse_epsilon_px: 0.1,
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
            && self.coarse_window % 2 == 1
            && (5..=MAX_WINDOW).contains(&self.coarse_window)
            && (1..=1000).contains(&self.max_iterations)
            && self.epsilon_px > 0.0
            && self.epsilon_px <= 10.0
            && self.coarse_epsilon_px >= self.epsilon_px
            && self.coarse_epsilon_px <= 10.0
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
    /// Values (`8 x grey`), rows of `wp` with zero padding.
    t: [i16; MAX_WINDOW * MAX_WP],
    /// Gradients (`8 x grey / px`), zero in the padding.
    gx: [i16; MAX_WINDOW * MAX_WP],
    gy: [i16; MAX_WINDOW * MAX_WP],
    a11: f64,
    a12: f64,
    a22: f64,
}

/// Scratch of one LK track (about 12 KiB): the template, the interpolated patch, the window
/// differences and the border patch.
#[derive(Clone)]
pub struct LkScratch {
    tmpl: Template,
    interp: [i16; MAX_PATCH_H * MAX_PATCH_W],
    diff: [i16; MAX_WINDOW * MAX_WP],
    patch: [u8; MAX_SRC_H * MAX_SRC_W],
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
                t: [0; MAX_WINDOW * MAX_WP],
                gx: [0; MAX_WINDOW * MAX_WP],
                gy: [0; MAX_WINDOW * MAX_WP],
                a11: 0.0,
                a12: 0.0,
                a22: 0.0,
            },
            interp: [0; MAX_PATCH_H * MAX_PATCH_W],
            diff: [0; MAX_WINDOW * MAX_WP],
            patch: [0; MAX_SRC_H * MAX_SRC_W],
        }
    }
}

/// Window row length padded to a multiple of 8.
#[inline]
fn padded(win: usize) -> usize {
    win.div_ceil(8) * 8
}

/// Bilinear weights `(w00, w01, w10, w11)` of the fractional offsets `ax, ay` in `[0, 1)`: each
/// rounded to 8 bits, the rounding excess (at most 2) taken from the largest (at least 64), so
/// they are non-negative and sum to exactly `2^8`.
#[inline]
fn weights(ax: f64, ay: f64) -> [u16; 4] {
    let one = f64::from(1u32 << WEIGHT_BITS);
    let q = |v: f64| (v * one + 0.5) as i32;
    let mut w = [
        q((1.0 - ax) * (1.0 - ay)),
        q(ax * (1.0 - ay)),
        q((1.0 - ax) * ay),
        q(ax * ay),
    ];
    let excess = w.iter().sum::<i32>() - (1 << WEIGHT_BITS);
    let mut big = 0;
    for (i, v) in w.iter().enumerate() {
        if *v > w[big] {
            big = i;
        }
    }
    w[big] -= excess;
    w.map(|v| v.clamp(0, 1 << WEIGHT_BITS) as u16)
}

/// A source block of `rows x cols` pixels at integer top-left `(ix, iy)`: the image itself when
/// inside, otherwise a border-replicated copy in `patch`. Returns the data, its stride and the
/// offset of the block's first pixel.
fn source_block<'a>(
    img: &ImageView<'a>,
    ix: i64,
    iy: i64,
    cols: usize,
    rows: usize,
    patch: &'a mut [u8; MAX_SRC_H * MAX_SRC_W],
) -> (&'a [u8], usize, usize) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    if ix >= 0 && iy >= 0 && ix + cols as i64 <= w && iy + rows as i64 <= h {
        let off = iy as usize * img.stride() + ix as usize;
        return (img.data(), img.stride(), off);
    }
    // Row by row: the clamped source row, the inside span copied, the edges replicated.
    let left = (-ix).clamp(0, cols as i64) as usize;
    let inside_end = (w - ix).clamp(0, cols as i64) as usize;
    let (x_first, x_last) = (
        ix.clamp(0, w - 1) as usize,
        (ix + cols as i64 - 1).clamp(0, w - 1) as usize,
    );
    for (r, dst) in patch.chunks_exact_mut(cols).take(rows).enumerate() {
        let y = (iy + r as i64).clamp(0, h - 1) as usize;
        let src = img.row(y);
        let (l, rest) = dst.split_at_mut(left.min(inside_end.max(left)));
        let (mid, right) = rest.split_at_mut(inside_end.saturating_sub(left));
        l.fill(src.first().copied().unwrap_or(0));
        if let Some(s) = src.get(x_first..x_first + mid.len()) {
            mid.copy_from_slice(s);
        }
        right.fill(src.get(x_last).copied().unwrap_or(0));
    }
    let shared: &'a [u8] = patch;
    (shared, cols, 0)
}

/// One bilinear row of `N` pixels: `out[i] = ((sum w I) + round) >> shift - sub[i]` from source
/// rows `s0`, `s1` (at least `N + 1` pixels each). `u16` arithmetic is exact (`sum <= 65280`).
#[inline(always)]
fn bilinear_row<const N: usize>(
    s0: &[u8],
    s1: &[u8],
    w: [u16; 4],
    shift: u32,
    sub: Option<&[i16]>,
    out: &mut [i16],
) -> Option<()> {
    let a: &[u8; N] = s0.get(..N)?.try_into().ok()?;
    let b: &[u8; N] = s0.get(1..N + 1)?.try_into().ok()?;
    let c: &[u8; N] = s1.get(..N)?.try_into().ok()?;
    let d: &[u8; N] = s1.get(1..N + 1)?.try_into().ok()?;
    let o: &mut [i16; N] = out.get_mut(..N)?.try_into().ok()?;
    let round = 1u16 << (shift - 1);
    let [w00, w01, w10, w11] = w;
    for i in 0..N {
        let s = (w00 * u16::from(a[i]) + w01 * u16::from(b[i]))
            + (w10 * u16::from(c[i]) + w11 * u16::from(d[i]));
        o[i] = ((s + round) >> shift) as i16;
    }
    if let Some(sub) = sub {
        let t: &[i16; N] = sub.get(..N)?.try_into().ok()?;
        for i in 0..N {
            o[i] -= t[i];
        }
    }
    Some(())
}

/// [`bilinear_row`] for a runtime length among the padded sizes.
#[inline(always)]
fn bilinear_row_n(
    n: usize,
    s0: &[u8],
    s1: &[u8],
    w: [u16; 4],
    shift: u32,
    sub: Option<&[i16]>,
    out: &mut [i16],
) -> Option<()> {
    match n {
        8 => bilinear_row::<8>(s0, s1, w, shift, sub, out),
        10 => bilinear_row::<10>(s0, s1, w, shift, sub, out),
        16 => bilinear_row::<16>(s0, s1, w, shift, sub, out),
        18 => bilinear_row::<18>(s0, s1, w, shift, sub, out),
        24 => bilinear_row::<24>(s0, s1, w, shift, sub, out),
        26 => bilinear_row::<26>(s0, s1, w, shift, sub, out),
        32 => bilinear_row::<32>(s0, s1, w, shift, sub, out),
        34 => bilinear_row::<34>(s0, s1, w, shift, sub, out),
        _ => None,
    }
}

/// `(sum d gx, sum d gy)` over flat rows: exact, and a multiply-add reduction once vectorized.
#[inline(always)]
fn dot2(d: &[i16], gx: &[i16], gy: &[i16]) -> (i32, i32) {
    let (mut sx, mut sy) = (0i32, 0i32);
    for ((&d, &x), &y) in d.iter().zip(gx).zip(gy) {
        sx += i32::from(d) * i32::from(x);
        sy += i32::from(d) * i32::from(y);
    }
    (sx, sy)
}

/// `(sum gx^2, sum gx gy, sum gy^2)`.
#[inline(always)]
fn hessian(gx: &[i16], gy: &[i16]) -> (i32, i32, i32) {
    let (mut a, mut b, mut c) = (0i32, 0i32, 0i32);
    for (&x, &y) in gx.iter().zip(gy) {
        a += i32::from(x) * i32::from(x);
        b += i32::from(x) * i32::from(y);
        c += i32::from(y) * i32::from(y);
    }
    (a, b, c)
}

impl Template {
    /// Builds the template of window `win` around level coordinates `(x, y)` in `img`.
    fn build(
        &mut self,
        img: &ImageView,
        x: f64,
        y: f64,
        win: usize,
        interp: &mut [i16; MAX_PATCH_H * MAX_PATCH_W],
        patch: &mut [u8; MAX_SRC_H * MAX_SRC_W],
    ) -> Result<(), LkFailure> {
        let half = (win / 2) as f64;
        let wp = padded(win);
        let (pw, ph) = (wp + 2, win + 2);
        let (xt, yt) = (x - half - 1.0, y - half - 1.0);
        let (fx, fy) = (libm::floor(xt), libm::floor(yt));
        if !(fx.is_finite() && fy.is_finite()) {
            return Err(LkFailure::NonFinite);
        }
        let (ix, iy) = (fx as i64, fy as i64);
        let (w, h) = (img.width() as i64, img.height() as i64);
        if ix + ph as i64 <= 0 || iy + ph as i64 <= 0 || ix >= w || iy >= h {
            return Err(LkFailure::OutOfImage);
        }
        let wgt = weights(xt - fx, yt - fy);
        let (src, stride, off) = source_block(img, ix, iy, pw + 1, ph + 1, patch);
        // Interpolated (W+2) x (WP+2) patch, 3 fractional bits (x 8), rounded exactly as the
        // iterations sample the target.
        for (r, out) in interp.chunks_exact_mut(pw).take(ph).enumerate() {
            let o0 = off + r * stride;
            let (Some(s0), Some(s1)) = (src.get(o0..), src.get(o0 + stride..)) else {
                return Err(LkFailure::OutOfImage);
            };
            bilinear_row_n(pw, s0, s1, wgt, WEIGHT_BITS - 3, None, out)
                .ok_or(LkFailure::OutOfImage)?;
        }
        // Values (x 8) and Scharr gradients (x 8 grey / px) of the interior; zero padding.
        let rows = self
            .t
            .chunks_exact_mut(wp)
            .zip(self.gx.chunks_exact_mut(wp))
            .zip(self.gy.chunks_exact_mut(wp))
            .take(win);
        for (r, ((t, gx), gy)) in rows.enumerate() {
            let (Some(p0), Some(p1), Some(p2)) = (
                interp.get(r * pw..r * pw + pw),
                interp.get((r + 1) * pw..(r + 1) * pw + pw),
                interp.get((r + 2) * pw..(r + 2) * pw + pw),
            ) else {
                return Err(LkFailure::OutOfImage);
            };
            scharr_row(p0, p1, p2, t, gx, gy);
            for v in t
                .iter_mut()
                .skip(win)
                .chain(gx.iter_mut().skip(win))
                .chain(gy.iter_mut().skip(win))
            {
                *v = 0;
            }
        }
        let n = win * wp;
        let (a11, a12, a22) = hessian(
            self.gx.get(..n).unwrap_or(&[]),
            self.gy.get(..n).unwrap_or(&[]),
        );
        self.a11 = f64::from(a11);
        self.a12 = f64::from(a12);
        self.a22 = f64::from(a22);
        Ok(())
    }

    /// Smallest eigenvalue of `A / N`, `(grey / px)^2`.
    fn min_eigen(&self, win: usize) -> f64 {
        let (a, b, c) = (self.a11, self.a12, self.a22);
        let d = a - c;
        let l = 0.5 * ((a + c) - libm::sqrt(d * d + 4.0 * (b * b)));
        l / ((win * win) as f64 * 64.0)
    }
}

/// Template row and its Scharr gradients (`x 8 grey / px`) from three rows of the `x 8` patch.
#[inline(always)]
fn scharr_row(p0: &[i16], p1: &[i16], p2: &[i16], t: &mut [i16], gx: &mut [i16], gy: &mut [i16]) {
    let n = t.len();
    let (Some(a0), Some(a1), Some(a2)) = (p0.get(..n), p0.get(1..n + 1), p0.get(2..n + 2)) else {
        return;
    };
    let (Some(b0), Some(b1), Some(b2)) = (p1.get(..n), p1.get(1..n + 1), p1.get(2..n + 2)) else {
        return;
    };
    let (Some(c0), Some(c1), Some(c2)) = (p2.get(..n), p2.get(1..n + 1), p2.get(2..n + 2)) else {
        return;
    };
    let it = t
        .iter_mut()
        .zip(gx.iter_mut())
        .zip(gy.iter_mut())
        .zip(a0.iter().zip(a1).zip(a2))
        .zip(b0.iter().zip(b1).zip(b2))
        .zip(c0.iter().zip(c1).zip(c2));
    for (((((ot, ox), oy), ((&a0, &a1), &a2)), ((&b0, &b1), &b2)), ((&c0, &c1), &c2)) in it {
        // Scharr of a x 8 image (values 0..=2040) is 32 x 8 = 256 per grey / px; >> 5 gives
        // x 8 (|g| <= 1020). Exact in i16: |sum| <= 16 * 2040 + 16 = 32656.
        *ox = (3 * (a2 - a0) + 10 * (b2 - b0) + 3 * (c2 - c0) + 16) >> 5;
        *oy = (3 * (c0 - a0) + 10 * (c1 - a1) + 3 * (c2 - a2) + 16) >> 5;
        *ot = b1;
    }
}

/// `(sum diff gx, sum diff gy)` of the window at integer top-left `(ix, iy)` with `wgt`
/// (differences left in `diff`).
fn window_sums(
    src: &[u8],
    stride: usize,
    off: usize,
    wgt: [u16; 4],
    tmpl: &Template,
    win: usize,
    diff: &mut [i16; MAX_WINDOW * MAX_WP],
) -> Option<(i64, i64)> {
    let wp = padded(win);
    let rows = diff
        .chunks_exact_mut(wp)
        .zip(tmpl.t.chunks_exact(wp))
        .take(win);
    for (r, (d, t)) in rows.enumerate() {
        let o0 = off + r * stride;
        let (s0, s1) = (src.get(o0..)?, src.get(o0 + stride..)?);
        bilinear_row_n(wp, s0, s1, wgt, WEIGHT_BITS - 3, Some(t), d)?;
    }
    let n = win * wp;
    let (bx, by) = dot2(diff.get(..n)?, tmpl.gx.get(..n)?, tmpl.gy.get(..n)?);
    Some((i64::from(bx), i64::from(by)))
}

/// Mean `|J - T|` over the window (padding excluded), grey levels.
fn window_residual(diff: &[i16], win: usize) -> f32 {
    let wp = padded(win);
    let mut s = 0i32;
    for row in diff.chunks_exact(wp).take(win) {
        for &d in row.iter().take(win) {
            s += i32::from(d).abs();
        }
    }
    (f64::from(s) / ((win * win) as f64 * 8.0)) as f32
}

/// What one pyramid level did.
struct LevelRun {
    outcome: Result<(), LkFailure>,
    iterations: u32,
    converged: bool,
}

/// Gauss-Newton iterations on one level: template at `p` in `from`, guess `q` in `to`. With
/// `final_residual`, the mean photometric error at the final `q` is written to it.
#[allow(clippy::too_many_arguments)]
fn refine_level(
    from: &ImageView,
    to: &ImageView,
    p: [f64; 2],
    q: &mut [f64; 2],
    cfg: &LkConfig,
    win: usize,
    eps2: f64,
    scratch: &mut LkScratch,
    final_residual: Option<&mut f32>,
) -> LevelRun {
    let mut run = LevelRun {
        outcome: Ok(()),
        iterations: 0,
        converged: false,
    };
    let half = (win / 2) as f64;
    let wp = padded(win);
    let LkScratch {
        tmpl,
        interp,
        diff,
        patch,
    } = scratch;
    if let Err(e) = tmpl.build(from, p[0], p[1], win, interp, patch) {
        run.outcome = Err(e);
        return run;
    }
    let det = tmpl.a11 * tmpl.a22 - tmpl.a12 * tmpl.a12;
    if tmpl.min_eigen(win) < f64::from(cfg.min_eigen) || det.is_nan() || det <= 0.0 {
        run.outcome = Err(LkFailure::SmallEigen);
        return run;
    }
    let inv_det = 1.0 / det;
    let (wl, hl) = (to.width() as f64, to.height() as f64);
    let in_range = |q: &[f64; 2]| {
        q[0] >= -half && q[1] >= -half && q[0] <= wl - 1.0 + half && q[1] <= hl - 1.0 + half
    };
    let mut prev = [0.0f64; 2];
    for it in 0..cfg.max_iterations {
        if !(q[0].is_finite() && q[1].is_finite()) {
            run.outcome = Err(LkFailure::NonFinite);
            return run;
        }
        if !in_range(q) {
            run.outcome = Err(LkFailure::OutOfImage);
            return run;
        }
        let (xt, yt) = (q[0] - half, q[1] - half);
        let (fx, fy) = (libm::floor(xt), libm::floor(yt));
        let wgt = weights(xt - fx, yt - fy);
        let (src, stride, off) = source_block(to, fx as i64, fy as i64, wp + 1, win + 1, patch);
        let Some((bx, by)) = window_sums(src, stride, off, wgt, tmpl, win, diff) else {
            run.outcome = Err(LkFailure::OutOfImage);
            return run;
        };
        run.iterations += 1;
        let (bx, by) = (bx as f64, by as f64);
        let d = [
            (tmpl.a22 * bx - tmpl.a12 * by) * inv_det,
            (tmpl.a11 * by - tmpl.a12 * bx) * inv_det,
        ];
        *q = [q[0] - d[0], q[1] - d[1]];
        if d[0] * d[0] + d[1] * d[1] <= eps2 {
            run.converged = true;
            break;
        }
        if it > 0 && libm::fabs(d[0] + prev[0]) < 0.01 && libm::fabs(d[1] + prev[1]) < 0.01 {
            // Oscillating between two points: settle in the middle.
            *q = [q[0] + 0.5 * d[0], q[1] + 0.5 * d[1]];
            run.converged = true;
            break;
        }
        prev = d;
    }
    if let Some(res) = final_residual {
        // The differences of the last iteration, sampled less than one step (below
        // `epsilon_px` when converged) from the final position.
        if !(q[0].is_finite() && q[1].is_finite() && in_range(q)) || run.iterations == 0 {
            run.outcome = Err(LkFailure::OutOfImage);
            return run;
        }
        *res = window_residual(diff, win);
    }
    run
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
    track_point_impl(from, to, p0, seed, max_level, cfg, scratch, true)
}

/// [`track_point`] without the final residual pass and check (`residual` is 0): for the
/// backward track of the forward-backward check, which only uses the position.
pub fn track_point_no_residual<const B: usize, const L: usize>(
    from: &Pyramid<B, L>,
    to: &Pyramid<B, L>,
    p0: [f64; 2],
    seed: [f64; 2],
    max_level: usize,
    cfg: &LkConfig,
    scratch: &mut LkScratch,
) -> Result<LkTrack, LkFailure> {
    track_point_impl(from, to, p0, seed, max_level, cfg, scratch, false)
}

#[allow(clippy::too_many_arguments)]
fn track_point_impl<const B: usize, const L: usize>(
    from: &Pyramid<B, L>,
    to: &Pyramid<B, L>,
    p0: [f64; 2],
    seed: [f64; 2],
    max_level: usize,
    cfg: &LkConfig,
    scratch: &mut LkScratch,
    with_residual: bool,
) -> Result<LkTrack, LkFailure> {
    if cfg.validate().is_err() {
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
    let eps2 = f64::from(cfg.epsilon_px) * f64::from(cfg.epsilon_px);
    let coarse_eps2 = f64::from(cfg.coarse_epsilon_px) * f64::from(cfg.coarse_epsilon_px);
    let mut q = [filter.to_level(seed[0], top), filter.to_level(seed[1], top)];
    let mut iterations = 0u32;
    let mut residual = 0.0f32;
    let mut converged = false;
    for level in (0..=top).rev() {
        let (Some(img_from), Some(img_to)) = (from.level(level), to.level(level)) else {
            return Err(LkFailure::OutOfImage);
        };
        let p = [filter.to_level(p0[0], level), filter.to_level(p0[1], level)];
        let res = (level == 0 && with_residual).then_some(&mut residual);
        let (eps2, win) = if level == 0 {
            (eps2, cfg.window)
        } else {
            (coarse_eps2, cfg.coarse_window)
        };
        let lv = refine_level(&img_from, &img_to, p, &mut q, cfg, win, eps2, scratch, res);
        iterations += lv.iterations;
        match lv.outcome {
            Ok(()) => converged = lv.converged,
            // As OpenCV: a weak template or a window off the image at a coarse level skips the
            // level (the guess carries down); only level 0 decides.
            Err(LkFailure::SmallEigen | LkFailure::OutOfImage) if level > 0 => {}
            Err(e) => return Err(e),
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
    fn border_block_replicates_edges() {
        let img: std::vec::Vec<u8> = (0..50u8).collect(); // 10 x 5, value = 10 y + x
        let v = ImageView::new(&img, 10, 5, 10).unwrap();
        let mut patch = [0u8; MAX_SRC_H * MAX_SRC_W];
        for &(ix, iy, cols, rows) in &[
            (-3i64, -2i64, 6usize, 4usize),
            (7, 3, 6, 4),
            (-4, 1, 18, 2),
            (12, 7, 3, 3),
            (-9, -9, 4, 4),
        ] {
            let mut want = std::vec::Vec::new();
            for r in 0..rows as i64 {
                for c in 0..cols as i64 {
                    want.push(v.clamped((ix + c) as isize, (iy + r) as isize));
                }
            }
            let (src, stride, off) = source_block(&v, ix, iy, cols, rows, &mut patch);
            assert_eq!((stride, off), (cols, 0));
            assert_eq!(&src[..cols * rows], &want[..], "{ix} {iy} {cols} {rows}");
        }
    }

    #[test]
    fn weights_sum_to_256() {
        for i in 0..=200 {
            for j in 0..=200 {
                let w = weights(f64::from(i) / 200.5, f64::from(j) / 200.5);
                assert_eq!(w.iter().map(|&v| u32::from(v)).sum::<u32>(), 256, "{i} {j}");
            }
        }
        assert_eq!(weights(0.0, 0.0), [256, 0, 0, 0]);
        assert_eq!(weights(0.5, 0.5), [64, 64, 64, 64]);
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

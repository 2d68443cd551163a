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
//! - **Photometric compensation** ([`LkConfig::photometric`]): between two frames the exposure,
//!   gain or lighting changes (`J ~ alpha T + beta`); an uncompensated fit then moves the point to
//!   explain the brightness change with the gradients. As in the anchored refinement
//!   ([`super::affine`]), the error's component in the span of `{1}` (offset) or `{1, T}` (gain
//!   and offset) is projected out (Baker & Matthews' *project out*): `A' = g^T (I - P) g`,
//!   `b' = b - g^T P e`. `P e` needs the iteration's `sum e` and `sum T e` (two more
//!   multiply-adds per pixel in the same `i32` pass, `T` stored less 1024); `g^T P` the
//!   template's `sum g`, `sum g T`, `sum T`, `sum T^2` (exact integers, from one flat `i32` pass in
//!   the `photometric` submodule). The eigenvalue test applies to the projected `A'`, so a window
//!   whose texture is only a brightness ramp is rejected, and the residual is that of `(I - P) e`.
//!   As the residual without the brightness no longer separates a match from unrelated texture,
//!   the target must also correlate with the template ([`MIN_CORRELATION`]).
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
//! mean `|J - T|` (after the compensation) over the window in the last iteration at level 0 (less
//! than one step from the final position), in grey levels.

use super::affine::Photometric;
use super::pyramid::{Pyramid, PyramidFilter};
use super::view::ImageView;
use crate::Error;

mod photometric;
use photometric::Projection;
pub use photometric::{CONTRAST_CHANGE_RANGE, GAIN_CHANGE_RANGE, MIN_CORRELATION};

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
    /// Largest accepted mean absolute photometric error over the window at level 0 (after the
    /// compensation), grey levels.
    pub max_residual: f32,
    /// Which brightness changes between consecutive frames the fit absorbs (`"none"`, the
    /// default, `"offset"`, `"gain_offset"`). `"offset"` removes the drift that exposure
    /// changes cause (hand-held simulation with 2% exposure steps per frame: median error from
    /// the track's start 0.861 -> 0.554 px) and on real images (DM-VIO) keeps the tracks with
    /// fewer epipolar violations. It is not the default: where the brightness does not change it
    /// only removes a constraint (simulated EuRoC-like flights: ATE +22-57%, while hand-held and
    /// robot sequences gain 6-42%), it costs a quarter more front-end instructions, and its
    /// contrast check drops near-flat, noise-dominated windows that the default keeps (DM-VIO:
    /// 135.9 vs 136.8 tracked per image). Noise-like targets fail [`MIN_CORRELATION`].
    /// `"gain_offset"` fits the exposure model exactly, but on real blurred frames the gain
    /// absorbs the contrast loss and those tracks fail the gain range or the forward-backward
    /// check (BENCHMARKS.md, issue 14).
    pub photometric: Photometric,
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
            photometric: Photometric::None,
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
    /// The final photometric residual was too large; with a photometric model also: the fitted
    /// gain change left [`GAIN_CHANGE_RANGE`] / [`CONTRAST_CHANGE_RANGE`], or the target's
    /// correlation with the template fell below [`MIN_CORRELATION`].
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
    /// `t - 1024` in the window, 0 in the padding (so `sum (t - 1024) e` fits `i32`:
    /// `2040 * 1024 * 31 * 32 < 2^31`).
    t_off: [i16; MAX_WINDOW * MAX_WP],
    /// For the photometric sums, per window side in `mask_wins` (the fine and the coarse
    /// levels' windows alternate): 1 in the window, 0 in the padding.
    masks: [[i16; MAX_WINDOW * MAX_WP]; 2],
    mask_wins: [usize; 2],
    /// `A` (projected by `proj` when there is one).
    a11: f64,
    a12: f64,
    a22: f64,
    /// The template's sums for the photometric projection.
    proj: Option<Projection>,
}

/// Scratch of one LK track (about 17 KiB): the template, the interpolated patch, the window
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
                t_off: [0; MAX_WINDOW * MAX_WP],
                masks: [[0; MAX_WINDOW * MAX_WP]; 2],
                mask_wins: [0; 2],
                a11: 0.0,
                a12: 0.0,
                a22: 0.0,
                proj: None,
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

/// `[sum d gx, sum d gy, sum d m, sum d t]` over flat rows, exact in `i32` (see the fields of
/// `Template`).
#[inline(always)]
fn dot4(d: &[i16], gx: &[i16], gy: &[i16], m: &[i16], t: &[i16]) -> [i32; 4] {
    let mut s = [0i32; 4];
    for ((((&d, &x), &y), &m), &t) in d.iter().zip(gx).zip(gy).zip(m).zip(t) {
        let d = i32::from(d);
        s[0] += d * i32::from(x);
        s[1] += d * i32::from(y);
        s[2] += d * i32::from(m);
        s[3] += d * i32::from(t);
    }
    s
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
    #[allow(clippy::too_many_arguments)]
    fn build(
        &mut self,
        img: &ImageView,
        x: f64,
        y: f64,
        win: usize,
        photo: Photometric,
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
        self.proj = self.projection(win, photo);
        if let Some(p) = &self.proj {
            let [r11, r12, r22] = p.removed_hessian();
            self.a11 -= r11;
            self.a12 -= r12;
            self.a22 -= r22;
        }
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

/// What one iteration sums over the window: `b = sum e g` and, for the photometric projection,
/// `sum e` and `sum T e` (`e = J - T`, padding excluded).
#[derive(Clone, Copy, Default)]
struct WindowSums {
    b: [i64; 2],
    se: i64,
    ste: i64,
}

/// The sums of the window at integer top-left `(ix, iy)` with `wgt` (differences left in `diff`);
/// `se`/`ste` only with `photo`.
#[allow(clippy::too_many_arguments)]
fn window_sums(
    src: &[u8],
    stride: usize,
    off: usize,
    wgt: [u16; 4],
    tmpl: &Template,
    win: usize,
    photo: bool,
    diff: &mut [i16; MAX_WINDOW * MAX_WP],
) -> Option<WindowSums> {
    let wp = padded(win);
    let mut out = WindowSums::default();
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
    let (d, gx, gy) = (diff.get(..n)?, tmpl.gx.get(..n)?, tmpl.gy.get(..n)?);
    let (bx, by) = if photo {
        // One flat multiply-add pass for the four sums: sum e = sum mask e and
        // sum T e = sum (T - 1024) e + 1024 sum e.
        let (m, to) = (tmpl.mask(win)?.get(..n)?, tmpl.t_off.get(..n)?);
        let [bx, by, se, sto] = dot4(d, gx, gy, m, to);
        out.se = i64::from(se);
        out.ste = i64::from(sto) + 1024 * i64::from(se);
        (bx, by)
    } else {
        dot2(d, gx, gy)
    };
    out.b = [i64::from(bx), i64::from(by)];
    Some(out)
}

/// Mean `|e - mean - k Tc|` over the window (padding excluded), grey levels: the error left
/// after the photometric projection `[mean, k]` (`[0, 0]` without one).
fn window_residual(diff: &[i16], tmpl: &Template, win: usize, removed: [f64; 2]) -> f32 {
    let wp = padded(win);
    let [mean, k] = removed;
    let t_mean = tmpl.proj.map_or(0.0, |p| p.mean_t());
    let mut s = 0.0f64;
    for (row, t) in diff.chunks_exact(wp).zip(tmpl.t.chunks_exact(wp)).take(win) {
        for (&d, &t) in row.iter().zip(t).take(win) {
            s += libm::fabs(f64::from(d) - mean - k * (f64::from(t) - t_mean));
        }
    }
    (s / ((win * win) as f64 * 8.0)) as f32
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
    if let Err(e) = tmpl.build(from, p[0], p[1], win, cfg.photometric, interp, patch) {
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
    let photo = tmpl.proj.is_some();
    let mut removed = [0.0f64; 2];
    let mut gain_change = 0.0f64;
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
        let Some(sums) = window_sums(src, stride, off, wgt, tmpl, win, photo, diff) else {
            run.outcome = Err(LkFailure::OutOfImage);
            return run;
        };
        run.iterations += 1;
        let (mut bx, mut by) = (sums.b[0] as f64, sums.b[1] as f64);
        if let Some(pr) = &tmpl.proj {
            let (r, pe, k_fit) = pr.removed_gradient(sums.se, sums.ste);
            bx -= r[0];
            by -= r[1];
            removed = pe;
            gain_change = k_fit;
        }
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
        // A gain far from 1 means the fit explained the window by the brightness model (a
        // textured template against a flat target is `J = 0 T + beta`), not by a motion.
        // Without a photometric model the residual check alone decides, as before.
        // With the brightness removed, the residual alone no longer separates a match from
        // unrelated texture (interpolated noise leaves a mean |e - mean| near 30 grey levels):
        // the target must also correlate with the template.
        if let Some(p) = &tmpl.proj {
            let (lo, hi) = p.gain_range();
            if !(lo..=hi).contains(&gain_change)
                || tmpl.correlation(diff, win, p) < photometric::MIN_CORRELATION
            {
                run.outcome = Err(LkFailure::Residual);
                return run;
            }
        }
        *res = window_residual(diff, tmpl, win, removed);
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
#[path = "lk_tests.rs"]
mod tests;

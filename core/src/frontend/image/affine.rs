//! Inverse-compositional affine Lucas-Kanade of one window against a stored reference template
//! (the anchored refinement of [`super::reference`]), in fixed point.
//!
//! The template is the `(win + 2)^2` raw level-0 pixels around the integer pixel `c` nearest the
//! reference point `c + delta` (no interpolation: the sub-pixel offset `delta` is carried by the
//! warp). Its 3x3 Scharr gradients (`32 x grey / px`, `|g| <= 4080`), the steepest-descent images
//! `SD = [gx x, gx y, gy x, gy y, gx, gy]` and the 6x6 Gauss-Newton Hessian `H = sum SD SD^T`
//! (exact in `i64`) are fixed by the template: `H^-1` is computed once per reference
//! ([`Template::build`]), never per frame.
//!
//! The warp maps a template offset `x` (px from `c`) to `A x + t` in the target; the tracked point
//! is `A delta + t`. Each iteration samples the target at the warped offsets row by row in
//! 16.16 fixed point (the row's start from `f64`, then a constant integer step: the positions of
//! an affine warp along a row are linear), bilinearly with 8-bit weights to `1/8` grey, and
//! accumulates `b = sum SD^T (I(W(x)) - T(x))` in integers (per row in `i32`, which cannot
//! overflow: `4080 * 2040 * 10 * 21 < 2^31`; across rows in `i64`), then `dp = H^-1 b` (`f64`)
//! and composes `W <- W o W(dp)^-1`. Rows whose samples stay inside the image read it directly,
//! the others clamp (border pixels replicated).
//!
//! **Photometric compensation** ([`Photometric`]): a brightness change between the reference and
//! the target (auto exposure, gain, a light turned away) biases an uncompensated fit, since
//! `b = sum SD^T e` then holds `beta sum SD` as well. With [`Photometric::Offset`] or
//! [`Photometric::GainOffset`] the error's component in the span of `{1}` or `{1, T}` is
//! projected out (Baker & Matthews' *project out* inverse-compositional algorithm):
//! `H' = SD^T (I - P) SD`, `b' = SD^T (I - P) e = b - SD^T P e`, with `P` the orthogonal
//! projector onto that span. `P e` needs only `sum e` and `sum T e` of the iteration, and
//! `SD^T P` only the template's `sum SD`, `sum SD T`, `sum T` and `sum T^2`: exact integers, so a
//! step costs one multiply-add per pixel more than without compensation. The residual is the
//! root mean square of `(I - P) e`.
//!
//! Integers, and `f64` in a fixed order without fused multiply-add: bit-identical on every IEEE
//! platform.

use super::view::ImageView;

/// Largest refinement window side, px (sizes the per-track storage).
pub const MAX_AFFINE_WINDOW: usize = 21;
/// Side of a stored template (window plus the gradients' one-pixel border).
pub const TEMPLATE_SIDE: usize = MAX_AFFINE_WINDOW + 2;
const MAX_N: usize = MAX_AFFINE_WINDOW * MAX_AFFINE_WINDOW;
/// Fractional bits of the sampling positions.
const FRAC: u32 = 16;
const ONE: f64 = (1u32 << FRAC) as f64;

/// Which brightness changes between the reference and the target the refinement absorbs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "snake_case")
)]
pub enum Photometric {
    /// None: the target must have the reference's grey levels.
    None,
    /// A constant offset `J = T + beta`.
    Offset,
    /// Gain and offset `J = alpha T + beta` (exposure changes).
    #[default]
    GainOffset,
}

impl Photometric {
    fn code(self) -> u8 {
        match self {
            Photometric::None => 0,
            Photometric::Offset => 1,
            Photometric::GainOffset => 2,
        }
    }

    fn from_code(c: u8) -> Self {
        match c {
            1 => Photometric::Offset,
            2 => Photometric::GainOffset,
            _ => Photometric::None,
        }
    }
}

/// An affine warp: template offset `x` (px from the template's centre pixel) -> `a x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// Linear part, row-major `[[a00, a01], [a10, a11]]`.
    pub a: [f64; 4],
    /// Translation: where the template's centre pixel lands in the target, px.
    pub t: [f64; 2],
}

impl Affine {
    /// The warp with linear part `a` that maps the point `c + delta` to `q`.
    pub fn through(a: [f64; 4], delta: [f64; 2], q: [f64; 2]) -> Self {
        Affine {
            a,
            t: [
                q[0] - (a[0] * delta[0] + a[1] * delta[1]),
                q[1] - (a[2] * delta[0] + a[3] * delta[1]),
            ],
        }
    }

    /// Where the point `c + delta` lands.
    pub fn point(&self, delta: [f64; 2]) -> [f64; 2] {
        [
            self.a[0] * delta[0] + self.a[1] * delta[1] + self.t[0],
            self.a[2] * delta[0] + self.a[3] * delta[1] + self.t[1],
        ]
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
    /// Root mean square photometric error over the window in the last iteration (after the
    /// [`Photometric`] compensation), grey levels.
    pub residual: f64,
    /// Whether the last step moved the window's corners less than `eps_px`.
    pub converged: bool,
    /// Iterations run.
    pub iterations: u32,
}

/// One reference template: raw pixels and the inverse of its Gauss-Newton Hessian. All zero
/// is the empty (invalid) template.
#[derive(Clone, Copy)]
pub struct Template {
    /// `(win + 2)^2` raw pixels, row stride [`TEMPLATE_SIDE`].
    pix: [u8; TEMPLATE_SIDE * TEMPLATE_SIDE],
    /// Upper triangle of `4 H^-1` (row by row), `H` from the raw gradients (projected by the
    /// photometric model, see the module doc).
    hinv: [f64; 21],
    /// Window side (0: invalid).
    win: u8,
    /// [`Photometric`] code the Hessian was projected with.
    photo: u8,
}

impl Template {
    /// The empty template.
    pub const EMPTY: Template = Template {
        pix: [0; TEMPLATE_SIDE * TEMPLATE_SIDE],
        hinv: [0.0; 21],
        win: 0,
        photo: 0,
    };

    /// Makes the template invalid.
    pub fn clear(&mut self) {
        self.win = 0;
    }

    /// Whether the template can be refined against.
    pub fn is_valid(&self) -> bool {
        self.win != 0
    }

    /// The raw pixels (row stride [`TEMPLATE_SIDE`], `(win + 2)^2` used) and the window side
    /// (0: invalid).
    pub fn pixels(&self) -> (&[u8; TEMPLATE_SIDE * TEMPLATE_SIDE], usize) {
        (&self.pix, usize::from(self.win))
    }

    /// Captures the `win x win` template (odd, `5..=MAX_AFFINE_WINDOW`) centred on the integer
    /// pixel `c` of `img` (outside pixels replicate the border) and inverts its Hessian, projected
    /// by the photometric model `photo`. An invalid template (bad window, empty image, flat or
    /// one-dimensional texture) results otherwise; `g` is gradient scratch.
    pub fn build(
        &mut self,
        img: &ImageView,
        c: [i64; 2],
        win: usize,
        photo: Photometric,
        g: &mut Gradients,
    ) {
        self.win = 0;
        if win.is_multiple_of(2) || !(5..=MAX_AFFINE_WINDOW).contains(&win) {
            return;
        }
        let (w, h) = (img.width() as i64, img.height() as i64);
        if w == 0 || h == 0 || c[0].abs() > 1 << 20 || c[1].abs() > 1 << 20 {
            return;
        }
        let side = win + 2;
        let r = (win / 2 + 1) as i64;
        let (x0, y0) = (c[0] - r, c[1] - r);
        for (row, dst) in self
            .pix
            .chunks_exact_mut(TEMPLATE_SIDE)
            .take(side)
            .enumerate()
        {
            let src = img.row((y0 + row as i64).clamp(0, h - 1) as usize);
            for (col, d) in dst.iter_mut().take(side).enumerate() {
                let x = (x0 + col as i64).clamp(0, w - 1) as usize;
                *d = src.get(x).copied().unwrap_or(0);
            }
        }
        g.compute(&self.pix, win);
        if let Some(hinv) = inverse_hessian(g, win, photo) {
            self.hinv = hinv;
            self.win = win as u8;
            self.photo = photo.code();
        }
    }
}

/// Per-call scratch: the template's values (`8 x grey`) and Scharr gradients, one row of
/// errors and the column offsets `x` of the window.
#[derive(Clone)]
pub struct Gradients {
    t8: [i16; MAX_N],
    gx: [i16; MAX_N],
    gy: [i16; MAX_N],
    /// `J - T` of one row, `1/8` grey (`|e| <= 2040`).
    e: [i16; MAX_AFFINE_WINDOW],
    /// `c - win / 2` for column `c` (`|x e| <= 20400`: the products `x e` fit `i16`).
    xs: [i16; MAX_AFFINE_WINDOW],
}

impl Default for Gradients {
    fn default() -> Self {
        Self::new()
    }
}

impl Gradients {
    /// Zeroed scratch.
    pub const fn new() -> Self {
        Gradients {
            t8: [0; MAX_N],
            gx: [0; MAX_N],
            gy: [0; MAX_N],
            e: [0; MAX_AFFINE_WINDOW],
            xs: [0; MAX_AFFINE_WINDOW],
        }
    }

    /// Values and Scharr gradients of the `win x win` interior of `pix` (stride
    /// [`TEMPLATE_SIDE`]): three template rows at a time, one output row per step (the same
    /// integers as the per-pixel formula, see the tests).
    fn compute(&mut self, pix: &[u8; TEMPLATE_SIDE * TEMPLATE_SIDE], win: usize) {
        let side = win + 2;
        let half = (win / 2) as i16;
        for (c, x) in self.xs.iter_mut().enumerate() {
            *x = c as i16 - half;
        }
        for r in 0..win {
            let o = r * TEMPLATE_SIDE;
            let rows = (
                pix.get(o..o + side),
                pix.get(o + TEMPLATE_SIDE..o + TEMPLATE_SIDE + side),
                pix.get(o + 2 * TEMPLATE_SIDE..o + 2 * TEMPLATE_SIDE + side),
            );
            let out = r * win..(r + 1) * win;
            let (Some(up), Some(mid), Some(dn)) = rows else {
                return;
            };
            let (Some(t8), Some(gx), Some(gy)) = (
                self.t8.get_mut(out.clone()),
                self.gx.get_mut(out.clone()),
                self.gy.get_mut(out),
            ) else {
                return;
            };
            let cols = up.windows(3).zip(mid.windows(3)).zip(dn.windows(3));
            for ((((u, m), d), t), (x, y)) in cols.zip(t8).zip(gx.iter_mut().zip(gy)) {
                let (Some(&[u0, u1, u2]), Some(&[m0, m1, m2]), Some(&[d0, d1, d2])) =
                    (u.get(..3), m.get(..3), d.get(..3))
                else {
                    continue;
                };
                let [u0, u1, u2, m0, m2, d0, d1, d2] =
                    [u0, u1, u2, m0, m2, d0, d1, d2].map(i16::from);
                *t = 8 * i16::from(m1);
                *x = 3 * (u2 - u0) + 10 * (m2 - m0) + 3 * (d2 - d0);
                *y = 3 * (d0 - u0) + 10 * (d1 - u1) + 3 * (d2 - u2);
            }
        }
    }
}

/// Index of `(i, j)`, `i <= j`, in a packed upper triangle of a 6x6 matrix.
const fn upper(i: usize, j: usize) -> usize {
    i * 6 - i * (i + 1) / 2 + j
}

/// The template's sums that the photometric projection needs (exact integers): with
/// `SD = [gx x, gx y, gy x, gy y, gx, gy]` (32 grey/px) and `t` the template (8 x grey), `s1 =
/// sum SD`, `st = n sum SD t - s1 sum t` (`n` times `sum SD (t - mean t)`), `var = n sum t^2 -
/// (sum t)^2` (`n^2` times the variance), `sum_t = sum t`, `n` the pixel count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PhotoSums {
    s1: [i64; 6],
    st: [i64; 6],
    var: i64,
    sum_t: i64,
    n: i64,
}

impl PhotoSums {
    #[allow(clippy::needless_range_loop)] // fixed 6-vectors
    /// The sums of the template in `g` (`None` when `g` holds fewer than `win^2` values).
    fn of(g: &Gradients, win: usize) -> Option<Self> {
        let half = (win / 2) as i64;
        let (mut s1, mut sdt) = ([0i64; 6], [0i64; 6]);
        let (mut sum_t, mut sum_tt) = (0i64, 0i64);
        for k in 0..win * win {
            let (x, y) = ((k % win) as i64 - half, (k / win) as i64 - half);
            let (gx, gy) = (i64::from(*g.gx.get(k)?), i64::from(*g.gy.get(k)?));
            let t = i64::from(*g.t8.get(k)?);
            let sd = [gx * x, gx * y, gy * x, gy * y, gx, gy];
            for i in 0..6 {
                s1[i] += sd[i];
                sdt[i] += sd[i] * t;
            }
            sum_t += t;
            sum_tt += t * t;
        }
        let n = (win * win) as i64;
        let mut st = [0i64; 6];
        for i in 0..6 {
            st[i] = n * sdt[i] - s1[i] * sum_t;
        }
        Some(PhotoSums {
            s1,
            st,
            var: n * sum_tt - sum_t * sum_t,
            sum_t,
            n,
        })
    }

    /// `SD^T P e` (what the projection removes from `b`) and `|P e|^2`, from the iteration's
    /// `sum e` and `sum t e`; `photo` selects the span of `P`.
    fn removed(&self, photo: Photometric, se: i64, ste: i64) -> ([f64; 6], f64) {
        let n = self.n as f64;
        let mut out = [0.0f64; 6];
        if photo == Photometric::None {
            return (out, 0.0);
        }
        // Offset: P e = mean(e) 1.
        let se_f = se as f64;
        for (o, &s1) in out.iter_mut().zip(&self.s1) {
            *o = (se as f64 * s1 as f64) / n;
        }
        let mut pe2 = se_f * se_f / n;
        if photo == Photometric::GainOffset && self.var > 0 {
            // Gain: + k (t - mean t), k = n sum (t - mean t) e / (n^2 var) = c / var.
            let c = (self.n * ste - self.sum_t * se) as f64;
            let var = self.var as f64;
            for (o, &st) in out.iter_mut().zip(&self.st) {
                *o += (c * st as f64) / (var * n);
            }
            pe2 += (c * c) / (var * n);
        }
        (out, pe2)
    }
}

/// `4 H^-1` (packed upper triangle) of the template in `g`, `H` projected by the photometric model
/// `photo`; `None` if `H` is not positive definite or badly conditioned.
#[allow(clippy::needless_range_loop)] // fixed 6x6 indices, clearer than iterators
fn inverse_hessian(g: &Gradients, win: usize, photo: Photometric) -> Option<[f64; 21]> {
    let half = (win / 2) as i64;
    let mut h = [0i64; 21];
    for k in 0..win * win {
        let (x, y) = ((k % win) as i64 - half, (k / win) as i64 - half);
        let (gx, gy) = (i64::from(*g.gx.get(k)?), i64::from(*g.gy.get(k)?));
        let sd = [gx * x, gx * y, gy * x, gy * y, gx, gy];
        for i in 0..6 {
            for j in i..6 {
                h[upper(i, j)] += sd[i] * sd[j];
            }
        }
    }
    // H / 1024 (gradients in grey/px: keeps the numbers moderate), minus SD^T P SD.
    let mut hp = h.map(|v| v as f64 / 1024.0);
    if photo != Photometric::None {
        let ps = PhotoSums::of(g, win)?;
        let n = ps.n as f64;
        let var = ps.var as f64;
        for i in 0..6 {
            for j in i..6 {
                let mut d = (ps.s1[i] as f64 * ps.s1[j] as f64) / n;
                if photo == Photometric::GainOffset && ps.var > 0 {
                    d += (ps.st[i] as f64 * ps.st[j] as f64) / (var * n);
                }
                hp[upper(i, j)] -= d / 1024.0;
            }
        }
    }
    // Cholesky of the projected H / 1024, then the inverse.
    let mut l = [[0.0f64; 6]; 6];
    for j in 0..6 {
        let mut d = hp[upper(j, j)];
        for k in 0..j {
            d -= l[j][k] * l[j][k];
        }
        // A near-singular H (a flat window or an edge) gives no reliable warp.
        if d.is_nan() || d <= 1e-6 * (h[upper(j, j)] as f64 / 1024.0) || d <= 0.0 {
            return None;
        }
        let d = libm::sqrt(d);
        l[j][j] = d;
        for i in j + 1..6 {
            let mut s = hp[upper(j, i)];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / d;
        }
    }
    // Columns of (H/1024)^-1 by forward and back substitution; the stored 4 H^-1 is that over 256
    // (dp = H^-1 b with g in 32 grey/px and e in 8 grey: dp = 4 H_raw^-1 b_raw).
    let mut out = [0.0f64; 21];
    for col in 0..6 {
        let mut y = [0.0f64; 6];
        for i in 0..6 {
            let mut s = if i == col { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i][k] * y[k];
            }
            y[i] = s / l[i][i];
        }
        let mut x = [0.0f64; 6];
        for i in (0..6).rev() {
            let mut s = y[i];
            for k in i + 1..6 {
                s -= l[k][i] * x[k];
            }
            x[i] = s / l[i][i];
        }
        for i in 0..=col {
            out[upper(i, col)] = x[i] / 256.0;
        }
    }
    Some(out)
}

/// `M b` for the symmetric `M` stored as [`inverse_hessian`]'s packed upper triangle.
#[allow(clippy::needless_range_loop)]
fn sym_mul(m: &[f64; 21], b: &[f64; 6]) -> [f64; 6] {
    let mut out = [0.0f64; 6];
    for i in 0..6 {
        let mut s = 0.0;
        for j in 0..6 {
            let k = if i <= j { upper(i, j) } else { upper(j, i) };
            s += m[k] * b[j];
        }
        out[i] = s;
    }
    out
}

/// 16.16 fixed point of `v`, `None` if non-finite or beyond +-16384 px.
#[inline]
fn fixed(v: f64) -> Option<i32> {
    if !(-16384.0..16384.0).contains(&v) {
        return None;
    }
    Some(libm::floor(v * ONE + 0.5) as i32)
}

/// Bilinear value of the four pixels with 8-bit weights `fx`, `fy`, in `1/8` grey.
#[inline(always)]
fn blend(p00: u8, p01: u8, p10: u8, p11: u8, fx: i32, fy: i32) -> i32 {
    // `a (256 - f) + b f = 256 a + (b - a) f`: the same integers with one product each.
    let top = (i32::from(p00) << 8) + (i32::from(p01) - i32::from(p00)) * fx;
    let bot = (i32::from(p10) << 8) + (i32::from(p11) - i32::from(p10)) * fx;
    ((top << 8) + (bot - top) * fy + (1 << 12)) >> 13
}

/// Side of the local copy of the target one iteration samples ([`TargetBox`]), a power of two.
const BOX: usize = 32;

/// The target pixels under one iteration's samples, border replicated: `rows x cols` pixels
/// from `(x0, y0)`, row stride [`BOX`]. The padding past `BOX * BOX` lets the 2x2 reads of a
/// masked index go unchecked.
pub(crate) struct TargetBox {
    pix: [u8; BOX * BOX + BOX + 1],
    /// Origin in the target, px.
    x0: i64,
    y0: i64,
}

impl TargetBox {
    pub(crate) const fn new() -> Self {
        TargetBox {
            pix: [0; BOX * BOX + BOX + 1],
            x0: 0,
            y0: 0,
        }
    }

    /// Loads the pixels that rows starting at `starts` (16.16) with `win` samples in steps
    /// `step` read (their 2x2 neighbourhoods); `false` (nothing loaded) when they span more
    /// than `BOX - 1` pixels either way.
    fn load(
        &mut self,
        img: &ImageView,
        starts: &[(i32, i32)],
        step: (i32, i32),
        win: usize,
    ) -> bool {
        let last = win as i64 - 1;
        let (mut x0, mut x1, mut y0, mut y1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for &(u, v) in starts {
            let (u, v) = (i64::from(u), i64::from(v));
            let (ue, ve) = (u + last * i64::from(step.0), v + last * i64::from(step.1));
            x0 = x0.min(u.min(ue) >> FRAC);
            x1 = x1.max(u.max(ue) >> FRAC);
            y0 = y0.min(v.min(ve) >> FRAC);
            y1 = y1.max(v.max(ve) >> FRAC);
        }
        // Pixels x0..=x1 + 1 and y0..=y1 + 1 (the neighbourhoods' right and bottom pixels).
        let (cols, rows) = (x1 - x0 + 2, y1 - y0 + 2);
        if !(1..=BOX as i64).contains(&cols) || !(1..=BOX as i64).contains(&rows) {
            return false;
        }
        let (w, h) = (img.width() as i64, img.height() as i64);
        let cols = cols as usize;
        for (j, dst) in self
            .pix
            .chunks_exact_mut(BOX)
            .take(rows as usize)
            .enumerate()
        {
            let src = img.row((y0 + j as i64).clamp(0, h - 1) as usize);
            let dst = dst.get_mut(..cols).unwrap_or(&mut []);
            let inner = usize::try_from(x0).ok().and_then(|x| src.get(x..x + cols));
            match inner {
                Some(s) if s.len() == dst.len() => dst.copy_from_slice(s),
                _ => {
                    for (i, d) in dst.iter_mut().enumerate() {
                        let x = (x0 + i as i64).clamp(0, w - 1) as usize;
                        *d = src.get(x).copied().unwrap_or(0);
                    }
                }
            }
        }
        self.x0 = x0;
        self.y0 = y0;
        true
    }

    /// Samples one row from the box (the row must be one of those [`TargetBox::load`] was
    /// given): `e = J - T` as in [`sample_row`].
    #[inline]
    fn sample_row(&self, (u, v): (i32, i32), (du, dv): (i32, i32), t8: &[i16], e: &mut [i16]) {
        // Box coordinates: whole pixels off, the fractions unchanged (in range after `load`).
        let mut uu = (i64::from(u) - (self.x0 << FRAC)) as i32;
        let mut vv = (i64::from(v) - (self.y0 << FRAC)) as i32;
        for (ei, &t) in e.iter_mut().zip(t8) {
            let (ix, iy) = ((uu >> FRAC) as usize, (vv >> FRAC) as usize);
            let o = (iy & (BOX - 1)) * BOX + (ix & (BOX - 1));
            let (fx, fy) = ((uu >> (FRAC - 8)) & 255, (vv >> (FRAC - 8)) & 255);
            let p = &self.pix;
            let j = blend(p[o], p[o + 1], p[o + BOX], p[o + BOX + 1], fx, fy);
            *ei = (j - i32::from(t)) as i16;
            uu = uu.wrapping_add(du);
            vv = vv.wrapping_add(dv);
        }
    }
}

/// Samples one row of the warped window (`e.len()` positions from `(u, v)` in steps `(du, dv)`,
/// 16.16) into `e` as `J - T` (`1/8` grey) straight from the image (rows a [`TargetBox`]
/// cannot hold).
#[inline]
fn sample_row(
    img: &ImageView,
    (u, v): (i32, i32),
    (du, dv): (i32, i32),
    t8: &[i16],
    e: &mut [i16],
) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let last = e.len() as i64 - 1;
    let (ue, ve) = (
        i64::from(u) + last * i64::from(du),
        i64::from(v) + last * i64::from(dv),
    );
    let ok = |p: i64, lim: i64| p >= 0 && (p >> FRAC) < lim - 1;
    let inside = ok(i64::from(u), w) && ok(ue, w) && ok(i64::from(v), h) && ok(ve, h);
    let (data, stride) = (img.data(), img.stride());
    let (mut uu, mut vv) = (u, v);
    for (ei, &t) in e.iter_mut().zip(t8) {
        let (ix, iy) = (uu >> FRAC, vv >> FRAC);
        let (fx, fy) = ((uu >> (FRAC - 8)) & 255, (vv >> (FRAC - 8)) & 255);
        let j = if inside {
            // One bounds check for the 2x2 neighbourhood (`q.len() == stride + 2`).
            let o = iy as usize * stride + ix as usize;
            let q = data.get(o..o + stride + 2).unwrap_or(&[]);
            match (q.first(), q.get(1), q.get(stride), q.get(stride + 1)) {
                (Some(&p00), Some(&p01), Some(&p10), Some(&p11)) => {
                    blend(p00, p01, p10, p11, fx, fy)
                }
                _ => 0,
            }
        } else {
            let (ix, iy) = (ix as isize, iy as isize);
            blend(
                img.clamped(ix, iy),
                img.clamped(ix + 1, iy),
                img.clamped(ix, iy + 1),
                img.clamped(ix + 1, iy + 1),
                fx,
                fy,
            )
        };
        *ei = (j - i32::from(t)) as i16;
        uu = uu.wrapping_add(du);
        vv = vv.wrapping_add(dv);
    }
}

/// One row's sums `(sum gx e, sum gx x e, sum gy e, sum gy x e, sum e, sum t e, sum e^2)`
/// (`i32`: every term is at most `4080 x 20400` or `2040 x 2040`, 21 of them, see the module
/// doc); every product is `i16 x i16` (`x e` fits, see [`Gradients`]).
#[inline]
fn row_sums(e: &[i16], xs: &[i16], gx: &[i16], gy: &[i16], t8: &[i16]) -> [i32; 7] {
    let (mut sx, mut sxx, mut sy, mut syx) = (0i32, 0i32, 0i32, 0i32);
    let (mut se, mut ste, mut see) = (0i32, 0i32, 0i32);
    for ((((&e, &x), &gxv), &gyv), &t) in e.iter().zip(xs).zip(gx).zip(gy).zip(t8) {
        let xe = i32::from(x * e);
        let (e, gxv, gyv, t) = (i32::from(e), i32::from(gxv), i32::from(gyv), i32::from(t));
        sx += gxv * e;
        sxx += gxv * xe;
        sy += gyv * e;
        syx += gyv * xe;
        se += e;
        ste += t * e;
        see += e * e;
    }
    [sx, sxx, sy, syx, se, ste, see]
}

/// The step `dp = H^-1 b'` and the residual (grey levels, RMS) from an iteration's sums: `b`,
/// `sum e`, `sum t e`, `sum e^2` (see [`PhotoSums::removed`]).
fn photometric_step(
    tpl: &Template,
    ps: Option<&PhotoSums>,
    b: &[i64; 6],
    (se, ste, see): (i64, i64, i64),
    n: usize,
) -> ([f64; 6], f64) {
    let mut bf = b.map(|v| v as f64);
    let mut pe2 = 0.0;
    if let Some(ps) = ps {
        let (rm, p) = ps.removed(Photometric::from_code(tpl.photo), se, ste);
        for (x, r) in bf.iter_mut().zip(rm) {
            *x -= r;
        }
        pe2 = p;
    }
    let ms = (see as f64 - pe2).max(0.0) / n as f64;
    (sym_mul(&tpl.hinv, &bf), libm::sqrt(ms) / 8.0)
}

/// Refines `init` (the warp of `tpl`'s centre pixel into `img`), at most `max_iter` iterations,
/// stopping when the window's corners move less than `eps_px`. `None` for an invalid template or
/// a degenerate or non-finite warp.
pub fn refine_affine(
    tpl: &Template,
    img: &ImageView,
    init: Affine,
    max_iter: u32,
    eps_px: f64,
    g: &mut Gradients,
) -> Option<AffineFit> {
    let win = usize::from(tpl.win);
    if win == 0 {
        return None;
    }
    g.compute(&tpl.pix, win);
    let ps = match Photometric::from_code(tpl.photo) {
        Photometric::None => None,
        _ => Some(PhotoSums::of(g, win)?),
    };
    let mut tb = TargetBox::new();
    let tb = &mut tb;
    let half = (win / 2) as i64;
    let hf = half as f64;
    let mut w = init;
    let mut fit = AffineFit {
        warp: w,
        residual: 0.0,
        converged: false,
        iterations: 0,
    };
    for _ in 0..max_iter {
        let mut b = [0i64; 6];
        let (mut se, mut ste, mut see) = (0i64, 0i64, 0i64);
        let step = (fixed(w.a[0])?, fixed(w.a[2])?);
        // Row starts from `f64` (the same rounding for every row), then integer steps.
        let mut starts = [(0i32, 0i32); MAX_AFFINE_WINDOW];
        for (r, st) in starts.iter_mut().take(win).enumerate() {
            let yf = (r as i64 - half) as f64;
            *st = (
                fixed(w.t[0] - w.a[0] * hf + w.a[1] * yf)?,
                fixed(w.t[1] - w.a[2] * hf + w.a[3] * yf)?,
            );
        }
        let starts = starts.get(..win)?;
        let boxed = tb.load(img, starts, step, win);
        for (r, &start) in starts.iter().enumerate() {
            let y = r as i64 - half;
            let row = r * win..(r + 1) * win;
            let (t8, gx, gy) = (
                g.t8.get(row.clone())?,
                g.gx.get(row.clone())?,
                g.gy.get(row)?,
            );
            let (e, xs) = (g.e.get_mut(..win)?, g.xs.get(..win)?);
            if boxed {
                tb.sample_row(start, step, t8, e);
            } else {
                sample_row(img, start, step, t8, e);
            }
            let [sx, sxx, sy, syx, s_e, s_te, s_ee] = row_sums(e, xs, gx, gy, t8);
            b[0] += i64::from(sxx);
            b[1] += y * i64::from(sx);
            b[2] += i64::from(syx);
            b[3] += y * i64::from(sy);
            b[4] += i64::from(sx);
            b[5] += i64::from(sy);
            se += i64::from(s_e);
            ste += i64::from(s_te);
            see += i64::from(s_ee);
        }
        fit.iterations += 1;
        let (dp, residual) = photometric_step(tpl, ps.as_ref(), &b, (se, ste, see), win * win);
        fit.residual = residual;
        let (nw, moved2) = compose(&w, &dp, hf)?;
        w = nw;
        if moved2 <= eps_px * eps_px {
            fit.converged = true;
            break;
        }
    }
    fit.warp = w;
    Some(fit)
}

/// `W o W(dp)^-1` with `W(dp): x -> (I + D) x + d`, and the squared distance the window's
/// corner (at `half` px) moves; `None` for a degenerate step or warp.
fn compose(w: &Affine, dp: &[f64; 6], half: f64) -> Option<(Affine, f64)> {
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
    let nt = [
        w.t[0] - (na[0] * dp[4] + na[1] * dp[5]),
        w.t[1] - (na[2] * dp[4] + na[3] * dp[5]),
    ];
    // Translation plus the linear change at `half`.
    let (du, dv) = (nt[0] - w.t[0], nt[1] - w.t[1]);
    let lin = (na[0] - a[0]) * (na[0] - a[0])
        + (na[1] - a[1]) * (na[1] - a[1])
        + (na[2] - a[2]) * (na[2] - a[2])
        + (na[3] - a[3]) * (na[3] - a[3]);
    let nw = Affine { a: na, t: nt };
    if !(nw.t[0].is_finite() && nw.t[1].is_finite() && (0.25..=4.0).contains(&nw.det())) {
        return None;
    }
    Some((nw, du * du + dv * dv + lin * half * half))
}

#[cfg(test)]
#[path = "affine_tests.rs"]
mod tests;

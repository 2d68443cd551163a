//! The template's side of LK's photometric compensation (see the parent module's docs): the
//! offset template `T - 1024` and the sums of the projection `P` onto `{1}` or `{1, T}`, exact
//! integers from one flat `i32` pass over the padded rows (16-bit lanes, multiply-add once
//! vectorized), the `f64` terms each iteration removes, and the correlation test.
//!
//! Bounds of the flat `i32` sums over at most `31 x 32` padded pixels (`T <= 2040` so
//! `|T - 1024| <= 1024`, `|g| <= 1020`): `sum g (T - 1024) <= 1020 * 1024 * 992 < 2^31`,
//! `sum (T - 1024)^2 <= 1024^2 * 992 < 2^31`. The window's `sum T`, `sum g T` and `sum T^2`
//! follow exactly in `i64`.

use super::super::affine::Photometric;
use super::{padded, Template};

/// With [`Photometric::GainOffset`], the accepted range of the fitted gain change `alpha - 1`
/// of `J ~ alpha T + beta` at level 0 (gain 2/3 to 3/2): beyond it the point fails as
/// [`super::LkFailure::Residual`].
pub const GAIN_CHANGE_RANGE: (f64, f64) = (-1.0 / 3.0, 0.5);
/// With [`Photometric::Offset`], the accepted range of the same fitted gain change (which the
/// offset model does not remove): the target window must keep at least half of the template's
/// contrast. Without it a textured template matches a flat target once the offset is removed.
pub const CONTRAST_CHANGE_RANGE: (f64, f64) = (-0.5, 1.0);

/// With a photometric model, the smallest accepted correlation coefficient between the template
/// and the target window at level 0. Once the offset (and gain) is removed, the mean residual no
/// longer separates a match from unrelated texture (an interpolated uniform-noise target leaves
/// about 30 grey levels, the default `max_residual`), and against a weak template the fitted
/// gain is too noisy for the contrast range. LK's search finds correlations up to 0.3-0.4 on
/// noise; accepted frame-to-frame tracks correlate above 0.4 (real hand-held images, 50 000
/// tracks: 0.1% below 0.56, the lowest 0.41 on near-flat windows) and above 0.5 in the simulator
/// with exposure changes or motion blur.
pub const MIN_CORRELATION: f64 = 0.4;

/// Writes the window mask of side `win` in rows of `wp`: 1 in the window, 0 in the padding.
pub(super) fn window_mask(mask: &mut [i16], win: usize, wp: usize) {
    for row in mask.chunks_exact_mut(wp).take(win) {
        for (i, m) in row.iter_mut().enumerate() {
            *m = i16::from(i < win);
        }
    }
}

/// `t_off = (t - 1024) mask` over flat rows: `T - 1024` in the window, 0 in the padding.
#[inline(always)]
pub(super) fn offset_template(t: &[i16], mask: &[i16], t_off: &mut [i16]) {
    for ((o, &t), &m) in t_off.iter_mut().zip(t).zip(mask) {
        *o = (t - 1024) * m;
    }
}

impl Template {
    /// The offset template and the projection's sums of a built template (`t`, `gx`, `gy` of
    /// side `win`); `None` without a photometric model.
    pub(super) fn projection(&mut self, win: usize, photo: Photometric) -> Option<Projection> {
        if photo == Photometric::None {
            return None;
        }
        let n = win * padded(win);
        let slot = self.mask_slot(win);
        let (t, m, to) = (
            self.t.get(..n)?,
            self.masks.get(slot)?.get(..n)?,
            self.t_off.get_mut(..n)?,
        );
        offset_template(t, m, to);
        Some(Projection::of(
            self.t_off.get(..n)?,
            self.gx.get(..n)?,
            self.gy.get(..n)?,
            win,
            photo,
        ))
    }

    /// The slot of `masks` that holds the mask of side `win`, built if neither does.
    fn mask_slot(&mut self, win: usize) -> usize {
        if let Some(slot) = self.mask_wins.iter().position(|&w| w == win) {
            return slot;
        }
        // Slot 0 first, then slot 1 (which a third window side would keep rebuilding).
        let slot = usize::from(self.mask_wins.first() != Some(&0));
        if let (Some(mask), Some(w)) = (self.masks.get_mut(slot), self.mask_wins.get_mut(slot)) {
            window_mask(mask, win, padded(win));
            *w = win;
        }
        slot
    }

    /// The mask of side `win` (built by [`Template::projection`]).
    pub(super) fn mask(&self, win: usize) -> Option<&[i16]> {
        let slot = self.mask_wins.iter().position(|&w| w == win)?;
        self.masks.get(slot).map(|m| &m[..])
    }

    /// Correlation coefficient of the template `T` and the target window `J = T + e` (`diff`)
    /// over the window (padding excluded), from exact integer sums; 0 when either is flat.
    pub(super) fn correlation(&self, diff: &[i16], win: usize, proj: &Projection) -> f64 {
        let n = win * padded(win);
        let (Some(d), Some(m), Some(to)) = (
            diff.get(..n),
            self.mask(win).and_then(|m| m.get(..n)),
            self.t_off.get(..n),
        ) else {
            return 0.0;
        };
        // One flat pass with `J - 1024 = (T - 1024) + e` in the window, 0 in the padding:
        // `|J - 1024| <= 1024`, so the sums fit `i32`.
        let (mut sj, mut sjj, mut stj) = (0i32, 0i32, 0i32);
        for ((&d, &m), &t) in d.iter().zip(m).zip(to) {
            let (t, j) = (i32::from(t), i32::from(t) + i32::from(d) * i32::from(m));
            sj += j;
            sjj += j * j;
            stj += t * j;
        }
        proj.correlation(i64::from(sj), i64::from(sjj), i64::from(stj))
    }
}

/// The template's part of the photometric projection `P`: with `n` the window's pixel count,
/// `s = sum g`, `st = n sum g T - s sum T = n sum g Tc` (`Tc` the centred template) and
/// `var = n sum T^2 - (sum T)^2 = n sum Tc^2`, exact integers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Projection {
    pub(super) gain: bool,
    pub(super) n: i64,
    pub(super) s: [i64; 2],
    pub(super) st: [i64; 2],
    pub(super) var: i64,
    pub(super) sum_t: i64,
}

impl Projection {
    /// The sums of a template of side `win` from flat padded rows: `t_off` (`T - 1024`, 0 in
    /// the padding, see [`offset_template`]) and the gradients `gx`, `gy` (0 in the padding).
    pub(super) fn of(
        t_off: &[i16],
        gx: &[i16],
        gy: &[i16],
        win: usize,
        photo: Photometric,
    ) -> Self {
        let (mut sx, mut sy, mut sxt, mut syt, mut st, mut stt) =
            (0i32, 0i32, 0i32, 0i32, 0i32, 0i32);
        for ((&t, &x), &y) in t_off.iter().zip(gx).zip(gy) {
            let (t, x, y) = (i32::from(t), i32::from(x), i32::from(y));
            sx += x;
            sy += y;
            sxt += x * t;
            syt += y * t;
            st += t;
            stt += t * t;
        }
        let n = (win * win) as i64;
        let s = [i64::from(sx), i64::from(sy)];
        let sum_t = i64::from(st) + 1024 * n;
        // sum g T = sum g (T - 1024) + 1024 sum g; sum T^2 = sum (T - 1024)^2 + 2048 sum (T - 1024)
        // + 1024^2 n (the padding adds nothing to any of them).
        let sgt = [i64::from(sxt) + 1024 * s[0], i64::from(syt) + 1024 * s[1]];
        let sum_tt = i64::from(stt) + 2048 * i64::from(st) + 1024 * 1024 * n;
        Projection {
            gain: photo == Photometric::GainOffset,
            n,
            s,
            st: [n * sgt[0] - s[0] * sum_t, n * sgt[1] - s[1] * sum_t],
            var: n * sum_tt - sum_t * sum_t,
            sum_t,
        }
    }

    /// Whether the gain direction is projected (a flat template has none).
    pub(super) fn with_gain(&self) -> bool {
        self.gain && self.var > 0
    }

    /// `g^T P g` (`[11, 12, 22]`), what the projection removes from `A`.
    pub(super) fn removed_hessian(&self) -> [f64; 3] {
        let n = self.n as f64;
        let s = self.s.map(|v| v as f64);
        let mut r = [s[0] * s[0] / n, s[0] * s[1] / n, s[1] * s[1] / n];
        if self.with_gain() {
            let st = self.st.map(|v| v as f64);
            let vn = self.var as f64 * n;
            r[0] += st[0] * st[0] / vn;
            r[1] += st[0] * st[1] / vn;
            r[2] += st[1] * st[1] / vn;
        }
        r
    }

    /// What one iteration's `sum e` and `sum T e` remove: `g^T P e`, and `[mean e, k]` with
    /// `P e = mean(e) + k Tc` (`k = 0` without the gain). Also the fitted gain change
    /// `sum Tc e / sum Tc^2` (`alpha - 1` of `J ~ alpha T + beta`), computed for both models.
    pub(super) fn removed_gradient(&self, se: i64, ste: i64) -> ([f64; 2], [f64; 2], f64) {
        let n = self.n as f64;
        let mean = se as f64 / n;
        let mut out = [mean * self.s[0] as f64, mean * self.s[1] as f64];
        // k = sum Tc e / sum Tc^2 = c / var with c = n sum Tc e.
        let k_fit = if self.var > 0 {
            (self.n * ste - self.sum_t * se) as f64 / self.var as f64
        } else {
            0.0
        };
        let mut k = 0.0;
        if self.with_gain() {
            k = k_fit;
            out[0] += k * self.st[0] as f64 / n;
            out[1] += k * self.st[1] as f64 / n;
        }
        (out, [mean, k], k_fit)
    }

    /// Accepted range of the fitted gain change at level 0.
    pub(super) fn gain_range(&self) -> (f64, f64) {
        if self.gain {
            GAIN_CHANGE_RANGE
        } else {
            CONTRAST_CHANGE_RANGE
        }
    }

    /// Correlation coefficient of the template and a target window `J` given the window sums
    /// `sum (J - 1024)`, `sum (J - 1024)^2` and `sum (T - 1024) (J - 1024)` (exact integers; the
    /// offset cancels); 0 when either is flat.
    pub(super) fn correlation(&self, sj: i64, sjj: i64, stj: i64) -> f64 {
        let var_j = self.n * sjj - sj * sj;
        if self.var <= 0 || var_j <= 0 {
            return 0.0;
        }
        let cov = (self.n * stj - (self.sum_t - 1024 * self.n) * sj) as f64;
        cov / libm::sqrt(self.var as f64 * var_j as f64)
    }

    /// Mean of the template over the window (`x 8 grey`).
    pub(super) fn mean_t(&self) -> f64 {
        if self.n > 0 {
            self.sum_t as f64 / self.n as f64
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The straightforward `i64` sums over the window, the oracle for the flat `i32` passes.
    fn oracle(t: &[i16], gx: &[i16], gy: &[i16], win: usize, wp: usize) -> [i64; 6] {
        let mut o = [0i64; 6];
        for r in 0..win {
            for c in 0..win {
                let i = r * wp + c;
                let (t, x, y) = (i64::from(t[i]), i64::from(gx[i]), i64::from(gy[i]));
                o[0] += x;
                o[1] += y;
                o[2] += x * t;
                o[3] += y * t;
                o[4] += t;
                o[5] += t * t;
            }
        }
        o
    }

    /// Flat `i32` sums equal the `i64` window sums, at the extremes of the value ranges (which
    /// would overflow `i32` without the offset) and on pseudo-random templates, for every
    /// window side and padding.
    #[test]
    fn flat_sums_equal_the_window_sums_at_the_extremes() {
        const N: usize = 31 * 32;
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        for win in [3usize, 7, 9, 15, 21, 31] {
            let wp = win.div_ceil(8) * 8;
            for case in 0..6 {
                let (mut t, mut gx, mut gy) = ([0i16; N], [0i16; N], [0i16; N]);
                for r in 0..win {
                    for c in 0..win {
                        let i = r * wp + c;
                        let u = next();
                        (t[i], gx[i], gy[i]) = match case {
                            0 => (2040, 1020, -1020),
                            1 => (0, -1020, 1020),
                            2 => (2040, -1020, -1020),
                            _ => (
                                (u % 2041) as i16,
                                ((u >> 16) % 2041) as i16 - 1020,
                                ((u >> 32) % 2041) as i16 - 1020,
                            ),
                        };
                    }
                }
                let mut mask = [0i16; N];
                let mut t_off = [0i16; N];
                window_mask(&mut mask, win, wp);
                offset_template(&t[..win * wp], &mask[..win * wp], &mut t_off[..win * wp]);
                let o = oracle(&t, &gx, &gy, win, wp);
                let n = (win * win) as i64;
                for photo in [Photometric::Offset, Photometric::GainOffset] {
                    let p = Projection::of(
                        &t_off[..win * wp],
                        &gx[..win * wp],
                        &gy[..win * wp],
                        win,
                        photo,
                    );
                    assert_eq!(p.n, n);
                    assert_eq!(p.s, [o[0], o[1]], "win {win} case {case}");
                    assert_eq!(p.sum_t, o[4], "win {win} case {case}");
                    assert_eq!(
                        p.st,
                        [n * o[2] - o[0] * o[4], n * o[3] - o[1] * o[4]],
                        "win {win} case {case}"
                    );
                    assert_eq!(p.var, n * o[5] - o[4] * o[4], "win {win} case {case}");
                    assert_eq!(p.gain, photo == Photometric::GainOffset);
                }
            }
        }
    }

    /// The mask and the offset template are zero in the padding, `T - 1024` inside.
    #[test]
    fn offset_template_is_zero_in_the_padding() {
        let (win, wp) = (5usize, 8usize);
        let mut mask = [7i16; 40];
        window_mask(&mut mask, win, wp);
        let t = [2040i16; 40];
        let mut t_off = [0i16; 40];
        offset_template(&t, &mask, &mut t_off);
        for r in 0..win {
            for c in 0..wp {
                let inside = c < win;
                assert_eq!(mask[r * wp + c], i16::from(inside));
                assert_eq!(t_off[r * wp + c], if inside { 1016 } else { 0 });
            }
        }
    }
}

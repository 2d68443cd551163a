//! Image pyramid in a fixed buffer: level 0 is a copy of the input (optionally equalized), each
//! next level a 2x integer downsample.
//!
//! Two filters, both in exact integer arithmetic (bit-identical on every target):
//! - [`PyramidFilter::Gaussian5`] (default): OpenCV's `pyrDown`, the separable
//!   `[1 4 6 4 1] / 16` kernel in both directions with reflect-101 borders, sampled at even
//!   pixels, rounded (`(sum + 128) >> 8`). Level `l` pixel `i` sits at level-0 pixel `2^l i`.
//! - [`PyramidFilter::Box2`]: the 2x2 mean (`(a + b + c + d + 2) >> 2`, the last column/row
//!   replicated for odd sizes). Level `l` pixel `i` covers level-0 pixels `2^l i .. 2^l (i+1)`,
//!   so its centre is at `2^l (i + 0.5) - 0.5`.
//!
//! Level `l` has size `((w_{l-1} + 1) / 2, (h_{l-1} + 1) / 2)` for both filters.

use super::equalize::{Equalization, Equalizer};
use super::view::{ImageView, MAX_IMAGE_SIDE};
use crate::Error;

/// Levels stop before a side would drop below this many pixels.
pub const MIN_LEVEL_SIDE: usize = 8;

/// Downsampling filter between pyramid levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum PyramidFilter {
    /// `[1 4 6 4 1] / 16` separable Gaussian, reflect-101 borders (OpenCV `pyrDown`).
    #[default]
    Gaussian5,
    /// 2x2 box mean (OpenCV `INTER_AREA` at one half).
    Box2,
}

impl PyramidFilter {
    /// Level-`level` coordinate of the level-0 pixel coordinate `x0_px`.
    #[inline]
    pub fn to_level(self, x0_px: f64, level: usize) -> f64 {
        let s = level_scale(level);
        match self {
            PyramidFilter::Gaussian5 => x0_px / s,
            PyramidFilter::Box2 => (x0_px + 0.5) / s - 0.5,
        }
    }

    /// Level-0 coordinate of the level-`level` pixel coordinate `xl_px`.
    #[inline]
    pub fn from_level(self, xl_px: f64, level: usize) -> f64 {
        let s = level_scale(level);
        match self {
            PyramidFilter::Gaussian5 => xl_px * s,
            PyramidFilter::Box2 => (xl_px + 0.5) * s - 0.5,
        }
    }

    /// Level-`level` coordinate of the level-`level + 1` coordinate `x_px` (one step finer).
    #[inline]
    pub fn up_one(self, x_px: f64) -> f64 {
        match self {
            PyramidFilter::Gaussian5 => x_px * 2.0,
            PyramidFilter::Box2 => (x_px + 0.5) * 2.0 - 0.5,
        }
    }
}

#[inline]
fn level_scale(level: usize) -> f64 {
    // Exact powers of two; levels beyond 62 never occur (MIN_LEVEL_SIDE stops far earlier).
    (1u64 << level.min(62)) as f64
}

/// Size of level `level` of a `width` x `height` image: each level halves, rounding up.
pub const fn level_size(width: usize, height: usize, level: usize) -> (usize, usize) {
    let (mut w, mut h) = (width, height);
    let mut l = 0;
    while l < level {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        l += 1;
    }
    (w, h)
}

/// Bytes a pyramid of `levels` levels (level 0 included) of a `width` x `height` image needs:
/// use it to size the `BYTES` parameter of [`Pyramid`] (e.g. `pyramid_bytes(752, 480, 4)` =
/// 479 400).
pub const fn pyramid_bytes(width: usize, height: usize, levels: usize) -> usize {
    let mut total = 0;
    let mut l = 0;
    while l < levels {
        let (w, h) = level_size(width, height, l);
        total += w * h;
        l += 1;
    }
    total
}

/// An image pyramid of at most `LEVELS` levels held in a `BYTES`-byte buffer (levels stored
/// one after the other, rows packed: stride = width). Size `BYTES` with [`pyramid_bytes`].
///
/// Besides the buffer the struct holds two rows of scratch (`4 * MAX_IMAGE_SIDE` bytes, 32 KiB)
/// and the equalizer's lookup tables (see [`Equalizer`]).
#[derive(Clone)]
pub struct Pyramid<const BYTES: usize, const LEVELS: usize> {
    buf: [u8; BYTES],
    dims: [(usize, usize); LEVELS],
    offsets: [usize; LEVELS],
    levels: usize,
    filter: PyramidFilter,
    vert: [u16; MAX_IMAGE_SIDE],
    horiz: [u16; MAX_IMAGE_SIDE],
    equalizer: Equalizer,
}

impl<const BYTES: usize, const LEVELS: usize> Default for Pyramid<BYTES, LEVELS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const BYTES: usize, const LEVELS: usize> Pyramid<BYTES, LEVELS> {
    /// An empty pyramid (no level built).
    pub const fn new() -> Self {
        Pyramid {
            buf: [0; BYTES],
            dims: [(0, 0); LEVELS],
            offsets: [0; LEVELS],
            levels: 0,
            filter: PyramidFilter::Gaussian5,
            vert: [0; MAX_IMAGE_SIDE],
            horiz: [0; MAX_IMAGE_SIDE],
            equalizer: Equalizer::new(),
        }
    }

    /// Back to the state [`Self::new`] builds: no level built, the default filter (the image
    /// bytes and scratch are left as they are: a build writes them before reading).
    pub fn reset_to_new(&mut self) {
        self.dims = [(0, 0); LEVELS];
        self.offsets = [0; LEVELS];
        self.levels = 0;
        self.filter = PyramidFilter::Gaussian5;
    }

    /// Number of levels built (0 before the first build or after a failed one).
    #[inline]
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// The filter the pyramid was built with.
    #[inline]
    pub fn filter(&self) -> PyramidFilter {
        self.filter
    }

    /// Level `level` as an image, or `None` if it was not built.
    pub fn level(&self, level: usize) -> Option<ImageView<'_>> {
        if level >= self.levels {
            return None;
        }
        let (w, h) = *self.dims.get(level)?;
        let off = *self.offsets.get(level)?;
        let data = self.buf.get(off..off + w * h)?;
        ImageView::new(data, w, h, w).ok()
    }

    /// Builds up to `levels` levels (at most `LEVELS`; fewer when a level would have a side below
    /// [`MIN_LEVEL_SIDE`]) from `image`, equalizing level 0 as asked. Returns the number built.
    ///
    /// Errors: [`Error::CapacityExceeded`] if the levels do not fit in `BYTES` (the pyramid is
    /// then empty), [`Error::InvalidConfig`] for an invalid equalization setting.
    pub fn build(
        &mut self,
        image: &ImageView,
        levels: usize,
        filter: PyramidFilter,
        equalization: Equalization,
    ) -> Result<usize, Error> {
        self.levels = 0;
        self.filter = filter;
        let (w0, h0) = (image.width(), image.height());
        let mut n = levels.clamp(1, LEVELS.max(1));
        if LEVELS == 0 {
            return Err(Error::CapacityExceeded);
        }
        // Drop levels that would be too small to track on.
        let mut l = 1;
        while l < n {
            let (w, h) = level_size(w0, h0, l);
            if w < MIN_LEVEL_SIDE || h < MIN_LEVEL_SIDE {
                n = l;
                break;
            }
            l += 1;
        }
        if pyramid_bytes(w0, h0, n) > BYTES {
            return Err(Error::CapacityExceeded);
        }
        let mut off = 0;
        for l in 0..n {
            let d = level_size(w0, h0, l);
            if let (Some(dim), Some(o)) = (self.dims.get_mut(l), self.offsets.get_mut(l)) {
                *dim = d;
                *o = off;
            }
            off += d.0 * d.1;
        }
        // Level 0: copy (and equalize).
        let dst0 = self.buf.get_mut(..w0 * h0).ok_or(Error::CapacityExceeded)?;
        self.equalizer.apply(image, equalization, dst0)?;
        for l in 1..n {
            let (ws, hs) = level_size(w0, h0, l - 1);
            let (wd, hd) = level_size(w0, h0, l);
            let (so, doff) = match (self.offsets.get(l - 1), self.offsets.get(l)) {
                (Some(&a), Some(&b)) => (a, b),
                _ => return Err(Error::CapacityExceeded),
            };
            let (lo, hi) = self.buf.split_at_mut(doff);
            let src = lo.get(so..so + ws * hs).ok_or(Error::CapacityExceeded)?;
            let dst = hi.get_mut(..wd * hd).ok_or(Error::CapacityExceeded)?;
            match filter {
                PyramidFilter::Gaussian5 => {
                    gaussian_down(src, ws, hs, dst, wd, hd, &mut self.vert, &mut self.horiz)
                }
                PyramidFilter::Box2 => box_down(src, ws, hs, dst, wd, hd),
            }
        }
        self.levels = n;
        Ok(n)
    }
}

/// Reflect-101 index (`-1 -> 1`, `n -> n - 2`), clamped for tiny sizes.
#[inline]
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n <= 1 {
        return 0;
    }
    let r = if i < 0 {
        -i
    } else if i >= n {
        2 * n - 2 - i
    } else {
        i
    };
    r.clamp(0, n - 1) as usize
}

/// One Gaussian `pyrDown` step: vertical 5-tap over the full width into `vert` (`u16`, at most
/// `16 * 255`), horizontal 5-tap at every column into `horiz` (at most `256 * 255 + 128`, still
/// `u16`), then every other column rounded (`>> 8`). Contiguous loops that vectorize; the two
/// columns at each border use reflect-101.
#[allow(clippy::too_many_arguments)]
fn gaussian_down(
    src: &[u8],
    ws: usize,
    hs: usize,
    dst: &mut [u8],
    wd: usize,
    hd: usize,
    vert: &mut [u16],
    horiz: &mut [u16],
) {
    let (Some(vert), Some(horiz)) = (vert.get_mut(..ws), horiz.get_mut(..ws)) else {
        return;
    };
    let row = |y: usize| src.get(y * ws..y * ws + ws).unwrap_or(&[]);
    for (yd, drow) in dst.chunks_exact_mut(wd).take(hd).enumerate() {
        let yc = 2 * yd as isize;
        let r0 = row(reflect101(yc - 2, hs));
        let r1 = row(reflect101(yc - 1, hs));
        let r2 = row(reflect101(yc, hs));
        let r3 = row(reflect101(yc + 1, hs));
        let r4 = row(reflect101(yc + 2, hs));
        let it = vert
            .iter_mut()
            .zip(r0.iter().zip(r4))
            .zip(r1.iter().zip(r3))
            .zip(r2);
        for (((v, (&a, &e)), (&b, &d)), &c) in it {
            *v = (u16::from(a) + u16::from(e))
                + 4 * (u16::from(b) + u16::from(d))
                + 6 * u16::from(c);
        }
        // Horizontal at every interior column x in 2..ws-2 (max 16 * 4080 + 128 = 65408).
        if ws >= 5 {
            let n = ws - 4;
            let (Some(t0), Some(t1), Some(t2), Some(t3), Some(t4)) = (
                vert.get(..n),
                vert.get(1..n + 1),
                vert.get(2..n + 2),
                vert.get(3..n + 3),
                vert.get(4..n + 4),
            ) else {
                return;
            };
            let out = horiz.get_mut(2..n + 2).unwrap_or(&mut []);
            for (((((o, &a), &b), &c), &d), &e) in
                out.iter_mut().zip(t0).zip(t1).zip(t2).zip(t3).zip(t4)
            {
                *o = ((a + e) + 4 * (b + d) + 6 * c + 128) >> 8;
            }
        }
        // Border columns with reflect-101 on the vertical sums.
        let col = |x: isize| u32::from(vert.get(reflect101(x, ws)).copied().unwrap_or(0));
        for x in (0..2.min(ws)).chain(ws.saturating_sub(2).max(2)..ws) {
            let xc = x as isize;
            let sum = col(xc - 2) + 4 * col(xc - 1) + 6 * col(xc) + 4 * col(xc + 1) + col(xc + 2);
            if let Some(h) = horiz.get_mut(x) {
                *h = ((sum + 128) >> 8) as u16;
            }
        }
        // Every other column.
        for (o, pair) in drow.iter_mut().zip(horiz.chunks_exact(2)) {
            *o = pair[0] as u8;
        }
        if ws % 2 == 1 {
            if let (Some(o), Some(&h)) = (drow.get_mut(wd - 1), horiz.get(ws - 1)) {
                *o = h as u8;
            }
        }
    }
}

/// One 2x2 box step; the last column / row is replicated for odd sizes.
fn box_down(src: &[u8], ws: usize, hs: usize, dst: &mut [u8], wd: usize, hd: usize) {
    let row = |y: usize| src.get(y * ws..y * ws + ws).unwrap_or(&[]);
    for (yd, drow) in dst.chunks_exact_mut(wd).take(hd).enumerate() {
        let a = row(2 * yd);
        let b = row((2 * yd + 1).min(hs - 1));
        for ((o, pa), pb) in drow
            .iter_mut()
            .zip(a.chunks_exact(2))
            .zip(b.chunks_exact(2))
        {
            let s = u16::from(pa[0]) + u16::from(pa[1]) + u16::from(pb[0]) + u16::from(pb[1]) + 2;
            *o = (s >> 2) as u8;
        }
        if ws % 2 == 1 {
            let x = ws - 1;
            let s = 2 * u16::from(a.get(x).copied().unwrap_or(0))
                + 2 * u16::from(b.get(x).copied().unwrap_or(0))
                + 2;
            if let Some(o) = drow.get_mut(wd - 1) {
                *o = (s >> 2) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::{vec, vec::Vec};

    #[test]
    fn sizes() {
        assert_eq!(level_size(752, 480, 3), (94, 60));
        assert_eq!(level_size(641, 361, 1), (321, 181));
        assert_eq!(pyramid_bytes(752, 480, 4), 360960 + 90240 + 22560 + 5640);
        assert_eq!(pyramid_bytes(10, 10, 0), 0);
    }

    /// Reference pyrDown straight from the definition (2-D kernel, reflect-101, rounding).
    fn reference_gauss(src: &[u8], w: usize, h: usize) -> Vec<u8> {
        let k = [1i32, 4, 6, 4, 1];
        let (wd, hd) = (w.div_ceil(2), h.div_ceil(2));
        let mut out = vec![0u8; wd * hd];
        for yd in 0..hd {
            for xd in 0..wd {
                let mut s = 0i32;
                for (j, kj) in k.iter().enumerate() {
                    for (i, ki) in k.iter().enumerate() {
                        let y = reflect101(2 * yd as isize + j as isize - 2, h);
                        let x = reflect101(2 * xd as isize + i as isize - 2, w);
                        s += kj * ki * i32::from(src[y * w + x]);
                    }
                }
                out[yd * wd + xd] = ((s + 128) >> 8) as u8;
            }
        }
        out
    }

    fn pseudo_image(w: usize, h: usize, seed: u32) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 24) as u8
            })
            .collect()
    }

    #[test]
    fn gaussian_matches_definition_on_odd_and_even_sizes() {
        for &(w, h) in &[(37usize, 23usize), (40, 32), (17, 15), (64, 48)] {
            let img = pseudo_image(w, h, (w * h) as u32);
            let view = ImageView::new(&img, w, h, w).unwrap();
            let mut p = Pyramid::<{ pyramid_bytes(64, 48, 3) }, 3>::new();
            let n = p
                .build(&view, 3, PyramidFilter::Gaussian5, Equalization::Off)
                .unwrap();
            assert!(n >= 2);
            let l0 = p.level(0).unwrap();
            assert_eq!(l0.row(h - 1), &img[(h - 1) * w..h * w]);
            let l1 = p.level(1).unwrap();
            let want = reference_gauss(&img, w, h);
            let (wd, hd) = (w.div_ceil(2), h.div_ceil(2));
            assert_eq!((l1.width(), l1.height()), (wd, hd));
            for y in 0..hd {
                assert_eq!(l1.row(y), &want[y * wd..(y + 1) * wd], "{w}x{h} row {y}");
            }
        }
    }

    #[test]
    fn gaussian_hand_computed() {
        // A single bright pixel at (8, 8) of a 17x17 zero image spreads as the outer product of
        // [1 4 6 4 1]/16 sampled at even pixels.
        let mut img = [0u8; 17 * 17];
        img[8 * 17 + 8] = 255;
        let view = ImageView::new(&img, 17, 17, 17).unwrap();
        let mut p = Pyramid::<400, 2>::new();
        p.build(&view, 2, PyramidFilter::Gaussian5, Equalization::Off)
            .unwrap();
        let l1 = p.level(1).unwrap();
        // (255 * 36 + 128) >> 8 = 36; a neighbour 2 px away: (255 * 6 + 128) >> 8 = 6; diagonal
        // (255 + 128) >> 8 = 1.
        assert_eq!(l1.get(4, 4), Some(36));
        assert_eq!(l1.get(3, 4), Some(6));
        assert_eq!(l1.get(4, 5), Some(6));
        assert_eq!(l1.get(3, 3), Some(1));
        assert_eq!(l1.get(2, 4), Some(0));
    }

    #[test]
    fn box_hand_computed_and_odd_sizes() {
        let img = [
            10u8, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120, 130, 140, 150,
        ];
        // 5x3: level 1 is 3x2.
        let view = ImageView::new(&img, 5, 3, 5).unwrap();
        let mut p = Pyramid::<64, 2>::new();
        // Too small for a second level (MIN_LEVEL_SIDE): only level 0 is built.
        assert_eq!(
            p.build(&view, 2, PyramidFilter::Box2, Equalization::Off)
                .unwrap(),
            1
        );
        let mut big = [0u8; 16 * 16];
        for (i, b) in big.iter_mut().enumerate() {
            *b = (i % 16 * 10 + i / 16) as u8;
        }
        let view = ImageView::new(&big, 15, 16, 16).unwrap();
        let mut p = Pyramid::<512, 2>::new();
        assert_eq!(
            p.build(&view, 2, PyramidFilter::Box2, Equalization::Off)
                .unwrap(),
            2
        );
        let l1 = p.level(1).unwrap();
        assert_eq!((l1.width(), l1.height()), (8, 8));
        // (0,0): pixels (0,0)=0,(1,0)=10,(0,1)=1,(1,1)=11 -> (22+2)/4 = 6.
        assert_eq!(l1.get(0, 0), Some(6));
        // Last column replicated: x=14 -> 2 * 140 + 2 * 141 + 2 = 564 -> 564 / 4 = 141.
        assert_eq!(l1.get(7, 0), Some(141));
    }

    #[test]
    fn capacity_and_coordinates() {
        let img = [0u8; 100 * 100];
        let view = ImageView::new(&img, 100, 100, 100).unwrap();
        let mut p = Pyramid::<10000, 2>::new();
        assert_eq!(
            p.build(&view, 2, PyramidFilter::Gaussian5, Equalization::Off),
            Err(Error::CapacityExceeded)
        );
        assert_eq!(p.levels(), 0);
        assert!(p.level(0).is_none());
        for f in [PyramidFilter::Gaussian5, PyramidFilter::Box2] {
            for l in 0..4 {
                let x = 123.375;
                assert_eq!(f.from_level(f.to_level(x, l), l), x);
            }
            assert_eq!(f.up_one(f.to_level(7.25, 1)), 7.25);
        }
        assert_eq!(PyramidFilter::Box2.to_level(0.5, 1), 0.0);
    }
}

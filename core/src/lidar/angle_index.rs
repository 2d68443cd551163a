//! Equal-angle cell index of a tangent without an `atan` per point.
//!
//! An axis of `N` cells of `c` rad centred on 0 has lower boundaries `a_i = (i - N/2) c`. Cell
//! `i` holds the angles in `[a_i, a_(i+1))`, i.e. the tangents `u` in `[tan a_i, tan a_(i+1))`
//! (tangent is increasing on `(-pi/2, pi/2)`; boundaries beyond are `-inf`/`+inf`). A lookup
//! table over `u` in uniform bins gives the cell of each bin's lower edge; bins are narrower
//! than any cell (for extents up to about +-80 deg at 0.5 deg cells), so the cell of `u` is that
//! one or the next, settled by comparing with the tabulated boundary. The comparisons make the
//! answer exactly the tabulated cell (a walk handles bins wider than cells), bit-reproducible:
//! only `-`, `*` and comparisons per point. Keys and boundaries are `f32` (the grid's points
//! are), and the table coordinate `(u - u0) / step` can be computed in vectorized batches.

use core::f64::consts::FRAC_PI_2;

/// Bins of the lookup table (2 bytes each).
pub(crate) const LUT_BINS: usize = 2048;
/// The table covers tangents up to this magnitude (89.4 deg); beyond, the walk finishes.
const TAN_LIMIT: f64 = 100.0;

/// Cell boundaries and lookup table of one grid axis of `N` cells (`N <= 65536`; 0 holds nothing).
#[derive(Debug, Clone)]
pub(crate) struct Axis<const N: usize> {
    /// `lower[i] = tan((i - N/2) c)` rounded to `f32`.
    lower: [f32; N],
    /// Lower bound of the first cell and upper bound of the last.
    first: f32,
    upper: f32,
    /// Cell of the lowest tangent of each bin (table coordinate in `[k, k + 1)`).
    lut: [u16; LUT_BINS],
    u0: f32,
    inv_step: f32,
    /// Every bin holds at most one boundary.
    one_step: bool,
}

impl<const N: usize> Axis<N> {
    // N = 0: an axis of a grid that holds nothing (an estimator built without LiDAR storage).
    const FITS: () = assert!(N <= 1 << 16, "an axis has at most 65536 cells");

    /// An axis holding nothing until [`Axis::configure`].
    pub(crate) const fn new() -> Self {
        let () = Self::FITS;
        Axis {
            lower: [0.0; N],
            first: 0.0,
            upper: 0.0,
            lut: [0; LUT_BINS],
            u0: 0.0,
            inv_step: 0.0,
            one_step: false,
        }
    }

    /// Back to the state [`Axis::new`] builds, in place.
    pub(crate) fn reset_to_new(&mut self) {
        self.lower.fill(0.0);
        self.first = 0.0;
        self.upper = 0.0;
        self.lut.fill(0);
        self.u0 = 0.0;
        self.inv_step = 0.0;
        self.one_step = false;
    }

    /// Tabulates cells of `cell_rad` (positive, finite).
    pub(crate) fn configure(&mut self, cell_rad: f64) {
        let half = N as f64 * 0.5;
        let tan_at = |i: f64| {
            let a = (i - half) * cell_rad;
            if a <= -FRAC_PI_2 {
                f32::NEG_INFINITY
            } else if a >= FRAC_PI_2 {
                f32::INFINITY
            } else {
                libm::tan(a) as f32
            }
        };
        let mut prev = f32::NEG_INFINITY;
        for (i, t) in self.lower.iter_mut().enumerate() {
            // Rounding to f32 must not reorder boundaries (cells of ~1e-7 rad).
            *t = tan_at(i as f64).max(prev);
            prev = *t;
        }
        self.first = self.lower.first().copied().unwrap_or(0.0);
        self.upper = tan_at(N as f64).max(prev);
        let lo = f64::from(self.first).max(-TAN_LIMIT);
        let hi = f64::from(self.upper).min(TAN_LIMIT);
        self.u0 = lo as f32;
        self.inv_step = (LUT_BINS as f64 / (hi - lo)) as f32;
        let step = 1.0 / f64::from(self.inv_step);
        // The f32 table coordinate of a key is off by well under 1% of a bin: each entry is the
        // cell of its bin's lowest key less that slack, and a bin with its slack may hold one
        // boundary for the single comparison to settle it.
        let slack = 0.01 * step;
        let lower = &self.lower;
        let cell_of = |u: f64| {
            lower
                .partition_point(|&l| f64::from(l) <= u)
                .saturating_sub(1)
        };
        let mut one_step = step.is_finite() && step > 0.0;
        for (k, e) in self.lut.iter_mut().enumerate() {
            let u = f64::from(self.u0) + k as f64 * step;
            let first = cell_of(u - slack);
            *e = u16::try_from(first).unwrap_or(u16::MAX);
            one_step &= cell_of(u + step + slack) <= first + 1;
        }
        self.one_step = one_step;
    }

    /// The table bin of a key, or -1 outside the table (and for NaN): branch-free, for
    /// [`Axis::cell_in_bin`] (cheap to compute for many keys at once).
    #[inline]
    pub(crate) fn bin(&self, u: f32) -> i32 {
        let t = (u - self.u0) * self.inv_step;
        if t >= 0.0 && t < LUT_BINS as f32 {
            t as i32
        } else {
            -1
        }
    }

    /// Cell of tangent `u`; `None` outside the axis and for a non-finite `u`.
    #[cfg(test)]
    pub(crate) fn cell(&self, u: f32) -> Option<usize> {
        self.cell_in_bin(u, self.bin(u))
    }

    /// [`Axis::cell`] given `bin = self.bin(u)`.
    #[inline]
    pub(crate) fn cell_in_bin(&self, u: f32, bin: i32) -> Option<usize> {
        if let (true, Ok(b)) = (self.one_step, usize::try_from(bin)) {
            // In the table: u >= u0 >= the first boundary; the last cell ends at `upper`.
            if u >= self.upper {
                return None;
            }
            let i = usize::from(*self.lut.get(b)?);
            // The step is taken half the time: no branch for it.
            return Some(i + usize::from(self.lower.get(i + 1).is_some_and(|&l| u >= l)));
        }
        let inside = u >= self.first && u < self.upper && u.is_finite();
        if !inside {
            return None;
        }
        self.walk(u, (u - self.u0) * self.inv_step)
    }

    /// The cell of `u` (inside the axis) from the table's guess, boundary by boundary.
    fn walk(&self, u: f32, t: f32) -> Option<usize> {
        // Saturating cast: negative and NaN give bin 0.
        let bin = (t as usize).min(LUT_BINS - 1);
        let mut i = usize::from(*self.lut.get(bin)?).min(N - 1);
        while i > 0 && self.lower.get(i).is_some_and(|&l| u < l) {
            i -= 1;
        }
        while self.lower.get(i + 1).is_some_and(|&l| u >= l) {
            i += 1;
        }
        Some(i)
    }

    /// True when every key inside the table takes the single-comparison path.
    #[cfg(test)]
    pub(crate) fn is_one_step(&self) -> bool {
        self.one_step
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cells of `N` x `c` against `floor(atan(u) / c + N/2)` computed in f64; returns whether
    /// the single-comparison path was on.
    fn check<const N: usize>(c: f64) -> bool {
        let mut axis = Axis::<N>::new();
        assert_eq!(axis.cell(0.0), None, "unconfigured");
        axis.configure(c);
        let half = N as f64 * 0.5;
        let mut hits = 0;
        for k in -30000..=30000 {
            let a = k as f64 * 5.1e-5;
            let u = libm::tan(a) as f32;
            let exact = libm::floor(libm::atan(f64::from(u)) / c + half);
            // f32 boundaries (rounded by ~3e-8 rad) may put a key within 1e-3 cell of a
            // boundary in either cell.
            let frac = libm::atan(f64::from(u)) / c + half - exact;
            let near_boundary = !(1e-3..=1.0 - 1e-3).contains(&frac);
            let got = axis.cell(u);
            if near_boundary {
                continue;
            }
            if exact >= 0.0 && exact < N as f64 {
                assert_eq!(got, Some(exact as usize), "N {N} a {a}");
                hits += 1;
            } else {
                assert_eq!(got, None, "N {N} a {a}");
            }
        }
        assert!(hits > 1000);
        for u in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(axis.cell(u), None);
        }
        // Exactly on a boundary: the upper cell (cells are half-open).
        if N > 4 {
            let i = N / 2 + 1;
            let b = axis.lower[i];
            assert_eq!(axis.cell(b), Some(i));
            assert_eq!(axis.cell(f32::from_bits(b.to_bits() - 1)), Some(i - 1));
        }
        axis.is_one_step()
    }

    #[test]
    fn cell_equals_floor_of_angle_over_cell() {
        // The grid's axes (+-64 and +-48 deg) take the fast path.
        assert!(check::<256>(0.5f64.to_radians()));
        assert!(check::<192>(0.5f64.to_radians()));
        assert!(check::<255>(0.5f64.to_radians())); // odd: a cell centred on the axis
                                                    // Outer cells reaching +-90 deg (keys past the table walk), and cells narrower than a
                                                    // bin (every key walks).
        check::<7>(0.6);
        assert!(!check::<4000>(0.04f64.to_radians()));
    }
}

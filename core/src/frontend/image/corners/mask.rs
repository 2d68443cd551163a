//! The occupancy mask of the grid detector: a bit per square block of the image, marked around
//! every track and every corner taken, so the minimum-distance test of a candidate is one bit
//! read.

/// Occupancy mask resolution: at most this many blocks per side (blocks are square, of
/// `ceil(max(width, height) / MASK_BLOCKS)` px).
pub const MASK_BLOCKS: usize = 256;

const MASK_WORDS_PER_ROW: usize = MASK_BLOCKS / 64;

/// A bit mask of occupied blocks: a cheap minimum-distance test.
#[derive(Clone)]
pub struct OccupancyMask {
    bits: [u64; MASK_BLOCKS * MASK_WORDS_PER_ROW],
    block: usize,
    bw: usize,
    bh: usize,
    w: usize,
    h: usize,
}

impl Default for OccupancyMask {
    fn default() -> Self {
        Self::new()
    }
}

impl OccupancyMask {
    /// An empty mask (call [`Self::reset`] before use).
    pub const fn new() -> Self {
        OccupancyMask {
            bits: [0; MASK_BLOCKS * MASK_WORDS_PER_ROW],
            block: 1,
            bw: 0,
            bh: 0,
            w: 0,
            h: 0,
        }
    }

    /// Clears the mask for a `width` x `height` image.
    pub fn reset(&mut self, width: usize, height: usize) {
        let side = width.max(height).max(1);
        self.block = side.div_ceil(MASK_BLOCKS).max(1);
        self.bw = width.div_ceil(self.block).min(MASK_BLOCKS);
        self.bh = height.div_ceil(self.block).min(MASK_BLOCKS);
        (self.w, self.h) = (width, height);
        self.bits.fill(0);
    }

    /// Block side, px.
    pub fn block_px(&self) -> usize {
        self.block
    }

    /// Whether the block holding pixel `(x, y)` is free (outside the image counts as occupied).
    #[inline]
    pub fn is_free(&self, x: usize, y: usize) -> bool {
        if x >= self.w || y >= self.h {
            return false;
        }
        let (bx, by) = (x / self.block, y / self.block);
        if bx >= self.bw || by >= self.bh {
            return false;
        }
        let word = by * MASK_WORDS_PER_ROW + bx / 64;
        self.bits
            .get(word)
            .is_some_and(|w| w & (1u64 << (bx % 64)) == 0)
    }

    /// Marks every block whose centre lies within `radius_px` of `(x, y)` (and the block holding
    /// the point itself).
    pub fn mark_disc(&mut self, x: f64, y: f64, radius_px: f64) {
        if !(x.is_finite() && y.is_finite() && radius_px.is_finite()) {
            return;
        }
        let b = self.block as f64;
        let half = (b - 1.0) * 0.5;
        let r2 = radius_px * radius_px;
        // Block rows whose centre row lies within the radius.
        let by0 = libm::ceil((y - radius_px - half) / b).max(0.0);
        let by1 = libm::floor((y + radius_px - half) / b).min(self.bh as f64 - 1.0);
        let mut by = by0;
        while by <= by1 {
            let dy = by * b + half - y;
            let rem = r2 - dy * dy;
            if rem >= 0.0 {
                let dx = libm::sqrt(rem);
                let bx0 = libm::ceil((x - dx - half) / b).max(0.0);
                let bx1 = libm::floor((x + dx - half) / b).min(self.bw as f64 - 1.0);
                if bx0 <= bx1 {
                    self.set_span(by as usize, bx0 as usize, bx1 as usize);
                }
            }
            by += 1.0;
        }
        if x >= 0.0 && y >= 0.0 {
            let (bx, by) = (x as usize / self.block, y as usize / self.block);
            if bx < self.bw && by < self.bh {
                self.set_span(by, bx, bx);
            }
        }
    }

    fn set_span(&mut self, by: usize, bx0: usize, bx1: usize) {
        for bx in bx0..=bx1 {
            if let Some(w) = self.bits.get_mut(by * MASK_WORDS_PER_ROW + bx / 64) {
                *w |= 1u64 << (bx % 64);
            }
        }
    }
}

//! Shi-Tomasi corners on a grid, computed only where features are missing.
//!
//! Response: the minimum eigenvalue of the 2x2 structure tensor summed over a 3x3 block of 3x3
//! Sobel gradients (OpenCV `goodFeaturesToTrack` with `blockSize = 3`). Gradients, products and
//! block sums are exact integers (`|sum| < 2^24`); the eigenvalue is evaluated once per pixel in
//! `f32` in a fixed order with a correctly rounded square root, so it is bit-identical on every
//! target. Responses are reported in `(grey level / px)^2` (the eigenvalue of the block's mean
//! gradient outer product): raw Sobel sums are `8 * 8 * 9 = 576` times that.
//!
//! The image is split into `grid_cols` x `grid_rows` cells. A cell is scanned only when it holds
//! fewer than `max_per_cell` features, the emptiest cells first, until the scanned cells are
//! expected to give twice the features wanted (each cell is expected to give what it gave at
//! its last scan, capped by its room, or half its room if never scanned); a scanned cell that gives nothing is skipped for
//! [`BARREN_SKIP_FRAMES`] frames (unless fewer tracks exist than are wanted). Each scanned cell streams its rows (three rows of products and
//! three of responses in scratch, no image-sized buffer), keeps local maxima of its 3x3
//! neighbourhood above the absolute floor that are not inside the occupancy mask of existing
//! tracks, and retains up to [`MAX_CANDIDATES_PER_CELL`] of them spread out: a candidate within
//! half of `min_distance_px` of a stronger one is dropped, and evicts the weaker ones near it. The
//! quality threshold is `quality_level` times the best response among the scanned cells (like
//! OpenCV's masked `goodFeaturesToTrack`; optionally also the responses at the existing tracks,
//! `quality_from_tracks`), and at least the absolute floor. Selection then goes round-robin over the scanned cells in priority order, taking each
//! cell's best remaining candidate that is at least `min_distance_px` (on the mask's block grid)
//! from every track and every corner already taken, until enough corners are found.

use super::view::ImageView;
use crate::camera::FeatureObs;
use crate::Error;

/// Largest number of grid cells (`grid_cols * grid_rows`).
pub const MAX_GRID_CELLS: usize = 256;
/// Largest cell side, px (the image side divided by the cell count, rounded up). Sizes the row
/// scratch of the scanner.
pub const MAX_CELL_SIDE: usize = 512;
/// Candidates retained per scanned cell (the strongest local maxima).
pub const MAX_CANDIDATES_PER_CELL: usize = 32;
/// Frames a scanned cell that produced no candidate is skipped.
pub const BARREN_SKIP_FRAMES: u32 = 8;
/// Occupancy mask resolution: at most this many blocks per side (blocks are square, of
/// `ceil(max(width, height) / MASK_BLOCKS)` px).
pub const MASK_BLOCKS: usize = 256;
/// Raw Sobel-block units per `(grey / px)^2`: Sobel gain 8, squared, times the 9-pixel block.
pub const RESPONSE_SCALE: f32 = 576.0;

const SPAN: usize = MAX_CELL_SIDE + 4;
const MASK_WORDS_PER_ROW: usize = MASK_BLOCKS / 64;

/// Parameters of the grid detector.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct DetectorConfig {
    /// Grid columns.
    pub grid_cols: usize,
    /// Grid rows.
    pub grid_rows: usize,
    /// New corners are added to a cell only while it holds fewer features than this.
    pub max_per_cell: usize,
    /// Minimum distance from a new corner to any track or other new corner, px.
    pub min_distance_px: f32,
    /// Quality threshold relative to the best response among the scanned cells (OpenCV's
    /// `qualityLevel`).
    pub quality_level: f32,
    /// Absolute response floor, `(grey / px)^2` (rejects flat and noise-only regions).
    pub min_eigen: f32,
    /// Corners are detected at least this far from the image border, px (at least 4).
    pub border_px: usize,
    /// Whether the responses at the existing tracks count in the frame's best response (the
    /// reference of `quality_level`). Off: the best among the scanned cells only, as OpenCV's
    /// `goodFeaturesToTrack` with a mask (the threshold drops when the strong corners are
    /// already tracked, so weaker regions get features too).
    pub quality_from_tracks: bool,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            grid_cols: 8,
            grid_rows: 6,
            max_per_cell: 8,
            min_distance_px: 20.0,
            quality_level: 0.01,
            min_eigen: 1.0,
            border_px: 11,
            quality_from_tracks: false,
        }
    }
}

impl DetectorConfig {
    /// Checks every parameter's range ([`Error::InvalidConfig`] otherwise).
    pub fn validate(&self) -> Result<(), Error> {
        let ok = self.grid_cols >= 1
            && self.grid_rows >= 1
            && self.grid_cols * self.grid_rows <= MAX_GRID_CELLS
            && (1..=MAX_CANDIDATES_PER_CELL / 2).contains(&self.max_per_cell)
            && (0.0..=1000.0).contains(&self.min_distance_px)
            && (0.0..=1.0).contains(&self.quality_level)
            && (0.0..=1.0e6).contains(&self.min_eigen)
            && (4..=1024).contains(&self.border_px);
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

/// A detected corner: integer pixel and its response.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Corner {
    /// Column, px.
    pub x: u16,
    /// Row, px.
    pub y: u16,
    /// Minimum eigenvalue, `(grey / px)^2`.
    pub response: f32,
}

/// What one detection did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DetectStats {
    /// Cells scanned.
    pub cells_scanned: u32,
    /// Pixels whose response was computed.
    pub pixels: u32,
    /// Candidates retained over all scanned cells.
    pub candidates: u32,
    /// Corners returned.
    pub detected: u32,
    /// Best response among the scanned cells, `(grey / px)^2`.
    pub best_response: f32,
}

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

#[derive(Clone, Copy)]
struct CellCandidates {
    items: [Corner; MAX_CANDIDATES_PER_CELL],
    len: usize,
    next: usize,
    taken: usize,
}

impl CellCandidates {
    const EMPTY: CellCandidates = CellCandidates {
        items: [Corner {
            x: 0,
            y: 0,
            response: 0.0,
        }; MAX_CANDIDATES_PER_CELL],
        len: 0,
        next: 0,
        taken: 0,
    };

    /// Inserts `c` into the cell's spread-out candidate set: dropped if a candidate at least as
    /// strong lies within `sqrt(md2)` px (so equal responses keep the earlier one in scan order:
    /// deterministic), otherwise it evicts the weaker candidates within that distance and takes
    /// its place in descending order (the weakest falls out of a full set).
    #[inline]
    fn insert(&mut self, c: Corner, md2: i32) {
        let near = |e: &Corner| {
            let (dx, dy) = (
                i32::from(e.x) - i32::from(c.x),
                i32::from(e.y) - i32::from(c.y),
            );
            dx * dx + dy * dy < md2
        };
        let items = self.items.get(..self.len).unwrap_or(&[]);
        if items.iter().any(|e| e.response >= c.response && near(e)) {
            return;
        }
        // Remove the weaker neighbours (order preserved).
        let mut k = 0usize;
        for i in 0..self.len {
            let Some(e) = self.items.get(i).copied() else {
                break;
            };
            if !near(&e) {
                if let Some(s) = self.items.get_mut(k) {
                    *s = e;
                }
                k += 1;
            }
        }
        self.len = k;
        if self.len == MAX_CANDIDATES_PER_CELL {
            match self.items.last() {
                Some(last) if c.response > last.response => {}
                _ => return,
            }
        } else {
            self.len += 1;
        }
        let mut i = self.len - 1;
        while i > 0 {
            match self.items.get(i - 1) {
                Some(prev) if prev.response < c.response => {
                    let p = *prev;
                    if let Some(s) = self.items.get_mut(i) {
                        *s = p;
                    }
                    i -= 1;
                }
                _ => break,
            }
        }
        if let Some(s) = self.items.get_mut(i) {
            *s = c;
        }
    }
}

/// Row scratch of the streaming scan.
#[derive(Clone)]
struct ScanScratch {
    gx: [i32; SPAN],
    gy: [i32; SPAN],
    pxx: [f32; SPAN],
    pxy: [f32; SPAN],
    pyy: [f32; SPAN],
    hxx: [[f32; SPAN]; 3],
    hxy: [[f32; SPAN]; 3],
    hyy: [[f32; SPAN]; 3],
    resp: [[f32; SPAN]; 3],
    hmax: [[f32; SPAN]; 3],
    is_max: [u8; SPAN],
}

#[derive(Clone, Copy)]
struct CellState {
    barren_until: u32,
    last_scanned: u32,
    /// Candidates above the threshold at the last scan (`u8::MAX`: never scanned).
    last_yield: u8,
}

impl CellState {
    const NEW: CellState = CellState {
        barren_until: 0,
        last_scanned: 0,
        last_yield: u8::MAX,
    };
}

/// The grid detector with its scratch (125 328 bytes: per-cell candidate lists, the occupancy
/// mask and the row buffers; no image-sized buffer).
#[derive(Clone)]
pub struct GridDetector {
    mask: OccupancyMask,
    scratch: ScanScratch,
    cands: [CellCandidates; MAX_GRID_CELLS],
    cell_list: [u16; MAX_GRID_CELLS],
    cells: [CellState; MAX_GRID_CELLS],
    frame: u32,
    dims: (usize, usize, usize, usize),
}

impl Default for GridDetector {
    fn default() -> Self {
        Self::new()
    }
}

impl GridDetector {
    /// A detector with empty scratch.
    pub const fn new() -> Self {
        GridDetector {
            mask: OccupancyMask::new(),
            scratch: ScanScratch {
                gx: [0; SPAN],
                gy: [0; SPAN],
                pxx: [0.0; SPAN],
                pxy: [0.0; SPAN],
                pyy: [0.0; SPAN],
                hxx: [[0.0; SPAN]; 3],
                hxy: [[0.0; SPAN]; 3],
                hyy: [[0.0; SPAN]; 3],
                resp: [[0.0; SPAN]; 3],
                hmax: [[0.0; SPAN]; 3],
                is_max: [0; SPAN],
            },
            cands: [CellCandidates::EMPTY; MAX_GRID_CELLS],
            cell_list: [0; MAX_GRID_CELLS],
            cells: [CellState::NEW; MAX_GRID_CELLS],
            frame: 0,
            dims: (0, 0, 0, 0),
        }
    }

    /// Forgets the per-cell history (barren cells).
    pub fn reset(&mut self) {
        self.cells.fill(CellState::NEW);
        self.frame = 0;
    }

    /// The occupancy mask of the last detection (tracks and the corners it returned).
    pub fn mask(&self) -> &OccupancyMask {
        &self.mask
    }

    /// Detects up to `min(wanted, out.len())` new corners in `image` away from `existing`
    /// features, writes them to `out` (in selection order) and returns the statistics
    /// (`detected` is the count written).
    ///
    /// Errors: [`Error::InvalidConfig`] for an invalid `cfg` or a cell side above
    /// [`MAX_CELL_SIDE`].
    pub fn detect(
        &mut self,
        image: &ImageView,
        cfg: &DetectorConfig,
        existing: &[FeatureObs],
        wanted: usize,
        out: &mut [Corner],
    ) -> Result<DetectStats, Error> {
        cfg.validate()?;
        let (w, h) = (image.width(), image.height());
        let (cols, rows) = (cfg.grid_cols, cfg.grid_rows);
        if w.div_ceil(cols) > MAX_CELL_SIDE || h.div_ceil(rows) > MAX_CELL_SIDE {
            return Err(Error::InvalidConfig);
        }
        if self.dims != (w, h, cols, rows) {
            self.reset();
            self.dims = (w, h, cols, rows);
        }
        self.frame = self.frame.wrapping_add(1);
        let frame = self.frame;
        let mut stats = DetectStats::default();
        let wanted = wanted.min(out.len());
        // Occupancy of existing tracks and per-cell counts.
        let n_cells = cols * rows;
        let mut counts = [0u16; MAX_GRID_CELLS];
        self.mask.reset(w, h);
        let radius = f64::from(cfg.min_distance_px);
        for f in existing {
            if !(f.u_px.is_finite() && f.v_px.is_finite()) {
                continue;
            }
            self.mask.mark_disc(f.u_px, f.v_px, radius);
            if let Some(c) =
                cell_of(f.u_px, f.v_px, w, h, cols, rows).and_then(|i| counts.get_mut(i))
            {
                *c = c.saturating_add(1);
            }
        }
        if wanted == 0 || w < 2 * cfg.border_px + 1 || h < 2 * cfg.border_px + 1 {
            return Ok(stats);
        }
        // Cells to scan: not full, not barren; emptiest first, then least recently scanned.
        // Barren cells are skipped only while at least as many tracks exist as are wanted (so a
        // scene that appears after a black frame is found at once).
        let skip_barren = existing.len() >= wanted;
        let mut n_list = 0usize;
        for (i, (st, &cnt)) in self
            .cells
            .iter()
            .zip(counts.iter())
            .enumerate()
            .take(n_cells)
        {
            let barren = skip_barren
                && st.barren_until != 0
                && frame.wrapping_sub(st.barren_until) > u32::MAX / 2;
            if usize::from(cnt) < cfg.max_per_cell && !barren {
                if let Some(s) = self.cell_list.get_mut(n_list) {
                    *s = i as u16;
                    n_list += 1;
                }
            }
        }
        let cells = &self.cells;
        let key = |i: u16| {
            let i = usize::from(i);
            let st = cells.get(i).copied().unwrap_or(CellState::NEW);
            (
                counts.get(i).copied().unwrap_or(0),
                st.last_scanned,
                i as u32,
            )
        };
        let list = self.cell_list.get_mut(..n_list).unwrap_or(&mut []);
        list.sort_unstable_by_key(|&i| key(i));
        // Scan until the expected yield covers twice the features wanted: a cell is expected to
        // give what it gave at its last scan (capped by its room), or half its room if never
        // scanned.
        let mut expected = 0usize;
        let mut n_scan = 0usize;
        for &i in list.iter() {
            if expected >= 2 * wanted {
                break;
            }
            let i = usize::from(i);
            let room = cfg
                .max_per_cell
                .saturating_sub(usize::from(counts.get(i).copied().unwrap_or(0)));
            let last = self.cells.get(i).map_or(u8::MAX, |c| c.last_yield);
            expected += if last == u8::MAX {
                room / 2
            } else {
                room.min(usize::from(last))
            };
            n_scan += 1;
        }
        // Scan.
        let floor_raw = cfg.min_eigen * RESPONSE_SCALE;
        // Candidates within a cell are spread at half the minimum distance (the selection below
        // enforces the full distance through the mask): a candidate dropped next to a stronger
        // one that is later evicted is then rarely lost.
        let md = libm::ceilf(cfg.min_distance_px) as i32;
        let md2 = (md / 2) * (md / 2);
        // The frame's best response: the scanned cells' and the existing tracks' (the strongest
        // corners were selected and are still tracked; each costs one 3x3 block).
        let mut best_raw = 0.0f32;
        for f in existing.iter().filter(|_| cfg.quality_from_tracks) {
            if f.u_px >= 0.0 && f.v_px >= 0.0 {
                best_raw = best_raw.max(response_at(image, f.u_px as usize, f.v_px as usize));
            }
        }
        for k in 0..n_scan {
            let Some(&ci) = self.cell_list.get(k) else {
                break;
            };
            let ci = usize::from(ci);
            let (cx, cy) = (ci % cols, ci / cols);
            let rect = (
                (cx * w / cols).max(cfg.border_px),
                (cy * h / rows).max(cfg.border_px),
                ((cx + 1) * w / cols).min(w - cfg.border_px),
                ((cy + 1) * h / rows).min(h - cfg.border_px),
            );
            let Some(cands) = self.cands.get_mut(k) else {
                break;
            };
            *cands = CellCandidates::EMPTY;
            if rect.0 < rect.2 && rect.1 < rect.3 {
                let (best, px) = scan_cell(
                    image,
                    rect,
                    floor_raw,
                    md2,
                    &self.mask,
                    &mut self.scratch,
                    cands,
                );
                best_raw = best_raw.max(best);
                stats.pixels += px;
            }
            stats.cells_scanned += 1;
            stats.candidates += cands.len as u32;
            if let Some(st) = self.cells.get_mut(ci) {
                st.last_scanned = frame;
            }
        }
        stats.best_response = best_raw / RESPONSE_SCALE;
        let thr = (cfg.quality_level * best_raw).max(floor_raw);
        // Select: round-robin over the scanned cells in priority order.
        let mut taken = 0usize;
        let mut progress = true;
        while taken < wanted && progress {
            progress = false;
            for k in 0..n_scan {
                if taken >= wanted {
                    break;
                }
                let ci = usize::from(self.cell_list.get(k).copied().unwrap_or(0));
                let Some(cnt) = counts.get_mut(ci) else {
                    continue;
                };
                if usize::from(*cnt) >= cfg.max_per_cell {
                    continue;
                }
                let Some(cands) = self.cands.get_mut(k) else {
                    continue;
                };
                while cands.next < cands.len {
                    let c = cands.items.get(cands.next).copied().unwrap_or_default();
                    cands.next += 1;
                    if c.response < thr {
                        cands.next = cands.len;
                        break;
                    }
                    if self.mask.is_free(usize::from(c.x), usize::from(c.y)) {
                        self.mask.mark_disc(f64::from(c.x), f64::from(c.y), radius);
                        if let Some(o) = out.get_mut(taken) {
                            *o = Corner {
                                response: c.response / RESPONSE_SCALE,
                                ..c
                            };
                            taken += 1;
                        }
                        *cnt += 1;
                        cands.taken += 1;
                        progress = true;
                        break;
                    }
                }
            }
        }
        // Remember what each scanned cell can still give (good candidates not taken).
        for k in 0..n_scan {
            let ci = usize::from(self.cell_list.get(k).copied().unwrap_or(0));
            let (Some(cands), Some(st)) = (self.cands.get(k), self.cells.get_mut(ci)) else {
                continue;
            };
            let left = cands
                .items
                .iter()
                .take(cands.len)
                .skip(cands.next)
                .filter(|c| c.response >= thr)
                .count();
            let got = cands.taken;
            st.last_yield = left.min(usize::from(u8::MAX - 1)) as u8;
            st.barren_until = if left == 0 && got == 0 {
                frame.wrapping_add(BARREN_SKIP_FRAMES).max(1)
            } else {
                0
            };
        }
        stats.detected = taken as u32;
        Ok(stats)
    }
}

/// Grid cell of pixel `(u, v)`, or `None` outside the image.
pub(crate) fn cell_of(
    u: f64,
    v: f64,
    w: usize,
    h: usize,
    cols: usize,
    rows: usize,
) -> Option<usize> {
    if !(u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64) {
        return None;
    }
    let (x, y) = (u as usize, v as usize);
    let cx = (x * cols / w).min(cols - 1);
    let cy = (y * rows / h).min(rows - 1);
    Some(cy * cols + cx)
}

/// Raw response at pixel `(x, y)` (0 within 3 px of the border).
fn response_at(img: &ImageView, x: usize, y: usize) -> f32 {
    if x < 3 || y < 3 || x + 3 >= img.width() || y + 3 >= img.height() {
        return 0.0;
    }
    let (mut a, mut b, mut c) = (0i32, 0i32, 0i32);
    for yy in y - 1..=y + 1 {
        let (Some(ra), Some(rb), Some(rc)) = (
            img.span(x - 2, yy - 1, 5),
            img.span(x - 2, yy, 5),
            img.span(x - 2, yy + 1, 5),
        ) else {
            return 0.0;
        };
        let (mut gx, mut gy) = ([0i32; 3], [0i32; 3]);
        sobel_row(ra, rb, rc, &mut gx, &mut gy);
        for (x, y) in gx.iter().zip(&gy) {
            a += x * x;
            b += x * y;
            c += y * y;
        }
    }
    min_eig(a, b, c)
}

/// Minimum eigenvalue of `[[a, b], [b, c]]` (raw integer sums, exact in `f32`).
#[inline(always)]
fn min_eig(a: i32, b: i32, c: i32) -> f32 {
    let (a, b, c) = (a as f32, b as f32, c as f32);
    let d = a - c;
    0.5 * ((a + c) - libm::sqrtf(d * d + 4.0 * (b * b)))
}

/// `sqrt(x)` for `x >= 0` from IEEE `+ - * /` and integer bit operations only: an initial guess
/// from the exponent bits (within 4%) and three Newton steps, accurate to `f32` rounding. Unlike
/// `libm::sqrtf` (an opaque instruction) it vectorizes, and it is bit-identical on every IEEE
/// target (no fused multiply-add, no estimate instructions).
#[inline(always)]
fn sqrt_newton(x: f32) -> f32 {
    let g = f32::from_bits((x.to_bits() >> 1) + 0x1fbd_1df5);
    let g = 0.5 * (g + x / g);
    let g = 0.5 * (g + x / g);
    0.5 * (g + x / g)
}

/// Responses of one row from the block sums: the minimum eigenvalue where it exceeds the floor
/// `f` (tested exactly: `a > f` and `(a - f)(c - f) > b^2`), else 0. The sums are exact integers
/// in `f32` (`< 2^24`). Branch-free so it vectorizes.
#[inline(always)]
fn response_row(a: &[f32], b: &[f32], c: &[f32], f: f32, out: &mut [f32]) {
    for (((r, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        let (am, cm) = (a - f, c - f);
        let pass = (am > 0.0) & (am * cm > b * b);
        let d = a - c;
        let l = 0.5 * ((a + c) - sqrt_newton(d * d + 4.0 * (b * b)));
        *r = if pass { l } else { 0.0 };
    }
}

/// `out[k] = max(v[k], v[k + 1], v[k + 2])` (no NaN occurs).
#[inline(always)]
fn hmax3(v: &[f32], out: &mut [f32]) {
    let n = out.len();
    let (Some(a), Some(b), Some(c)) = (v.get(..n), v.get(1..n + 1), v.get(2..n + 2)) else {
        return;
    };
    for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        let m = if a > b { a } else { b };
        *o = if m > c { m } else { c };
    }
}

/// `out[k] = 1` where `mid[k]` is positive and at least the row maxima `up[k]`, `hm[k]`, `dn[k]`
/// of its 3x3 neighbourhood, else 0 (branch-free).
#[inline(always)]
fn local_max_row(mid: &[f32], up: &[f32], hm: &[f32], dn: &[f32], out: &mut [u8]) {
    for ((((o, &r), &u), &m), &d) in out.iter_mut().zip(mid).zip(up).zip(hm).zip(dn) {
        *o = u8::from((r >= u) & (r >= m) & (r >= d) & (r > 0.0));
    }
}

/// Scans cell `rect = (x0, y0, x1, y1)` (candidate pixels; the image must extend 3 px beyond
/// it). Returns the best raw response outside the mask and the pixel count.
#[allow(clippy::too_many_arguments)]
fn scan_cell(
    img: &ImageView,
    rect: (usize, usize, usize, usize),
    floor_raw: f32,
    md2: i32,
    mask: &OccupancyMask,
    s: &mut ScanScratch,
    out: &mut CellCandidates,
) -> (f32, u32) {
    let (x0, y0, x1, y1) = rect;
    if x0 < 3 || y0 < 3 || x1 + 3 > img.width() || y1 + 3 > img.height() {
        return (0.0, 0);
    }
    let n_r = x1 - x0 + 2; // response columns x0-1 .. x1+1
    let n_p = n_r + 2; // product columns x0-2 .. x1+2
    if n_p > SPAN {
        return (0.0, 0);
    }
    let mut best = 0.0f32;
    let mut pixels = 0u32;
    // Gradient rows y0-2 ..= y1+1.
    for (gi, gyr) in (y0 - 2..y1 + 2).enumerate() {
        // Sobel for columns x0-2 .. x1+2 from image columns x0-3 .. x1+3.
        let (Some(ra), Some(rb), Some(rc)) = (
            img.span(x0 - 3, gyr - 1, n_p + 2),
            img.span(x0 - 3, gyr, n_p + 2),
            img.span(x0 - 3, gyr + 1, n_p + 2),
        ) else {
            return (best, pixels);
        };
        sobel_row(ra, rb, rc, &mut s.gx[..n_p], &mut s.gy[..n_p]);
        // Per-column products (exact in f32: |g| <= 1020).
        for ((((&x, &y), xx), xy), yy) in s.gx[..n_p]
            .iter()
            .zip(&s.gy[..n_p])
            .zip(s.pxx[..n_p].iter_mut())
            .zip(s.pxy[..n_p].iter_mut())
            .zip(s.pyy[..n_p].iter_mut())
        {
            let (x, y) = (x as f32, y as f32);
            *xx = x * x;
            *xy = x * y;
            *yy = y * y;
        }
        let slot = gi % 3;
        hsum3(&s.pxx[..n_p], &mut s.hxx[slot][..n_r]);
        hsum3(&s.pxy[..n_p], &mut s.hxy[slot][..n_r]);
        hsum3(&s.pyy[..n_p], &mut s.hyy[slot][..n_r]);
        if gi < 2 {
            continue;
        }
        // Response row gyr - 1 (index ri from y0-1): block sums then eigenvalues.
        let ri = gi - 2;
        let rslot = ri % 3;
        {
            // Reuse the product rows as the block-sum rows (their content is consumed).
            let [a0, a1, a2] = &s.hxx;
            let [b0, b1, b2] = &s.hxy;
            let [c0, c1, c2] = &s.hyy;
            vsum3(&a0[..n_r], &a1[..n_r], &a2[..n_r], &mut s.pxx[..n_r]);
            vsum3(&b0[..n_r], &b1[..n_r], &b2[..n_r], &mut s.pxy[..n_r]);
            vsum3(&c0[..n_r], &c1[..n_r], &c2[..n_r], &mut s.pyy[..n_r]);
            response_row(
                &s.pxx[..n_r],
                &s.pxy[..n_r],
                &s.pyy[..n_r],
                floor_raw,
                &mut s.resp[rslot][..n_r],
            );
            // Row maxima of 3 around response columns 1 .. n_r - 1.
            hmax3(&s.resp[rslot][..n_r], &mut s.hmax[rslot][..n_r - 2]);
        }
        pixels += n_r as u32;
        if ri < 2 {
            continue;
        }
        // Non-maximum suppression on response row ny (candidate row y0 + ri - 2).
        let ny = y0 + ri - 2;
        local_max_row(
            &s.resp[(ri + 2) % 3][1..n_r - 1],
            &s.hmax[(ri + 1) % 3][..n_r - 2],
            &s.hmax[(ri + 2) % 3][..n_r - 2],
            &s.hmax[ri % 3][..n_r - 2],
            &mut s.is_max[..n_r - 2],
        );
        let mid = &s.resp[(ri + 2) % 3][..n_r];
        for (k, (&m, &r)) in s.is_max[..n_r - 2].iter().zip(&mid[1..]).enumerate() {
            if m == 0 {
                continue;
            }
            let x = x0 + k;
            if !mask.is_free(x, ny) {
                continue;
            }
            // The best response outside the occupancy mask (OpenCV's masked maximum).
            best = best.max(r);
            out.insert(
                Corner {
                    x: x as u16,
                    y: ny as u16,
                    response: r,
                },
                md2,
            );
        }
    }
    (best, pixels)
}

/// `out[k] = v[k] + v[k + 1] + v[k + 2]`.
#[inline(always)]
fn hsum3(v: &[f32], out: &mut [f32]) {
    let n = out.len();
    let (Some(a), Some(b), Some(c)) = (v.get(..n), v.get(1..n + 1), v.get(2..n + 2)) else {
        return;
    };
    for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        *o = (a + b) + c;
    }
}

/// `out[k] = a[k] + b[k] + c[k]`.
#[inline(always)]
fn vsum3(a: &[f32], b: &[f32], c: &[f32], out: &mut [f32]) {
    for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        *o = (a + b) + c;
    }
}

/// 3x3 Sobel of the middle row `rb` (rows `ra`, `rc` above and below); `gx.len() + 2` pixels in.
#[inline(always)]
fn sobel_row(ra: &[u8], rb: &[u8], rc: &[u8], gx: &mut [i32], gy: &mut [i32]) {
    let n = gx.len().min(gy.len());
    let (Some(a0), Some(a1), Some(a2)) = (ra.get(..n), ra.get(1..n + 1), ra.get(2..n + 2)) else {
        return;
    };
    let (Some(b0), Some(b2)) = (rb.get(..n), rb.get(2..n + 2)) else {
        return;
    };
    let (Some(c0), Some(c1), Some(c2)) = (rc.get(..n), rc.get(1..n + 2 - 1), rc.get(2..n + 2))
    else {
        return;
    };
    let it = gx
        .iter_mut()
        .zip(gy.iter_mut())
        .zip(a0.iter().zip(a1).zip(a2))
        .zip(b0.iter().zip(b2))
        .zip(c0.iter().zip(c1).zip(c2));
    for ((((ox, oy), ((&a0, &a1), &a2)), (&b0, &b2)), ((&c0, &c1), &c2)) in it {
        let (a0, a1, a2) = (i32::from(a0), i32::from(a1), i32::from(a2));
        let (b0, b2) = (i32::from(b0), i32::from(b2));
        let (c0, c1, c2) = (i32::from(c0), i32::from(c1), i32::from(c2));
        *ox = (a2 - a0) + 2 * (b2 - b0) + (c2 - c0);
        *oy = (c0 + 2 * c1 + c2) - (a0 + 2 * a1 + a2);
    }
}

#[cfg(test)]
#[path = "corners_tests.rs"]
mod tests;

//! Shi-Tomasi corners on a grid, computed only where features are missing.
//!
//! Response: the minimum eigenvalue of the 2x2 structure tensor of 3x3 Sobel gradients summed
//! over a 3x3 block (OpenCV `goodFeaturesToTrack` with `blockSize = 3`), in `(grey level / px)^2`,
//! bit-identical on every target (the arithmetic and its exactness are described in the `score`
//! submodule).
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
//!
//! Submodules: `score` (gradients, structure tensor, eigenvalue), `scan` (the streaming scan of
//! a cell with its non-maximum suppression and candidate set), `select` (the round-robin
//! selection and each cell's remembered yield), `mask` ([`OccupancyMask`]).

use super::view::ImageView;
use crate::camera::FeatureObs;
use crate::Error;

mod mask;
mod scan;
mod score;
mod select;
pub use mask::{OccupancyMask, MASK_BLOCKS};

/// Largest number of grid cells (`grid_cols * grid_rows`).
pub const MAX_GRID_CELLS: usize = 256;
/// Largest cell side, px (the image side divided by the cell count, rounded up). Sizes the row
/// scratch of the scanner.
pub const MAX_CELL_SIDE: usize = 512;
/// Candidates retained per scanned cell (the strongest local maxima).
pub const MAX_CANDIDATES_PER_CELL: usize = 32;
/// Frames a scanned cell that produced no candidate is skipped.
pub const BARREN_SKIP_FRAMES: u32 = 8;
/// Raw Sobel-block units per `(grey / px)^2`: Sobel gain 8, squared, times the 9-pixel block.
pub const RESPONSE_SCALE: f32 = 576.0;

const SPAN: usize = MAX_CELL_SIDE + 4;

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
        let mut stats = DetectStats::default();
        let wanted = wanted.min(out.len());
        let mut counts = self.mark_tracks(image, cfg, existing);
        if wanted == 0 || w < 2 * cfg.border_px + 1 || h < 2 * cfg.border_px + 1 {
            return Ok(stats);
        }
        let n_scan = self.plan_scan(cfg, &counts, existing, wanted);
        // Scan.
        let floor_raw = cfg.min_eigen * RESPONSE_SCALE;
        let best_raw = self.scan_cells(image, cfg, existing, n_scan, floor_raw, &mut stats);
        stats.best_response = best_raw / RESPONSE_SCALE;
        let thr = (cfg.quality_level * best_raw).max(floor_raw);
        let taken = self.select(cfg, &mut counts, n_scan, wanted, thr, out);
        self.remember_yields(n_scan, thr);
        stats.detected = taken as u32;
        Ok(stats)
    }

    /// Resets the occupancy mask to the image and marks every existing track in it; returns the
    /// tracks per grid cell.
    fn mark_tracks(
        &mut self,
        image: &ImageView,
        cfg: &DetectorConfig,
        existing: &[FeatureObs],
    ) -> [u16; MAX_GRID_CELLS] {
        let (w, h) = (image.width(), image.height());
        let (cols, rows) = (cfg.grid_cols, cfg.grid_rows);
        // Occupancy of existing tracks and per-cell counts.
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
        counts
    }

    /// Lists the cells to scan, in priority order, in `cell_list` and returns how many of its
    /// first ones are scanned (`counts`: tracks per cell).
    fn plan_scan(
        &mut self,
        cfg: &DetectorConfig,
        counts: &[u16; MAX_GRID_CELLS],
        existing: &[FeatureObs],
        wanted: usize,
    ) -> usize {
        let n_cells = cfg.grid_cols * cfg.grid_rows;
        let frame = self.frame;
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
        n_scan
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

#[cfg(test)]
#[path = "corners_tests.rs"]
mod tests;

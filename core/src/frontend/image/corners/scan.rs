//! The streaming scan of the grid cells: each scanned cell's responses row by row (three rows
//! of products and three of responses in scratch, no image-sized buffer), the 3x3
//! non-maximum suppression, and the cell's spread-out candidate set.

use super::super::view::ImageView;
use super::score::{hsum3, response_at, response_row, sobel_row, vsum3};
use super::{
    CellCandidates, Corner, DetectStats, DetectorConfig, GridDetector, OccupancyMask, ScanScratch,
    MAX_CANDIDATES_PER_CELL, SPAN,
};
use crate::camera::FeatureObs;

impl CellCandidates {
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

impl GridDetector {
    /// Scans the first `n_scan` cells of the priority list into their candidate sets (counted in
    /// `stats`) and returns the frame's best raw response, the reference of the quality
    /// threshold.
    pub(super) fn scan_cells(
        &mut self,
        image: &ImageView,
        cfg: &DetectorConfig,
        existing: &[FeatureObs],
        n_scan: usize,
        floor_raw: f32,
        stats: &mut DetectStats,
    ) -> f32 {
        let (w, h) = (image.width(), image.height());
        let (cols, rows) = (cfg.grid_cols, cfg.grid_rows);
        let frame = self.frame;
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
        best_raw
    }
}

/// One gradient row of the scan into row slot `slot` (0..3): the 3x3 Sobel gradients of `n_p`
/// product columns from the image rows `ra`, `rb`, `rc` (`n_p + 2` pixels each), their
/// per-column products and the products' horizontal sums of 3 over `n_r = n_p - 2` columns
/// (`n_p <= SPAN`, checked by [`scan_cell`]).
#[inline(always)]
fn gradient_row(
    s: &mut ScanScratch,
    ra: &[u8],
    rb: &[u8],
    rc: &[u8],
    n_p: usize,
    n_r: usize,
    slot: usize,
) {
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
    hsum3(&s.pxx[..n_p], &mut s.hxx[slot][..n_r]);
    hsum3(&s.pxy[..n_p], &mut s.hxy[slot][..n_r]);
    hsum3(&s.pyy[..n_p], &mut s.hyy[slot][..n_r]);
}

/// One response row of the scan into row slot `rslot` (0..3) from the three buffered gradient
/// rows: their vertical sums of 3 (the structure tensor's 3x3 block sums), the responses above
/// `floor_raw`, and their row maxima of 3 (`3 <= n_r <= SPAN`, checked by [`scan_cell`]).
#[inline(always)]
fn block_responses(s: &mut ScanScratch, n_r: usize, rslot: usize, floor_raw: f32) {
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
        let slot = gi % 3;
        gradient_row(s, ra, rb, rc, n_p, n_r, slot);
        if gi < 2 {
            continue;
        }
        // Response row gyr - 1 (index ri from y0-1): block sums then eigenvalues.
        let ri = gi - 2;
        let rslot = ri % 3;
        block_responses(s, n_r, rslot, floor_raw);
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

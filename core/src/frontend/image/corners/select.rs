//! Selection of the new corners from the scanned cells' candidates (round-robin over the cells
//! in priority order, against the quality threshold and the occupancy mask), and what each
//! scanned cell is remembered to still give (its expected yield, or a barren skip).

use super::{
    Corner, DetectorConfig, GridDetector, BARREN_SKIP_FRAMES, MAX_GRID_CELLS, RESPONSE_SCALE,
};

impl GridDetector {
    /// Takes up to `wanted` corners with a response of at least `thr` (raw) into `out`, one per
    /// scanned cell in turn (the first `n_scan` of the priority list) while the cell has room
    /// (`counts`, updated), each the cell's best remaining candidate on a free block of the mask,
    /// which is then marked. Returns the count written.
    pub(super) fn select(
        &mut self,
        cfg: &DetectorConfig,
        counts: &mut [u16; MAX_GRID_CELLS],
        n_scan: usize,
        wanted: usize,
        thr: f32,
        out: &mut [Corner],
    ) -> usize {
        let radius = f64::from(cfg.min_distance_px);
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
        taken
    }

    /// Records for each of the first `n_scan` cells of the priority list what it can still
    /// give after the selection, and marks it barren for [`BARREN_SKIP_FRAMES`] frames when it
    /// had nothing above the threshold `thr`.
    pub(super) fn remember_yields(&mut self, n_scan: usize, thr: f32) {
        let frame = self.frame;
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
    }
}

//! The per-frame tracking step: each track's seed (its INS prediction, its previous position
//! rotated by the gyro, or its previous position), the forward pyramidal LK into the new image
//! and the forward-backward check, followed by the per-track patch checks (`patches`).

use super::super::lk::{track_point, track_point_no_residual, LkFailure, LkScratch};
use super::super::pyramid::Pyramid;
use super::super::ransac;
use super::{Fate, FeatureTracker, TrackHints, TrackStats, TrackerConfig};
use crate::camera::{PinholeCamera, Vec2};

impl<const F: usize, const BYTES: usize, const LEVELS: usize> FeatureTracker<F, BYTES, LEVELS> {
    /// Forward LK (seeded) and the forward-backward check for every feature; fills `fate`,
    /// `new_pos`.
    pub(super) fn track_forward(
        &mut self,
        next: usize,
        hints: &TrackHints,
        cam: &PinholeCamera,
        st: &mut TrackStats,
    ) {
        let cfg = self.cfg;
        self.index_predictions(hints);
        let (Some(prev_pyr), Some(next_pyr)) = (self.pyr.get(self.cur), self.pyr.get(next)) else {
            return;
        };
        let (wf, hf) = ((self.dims.0 as f64) - 1.0, (self.dims.1 as f64) - 1.0);
        let inside = |p: &[f64; 2]| (0.0..=wf).contains(&p[0]) && (0.0..=hf).contains(&p[1]);
        let items = self
            .features
            .iter()
            .zip(self.norm.iter())
            .zip(self.pred.iter())
            .zip(self.fate.iter_mut().zip(self.new_pos.iter_mut()));
        for (((f, xn), pred), (fate, new_pos)) in items {
            *fate = Fate::Lost;
            let p0 = [f.u_px, f.v_px];
            let rot_seed = hints.r_cur_prev.as_ref().and_then(|r| {
                if !(xn[0].is_finite() && xn[1].is_finite()) {
                    return None;
                }
                let y = ransac::rotate(r, &[xn[0], xn[1], 1.0]);
                if y[2].is_nan() || y[2] <= 1e-6 {
                    return None;
                }
                let uv = cam.distort(&Vec2::new(y[0] / y[2], y[1] / y[2]));
                let uv = [uv.x, uv.y];
                inside(&uv).then_some(uv)
            });
            let (seed, top) = match (pred.filter(|p| inside(p)), rot_seed) {
                (Some(p), _) => {
                    st.seeded_prediction += 1;
                    (p, cfg.predicted_max_level)
                }
                (None, Some(r)) => {
                    st.seeded_rotation += 1;
                    (r, cfg.rotation_max_level)
                }
                (None, None) => {
                    st.seeded_previous += 1;
                    (p0, cfg.max_level)
                }
            };
            let fwd = track_point(prev_pyr, next_pyr, p0, seed, top, &cfg.lk, &mut self.lk);
            let tr = match fwd {
                Ok(tr) => tr,
                Err(e) => {
                    count_failure(e, st);
                    continue;
                }
            };
            st.lk_iterations += tr.iterations;
            if !inside(&tr.pos) {
                st.lost_out_of_image += 1;
                continue;
            }
            if cfg.fb_check
                && !round_trip_ok(prev_pyr, next_pyr, tr.pos, p0, &cfg, &mut self.lk, st)
            {
                continue;
            }
            if !tr.converged {
                st.not_converged += 1;
            }
            *fate = Fate::Alive;
            *new_pos = tr.pos;
        }
        if cfg.reference.enabled {
            self.refine_against_references(next, st);
        }
        if cfg.provisional.enabled {
            self.check_new_tracks(next, st);
        }
    }

    /// Writes the INS predictions of `hints` (non-finite ones ignored) to `pred` by feature
    /// index; features without one get `None`.
    fn index_predictions(&mut self, hints: &TrackHints) {
        let n = self.features.len();
        // Predictions by id (features are sorted by id).
        for p in self.pred.iter_mut().take(n) {
            *p = None;
        }
        for &(id, uv) in hints.predictions {
            if !(uv[0].is_finite() && uv[1].is_finite()) {
                continue;
            }
            if let Ok(i) = self.features.binary_search_by_key(&id, |f| f.id) {
                if let Some(p) = self.pred.get_mut(i) {
                    *p = Some(uv);
                }
            }
        }
    }
}

/// The forward-backward check of one track: tracks its new position `pos` back from `next_pyr`
/// into `prev_pyr`, seeded at its previous position `p0`; false (counted in
/// `lost_forward_backward`) when that fails or misses `p0` by more than `fb_threshold_px`.
fn round_trip_ok<const BYTES: usize, const LEVELS: usize>(
    prev_pyr: &Pyramid<BYTES, LEVELS>,
    next_pyr: &Pyramid<BYTES, LEVELS>,
    pos: [f64; 2],
    p0: [f64; 2],
    cfg: &TrackerConfig,
    lk: &mut LkScratch,
    st: &mut TrackStats,
) -> bool {
    match track_point_no_residual(next_pyr, prev_pyr, pos, p0, cfg.fb_max_level, &cfg.lk, lk) {
        Ok(back) => {
            st.lk_iterations += back.iterations;
            let (dx, dy) = (back.pos[0] - p0[0], back.pos[1] - p0[1]);
            let thr = f64::from(cfg.fb_threshold_px);
            if dx * dx + dy * dy > thr * thr {
                st.lost_forward_backward += 1;
                return false;
            }
            true
        }
        Err(_) => {
            st.lost_forward_backward += 1;
            false
        }
    }
}

/// Counts an LK failure in its `lost_*` statistic.
fn count_failure(e: LkFailure, st: &mut TrackStats) {
    match e {
        LkFailure::SmallEigen => st.lost_small_eigen += 1,
        LkFailure::OutOfImage => st.lost_out_of_image += 1,
        LkFailure::Residual => st.lost_residual += 1,
        LkFailure::NonFinite => st.lost_nonfinite += 1,
    }
}

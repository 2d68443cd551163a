//! The per-track patch checks after the forward LK: the anchored refinement of every surviving
//! track against its reference patch ([`reference`](super::super::reference)), the first-steps
//! check of new tracks against their detection patch ([`provisional`]), and the template
//! settings the two share.

use super::super::provisional::{self, Verdict};
use super::super::reference::{decide, ReferenceConfig, Refined};
use super::{median_of, Fate, FeatureTracker, TrackStats};

impl<const F: usize, const BYTES: usize, const LEVELS: usize> FeatureTracker<F, BYTES, LEVELS> {
    /// The template settings of the per-track patches: the anchored refinement's when it is on
    /// (the first-steps check then shares its templates), else the first-steps check's.
    pub(super) fn template_config(&self) -> ReferenceConfig {
        if self.cfg.reference.enabled {
            self.cfg.reference
        } else {
            self.cfg.provisional.as_reference()
        }
    }

    /// The first-steps check ([`super::super::provisional`]) of the surviving tracks of ages
    /// `0..frames` (before this step): ends those not explained by one surface.
    pub(super) fn check_new_tracks(&mut self, next: usize, st: &mut TrackStats) {
        let n = self.features.len();
        let Some(img) = self.pyr.get(next).and_then(|p| p.level(0)) else {
            return;
        };
        let pc = self.cfg.provisional;
        let rc = self.template_config();
        let abs = f64::from(pc.max_misalignment_px);
        let relative = pc.relative_to_median > 0.0;
        // Relative mode: the misalignments go to `new_norm[i][0]` (NaN: decided) and `flow`
        // (for the median); both are free until `reject_outliers` writes them.
        let mut m = 0usize;
        let items = self
            .fate
            .iter_mut()
            .zip(self.new_pos.iter())
            .zip(self.ages.iter())
            .zip(self.new_norm.iter_mut());
        for (i, (((fate, pos), &age), nn)) in items.take(n).enumerate() {
            nn[0] = f64::NAN;
            if *fate != Fate::Alive || age >= pc.frames {
                continue;
            }
            let meas = provisional::measure(&mut self.refs, i, &img, *pos, &pc, &rc);
            match meas {
                provisional::Measured::Misalignment(x) if relative => {
                    nn[0] = x;
                    if let Some(f) = self.flow.get_mut(m) {
                        *f = x;
                        m += 1;
                    }
                }
                _ => {
                    if provisional::verdict(meas, abs) == Verdict::Reject {
                        *fate = Fate::Lost;
                        st.lost_provisional += 1;
                    }
                }
            }
        }
        if !relative || m == 0 {
            return;
        }
        let median = median_of(self.flow.get_mut(..m).unwrap_or(&mut []));
        let thr = abs.max(f64::from(pc.relative_to_median) * median);
        let items = self.fate.iter_mut().zip(self.new_norm.iter()).take(n);
        for (fate, nn) in items {
            if nn[0] > thr {
                *fate = Fate::Lost;
                st.lost_provisional += 1;
            }
        }
    }

    /// Refines every surviving track against its reference patch ([`super::super::reference`]):
    /// accepted refinements replace `new_pos`, disagreeing tracks are lost, the others are
    /// re-anchored at their frame-to-frame position. The thresholds scale with the frame's
    /// median disagreement ([`ReferenceConfig::relative_to_median`]), so they are decided after
    /// every track is refined: the refined positions wait in `r_cur` (marked in `r_in`), their
    /// distances in `flow` (both scratch until [`Self::reject_outliers`]).
    pub(super) fn refine_against_references(&mut self, next: usize, st: &mut TrackStats) {
        let n = self.features.len();
        let Some(img) = self.pyr.get(next).and_then(|p| p.level(0)) else {
            return;
        };
        let rc = self.cfg.reference;
        let every = u64::from(rc.every_frames.max(1));
        let mut m = 0usize;
        for i in 0..n {
            let Some(mark) = self.r_in.get_mut(i) else {
                break;
            };
            *mark = false;
            let (Some(&Fate::Alive), Some(&pos)) = (self.fate.get(i), self.new_pos.get(i)) else {
                continue;
            };
            let id = self.features.get(i).map_or(0, |f| f.id);
            if !(self.frame.wrapping_add(id)).is_multiple_of(every) {
                continue;
            }
            match self.refs.refine_warp(i, &img, pos, &rc) {
                Some(t) if t.converged && t.residual <= rc.max_residual => {
                    // The warm start of the next refinement (re-anchoring resets it).
                    self.refs.set_linear(i, t.lin);
                    if let (Some(r), Some(d)) = (self.r_cur.get_mut(i), self.flow.get_mut(m)) {
                        *r = t.pos;
                        *d = libm::hypot(t.pos[0] - pos[0], t.pos[1] - pos[1]);
                        *mark = true;
                        m += 1;
                    }
                }
                _ => {
                    self.refs.capture(i, &img, pos, &rc);
                    st.reanchored += 1;
                }
            }
        }
        let scale = median_of(self.flow.get_mut(..m).unwrap_or(&mut []));
        st.reference_median_shift_px = scale as f32;
        let (wf, hf) = ((self.dims.0 as f64) - 1.0, (self.dims.1 as f64) - 1.0);
        let inside = |p: &[f64; 2]| (0.0..=wf).contains(&p[0]) && (0.0..=hf).contains(&p[1]);
        for i in 0..n {
            let (Some(&true), Some(&r), Some(pos), Some(fate)) = (
                self.r_in.get(i),
                self.r_cur.get(i),
                self.new_pos.get_mut(i),
                self.fate.get_mut(i),
            ) else {
                continue;
            };
            match decide(r, *pos, &rc, scale) {
                Refined::Accepted(p) if inside(&p) => {
                    *pos = p;
                    st.refined += 1;
                }
                Refined::Disagrees => {
                    *fate = Fate::Lost;
                    st.lost_reference += 1;
                }
                Refined::Accepted(_) | Refined::Reanchor => {
                    self.refs.capture(i, &img, *pos, &rc);
                    st.reanchored += 1;
                }
            }
        }
    }
}

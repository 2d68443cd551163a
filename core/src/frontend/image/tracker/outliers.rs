//! Geometric outlier rejection of the tracked points (undistortion, the parallax proxy, the
//! choice of the RANSAC model and its run) and the bookkeeping of the survivors (kept in order
//! with their new positions, ages and normalized points).

use super::super::ransac::{self, RansacModel, XorShift64};
use super::{median_of, Fate, FeatureTracker, RansacRun, TrackHints, TrackStats};
use crate::camera::{FeatureObs, PinholeCamera};

impl<const F: usize, const BYTES: usize, const LEVELS: usize> FeatureTracker<F, BYTES, LEVELS> {
    /// Undistorts the surviving tracks and runs RANSAC on those with valid previous and
    /// current normalized points.
    pub(super) fn reject_outliers(
        &mut self,
        hints: &TrackHints,
        cam: &PinholeCamera,
        st: &mut TrackStats,
    ) {
        let focal = 0.5 * (libm::fabs(cam.fx) + libm::fabs(cam.fy));
        let m = self.gather_pairs(hints, cam, focal, st);
        let rc = self.cfg.ransac;
        let flow = self.flow.get_mut(..m).unwrap_or(&mut []);
        let median_flow = median_of(flow);
        let low_flow = median_flow < rc.eight_point_min_flow_px;
        let gyro = hints.r_cur_prev.is_some();
        let run = match rc.model {
            RansacModel::Off => RansacRun::None,
            RansacModel::TwoPoint if gyro => RansacRun::TwoPoint,
            RansacModel::TwoPoint => RansacRun::None,
            RansacModel::Auto if low_flow && gyro => RansacRun::TwoPoint,
            RansacModel::Auto | RansacModel::EightPoint if low_flow => RansacRun::SkippedLowFlow,
            RansacModel::Auto | RansacModel::EightPoint => RansacRun::EightPoint,
        };
        let thr_n = rc.threshold_px / focal;
        let thr2_n = rc.two_point_threshold_px / focal;
        let mut rng = XorShift64::new(rc.seed ^ self.frame.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let (prev_n, cur_n, inl) = (
            self.r_prev.get(..m).unwrap_or(&[]),
            self.r_cur.get(..m).unwrap_or(&[]),
            self.r_in.get_mut(..m).unwrap_or(&mut []),
        );
        let run = match (run, &hints.r_cur_prev) {
            (RansacRun::TwoPoint, Some(r)) => {
                st.ransac = ransac::two_point(
                    prev_n,
                    cur_n,
                    r,
                    thr2_n,
                    &rc,
                    &mut rng,
                    &mut self.r_y,
                    &mut self.r_m,
                    inl,
                );
                RansacRun::TwoPoint
            }
            (RansacRun::EightPoint, _) => {
                st.ransac = ransac::eight_point(prev_n, cur_n, thr_n, &rc, &mut rng, inl);
                RansacRun::EightPoint
            }
            (RansacRun::TwoPoint, None) => RansacRun::None,
            (other, _) => other,
        };
        st.ransac_run = run;
        if matches!(run, RansacRun::TwoPoint | RansacRun::EightPoint) {
            for (&ok, &i) in self.r_in.iter().zip(self.r_idx.iter()).take(m) {
                if !ok {
                    if let Some(fate) = self.fate.get_mut(usize::from(i)) {
                        *fate = Fate::Lost;
                        st.lost_ransac += 1;
                    }
                }
            }
        }
    }

    /// Undistorts the surviving tracks into `new_norm` and gathers the RANSAC input: the pairs
    /// of valid previous and current normalized points (`r_prev`, `r_cur`, the track indices in
    /// `r_idx`) and each pair's parallax proxy in `flow`, px (`focal`: the mean focal length).
    /// Returns the pair count.
    fn gather_pairs(
        &mut self,
        hints: &TrackHints,
        cam: &PinholeCamera,
        focal: f64,
        st: &mut TrackStats,
    ) -> usize {
        let n = self.features.len();
        let mut m = 0usize;
        let items = self
            .fate
            .iter()
            .zip(self.new_pos.iter())
            .zip(self.new_norm.iter_mut())
            .zip(self.norm.iter())
            .take(n)
            .enumerate();
        for (i, (((fate, pos), nn), pn)) in items {
            if *fate != Fate::Alive {
                continue;
            }
            *nn = match cam.undistort(pos[0], pos[1]) {
                Ok(x) => [x.x, x.y],
                Err(_) => {
                    st.undistort_failed += 1;
                    [f64::NAN, f64::NAN]
                }
            };
            if nn[0].is_finite() && pn[0].is_finite() && pn[1].is_finite() {
                if let (Some(a), Some(b), Some(ix), Some(fl)) = (
                    self.r_prev.get_mut(m),
                    self.r_cur.get_mut(m),
                    self.r_idx.get_mut(m),
                    self.flow.get_mut(m),
                ) {
                    *a = *pn;
                    *b = *nn;
                    *ix = i as u16;
                    // Parallax proxy: the image motion, derotated when the gyro rotation is known
                    // (normalized plane, scaled by the focal length below).
                    let (dx, dy) = match &hints.r_cur_prev {
                        Some(r) => {
                            let y = ransac::rotate(r, &[pn[0], pn[1], 1.0]);
                            if y[2] > 1e-6 {
                                (nn[0] - y[0] / y[2], nn[1] - y[1] / y[2])
                            } else {
                                (f64::INFINITY, 0.0)
                            }
                        }
                        None => (nn[0] - pn[0], nn[1] - pn[1]),
                    };
                    *fl = libm::sqrt(dx * dx + dy * dy) * focal;
                    m += 1;
                }
            }
        }
        m
    }

    /// Keeps the survivors in order with their new positions and ages.
    pub(super) fn compact(&mut self, st: &mut TrackStats) {
        let n = self.features.len();
        let mut k = 0usize;
        for i in 0..n {
            if self.fate.get(i) != Some(&Fate::Alive) {
                continue;
            }
            let (Some(&pos), Some(&nn)) = (self.new_pos.get(i), self.new_norm.get(i)) else {
                continue;
            };
            let id = self.features.get(i).map_or(0, |f| f.id);
            let age = self.ages.get(i).copied().unwrap_or(0).saturating_add(1);
            if let (Some(f), Some(a), Some(x)) = (
                self.features.get_mut(k),
                self.ages.get_mut(k),
                self.norm.get_mut(k),
            ) {
                *f = FeatureObs {
                    id,
                    u_px: pos[0],
                    v_px: pos[1],
                };
                *a = age;
                *x = nn;
                self.refs.move_slot(i, k);
                k += 1;
            }
        }
        self.features.truncate(k);
        self.ages.truncate(k);
        self.norm.truncate(k);
        st.tracked = k as u32;
    }
}

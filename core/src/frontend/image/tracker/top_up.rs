//! Top-up detection: new corners where features are missing, appended as new tracks with
//! fresh ids (and, when a patch check is on, their template patch).

use super::{FeatureTracker, TrackStats};
use crate::camera::{FeatureObs, PinholeCamera};

impl<const F: usize, const BYTES: usize, const LEVELS: usize> FeatureTracker<F, BYTES, LEVELS> {
    /// Detects new corners up to `max_features` and appends them as new tracks.
    pub(super) fn top_up(&mut self, cam: &PinholeCamera, st: &mut TrackStats) {
        let wanted = self.cfg.max_features.saturating_sub(self.features.len());
        if wanted == 0 {
            return;
        }
        let Some(img) = self.pyr.get(self.cur).and_then(|p| p.level(0)) else {
            return;
        };
        let res = self.detector.detect(
            &img,
            &self.cfg.detector,
            &self.features,
            wanted,
            &mut self.corners,
        );
        let Ok(ds) = res else {
            return;
        };
        st.detect = ds;
        for c in self.corners.iter().take(ds.detected as usize) {
            let (u, v) = (f64::from(c.x), f64::from(c.y));
            let nn = cam
                .undistort(u, v)
                .map_or([f64::NAN, f64::NAN], |x| [x.x, x.y]);
            let obs = FeatureObs {
                id: self.next_id,
                u_px: u,
                v_px: v,
            };
            if self.features.push(obs).is_err() {
                break;
            }
            // Same capacity as `features`: these cannot fail once that push succeeded.
            let _ = self.ages.push(0);
            let _ = self.norm.push(nn);
            if self.cfg.reference.enabled || self.cfg.provisional.enabled {
                let rc = self.template_config();
                self.refs
                    .capture(self.features.len() - 1, &img, [u, v], &rc);
            }
            self.next_id += 1;
            st.detected += 1;
        }
    }
}

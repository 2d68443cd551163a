//! Landmark bookkeeping over the sliding window.
//!
//! Keyframes are addressed by their *position* in the window, `0` = oldest. Each landmark keeps
//! one optional observation per position; when the oldest keyframe is marginalized every
//! landmark shifts its observations one position down. The anchor `s` is the first observing
//! keyframe (re-chosen after a shift), `e` the keyframe of largest parallax (re-chosen by the
//! estimator whenever poses change).
//!
//! Capacity: at most `L` landmarks. A track seen for the first time while the manager is full is
//! refused and counted in [`ManagerStats::refused_capacity`]; existing landmarks are never evicted
//! to make room, so a long-lived well-constrained landmark is never traded for a new one.

use crate::frontend::NormalizedObs;
use heapless::index_map::FnvIndexMap;
use heapless::Vec;

/// One observation of a landmark in a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct KfObs {
    /// Normalized image coordinates in that keyframe's camera.
    pub x_n: [f64; 2],
    /// Feature velocity on the normalized plane, 1/s.
    pub vel: [f64; 2],
    /// Time delay `td` (s) of the keyframe when the observation was taken (for `x - (td - td0) v`).
    pub td0_s: f64,
}

/// Status of a landmark's LiDAR depth (filled by the LiDAR layer).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LidarDepth {
    /// Depth (z in the anchor camera), m.
    pub depth_m: f64,
    /// Its standard deviation, m.
    pub sigma_m: f64,
}

/// A landmark: its track id and observations over the window.
#[derive(Debug, Clone, PartialEq)]
pub struct Landmark<const N: usize> {
    /// Track id.
    pub id: u64,
    /// Observation per window position (0 = oldest keyframe).
    pub obs: [Option<KfObs>; N],
    /// Anchor `s`: first observing position.
    pub anchor_s: u8,
    /// Anchor `e`: position of largest parallax w.r.t. `s`, once chosen.
    pub anchor_e: Option<u8>,
    /// Inverse depth in the anchor camera (inverse-depth mode state, and depth-only results), 1/m.
    pub inv_depth: f64,
    /// True once the landmark passed the parallax gate and may enter the optimization.
    pub usable: bool,
    /// Associated LiDAR depth in the anchor frame, if any.
    pub lidar: Option<LidarDepth>,
}

impl<const N: usize> Landmark<N> {
    /// Number of keyframes observing the landmark.
    pub fn n_obs(&self) -> usize {
        self.obs.iter().filter(|o| o.is_some()).count()
    }

    /// The first observing position, if any.
    pub fn first_obs(&self) -> Option<usize> {
        self.obs.iter().position(|o| o.is_some())
    }
}

/// Counters of the manager's decisions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ManagerStats {
    /// New landmarks created.
    pub created: u64,
    /// New tracks refused because `L` landmarks already exist.
    pub refused_capacity: u64,
    /// Landmarks removed because no keyframe in the window observes them any more.
    pub removed_unobserved: u64,
    /// Landmarks removed by outlier culling.
    pub removed_outlier: u64,
}

/// Fixed-capacity landmark store for a window of `N` keyframes and at most `L` landmarks.
/// `H` is the capacity of the id index and must be a power of two `>= L`.
#[derive(Clone)]
pub struct LandmarkManager<const N: usize, const L: usize, const H: usize> {
    lms: Vec<Landmark<N>, L>,
    index: FnvIndexMap<u64, u16, H>,
    /// Counters.
    pub stats: ManagerStats,
}

impl<const N: usize, const L: usize, const H: usize> Default for LandmarkManager<N, L, H> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const L: usize, const H: usize> LandmarkManager<N, L, H> {
    /// An empty manager.
    pub fn new() -> Self {
        LandmarkManager {
            lms: Vec::new(),
            index: FnvIndexMap::new(),
            stats: ManagerStats::default(),
        }
    }

    /// Landmarks, in storage order.
    pub fn landmarks(&self) -> &[Landmark<N>] {
        &self.lms
    }

    /// Mutable landmarks, in storage order.
    pub fn landmarks_mut(&mut self) -> &mut [Landmark<N>] {
        &mut self.lms
    }

    /// Number of landmarks.
    pub fn len(&self) -> usize {
        self.lms.len()
    }

    /// True when there are no landmarks.
    pub fn is_empty(&self) -> bool {
        self.lms.is_empty()
    }

    /// Looks a landmark up by track id.
    pub fn get(&self, id: u64) -> Option<&Landmark<N>> {
        self.index.get(&id).and_then(|&i| self.lms.get(i as usize))
    }

    /// Adds a keyframe's observations at window position `pos`. Returns how many were added.
    pub fn add_keyframe_obs(&mut self, pos: usize, obs: &[NormalizedObs], td_s: f64) -> usize {
        if pos >= N {
            return 0;
        }
        let mut added = 0;
        for o in obs {
            let kf = KfObs {
                x_n: o.x_n,
                vel: o.vel,
                td0_s: td_s,
            };
            if let Some(&i) = self.index.get(&o.id) {
                if let Some(lm) = self.lms.get_mut(i as usize) {
                    if let Some(slot) = lm.obs.get_mut(pos) {
                        *slot = Some(kf);
                        added += 1;
                    }
                }
                continue;
            }
            let mut lm = Landmark {
                id: o.id,
                obs: [None; N],
                anchor_s: pos as u8,
                anchor_e: None,
                inv_depth: 0.0,
                usable: false,
                lidar: None,
            };
            if let Some(slot) = lm.obs.get_mut(pos) {
                *slot = Some(kf);
            }
            let idx = self.lms.len();
            if self.lms.push(lm).is_err() || self.index.insert(o.id, idx as u16).is_err() {
                // Keep the two structures consistent if only the index was full.
                if self.lms.len() > idx {
                    self.lms.truncate(idx);
                }
                self.stats.refused_capacity += 1;
                continue;
            }
            self.stats.created += 1;
            added += 1;
        }
        added
    }

    /// Drops the oldest window position: shifts every landmark's observations down by one,
    /// re-anchors `s` (and clears `e` if it pointed at the dropped keyframe) and removes landmarks
    /// no keyframe observes any more. Returns the number removed.
    pub fn shift_out_oldest(&mut self) -> usize {
        for lm in self.lms.iter_mut() {
            lm.obs.rotate_left(1);
            if let Some(last) = lm.obs.last_mut() {
                *last = None;
            }
            let had_anchor_at_zero = lm.anchor_s == 0;
            match lm.first_obs() {
                Some(s) => lm.anchor_s = s as u8,
                None => continue,
            }
            lm.anchor_e = match lm.anchor_e {
                Some(e) if e > 0 && e.saturating_sub(1) != lm.anchor_s => Some(e - 1),
                _ => None,
            };
            if had_anchor_at_zero {
                // The depth was expressed in the dropped anchor; the LiDAR depth belongs to it.
                lm.lidar = None;
                lm.inv_depth = 0.0;
            }
        }
        self.retain(|lm| lm.first_obs().is_some(), false)
    }

    /// Clears every observation at window position `pos` (e.g. when a keyframe is replaced).
    pub fn clear_position(&mut self, pos: usize) {
        for lm in self.lms.iter_mut() {
            if let Some(o) = lm.obs.get_mut(pos) {
                *o = None;
            }
        }
    }

    /// Removes the landmarks for which `keep` is false. `outliers` selects which counter grows.
    pub fn retain(&mut self, mut keep: impl FnMut(&Landmark<N>) -> bool, outliers: bool) -> usize {
        let before = self.lms.len();
        self.lms.retain(|lm| keep(lm));
        let removed = before - self.lms.len();
        if removed > 0 {
            if outliers {
                self.stats.removed_outlier += removed as u64;
            } else {
                self.stats.removed_unobserved += removed as u64;
            }
            self.index.clear();
            for (i, lm) in self.lms.iter().enumerate() {
                // Same capacity as before the removal: cannot fail.
                let _ = self.index.insert(lm.id, i as u16);
            }
        }
        removed
    }

    /// Removes everything.
    pub fn clear(&mut self) {
        self.lms.clear();
        self.index.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(id: u64) -> NormalizedObs {
        NormalizedObs {
            id,
            x_n: [0.1 * id as f64, 0.0],
            vel: [0.0; 2],
        }
    }

    #[test]
    fn capacity_is_defined_and_counted() {
        let mut m: LandmarkManager<4, 3, 4> = LandmarkManager::new();
        let added = m.add_keyframe_obs(0, &[obs(1), obs(2), obs(3), obs(4), obs(5)], 0.0);
        assert_eq!(added, 3);
        assert_eq!(m.len(), 3);
        assert_eq!(m.stats.refused_capacity, 2);
        assert!(m.get(4).is_none());
        // Existing landmarks still receive observations when full.
        assert_eq!(m.add_keyframe_obs(1, &[obs(1), obs(5)], 0.0), 1);
        assert_eq!(m.get(1).map(|l| l.n_obs()), Some(2));
    }

    #[test]
    fn shifting_reanchors_and_drops_unobserved() {
        let mut m: LandmarkManager<3, 8, 8> = LandmarkManager::new();
        m.add_keyframe_obs(0, &[obs(1), obs(2)], 0.0);
        m.add_keyframe_obs(1, &[obs(1), obs(3)], 0.0);
        m.add_keyframe_obs(2, &[obs(1), obs(3)], 0.0);
        if let Some(lm) = m.landmarks_mut().iter_mut().find(|l| l.id == 1) {
            lm.anchor_e = Some(2);
        }
        let removed = m.shift_out_oldest();
        assert_eq!(
            removed, 1,
            "landmark 2 was seen only in the dropped keyframe"
        );
        let l1 = m.get(1).unwrap();
        assert_eq!((l1.anchor_s, l1.anchor_e, l1.n_obs()), (0, Some(1), 2));
        let l3 = m.get(3).unwrap();
        assert_eq!((l3.anchor_s, l3.n_obs()), (0, 2));
        assert!(l3.obs[2].is_none());
    }
}

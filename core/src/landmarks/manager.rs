//! Landmark bookkeeping over the sliding window.
//!
//! Keyframes are addressed by their *position* in the window, `0` = oldest. Each landmark keeps
//! one optional observation per position; when the oldest keyframe is marginalized every
//! landmark shifts its observations one position down. The anchor `s` is the first observing
//! keyframe (re-chosen after a shift), `e` the keyframe of largest parallax (re-chosen by the
//! estimator whenever poses change).
//!
//! Capacity: at most `L` landmarks, chosen among the tracks. Every keyframe's observations go
//! into an [`ObservationStore`] first; a track becomes a landmark only once it has valid
//! observations in two keyframes ([`LandmarkManager::promote`], usually decided by the
//! estimator's slot policy, which also evicts the landmarks worth least). A promoted track brings
//! every observation it has in the window, so a slot given late loses nothing. Tracks removed as
//! outliers are banned and never promoted again.

use super::obs::{KfObs, LidarDepth};
use super::store::{ObservationStore, TrackObs};
use crate::frontend::NormalizedObs;
use crate::Error;
use heapless::index_map::FnvIndexMap;
use heapless::Vec;

/// Outlier tracks remembered so they are not promoted again (the most recent ones).
pub const BANNED_TRACKS: usize = 256;

/// What the marginalization of the oldest keyframe (position 0) does with a landmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MargPlan {
    /// Not involved (no usable observation at position 0).
    #[default]
    None,
    /// Re-anchored on keyframes after 0; only the residual of its observation at 0 goes into the
    /// prior, the others stay in the window (nothing is counted twice, nothing lost).
    ObsZero,
    /// Every residual goes into the prior and the landmark leaves the window (no second anchor
    /// with parallax after position 0, or a LiDAR landmark whose depth belongs to position 0).
    Whole,
    /// Every residual goes into the prior and the landmark stays, re-anchored after the shift,
    /// so its later residuals are counted a second time (VINS-Mono's approximation; see
    /// `EstimatorConfig::reuse_marginalized_landmarks`).
    Reuse,
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
    /// Correction `(dx, dy)` of the anchor observation's normalized bearing, solved with the
    /// inverse depth where the depth is eliminated (`estimator::problem::visual`; a warm start,
    /// zero after every change of anchor).
    pub bearing_delta: [f64; 2],
    /// True once the landmark passed the parallax gate and may enter the optimization.
    pub usable: bool,
    /// Associated LiDAR depth in the anchor frame, if any.
    pub lidar: Option<LidarDepth>,
    /// Role in the coming marginalization (set just before it).
    pub marg: MargPlan,
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
    /// Landmarks created (tracks promoted).
    pub created: u64,
    /// Promotions refused because `L` landmarks already exist.
    pub refused_capacity: u64,
    /// Landmarks evicted to give their slot to a more informative track.
    pub evicted: u64,
    /// Landmarks removed because no keyframe in the window observes them any more.
    pub removed_unobserved: u64,
    /// Landmarks removed by outlier culling.
    pub removed_outlier: u64,
}

impl ManagerStats {
    /// All zero (what [`Default`] gives).
    pub const ZERO: ManagerStats = ManagerStats {
        created: 0,
        refused_capacity: 0,
        evicted: 0,
        removed_unobserved: 0,
        removed_outlier: 0,
    };
}

/// Fixed-capacity landmark store for a window of `N` keyframes and at most `L` landmarks, with
/// the observations of up to `F` tracks per keyframe. `H` is the capacity of the id index and
/// must be a power of two `>= L`.
#[derive(Clone)]
pub struct LandmarkManager<const N: usize, const L: usize, const H: usize, const F: usize> {
    lms: Vec<Landmark<N>, L>,
    index: FnvIndexMap<u64, u16, H>,
    store: ObservationStore<N, F>,
    banned: Vec<u64, BANNED_TRACKS>,
    banned_next: usize,
    /// Counters.
    pub stats: ManagerStats,
}

impl<const N: usize, const L: usize, const H: usize, const F: usize> Default
    for LandmarkManager<N, L, H, F>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const L: usize, const H: usize, const F: usize> LandmarkManager<N, L, H, F> {
    /// An empty manager; `const` so it can initialize a `static`.
    pub const fn new() -> Self {
        LandmarkManager {
            lms: Vec::new(),
            index: FnvIndexMap::new(),
            store: ObservationStore::new(),
            banned: Vec::new(),
            banned_next: 0,
            stats: ManagerStats::ZERO,
        }
    }

    /// Back to the state [`LandmarkManager::new`] builds, in place (unlike
    /// [`LandmarkManager::clear`], the bans and statistics go too).
    pub fn reset_to_new(&mut self) {
        self.clear();
        self.banned.clear();
        self.banned_next = 0;
        self.stats = ManagerStats::ZERO;
    }

    /// Every track's observations in the window.
    pub fn store(&self) -> &ObservationStore<N, F> {
        &self.store
    }

    /// True when `id` was removed as an outlier recently.
    pub fn is_banned(&self, id: u64) -> bool {
        self.banned.contains(&id)
    }

    /// Remembers `id` as an outlier track (the oldest ban is forgotten when full).
    pub fn ban(&mut self, id: u64) {
        if self.is_banned(id) {
            return;
        }
        if self.banned.push(id).is_err() {
            if let Some(b) = self.banned.get_mut(self.banned_next) {
                *b = id;
            }
            self.banned_next = (self.banned_next + 1) % BANNED_TRACKS;
        }
    }

    /// Appends a keyframe's observations (sorted by id) at window position `pos` (the next one):
    /// into the store, and to the landmarks that track them. Returns how many landmarks got one.
    pub fn add_keyframe(
        &mut self,
        pos: usize,
        obs: &[NormalizedObs],
        td_s: f64,
    ) -> Result<usize, Error> {
        if pos >= N || pos != self.store.len() {
            return Err(Error::DimensionMismatch);
        }
        self.store.push_keyframe(obs, td_s)?;
        let mut added = 0;
        for o in self.store.at(pos) {
            let Some(&i) = self.index.get(&o.id) else {
                continue;
            };
            if let Some(slot) = self
                .lms
                .get_mut(i as usize)
                .and_then(|l| l.obs.get_mut(pos))
            {
                *slot = Some(o.obs);
                added += 1;
            }
        }
        Ok(added)
    }

    /// Tracks observed at the newest position that are not landmarks, not banned, and have valid
    /// observations in at least two keyframes of the window: the candidates for a slot, written
    /// to `out` with their number of observations.
    pub fn candidates<const C: usize>(&self, out: &mut Vec<(u64, u8), C>) {
        out.clear();
        let Some(newest) = self.store.len().checked_sub(1) else {
            return;
        };
        for o in self.store.at(newest) {
            if !o.valid || self.index.contains_key(&o.id) || self.is_banned(o.id) {
                continue;
            }
            let n = (0..newest)
                .filter(|&k| self.store.find(k, o.id).is_some())
                .count()
                + 1;
            if n >= 2 && out.push((o.id, n as u8)).is_err() {
                break;
            }
        }
    }

    /// Makes track `id` a landmark with every valid observation the store has of it; the anchor
    /// `s` is its first observation (with the LiDAR depth associated there, if any). Returns the
    /// landmark's index (also when it is one already). [`Error::CapacityExceeded`] when `L`
    /// landmarks exist (counted), [`Error::NotEnoughData`] with fewer than two observations.
    pub fn promote(&mut self, id: u64) -> Result<usize, Error> {
        if let Some(&i) = self.index.get(&id) {
            return Ok(i as usize);
        }
        let mut lm = Landmark {
            id,
            obs: [None; N],
            anchor_s: 0,
            anchor_e: None,
            inv_depth: 0.0,
            bearing_delta: [0.0; 2],
            usable: false,
            lidar: None,
            marg: MargPlan::None,
        };
        let mut first: Option<&TrackObs> = None;
        let mut n = 0;
        for (k, slot) in lm.obs.iter_mut().enumerate().take(self.store.len()) {
            if let Some(o) = self.store.find(k, id) {
                *slot = Some(o.obs);
                first = first.or(Some(o));
                n += 1;
            }
        }
        let Some(first) = first.filter(|_| n >= 2) else {
            return Err(Error::NotEnoughData);
        };
        lm.anchor_s = lm.first_obs().unwrap_or(0) as u8;
        lm.lidar = first.lidar;
        if let Some(d) = first.lidar {
            lm.inv_depth = 1.0 / d.depth_m;
        }
        let idx = self.lms.len();
        if self.lms.push(lm).is_err() || self.index.insert(id, idx as u16).is_err() {
            if self.lms.len() > idx {
                self.lms.truncate(idx);
            }
            self.stats.refused_capacity += 1;
            return Err(Error::CapacityExceeded);
        }
        self.stats.created += 1;
        Ok(idx)
    }

    /// Removes landmark `li` to free its slot (its observations stay in the store).
    pub fn evict(&mut self, li: usize) {
        let Some(id) = self.lms.get(li).map(|l| l.id) else {
            return;
        };
        self.stats.evicted += self.remove_where(|l| l.id == id) as u64;
    }

    /// Removes the landmarks whose id is in `ids` to free their slots.
    pub fn evict_ids(&mut self, ids: &[u64]) {
        self.stats.evicted += self.remove_where(|l| ids.contains(&l.id)) as u64;
    }

    fn remove_where(&mut self, mut drop: impl FnMut(&Landmark<N>) -> bool) -> usize {
        let before = self.lms.len();
        self.lms.retain(|lm| !drop(lm));
        let removed = before - self.lms.len();
        if removed > 0 {
            self.index.clear();
            for (i, lm) in self.lms.iter().enumerate() {
                // Same capacity as before the removal: cannot fail.
                let _ = self.index.insert(lm.id, i as u16);
            }
        }
        removed
    }

    /// Removes landmark `li` after its every residual went into the marginalization prior: its
    /// observations are invalidated in the store too, so that a later promotion of the same
    /// track does not use them a second time.
    pub fn remove_marginalized(&mut self, li: usize) {
        let Some(lm) = self.lms.get(li) else { return };
        let id = lm.id;
        for k in 0..self.store.len() {
            self.store.invalidate(k, id);
        }
        self.remove_where(|l| l.id == id);
    }

    /// Removes the observation of landmark `li` at `pos` as an outlier (also from the store, so a
    /// later promotion does not bring it back).
    pub fn invalidate_obs(&mut self, li: usize, pos: usize) -> bool {
        let Some(lm) = self.lms.get_mut(li) else {
            return false;
        };
        let id = lm.id;
        let had = lm.obs.get_mut(pos).and_then(|o| o.take()).is_some();
        self.store.invalidate(pos, id);
        had
    }

    /// Records a LiDAR depth for track `id`'s observation at `pos` (store and landmark, when the
    /// landmark is anchored there).
    pub fn set_lidar(&mut self, pos: usize, id: u64, depth: LidarDepth) {
        self.store.set_lidar(pos, id, Some(depth));
        if let Some(lm) = self
            .index
            .get(&id)
            .and_then(|&i| self.lms.get_mut(i as usize))
        {
            if lm.anchor_s as usize == pos {
                lm.lidar = Some(depth);
                lm.inv_depth = 1.0 / depth.depth_m;
            }
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

    /// Drops the oldest window position: shifts every landmark's observations down by one,
    /// re-anchors `s` (and clears `e` if it pointed at the dropped keyframe) and removes landmarks
    /// no keyframe observes any more. Returns the number removed.
    pub fn shift_out_oldest(&mut self) -> usize {
        self.store.shift_out_oldest();
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
                // A depth associated at the new anchor (if any) takes its place.
                lm.lidar = self
                    .store
                    .find(lm.anchor_s as usize, lm.id)
                    .and_then(|o| o.lidar);
                lm.inv_depth = lm.lidar.map_or(0.0, |d| 1.0 / d.depth_m);
                lm.bearing_delta = [0.0; 2];
            }
        }
        self.retain(|lm| lm.first_obs().is_some(), false)
    }

    /// Removes the landmarks for which `keep` is false. `outliers` selects which counter grows.
    pub fn retain(&mut self, mut keep: impl FnMut(&Landmark<N>) -> bool, outliers: bool) -> usize {
        let removed = self.remove_where(|lm| !keep(lm));
        if outliers {
            self.stats.removed_outlier += removed as u64;
        } else {
            self.stats.removed_unobserved += removed as u64;
        }
        removed
    }

    /// Removes everything (the bans stay: they are about tracks, not about this window).
    pub fn clear(&mut self) {
        self.lms.clear();
        self.index.clear();
        self.store.clear();
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
            row_dt_s: 0.0,
        }
    }

    fn kf(m: &mut LandmarkManager<4, 3, 4, 8>, pos: usize, ids: &[u64]) -> usize {
        let v: Vec<NormalizedObs, 8> = ids.iter().map(|&i| obs(i)).collect();
        m.add_keyframe(pos, &v, 0.0).unwrap()
    }

    #[test]
    fn promotion_needs_two_views_and_respects_capacity() {
        let mut m: LandmarkManager<4, 3, 4, 8> = LandmarkManager::new();
        assert_eq!(kf(&mut m, 0, &[1, 2, 3, 4, 5]), 0);
        let mut c: Vec<(u64, u8), 8> = Vec::new();
        m.candidates(&mut c);
        assert!(c.is_empty(), "single views are no candidates");
        assert_eq!(m.promote(1), Err(Error::NotEnoughData));
        assert_eq!(kf(&mut m, 1, &[1, 2, 3, 4, 6]), 0);
        m.candidates(&mut c);
        assert_eq!(c.as_slice(), &[(1, 2), (2, 2), (3, 2), (4, 2)]);
        for id in [1, 2, 3] {
            m.promote(id).unwrap();
        }
        assert_eq!(m.promote(4), Err(Error::CapacityExceeded));
        assert_eq!(m.stats.refused_capacity, 1);
        assert_eq!(m.promote(2), Ok(1), "promoting a landmark is a no-op");
        // Existing landmarks receive their observations; a late promotion brings all of them.
        assert_eq!(kf(&mut m, 2, &[1, 4]), 1);
        m.evict(1);
        assert_eq!((m.len(), m.stats.evicted), (2, 1));
        let i = m.promote(4).unwrap();
        assert_eq!(m.landmarks()[i].n_obs(), 3);
        // A culled observation never comes back; a banned track is no candidate.
        assert!(m.invalidate_obs(i, 1));
        m.evict(i);
        let i = m.promote(4).unwrap();
        assert_eq!(m.landmarks()[i].n_obs(), 2);
        m.evict(i);
        m.ban(4);
        m.candidates(&mut c);
        assert!(c.iter().all(|(id, _)| *id != 4));
    }

    #[test]
    fn shifting_reanchors_and_drops_unobserved() {
        let mut m: LandmarkManager<3, 8, 8, 8> = LandmarkManager::new();
        let v = |ids: &[u64]| -> Vec<NormalizedObs, 8> { ids.iter().map(|&i| obs(i)).collect() };
        m.add_keyframe(0, &v(&[1, 2]), 0.0).unwrap();
        m.add_keyframe(1, &v(&[1, 2, 3]), 0.0).unwrap();
        m.add_keyframe(2, &v(&[1, 3]), 0.0).unwrap();
        for id in [1, 2, 3] {
            m.promote(id).unwrap();
        }
        if let Some(lm) = m.landmarks_mut().iter_mut().find(|l| l.id == 1) {
            lm.anchor_e = Some(2);
        }
        m.shift_out_oldest();
        let l1 = m.get(1).unwrap();
        assert_eq!((l1.anchor_s, l1.anchor_e, l1.n_obs()), (0, Some(1), 2));
        let l3 = m.get(3).unwrap();
        assert_eq!((l3.anchor_s, l3.n_obs()), (0, 2));
        assert!(l3.obs[2].is_none());
        m.shift_out_oldest();
        assert!(m.get(2).is_none(), "landmark 2 is no longer observed");
        assert_eq!(m.store().len(), 1);
    }
}

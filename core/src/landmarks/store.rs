//! Every track's observation in every keyframe of the window, landmark or not.
//!
//! The landmark slots are few (`L`) and the tracks many: a keyframe typically holds 100-250
//! features, and the window sees 300-500 distinct tracks in two or more of its keyframes. Which
//! tracks hold a slot is decided anew at every keyframe
//! ([`super::LandmarkManager::candidates`], [`super::LandmarkManager::promote`]); the store
//! keeps each keyframe's observations (sorted by track id) so that a track promoted late still
//! brings every observation it has in the window, and an evicted landmark loses nothing that a
//! later promotion could not restore.
//!
//! Positions are window positions (`0` = oldest), as in the landmark manager; the store is a ring
//! that drops position 0 when the oldest keyframe leaves the window.

use super::obs::{KfObs, LidarDepth};
use crate::frontend::NormalizedObs;
use crate::Error;
use heapless::Vec as HVec;

/// One track's observation in one keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackObs {
    /// Track id.
    pub id: u64,
    /// The observation.
    pub obs: KfObs,
    /// False once outlier culling removed it: it never comes back.
    pub valid: bool,
    /// LiDAR depth associated with it in this keyframe (z in this keyframe's camera), if any.
    pub lidar: Option<LidarDepth>,
}

/// Observations of up to `F` tracks in each of `N` keyframes.
#[derive(Clone)]
pub struct ObservationStore<const N: usize, const F: usize> {
    kfs: [HVec<TrackObs, F>; N],
    head: usize,
    count: usize,
}

impl<const N: usize, const F: usize> Default for ObservationStore<N, F> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const F: usize> ObservationStore<N, F> {
    /// Empty; `const` so it can initialize a `static`.
    pub const fn new() -> Self {
        ObservationStore {
            kfs: [const { HVec::new() }; N],
            head: 0,
            count: 0,
        }
    }

    /// Keyframes held.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True when no keyframe is held.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    fn slot(&self, pos: usize) -> Option<usize> {
        (pos < self.count && N > 0).then(|| (self.head + pos) % N)
    }

    /// The observations of window position `pos`, sorted by track id (empty when out of range).
    pub fn at(&self, pos: usize) -> &[TrackObs] {
        self.slot(pos)
            .and_then(|s| self.kfs.get(s))
            .map_or(&[], |v| v.as_slice())
    }

    /// The observation of track `id` at `pos`, if stored and valid.
    pub fn find(&self, pos: usize, id: u64) -> Option<&TrackObs> {
        let v = self.at(pos);
        v.binary_search_by(|o| o.id.cmp(&id))
            .ok()
            .and_then(|i| v.get(i))
            .filter(|o| o.valid)
    }

    fn find_mut(&mut self, pos: usize, id: u64) -> Option<&mut TrackObs> {
        let s = self.slot(pos)?;
        let v = self.kfs.get_mut(s)?;
        let i = v.binary_search_by(|o| o.id.cmp(&id)).ok()?;
        v.get_mut(i)
    }

    /// Appends a keyframe's observations (sorted by id, as the track table gives them) at the
    /// next position; `td_s` is the keyframe's delay when they were taken.
    /// [`Error::CapacityExceeded`] when `N` keyframes are held (shift first).
    pub fn push_keyframe(&mut self, obs: &[NormalizedObs], td_s: f64) -> Result<(), Error> {
        if self.count >= N {
            return Err(Error::CapacityExceeded);
        }
        let s = (self.head + self.count) % N;
        let v = self.kfs.get_mut(s).ok_or(Error::CapacityExceeded)?;
        v.clear();
        for o in obs.iter().take(F) {
            // Same capacity as the frame: cannot fail.
            let _ = v.push(TrackObs {
                id: o.id,
                obs: KfObs {
                    x_n: o.x_n,
                    vel: o.vel,
                    td0_s: td_s,
                },
                valid: true,
                lidar: None,
            });
        }
        self.count += 1;
        Ok(())
    }

    /// Drops the oldest keyframe.
    pub fn shift_out_oldest(&mut self) {
        if self.count == 0 || N == 0 {
            return;
        }
        if let Some(v) = self.kfs.get_mut(self.head) {
            v.clear();
        }
        self.head = (self.head + 1) % N;
        self.count -= 1;
    }

    /// Marks the observation of `id` at `pos` as an outlier for good.
    pub fn invalidate(&mut self, pos: usize, id: u64) {
        if let Some(o) = self.find_mut(pos, id) {
            o.valid = false;
        }
    }

    /// Records a LiDAR depth for the observation of `id` at `pos`.
    pub fn set_lidar(&mut self, pos: usize, id: u64, depth: Option<LidarDepth>) {
        if let Some(o) = self.find_mut(pos, id) {
            o.lidar = depth;
        }
    }

    /// Tracks with valid observations in at least two keyframes of the window, and the number of
    /// those observations: what the window offers an estimator (tracks are continuous, so a
    /// track's keyframes are consecutive positions; `O(observations)` by merging neighbours).
    pub fn multi_view(&self) -> (u32, u32) {
        let (mut tracks, mut observations) = (0u32, 0u32);
        for k in 0..self.count {
            let (prev, cur) = (if k > 0 { self.at(k - 1) } else { &[] }, self.at(k));
            let mut ip = 0;
            for o in cur {
                while prev.get(ip).is_some_and(|p| p.id < o.id) {
                    ip += 1;
                }
                if prev.get(ip).is_some_and(|p| p.id == o.id) {
                    continue; // not the track's first keyframe
                }
                // First keyframe of this track: count its valid observations along its run.
                let mut n = u32::from(o.valid);
                for j in k + 1..self.count {
                    match self.at(j).binary_search_by(|x| x.id.cmp(&o.id)) {
                        Ok(i) => n += u32::from(self.at(j).get(i).is_some_and(|x| x.valid)),
                        Err(_) => break,
                    }
                }
                if n >= 2 {
                    tracks += 1;
                    observations += n;
                }
            }
        }
        (tracks, observations)
    }

    /// Drops everything.
    pub fn clear(&mut self) {
        for v in self.kfs.iter_mut() {
            v.clear();
        }
        self.head = 0;
        self.count = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(ids: &[u64]) -> heapless::Vec<NormalizedObs, 8> {
        ids.iter()
            .map(|&id| NormalizedObs {
                id,
                x_n: [id as f64, 0.0],
                vel: [0.0; 2],
                row_dt_s: 0.0,
            })
            .collect()
    }

    #[test]
    fn ring_keeps_positions_and_validity() {
        let mut s: ObservationStore<3, 8> = ObservationStore::new();
        s.push_keyframe(&obs(&[1, 2, 5]), 0.0).unwrap();
        s.push_keyframe(&obs(&[2, 5, 7]), 0.001).unwrap();
        s.push_keyframe(&obs(&[5]), 0.002).unwrap();
        assert_eq!(
            s.push_keyframe(&obs(&[9]), 0.0),
            Err(Error::CapacityExceeded)
        );
        assert_eq!(s.find(1, 7).map(|o| o.obs.td0_s), Some(0.001));
        s.invalidate(1, 5);
        assert!(s.find(1, 5).is_none(), "an invalidated observation is gone");
        s.shift_out_oldest();
        assert_eq!(s.len(), 2);
        // Position 0 is now the old position 1.
        assert_eq!(
            s.at(0)
                .iter()
                .map(|o| o.id)
                .collect::<heapless::Vec<u64, 4>>(),
            [2, 5, 7]
        );
        assert!(s.find(0, 5).is_none());
        s.push_keyframe(&obs(&[9]), 0.0).unwrap();
        assert!(s.find(2, 9).is_some());
        assert!(s.find(5, 9).is_none(), "out of range");
        assert!(s.at(7).is_empty());
        // Tracks 2 and 7 span positions 0-1 (5 is invalid there), 9 is single.
        assert_eq!(s.multi_view(), (0, 0));
        s.push_keyframe(&obs(&[2, 9]), 0.0).unwrap_err();
    }

    #[test]
    fn multi_view_counts_tracks_over_consecutive_keyframes() {
        let mut s: ObservationStore<4, 8> = ObservationStore::new();
        s.push_keyframe(&obs(&[1, 2, 3]), 0.0).unwrap();
        s.push_keyframe(&obs(&[1, 2, 4]), 0.0).unwrap();
        s.push_keyframe(&obs(&[1, 4, 6]), 0.0).unwrap();
        s.push_keyframe(&obs(&[1, 6]), 0.0).unwrap();
        // 1: 4 obs, 2: 2, 4: 2, 6: 2; 3 is single.
        assert_eq!(s.multi_view(), (4, 10));
        s.invalidate(1, 2);
        assert_eq!(s.multi_view(), (3, 8));
    }
}

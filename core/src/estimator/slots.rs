//! The slot policy: which tracks hold the `L` landmark slots.
//!
//! A keyframe offers far more tracks seen in two or more keyframes than there are slots (on
//! EuRoC-like flights 300-450 per window for 200 slots). Giving slots first come, first served
//! filled the store with young, distant or stale tracks that never became usable, while the
//! tracks that would have carried information were refused (measured: 40 of 200 landmarks used
//! on the simulated robot). So at every keyframe each candidate (a track seen in the newest
//! keyframe and at least one earlier one, not a landmark, not banned as an outlier) and each
//! landmark gets a score, the free slots go to the best candidates, and a candidate replaces the
//! worst landmark when it scores higher by a margin (so landmarks do not flap):
//!
//! ```text
//! score = (n + alive) * clamp(theta / theta_ref, 0.1, 1)
//! ```
//!
//! with `n` the valid observations in the window, `alive` 1 when the track is seen in the newest
//! keyframe (it will keep growing), `theta = max_k |x_k x R_ks x_s|` the largest parallax
//! against the first observation at the current poses, and `theta_ref`
//! ([`super::EstimatorConfig::slot_parallax_ref`]) the parallax at which a landmark's depth is
//! well determined. Each observation adds a residual; parallax decides whether the residuals
//! constrain translation or only rotation.

use super::{corrected_obs, Estimator, MAX_FEATURES};
use crate::camera::CameraPose;
use crate::landmarks::KfObs;
use crate::math::{Mat3, Vec3};
use heapless::Vec as HVec;

/// Relative rotations `R_ks = R_kw R_ws` (`[k][s]`) of the first `count` cameras, each formed
/// as [`CameraPose::relative_from`] forms it (the same values), but once per pair and from one
/// rotation matrix per camera instead of two quaternion conversions per landmark and pair.
pub(super) fn relative_rotations<const N: usize>(
    cams: &[CameraPose; N],
    count: usize,
) -> [[Mat3; N]; N] {
    let r_wc: [Mat3; N] = core::array::from_fn(|k| match cams.get(k) {
        Some(c) if k < count => c.q_wc.to_rotation_matrix().into_inner(),
        _ => Mat3::identity(),
    });
    core::array::from_fn(|k| {
        core::array::from_fn(|s| match (r_wc.get(k), r_wc.get(s)) {
            (Some(r_wk), Some(r_ws)) => r_wk.transpose() * r_ws,
            _ => Mat3::identity(),
        })
    })
}

/// Largest parallax `|x_k x R_ks x_s|` of a track against its first observation `s`, over the
/// other observations; `obs(k)` gives the delay-corrected observation at position `k`, `rel`
/// the window's [`relative_rotations`].
pub(super) fn max_parallax<const N: usize>(
    rel: &[[Mat3; N]; N],
    count: usize,
    s: usize,
    obs: impl Fn(usize) -> Option<Vec3>,
) -> Option<(usize, f64, Vec3)> {
    let x_s = obs(s)?;
    let mut best: Option<(usize, f64, Vec3)> = None;
    for (k, row) in rel.iter().enumerate().take(count) {
        if k == s {
            continue;
        }
        let Some(x_k) = obs(k) else { continue };
        let Some(r_ks) = row.get(s) else { continue };
        let theta = x_k.cross(&(r_ks * x_s)).norm();
        if theta.is_finite() && best.is_none_or(|(_, t, _)| theta > t) {
            best = Some((k, theta, x_k));
        }
    }
    best
}

/// The score of a track (see the module docs).
fn score(n_obs: usize, alive: bool, theta: f64, theta_ref: f64) -> f64 {
    let q = (theta / theta_ref).clamp(0.1, 1.0);
    (n_obs as f64 + if alive { 1.0 } else { 0.0 }) * q
}

/// A slot must be worth this much more than the landmark it replaces (one observation).
const SWAP_MARGIN: f64 = 1.0;

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    pub(super) fn window_cams(&self) -> [CameraPose; N] {
        let poses = self.window.poses();
        core::array::from_fn(|k| self.ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb))
    }

    /// Gives the landmark slots to the most informative tracks (module docs). Returns (promoted,
    /// evicted).
    // Not inlined: its candidate lists (about 20 kB) must not sit in the keyframe step's frame
    // during the solve.
    #[inline(never)]
    pub(super) fn select_landmarks(&mut self) -> (u32, u32) {
        let count = self.window.len();
        let Some(newest) = count.checked_sub(1).filter(|&n| n > 0) else {
            return (0, 0);
        };
        let rel = relative_rotations(&self.window_cams(), count);
        let theta_ref = self.cfg.slot_parallax_ref;
        let td = |k: usize| self.window.get(k).map_or(0.0, |kf| kf.td_s);
        let timed = |o: &KfObs, k: usize| {
            crate::factors::TimedObs {
                x_n: crate::camera::Vec2::new(o.x_n[0], o.x_n[1]),
                vel: crate::camera::Vec2::new(o.vel[0], o.vel[1]),
                td0: o.td0_s,
            }
            .corrected(td(k))
        };

        let mut cands: HVec<(u64, u8), MAX_FEATURES> = HVec::new();
        self.lms.candidates(&mut cands);
        if cands.is_empty() {
            return (0, 0);
        }
        let store = self.lms.store();
        let mut cs: HVec<(f64, u64), MAX_FEATURES> = HVec::new();
        for &(id, n) in cands.iter() {
            let first = (0..count).find(|&k| store.find(k, id).is_some());
            let theta = first
                .and_then(|s| {
                    max_parallax(&rel, count, s, |k| {
                        store.find(k, id).map(|o| timed(&o.obs, k))
                    })
                })
                .map_or(0.0, |(_, t, _)| t);
            let _ = cs.push((score(usize::from(n), true, theta, theta_ref), id));
        }
        let mut ls: HVec<(f64, u64), L> = HVec::new();
        for lm in self.lms.landmarks() {
            let alive = lm.obs.get(newest).is_some_and(|o| o.is_some());
            let theta = max_parallax(&rel, count, lm.anchor_s as usize, |k| {
                corrected_obs(lm, k, td(k))
            })
            .map_or(0.0, |(_, t, _)| t);
            let _ = ls.push((score(lm.n_obs(), alive, theta, theta_ref), lm.id));
        }
        // Best candidates first, worst landmarks first; ties by id so the order is total.
        cs.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        ls.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));

        let free = L.saturating_sub(self.lms.len());
        let mut evict: HVec<u64, L> = HVec::new();
        let mut take = free.min(cs.len());
        for (c, l) in cs.iter().skip(take).zip(ls.iter()) {
            if c.0 <= l.0 + SWAP_MARGIN {
                break;
            }
            let _ = evict.push(l.1);
            take += 1;
        }
        if !evict.is_empty() {
            self.lms.evict_ids(&evict);
        }
        let mut promoted = 0;
        for &(_, id) in cs.iter().take(take) {
            if self.lms.promote(id).is_ok() {
                promoted += 1;
            }
        }
        (promoted, evict.len() as u32)
    }
}

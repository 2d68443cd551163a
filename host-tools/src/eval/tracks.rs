//! Scores feature tracks from an image front end against the simulator's image truth.
//!
//! Every track is anchored at its first observation: the world point the front end started
//! tracking is what the anchor pixel shows. Each later observation is compared with where that
//! point truly is in its frame (`transfer(anchor frame, anchor pixel, frame)`, e.g.
//! [`ImageTruth::transfer`](crate::sim::render::truth::ImageTruth::transfer)), which measures
//! the accumulated drift; the step error compares each observation with the transfer of the
//! previous one (one frame of tracking). A track is wrong when an observation is more than
//! `wrong_px` from the truth or when the tracked point is no longer visible there (occluded or
//! out of view) while the front end still reports it.

use povins_platform::dataset::FeatureFrame;
use std::collections::HashMap;

/// Track accuracy figures.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TrackScore {
    /// Tracks with at least two observations (scored).
    pub tracks: usize,
    /// Observations after the anchor of the scored tracks.
    pub observations: usize,
    /// Observations compared with a truth (the others had their point hidden).
    pub compared: usize,
    /// Median error against the anchored truth over compared observations, px.
    pub median_px: f64,
    /// 90th percentile of the same, px.
    pub p90_px: f64,
    /// Median and 90th percentile over the observations of tracks that are not wrong, px.
    pub inlier_median_px: f64,
    /// See [`TrackScore::inlier_median_px`].
    pub inlier_p90_px: f64,
    /// Median frame-to-frame error (observation vs transfer of the previous observation), px.
    pub step_median_px: f64,
    /// 90th percentile of the same, px.
    pub step_p90_px: f64,
    /// Wrong tracks.
    pub wrong_tracks: usize,
    /// Wrong tracks / scored tracks.
    pub wrong_share: f64,
}

/// `q`-quantile (nearest rank) of unsorted values, NaN when empty.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

/// Scores `frames` (frame `i` of the slice is frame `i` of the truth) with
/// `transfer(from_frame, pixel, to_frame)`.
pub fn score_tracks(
    frames: &[FeatureFrame],
    transfer: impl Fn(usize, [f64; 2], usize) -> Option<[f64; 2]>,
    wrong_px: f64,
) -> TrackScore {
    // id -> observations (frame, pixel) in frame order.
    let mut tracks: HashMap<u64, Vec<(usize, [f64; 2])>> = HashMap::new();
    for (i, f) in frames.iter().enumerate() {
        for o in &f.obs {
            tracks.entry(o.id).or_default().push((i, [o.u_px, o.v_px]));
        }
    }
    let mut ids: Vec<u64> = tracks.keys().copied().collect();
    ids.sort_unstable();
    let (mut all, mut inliers, mut steps) = (Vec::new(), Vec::new(), Vec::new());
    let (mut scored, mut observations, mut wrong) = (0, 0, 0);
    for id in ids {
        let obs = &tracks[&id];
        if obs.len() < 2 {
            continue;
        }
        scored += 1;
        let (i0, uv0) = obs[0];
        let mut errs = Vec::with_capacity(obs.len() - 1);
        let mut bad = false;
        for (k, &(j, uv)) in obs.iter().enumerate().skip(1) {
            observations += 1;
            let dist = |t: [f64; 2]| ((uv[0] - t[0]).powi(2) + (uv[1] - t[1]).powi(2)).sqrt();
            match transfer(i0, uv0, j) {
                Some(t) => {
                    let e = dist(t);
                    bad |= e > wrong_px;
                    errs.push(e);
                }
                None => bad = true,
            }
            let (ip, uvp) = obs[k - 1];
            if let Some(t) = transfer(ip, uvp, j) {
                steps.push(dist(t));
            }
        }
        wrong += usize::from(bad);
        if !bad {
            inliers.extend_from_slice(&errs);
        }
        all.extend(errs);
    }
    TrackScore {
        tracks: scored,
        observations,
        compared: all.len(),
        median_px: quantile(&mut all, 0.5),
        p90_px: quantile(&mut all, 0.9),
        inlier_median_px: quantile(&mut inliers, 0.5),
        inlier_p90_px: quantile(&mut inliers, 0.9),
        step_median_px: quantile(&mut steps, 0.5),
        step_p90_px: quantile(&mut steps, 0.9),
        wrong_tracks: wrong,
        wrong_share: wrong as f64 / scored.max(1) as f64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::FeatureObs;

    /// Truth: the image moves 3 px right per frame; nothing is visible beyond u = 500.
    fn shift(i: usize, uv: [f64; 2], j: usize) -> Option<[f64; 2]> {
        let u = uv[0] + 3.0 * (j as f64 - i as f64);
        (u < 500.0).then_some([u, uv[1]])
    }

    #[test]
    fn errors_and_wrong_tracks_are_counted() {
        // 10 frames; tracks 1..=8 follow the truth with a 0.1 px error in u from frame 1 on;
        // track 9 jumps 5 px at frame 4 (wrong); track 10 leaves the visible area (wrong:
        // reported where the point is hidden); track 11 has one observation (not scored).
        let mut frames: Vec<FeatureFrame> = (0..10)
            .map(|i| FeatureFrame {
                t_ns: i as i64,
                obs: Vec::new(),
            })
            .collect();
        for (i, f) in frames.iter_mut().enumerate() {
            let e = if i == 0 { 0.0 } else { 0.1 };
            for id in 1..=8u64 {
                f.obs.push(FeatureObs {
                    id,
                    u_px: 10.0 * id as f64 + 3.0 * i as f64 + e,
                    v_px: 7.0,
                });
            }
            f.obs.push(FeatureObs {
                id: 9,
                u_px: 200.0 + 3.0 * i as f64 + if i >= 4 { 5.0 } else { 0.0 },
                v_px: 9.0,
            });
            f.obs.push(FeatureObs {
                id: 10,
                u_px: 490.0 + 3.0 * i as f64,
                v_px: 9.0,
            });
        }
        frames[3].obs.push(FeatureObs {
            id: 11,
            u_px: 1.0,
            v_px: 1.0,
        });
        let s = score_tracks(&frames, shift, 2.0);
        assert_eq!(s.tracks, 10);
        assert_eq!(s.observations, 90);
        assert_eq!(s.wrong_tracks, 2);
        assert!((s.wrong_share - 0.2).abs() < 1e-12);
        // Track 10 is visible at frames 1..=3 only (u = 493, 496, 499).
        assert_eq!(s.compared, 90 - 6);
        assert!((s.inlier_median_px - 0.1).abs() < 1e-9);
        assert!((s.inlier_p90_px - 0.1).abs() < 1e-9);
        assert!((s.median_px - 0.1).abs() < 1e-9);
        // Steps: 0.1 px for the first step, 0 after; track 9's jump is one 5 px step.
        assert!(s.step_median_px.abs() < 1e-9);
        assert!((s.p90_px - 0.1).abs() < 1e-9);
        // Make the trackers perfect: every figure drops to zero.
        for f in &mut frames {
            for o in &mut f.obs {
                if o.id <= 8 {
                    o.u_px = 10.0 * o.id as f64 + 3.0 * f.t_ns as f64;
                }
            }
        }
        let s = score_tracks(&frames, shift, 2.0);
        assert_eq!(s.inlier_p90_px, 0.0);
        assert_eq!(s.wrong_tracks, 2);
    }
}

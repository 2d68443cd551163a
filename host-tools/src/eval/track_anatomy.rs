//! Scoring a front end's tracks against a simulation's truth (what `povins score-tracks` runs):
//! the tracks against the true motion of every pixel ([`crate::eval::tracks::score_tracks`]), and
//! the anatomy of the wrong ones (where their anchor sits, how the error grows with age).

use crate::eval::tracks::{score_tracks, TrackScore};
use crate::sim::render::truth::ImageTruth;
use crate::sim::{self, SimConfig};
use anyhow::{bail, Context, Result};
use povins_core::camera::FeatureObs;
use povins_platform::dataset::FeatureFrame;
use std::collections::BTreeMap;
use std::path::Path;

/// Why tracks are wrong, and how the anchored error grows with the age of a track.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TrackAnatomy {
    /// Wrong tracks whose point is hidden (occluded, out of view, sky) at some reported frame.
    pub hidden: usize,
    /// Of those, hidden already at the first frame after the anchor.
    pub hidden_at_once: usize,
    /// Wrong tracks only because of an error above the threshold.
    pub off: usize,
    /// Of those, off by more than the threshold already at the first step.
    pub off_at_once: usize,
    /// Tracks that jump: an observation more than [`JUMP_PX`] from the truth's transfer of
    /// the previous observation (a step to another point, not drift).
    pub jumped: usize,
    /// Tracks that are hidden while reported or jump: wrong tracks in the strict sense.
    pub hidden_or_jumped: usize,
    /// Tracks scored (two or more observations).
    pub tracks: usize,
    /// `(age in frames, observations, median, p90 px)` of the anchored error.
    pub by_age: Vec<(usize, usize, f64, f64)>,
    /// Cause of the hidden-or-jumped tracks by where the track started: `[anchor class]` with
    /// classes [`ANCHOR_CLASSES`] (surface, depth edge, sky) and counts `[all tracks, hidden at
    /// the first step, hidden later, jumped while visible]`.
    pub causes: [[usize; 4]; 3],
    /// Tracks anchored on the sky ([`ANCHOR_CLASSES`] 2) that do follow a surface point: every
    /// later observation within the threshold of the truth transferred from the nearest
    /// non-sky pixel of the anchor (within 2 px), which then stays visible. The others of that
    /// class slide or are hidden from there too.
    pub sky_following: usize,
    /// Mean observations per scored track.
    pub mean_length: f64,
    /// Scored tracks with at least 5 / 10 / 30 observations.
    pub long_tracks: [usize; 3],
}

/// Names of the anchor classes of [`TrackAnatomy::causes`]: the anchor pixel's 7x7
/// neighbourhood is on one surface (depths within 5%), straddles a depth edge (depths differ by
/// more, or part of it is sky), or the anchor pixel itself shows the sky.
pub const ANCHOR_CLASSES: [&str; 3] = ["one surface", "depth edge", "sky at the anchor"];

/// Anchor class (index into [`ANCHOR_CLASSES`]) from `depth(du, dv)`, the distance along the
/// ray of the pixel `(du, dv)` from the anchor (`None`: sky).
pub fn anchor_class(depth: impl Fn(i32, i32) -> Option<f64>) -> usize {
    if depth(0, 0).is_none() {
        return 2;
    }
    let (mut lo, mut hi, mut sky) = (f64::INFINITY, 0.0f64, false);
    for dv in -3..=3 {
        for du in -3..=3 {
            match depth(du, dv) {
                Some(d) => {
                    lo = lo.min(d);
                    hi = hi.max(d);
                }
                None => sky = true,
            }
        }
    }
    usize::from(sky || hi > 1.05 * lo)
}

/// A frame-to-frame error above this is a jump to another point, px.
pub const JUMP_PX: f64 = 1.0;

/// See [`TrackAnatomy`].
pub fn anatomy(
    frames: &[FeatureFrame],
    transfer: impl Fn(usize, [f64; 2], usize) -> Option<[f64; 2]>,
    classify: impl Fn(usize, [f64; 2]) -> usize,
    surface_near: impl Fn(usize, [f64; 2]) -> Option<[f64; 2]>,
    wrong_px: f64,
) -> TrackAnatomy {
    let mut tracks: BTreeMap<u64, Vec<(usize, [f64; 2])>> = BTreeMap::new();
    for (i, f) in frames.iter().enumerate() {
        for o in &f.obs {
            tracks.entry(o.id).or_default().push((i, [o.u_px, o.v_px]));
        }
    }
    let edges = [1usize, 2, 5, 10, 20, 50, 100, usize::MAX];
    let mut errs: Vec<Vec<f64>> = vec![Vec::new(); edges.len()];
    let mut a = TrackAnatomy::default();
    for obs in tracks.values().filter(|o| o.len() >= 2) {
        a.tracks += 1;
        let (i0, uv0) = obs[0];
        let (mut hidden, mut off, mut jump) = (None, None, false);
        for (k, &(j, uv)) in obs.iter().enumerate().skip(1) {
            let (ip, uvp) = obs[k - 1];
            if let Some(t) = transfer(ip, uvp, j) {
                jump |= ((uv[0] - t[0]).powi(2) + (uv[1] - t[1]).powi(2)).sqrt() > JUMP_PX;
            }
            match transfer(i0, uv0, j) {
                Some(t) => {
                    let e = ((uv[0] - t[0]).powi(2) + (uv[1] - t[1]).powi(2)).sqrt();
                    if e > wrong_px && off.is_none() {
                        off = Some(k);
                    }
                    let b = edges
                        .iter()
                        .position(|&x| k <= x)
                        .unwrap_or(edges.len() - 1);
                    errs[b].push(e);
                }
                None => {
                    if hidden.is_none() {
                        hidden = Some(k);
                    }
                }
            }
        }
        a.jumped += usize::from(jump);
        a.hidden_or_jumped += usize::from(jump || hidden.is_some());
        let len = obs.len();
        for (n, min) in a.long_tracks.iter_mut().zip([5, 10, 30]) {
            *n += usize::from(len >= min);
        }
        a.mean_length += len as f64;
        let class = classify(i0, uv0).min(2);
        if class == 2 {
            let follows = surface_near(i0, uv0).is_some_and(|alt| {
                obs.iter().skip(1).all(|&(j, uv)| {
                    transfer(i0, alt, j).is_some_and(|t| {
                        ((uv[0] - t[0]).powi(2) + (uv[1] - t[1]).powi(2)).sqrt() <= wrong_px
                    })
                })
            });
            a.sky_following += usize::from(follows);
        }
        let c = &mut a.causes[class];
        c[0] += 1;
        match hidden {
            Some(1) => c[1] += 1,
            Some(_) => c[2] += 1,
            None if jump => c[3] += 1,
            None => {}
        }
        if let Some(k) = hidden {
            a.hidden += 1;
            a.hidden_at_once += usize::from(k == 1);
        } else if let Some(k) = off {
            a.off += 1;
            a.off_at_once += usize::from(k == 1);
        }
    }
    a.mean_length /= a.tracks.max(1) as f64;
    for (b, v) in errs.iter_mut().enumerate() {
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        a.by_age.push((edges[b], v.len(), q(0.5), q(0.9)));
    }
    a
}

/// Reads a `features0` CSV into frames (rows of a frame consecutive, frames in time order).
pub fn read_features_csv(path: &Path) -> Result<Vec<FeatureFrame>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut by_t: BTreeMap<i64, Vec<FeatureObs>> = BTreeMap::new();
    for (k, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        let bad = || format!("{}:{}: expected t_ns,id,u,v", path.display(), k + 1);
        if f.len() != 4 {
            bail!(bad());
        }
        let t: i64 = f[0].parse().with_context(bad)?;
        by_t.entry(t).or_default().push(FeatureObs {
            id: f[1].parse().with_context(bad)?,
            u_px: f[2].parse().with_context(bad)?,
            v_px: f[3].parse().with_context(bad)?,
        });
    }
    Ok(by_t
        .into_iter()
        .map(|(t_ns, obs)| FeatureFrame { t_ns, obs })
        .collect())
}

/// Scores `tracks` against the simulation `cfg` rebuilds: returns the score, the number of
/// track frames whose stamp is not a camera frame of the simulation (not scored) and the
/// anatomy of the errors.
pub fn score_against_simulation(
    cfg: &SimConfig,
    tracks: &[FeatureFrame],
    wrong_px: f64,
) -> Result<(TrackScore, usize, TrackAnatomy)> {
    let out = sim::simulate(cfg, &|_, _, _| {})?;
    let truth = ImageTruth::new(&out);
    let mut frames: Vec<FeatureFrame> = truth
        .stamps()
        .iter()
        .map(|&t_ns| FeatureFrame {
            t_ns,
            obs: Vec::new(),
        })
        .collect();
    let mut unmatched = 0;
    for f in tracks {
        match truth.frame_at(f.t_ns).and_then(|i| frames.get_mut(i)) {
            Some(slot) => slot.obs.clone_from(&f.obs),
            None => unmatched += 1,
        }
    }
    let score = score_tracks(&frames, |i, uv, j| truth.transfer(i, uv, j), wrong_px);
    let classify = |i: usize, uv: [f64; 2]| {
        anchor_class(|du, dv| {
            let v = truth.view(i)?;
            let (p, _) = truth.surface_point(i, [uv[0] + f64::from(du), uv[1] + f64::from(dv)])?;
            Some((p - v.o_w).norm())
        })
    };
    // The nearest pixel (in steps of 0.5 px, up to 2 px) that shows a surface.
    let surface_near = |i: usize, uv: [f64; 2]| {
        let mut best: Option<(f64, [f64; 2])> = None;
        for dv in -4..=4 {
            for du in -4..=4 {
                let d = [0.5 * f64::from(du), 0.5 * f64::from(dv)];
                let r2 = d[0] * d[0] + d[1] * d[1];
                let p = [uv[0] + d[0], uv[1] + d[1]];
                if best.is_none_or(|b| r2 < b.0) && truth.surface_point(i, p).is_some() {
                    best = Some((r2, p));
                }
            }
        }
        best.map(|b| b.1)
    };
    let detail = anatomy(
        &frames,
        |i, uv, j| truth.transfer(i, uv, j),
        classify,
        surface_near,
        wrong_px,
    );
    Ok((score, unmatched, detail))
}

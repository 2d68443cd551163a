//! `povins score-tracks --tracks FILE --scenario S --seed N --duration D`: scores feature tracks
//! (a `features0` CSV, e.g. from `povins track` on a simulated sequence) against the true motion
//! of every pixel. The simulation is deterministic, so the world and trajectory are rebuilt from
//! the scenario, seed, duration, rest time and delay the sequence was simulated with, and
//! [`ImageTruth`] transfers each tracked pixel ([`score_tracks`]: error against the truth
//! anchored at the track's first observation, frame-to-frame error, wrong tracks).

use crate::eval::tracks::{score_tracks, TrackScore};
use crate::sim::render::truth::ImageTruth;
use crate::sim::{self, Scenario, SimConfig};
use anyhow::{bail, Context, Result};
use povins_core::camera::FeatureObs;
use povins_platform::dataset::FeatureFrame;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Arguments of `povins score-tracks`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Tracks to score: a `features0` CSV (`#timestamp [ns],feature_id,u [px],v [px]`).
    #[arg(long)]
    pub tracks: PathBuf,
    /// Scenario the sequence was simulated with.
    #[arg(long, value_enum)]
    pub scenario: Scenario,
    /// Seed it was simulated with.
    #[arg(long)]
    pub seed: u64,
    /// Duration it was simulated with, s.
    #[arg(long)]
    pub duration: f64,
    /// Rest time it was simulated with, s.
    #[arg(long, default_value_t = 1.0)]
    pub static_s: f64,
    /// Camera-IMU delay it was simulated with, ms.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub td_ms: f64,
    /// A track is wrong when an observation is farther than this from the truth, px.
    #[arg(long, default_value_t = 2.0)]
    pub wrong_px: f64,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also print the anatomy of the wrong tracks and the error by track age.
    #[arg(long)]
    pub detail: bool,
}

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
}

/// A frame-to-frame error above this is a jump to another point, px.
pub const JUMP_PX: f64 = 1.0;

/// See [`TrackAnatomy`].
pub fn anatomy(
    frames: &[FeatureFrame],
    transfer: impl Fn(usize, [f64; 2], usize) -> Option<[f64; 2]>,
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
        if let Some(k) = hidden {
            a.hidden += 1;
            a.hidden_at_once += usize::from(k == 1);
        } else if let Some(k) = off {
            a.off += 1;
            a.off_at_once += usize::from(k == 1);
        }
    }
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
    let detail = anatomy(&frames, |i, uv, j| truth.transfer(i, uv, j), wrong_px);
    Ok((score, unmatched, detail))
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let tracks = read_features_csv(&args.tracks)?;
    let mut cfg = SimConfig::new(args.scenario, args.seed, args.duration);
    cfg.static_s = args.static_s;
    cfg.td_s = args.td_ms * 1e-3;
    // The LiDAR does not change the world, the trajectory or the camera stamps.
    cfg.lidar_points = Some(100);
    let (s, unmatched, detail) = score_against_simulation(&cfg, &tracks, args.wrong_px)?;
    if unmatched == tracks.len() && !tracks.is_empty() {
        bail!(
            "none of the {} track frames is a camera frame of {} seed {} ({} s): wrong scenario, \
             seed, duration, rest time or delay?",
            tracks.len(),
            args.scenario.name(),
            args.seed,
            args.duration
        );
    }
    if args.json {
        let v = serde_json::json!({ "score": s, "anatomy": detail, "unmatched_frames": unmatched });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{} seed {}: {} tracks, {} observations ({} compared with the truth; {} frames not in the simulation)",
        args.scenario.name(),
        args.seed,
        s.tracks,
        s.observations,
        s.compared,
        unmatched
    );
    println!(
        "error vs the truth from the track's start: median {:.3} px, p90 {:.3} px (tracks not wrong: {:.3} / {:.3} px)",
        s.median_px, s.p90_px, s.inlier_median_px, s.inlier_p90_px
    );
    println!(
        "frame-to-frame error: median {:.3} px, p90 {:.3} px",
        s.step_median_px, s.step_p90_px
    );
    println!(
        "wrong tracks (an observation > {} px off or hidden): {} ({:.2}%)",
        args.wrong_px,
        s.wrong_tracks,
        100.0 * s.wrong_share
    );
    if args.detail {
        println!(
            "  hidden while reported: {} ({} at the first step); off by > {} px: {} ({} at the first step)",
            detail.hidden, detail.hidden_at_once, args.wrong_px, detail.off, detail.off_at_once
        );
        println!(
            "  jumped (a step > {JUMP_PX} px from the truth): {}; hidden or jumped: {} ({:.2}% of {})",
            detail.jumped,
            detail.hidden_or_jumped,
            100.0 * detail.hidden_or_jumped as f64 / detail.tracks.max(1) as f64,
            detail.tracks
        );
        for (age, n, med, p90) in &detail.by_age {
            let age = if *age == usize::MAX {
                "older".to_string()
            } else {
                format!("<= {age}")
            };
            println!(
                "  age {age:>6} frames: {n:>6} observations, median {med:.3} px, p90 {p90:.3} px"
            );
        }
    }
    Ok(())
}

//! `povins score-tracks --tracks FILE --scenario S --seed N --duration D`: scores feature tracks
//! (a `features0` CSV, e.g. from `povins track` on a simulated sequence) against the true motion
//! of every pixel. The simulation is deterministic, so the world and trajectory are rebuilt from
//! the scenario, seed, duration, rest time and delay the sequence was simulated with, and
//! [`ImageTruth`] transfers each tracked pixel ([`score_tracks`]: error against the truth
//! anchored at the track's first observation, frame-to-frame error, wrong tracks).

use crate::eval::track_anatomy::{
    read_features_csv, score_against_simulation, ANCHOR_CLASSES, JUMP_PX,
};
use crate::sim::{Scenario, SimConfig};
use anyhow::{bail, Result};
use std::path::PathBuf;

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
        println!(
            "  mean length {:.1} observations; tracks >= 5 / 10 / 30: {} / {} / {}",
            detail.mean_length, detail.long_tracks[0], detail.long_tracks[1], detail.long_tracks[2]
        );
        for (name, c) in ANCHOR_CLASSES.iter().zip(detail.causes.iter()) {
            println!(
                "  anchored on {name}: {} tracks; hidden at the first step {}, hidden later {}, jumped while visible {}",
                c[0], c[1], c[2], c[3]
            );
        }
        println!(
            "  of the sky-anchored, following the nearest surface pixel (within {} px throughout): {}",
            args.wrong_px, detail.sky_following
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

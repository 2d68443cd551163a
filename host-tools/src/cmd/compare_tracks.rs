//! `povins compare-tracks DATASET --tracks A.csv --tracks B.csv`: compares feature tracks of
//! different front ends on the same real images, without ground truth: features and tracks per
//! image, track lengths, and the steps that violate the epipolar constraint of the gyro rotation
//! ([`crate::eval::epipolar`]). Tracks are `features0` CSVs (`povins track` writes them; OpenCV's
//! with `scripts/opencv_tracks.py`).

use crate::eval::epipolar::{check, EpipolarReport, THRESHOLDS_PX};
use crate::eval::track_anatomy::read_features_csv;
use crate::track::track_lengths;
use anyhow::{bail, Result};
use povins_platform::dataset::FeatureFrame;
use std::collections::HashSet;
use std::path::PathBuf;

/// Arguments of `povins compare-tracks`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The dataset the tracks come from (its IMU and calibration).
    pub dataset: PathBuf,
    /// Track files (`features0` CSV), one per front end.
    #[arg(long, required = true)]
    pub tracks: Vec<PathBuf>,
    /// Camera-IMU delay for the gyro rotation, ms (default: the dataset's calibration).
    #[arg(long, allow_hyphen_values = true)]
    pub td_ms: Option<f64>,
    /// Only the first N images of each file.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Figures of one track file.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TrackFigures {
    /// The file.
    pub file: String,
    /// Images.
    pub frames: usize,
    /// Mean features per image.
    pub features_per_frame: f64,
    /// Mean features per image that continue a track of the previous image.
    pub tracked_per_frame: f64,
    /// Tracks (ids).
    pub tracks: usize,
    /// Mean observations per track.
    pub mean_length: f64,
    /// Mean observations per track, tracks seen at least twice.
    pub mean_length_2plus: f64,
    /// Tracks seen in at least 10 / 30 images.
    pub tracks_10plus: usize,
    /// See `tracks_10plus`.
    pub tracks_30plus: usize,
    /// The epipolar check.
    pub epipolar: EpipolarReport,
}

/// Computes the figures of `frames`.
pub fn figures(file: String, frames: &[FeatureFrame], epipolar: EpipolarReport) -> TrackFigures {
    let n = frames.len().max(1) as f64;
    let mut tracked = 0usize;
    for w in frames.windows(2) {
        let prev: HashSet<u64> = w[0].obs.iter().map(|o| o.id).collect();
        tracked += w[1].obs.iter().filter(|o| prev.contains(&o.id)).count();
    }
    let lengths = track_lengths(frames);
    let multi: Vec<usize> = lengths.iter().copied().filter(|&l| l >= 2).collect();
    let mean = |v: &[usize]| v.iter().sum::<usize>() as f64 / v.len().max(1) as f64;
    TrackFigures {
        file,
        frames: frames.len(),
        features_per_frame: frames.iter().map(|f| f.obs.len()).sum::<usize>() as f64 / n,
        tracked_per_frame: tracked as f64 / (frames.len().max(2) - 1) as f64,
        tracks: lengths.len(),
        mean_length: mean(&lengths),
        mean_length_2plus: mean(&multi),
        tracks_10plus: lengths.iter().filter(|&&l| l >= 10).count(),
        tracks_30plus: lengths.iter().filter(|&&l| l >= 30).count(),
        epipolar,
    }
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let ds = povins_platform::read_dataset(&args.dataset)?;
    if ds.imu.is_empty() {
        bail!("{}: no IMU samples for the gyro rotation", ds.name);
    }
    let td_s = args.td_ms.map_or(ds.calib.td_s, |ms| ms * 1e-3);
    let r_bc = ds.calib.t_bc.q_ab.to_rotation_matrix().into_inner();
    let mut rows = Vec::new();
    for path in &args.tracks {
        let mut frames = read_features_csv(path)?;
        if let Some(n) = args.frames {
            frames.truncate(n);
        }
        let ep = check(&frames, &ds.imu, &ds.calib.camera, &r_bc, td_s);
        rows.push(figures(path.display().to_string(), &frames, ep));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "{} (td {:.1} ms): epipolar violations are steps farther than {:?} px from the line of \
         the gyro rotation",
        ds.name,
        td_s * 1e3,
        THRESHOLDS_PX
    );
    println!(
        "| tracks | images | features/image | tracked/image | tracks | mean length (>= 2) | tracks >= 10 / >= 30 images | steps | violating steps 1 / 2 / 4 px | tracks violating at 2 px | median px |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        let e = &r.epipolar;
        println!(
            "| {} | {} | {:.1} | {:.1} | {} | {:.1} ({:.1}) | {} / {} | {} | {:.2}% / {:.2}% / {:.2}% | {:.1}% | {:.3} |",
            r.file,
            r.frames,
            r.features_per_frame,
            r.tracked_per_frame,
            r.tracks,
            r.mean_length,
            r.mean_length_2plus,
            r.tracks_10plus,
            r.tracks_30plus,
            e.steps,
            100.0 * e.step_share(0),
            100.0 * e.step_share(1),
            100.0 * e.step_share(2),
            100.0 * e.track_share(1),
            e.median_px
        );
    }
    Ok(())
}

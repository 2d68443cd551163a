//! `povins track DATASET --out DIR`: the image front end alone (no estimator) on a dataset's
//! camera images, seeded by the gyro rotation between images (integrated from the dataset's IMU
//! with the camera-IMU rotation and delay of its calibration, no bias). Writes
//! - `features0.csv`: the tracks in the EuRoC `features0` layout (`#timestamp [ns],feature_id,u
//!   [px],v [px]`, raw pixels; copy it to `mav0/features0/data.csv` to replay the tracks);
//! - `frames.csv`: per image, the tracks, the losses by reason, new corners and the time;
//! - `frame_<ns>.png`: a few images with the tracks drawn (trails over the last frames,
//!   coloured by age) and `track_lengths.svg`, the histogram of track lengths;
//! - `summary.json`; the summary is printed too.

use crate::frontend_stats::{summarize_frames, summary_lines, write_frames_csv};
use crate::progress::Progress;
use crate::runner::{percentile, InitMode};
use crate::setup::RunSetup;
use crate::track::{track_dataset, track_lengths, write_features_csv, TrackOptions, TrackSummary};
use crate::track_pictures::draw_length_histogram;
use anyhow::{bail, Context, Result};
use std::path::PathBuf;

/// Arguments of `povins track`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// EuRoC ASL folder with `cam0/data/*.png`, or an `.mcap` file with camera images.
    pub dataset: PathBuf,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML file whose `[frontend]` section sets the tracker (see docs/formats.md).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Camera-IMU delay for the gyro rotation, ms (`t_imu = t_cam + td`; default: the dataset's
    /// calibration).
    #[arg(long, allow_hyphen_values = true)]
    pub td_ms: Option<f64>,
    /// Do not seed with the gyro rotation (and no 2-point RANSAC).
    #[arg(long)]
    pub no_gyro: bool,
    /// First image (index into the dataset's images).
    #[arg(long, default_value_t = 0)]
    pub start: usize,
    /// Images to process (default: all).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Images drawn with their tracks (evenly spaced).
    #[arg(long, default_value_t = 6)]
    pub pictures: usize,
}
/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let rec = povins_platform::open_recording(&args.dataset)?;
    let ds = &*rec;
    let mut setup = RunSetup::defaults(ds, InitMode::Static);
    if let Some(path) = &args.config {
        setup.apply_file(path)?;
    }
    let fe = setup.frontend;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let td_s = args.td_ms.map_or(ds.calibration().td_s, |ms| ms * 1e-3);
    if !td_s.is_finite() || td_s.abs() > 1.0 {
        bail!("--td-ms must be within +-1000 ms");
    }
    let end = args
        .frames
        .map_or(usize::MAX, |n| args.start.saturating_add(n));
    let opts = TrackOptions {
        tracker: fe.tracker,
        gyro: fe.aiding.gyro_rotation && !args.no_gyro,
        td_s,
        range: args.start..end,
        pictures: Some((args.out.clone(), args.pictures)),
    };
    let progress = Progress::new(0, "track");
    let out = track_dataset(ds, &opts, &progress)?;
    for (t, e) in out.errors.iter().take(20) {
        eprintln!("warning: image at {t} ns: {e}");
    }
    write_features_csv(&args.out.join("features0.csv"), &out.frames)?;
    write_frames_csv(&args.out.join("frames.csv"), &out.logs)?;
    let lengths = track_lengths(&out.frames);
    let lf: Vec<f64> = lengths.iter().map(|&l| l as f64).collect();
    let multi: Vec<f64> = lf.iter().copied().filter(|&l| l >= 2.0).collect();
    let mean = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let summary = TrackSummary {
        dataset: ds.name().to_string(),
        width: ds.calibration().camera.width,
        height: ds.calibration().camera.height,
        gyro: opts.gyro,
        td_ms: td_s * 1e3,
        frontend: summarize_frames(&out.logs),
        tracks: lengths.len(),
        track_length_mean: mean(&lf),
        track_length_median: percentile(&lf, 50.0),
        track_length_p90: percentile(&lf, 90.0),
        track_length_mean_2plus: mean(&multi),
        image_errors: out.errors.len(),
    };
    draw_length_histogram(
        &args.out.join("track_lengths.svg"),
        &lengths,
        &format!(
            "{}: {} tracks, mean length {:.1} frames (median {:.0})",
            ds.name(),
            summary.tracks,
            summary.track_length_mean,
            summary.track_length_median
        ),
    )?;
    std::fs::write(
        args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)? + "\n",
    )?;
    println!(
        "dataset   {} ({}x{}, gyro seeding {}, td {:.1} ms)",
        summary.dataset,
        summary.width,
        summary.height,
        if summary.gyro { "on" } else { "off" },
        summary.td_ms
    );
    if let Some(fe) = &summary.frontend {
        for line in summary_lines(fe) {
            println!("{line}");
        }
    }
    println!(
        "lengths   {} tracks: mean {:.1}, median {:.0}, p90 {:.0} images ({:.1} mean over tracks seen twice or more)",
        summary.tracks,
        summary.track_length_mean,
        summary.track_length_median,
        summary.track_length_p90,
        summary.track_length_mean_2plus
    );
    if !out.errors.is_empty() {
        println!("images    {} could not be used", out.errors.len());
    }
    println!(
        "output    {} (features0.csv, frames.csv, {} pictures, track_lengths.svg)",
        args.out.display(),
        out.pictures.len()
    );
    Ok(())
}

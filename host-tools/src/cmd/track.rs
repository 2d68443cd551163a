//! `povins track DATASET --out DIR`: the image front end alone (no estimator) on a dataset's
//! camera images, seeded by the gyro rotation between images (integrated from the dataset's IMU
//! with the camera-IMU rotation and delay of its calibration, no bias). Writes
//! - `features0.csv`: the tracks in the EuRoC `features0` layout (`#timestamp [ns],feature_id,u
//!   [px],v [px]`, raw pixels; copy it to `mav0/features0/data.csv` to replay the tracks);
//! - `frames.csv`: per image, the tracks, the losses by reason, new corners and the time;
//! - `frame_<ns>.png`: a few images with the tracks drawn (trails over the last frames,
//!   coloured by age) and `track_lengths.svg`, the histogram of track lengths;
//! - `summary.json`; the summary is printed too.

use crate::cmd::run::{frontend_options, load_dataset};
use crate::frontend_stats::{summarize_frames, summary_lines, write_frames_csv, FrontendSummary};
use crate::images::with_images;
use crate::progress::Progress;
use crate::runner::{percentile, FrameLog};
use crate::track_pictures::{draw_frame, draw_length_histogram, DrawnTrack};
use anyhow::{bail, Context, Result};
use povins_core::camera::PinholeCamera;
use povins_core::frontend::image::{
    EurocTracker, FeatureTracker, HdTracker, ImageView, TrackHints, TrackerConfig,
};
use povins_core::math::{Mat3, Vec3};
use povins_core::vio::{GyroIntegrator, ImageReport, GYRO_SAMPLES};
use povins_platform::boxed::boxed_tracker;
use povins_platform::dataset::FeatureFrame;
use povins_platform::Dataset;
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

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

/// What a front-end pass produced.
#[derive(Debug, Clone, Default)]
pub struct TrackOutput {
    /// Tracks per image, as `features0` rows.
    pub frames: Vec<FeatureFrame>,
    /// Per-image statistics.
    pub logs: Vec<FrameLog>,
    /// Images that could not be used, with the reason.
    pub errors: Vec<(i64, String)>,
    /// Pictures written.
    pub pictures: Vec<PathBuf>,
}

/// Settings of a front-end pass.
#[derive(Debug, Clone)]
pub struct TrackOptions {
    /// The tracker.
    pub tracker: TrackerConfig,
    /// Seed with the gyro rotation.
    pub gyro: bool,
    /// Camera-IMU delay, s.
    pub td_s: f64,
    /// Images to process: `start..end` of the dataset's images.
    pub range: std::ops::Range<usize>,
    /// Where to draw pictures (`None`: none) and how many.
    pub pictures: Option<(PathBuf, usize)>,
}

/// Runs the front end alone over `ds`'s images (see the module docs).
pub fn track_dataset(
    ds: &Dataset,
    opts: &TrackOptions,
    progress: &Progress,
) -> Result<TrackOutput> {
    if ds.images.is_empty() {
        bail!(
            "{}: the dataset has no camera images (EuRoC cam0/data.csv with cam0/data/*.png, \
             MCAP /cam0/image_raw or /cam0/image_raw/compressed)",
            ds.name
        );
    }
    let cam = ds.calib.camera;
    let (w, h) = (cam.width, cam.height);
    if w <= 752 && h <= 480 {
        let mut t: Box<EurocTracker> = boxed_tracker(opts.tracker)
            .map_err(|e| anyhow::anyhow!("invalid front-end settings: {e}"))?;
        run_tracker(&mut t, ds, opts, progress)
    } else if w <= 1280 && h <= 720 {
        let mut t: Box<HdTracker> = boxed_tracker(opts.tracker)
            .map_err(|e| anyhow::anyhow!("invalid front-end settings: {e}"))?;
        run_tracker(&mut t, ds, opts, progress)
    } else {
        bail!(
            "{}: {w}x{h} images are larger than the front end's largest capacity (1280x720)",
            ds.name
        )
    }
}

fn run_tracker<const F: usize, const B: usize, const LV: usize>(
    tracker: &mut FeatureTracker<F, B, LV>,
    ds: &Dataset,
    opts: &TrackOptions,
    progress: &Progress,
) -> Result<TrackOutput> {
    let cam: PinholeCamera = ds.calib.camera;
    let r_bc: Mat3 = ds.calib.t_bc.q_ab.to_rotation_matrix().into_inner();
    let end = opts.range.end.min(ds.images.len());
    let start = opts.range.start.min(end);
    let images = &ds.images[start..end];
    let n = images.len();
    let picture_at: Vec<usize> = match &opts.pictures {
        Some((_, p)) if *p > 0 && n > 0 => (1..=*p).map(|i| i * n / (*p + 1)).collect(),
        _ => Vec::new(),
    };
    let mut gyro: Box<GyroIntegrator<GYRO_SAMPLES>> = Box::new(GyroIntegrator::new());
    let mut imu_k = 0usize;
    let mut prev_t: Option<i64> = None;
    let mut out = TrackOutput::default();
    let mut trails: HashMap<u64, Vec<[f64; 2]>> = HashMap::new();
    with_images(images, |stream| -> Result<()> {
        for im in stream {
            progress.set_position(im.index as u64);
            // The IMU up to the image's stamp, as a live system has it.
            while let Some(s) = ds.imu.get(imu_k).filter(|s| s.t_ns <= im.t_ns) {
                gyro.push(s.t_ns, &s.gyro_rps);
                imu_k += 1;
            }
            let (iw, ih, px) = match &im.pixels {
                Ok(p) => p,
                Err(e) => {
                    out.errors.push((im.t_ns, e.clone()));
                    continue;
                }
            };
            let view = match ImageView::new(px, *iw, *ih, *iw) {
                Ok(v) => v,
                Err(e) => {
                    out.errors.push((im.t_ns, format!("{iw}x{ih} image: {e}")));
                    continue;
                }
            };
            let t0 = Instant::now();
            let rotation = match prev_t {
                Some(p) if opts.gyro => {
                    gyro.camera_rotation(p, im.t_ns, opts.td_s, &Vec3::zeros(), &r_bc)
                }
                _ => None,
            };
            let hints = TrackHints {
                r_cur_prev: rotation,
                predictions: &[],
            };
            let stats = match tracker.track(im.t_ns, &view, &hints, &cam) {
                Ok(s) => s,
                Err(e) => {
                    out.errors
                        .push((im.t_ns, format!("{iw}x{ih} image refused: {e}")));
                    continue;
                }
            };
            let frontend_ns = t0.elapsed().as_nanos() as u64;
            prev_t = Some(im.t_ns);
            out.logs.push(FrameLog {
                t_ns: im.t_ns,
                report: ImageReport {
                    track: stats,
                    predictions: 0,
                    rotation_seed: rotation.is_some(),
                    tracks: tracker.features().len() as u32,
                    frontend_ns,
                    frame_error: None,
                },
                decode_ms: im.decode_s * 1e3,
            });
            out.frames.push(FeatureFrame {
                t_ns: im.t_ns,
                obs: tracker.features().to_vec(),
            });
            // Trails of the live tracks (the last 15 positions).
            let mut next: HashMap<u64, Vec<[f64; 2]>> = HashMap::with_capacity(trails.len());
            for f in tracker.features() {
                let mut t = trails.remove(&f.id).unwrap_or_default();
                t.push([f.u_px, f.v_px]);
                if t.len() > 15 {
                    t.remove(0);
                }
                next.insert(f.id, t);
            }
            trails = next;
            if let (Some((dir, _)), true) = (&opts.pictures, picture_at.contains(&im.index)) {
                let drawn: Vec<DrawnTrack> = tracker
                    .features()
                    .iter()
                    .zip(tracker.ages())
                    .filter_map(|(f, &age)| {
                        Some(DrawnTrack {
                            trail: trails.get(&f.id)?.clone(),
                            age: age as usize,
                        })
                    })
                    .collect();
                let path = dir.join(format!("frame_{}.png", im.t_ns));
                let caption = format!(
                    "{} image {} ({} ns): {} tracks, {} tracked from the previous image, {} new",
                    ds.name,
                    start + im.index,
                    im.t_ns,
                    stats.total,
                    stats.tracked,
                    stats.detected
                );
                draw_frame(&path, *iw, *ih, px, &drawn, &caption)?;
                out.pictures.push(path);
            }
        }
        Ok(())
    })?;
    progress.finish();
    Ok(out)
}

/// Writes tracks in the `features0` layout.
pub fn write_features_csv(path: &Path, frames: &[FeatureFrame]) -> Result<()> {
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    writeln!(f, "#timestamp [ns],feature_id,u [px],v [px]")?;
    for fr in frames {
        for o in &fr.obs {
            writeln!(f, "{},{},{},{}", fr.t_ns, o.id, o.u_px, o.v_px)?;
        }
    }
    f.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Observations per track (tracks seen in one image count with length 1).
pub fn track_lengths(frames: &[FeatureFrame]) -> Vec<usize> {
    let mut n: HashMap<u64, usize> = HashMap::new();
    for fr in frames {
        for o in &fr.obs {
            *n.entry(o.id).or_default() += 1;
        }
    }
    let mut v: Vec<usize> = n.into_values().collect();
    v.sort_unstable();
    v
}

/// Figures of `povins track` in `summary.json`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TrackSummary {
    /// Dataset name.
    pub dataset: String,
    /// Image size.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Gyro seeding on.
    pub gyro: bool,
    /// Camera-IMU delay used for the gyro rotation, ms.
    pub td_ms: f64,
    /// Per-image figures (timing measured around the tracker on the host).
    pub frontend: Option<FrontendSummary>,
    /// Tracks (ids).
    pub tracks: usize,
    /// Mean observations per track.
    pub track_length_mean: f64,
    /// Median.
    pub track_length_median: f64,
    /// 90th percentile.
    pub track_length_p90: f64,
    /// Mean observations per track among tracks seen in at least two images.
    pub track_length_mean_2plus: f64,
    /// Images that could not be used.
    pub image_errors: usize,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let ds = load_dataset(&args.dataset)?;
    let fe = frontend_options(args.config.as_deref(), None, &ds)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let td_s = args.td_ms.map_or(ds.calib.td_s, |ms| ms * 1e-3);
    if !td_s.is_finite() || td_s.abs() > 1.0 {
        bail!("--td-ms must be within +-1000 ms");
    }
    let end = args
        .frames
        .map_or(ds.images.len(), |n| args.start.saturating_add(n));
    let opts = TrackOptions {
        tracker: fe.tracker,
        gyro: fe.aiding.gyro_rotation && !args.no_gyro,
        td_s,
        range: args.start..end,
        pictures: Some((args.out.clone(), args.pictures)),
    };
    let progress = Progress::new(ds.images.len() as u64, "track");
    let out = track_dataset(&ds, &opts, &progress)?;
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
        dataset: ds.name.clone(),
        width: ds.calib.camera.width,
        height: ds.calib.camera.height,
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
            ds.name, summary.tracks, summary.track_length_mean, summary.track_length_median
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

//! `povins run <dataset> --out DIR`: replays an EuRoC folder or an MCAP file through the
//! estimator, fed by the image front end (`--frontend images`, the default when the dataset has
//! camera images; `frontend.csv` gets a row per image) or by the dataset's feature tracks
//! (`--frontend tracks`), and writes `trajectory.tum` (IMU rate), `keyframes.tum`, `stats.csv`
//! (a row per keyframe), `summary.json` and `config.toml` (the run's effective configuration,
//! every key; `--config` it to repeat the run); with ground truth in the dataset it also evaluates
//! (ATE, position + yaw alignment) and prints the result. LiDAR sweeps in the dataset are used
//! by default (`--no-lidar`, `--ldm`, `--no-depth-outlier-rejection`, `--no-depth-only-opt`
//! switch parts off); with simulator truth the LiDAR depth association is checked against it.
//!
//! The files are written row by row while the run goes, each as `NAME.partial` until the run
//! has ended, then renamed; memory does not grow with the recording's length (the poses the
//! evaluation passes over afterwards are logged to anonymous temporary files in `$TMPDIR`:
//! [`crate::report::spill`]). A run that
//! fails part-way (a recording that cannot be read, a write error) exits non-zero, says so, and
//! leaves the `.partial` files with the rows up to the failure (the keyframes still in the window
//! are not in them) and no `summary.json`; the complete files of an earlier run into the same
//! folder are left as they were. A camera recording on which the estimator never started (no
//! keyframe: no static period for `--init static`) writes its files and `summary.json` (the
//! counters, the front end's figures) but exits non-zero: there is no estimate. When no camera
//! data reached the estimator the error names why (stamps in another unit or clock, no frames,
//! every image or feature refused: [`crate::report::faults`]). Every run ends with a status
//! line, and a run whose output covers less than `--min-coverage` of the input exits non-zero
//! (`--allow-partial`: a warning).

use crate::progress::Progress;
use crate::report::faults::{camera_never_reached, status_line};
use crate::report::{print_summary, summarize_digest, OutputFiles, RunDigest};
use crate::setup::{RunArgs, RunSetup};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `povins run`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording and how to run it.
    #[command(flatten)]
    pub run: RunArgs,
    /// Output folder (created if missing).
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Least share of the input the output must cover (`coverage` against the ground truth
    /// when the recording has it, else `input_coverage`, both in summary.json); below it the
    /// run exits non-zero after writing its files.
    #[arg(long, default_value_t = DEFAULT_MIN_COVERAGE, value_parser = share)]
    pub min_coverage: f64,
    /// Accept an output covering less than `--min-coverage` (a warning, exit 0).
    #[arg(long)]
    pub allow_partial: bool,
}

/// Default of `--min-coverage`. Coverage counts from the first camera frame, so a start at
/// rest costs its static period (1 s of the simulator's runs: 0.967 of 30 s, 0.93 of 15 s,
/// 0.5 of the 2 s bags in tests/data), and a full reset (an IMU gap over `imu_gap.bridge_max_s`)
/// costs the time until the restart: 0.75 fails a run that lost a quarter of its input, not a
/// short one that started at rest. Bridged gaps cost nothing (0.95-0.97 on 30 s runs).
pub const DEFAULT_MIN_COVERAGE: f64 = 0.75;

/// A share in `0..=1`.
fn share(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is not in 0..=1"))
    }
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let rec = args.run.open()?;
    let setup = RunSetup::from_args(&*rec, &args.run)?;
    for note in setup.notes(&*rec, &args.run.lidar) {
        eprintln!("{note}");
    }
    let progress = Progress::new(0, "run");
    let mut sink = (
        OutputFiles::create(&args.out, setup.frontend.frontend)?,
        RunDigest::for_recording(&*rec),
    );
    let ran = setup.replay_into(&*rec, &progress, &mut sink);
    let (files, digest) = sink;
    let totals = match ran {
        Ok(t) => t,
        Err(e) => return Err(files.abandon(e)),
    };
    for (t, e) in &totals.image_errors {
        eprintln!("warning: image at {t} ns: {e}");
    }
    for w in rec.warnings() {
        let (label, text) = povins_platform::recording::label(&w);
        eprintln!("{label}: {text}");
    }
    if totals.image_failures > totals.image_errors.len() {
        eprintln!(
            "warning: {} more images could not be used",
            totals.image_failures - totals.image_errors.len()
        );
    }
    let summary = match summarize_digest(&*rec, &setup.mode_name(), setup.init, digest, &totals) {
        Ok(s) => s,
        Err(e) => return Err(files.abandon(e)),
    };
    files.finish(&summary)?;
    let path = args.out.join("config.toml");
    std::fs::write(&path, setup.effective_toml()?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    print_summary(&summary, &args.out);
    println!("{}", status_line(&summary));
    let cam = setup.estimator.camera;
    let has = rec.contents();
    let fe = setup.frontend.frontend;
    if let Some(cause) = camera_never_reached(&has, fe, &summary, &totals, (cam.width, cam.height))
    {
        anyhow::bail!(
            "{}: no camera data reached the estimator: {cause} (the files in {} hold no \
             visual estimate)",
            rec.name(),
            args.out.display()
        );
    }
    // A camera recording that never gave a keyframe gave no estimate: the run failed (the files
    // are written, with their headers, for the counters and the front end's figures).
    if summary.keyframes == 0 && summary.camera_frames > 0 {
        anyhow::bail!(
            "no estimate: the estimator never started over {} camera frames ({}; the files in {} \
             hold no poses)",
            summary.camera_frames,
            summary.never_started_reason(),
            args.out.display()
        );
    }
    if let Some((c, of)) = summary.judged_coverage() {
        if c < args.min_coverage {
            let why = format!(
                "partial estimate: the output covers {:.1}% {of}, less than --min-coverage {} \
                 ({} resets, {} re-initializations; the files in {} hold what was estimated)",
                100.0 * c,
                args.min_coverage,
                summary.counters["resets"],
                summary.counters["reinitializations"],
                args.out.display()
            );
            if !args.allow_partial {
                anyhow::bail!("{why}; --allow-partial accepts it");
            }
            eprintln!("warning: {why} (accepted: --allow-partial)");
        }
    }
    Ok(())
}

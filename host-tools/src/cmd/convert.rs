//! `povins convert RECORDING --out DIR`: writes any recording `run` opens (an EuRoC folder, an
//! MCAP file, a ROS 1 bag with `--calib`, the same topic switches) as an EuRoC ASL folder, for
//! the existing tools and other estimators. Streaming: each sensor's stream is pulled message by
//! message into [`EurocWriter`] (images written as PNG one at a time), so memory does not grow
//! with the recording. The samples are the ones `run` would get (after the recording's stamp
//! rules), so `povins run DIR` replays the same sequence. An `--out` folder that exists and is
//! not empty is refused.

use crate::progress::Progress;
use crate::setup::RecordingArgs;
use anyhow::{Context, Result};
use povins_platform::euroc::{EurocWriter, Written};
use povins_platform::recording::{Recording, Stream};
use std::path::{Path, PathBuf};

/// Arguments of `povins convert`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording, opened as `povins run` opens it.
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// TOML file whose `[input]` table (and `[imu_noise]`) names the calibration and topics,
    /// as for `povins run --config`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output EuRoC folder (`DIR/mav0/...`); must not exist or be empty.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    check_out_dir(&args.out)?;
    let rec = args.recording.open(args.config.as_deref())?;
    let progress = TimeProgress::new(rec.contents().imu_span_ns);
    let written = convert(&*rec, &args.out, &progress)
        .with_context(|| format!("converting {}", args.recording.dataset.display()))?;
    progress.bar.finish();
    for w in rec.warnings() {
        let (label, text) = povins_platform::recording::label(&w);
        eprintln!("{label}: {text}");
    }
    println!("{}", summary(&args.out, &written));
    Ok(())
}

/// Refuses an `out` that exists and is not an empty folder.
pub(crate) fn check_out_dir(out: &Path) -> Result<()> {
    if !out.exists() {
        return Ok(());
    }
    let mut entries = std::fs::read_dir(out)
        .with_context(|| format!("--out {}: not a readable folder", out.display()))?;
    anyhow::ensure!(
        entries.next().is_none(),
        "--out {}: the folder exists and is not empty; give a new or empty folder",
        out.display()
    );
    Ok(())
}

/// Progress over the recording's time: each stream is a pass over the IMU's time span.
struct TimeProgress {
    bar: Progress,
    span_ns: Option<(i64, i64)>,
}

impl TimeProgress {
    fn new(span_ns: Option<(i64, i64)>) -> Self {
        let len_ms = span_ns.map_or(0, |(a, b)| ((b - a).max(0) / 1_000_000) as u64);
        TimeProgress {
            bar: Progress::new(len_ms, "convert"),
            span_ns,
        }
    }

    fn start(&self, stream: &str) {
        self.bar
            .set_message(format!("{stream} (ms of the recording)"));
        self.bar.set_position(0);
    }

    fn at(&self, t_ns: i64) {
        if let Some((t0, t1)) = self.span_ns {
            self.bar
                .set_position((t_ns.clamp(t0, t1) - t0) as u64 / 1_000_000);
        }
    }
}

/// Pulls every message of `stream` into `put`, advancing the progress bar by its stamps.
fn copy<T>(
    stream: Stream<'_, T>,
    name: &str,
    progress: &TimeProgress,
    stamp: impl Fn(&T) -> i64,
    mut put: impl FnMut(&T) -> Result<(), povins_platform::error::IoError>,
) -> Result<()> {
    progress.start(name);
    for (k, item) in stream.enumerate() {
        let item = item.with_context(|| format!("{name} message {k}"))?;
        progress.at(stamp(&item));
        put(&item)?;
    }
    Ok(())
}

/// Writes `rec` as an EuRoC folder at `out` (see the module docs).
fn convert(rec: &dyn Recording, out: &Path, progress: &TimeProgress) -> Result<Written> {
    let mut w = EurocWriter::create(out, rec.calibration())?;
    copy(rec.imu()?, "imu", progress, |s| s.t_ns, |s| w.imu(s))?;
    copy(
        rec.images()?,
        "images",
        progress,
        |im| im.t_ns,
        |im| w.image(im),
    )?;
    copy(
        rec.frames()?,
        "features",
        progress,
        |f| f.t_ns,
        |f| w.frame(f),
    )?;
    copy(rec.sweeps()?, "lidar", progress, |s| s.t_ns, |s| w.sweep(s))?;
    w.ground_truth(&rec.ground_truth()?)?;
    Ok(w.finish()?)
}

/// What was written, for people.
fn summary(out: &Path, n: &Written) -> String {
    let mut s = format!(
        "wrote {} (EuRoC ASL): {} IMU samples, {} images",
        out.display(),
        n.imu,
        n.images
    );
    if n.frames > 0 {
        s += &format!(", {} feature frames", n.frames);
    }
    if n.sweeps > 0 {
        s += &format!(", {} LiDAR sweeps ({} points)", n.sweeps, n.points);
    }
    if n.ground_truth > 0 {
        s += &format!(", {} ground-truth states", n.ground_truth);
    }
    s
}

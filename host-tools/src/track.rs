//! The image front end alone over a recording (what `povins track` runs): the recording's images
//! and IMU in the replay's order through the one driver into [`povins_core::vio::Tracking`],
//! the tracks, per-image statistics, trails and pictures collected on the way.

use crate::frontend_stats::FrontendSummary;
use crate::progress::Progress;
use crate::runner::{
    check_input, config_for, monotonic_ns, FrameLog, FrontendOptions, ReplayProgress,
};
use crate::track_pictures::{draw_frame, DrawnTrack};
use anyhow::{Context, Result};
use povins_core::camera::FeatureObs;
use povins_core::frontend::image::{ImageView, TrackerConfig};
use povins_core::odometry::FrameOutput;
use povins_core::vio::ImageReport;
use povins_platform::dataset::FeatureFrame;
use povins_platform::driver::{self, ImageIn, Observer};
use povins_platform::odometry::{boxed_odometry, FrontEnd};
use povins_platform::recording::Recording;
use povins_platform::source::{
    CameraInput, MergeOptions, MergedSource, Prefetch, SensorEvent, Source,
};
use povins_platform::IoError;
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

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

/// Runs the front end alone over `rec`'s images (see the module docs): the recording's images and
/// IMU in the replay's order through the one driver, into the front end alone
/// ([`povins_core::vio::Tracking`], its capacity chosen by the image size).
pub fn track_dataset(
    rec: &dyn Recording,
    opts: &TrackOptions,
    progress: &Progress,
) -> Result<TrackOutput> {
    check_input(rec, &FrontendOptions::images(opts.tracker))?;
    let mut cfg = config_for(rec);
    cfg.td_s = opts.td_s;
    cfg.lidar.enabled = false;
    let fe = FrontEnd::TrackingOnly {
        tracker: opts.tracker,
        gyro_rotation: opts.gyro,
    };
    let mut odo =
        boxed_odometry(cfg, &fe, Some(monotonic_ns)).with_context(|| rec.name().to_string())?;
    let merge = MergeOptions {
        lidar: false,
        ..MergeOptions::new(CameraInput::Images)
    };
    let source = ImageRange {
        inner: MergedSource::new(rec, &merge)?,
        range: opts.range.clone(),
        seen: 0,
    };
    let mut out = TrackCollector::new(rec, opts, progress);
    let (ran, _) = Prefetch::run(source, |p| driver::run(&mut *odo, p, &mut out));
    ran.with_context(|| format!("reading {}", rec.name()))?;
    progress.finish();
    out.finish()
}

/// The images `range` of a source (by their order) and everything before the last of them.
struct ImageRange<S> {
    inner: S,
    range: std::ops::Range<usize>,
    seen: usize,
}

impl<S: Source> Source for ImageRange<S> {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        loop {
            let Some(ev) = self.inner.next()? else {
                return Ok(None);
            };
            if matches!(ev, SensorEvent::Image { .. }) {
                let k = self.seen;
                self.seen += 1;
                if k >= self.range.end {
                    return Ok(None);
                }
                if k < self.range.start {
                    continue;
                }
            }
            return Ok(Some(ev));
        }
    }

    fn is_realtime(&self) -> bool {
        self.inner.is_realtime()
    }
}

/// Collects the front end's output per image: the tracks, the statistics, the trails and the
/// pictures (the driver's observer).
struct TrackCollector<'a> {
    out: TrackOutput,
    name: String,
    start: usize,
    /// Images seen so far (tracked or not).
    index: usize,
    picture_at: Vec<usize>,
    picture_dir: Option<PathBuf>,
    trails: HashMap<u64, Vec<[f64; 2]>>,
    progress: ReplayProgress<'a>,
    error: Option<anyhow::Error>,
}

impl<'a> TrackCollector<'a> {
    fn new(rec: &dyn Recording, opts: &TrackOptions, progress: &'a Progress) -> Self {
        // Images in the range (the recording's count bounds an open range).
        let end = match rec.contents().image_count {
            Some(count) => opts.range.end.min(count),
            None => opts.range.end,
        };
        let n = end.saturating_sub(opts.range.start);
        let picture_at: Vec<usize> = match &opts.pictures {
            Some((_, p)) if *p > 0 && n > 0 && n < usize::MAX / 2 => {
                (1..=*p).map(|i| i * n / (*p + 1)).collect()
            }
            _ => Vec::new(),
        };
        TrackCollector {
            out: TrackOutput::default(),
            name: rec.name().to_string(),
            start: opts.range.start,
            index: 0,
            picture_at,
            picture_dir: opts.pictures.as_ref().map(|(d, _)| d.clone()),
            trails: HashMap::new(),
            progress: ReplayProgress::new(rec, progress),
            error: None,
        }
    }

    fn finish(self) -> Result<TrackOutput> {
        match self.error {
            Some(e) => Err(e),
            None => Ok(self.out),
        }
    }

    /// Keeps the last 15 positions of every live track.
    fn update_trails(&mut self, tracks: &[FeatureObs]) {
        let mut next: HashMap<u64, Vec<[f64; 2]>> = HashMap::with_capacity(self.trails.len());
        for f in tracks {
            let mut t = self.trails.remove(&f.id).unwrap_or_default();
            t.push([f.u_px, f.v_px]);
            if t.len() > 15 {
                t.remove(0);
            }
            next.insert(f.id, t);
        }
        self.trails = next;
    }

    /// Draws image `index` with its tracks' trails.
    fn picture(
        &mut self,
        f: &FrameOutput<'_>,
        report: &ImageReport,
        view: &ImageView<'_>,
    ) -> Result<()> {
        let Some(dir) = &self.picture_dir else {
            return Ok(());
        };
        let drawn: Vec<DrawnTrack> = f
            .tracks
            .iter()
            .zip(f.track_ages)
            .filter_map(|(t, &age)| {
                Some(DrawnTrack {
                    trail: self.trails.get(&t.id)?.clone(),
                    age: age as usize,
                })
            })
            .collect();
        let path = dir.join(format!("frame_{}.png", f.t_cam_ns));
        let caption = format!(
            "{} image {} ({} ns): {} tracks, {} tracked from the previous image, {} new",
            self.name,
            self.start + self.index,
            f.t_cam_ns,
            report.track.total,
            report.track.tracked,
            report.track.detected
        );
        draw_frame(
            &path,
            view.width(),
            view.height(),
            view.data(),
            &drawn,
            &caption,
        )?;
        self.out.pictures.push(path);
        Ok(())
    }
}

impl Observer for TrackCollector<'_> {
    fn imu(&mut self, t_ns: i64) {
        self.progress.imu(t_ns);
    }

    fn frame(&mut self, f: &FrameOutput<'_>, image: Option<&ImageIn<'_>>) {
        let (Some(report), Some(im)) = (f.image, image) else {
            return;
        };
        self.out.logs.push(FrameLog::of(f.t_cam_ns, report, im));
        self.out.frames.push(FeatureFrame {
            t_ns: f.t_cam_ns,
            obs: f.tracks.to_vec(),
        });
        self.update_trails(f.tracks);
        if self.picture_at.contains(&self.index) && self.error.is_none() {
            if let Err(e) = self.picture(f, &report, im.view) {
                self.error = Some(e);
            }
        }
        self.index += 1;
    }

    fn image_failed(&mut self, t_cam_ns: i64, why: String) {
        self.out.errors.push((t_cam_ns, why));
        self.index += 1;
    }
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

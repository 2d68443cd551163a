//! `povins simulate`: writes a simulated camera + IMU + LiDAR sequence with ground truth.
//!
//! Every scenario starts at rest and ramps up to full motion. `--start-s T` drops the first T
//! seconds of every stream (stamps unchanged), so the sequence starts in motion; the bar of
//! issue 31 (in-motion initialization) uses T = the scenario's rest plus its ramp to full motion,
//! `--start-s motion` ([`sim::motion_start_s`]): with the default `--static-s 1`, 3 s for robot,
//! handheld, flight and fast, 9 s for vehicle. `--td-step-ms D --td-step-at-s T` steps the true
//! camera-IMU delay by D from T on (issue 31, item 6).

use crate::sim::render::{sequence, RenderOptions};
use crate::sim::{self, LidarKind, Scenario, SimConfig, SimOutput};
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use povins_platform::cloud::Wire;
use povins_platform::dataset::{Calibration, Dataset, ImageFrame};
use povins_platform::mcap_log::write::McapWriter;
use povins_platform::rosbag1::write::{BagWriter, Compression};
use povins_platform::rosbag2::write::{Rosbag2Writer, Storage};
use povins_platform::rosrec::write::{self as roswrite, ContainerWriter, DatasetTopics};
use povins_platform::rosrec::Encoding;
use povins_platform::IoError;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Output container.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One MCAP file (ROS 2 CDR messages).
    Mcap,
    /// EuRoC ASL folder: camera calibration, IMU, features, ground truth.
    Euroc,
    /// ROS 1 bag with the topic names of a RealSense D435i (`/camera/imu`,
    /// `/camera/infra1/image_rect_raw` mono8 with --images) and `/lidar/points`
    /// (`sensor_msgs/PointCloud2`), chunks compressed by --compression; the calibration beside
    /// it ([`write_bag_calibration`]).
    Rosbag1,
    /// ROS 2 bag folder, sqlite3 storage (`metadata.yaml`, `<name>_0.db3`), CDR messages on the
    /// topics of `rosbag1`; the calibration beside it.
    #[value(name = "rosbag2-sqlite3")]
    Rosbag2Sqlite3,
    /// ROS 2 bag folder, MCAP storage (`metadata.yaml`, `<name>_0.mcap`), CDR messages on the
    /// topics of `rosbag1`; the calibration beside it.
    #[value(name = "rosbag2-mcap")]
    Rosbag2Mcap,
    /// One MCAP file of ROS 1 messages (profile `ros1`, `ros1msg` schemas) on the topics of
    /// `rosbag1`; the calibration beside it.
    #[value(name = "mcap-ros1")]
    McapRos1,
}

/// How images are stored in a ROS recording (`--image-encoding raw|jpeg[=QUALITY]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageEncoding {
    /// `sensor_msgs/Image`, mono8.
    Raw,
    /// `sensor_msgs/CompressedImage`, format `jpeg`, gray JPEG of this quality (1-100).
    Jpeg(u8),
}

/// Parses `raw`, `jpeg` (quality 90) or `jpeg=QUALITY`.
fn parse_image_encoding(s: &str) -> Result<ImageEncoding, String> {
    match s.split_once('=') {
        None if s == "raw" => Ok(ImageEncoding::Raw),
        None if s == "jpeg" => Ok(ImageEncoding::Jpeg(90)),
        Some(("jpeg", q)) => match q.parse::<u8>() {
            Ok(q) if (1..=100).contains(&q) => Ok(ImageEncoding::Jpeg(q)),
            _ => Err(format!("JPEG quality {q:?} is not an integer in 1..=100")),
        },
        _ => Err(format!("{s:?}: expected raw, jpeg or jpeg=QUALITY")),
    }
}

/// Chunk compression of a ROS 1 bag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BagCompression {
    /// Uncompressed chunks.
    None,
    /// LZ4 (`rosbag record --lz4`).
    Lz4,
    /// bzip2 (`rosbag record --bz2`).
    Bz2,
}

impl From<BagCompression> for Compression {
    fn from(c: BagCompression) -> Self {
        match c {
            BagCompression::None => Compression::None,
            BagCompression::Lz4 => Compression::Lz4,
            BagCompression::Bz2 => Compression::Bz2,
        }
    }
}

/// Arguments of `povins simulate`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Carrier.
    #[arg(long, value_enum, default_value = "robot")]
    pub scenario: Scenario,
    /// Random seed (same seed -> identical output).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sequence length, s.
    #[arg(long, default_value_t = 60.0)]
    pub duration: f64,
    /// Output file (MCAP, ROS 1 bag) or folder (EuRoC, ROS 2 bag).
    #[arg(long)]
    pub out: PathBuf,
    /// Output format.
    #[arg(long, value_enum, default_value = "mcap")]
    pub format: Format,
    /// Images of a ROS recording (`rosbag1`, `rosbag2-*`, `mcap-ros1`): `raw` (mono8
    /// `sensor_msgs/Image`) or `jpeg[=QUALITY]` (`sensor_msgs/CompressedImage` on
    /// `<image topic>/compressed`, quality 90 by default). Needs --images.
    #[arg(long, value_parser = parse_image_encoding, default_value = "raw")]
    pub image_encoding: ImageEncoding,
    /// Chunk compression of `--format rosbag1` (default none).
    #[arg(long, value_enum)]
    pub compression: Option<BagCompression>,
    /// Camera-IMU time offset td, ms (`t_imu = t_cam + td`). A camera stamp is its exposure
    /// instant on the IMU clock minus td (of that frame, see --td-step-ms); the calibration
    /// written (`timeshift_cam_imu`) holds this value, the delay before any step.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub td_ms: f64,
    /// Step of the true camera-IMU delay, ms: frames exposed at or after --td-step-at-s are
    /// stamped with td = td_ms + D (`t_cam = t_imu - td`; a positive D moves their stamps D
    /// earlier). Must be below the frame period. The calibration keeps td_ms.
    #[arg(long, allow_hyphen_values = true, requires = "td_step_at_s")]
    pub td_step_ms: Option<f64>,
    /// When the delay steps, s on the IMU clock from the first IMU sample (the sequence's time,
    /// --start-s not subtracted).
    #[arg(long, requires = "td_step_ms")]
    pub td_step_at_s: Option<f64>,
    /// Rolling-shutter readout time of the camera, ms (0: global shutter): rows are read out top
    /// to bottom, the stamp is the middle row's time, and each feature (and each rendered row)
    /// is seen at its row's time. The calibration carries it (`readout_s` in `cam0/sensor.yaml`
    /// and the MCAP calibration), so `povins run` models it unless the configuration sets
    /// `[camera] readout_s = 0.0`.
    #[arg(long, default_value_t = 0.0)]
    pub readout_ms: f64,
    /// Drop the first T seconds of every stream (IMU, ground truth, camera frames and images by
    /// exposure instant, LiDAR sweeps by their start), stamps unchanged: a sequence that starts
    /// in motion. `motion`: the scenario's rest plus its ramp to full motion (3 s; vehicle 9 s,
    /// with --static-s 1). 0 = the whole sequence.
    #[arg(long, default_value = "0")]
    pub start_s: StartAt,
    /// LiDAR-IMU time offset td_l, ms (`t_imu = t_lidar + td_l`): each LiDAR point is stamped
    /// with its instant on the IMU clock minus td_l. The calibration written holds it (EuRoC
    /// `lidar0/sensor.yaml` `timeshift_lidar_imu`, also in a ROS recording's `<stem>-calib/`
    /// folder for --calib; the MCAP calibration's `td_l_s`).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub lidar_td_ms: f64,
    /// LiDAR pattern (default: livox for robot/handheld, ouster for vehicle). The sensor models
    /// (os1-128, vlp16, avia, mid70) also have their beam's divergence: a beam across an edge
    /// returns the stronger surface or, surfaces under 1 m apart, a mixed range between them.
    #[arg(long, value_enum)]
    pub lidar: Option<LidarKind>,
    /// Points per LiDAR sweep (default per sensor).
    #[arg(long)]
    pub lidar_points: Option<usize>,
    /// How the sweeps of a ROS recording (`rosbag1`, `rosbag2-*`, `mcap-ros1`) are written: a
    /// driver's `sensor_msgs/PointCloud2` layout (`compact`, povins' own, the default;
    /// `ouster`, `velodyne`, `hesai`, `robosense`, `livox2`) or Livox's `CustomMsg`
    /// (`livox-custom`: livox_ros_driver, ROS 1 only; `livox2-custom`: livox_ros_driver2).
    /// See `povins_platform::cloud`.
    #[arg(long, value_parser = parse_wire, default_value = "compact")]
    pub lidar_layout: Wire,
    /// Rotation error of the true camera-LiDAR relation vs the stored calibration, deg.
    #[arg(long, default_value_t = 0.5)]
    pub lidar_extrinsic_error_deg: f64,
    /// Translation error of the true camera-LiDAR relation vs the stored calibration, m.
    #[arg(long, default_value_t = 0.03)]
    pub lidar_extrinsic_error_m: f64,
    /// Probability that a LiDAR ray passes through a tree crown, in [0, 1] (0: opaque crowns).
    #[arg(long, default_value_t = 0.0)]
    pub foliage_porosity: f64,
    /// Fraction of new feature tracks that jump to a wrong landmark (default 0.02).
    #[arg(long)]
    pub wrong_track_rate: Option<f64>,
    /// Noise of the simulated feature tracks (1 sigma), px. The rendered images are not affected
    /// (see --image-noise).
    #[arg(long, default_value_t = 1.0)]
    pub pixel_noise: f64,
    /// Maximum tracked features per frame (default per scenario).
    #[arg(long)]
    pub max_features: Option<usize>,
    /// Time at rest before moving, s.
    #[arg(long, default_value_t = 1.0)]
    pub static_s: f64,
    /// Render grayscale camera images at the camera rate (EuRoC: `cam0/data/<ns>.png`; MCAP:
    /// `sensor_msgs/msg/Image` on `/cam0/image_raw`; ROS recordings: mono8 `sensor_msgs/Image`
    /// on `/camera/infra1/image_rect_raw`).
    #[arg(long)]
    pub images: bool,
    /// Motion blur: exposure time, ms (0 = off; the stamp is mid-exposure). Needs --images.
    #[arg(long, default_value_t = 0.0)]
    pub motion_blur_ms: f64,
    /// Exposure/gain changes over time: standard deviation of the log gain (0 = constant,
    /// 0.2 = about +-20 %). Needs --images.
    #[arg(long, default_value_t = 0.0)]
    pub exposure_var: f64,
    /// Gaussian pixel noise, grey levels (1 sigma). Needs --images.
    #[arg(long, default_value_t = 0.0)]
    pub image_noise: f64,
    /// Samples per pixel side (1 = one footprint-filtered sample per pixel, edges 3x3).
    /// Needs --images.
    #[arg(long, default_value_t = 1)]
    pub image_supersample: u32,
}

/// Where the written sequence starts (`--start-s`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StartAt {
    /// Seconds from the first IMU sample.
    Seconds(f64),
    /// The scenario's rest plus its ramp to full motion ([`sim::motion_start_s`]).
    Motion,
}

impl std::str::FromStr for StartAt {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "motion" {
            return Ok(StartAt::Motion);
        }
        match s.parse::<f64>() {
            Ok(t) if t.is_finite() && t >= 0.0 => Ok(StartAt::Seconds(t)),
            _ => Err(format!(
                "`{s}`: expected seconds >= 0 or `motion` (the scenario's rest plus its ramp)"
            )),
        }
    }
}

impl Args {
    /// Render options from the flags; an error when a render flag is given without --images.
    pub fn render_options(&self) -> anyhow::Result<Option<RenderOptions>> {
        let opts = RenderOptions {
            supersample: self.image_supersample,
            edge_samples: RenderOptions::default()
                .edge_samples
                .max(self.image_supersample),
            motion_blur_s: self.motion_blur_ms * 1e-3,
            exposure_var: self.exposure_var,
            noise_grey: self.image_noise,
            ..RenderOptions::default()
        };
        if !self.images {
            anyhow::ensure!(
                opts == RenderOptions::default(),
                "--motion-blur-ms, --exposure-var, --image-noise and --image-supersample need --images"
            );
            return Ok(None);
        }
        opts.check()?;
        Ok(Some(opts))
    }
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut cfg = SimConfig::new(args.scenario, args.seed, args.duration);
    cfg.td_s = args.td_ms * 1e-3;
    cfg.readout_s = args.readout_ms * 1e-3;
    if let (Some(d), Some(at)) = (args.td_step_ms, args.td_step_at_s) {
        cfg.td_step = Some(sim::TdStep {
            step_s: d * 1e-3,
            at_s: at,
        });
    }
    cfg.start_s = match args.start_s {
        StartAt::Seconds(t) => t,
        StartAt::Motion => sim::motion_start_s(args.scenario, args.static_s),
    };
    cfg.lidar_td_s = args.lidar_td_ms * 1e-3;
    cfg.lidar = args.lidar;
    cfg.lidar_points = args.lidar_points;
    cfg.lidar_extrinsic_error_deg = args.lidar_extrinsic_error_deg;
    cfg.lidar_extrinsic_error_m = args.lidar_extrinsic_error_m;
    cfg.foliage_porosity = args.foliage_porosity;
    cfg.wrong_track_rate = args.wrong_track_rate;
    cfg.max_features = args.max_features;
    anyhow::ensure!(
        args.pixel_noise.is_finite() && (0.0..=100.0).contains(&args.pixel_noise),
        "--pixel-noise must be within 0..=100 px"
    );
    cfg.pixel_noise_px = args.pixel_noise;
    cfg.static_s = args.static_s;
    let render = args.render_options()?;
    anyhow::ensure!(
        args.compression.is_none() || args.format == Format::Rosbag1,
        "--compression applies to --format rosbag1 only"
    );
    anyhow::ensure!(
        args.lidar_layout == Wire::default() || !matches!(args.format, Format::Mcap | Format::Euroc),
        "--lidar-layout needs a ROS recording (rosbag1, rosbag2-sqlite3, rosbag2-mcap, mcap-ros1): \
         povins' MCAP and EuRoC folders have their own layout"
    );
    if args.image_encoding != ImageEncoding::Raw {
        anyhow::ensure!(
            args.images && !matches!(args.format, Format::Mcap | Format::Euroc),
            "--image-encoding jpeg needs --images and a ROS recording (rosbag1, rosbag2-sqlite3, \
             rosbag2-mcap, mcap-ros1)"
        );
    }

    let bar = std::io::stderr().is_terminal().then(|| {
        let b = ProgressBar::new(1);
        b.set_style(
            ProgressStyle::with_template("simulating [{bar:40}] {pos}/{len} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    });
    // The camera and LiDAR stages run concurrently, images after them: the bar shows their
    // combined progress.
    let counts = Mutex::new([(0usize, 0usize); 3]);
    let report = |name: &'static str, done: usize, total: usize| {
        if let (Some(b), Ok(mut c)) = (&bar, counts.lock()) {
            let slot = match name {
                "lidar" => 1,
                "images" => 2,
                _ => 0,
            };
            c[slot] = (done, total);
            b.set_length(c.iter().map(|x| x.1).sum::<usize>().max(1) as u64);
            b.set_position(c.iter().map(|x| x.0).sum::<usize>() as u64);
        }
    };
    let mut out = sim::simulate(&cfg, &report)?;
    if let Some(opts) = &render {
        render_images(&mut out, opts, &args, &report)?;
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    eprintln!("{} (seed {}):", out.dataset.name, args.seed);
    if cfg.start_s > 0.0 {
        eprintln!(
            "start           {:.3} s after the first IMU sample (the scenario is in full motion from {:.3} s)",
            cfg.start_s,
            sim::motion_start_s(args.scenario, args.static_s)
        );
    }
    eprintln!("{}", out.summary);
    match args.format {
        Format::Mcap => povins_platform::mcap_io::write_dataset(&args.out, &out.dataset)?,
        Format::Euroc => povins_platform::euroc::write_dataset(&args.out, &out.dataset)?,
        f => write_ros_recording(&args.out, &out.dataset, f, &args)?,
    }
    eprintln!("wrote {}", args.out.display());
    Ok(())
}

fn parse_wire(s: &str) -> Result<Wire, String> {
    Wire::parse(s).ok_or_else(|| {
        let names: Vec<&str> = Wire::all().into_iter().map(Wire::name).collect();
        format!("{s:?}: expected one of {}", names.join(", "))
    })
}

/// Writes `ds` at `out` as the ROS recording `format` with RealSense topic names
/// ([`DatasetTopics::realsense`]; [`roswrite::write_dataset`] decides the messages, the
/// container stores them), and its calibration beside it.
fn write_ros_recording(
    out: &Path,
    ds: &Dataset,
    format: Format,
    args: &Args,
) -> anyhow::Result<()> {
    let topics = DatasetTopics {
        lidar_wire: args.lidar_layout,
        ..DatasetTopics::realsense()
    };
    let jpeg = |q: u8| {
        move |w: u32, h: u32, px: &[u8]| -> Result<Vec<u8>, String> {
            let (w, h) = (u16::try_from(w), u16::try_from(h));
            let (Ok(w), Ok(h)) = (w, h) else {
                return Err("a JPEG image is at most 65535 pixels a side".into());
            };
            let mut buf = Vec::new();
            jpeg_encoder::Encoder::new(&mut buf, q)
                .encode(px, w, h, jpeg_encoder::ColorType::Luma)
                .map_err(|e| format!("JPEG encoding: {e}"))?;
            Ok(buf)
        }
    };
    let encode = match args.image_encoding {
        ImageEncoding::Raw => None,
        ImageEncoding::Jpeg(q) => Some(jpeg(q)),
    };
    let compress = encode.as_ref().map(|f| roswrite::ImageCompressor {
        format: "jpeg".into(),
        encode: f,
    });
    let compress = compress.as_ref();
    let image_topic = topics.image_topic(compress.is_some());
    let (what, n) = match format {
        Format::Rosbag1 => {
            let c: Compression = args.compression.unwrap_or(BagCompression::None).into();
            let w = BagWriter::create(out, c)?;
            let what = format!("ROS 1 bag, chunks: {}", c.name());
            (
                what,
                store(
                    w,
                    out,
                    ds,
                    &topics,
                    Encoding::Ros1,
                    compress,
                    BagWriter::finish,
                )?,
            )
        }
        Format::Rosbag2Sqlite3 | Format::Rosbag2Mcap => {
            let storage = match format {
                Format::Rosbag2Sqlite3 => Storage::Sqlite3,
                _ => Storage::Mcap,
            };
            let w = Rosbag2Writer::create(out, storage)?;
            let what = format!("ROS 2 bag, {} storage", storage.identifier());
            (
                what,
                store(
                    w,
                    out,
                    ds,
                    &topics,
                    Encoding::Cdr,
                    compress,
                    Rosbag2Writer::finish,
                )?,
            )
        }
        _ => {
            let w = McapWriter::create(out, Encoding::Ros1)?;
            let what = "MCAP, ROS 1 messages".to_string();
            (
                what,
                store(
                    w,
                    out,
                    ds,
                    &topics,
                    Encoding::Ros1,
                    compress,
                    McapWriter::finish,
                )?,
            )
        }
    };
    eprintln!(
        "recording       {what}: {} IMU on {}, {} images on {}, {} point clouds on {}",
        n.imu, topics.imu.0, n.images, image_topic, n.sweeps, topics.lidar.0,
    );
    let calib_dir = bag_calibration_dir(out);
    write_bag_calibration(&ds.calib, &calib_dir, &image_topic)?;
    eprintln!("calibration     {}", calib_dir.display());
    Ok(())
}

/// Writes `ds` into the container `w` in `encoding`, then `finish`es it.
fn store<W: ContainerWriter>(
    mut w: W,
    out: &Path,
    ds: &Dataset,
    topics: &DatasetTopics,
    encoding: Encoding,
    compress: Option<&roswrite::ImageCompressor<'_>>,
    finish: impl FnOnce(W) -> Result<(), IoError>,
) -> Result<roswrite::DatasetCounts, IoError> {
    let n = roswrite::write_dataset(&mut w, out, ds, topics, encoding, compress)?;
    finish(w)?;
    Ok(n)
}

/// Where the calibration of the recording `out` (a file or a ROS 2 bag folder) is written:
/// `<folder>/<stem>-calib` beside it.
pub fn bag_calibration_dir(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or("bag".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}-calib"))
}

/// Writes the calibration of a simulated bag into `dir`: Kalibr's `camchain-imucam.yaml` and
/// `imu.yaml` with the bag's topics (`povins run BAG --calib DIR/camchain-imucam.yaml
/// --imu-calib DIR/imu.yaml`), and the same as the EuRoC `sensor.yaml` files of `imu0` and
/// `cam0` with an `imu0/data.csv` of no samples (`povins run BAG --calib DIR`).
pub fn write_bag_calibration(
    calib: &Calibration,
    dir: &Path,
    image_topic: &str,
) -> anyhow::Result<()> {
    let topics = DatasetTopics::realsense();
    povins_platform::euroc::EurocWriter::create(dir, calib)
        .and_then(|w| w.finish())
        .and_then(|_| {
            povins_platform::kalibr::write_camchain(
                &dir.join("camchain-imucam.yaml"),
                calib,
                Some(image_topic),
            )
        })
        .and_then(|_| {
            povins_platform::kalibr::write_imu(&dir.join("imu.yaml"), calib, Some(&topics.imu.0))
        })
        .with_context(|| format!("writing the calibration to {}", dir.display()))?;
    Ok(())
}

/// Renders the camera images into `out.dataset.images`: as PNG files in the EuRoC folder
/// (rendered and encoded on the worker threads, the dataset keeps their paths) or in memory for
/// MCAP.
fn render_images(
    out: &mut SimOutput,
    opts: &RenderOptions,
    args: &Args,
    progress: sim::Progress<'_>,
) -> anyhow::Result<()> {
    let cam = out.dataset.calib.camera;
    let n = out.dataset.features.len();
    let slots: Mutex<Vec<Option<ImageFrame>>> = Mutex::new(vec![None; n]);
    let data_dir = args.out.join("mav0").join("cam0").join("data");
    if args.format == Format::Euroc {
        std::fs::create_dir_all(&data_dir)
            .map_err(|e| anyhow::anyhow!("{}: {e}", data_dir.display()))?;
    }
    let sink = |k: usize, t_ns: i64, px: Vec<u8>| -> anyhow::Result<()> {
        let mut im = ImageFrame {
            t_ns,
            width: cam.width,
            height: cam.height,
            mono8: px,
            path: None,
        };
        if args.format == Format::Euroc {
            let p = data_dir.join(format!("{t_ns}.png"));
            povins_platform::euroc::write_png_mono8(&p, im.width, im.height, &im.mono8)?;
            im.mono8 = Vec::new();
            im.path = Some(p);
        }
        if let Ok(mut s) = slots.lock() {
            s[k] = Some(im);
        }
        Ok(())
    };
    let stats = sequence::render_sequence(out, opts, args.seed, 0, progress, &sink)?;
    let images: Option<Vec<ImageFrame>> = slots
        .into_inner()
        .map_err(|_| anyhow::anyhow!("image rendering failed"))?
        .into_iter()
        .collect();
    out.dataset.images = images.ok_or_else(|| anyhow::anyhow!("image rendering failed"))?;
    eprintln!(
        "images          {} frames {}x{} in {:.1} s ({:.0} ms per frame per thread, {} threads)",
        stats.frames, cam.width, cam.height, stats.wall_s, stats.ms_per_frame, stats.threads
    );
    Ok(())
}

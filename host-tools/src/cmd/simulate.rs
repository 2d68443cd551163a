//! `povins simulate`: writes a simulated camera + IMU + LiDAR sequence with ground truth.

use crate::sim::{self, LidarKind, Scenario, SimConfig};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Mutex;

/// Output container.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One MCAP file (ROS 2 CDR messages).
    Mcap,
    /// EuRoC ASL folder: camera calibration, IMU, features, ground truth.
    Euroc,
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
    /// Output file (MCAP) or folder (EuRoC).
    #[arg(long)]
    pub out: PathBuf,
    /// Output format.
    #[arg(long, value_enum, default_value = "mcap")]
    pub format: Format,
    /// Camera-IMU time offset td, ms (`t_imu = t_cam + td`).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub td_ms: f64,
    /// LiDAR pattern (default: livox for robot/handheld, ouster for vehicle).
    #[arg(long, value_enum)]
    pub lidar: Option<LidarKind>,
    /// Points per LiDAR sweep (default per sensor).
    #[arg(long)]
    pub lidar_points: Option<usize>,
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
    /// Maximum tracked features per frame (default per scenario).
    #[arg(long)]
    pub max_features: Option<usize>,
    /// Time at rest before moving, s.
    #[arg(long, default_value_t = 1.0)]
    pub static_s: f64,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut cfg = SimConfig::new(args.scenario, args.seed, args.duration);
    cfg.td_s = args.td_ms * 1e-3;
    cfg.lidar = args.lidar;
    cfg.lidar_points = args.lidar_points;
    cfg.lidar_extrinsic_error_deg = args.lidar_extrinsic_error_deg;
    cfg.lidar_extrinsic_error_m = args.lidar_extrinsic_error_m;
    cfg.foliage_porosity = args.foliage_porosity;
    cfg.wrong_track_rate = args.wrong_track_rate;
    cfg.max_features = args.max_features;
    cfg.static_s = args.static_s;

    let bar = std::io::stderr().is_terminal().then(|| {
        let b = ProgressBar::new(1);
        b.set_style(
            ProgressStyle::with_template("simulating [{bar:40}] {pos}/{len} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    });
    // The camera and LiDAR stages run concurrently: the bar shows their combined progress.
    let counts = Mutex::new([(0usize, 0usize); 2]);
    let report = |name: &'static str, done: usize, total: usize| {
        if let (Some(b), Ok(mut c)) = (&bar, counts.lock()) {
            c[usize::from(name == "lidar")] = (done, total);
            b.set_length((c[0].1 + c[1].1).max(1) as u64);
            b.set_position((c[0].0 + c[1].0) as u64);
        }
    };
    let out = sim::simulate(&cfg, &report)?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    eprintln!("{} (seed {}):", out.dataset.name, args.seed);
    eprintln!("{}", out.summary);
    match args.format {
        Format::Mcap => povins_platform::mcap_io::write_dataset(&args.out, &out.dataset)?,
        Format::Euroc => povins_platform::euroc::write_dataset(&args.out, &out.dataset)?,
    }
    eprintln!("wrote {}", args.out.display());
    Ok(())
}

//! `povins ablation`: the LiDAR ablation (paper Table VI plus PO-VINS-WO) on simulated
//! sequences; prints the table and writes `ablation.md` and `ablation.json`. See
//! [`crate::ablation`] for what is run and how it is aggregated.

use crate::ablation::{render_markdown, run_ablation, run_count, AblationConfig};
use crate::config::RunConfigFile;
use crate::progress::Progress;
use crate::sim::{LidarKind, Scenario};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `povins ablation`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Simulated scenarios, comma separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "robot,handheld,vehicle"
    )]
    pub scenarios: Vec<Scenario>,
    /// Simulator seeds, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Simulated duration per sequence, s.
    #[arg(long, default_value_t = 60.0)]
    pub duration: f64,
    /// Runs in parallel (accuracy is identical for any value; timings are not).
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Output folder for `ablation.md` and `ablation.json`.
    #[arg(long, default_value = "target/ablation")]
    pub out: PathBuf,
    /// Print the JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// TOML estimator settings applied to every variant (the variants then set their switches).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Camera-LiDAR rotation error of the simulated calibration, deg: the source of the edge
    /// outliers (features on object edges picking up background depths).
    #[arg(long, default_value_t = 0.5)]
    pub lidar_extrinsic_error_deg: f64,
    /// Probability that a LiDAR ray passes through a tree crown, in [0, 1]: the camera sees the
    /// crown, the LiDAR the wall behind it (the paper's unstructured-scene depth outliers).
    #[arg(long, default_value_t = 0.0)]
    pub foliage_porosity: f64,
    /// LiDAR model simulated on every scenario, as `povins simulate --lidar` takes it (default:
    /// each scenario's own).
    #[arg(long, value_enum)]
    pub lidar: Option<LidarKind>,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let overrides = args
        .config
        .as_deref()
        .map(RunConfigFile::read)
        .transpose()?;
    let cfg = AblationConfig {
        scenarios: args.scenarios,
        seeds: args.seeds,
        duration_s: args.duration,
        jobs: args.jobs,
        lidar_extrinsic_error_deg: args.lidar_extrinsic_error_deg,
        foliage_porosity: args.foliage_porosity,
        lidar: args.lidar,
    };
    // Runs share the cores (`--jobs`): time each by its thread's CPU time, so that the
    // variants' back ends compare the work done rather than who ran beside whom.
    crate::runner::use_cpu_time(true);
    let progress = Progress::new(run_count(&cfg) as u64, "ablation");
    let report = run_ablation(&cfg, overrides.as_ref(), &progress)?;
    let md = render_markdown(&report);
    let json = serde_json::to_string_pretty(&report)? + "\n";
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    for (name, text) in [("ablation.md", &md), ("ablation.json", &json)] {
        let path = args.out.join(name);
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    if args.json {
        print!("{json}");
    } else {
        print!("{md}");
    }
    eprintln!("wrote {}", args.out.join("ablation.{md,json}").display());
    Ok(())
}

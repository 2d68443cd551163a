//! `povins demo`: the whole product on a fresh machine with nothing else. Simulates the robot
//! scenario (camera + IMU + the Livox LiDAR, with ground truth), runs the estimator with LiDAR
//! enhancement from the true initial state, evaluates against ground truth (ATE, position + yaw
//! alignment) and the LiDAR association against the simulator's truth, plots, and prints
//! accuracy and timing. `--no-lidar` runs PO-VINS-WO.

use crate::config::{LidarArgs, ModeArg};
use crate::eval::{Alignment, EvalOptions};
use crate::plot::{plot, BackendSample};
use crate::progress::Progress;
use crate::report::{print_summary, summarize, write_outputs};
use crate::runner::{config_for, replay, InitMode};
use crate::sim::{self, Scenario, SimConfig};
use anyhow::Result;
use povins_platform::trajectory::StampedPose;
use std::path::PathBuf;

/// Arguments of `povins demo`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder (trajectory, statistics, summary, plot).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated duration, s.
    #[arg(long, default_value_t = 60.0)]
    pub duration: f64,
    /// Visual measurement model.
    #[arg(long, value_enum, default_value = "pose-only")]
    pub mode: ModeArg,
    /// LiDAR switches (LiDAR enhancement is on by default).
    #[command(flatten)]
    pub lidar: LidarArgs,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    eprintln!(
        "simulating the robot scenario ({} s, seed {})...",
        args.duration, args.seed
    );
    let sim_cfg = SimConfig::new(Scenario::Robot, args.seed, args.duration);
    let sim = sim::simulate(&sim_cfg, &|_, _, _| {})?;
    let ds = sim.dataset;
    let mut cfg = config_for(&ds);
    cfg.mode = args.mode.into();
    args.lidar.apply(&mut cfg.lidar);
    let mode = format!("{:?}", cfg.mode);
    let progress = Progress::new(ds.imu.len() as u64, "estimating");
    let out = replay(&ds, cfg, InitMode::Groundtruth, &progress)?;
    let summary = summarize(&ds, &mode, InitMode::Groundtruth, &out)?;
    write_outputs(&args.out, &out, &summary)?;
    let gt: Vec<StampedPose> = ds.ground_truth.iter().map(StampedPose::from).collect();
    let est: Vec<StampedPose> = out.imu_rate.iter().map(StampedPose::from).collect();
    let backend: Vec<BackendSample> = out
        .reports
        .iter()
        .map(|r| BackendSample {
            t_s: r.t_ns as f64 * 1e-9,
            backend_ms: r.backend_ns() as f64 * 1e-6,
        })
        .collect();
    let png = args.out.join("demo.png");
    let opts = EvalOptions {
        alignment: Alignment::PosYaw,
        ..Default::default()
    };
    plot(
        &gt,
        &est,
        &opts,
        Some(&backend),
        &format!("povins demo: {}", ds.name),
        &png,
    )?;
    print_summary(&summary, &args.out);
    println!("plot      {}", png.display());
    Ok(())
}

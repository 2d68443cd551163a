//! The `povins` command.

use clap::{Parser, Subcommand};
use povins_host_tools::cmd;

#[derive(Parser)]
#[command(
    name = "povins",
    version,
    about = "PO-VINS: pose-only visual-inertial state estimator"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Simulate the robot scenario, estimate, evaluate and plot (the README's main job).
    Demo(cmd::demo::Args),
    /// Simulate a camera + IMU + LiDAR sequence with ground truth.
    Simulate(cmd::simulate::Args),
    /// Evaluate an estimated trajectory against ground truth (ATE, RTE).
    Eval(cmd::eval::Args),
    /// Plot an estimate against ground truth (SVG or PNG).
    Plot(cmd::plot::Args),
    /// Replay a dataset through the estimator and evaluate it.
    Run(cmd::run::Args),
    /// What a ROS recording holds (bags, MCAP: topics, types, counts, rates, time span) and which
    /// topics `run` would use.
    Info(cmd::info::Args),
    /// Write a recording (EuRoC folder, MCAP, ROS 1 bag with --calib) as an EuRoC ASL folder.
    Convert(cmd::convert::Args),
    /// Record an Ouster sensor's UDP stream (or convert a pcap capture of it) as an EuRoC
    /// folder or MCAP file: LiDAR sweeps, IMU samples, the LiDAR-IMU extrinsic.
    Record(cmd::record::Args),
    /// Run the image front end alone: tracks, per-image statistics, pictures.
    Track(cmd::track::Args),
    /// Compare front ends' tracks on real images: counts, lengths, epipolar violations vs gyro.
    CompareTracks(cmd::compare_tracks::Args),
    /// Score feature tracks on a simulated sequence against the true motion of every pixel.
    ScoreTracks(cmd::score_tracks::Args),
    /// LiDAR ablation on simulated sequences (PO-VINS vs -WO, rejection, LDM, depth-only opt).
    Ablation(cmd::ablation::Args),
    /// Accuracy regression suite: shared sequences and simulator seeds against stored figures.
    Regress(cmd::regress::Args),
    /// Replay a dataset through the threaded real-time pipeline (--realtime); writes
    /// trajectory.tum and prints the timing table.
    Replay(cmd::replay::Args),
    /// The real-time pipeline's timing over a dataset (paced): per-stage latency, IMU-output
    /// latency, back-end lag, misses, drops.
    Timing(cmd::timing::Args),
}

/// Output piped into a reader that stopped (`povins run ... | head -1`) ends the command quietly
/// with exit 0, as for other command-line tools, instead of a panic in `println!`.
fn quiet_on_closed_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(0);
        }
        default(info);
    }));
}

fn main() -> anyhow::Result<()> {
    quiet_on_closed_pipe();
    // On the main thread's stack: the estimator and the image front end are built in place on
    // the heap (`povins_platform::boxed`), and processing needs no large stack.
    match Cli::parse().cmd {
        Cmd::Demo(a) => cmd::demo::run(a),
        Cmd::Simulate(a) => cmd::simulate::run(a),
        Cmd::Eval(a) => cmd::eval::run(a),
        Cmd::Plot(a) => cmd::plot::run(a),
        Cmd::Run(a) => cmd::run::run(a),
        Cmd::Info(a) => cmd::info::run(a),
        Cmd::Convert(a) => cmd::convert::run(a),
        Cmd::Record(a) => cmd::record::run(a),
        Cmd::Track(a) => cmd::track::run(a),
        Cmd::CompareTracks(a) => cmd::compare_tracks::run(a),
        Cmd::ScoreTracks(a) => cmd::score_tracks::run(a),
        Cmd::Ablation(a) => cmd::ablation::run(a),
        Cmd::Regress(a) => cmd::regress::run(a),
        Cmd::Replay(a) => cmd::replay::run(a),
        Cmd::Timing(a) => cmd::timing::run(a),
    }
}

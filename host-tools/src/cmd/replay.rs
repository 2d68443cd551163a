//! `povins replay --realtime DATASET --out DIR`: the onboard pipeline (see `povins timing`)
//! over a dataset, writing the IMU-rate poses it published to `DIR/trajectory.tum` and
//! printing the timing table (and, with `--mcap-out FILE`, an MCAP file of the poses for
//! Foxglove: [`McapSink`]; with `--mavlink ADDRESS`, the odometry to an autopilot:
//! [`MavlinkSink`]). With `--deterministic` the trajectory is bit-identical to
//! `povins run`'s on the same input and settings, with either front end (`--frontend tracks`,
//! or `images`: the pipeline's image front-end stage).

use super::timing::{run_pipeline_with, PipelineArgs, TimingSummary};
use crate::eval::streamed::{ate_rmse, PoseStream};
use crate::eval::{Alignment, EvalOptions};
use anyhow::{bail, Context, Result};
use povins_platform::pipeline::mavlink::{BodyAxes, Endpoint};
use povins_platform::pipeline::{
    FileOptions, FoxgloveOptions, FoxgloveSink, MavlinkOptions, MavlinkSink, McapOptions, McapSink,
    TumSink,
};
use povins_platform::trajectory::{tum_poses, StampedPose};
use std::path::PathBuf;

/// Arguments of `povins replay`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Run the threaded real-time pipeline (the only replay this command does; the
    /// single-threaded replay is `povins run`).
    #[arg(long)]
    pub realtime: bool,
    /// The pipeline's settings.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Output folder (created if missing).
    #[arg(long, default_value = "out/replay")]
    pub out: PathBuf,
    /// Also write the published poses to this MCAP file for Foxglove: `foxglove.PoseInFrame`
    /// (JSON) on /povins/pose at IMU rate and each keyframe's optimized state on
    /// /povins/keyframe. Written during the run and flushed every second: a run that is killed
    /// leaves a file readable up to its last second.
    #[arg(long, value_name = "FILE")]
    pub mcap_out: Option<PathBuf>,
    /// Also send the odometry to an autopilot over MAVLink (`ODOMETRY` in the local FRD
    /// frame, `HEARTBEAT`, answers to `TIMESYNC`): udpout:HOST:PORT, udpin:ADDR:PORT or
    /// serial:DEVICE:BAUD (README, "Odometry to PX4 or ArduPilot").
    #[arg(long, value_name = "ADDRESS")]
    pub mavlink: Option<String>,
    /// `ODOMETRY` messages per second of sensor time.
    #[arg(long, value_name = "HZ", default_value_t = 30.0, requires = "mavlink")]
    pub mavlink_rate: f64,
    /// The vehicle's forward, right and down axes as signed IMU axes (x,-y,-z: an IMU
    /// mounted forward-left-up; x,y,z: forward-right-down).
    #[arg(
        long,
        value_name = "F,R,D",
        default_value = "x,-y,-z",
        requires = "mavlink"
    )]
    pub mavlink_body_axes: String,
    /// The MAVLink system id to send as (the vehicle's).
    #[arg(long, value_name = "ID", default_value_t = 1, requires = "mavlink")]
    pub mavlink_sysid: u8,
    /// Also send `VISION_POSITION_ESTIMATE` (#102) with each `ODOMETRY` (ArduPilot setups that
    /// take that message).
    #[arg(long, requires = "mavlink")]
    pub mavlink_vision_position: bool,
    /// Serve the live pose (/povins/pose, 30 Hz), the keyframes' path (/povins/path) and the
    /// window's landmarks (/povins/landmarks) to the Foxglove app over its WebSocket protocol:
    /// PORT (on 127.0.0.1: this machine only) or HOST:PORT (e.g. 0.0.0.0:8765 for the network).
    #[arg(long, value_name = "[HOST:]PORT")]
    pub foxglove: Option<String>,
}

/// The Foxglove server of `args`, when asked for (started before the run, its address printed).
fn foxglove_sink(args: &Args) -> Result<Option<FoxgloveSink>> {
    let Some(addr) = &args.foxglove else {
        return Ok(None);
    };
    let opts = FoxgloveOptions::parse(addr).map_err(|e| anyhow::anyhow!("--foxglove {e}"))?;
    let host = opts.host.clone();
    let sink = FoxgloveSink::new(opts)?;
    let shown = if host.contains(':') {
        format!("[{host}]")
    } else {
        host
    };
    eprintln!(
        "foxglove: serving ws://{shown}:{} (open it in the Foxglove app: Open connection)",
        sink.port()
    );
    Ok(Some(sink))
}

/// The MAVLink sink of `args`, when asked for.
fn mavlink_sink(args: &Args) -> Result<Option<MavlinkSink>> {
    let Some(addr) = &args.mavlink else {
        return Ok(None);
    };
    let endpoint = Endpoint::parse(addr).map_err(anyhow::Error::msg)?;
    let axes = BodyAxes::parse(&args.mavlink_body_axes)
        .map_err(|e| anyhow::anyhow!("--mavlink-body-axes: {e}"))?;
    let opts = MavlinkOptions {
        rate_hz: args.mavlink_rate,
        system_id: args.mavlink_sysid,
        vision_position: args.mavlink_vision_position,
        axes,
        ..MavlinkOptions::new(endpoint)
    };
    let sink = MavlinkSink::new(opts).with_context(|| format!("--mavlink {addr}"))?;
    Ok(Some(sink))
}

/// The summary line of the MAVLink output; an error when it sent nothing it was given.
fn mavlink_summary(addr: &str, rate_hz: f64, sink: &MavlinkSink, poses: u64) -> Result<()> {
    let c = sink.counts();
    println!(
        "mavlink   {addr}: {} ODOMETRY ({rate_hz} Hz), {} VISION_POSITION_ESTIMATE, {} HEARTBEAT, \
         {} TIMESYNC answered ({} before the first pose), {} received, {} resets",
        c.odometry_sent,
        c.vision_position_sent,
        c.heartbeats_sent,
        c.timesync_answered,
        c.timesync_unanswered,
        c.received,
        c.resets
    );
    if c.odometry_dropped_queue + c.odometry_unsent > 0 {
        eprintln!(
            "warning: mavlink: {} ODOMETRY not sent ({} queue full, {} with no peer or refused)",
            c.odometry_dropped_queue + c.odometry_unsent,
            c.odometry_dropped_queue,
            c.odometry_unsent
        );
    }
    if let Some(e) = &c.first_error {
        eprintln!("warning: mavlink: {} errors, the first: {e}", c.errors);
    }
    if poses > 0 && c.odometry_sent == 0 {
        bail!("--mavlink {addr}: no ODOMETRY could be sent");
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    if !args.realtime {
        bail!("povins replay needs --realtime (the single-threaded replay is povins run)");
    }
    let rec = args.pipeline.run.open()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let path = args.out.join("trajectory.tum");
    let mcap = match &args.mcap_out {
        Some(f) => Some(
            McapSink::create(f, McapOptions::default())
                .with_context(|| format!("--mcap-out {}", f.display()))?,
        ),
        None => None,
    };
    let mavlink = mavlink_sink(&args)?;
    let foxglove = foxglove_sink(&args)?;
    let tum = TumSink::create(&path, FileOptions::default())?;
    let mut sinks = (((tum, mcap), mavlink), foxglove);
    // The autopilot gets the estimator's covariance with each pose.
    let covariance = args.mavlink.is_some();
    let report = run_pipeline_with(&args.pipeline, &*rec, &mut sinks, "replay", covariance)?;
    let (((sink, mcap), mavlink), foxglove) = sinks;
    if let Some(m) = &mcap {
        let c = m.counts();
        if c.dropped_queue > 0 {
            eprintln!(
                "warning: mcap: {} of {} outputs not written (the writer fell behind)",
                c.dropped_queue,
                c.dropped_queue + c.poses + c.keyframes
            );
        }
    }
    for line in TimingSummary::new(&*rec, &args.pipeline, &report)?.lines() {
        println!("{line}");
    }
    let written = sink.counts();
    if written.dropped_queue > 0 {
        bail!(
            "{}: {} of {} poses not written (the writer fell behind): the trajectory is partial",
            path.display(),
            written.dropped_queue,
            written.dropped_queue + written.poses
        );
    }
    if rec.contents().ground_truth && written.poses > 0 {
        // Both sides as streams, neither held: the ground truth read from the recording and the
        // trajectory from its file, once per pass.
        let gt = || -> Result<PoseStream<'_>> {
            Ok(Box::new(rec.ground_truth_stream()?.map(|s| {
                s.map(|s| StampedPose::from(&s))
                    .map_err(anyhow::Error::from)
            })))
        };
        let est = || -> Result<PoseStream<'_>> {
            Ok(Box::new(
                tum_poses(&path)?.map(|p| p.map_err(anyhow::Error::from)),
            ))
        };
        let opts = EvalOptions {
            alignment: Alignment::PosYaw,
            ..Default::default()
        };
        match ate_rmse(&gt, &est, &opts) {
            Ok(r) => println!(
                "ATE       {:.4} m, {:.3} deg (posyaw-aligned, {} poses)",
                r.pos_rmse_m, r.rot_rmse_deg, r.matched
            ),
            Err(e) => eprintln!("warning: evaluation failed: {e:#}"),
        }
    }
    if let (Some(m), Some(addr)) = (&mavlink, &args.mavlink) {
        mavlink_summary(addr, args.mavlink_rate, m, written.poses)?;
    }
    if let Some(f) = &foxglove {
        let c = f.counts();
        println!(
            "foxglove  port {}: {} poses, {} paths, {} landmark updates published",
            f.port(),
            c.poses,
            c.paths,
            c.landmark_updates
        );
        if c.dropped_queue + c.landmarks_skipped > 0 {
            eprintln!(
                "warning: foxglove: {} outputs dropped (queue full), {} keyframes' landmarks skipped",
                c.dropped_queue, c.landmarks_skipped
            );
        }
    }
    println!("output    {}", path.display());
    if let (Some(m), Some(f)) = (&mcap, &args.mcap_out) {
        let c = m.counts();
        println!(
            "mcap      {} ({} poses, {} keyframes, flushed {} times during the run)",
            f.display(),
            c.poses,
            c.keyframes,
            c.flushes
        );
    }
    Ok(())
}

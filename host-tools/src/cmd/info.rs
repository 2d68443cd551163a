//! `povins info RECORDING`: what a recording holds, for every container `containers::open_log`
//! reads (ROS 1 bags, ROS 2 bags, MCAP files): its format, topics, types, message counts, mean
//! rates over each topic's span, time span, the container's warnings, and which topics `run`
//! would use. `--read-all` also reads and decodes every message of the chosen IMU and camera
//! topics through `rosrec::decode` (the reading speed in messages and MB per second, every
//! decoding error with its message index, corrupt parts counted and skipped). With `--calib`
//! (and `--imu-calib`, `--camera`) the calibration found in those files and the topics `run`
//! would use with their Kalibr `rostopic`s; without it, the calibration the recording carries
//! (its CameraInfo and `/tf_static`), or why there is none.

use crate::config::{InputArgs, InputOptions};
use anyhow::{bail, Context, Result};
use povins_platform::containers::open_log;
use povins_platform::rosrec::topics::TopicChoice;
use povins_platform::rosrec::{decode, topics, MessageLog, TopicInfo};
use povins_platform::IoError;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// Arguments of `povins info`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording: a ROS 1 `.bag`, a ROS 2 bag folder or `.db3` file, an `.mcap` file.
    pub recording: PathBuf,
    /// The topics and the calibration files (as for `povins run`).
    #[command(flatten)]
    pub input: InputArgs,
    /// Read and decode every message of the chosen topics.
    #[arg(long)]
    pub read_all: bool,
}

/// Runs `povins info`.
pub fn run(a: Args) -> Result<()> {
    let input = InputOptions::new(None, &a.input)?;
    if input.calib.is_none() && input.camera.is_some() {
        bail!("--camera needs --calib (a Kalibr camchain)");
    }
    let log = open_log(&a.recording)?;
    if !povins_platform::containers::is_ros_recording(&a.recording) {
        // povins' own MCAP: fixed topics and the calibration in the file (docs/formats.md).
        let rec = povins_platform::mcap_io::McapRecording::open(&a.recording)?;
        print!("{}{}", table(log.as_ref()), own_mcap(&rec));
        return Ok(());
    }
    let all = log.topics();
    let (choice, calib) = match input.calibration_files(log.as_ref()) {
        Ok(found) => {
            let kalibr_imu = found.imu.as_ref().and_then(|i| i.rostopic.as_deref());
            let choice = input.topic_choice(&all, kalibr_imu, found.camera.rostopic.as_deref());
            (choice, found.describe())
        }
        Err(e) if input.calib.is_none() => (
            input.topic_choice(&all, None, None),
            format!("calib     none in the recording: {e:#}\n"),
        ),
        Err(e) => return Err(e),
    };
    print!("{}", summary(log.as_ref(), &choice));
    print!("{calib}");
    if a.read_all {
        print!("{}", read_all(log.as_ref(), &choice)?);
    }
    Ok(())
}

/// What `povins run` reads of povins' own MCAP file.
fn own_mcap(rec: &povins_platform::mcap_io::McapRecording) -> String {
    use povins_platform::recording::Recording;
    let c = rec.contents();
    let calib = rec.calibration();
    let cam = &calib.camera;
    let yes = |b: bool, what: &str| {
        if b {
            what.to_string()
        } else {
            format!("no {what}")
        }
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "run uses  povins' own MCAP layout: {}, {}, {}, {}, {}{}",
        yes(c.imu, "IMU"),
        yes(c.frames, "feature tracks"),
        yes(c.images, "images"),
        yes(c.lidar, "LiDAR"),
        yes(c.ground_truth, "ground truth"),
        if rec.has_sim_truth() {
            ", simulator truth (evaluation only)"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "calib     the file's povins.calibration metadata: camera {}x{} fx {} fy {} cx {} cy {}, \
         td_s {} s{}",
        cam.width,
        cam.height,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        calib.td_s,
        match calib.t_bl {
            Some(_) => format!(", T_bl, td_l_s {} s", calib.td_l_s),
            None => String::new(),
        }
    );
    s
}

/// Bytes of a file, or of the files of a folder.
fn size_of(path: &Path) -> u64 {
    if path.is_dir() {
        std::fs::read_dir(path)
            .map(|d| {
                d.filter_map(|e| e.ok()?.metadata().ok())
                    .filter(|m| m.is_file())
                    .map(|m| m.len())
                    .sum()
            })
            .unwrap_or(0)
    } else {
        std::fs::metadata(path).map_or(0, |m| m.len())
    }
}

fn secs(ns: i64) -> f64 {
    ns as f64 * 1e-9
}

/// The summary of a recording, as `info` prints it.
/// The file, its format, time span and topics.
fn table(log: &dyn MessageLog) -> String {
    let mut s = String::new();
    let path = log.path();
    let _ = writeln!(s, "file      {} ({} bytes)", path.display(), size_of(path));
    let _ = writeln!(s, "format    {}", log.describe());
    let all = log.topics();
    let start = all.iter().filter_map(|t| t.span_ns).map(|s| s.0).min();
    let end = all.iter().filter_map(|t| t.span_ns).map(|s| s.1).max();
    match (start, end) {
        (Some(a), Some(b)) => {
            let _ = writeln!(
                s,
                "time      {:.3} .. {:.3} s ({:.3} s)",
                secs(a),
                secs(b),
                secs(b - a)
            );
        }
        _ => {
            let _ = writeln!(s, "time      no messages");
        }
    }
    let total: u64 = all.iter().map(|t| t.count).sum();
    let _ = writeln!(s, "messages  {total}");
    let w = all.iter().map(|t| t.topic.len()).max().unwrap_or(5).max(5);
    let tw = all
        .iter()
        .map(|t| t.msg_type.len())
        .max()
        .unwrap_or(4)
        .max(4);
    let _ = writeln!(
        s,
        "\n{:w$}  {:tw$}  {:>8}  {:>9}",
        "topic", "type", "messages", "rate_hz"
    );
    for t in &all {
        let rate = match t.span_ns {
            Some((a, b)) if b > a && t.count > 1 => {
                format!("{:.2}", t.count.saturating_sub(1) as f64 / secs(b - a))
            }
            _ => "-".into(),
        };
        let _ = writeln!(
            s,
            "{:w$}  {:tw$}  {:>8}  {:>9}",
            t.topic, t.msg_type, t.count, rate
        );
    }
    let _ = writeln!(s);
    s
}

/// What `povins info` says of a recording: [`table`], then the topics `povins run` would read.
pub fn summary(log: &dyn MessageLog, choice: &TopicChoice) -> String {
    let mut s = table(log);
    let all = log.topics();
    match topics::select_with(&all, choice) {
        Ok(sel) => {
            let name = |t: &Option<TopicInfo>| {
                t.as_ref()
                    .map_or_else(|| "none".to_string(), |t| t.topic.clone())
            };
            let _ = writeln!(
                s,
                "run uses  IMU {}, camera {}",
                name(&sel.imu),
                name(&sel.camera)
            );
            if let Some(a) = &sel.accel {
                let _ = writeln!(
                    s,
                    "          accelerometer {} merged into the IMU's samples",
                    a.topic
                );
            }
            match (&sel.lidar, &sel.lidar_note) {
                (Some(l), _) => {
                    let _ = writeln!(s, "          LiDAR {} ({})", l.topic, l.msg_type);
                }
                (None, Some(note)) => {
                    let _ = writeln!(s, "          LiDAR none: {note}");
                }
                (None, None) => {}
            }
            if sel.imu.is_none() || sel.camera.is_none() {
                let _ = writeln!(
                    s,
                    "          (run needs a sensor_msgs/Imu and a sensor_msgs/Image or \
                     CompressedImage topic)"
                );
            }
        }
        Err(e) => {
            let _ = writeln!(s, "run uses  cannot choose: {e}");
        }
    }
    if let Some(t) = all.iter().find(|t| t.msg_type.ends_with("/PacketMsg")) {
        let _ = writeln!(
            s,
            "note      {} carries raw sensor packets ({}): a LiDAR needs the driver's \
             sensor_msgs/PointCloud2 or Livox CustomMsg topic (replay the packets through the \
             driver)",
            t.topic, t.msg_type
        );
    }
    for warn in &log.warnings() {
        let _ = writeln!(s, "warning: {warn}");
    }
    s
}

/// Decodes every message of the chosen topics; the counts and the reading speed.
fn read_all(log: &dyn MessageLog, choice: &TopicChoice) -> Result<String> {
    let sel = topics::select_with(&log.topics(), choice).map_err(anyhow::Error::msg)?;
    let mut s = String::new();
    for t in [sel.imu, sel.accel, sel.camera].into_iter().flatten() {
        let t0 = std::time::Instant::now();
        let (mut n, mut bytes, mut skipped) = (0u64, 0u64, 0u64);
        for m in log.messages(&t.topic) {
            let m = match m {
                Ok(m) => m,
                Err(e @ IoError::Corrupt { .. }) => {
                    skipped += 1;
                    let _ = writeln!(s, "warning: {}: {e} (skipped)", t.topic);
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            let res = if t.msg_type == decode::IMU_TYPE {
                decode::imu(t.encoding, &m.data).map(drop)
            } else {
                decode::image(t.encoding, &t.msg_type, &m.data).map(drop)
            };
            res.map_err(|e| anyhow::anyhow!("byte {} of the message: {}", e.offset, e.msg))
                .with_context(|| {
                    format!(
                        "{}: {} message {n} ({}, record at byte offset {})",
                        log.path().display(),
                        t.topic,
                        t.msg_type,
                        m.offset
                    )
                })?;
            n += 1;
            bytes += m.data.len() as u64;
        }
        let dt = t0.elapsed().as_secs_f64().max(1e-9);
        let _ = writeln!(
            s,
            "read      {}: {n} messages decoded in {dt:.3} s ({:.0} messages/s, {:.1} MB/s){}",
            t.topic,
            n as f64 / dt,
            bytes as f64 / dt * 1e-6,
            if skipped > 0 {
                format!(", {skipped} corrupt parts skipped")
            } else {
                String::new()
            }
        );
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(rel: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/data")
            .join(rel)
    }

    #[test]
    fn povins_own_mcap_is_described_not_chosen_from() {
        use crate::sim::{self, Scenario, SimConfig};
        let mut c = SimConfig::new(Scenario::Handheld, 1, 2.0);
        c.threads = 1;
        let ds = sim::simulate(&c, &|_, _, _| {}).unwrap().dataset;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.mcap");
        povins_platform::mcap_io::write_dataset(&path, &ds).unwrap();
        assert!(!povins_platform::containers::is_ros_recording(&path));
        let rec = povins_platform::mcap_io::McapRecording::open(&path).unwrap();
        let s = own_mcap(&rec);
        assert!(
            s.contains("run uses  povins' own MCAP layout: IMU, feature tracks, no images, LiDAR")
                && s.contains("simulator truth (evaluation only)")
                && s.contains("camera 752x480"),
            "{s}"
        );
        // The ROS view of the same file cannot choose its IMU (the truth's biases are an Imu).
        let log = open_log(&path).unwrap();
        let ros = summary(log.as_ref(), &TopicChoice::default());
        assert!(ros.contains("cannot choose: 2 IMU topics"), "{ros}");
    }

    #[test]
    fn summary_of_the_sim_bag() {
        let log = open_log(&data("rosbag1-sim/sim.bag")).unwrap();
        let s = summary(log.as_ref(), &TopicChoice::default());
        assert!(s.contains("indexed, 15 chunks"), "{s}");
        assert!(s.contains("1.000 .. 3.000 s (2.000 s)"), "{s}");
        assert!(s.contains("messages  443"), "{s}");
        // IMU: 401 samples over 2 s.
        let imu: Vec<&str> = s
            .lines()
            .find(|l| l.starts_with("/imu0 "))
            .unwrap()
            .split_whitespace()
            .collect();
        assert_eq!(imu, ["/imu0", "sensor_msgs/Imu", "401", "200.00"]);
        assert!(s.contains("cannot choose: 2 camera topics"), "{s}");
        let s = summary(
            log.as_ref(),
            &TopicChoice {
                image: Some("/cam0/image_raw".into()),
                ..TopicChoice::default()
            },
        );
        assert!(
            s.contains("run uses  IMU /imu0, camera /cam0/image_raw"),
            "{s}"
        );
        let r = read_all(
            log.as_ref(),
            &TopicChoice {
                image: Some("/cam0/gray_png".into()),
                ..TopicChoice::default()
            },
        )
        .unwrap();
        assert!(
            r.contains("/imu0: 401 messages") && r.contains("/cam0/gray_png: 14"),
            "{r}"
        );
        assert!(r.contains("messages/s") && r.contains("MB/s"), "{r}");
    }

    #[test]
    fn summary_of_every_container() {
        for (rel, format) in [
            ("ros2-sim/sqlite3", "ROS 2 bag, sqlite3 storage, 2 files"),
            ("ros2-sim/mcap", "ROS 2 bag, mcap storage"),
            ("ros2-sim/ros1.mcap", "MCAP, with summary"),
            (
                "ros2-sim/cdr-nosummary.mcap",
                "MCAP, no usable summary: scanned",
            ),
        ] {
            let log = open_log(&data(rel)).unwrap();
            let s = summary(
                log.as_ref(),
                &TopicChoice {
                    image: Some("/cam0/image_raw".into()),
                    ..TopicChoice::default()
                },
            );
            assert!(s.contains(format), "{rel}: {s}");
            assert!(s.contains("1.000 .. 3.000 s (2.000 s)"), "{rel}: {s}");
            assert!(s.contains("messages  443"), "{rel}: {s}");
            let imu: Vec<&str> = s
                .lines()
                .find(|l| l.starts_with("/imu0 "))
                .unwrap()
                .split_whitespace()
                .collect();
            assert_eq!(imu, ["/imu0", "sensor_msgs/Imu", "401", "200.00"], "{rel}");
            assert!(!s.contains("warning"), "{rel}: {s}");
            let r = read_all(
                log.as_ref(),
                &TopicChoice {
                    image: Some("/cam0/image_raw".into()),
                    ..TopicChoice::default()
                },
            )
            .unwrap();
            assert!(
                r.contains("/imu0: 401 messages") && r.contains("/cam0/image_raw: 14"),
                "{rel}: {r}"
            );
        }
    }
}

//! `povins info RECORDING`: what a recording holds (for a ROS 1 bag: topics, types, message
//! counts, mean rates over the bag's span, time span, chunks, index state and warnings) and which topics `run`
//! would use; with `--calib` (and `--imu-calib`, `--camera`) the calibration found in those
//! files, and the topics `run` would use with their Kalibr `rostopic`s. `--read-all` also reads and decodes every message of the chosen IMU and camera
//! topics (the reading speed, and every decoding error with its message index).

use crate::config::{InputArgs, InputOptions};
use anyhow::{bail, Context, Result};
use povins_platform::rosbag1::{msgs, Bag};
use povins_platform::rosrec::{topics, MessageLog};
use std::fmt::Write;
use std::path::PathBuf;

/// Arguments of `povins info`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording (a ROS 1 `.bag` file).
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
    let is_bag = a.recording.extension().is_some_and(|e| e == "bag");
    if !is_bag {
        bail!(
            "{}: `info` reads ROS 1 bags (.bag) so far",
            a.recording.display()
        );
    }
    let input = InputOptions::new(None, &a.input)?;
    let bag = Bag::open(&a.recording)?;
    let mut calib = String::new();
    let (imu, image) = if input.calib.is_some() {
        let found = input.calibration_files(&bag)?;
        calib = found.describe();
        let kalibr_imu = found.imu.as_ref().and_then(|i| i.rostopic.as_deref());
        let c = input.topic_choice(&bag.topics(), kalibr_imu, found.camera.rostopic.as_deref());
        (c.imu, c.image)
    } else if input.imu_calib.is_some() || input.camera.is_some() {
        bail!("--imu-calib and --camera need --calib");
    } else {
        (input.imu_topic.clone(), input.image_topic.clone())
    };
    print!("{}", bag_summary(&bag, imu.as_deref(), image.as_deref()));
    print!("{calib}");
    if a.read_all {
        print!("{}", read_all(&bag, imu.as_deref(), image.as_deref())?);
    }
    Ok(())
}

fn secs(ns: i64) -> f64 {
    ns as f64 * 1e-9
}

/// The summary of a bag, as `info` prints it.
pub fn bag_summary(bag: &Bag, imu: Option<&str>, camera: Option<&str>) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "file      {} ({} bytes)",
        bag.path.display(),
        bag.file_len
    );
    let index = if bag.indexed {
        "indexed"
    } else {
        "no usable index: scanned"
    };
    let _ = writeln!(
        s,
        "format    ROS 1 bag v2.0, {index}, {} chunks",
        bag.chunks.len()
    );
    let start = bag.chunks.iter().map(|c| c.start_ns).min();
    let end = bag.chunks.iter().map(|c| c.end_ns).max();
    let span_s = match (start, end) {
        (Some(a), Some(b)) => {
            let _ = writeln!(
                s,
                "time      {:.3} .. {:.3} s ({:.3} s)",
                secs(a),
                secs(b),
                secs(b - a)
            );
            secs(b - a)
        }
        _ => {
            let _ = writeln!(s, "time      no messages");
            0.0
        }
    };
    let all = bag.topics();
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
        let rate = if span_s > 0.0 && t.count > 1 {
            format!("{:.2}", t.count.saturating_sub(1) as f64 / span_s)
        } else {
            "-".into()
        };
        let _ = writeln!(
            s,
            "{:w$}  {:tw$}  {:>8}  {:>9}",
            t.topic, t.msg_type, t.count, rate
        );
    }
    let _ = writeln!(s);
    match topics::select(&bag.topics(), imu, camera) {
        Ok(sel) => {
            let name = |t: &Option<povins_platform::rosrec::TopicInfo>| {
                t.as_ref()
                    .map_or_else(|| "none".to_string(), |t| t.topic.clone())
            };
            let _ = writeln!(
                s,
                "run uses  IMU {}, camera {}",
                name(&sel.imu),
                name(&sel.camera)
            );
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
             sensor_msgs/PointCloud2 topic (replay the packets through the driver)",
            t.topic, t.msg_type
        );
    }
    for warn in &bag.warnings {
        let _ = writeln!(s, "warning: {warn}");
    }
    s
}

/// Decodes every message of the chosen topics; the counts and the reading speed.
fn read_all(bag: &Bag, imu: Option<&str>, camera: Option<&str>) -> Result<String> {
    let sel = topics::select(&bag.topics(), imu, camera).map_err(anyhow::Error::msg)?;
    let mut s = String::new();
    for t in [sel.imu, sel.camera].into_iter().flatten() {
        let t0 = std::time::Instant::now();
        let conns = bag.topic_conns(&t.topic);
        let mut n = 0usize;
        for (k, m) in bag.conn_messages(conns).enumerate() {
            let m = m?;
            let res = if t.msg_type == msgs::IMU_TYPE {
                msgs::imu(&m.data).map(drop)
            } else {
                msgs::any_image(&t.msg_type, &m.data).map(drop)
            };
            res.map_err(|e| anyhow::anyhow!("byte {}: {}", e.offset, e.msg))
                .with_context(|| format!("{} message {k} ({})", t.topic, t.msg_type))?;
            n += 1;
        }
        let _ = writeln!(
            s,
            "read      {}: {n} messages decoded in {:.3} s",
            t.topic,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_of_the_sim_bag() {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/data/rosbag1-sim/sim.bag");
        let bag = Bag::open(&p).unwrap();
        let s = bag_summary(&bag, None, None);
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
        let s = bag_summary(&bag, None, Some("/cam0/image_raw"));
        assert!(
            s.contains("run uses  IMU /imu0, camera /cam0/image_raw"),
            "{s}"
        );
        let r = read_all(&bag, None, Some("/cam0/gray_png")).unwrap();
        assert!(
            r.contains("/imu0: 401 messages") && r.contains("/cam0/gray_png: 14"),
            "{r}"
        );
    }
}

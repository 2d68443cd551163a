//! `povins simulate --format rosbag2-sqlite3|rosbag2-mcap|mcap-ros1`, through the binary:
//! - each recording, run with the calibration written beside it, gives the byte-identical
//!   `trajectory.tum` and `keyframes_state.csv` as the EuRoC folder of the same simulation;
//! - independent readers (Python `rosbags` for the ROS 2 bags, PyPI `mcap` +
//!   `mcap-ros1-support` for the MCAP of ROS 1 messages) read every message back, with the
//!   simulation's stamps, values and counts (ignored: needs python3 and PyPI);
//! - a ROS 2 bag is not written into a non-empty folder; `--compression` is for ROS 1 bags only.

mod common;

use common::{povins, rosbags_python, simulate_handheld};
use std::path::{Path, PathBuf};

/// The new formats, and the name of the recording each writes.
const FORMATS: [(&str, &str); 3] = [
    ("rosbag2-sqlite3", "sim-sqlite3"),
    ("rosbag2-mcap", "sim-mcap"),
    ("mcap-ros1", "sim-ros1.mcap"),
];

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// `povins simulate` of the hand-held sequence with images (and LiDAR when `lidar`).
fn simulate(format: &str, out: &Path, seconds: &str, lidar: bool) {
    let extra: &[&str] = if lidar { &[] } else { &["--lidar", "none"] };
    simulate_handheld(format, out, seconds, extra);
}

/// `povins run RECORDING...` -> (trajectory.tum, keyframes_state.csv).
fn run(recording: &[&str], out: &Path) -> (Vec<u8>, Vec<u8>) {
    let mut args = vec!["run"];
    args.extend_from_slice(recording);
    args.extend_from_slice(&["--out", s(out)]);
    let (ok, _, err) = povins(&args);
    assert!(ok, "povins {args:?} failed: {err}");
    (
        std::fs::read(out.join("trajectory.tum")).expect("trajectory.tum"),
        std::fs::read(out.join("keyframes_state.csv")).expect("keyframes_state.csv"),
    )
}

fn calib_dir(rec: &Path) -> PathBuf {
    let stem = rec.file_stem().unwrap().to_string_lossy();
    rec.with_file_name(format!("{stem}-calib"))
}

#[test]
fn simulated_recordings_replay_to_the_euroc_folders_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("euroc");
    simulate("euroc", &euroc, "4", false);
    let want = run(&[s(&euroc)], &dir.path().join("run-euroc"));
    assert!(
        want.0.len() > 20_000,
        "trajectory too short: {} bytes",
        want.0.len()
    );
    assert!(want.1.len() > 1_000, "keyframes too short");
    for (format, name) in FORMATS {
        let rec = dir.path().join(name);
        simulate(format, &rec, "4", false);
        let calib = calib_dir(&rec);
        for f in ["camchain-imucam.yaml", "imu.yaml", "mav0/cam0/sensor.yaml"] {
            assert!(calib.join(f).is_file(), "{format}: no {f} beside it");
        }
        let got = run(
            &[s(&rec), "--calib", s(&calib)],
            &dir.path().join(format!("run-{format}")),
        );
        assert!(got.0 == want.0, "{format}: trajectory.tum differs");
        assert!(got.1 == want.1, "{format}: keyframes_state.csv differs");
    }
}

/// `--image-encoding jpeg=90`: the images go as `sensor_msgs/CompressedImage` on
/// `<topic>/compressed` (the Kalibr `rostopic` says so, and `run` picks it), are decoded, and the
/// run tracks the same sequence: as many keyframes within 10%, the trajectory's end within
/// 0.5 m of the raw run's (a 4 s walk). JPEG on a ROS 2 bag is read the same way. Raw encoding is
/// refused without images.
#[test]
fn jpeg_images_in_a_bag_are_decoded_and_tracked() {
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("euroc");
    simulate("euroc", &euroc, "4", false);
    let raw = run(&[s(&euroc)], &dir.path().join("run-raw"));
    let end = |tum: &[u8]| -> [f64; 3] {
        let text = String::from_utf8_lossy(tum);
        let last = text
            .lines()
            .rev()
            .find(|l| !l.starts_with('#'))
            .unwrap_or("");
        let v: Vec<f64> = last
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect();
        assert!(v.len() >= 4, "bad TUM row {last:?}");
        [v[1], v[2], v[3]]
    };
    let rows = |csv: &[u8]| String::from_utf8_lossy(csv).lines().count();
    for format in ["rosbag1", "rosbag2-sqlite3"] {
        let rec = dir.path().join(format!("jpeg-{format}.bag"));
        let rec = if format == "rosbag1" {
            rec
        } else {
            rec.with_extension("")
        };
        let err = simulate_handheld(
            format,
            &rec,
            "4",
            &["--lidar", "none", "--image-encoding", "jpeg=90"],
        );
        assert!(
            err.contains("/camera/infra1/image_rect_raw/compressed"),
            "{format}: no compressed topic named: {err}"
        );
        let calib = calib_dir(&rec);
        let camchain = std::fs::read_to_string(calib.join("camchain-imucam.yaml")).unwrap();
        assert!(camchain.contains("image_rect_raw/compressed"), "{camchain}");
        let got = run(
            &[
                s(&rec),
                "--calib",
                s(&calib.join("camchain-imucam.yaml")),
                "--imu-calib",
                s(&calib.join("imu.yaml")),
            ],
            &dir.path().join(format!("run-jpeg-{format}")),
        );
        let (a, b) = (rows(&raw.1) as f64, rows(&got.1) as f64);
        assert!(
            (a - b).abs() <= 0.1 * a,
            "{format}: {b} keyframe rows against {a} raw"
        );
        let (p, q) = (end(&raw.0), end(&got.0));
        let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        assert!(d < 0.5, "{format}: JPEG run ends {d:.3} m from the raw run");
    }
    let (ok, _, err) = povins(&[
        "simulate",
        "--duration",
        "0.5",
        "--lidar",
        "none",
        "--format",
        "rosbag1",
        "--image-encoding",
        "jpeg",
        "--out",
        s(&dir.path().join("noimg.bag")),
    ]);
    assert!(!ok && err.contains("--images"), "{err}");
}

#[test]
fn a_ros2_bag_needs_a_new_folder_and_compression_is_for_ros1_bags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bag");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), "x").unwrap();
    let base = [
        "simulate",
        "--duration",
        "0.5",
        "--lidar",
        "none",
        "--format",
        "rosbag2-sqlite3",
        "--out",
        s(&out),
    ];
    let (ok, _, err) = povins(&base);
    assert!(!ok, "a bag was written into a non-empty folder");
    assert!(err.contains("not empty") && err.contains("bag"), "{err}");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1);

    let mut args = base.to_vec();
    args.extend_from_slice(&["--compression", "lz4"]);
    let (ok, _, err) = povins(&args);
    assert!(!ok, "--compression accepted for a ROS 2 bag");
    assert!(err.contains("--compression"), "{err}");
}

/// The Python interpreter with `rosbags`, `mcap` and `mcap-ros1-support`:
#[test]
#[ignore = "needs python3 and PyPI (installs rosbags, mcap, mcap-ros1-support into target/pyenv-rosbags)"]
fn independent_readers_read_our_recordings() {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/check_ros_recording.py");
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("euroc");
    simulate("euroc", &euroc, "2", true);
    let ds = povins_platform::read_dataset(&euroc).unwrap();
    assert!(!ds.imu.is_empty() && !ds.images.is_empty() && !ds.lidar.is_empty());
    let py = rosbags_python();
    for (format, name) in FORMATS {
        let rec = dir.path().join(name);
        simulate(format, &rec, "2", true);
        let out = std::process::Command::new(&py)
            .arg(&script)
            .arg(&rec)
            .output()
            .expect("python runs");
        assert!(
            out.status.success(),
            "{format}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let topics = v["topics"].as_object().unwrap();
        assert_eq!(topics.len(), 3, "{format}: {:?}", topics.keys());
        let want_type = if format.starts_with("rosbag2") {
            "sensor_msgs/msg/Imu"
        } else {
            "sensor_msgs/Imu"
        };
        let imu = &topics["/camera/imu"];
        assert_eq!(imu["type"].as_str(), Some(want_type), "{format}");
        let msgs = imu["messages"].as_array().unwrap();
        assert_eq!(msgs.len(), ds.imu.len(), "{format}: IMU count");
        assert_eq!(imu["count"].as_u64(), Some(ds.imu.len() as u64));
        for (g, s) in msgs.iter().zip(&ds.imu) {
            assert_eq!(g["t"].as_i64(), Some(s.t_ns), "{format}");
            assert_eq!(g["stamp"].as_i64(), Some(s.t_ns), "{format}");
            assert_eq!(g["frame_id"].as_str(), Some("camera_imu_optical_frame"));
            for i in 0..3 {
                assert_eq!(g["gyro"][i].as_u64(), Some(s.gyro_rps[i].to_bits()));
                assert_eq!(g["accel"][i].as_u64(), Some(s.accel_mps2[i].to_bits()));
            }
            assert_eq!(g["ocov0"].as_u64(), Some((-1.0f64).to_bits()));
        }
        let images = topics["/camera/infra1/image_rect_raw"]["messages"]
            .as_array()
            .unwrap();
        assert_eq!(images.len(), ds.images.len(), "{format}: image count");
        for (g, im) in images.iter().zip(&ds.images) {
            let (w, h, px) =
                povins_platform::euroc::read_png_mono8(im.path.as_ref().unwrap()).unwrap();
            assert_eq!(g["stamp"].as_i64(), Some(im.t_ns), "{format}");
            assert_eq!(
                (g["width"].as_u64(), g["height"].as_u64()),
                (Some(w.into()), Some(h.into()))
            );
            assert_eq!(g["encoding"].as_str(), Some("mono8"));
            assert_eq!(g["step"].as_u64(), Some(w.into()));
            let sum: u64 = px.iter().map(|&b| u64::from(b)).sum();
            assert_eq!(
                g["sum"].as_u64(),
                Some(sum),
                "{format}: pixels at {}",
                im.t_ns
            );
        }
        let sweeps = topics["/lidar/points"]["messages"].as_array().unwrap();
        assert_eq!(sweeps.len(), ds.lidar.len(), "{format}: sweep count");
        for (g, sw) in sweeps.iter().zip(&ds.lidar) {
            assert_eq!(g["stamp"].as_i64(), Some(sw.t_ns), "{format}");
            assert_eq!(g["points"].as_u64(), Some(sw.points.len() as u64));
        }
    }
}

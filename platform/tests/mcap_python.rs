//! External validation: the official Python `mcap` reader and `mcap-ros2-support` decoder must
//! read and decode every message povins writes (`scripts/check_mcap.py`).
//!
//! The venv lives in `<repo>/target/pyenv-mcap` and is created on first use (needs `python3` with
//! `venv` and access to PyPI). Without them the test fails with a message saying so.

mod common;

use common::synthetic;
use povins_platform::mcap_io::write_dataset;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn run(cmd: &mut Command, what: &str) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: could not start {cmd:?}: {e} (is python3 installed?)"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The venv's python with `mcap` and `mcap-ros2-support`, installing them when missing.
fn python() -> PathBuf {
    let venv = repo().join("target").join("pyenv-mcap");
    let py = venv.join("bin").join("python");
    if !py.exists() {
        run(
            Command::new("python3").arg("-m").arg("venv").arg(&venv),
            "creating the venv (python3 -m venv)",
        );
    }
    let ready = Command::new(&py)
        .args(["-c", "import mcap, mcap_ros2.decoder"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ready {
        run(
            Command::new(&py).args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
                "mcap",
                "mcap-ros2-support",
            ]),
            "pip install mcap mcap-ros2-support",
        );
    }
    py
}

#[test]
fn official_python_tools_decode_every_message() {
    let py = python();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("syn.mcap");
    let ds = synthetic("syn");
    write_dataset(&file, &ds).unwrap();
    let out = run(
        Command::new(&py)
            .arg(repo().join("scripts").join("check_mcap.py"))
            .arg(&file),
        "scripts/check_mcap.py",
    );
    let lines: Vec<&str> = out.lines().collect();
    let t0 = ds.imu[0].t_ns;
    let f0 = ds.features[0].t_ns;
    let truth_stamps = common::sim_truth_stamps(&ds);
    let expected = [
        format!("topic /cam0/features sensor_msgs/msg/PointCloud 5 {f0}"),
        format!(
            "topic /cam0/image_raw sensor_msgs/msg/Image 3 {}",
            ds.images[0].t_ns
        ),
        format!(
            "topic /groundtruth nav_msgs/msg/Odometry 10 {}",
            ds.ground_truth[0].t_ns
        ),
        format!(
            "topic /groundtruth/imu_bias sensor_msgs/msg/Imu 10 {}",
            ds.ground_truth[0].t_ns
        ),
        format!("topic /imu0 sensor_msgs/msg/Imu 100 {t0}"),
        format!(
            "topic /lidar0/points sensor_msgs/msg/PointCloud2 2 {}",
            ds.lidar[0].t_ns
        ),
        // The simulator's truth: a message per stamp at which ids are first seen (ids never
        // seen at the first frame's).
        format!(
            "topic /povins/sim_truth/landmarks json {} {}",
            truth_stamps.len(),
            truth_stamps[0]
        ),
        // 16 keys, and `td_l_s` as the dataset's LiDAR has a time offset.
        "metadata povins.calibration 17".to_string(),
    ];
    assert_eq!(lines, expected, "{out}");
}

//! LiDAR sweeps in every driver layout (`povins_platform::cloud`), through the binary:
//! - a simulated ROS 1 bag with LiDAR, its sweeps written in each layout (`povins simulate
//!   --lidar-layout`), replays to the EuRoC folder's trajectory: byte-identical in povins'
//!   compact layout and within 1 mm in every driver's (float times round to the ns);
//! - the same in a ROS 2 bag for the CDR encoders (`velodyne`, `livox2-custom`);
//! - sweeps written by an independent writer (Python `rosbags`, `scripts/write_lidar_layouts.py`)
//!   in every layout, in a ROS 1 and a ROS 2 bag, are read back by `povins convert` as the same
//!   points (0.1 mm) and times (1 us) (ignored: needs python3 and PyPI).

mod common;

use common::{povins, rosbags_python, simulate_handheld};
use std::path::{Path, PathBuf};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn calib_dir(rec: &Path) -> PathBuf {
    let stem = rec.file_stem().unwrap().to_string_lossy();
    rec.with_file_name(format!("{stem}-calib"))
}

/// `povins run ARGS --out OUT` -> (trajectory.tum, stderr).
fn run(args: &[&str], out: &Path) -> (String, String) {
    let mut a = vec!["run"];
    a.extend_from_slice(args);
    a.extend_from_slice(&["--out", s(out)]);
    let (ok, _, err) = povins(&a);
    assert!(ok, "povins {a:?} failed: {err}");
    let tum = std::fs::read_to_string(out.join("trajectory.tum")).expect("trajectory.tum");
    (tum, err)
}

/// TUM rows: (t, x, y, z).
fn rows(tum: &str) -> Vec<[f64; 4]> {
    tum.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect()
}

fn max_distance(a: &str, b: &str) -> f64 {
    let (a, b) = (rows(a), rows(b));
    assert_eq!(a.len(), b.len(), "pose counts differ");
    a.iter()
        .zip(&b)
        .map(|(p, q)| {
            assert_eq!(p[0], q[0], "stamps differ");
            ((p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2) + (p[3] - q[3]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn every_lidar_layout_replays_to_the_euroc_folders_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("euroc");
    simulate_handheld("euroc", &euroc, "4", &[]);
    let (want, _) = run(&[s(&euroc)], &dir.path().join("run-euroc"));
    assert!(rows(&want).len() > 500, "trajectory too short");
    let cases: [(&str, &str); 10] = [
        ("rosbag1", "compact"),
        ("rosbag1", "ouster"),
        ("rosbag1", "velodyne"),
        ("rosbag1", "hesai"),
        ("rosbag1", "robosense"),
        ("rosbag1", "livox2"),
        ("rosbag1", "livox-custom"),
        ("rosbag1", "livox2-custom"),
        ("rosbag2-sqlite3", "velodyne"),
        ("rosbag2-sqlite3", "livox2-custom"),
    ];
    for (format, wire) in cases {
        let rec = match format {
            "rosbag1" => dir.path().join(format!("{wire}.bag")),
            _ => dir.path().join(format!("{wire}-ros2")),
        };
        simulate_handheld(format, &rec, "4", &["--lidar-layout", wire]);
        let (got, err) = run(
            &[s(&rec), "--calib", s(&calib_dir(&rec))],
            &dir.path().join(format!("run-{format}-{wire}")),
        );
        // The LiDAR topic was read, all its points kept, its time field named.
        let line = err
            .lines()
            .find(|l| l.contains("/lidar/points"))
            .unwrap_or_else(|| panic!("{format} {wire}: no LiDAR line in: {err}"));
        assert!(
            line.contains("points kept") && !line.contains("dropped"),
            "{line}"
        );
        if wire == "compact" {
            assert!(got == want, "{format} {wire}: trajectory.tum differs");
        } else {
            let d = max_distance(&want, &got);
            assert!(d <= 1e-3, "{format} {wire}: {d} m from the EuRoC run");
        }
    }
    // livox_ros_driver has no ROS 2 version.
    let (ok, _, err) = povins(&[
        "simulate",
        "--scenario",
        "handheld",
        "--duration",
        "1",
        "--images",
        "--format",
        "rosbag2-sqlite3",
        "--lidar-layout",
        "livox-custom",
        "--out",
        s(&dir.path().join("v1-ros2")),
    ]);
    assert!(!ok && err.contains("ROS 1 only"), "{err}");
}

/// `lidar0/data.csv` rows: (point t_ns, x, y, z), in file order.
fn lidar_rows(euroc: &Path) -> Vec<(i64, [f64; 3])> {
    std::fs::read_to_string(euroc.join("mav0/lidar0/data.csv"))
        .expect("lidar0/data.csv")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let f = |i: usize| v[i].trim().parse::<f64>().unwrap();
            (v[1].trim().parse().unwrap(), [f(2), f(3), f(4)])
        })
        .collect()
}

#[test]
#[ignore = "needs python3 and PyPI (installs rosbags and numpy into target/pyenv-rosbags)"]
fn sweeps_written_by_rosbags_in_every_layout_are_read_alike() {
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("euroc");
    simulate_handheld("euroc", &euroc, "1", &[]);
    let want = lidar_rows(&euroc);
    assert!(want.len() > 1000, "{} points", want.len());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/write_lidar_layouts.py");
    let out = std::process::Command::new(rosbags_python())
        .arg(&script)
        .arg(&euroc)
        .arg(dir.path())
        .output()
        .expect("python");
    assert!(
        out.status.success(),
        "write_lidar_layouts.py: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let topics = [
        "/ouster/points",
        "/velodyne_points",
        "/hesai/pandar",
        "/rslidar_points",
        "/livox/lidar_pc2",
        "/livox/lidar",
        "/livox2/lidar",
    ];
    for bag in ["layouts.bag", "layouts2"] {
        for topic in topics {
            if bag == "layouts2" && topic == "/livox/lidar" {
                continue;
            }
            let conv = dir
                .path()
                .join(format!("conv-{bag}{}", topic.replace('/', "-")));
            let (ok, _, err) = povins(&[
                "convert",
                s(&dir.path().join(bag)),
                "--calib",
                s(&euroc),
                "--lidar-topic",
                topic,
                "--out",
                s(&conv),
            ]);
            assert!(ok, "convert {bag} {topic}: {err}");
            assert!(
                !err.contains("not what") && !err.contains("dropped"),
                "{bag} {topic}: {err}"
            );
            let got = lidar_rows(&conv);
            assert_eq!(got.len(), want.len(), "{bag} {topic}: points");
            for (k, (a, b)) in want.iter().zip(&got).enumerate() {
                assert!(
                    (a.0 - b.0).abs() <= 1_000,
                    "{bag} {topic} point {k}: t {a:?} {b:?}"
                );
                for i in 0..3 {
                    assert!(
                        (a.1[i] - b.1[i]).abs() <= 1e-4,
                        "{bag} {topic} point {k}: {a:?} {b:?}"
                    );
                }
            }
        }
    }
}

//! The issue-30 bar on the repository's fixtures: the same simulated sequence in every container
//! (ROS 1 bag; ROS 2 bags in sqlite3, split in two files, and in MCAP storage; MCAP with `ros1`
//! encoding and with `cdr` and no summary; each written by an independent writer, see
//! tests/data/ros2-sim/README.md) gives `povins run` the bit-identical trajectory and front-end
//! output with the same Kalibr calibration, whatever the image encoding of each message.

mod common;

use common::povins;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data");

fn p(rel: &str) -> String {
    format!("{DATA}/{rel}")
}

#[test]
fn every_container_gives_the_same_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut reference: Option<(String, String, String)> = None;
    for rec in [
        "rosbag1-sim/sim.bag",
        "ros2-sim/sqlite3",
        "ros2-sim/mcap",
        "ros2-sim/ros1.mcap",
        "ros2-sim/cdr-nosummary.mcap",
    ] {
        let out = dir.path().join(rec.replace('/', "_"));
        let o = out.to_str().expect("utf-8");
        let (ok, _, err) = povins(&[
            "run",
            &p(rec),
            "--calib",
            &p("kalibr/sim-camchain-imucam.yaml"),
            "--imu-calib",
            &p("kalibr/sim-imu.yaml"),
            "--image-topic",
            "/cam0/image_raw",
            // 2 s recordings, half of them the rest before the start: partial by design.
            "--allow-partial",
            "--out",
            o,
        ]);
        assert!(ok, "{rec}: run failed: {err}");
        let read = |f: &str| std::fs::read_to_string(out.join(f)).expect(f);
        // frontend.csv without its timing columns (frontend_ms, decode_ms).
        let frontend: String = read("frontend.csv")
            .lines()
            .map(|l| {
                let v: Vec<&str> = l.split(',').collect();
                let mut kept = vec![v[0]];
                kept.extend(&v[3..]);
                kept.join(",") + "\n"
            })
            .collect();
        let got = (
            read("trajectory.tum"),
            frontend,
            read("keyframes_state.csv"),
        );
        assert!(got.0.lines().count() > 100, "{rec}: {}", got.0);
        assert_eq!(got.1.lines().count(), 1 + 14, "{rec}: {}", got.1);
        match &reference {
            None => reference = Some(got),
            Some(r) => {
                assert!(
                    r.0 == got.0,
                    "{rec}: trajectory differs from the ROS 1 bag's"
                );
                assert!(
                    r.1 == got.1,
                    "{rec}: front end differs from the ROS 1 bag's"
                );
                assert!(r.2 == got.2, "{rec}: keyframes differ from the ROS 1 bag's");
            }
        }
    }
}

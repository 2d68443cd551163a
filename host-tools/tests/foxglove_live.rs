//! `povins replay --realtime --foxglove ADDR` serves the live estimate over Foxglove's WebSocket
//! protocol. An independent client (`scripts/foxglove_client.py`: Python `websockets` and
//! `protobuf`, decoding with the schemas the server advertises) connects during the run and
//! receives the pose, the keyframe path and the landmarks; the poses equal the run's
//! `trajectory.tum` at the same stamps. Ignored: the client's packages come from PyPI.

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

const EUROC: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/euroc-v101-30s-features"
);
const CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/euroc.toml");

/// `trajectory.tum` as (stamp ns, [x y z qx qy qz qw]).
fn tum(path: &Path) -> Vec<(u64, Vec<f64>)> {
    std::fs::read_to_string(path)
        .expect("trajectory.tum")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut it = l.split_whitespace();
            let t: f64 = it.next().and_then(|t| t.parse().ok()).expect("a time");
            let v: Vec<f64> = it.map(|x| x.parse().expect("a number")).collect();
            ((t * 1e9).round() as u64, v)
        })
        .collect()
}

#[test]
#[ignore = "needs PyPI for the Python websockets and protobuf packages (target/pyenv-foxglove); CI runs it"]
fn foxglove_client_receives_the_live_pose_path_and_landmarks() {
    let py = common::foxglove_python();
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_povins"))
        .args(["replay", "--realtime", EUROC, "--config", CONFIG])
        .args([
            "--speed",
            "2",
            "--no-rt",
            "--foxglove",
            "127.0.0.1:0",
            "--out",
        ])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("povins starts");
    let mut stderr = BufReader::new(child.stderr.take().expect("stderr"));
    let mut url = None;
    let mut line = String::new();
    while stderr.read_line(&mut line).expect("stderr") > 0 {
        if let Some(rest) = line.trim().strip_prefix("foxglove: serving ") {
            url = rest.split_whitespace().next().map(str::to_string);
            break;
        }
        line.clear();
    }
    let url = url.unwrap_or_else(|| panic!("no server line on stderr (last: {line:?})"));
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");
    let rest = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut stderr, &mut s);
        s
    });
    let client = Command::new(&py)
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../scripts/foxglove_client.py"
        ))
        .args([url.as_str(), "600"])
        .output()
        .expect("the client runs");
    let status = child.wait().expect("the replay");
    let err = rest.join().unwrap_or_default();
    let mut stdout = String::new();
    let _ = std::io::Read::read_to_string(&mut child.stdout.take().expect("stdout"), &mut stdout);
    assert!(status.success(), "replay failed: {err}");
    let text = String::from_utf8_lossy(&client.stdout);
    assert!(
        client.status.success(),
        "client failed: {}\n{text}",
        String::from_utf8_lossy(&client.stderr)
    );
    let msgs: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    assert_eq!(msgs[0]["subprotocol"], "foxglove.sdk.v1");
    assert_eq!(
        msgs.last().map(|m| m["op"].clone()),
        Some(serde_json::json!("closed")),
        "the server closes the connection when the run ends"
    );
    let on =
        |t: &str| -> Vec<&serde_json::Value> { msgs.iter().filter(|m| m["topic"] == t).collect() };
    let (poses, paths, landmarks) = (
        on("/povins/pose"),
        on("/povins/path"),
        on("/povins/landmarks"),
    );
    // 30 s of data at twice the recorded pace: most of it after the client connected.
    assert!(poses.len() > 100, "{} poses", poses.len());
    assert!(paths.len() > 10, "{} paths", paths.len());
    assert!(landmarks.len() > 10, "{} landmark updates", landmarks.len());
    assert!(poses.iter().all(|m| m["schema"] == "foxglove.PoseInFrame"));
    assert!(paths.iter().all(|m| m["schema"] == "foxglove.PosesInFrame"));
    assert!(landmarks
        .iter()
        .all(|m| m["schema"] == "foxglove.SceneUpdate"));
    assert!(msgs
        .iter()
        .filter(|m| m.get("frame").is_some())
        .all(|m| m["frame"] == "world"));

    // Each pose is the trajectory's at its stamp, at 30 Hz of sensor time (the first sample at
    // or after each 1/30 s: 30 or 35 ms apart at 200 Hz).
    let traj = tum(&out.join("trajectory.tum"));
    let mut last = 0u64;
    for m in &poses {
        let t = m["log_time"].as_u64().expect("log time");
        assert_eq!(m["stamp"].as_u64(), Some(t), "stamp and log time");
        assert!(
            t >= last + 29_000_000 || last == 0,
            "{t} after {last}: not 30 Hz"
        );
        last = t;
        let k = traj
            .binary_search_by_key(&t, |p| p.0)
            .unwrap_or_else(|_| panic!("no trajectory pose at {t}"));
        let got: Vec<f64> = m["pose"]
            .as_array()
            .expect("pose")
            .iter()
            .map(|v| v.as_f64().expect("number"))
            .collect();
        for (a, b) in got.iter().zip(&traj[k].1) {
            assert!(
                (a - b).abs() < 1e-6,
                "pose at {t}: {got:?} vs {:?}",
                traj[k].1
            );
        }
    }
    // The path grows by one keyframe per message; the landmarks are the window's, at most 200,
    // some with LiDAR depth never (this sequence has no LiDAR).
    let lens: Vec<u64> = paths.iter().map(|m| m["n"].as_u64().expect("n")).collect();
    assert!(lens.windows(2).all(|w| w[1] == w[0] + 1), "{lens:?}");
    let counts: Vec<u64> = landmarks
        .iter()
        .map(|m| m["n"].as_u64().expect("n"))
        .collect();
    assert!(counts.iter().all(|&n| n <= 200), "{counts:?}");
    assert!(counts.iter().any(|&n| n >= 20), "{counts:?}");
    assert!(landmarks.iter().all(|m| m["lidar"] == 0));
    assert!(
        stdout.contains("foxglove  port"),
        "no foxglove summary: {stdout}"
    );
}

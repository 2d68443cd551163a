//! `povins replay --realtime` and `povins timing` on the repository's EuRoC 30 s tracks: the
//! deterministic pipeline writes `povins run`'s `trajectory.tum` byte for byte (same
//! configuration code, same start, same order), the run's `config.toml` repeats it byte for byte,
//! and `timing --json` reports a run with no drop. On simulated images (`povins simulate
//! --images`, PNG files) the pipeline's image front-end stage does the same: the deterministic
//! replay writes `povins run --frontend images`'s trajectory byte for byte.
//! No timed assertion.

mod common;

use common::{povins, simulate};

const EUROC: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/euroc-v101-30s-features"
);
const CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/euroc.toml");

#[test]
fn deterministic_replay_writes_the_runs_trajectory() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (rt_dir, run_dir) = (dir.path().join("rt"), dir.path().join("run"));
    let (ok, out, err) = povins(&[
        "replay",
        "--realtime",
        EUROC,
        "--config",
        CONFIG,
        "--deterministic",
        "--speed",
        "0",
        "--no-rt",
        "--out",
        rt_dir.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "replay failed: {err}");
    assert!(
        out.contains("back end keyframe solve"),
        "no timing table: {out}"
    );
    let (ok, _, err) = povins(&[
        "run",
        EUROC,
        "--config",
        CONFIG,
        "--frontend",
        "tracks",
        "--out",
        run_dir.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "run failed: {err}");
    let a = std::fs::read(rt_dir.join("trajectory.tum")).expect("replay's trajectory");
    let b = std::fs::read(run_dir.join("trajectory.tum")).expect("run's trajectory");
    assert!(a.len() > 100_000, "trajectory too short: {} bytes", a.len());
    assert!(
        a == b,
        "the deterministic pipeline's trajectory differs from povins run's"
    );
    // The run's `config.toml`, given back as `--config`, repeats the run byte for byte.
    let again = dir.path().join("again");
    let effective = run_dir.join("config.toml");
    let (ok, _, err) = povins(&[
        "run",
        EUROC,
        "--config",
        effective.to_str().expect("utf-8 path"),
        "--frontend",
        "tracks",
        "--out",
        again.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "run with the written config failed: {err}");
    let c = std::fs::read(again.join("trajectory.tum")).expect("the second run's trajectory");
    assert!(b == c, "the written config.toml does not repeat the run");
}

#[test]
fn timing_json_reports_no_drop_and_replay_needs_realtime() {
    let (ok, out, err) = povins(&[
        "timing", EUROC, "--config", CONFIG, "--speed", "0", "--no-rt", "--json",
    ]);
    assert!(ok, "timing failed: {err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("JSON on stdout");
    let c = &v["counters"];
    assert_eq!(c["imu_in"].as_u64(), Some(6021));
    for k in [
        "dropped_imu",
        "dropped_frames",
        "dropped_sweeps",
        "updates_too_old",
    ] {
        assert_eq!(c[k].as_u64(), Some(0), "{k}: {c}");
    }
    assert!(c["keyframes"].as_u64().unwrap_or(0) > 40, "{c}");
    assert_eq!(v["stages"].as_array().map(Vec::len), Some(11));
    assert_eq!(v["frontend"], "tracks");
    // The solve's work (p50, p99, p99.9, max): counted for every keyframe, ordered.
    let w: Vec<u64> = v["solve_work"]
        .as_array()
        .map(|a| a.iter().filter_map(serde_json::Value::as_u64).collect())
        .unwrap_or_default();
    assert_eq!(w.len(), 4, "{}", v["solve_work"]);
    assert!(w[0] > 100 && w.windows(2).all(|p| p[0] <= p[1]), "{w:?}");
    let (ok, _, err) = povins(&["replay", EUROC]);
    assert!(!ok);
    assert!(err.contains("--realtime"), "{err}");
}

/// The TUM file's poses as (time string, the other seven numbers as written).
fn tum_lines(path: &std::path::Path) -> Vec<(String, Vec<f64>)> {
    std::fs::read_to_string(path)
        .expect("a TUM file")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut it = l.split_whitespace();
            let t = it.next().expect("a time").to_string();
            (t, it.map(|v| v.parse().expect("a number")).collect())
        })
        .collect()
}

/// Real time (not lockstep) from ground truth: the pipeline publishes a pose at every sample
/// from the first, as many as `povins run --init groundtruth` writes; `--mcap-out` writes the
/// same poses as `foxglove.PoseInFrame` JSON messages on /povins/pose (and the keyframes on
/// /povins/keyframe), read back here with the mcap crate.
#[test]
fn realtime_replay_from_ground_truth_writes_every_pose_and_an_mcap() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (rt_dir, run_dir) = (dir.path().join("rt"), dir.path().join("run"));
    let mcap_path = dir.path().join("poses.mcap");
    let (ok, out, err) = povins(&[
        "replay",
        "--realtime",
        EUROC,
        "--config",
        CONFIG,
        "--init",
        "groundtruth",
        "--speed",
        "0",
        "--no-rt",
        "--out",
        rt_dir.to_str().expect("utf-8 path"),
        "--mcap-out",
        mcap_path.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "replay failed: {err}");
    assert!(out.contains("mcap "), "no mcap line: {out}");
    let (ok, _, err) = povins(&[
        "run",
        EUROC,
        "--config",
        CONFIG,
        "--init",
        "groundtruth",
        "--frontend",
        "tracks",
        "--out",
        run_dir.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "run failed: {err}");
    let rt = tum_lines(&rt_dir.join("trajectory.tum"));
    let run = tum_lines(&run_dir.join("trajectory.tum"));
    assert!(run.len() > 5000, "only {} poses from povins run", run.len());
    assert_eq!(rt.len(), run.len(), "poses: real-time replay vs povins run");
    assert_eq!(rt.first(), run.first(), "first pose");
    assert_eq!(
        rt.last().map(|p| &p.0),
        run.last().map(|p| &p.0),
        "last stamp"
    );

    let bytes = std::fs::read(&mcap_path).expect("the MCAP file");
    let mut poses = Vec::new();
    let mut keyframes = 0usize;
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a message");
        let schema = m.channel.schema.as_ref().expect("a schema");
        assert_eq!(schema.name, "foxglove.PoseInFrame");
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(m.channel.message_encoding, "json");
        let v: serde_json::Value = serde_json::from_slice(&m.data).expect("a JSON message");
        match m.channel.topic.as_str() {
            "/povins/pose" => poses.push((m.log_time, v)),
            "/povins/keyframe" => keyframes += 1,
            t => panic!("unexpected topic {t}"),
        }
    }
    assert_eq!(poses.len(), rt.len(), "MCAP poses vs TUM poses");
    assert!(keyframes > 40, "only {keyframes} keyframes");
    let (t0, first) = &poses[0];
    let (sec, nsec) = (
        first["timestamp"]["sec"].as_u64().expect("sec"),
        first["timestamp"]["nsec"].as_u64().expect("nsec"),
    );
    assert_eq!(sec * 1_000_000_000 + nsec, *t0);
    let t_tum: f64 = rt[0].0.parse().expect("a time");
    assert!(
        (*t0 as f64 * 1e-9 - t_tum).abs() < 1e-6,
        "{t0} ns vs {t_tum} s"
    );
    assert_eq!(first["frame_id"], "world");
    let p = &first["pose"]["position"];
    let q = &first["pose"]["orientation"];
    let got: Vec<f64> = [
        &p["x"], &p["y"], &p["z"], &q["x"], &q["y"], &q["z"], &q["w"],
    ]
    .iter()
    .map(|v| v.as_f64().expect("a number"))
    .collect();
    assert_eq!(got, rt[0].1, "first MCAP pose vs the TUM file's");
}

/// Images through the pipeline's front-end stage: a short simulated hand-held sequence with
/// rendered PNG images; `replay --realtime --deterministic` (front end chosen like `povins run`:
/// images when the dataset has them) writes `povins run --frontend images`'s trajectory byte
/// for byte, and `timing --json` reports the front end's stages and no drop.
#[test]
fn deterministic_replay_with_images_writes_the_image_runs_trajectory() {
    let dir = tempfile::tempdir().expect("temp dir");
    let sim = dir.path().join("sim");
    simulate("handheld", "1", "6", "euroc", &sim, &["--images"]);
    let sim = sim.to_str().expect("utf-8 path");
    let (rt_dir, run_dir) = (dir.path().join("rt"), dir.path().join("run"));
    let (ok, out, err) = povins(&[
        "replay",
        "--realtime",
        sim,
        "--init",
        "groundtruth",
        "--deterministic",
        "--speed",
        "0",
        "--no-rt",
        "--out",
        rt_dir.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "replay failed: {err}");
    assert!(
        out.contains("image front end"),
        "not the image front end: {out}"
    );
    assert!(
        out.contains("front end per image"),
        "no front-end timing: {out}"
    );
    let (ok, _, err) = povins(&[
        "run",
        sim,
        "--init",
        "groundtruth",
        "--frontend",
        "images",
        "--out",
        run_dir.to_str().expect("utf-8 path"),
    ]);
    assert!(ok, "run failed: {err}");
    let a = std::fs::read(rt_dir.join("trajectory.tum")).expect("replay's trajectory");
    let b = std::fs::read(run_dir.join("trajectory.tum")).expect("run's trajectory");
    assert!(a.len() > 50_000, "trajectory too short: {} bytes", a.len());
    assert!(
        a == b,
        "the deterministic pipeline's trajectory differs from povins run --frontend images'"
    );

    let (ok, out, err) = povins(&[
        "timing",
        sim,
        "--init",
        "groundtruth",
        "--frontend",
        "images",
        "--speed",
        "0",
        "--no-rt",
        "--json",
    ]);
    assert!(ok, "timing failed: {err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("JSON on stdout");
    assert_eq!(v["frontend"], "images");
    let c = &v["counters"];
    assert!(c["images_in"].as_u64().unwrap_or(0) > 50, "{c}");
    assert_eq!(c["frames_in"].as_u64(), Some(0), "{c}");
    for k in [
        "dropped_imu",
        "dropped_images",
        "image_failures",
        "updates_too_old",
    ] {
        assert_eq!(c[k].as_u64(), Some(0), "{k}: {c}");
    }
    let stage = |name: &str| {
        v["stages"]
            .as_array()
            .and_then(|a| a.iter().find(|s| s[0] == name))
            .map(|s| s[1]["count"].as_u64().unwrap_or(0))
    };
    assert_eq!(stage("front end per image"), c["images_in"].as_u64());
    assert_eq!(
        stage("image arrival -> track frame"),
        c["images_in"].as_u64()
    );
}

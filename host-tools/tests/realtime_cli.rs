//! `povins replay --realtime` and `povins timing` on the repository's EuRoC 30 s tracks: the
//! deterministic pipeline writes `povins run`'s `trajectory.tum` byte for byte (same
//! configuration code, same start, same order), the run's `config.toml` repeats it byte for byte,
//! and `timing --json` reports a run with no drop.
//! No timed assertion.

mod common;

use common::povins;

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
    assert_eq!(v["stages"].as_array().map(Vec::len), Some(7));
    let (ok, _, err) = povins(&["replay", EUROC]);
    assert!(!ok);
    assert!(err.contains("--realtime"), "{err}");
}

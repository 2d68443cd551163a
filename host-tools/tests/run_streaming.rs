//! `povins run` writes its files row by row while the run goes:
//! - the streamed files equal those written from the same run collected in memory
//!   (`RunOutput` through `write_outputs`), timing columns aside;
//! - a run that fails part-way exits non-zero, leaves `NAME.partial` files with the rows up to
//!   the failure and no `summary.json`, and leaves an earlier run's files as they were.

mod common;

use common::povins;
use povins_host_tools::progress::Progress;
use povins_host_tools::report::{summarize, write_outputs};
use povins_host_tools::runner::InitMode;
use povins_host_tools::setup::RunSetup;
use std::path::Path;

const EUROC: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/euroc-v101-30s-features"
);

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A CSV without its timing columns (headers ending in `_ms`).
fn without_timing(csv: &str) -> Vec<String> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let keep = |row: &str| {
        row.split(',')
            .zip(&header)
            .filter(|(_, h)| !h.ends_with("_ms"))
            .map(|(v, _)| v)
            .collect::<Vec<_>>()
            .join(",")
    };
    std::iter::once(keep(&header.join(",")))
        .chain(lines.map(keep))
        .collect()
}

/// `summary.json` without its timing figures.
fn summary_without_timing(p: &Path) -> serde_json::Value {
    let mut v: serde_json::Value = serde_json::from_str(&read(p)).expect("summary.json");
    if let Some(m) = v.as_object_mut() {
        m.retain(|k, _| !k.contains("_ms"));
    }
    v
}

#[test]
fn the_streamed_files_equal_the_collected_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let streamed = tmp.path().join("streamed");
    let (ok, _, err) = povins(&["run", EUROC, "--out", s(&streamed)]);
    assert!(ok, "povins run failed: {err}");

    let collected = tmp.path().join("collected");
    let dir = collected.clone();
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(move || {
            let rec = povins_platform::open_recording(Path::new(EUROC)).unwrap();
            let setup = RunSetup::defaults(&*rec, InitMode::Auto);
            let progress = Progress::with_visibility(1, "test", false);
            let out = setup.replay(&*rec, &progress).unwrap();
            let summary = summarize(&*rec, &setup.mode_name(), setup.init, &out).unwrap();
            write_outputs(&dir, &out, &summary).unwrap();
        })
        .unwrap()
        .join()
        .unwrap();

    for name in ["trajectory.tum", "keyframes.tum", "keyframes_state.csv"] {
        let (a, b) = (read(&streamed.join(name)), read(&collected.join(name)));
        assert!(a == b, "{name} differs");
    }
    let keyframes = read(&streamed.join("keyframes.tum")).lines().count();
    assert!(keyframes > 50, "{keyframes} lines in keyframes.tum");
    assert_eq!(
        without_timing(&read(&streamed.join("stats.csv"))),
        without_timing(&read(&collected.join("stats.csv")))
    );
    assert_eq!(
        summary_without_timing(&streamed.join("summary.json")),
        summary_without_timing(&collected.join("summary.json"))
    );
    // The counters are numbers under their names; coverage is the share of ground truth after
    // the first camera frame (the static start waits ~1 s at rest).
    let summary: serde_json::Value =
        serde_json::from_str(&read(&streamed.join("summary.json"))).unwrap();
    let c = &summary["counters"];
    assert_eq!(
        (c["resets"].as_u64(), c["reinitializations"].as_u64()),
        (Some(0), Some(0))
    );
    assert!(c["keyframes"].as_u64().is_some_and(|k| k > 50), "{c}");
    assert_eq!(c["front_end"]["images"].as_u64(), Some(0));
    let coverage = summary["coverage"].as_f64().expect("coverage");
    assert!((0.85..0.99).contains(&coverage), "coverage {coverage}");
    let leftovers: Vec<_> = std::fs::read_dir(&streamed)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".partial"))
        .map(|e| e.file_name())
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn a_run_that_fails_part_way_leaves_partial_files_and_an_earlier_runs_files() {
    let tmp = tempfile::tempdir().unwrap();
    // The dataset with an IMU row two thirds in that cannot be read.
    let copy = tmp.path().join("euroc");
    for sub in ["imu0", "features0", "cam0", "state_groundtruth_estimate0"] {
        let from = Path::new(EUROC).join("mav0").join(sub);
        let to = copy.join("mav0").join(sub);
        std::fs::create_dir_all(&to).unwrap();
        for e in std::fs::read_dir(&from).unwrap() {
            let e = e.unwrap();
            if e.file_type().unwrap().is_file() {
                std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
            }
        }
    }
    let imu = copy.join("mav0/imu0/data.csv");
    let mut lines: Vec<String> = read(&imu).lines().map(str::to_string).collect();
    let bad = lines.len() * 2 / 3;
    lines[bad] = lines[bad].replacen(',', ",not-a-number,", 1);
    std::fs::write(&imu, lines.join("\n") + "\n").unwrap();

    let out = tmp.path().join("out");
    let (ok, _, err) = povins(&["run", EUROC, "--out", s(&out)]);
    assert!(ok, "povins run failed: {err}");
    let earlier = |name: &str| std::fs::read(out.join(name)).unwrap();
    let before: Vec<Vec<u8>> = ["trajectory.tum", "summary.json"]
        .iter()
        .map(|n| earlier(n))
        .collect();

    let (ok, _, err) = povins(&["run", s(&copy), "--out", s(&out)]);
    assert!(!ok, "a run over an unreadable IMU row succeeded");
    assert!(
        err.contains("trajectory.tum.partial") && err.contains("incomplete"),
        "{err}"
    );
    let partial = read(&out.join("trajectory.tum.partial"));
    let rows = partial.lines().count();
    assert!(rows > 1000, "{rows} rows before the failure");
    let first_of_earlier = String::from_utf8_lossy(&before[0]);
    assert!(
        first_of_earlier.starts_with(&partial[..partial.len().min(4000)]),
        "the partial trajectory is not the start of the full one"
    );
    assert!(!out.join("summary.json.partial").exists());
    let after: Vec<Vec<u8>> = ["trajectory.tum", "summary.json"]
        .iter()
        .map(|n| earlier(n))
        .collect();
    assert_eq!(before, after, "the earlier run's files changed");
}

/// A corrupt chunk in the middle of an MCAP recording costs its messages, not the run: the run
/// goes on over the gap, exits 0, and says which chunk it skipped.
#[test]
fn a_corrupt_chunk_is_skipped_and_the_run_goes_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("handheld.mcap");
    // With the LiDAR a 1 MB chunk holds about 0.35 s: a gap the estimator bridges.
    common::simulate("handheld", "5", "10", "mcap", &rec, &[]);
    let mut d = std::fs::read(&rec).expect("the recording");
    let cs = common::mcap_chunks(&d);
    assert!(cs.len() >= 4, "{} chunks", cs.len());
    let (at, len) = cs[cs.len() * 2 / 3];
    d[at + len - 4] ^= 0x5a;
    std::fs::write(&rec, &d).expect("write");
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = povins(&["run", s(&rec), "--out", s(&out)]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains(&format!(
            "the chunk ending at byte offset {} was skipped",
            at + len
        )),
        "{stderr}"
    );
    let status = stdout
        .lines()
        .find(|l| l.starts_with("status"))
        .expect("status");
    assert!(status.contains("0 resets"), "{status}");
    assert!(status.contains("1 IMU gaps bridged"), "{status}");
    assert!(out.join("summary.json").exists());
}

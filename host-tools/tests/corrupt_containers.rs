//! Issue 32 item 4 for every ROS container: a corrupt chunk in the middle of a recording costs
//! its messages, not the run. `povins run` warns naming the file, the topic and the chunk's byte
//! offset, bridges the IMU gap the chunk leaves, and exits 0 with no reset. (povins' own MCAP:
//! `run_streaming::a_corrupt_chunk_is_skipped_and_the_run_goes_on`. ROS 2 sqlite3 bags carry
//! no checksum: a flipped byte there is not detectable, BENCHMARKS.md "Corrupt chunks skipped".)

mod common;

use common::{mcap_chunks, povins, simulate_handheld};
use std::path::Path;

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn u32_at(d: &[u8], at: usize) -> usize {
    u32::from_le_bytes(d[at..at + 4].try_into().expect("4 bytes")) as usize
}

/// The (data offset, data length) of every chunk record of ROS 1 bag bytes `d` (records after
/// the 13-byte version line: header length, header fields `name=value`, data length, data).
fn bag_chunks(d: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 13;
    while pos + 4 <= d.len() {
        let hl = u32_at(d, pos);
        let header = &d[pos + 4..pos + 4 + hl];
        let mut i = 0;
        let mut op = None;
        while i + 4 <= header.len() {
            let fl = u32_at(header, i);
            let field = &header[i + 4..i + 4 + fl];
            if let Some(v) = field.strip_prefix(b"op=") {
                op = v.first().copied();
            }
            i += 4 + fl;
        }
        let data = pos + 8 + hl;
        let dl = u32_at(d, pos + 4 + hl);
        if op == Some(0x05) {
            out.push((data, dl));
        }
        pos = data + dl;
    }
    out
}

/// Simulates 8 s of the hand-held scenario with images as `format` (`extra`: more `simulate`
/// arguments), flips a byte in the chunk two thirds in (`file`: the container file inside the
/// output, `chunks`: its chunks as (offset the warning names, length)), runs `povins run` and
/// checks the run went on over the gap.
fn corrupt_chunk_is_skipped(
    format: &str,
    name: &str,
    file: impl Fn(&Path) -> std::path::PathBuf,
    chunks: fn(&[u8]) -> Vec<(usize, usize)>,
    extra: &[&str],
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join(name);
    let mut args = vec!["--lidar", "none"];
    args.extend_from_slice(extra);
    simulate_handheld(format, &rec, "8", &args);
    let f = file(&rec);
    let mut d = std::fs::read(&f).expect("the recording");
    let cs = chunks(&d);
    assert!(cs.len() >= 6, "{format}: {} chunks", cs.len());
    let (at, len) = cs[cs.len() * 2 / 3];
    d[at + len - 4] ^= 0x5a;
    std::fs::write(&f, &d).expect("write");
    let calib = dir.path().join(format!(
        "{}-calib",
        name.trim_end_matches(".bag").trim_end_matches(".mcap")
    ));
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = povins(&["run", s(&rec), "--calib", s(&calib), "--out", s(&out)]);
    assert!(ok, "{format}: {stdout}\n{stderr}");
    let warned = stderr
        .lines()
        .any(|l| l.starts_with("warning:") && l.contains(&format!("at byte offset {at} skipped")));
    assert!(
        warned,
        "{format}: no warning naming byte offset {at}:\n{stderr}"
    );
    let status = stdout
        .lines()
        .find(|l| l.starts_with("status"))
        .expect("status");
    assert!(status.contains("0 resets"), "{format}: {status}");
    assert!(status.contains("1 IMU gaps bridged"), "{format}: {status}");
    assert!(out.join("trajectory.tum").exists(), "{format}");
}

#[test]
fn a_corrupt_lz4_chunk_of_a_ros1_bag_is_skipped() {
    corrupt_chunk_is_skipped(
        "rosbag1",
        "h.bag",
        |p| p.to_path_buf(),
        bag_chunks,
        &["--compression", "lz4"],
    );
}

#[test]
fn a_corrupt_bz2_chunk_of_a_ros1_bag_is_skipped() {
    corrupt_chunk_is_skipped(
        "rosbag1",
        "h.bag",
        |p| p.to_path_buf(),
        bag_chunks,
        &["--compression", "bz2"],
    );
}

#[test]
fn a_corrupt_chunk_of_a_ros1_mcap_is_skipped() {
    corrupt_chunk_is_skipped("mcap-ros1", "h.mcap", |p| p.to_path_buf(), mcap_chunks, &[]);
}

#[test]
fn a_corrupt_chunk_of_a_ros2_mcap_bag_is_skipped() {
    corrupt_chunk_is_skipped(
        "rosbag2-mcap",
        "h",
        |p| p.join("h_0.mcap"),
        mcap_chunks,
        &[],
    );
}

//! Corruption in povins' own MCAP files: a chunk whose CRC does not match is skipped with a
//! warning naming the offset its record ends at (never read as if it were data), and an
//! unreadable evaluation-only attachment is ignored with a warning (it never blocks a run).

use super::compressed_tests::dataset;
use super::*;
use crate::dataset::SimTruth;
use crate::recording::Recording;

/// The (offset, length) of every chunk record of the MCAP bytes `d`.
fn chunks(d: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= d.len() {
        let op = d[pos];
        let len = u64::from_le_bytes(d[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if op == 0x06 {
            out.push((pos, len));
        }
        if op == 0x02 {
            break;
        }
        pos += 9 + len;
    }
    out
}

/// A dataset of `n` IMU samples (200 Hz from 1 s), several chunks of the writer's size.
fn long_imu(n: i64) -> crate::dataset::Dataset {
    let mut ds = dataset();
    ds.imu = (0..n)
        .map(|k| povins_core::inertial::ImuSample {
            t_ns: 1_000_000_000 + k * 5_000_000,
            gyro_rps: povins_core::math::Vec3::zeros(),
            accel_mps2: povins_core::math::Vec3::new(0.0, 0.0, 9.81),
        })
        .collect();
    ds
}

/// A chunk whose CRC does not match is skipped, its messages lost: the pass at open warns with
/// the offset its record ends at; the streams read every other chunk (not the corrupt bytes as
/// if they were data); a file whose every chunk is corrupt has no IMU messages.
#[test]
fn a_chunk_with_a_bad_crc_is_skipped_with_a_warning_naming_where_it_ends() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.mcap");
    let n = 30_000;
    write_dataset(&path, &long_imu(n)).unwrap();
    let clean = std::fs::read(&path).unwrap();
    let cs = chunks(&clean);
    assert!(cs.len() >= 3, "{} chunks", cs.len());
    let mut d = clean.clone();
    let (at, len) = cs[1];
    // Past the chunk header (start, end, uncompressed size, CRC, compression string length and
    // at most "zstd"), inside its records.
    d[at + 9 + len - 4] ^= 0x5a;
    std::fs::write(&path, &d).unwrap();
    let r = McapRecording::open(&path).expect("the file opens");
    let end = at + 9 + len;
    let warnings = r.warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let w = &warnings[0];
    assert!(
        w.contains(&format!("chunk ending at byte offset {end} was skipped")),
        "{w} (chunk ends at {end})"
    );
    assert!(w.contains("CRC") || w.contains("zstd"), "{w}");
    let got: Vec<i64> = r.imu().unwrap().map(|s| s.unwrap().t_ns).collect();
    assert!(
        got.len() > n as usize / 3 && got.len() < n as usize,
        "{} samples",
        got.len()
    );
    assert!(got.windows(2).all(|w| w[1] > w[0]));
    // The samples kept are the file's, at their stamps: a gap where the chunk was.
    let gaps = got.windows(2).filter(|w| w[1] - w[0] != 5_000_000).count();
    assert_eq!(gaps, 1);
    // Every chunk corrupt: nothing to read, an error saying so.
    let mut all = clean;
    for &(at, len) in &cs {
        all[at + 9 + len - 4] ^= 0x5a;
    }
    std::fs::write(&path, &all).unwrap();
    let err = McapRecording::open(&path)
        .expect_err("no IMU left")
        .to_string();
    assert!(err.contains("no /imu0 messages"), "{err}");
}

#[test]
fn an_unreadable_sim_truth_attachment_is_ignored_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.mcap");
    let mut ds = dataset();
    ds.sim_truth = Some(SimTruth {
        landmarks_w: vec![(7, Vec3::new(1.0, 2.0, 3.0))],
        wrong_tracks: vec![7],
        ..Default::default()
    });
    write_dataset(&path, &ds).unwrap();
    let clean = McapRecording::open(&path).unwrap();
    assert!(clean.sim_truth().is_some());
    assert!(clean.warnings().is_empty());
    // Break the attachment's JSON in place (same length: the records around it stay intact).
    let mut d = std::fs::read(&path).unwrap();
    let key = b"landmarks_w";
    let i = d
        .windows(key.len())
        .position(|w| w == key)
        .expect("the attachment's JSON");
    d[i - 1] = b'#';
    std::fs::write(&path, &d).unwrap();
    let r =
        McapRecording::open(&path).expect("a broken evaluation-only attachment blocked the run");
    assert!(r.sim_truth().is_none());
    let w = r.warnings();
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].contains(SIM_TRUTH_ATTACHMENT), "{w:?}");
    assert_eq!(r.imu().unwrap().count(), ds.imu.len());
}

//! Corruption in povins' own MCAP files: a chunk whose CRC does not match is refused with the
//! offset its record ends at (not read as if it were data), and an unreadable evaluation-only
//! attachment is ignored with a warning (it never blocks a run).

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

#[test]
fn a_chunk_with_a_bad_crc_is_refused_naming_where_its_record_ends() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.mcap");
    write_dataset(&path, &dataset()).unwrap();
    let mut d = std::fs::read(&path).unwrap();
    let cs = chunks(&d);
    assert!(!cs.is_empty(), "no chunk record");
    let (at, len) = cs[0];
    // Past the chunk header (start, end, uncompressed size, CRC, compression string length and
    // at most "zstd"), inside its records.
    let flip = at + 9 + len - 4;
    d[flip] ^= 0x5a;
    std::fs::write(&path, &d).unwrap();
    let err = McapRecording::open(&path)
        .and_then(|r| r.imu().map(|s| s.count()))
        .expect_err("a corrupt chunk was read");
    let msg = err.to_string();
    let end = at + 9 + len;
    assert!(msg.contains("d.mcap"), "{msg}");
    assert!(
        msg.to_lowercase().contains("crc") || msg.contains("decompress"),
        "{msg}"
    );
    assert!(
        msg.contains(&format!("byte offset {end}")),
        "{msg} (chunk ends at {end})"
    );
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

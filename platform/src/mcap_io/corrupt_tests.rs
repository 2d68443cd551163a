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
    write_dataset_legacy_truth(&path, &ds).unwrap();
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

#[test]
fn an_older_files_truth_attachment_is_still_read() {
    let dir = tempfile::tempdir().unwrap();
    let (old, new) = (dir.path().join("old.mcap"), dir.path().join("new.mcap"));
    let mut ds = dataset();
    ds.sim_truth = Some(SimTruth {
        landmarks_w: vec![
            (7, Vec3::new(1.0, 2.0, 3.0)),
            (9, Vec3::new(-1.0, 0.5, 8.0)),
        ],
        wrong_tracks: vec![9],
        edge_features: vec![7, 11],
        ..Default::default()
    });
    write_dataset_legacy_truth(&old, &ds).unwrap();
    write_dataset(&new, &ds).unwrap();
    let ids = |p: &std::path::Path| -> Vec<(u64, Option<Vec3>, bool, bool)> {
        let r = McapRecording::open(p).unwrap();
        assert!(r.has_sim_truth());
        let mut v: Vec<_> = r
            .sim_landmarks()
            .unwrap()
            .expect("a truth")
            .map(|l| l.map(|l| (l.id, l.p_w, l.wrong, l.edge)))
            .collect::<Result<_, _>>()
            .unwrap();
        v.sort_by_key(|l| l.0);
        v
    };
    // The same ids, positions and flags either way (the attachment holds no spans).
    assert_eq!(ids(&old), ids(&new));
    assert_eq!(ids(&new).len(), 3);
    assert_eq!(read_dataset(&old).unwrap().sim_truth, ds.sim_truth);
    assert_eq!(read_dataset(&new).unwrap().sim_truth, ds.sim_truth);
}

#[test]
fn a_broken_truth_message_fails_only_the_truths_stream() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.mcap");
    let ds = dataset();
    // Written by hand, uncompressed: the IMU, the calibration and one truth message that is
    // not JSON.
    let f = std::fs::File::create(&path).unwrap();
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .create(std::io::BufWriter::new(f))
        .unwrap();
    let no_meta = BTreeMap::new();
    let sid = w
        .add_schema(IMU_TYPE, "ros2msg", ros2::imu_schema().as_bytes())
        .unwrap();
    let imu = w.add_channel(sid, TOPIC_IMU, "cdr", &no_meta).unwrap();
    let truth = w.add_channel(0, TOPIC_SIM_TRUTH, "json", &no_meta).unwrap();
    let msg = |channel_id, sequence, t: i64| mcap::records::MessageHeader {
        channel_id,
        sequence,
        log_time: t as u64,
        publish_time: t as u64,
    };
    for (k, s) in ds.imu.iter().enumerate() {
        let m = convert::imu_to_msg(s).encode().unwrap();
        w.write_to_known_channel(&msg(imu, k as u32 + 1, s.t_ns), &m)
            .unwrap();
        if k == 3 {
            let t = s.t_ns + 1;
            let body = format!("{{\"t_ns\": {t}, \"landmarks\": [#]}}");
            w.write_to_known_channel(&msg(truth, 1, t), body.as_bytes())
                .unwrap();
        }
    }
    w.write_metadata(&mcap::records::Metadata {
        name: CALIBRATION_METADATA.into(),
        metadata: calibration_metadata(&ds),
    })
    .unwrap();
    w.finish().unwrap();
    drop(w);
    let r = McapRecording::open(&path).expect("the evaluation-only truth blocked the open");
    assert!(r.has_sim_truth());
    assert_eq!(r.imu().unwrap().count(), ds.imu.len());
    let err = r
        .sim_landmarks()
        .unwrap()
        .expect("a truth")
        .find_map(Result::err)
        .expect("the broken message is an error")
        .to_string();
    assert!(
        err.contains(TOPIC_SIM_TRUTH) && err.contains("message 1"),
        "{err}"
    );
}

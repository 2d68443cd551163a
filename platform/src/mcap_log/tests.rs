//! MCAP files written by the Python `mcap` package (scripts/make_ros_fixtures.py): with a
//! summary and `ros1` encoding, without one and `cdr`; damaged copies of them.

use super::*;
use crate::rosrec::LogMessage;

pub(crate) fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/ros2-sim")
        .join(name)
}

fn imu_log_times(log: &McapLog) -> Vec<i64> {
    log.messages("/imu0")
        .filter_map(Result::ok)
        .map(|m| m.log_time_ns)
        .collect()
}

/// A copy of `path` changed by `edit`.
fn copy_with(path: &Path, edit: impl FnOnce(&mut Vec<u8>)) -> tempfile::NamedTempFile {
    let mut b = std::fs::read(path).unwrap();
    edit(&mut b);
    let f = tempfile::Builder::new().suffix(".mcap").tempfile().unwrap();
    std::fs::write(f.path(), &b).unwrap();
    f
}

#[test]
fn topics_with_and_without_a_summary() {
    let s = |a: &str, b: &str, n| (a.to_string(), b.to_string(), n);
    let want = [
        s("/cam0/gray_png", "sensor_msgs/CompressedImage", 14),
        s("/cam0/image_raw", "sensor_msgs/Image", 14),
        s("/chatter", "std_msgs/String", 14),
        s("/imu0", "sensor_msgs/Imu", 401),
    ];
    for (name, enc, summary) in [
        ("ros1.mcap", Encoding::Ros1, true),
        ("cdr-nosummary.mcap", Encoding::Cdr, false),
    ] {
        let log = McapLog::open(&fixture(name)).unwrap();
        assert_eq!(log.from_summary, summary, "{name}");
        assert!(log.warnings.is_empty(), "{name}: {:?}", log.warnings);
        let t = log.topics();
        let got: Vec<_> = t
            .iter()
            .map(|t| (t.topic.clone(), t.msg_type.clone(), t.count))
            .collect();
        assert_eq!(got, want, "{name}");
        assert!(t.iter().all(|t| t.encoding == enc));
        let imu = t.iter().find(|t| t.topic == "/imu0").unwrap();
        assert_eq!(imu.span_ns, Some((1_000_000_000, 3_000_000_000)), "{name}");
        assert!(log.chunks > 5, "{name}: {} chunks", log.chunks);
        let times = imu_log_times(&log);
        assert_eq!(times.len(), 401);
        assert!(times.windows(2).all(|w| w[1] - w[0] == 5_000_000));
        assert!(log.describe().contains("chunks"), "{}", log.describe());
    }
}

#[test]
fn a_channel_of_another_encoding_is_listed_not_read() {
    let log = McapLog::open(&fixture("ros1.mcap")).unwrap();
    let mut log = log;
    for c in log.channels.values_mut().filter(|c| c.topic == "/imu0") {
        c.encoding = None;
        c.msg_type = "sensor_msgs/Imu (json encoding, not read)".into();
    }
    let t = log.topics();
    let e = crate::rosrec::topics::select(&t, Some("/imu0"), None).unwrap_err();
    assert!(e.contains("json encoding, not read"), "{e}");
    assert_eq!(log.messages("/imu0").count(), 0);
}

/// (offset, length) of every chunk record of a file.
fn chunks(path: &Path) -> Vec<(u64, u64)> {
    let log = McapLog::open(path).unwrap();
    log.parts.iter().map(|p| (p.pos, p.len)).collect()
}

#[test]
fn a_chunk_with_a_bad_crc_is_skipped_naming_its_offset() {
    for name in ["ros1.mcap", "cdr-nosummary.mcap"] {
        let path = fixture(name);
        let all = imu_log_times(&McapLog::open(&path).unwrap());
        let (pos, _) = chunks(&path)[3];
        // The chunk header's uncompressed_crc (after start time, end time, size).
        let f = copy_with(&path, |b| b[pos as usize + 9 + 24] ^= 0x5A);
        let log = McapLog::open(f.path()).unwrap();
        let items: Vec<Result<LogMessage, IoError>> = log.messages("/imu0").collect();
        let errs: Vec<String> = items
            .iter()
            .filter_map(|r| r.as_ref().err().map(ToString::to_string))
            .collect();
        if log.from_summary {
            assert_eq!(errs.len(), 1, "{name}: {errs:?}");
            assert!(
                errs[0].contains(&format!("at byte offset {pos}"))
                    && errs[0].to_lowercase().contains("crc")
                    && errs[0].contains("log time"),
                "{name}: {}",
                errs[0]
            );
        } else {
            // Found by the walk: a warning at open, and the part in the stream.
            assert!(
                log.warnings
                    .iter()
                    .any(|w| w.contains(&format!("chunk at byte offset {pos}"))),
                "{name}: {:?}",
                log.warnings
            );
            assert!(
                errs.iter()
                    .any(|e| e.contains(&format!("at byte offset {pos}"))),
                "{name}: {errs:?}"
            );
        }
        let got: Vec<i64> = items
            .iter()
            .filter_map(|r| r.as_ref().ok().map(|m| m.log_time_ns))
            .collect();
        assert!(got.len() < all.len() && got.len() > all.len() / 2, "{name}");
        assert!(got.iter().all(|t| all.contains(t)));
        assert!(got.windows(2).all(|w| w[0] < w[1]));
    }
}

#[test]
fn a_flipped_byte_in_a_chunk_is_skipped_and_the_stream_goes_on() {
    for name in ["ros1.mcap", "cdr-nosummary.mcap"] {
        let path = fixture(name);
        let full = imu_log_times(&McapLog::open(&path).unwrap());
        let (pos, len) = chunks(&path)[2];
        let f = copy_with(&path, |b| b[(pos + len / 2) as usize] ^= 0x10);
        let log = McapLog::open(f.path()).unwrap();
        let mut errs = 0;
        let mut got = Vec::new();
        for m in log.messages("/imu0") {
            match m {
                Ok(m) => got.push(m.log_time_ns),
                Err(e) => {
                    errs += 1;
                    assert!(e.to_string().contains(&format!("byte offset {pos}")), "{e}");
                }
            }
        }
        assert!(errs <= 1, "{name}");
        assert!(got.iter().all(|t| full.contains(t)), "{name}");
        assert!(got.len() + 40 > full.len(), "{name}: {}", got.len());
        assert!(*got.last().unwrap() == *full.last().unwrap(), "{name}");
    }
}

#[test]
fn cut_anywhere_gives_a_prefix_with_a_warning() {
    for name in ["ros1.mcap", "cdr-nosummary.mcap"] {
        let path = fixture(name);
        let want = imu_log_times(&McapLog::open(&path).unwrap());
        let n = std::fs::metadata(&path).unwrap().len() as usize;
        let mut last = 0;
        for k in 1..60 {
            let cut = n * k / 60;
            let f = copy_with(&path, |b| b.truncate(cut));
            let log = McapLog::open(f.path()).unwrap();
            let got = imu_log_times(&log);
            assert_eq!(got[..], want[..got.len()], "{name}: cut at {cut}");
            assert!(got.len() >= last, "{name}: cut at {cut}");
            assert!(
                log.warnings.iter().any(|w| w.contains("no footer")),
                "{name}: cut at {cut}: {:?}",
                log.warnings
            );
            if got.len() < want.len() {
                assert!(
                    log.warnings
                        .iter()
                        .any(|w| w.contains(&format!("file cut at byte {cut}"))),
                    "{name}: cut at {cut}: {:?}",
                    log.warnings
                );
            }
            last = got.len();
        }
        assert!(last > 360, "{name}: {last}");
    }
    // Not an MCAP file at all.
    let f = copy_with(&fixture("ros1.mcap"), |b| b.truncate(5));
    let e = McapLog::open(f.path()).unwrap_err();
    assert!(e.to_string().contains("not an MCAP file"), "{e}");
}

#[test]
fn flipped_bytes_never_panic_and_errors_name_an_offset() {
    for name in ["ros1.mcap", "cdr-nosummary.mcap"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let mut s = 0x2545_F491u32;
        let mut rng = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as usize
        };
        let f = tempfile::Builder::new().suffix(".mcap").tempfile().unwrap();
        let mut opened = 0;
        for _ in 0..120 {
            let mut b = bytes.clone();
            for _ in 0..4 {
                let i = rng() % b.len();
                b[i] ^= 1 << (rng() % 8);
            }
            std::fs::write(f.path(), &b).unwrap();
            let Ok(log) = McapLog::open(f.path()) else {
                continue;
            };
            opened += 1;
            for t in log.topics() {
                for m in log.messages(&t.topic) {
                    if let Err(e) = m {
                        let e = e.to_string();
                        assert!(
                            e.contains("byte offset") && !e.contains("byte offset 0:"),
                            "{e}"
                        );
                    }
                }
            }
        }
        assert!(opened > 100, "{name}: {opened}");
    }
}

/// The calibration of the EuRoC fixture folder.
pub(crate) fn euroc_calibration() -> crate::dataset::Calibration {
    use crate::recording::Recording;
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/euroc-v101-30s-features");
    crate::euroc::EurocFolder::open(&p)
        .unwrap()
        .calibration()
        .clone()
}

#[test]
fn povins_own_mcap_is_told_apart() {
    let ds = crate::dataset::Dataset {
        name: "tiny".into(),
        calib: euroc_calibration(),
        imu: Vec::new(),
        features: Vec::new(),
        images: Vec::new(),
        lidar: Vec::new(),
        ground_truth: Vec::new(),
        sim_truth: None,
    };
    let f = tempfile::Builder::new().suffix(".mcap").tempfile().unwrap();
    crate::mcap_io::write_dataset(f.path(), &ds).unwrap();
    let cal = crate::mcap_io::CALIBRATION_METADATA;
    assert!(has_metadata(f.path(), cal));
    assert!(!crate::containers::is_ros_recording(f.path()));
    for name in ["ros1.mcap", "cdr-nosummary.mcap"] {
        assert!(!has_metadata(&fixture(name), cal));
        assert!(crate::containers::is_ros_recording(&fixture(name)));
    }
}

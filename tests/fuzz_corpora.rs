//! Replays every file of `fuzz/corpus/TARGET/` and `fuzz/artifacts/TARGET/` through the same
//! "run one input" functions the cargo-fuzz targets call (`fuzz/src/lib.rs`, included here), so
//! a normal `cargo test` guards the corpora and the crash reproducers without the fuzzing
//! toolchain. Each file must be handled without a panic. `write_seeds` (ignored) made the
//! generated seeds of the corpora.

#[path = "../fuzz/src/lib.rs"]
mod entry;

use std::path::{Path, PathBuf};

const FUZZ: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fuzz");

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.retain(|p| p.is_file());
    v.sort();
    v
}

/// Runs every input of one target on a thread with a small stack (as the fuzzer's main thread
/// would hold less than the test harness's); panics name the file.
fn replay(target: &str) {
    let run = entry::TARGETS
        .iter()
        .find(|(n, _)| *n == target)
        .map(|(_, f)| *f)
        .expect("a target");
    let mut inputs = files(&Path::new(FUZZ).join("corpus").join(target));
    assert!(!inputs.is_empty(), "fuzz/corpus/{target} is empty");
    inputs.extend(files(&Path::new(FUZZ).join("artifacts").join(target)));
    let target = target.to_string();
    std::thread::Builder::new()
        .stack_size(8 << 20)
        .spawn(move || {
            for p in &inputs {
                let data = std::fs::read(p).expect("readable input");
                let r = std::panic::catch_unwind(|| run(&data));
                assert!(r.is_ok(), "{target}: {} panicked", p.display());
            }
            entry::remove_scratch();
        })
        .expect("thread")
        .join()
        .expect("replay thread");
}

#[test]
fn every_target_has_a_test() {
    let names: Vec<&str> = entry::TARGETS.iter().map(|(n, _)| *n).collect();
    let dirs: Vec<String> = std::fs::read_dir(Path::new(FUZZ).join("fuzz_targets"))
        .expect("fuzz/fuzz_targets")
        .filter_map(|e| {
            let p = e.ok()?.path();
            Some(p.file_stem()?.to_str()?.to_string())
        })
        .collect();
    for d in &dirs {
        assert!(
            names.contains(&d.as_str()),
            "fuzz target {d} missing from TARGETS"
        );
    }
    assert_eq!(names.len(), dirs.len());
}

#[test]
fn euroc_csv() {
    replay("euroc_csv");
}
#[test]
fn euroc_yaml() {
    replay("euroc_yaml");
}
#[test]
fn kalibr_yaml() {
    replay("kalibr_yaml");
}
#[test]
fn rosbag1() {
    replay("rosbag1");
}
#[test]
fn mcap() {
    replay("mcap");
}
#[test]
fn ros_msgs() {
    replay("ros_msgs");
}
#[test]
fn image() {
    replay("image");
}
#[test]
fn config_toml() {
    replay("config_toml");
}
#[test]
fn estimator() {
    replay("estimator");
}
#[test]
fn ouster_packets() {
    replay("ouster_packets");
}

// ---------------------------------------------------------------------------------------------
// Seeds

fn seed(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new(FUZZ).join("corpus").join(target);
    std::fs::create_dir_all(&dir).unwrap();
    assert!(
        bytes.len() < 100_000,
        "{target}/{name}: {} bytes",
        bytes.len()
    );
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn with_sel(sel: u8, body: &[u8]) -> Vec<u8> {
    let mut v = vec![sel];
    v.extend_from_slice(body);
    v
}

/// The first `lines` lines of a file.
fn head(path: &str, lines: usize) -> Vec<u8> {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).unwrap();
    let mut out = String::new();
    for l in text.lines().take(lines) {
        out.push_str(l);
        out.push('\n');
    }
    out.into_bytes()
}

fn read(path: &str) -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).unwrap()
}

/// Writes the seeds of `fuzz/corpus/` from the repository's small real inputs (by hand:
/// `POVINS_WRITE_SEEDS=1 cargo test --test fuzz_corpora write_seeds -- --ignored`; without the
/// variable it does nothing, so that CI's run of the ignored tests leaves the corpus alone).
#[test]
#[ignore = "writes fuzz/corpus: run by hand with POVINS_WRITE_SEEDS=1"]
fn write_seeds() {
    if std::env::var_os("POVINS_WRITE_SEEDS").is_none() {
        eprintln!("write_seeds: set POVINS_WRITE_SEEDS=1 to rewrite the seeds of fuzz/corpus");
        return;
    }
    use povins::platform::dataset::{Dataset, ImageFrame, LidarScan};
    use povins::platform::rosbag1::write::Compression;
    use povins::platform::rosrec::{write::DatasetTopics, Encoding};
    const E: &str = "tests/data/euroc-v101-30s-features/mav0";
    // euroc_csv: selector 0 IMU, 1 features, 2 LiDAR, 3 camera list, 4 ground truth, 5 scans.
    seed(
        "euroc_csv",
        "imu",
        &with_sel(0, &head(&format!("{E}/imu0/data.csv"), 12)),
    );
    seed(
        "euroc_csv",
        "features",
        &with_sel(1, &head(&format!("{E}/features0/data.csv"), 40)),
    );
    seed("euroc_csv", "lidar", &with_sel(2, b"#timestamp [ns],point_timestamp [ns],x [m],y [m],z [m],intensity\n1000,900,1.0,2.0,3.0,10\n1000,950,1.5,-2.0,0.5,12\n2000,1900,4.0,0.0,-1.0,0\n"));
    seed("euroc_csv", "cam", &with_sel(3, b"#timestamp [ns],filename\n1403715273262142976,1403715273262142976.png\n1403715273312143104,1403715273312143104.png\n"));
    seed(
        "euroc_csv",
        "groundtruth",
        &with_sel(
            4,
            &head(&format!("{E}/state_groundtruth_estimate0/data.csv"), 6),
        ),
    );
    seed(
        "euroc_csv",
        "scan",
        &with_sel(5, &head(&format!("{E}/imu0/data.csv"), 4)),
    );
    // euroc_yaml: 0 imu0, 1 cam0, 2 lidar0.
    seed(
        "euroc_yaml",
        "imu0",
        &with_sel(0, &read(&format!("{E}/imu0/sensor.yaml"))),
    );
    seed(
        "euroc_yaml",
        "cam0",
        &with_sel(1, &read(&format!("{E}/cam0/sensor.yaml"))),
    );
    seed("euroc_yaml", "lidar0", &with_sel(2, b"sensor_type: lidar\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n"));
    // kalibr_yaml: even camchain, odd imu.
    for name in ["euroc-v101", "sim", "wiki"] {
        seed(
            "kalibr_yaml",
            &format!("{name}-camchain"),
            &with_sel(
                0,
                &read(&format!("tests/data/kalibr/{name}-camchain-imucam.yaml")),
            ),
        );
        seed(
            "kalibr_yaml",
            &format!("{name}-imu"),
            &with_sel(1, &read(&format!("tests/data/kalibr/{name}-imu.yaml"))),
        );
    }
    // A small data set: 0.1 s of EuRoC IMU, one 16x12 image, one LiDAR sweep.
    let mut ds: Dataset =
        povins::platform::euroc::read_dataset(&Path::new(env!("CARGO_MANIFEST_DIR")).join(E))
            .unwrap();
    let t0 = ds.imu[0].t_ns;
    ds.imu.retain(|s| s.t_ns <= t0 + 50_000_000);
    ds.features.retain(|f| f.t_ns <= t0 + 50_000_000);
    ds.ground_truth.retain(|g| g.t_ns <= t0 + 50_000_000);
    ds.images = vec![ImageFrame {
        t_ns: t0 + 20_000_000,
        width: 16,
        height: 12,
        mono8: (0..192).map(|i| (i * 7 % 256) as u8).collect(),
        path: None,
    }];
    ds.lidar = vec![LidarScan {
        t_ns: t0 + 25_000_000,
        points: (0..8)
            .map(|i| povins::core::lidar::LidarPoint {
                t_ns: t0 + 25_000_000 + i * 100_000,
                p_l: [i as f32, 1.0, -0.5],
                intensity: 3.0,
            })
            .collect(),
    }];
    ds.calib.t_bl = Some(povins::platform::dataset::Extrinsic::identity());
    let dir = tempfile::tempdir().unwrap();
    let topics = DatasetTopics::realsense();
    for (c, name) in [
        (Compression::None, "small"),
        (Compression::Lz4, "small-lz4"),
        (Compression::Bz2, "small-bz2"),
    ] {
        let p = dir.path().join(format!("{name}.bag"));
        povins::platform::rosbag1::write::write_dataset(&p, &ds, &topics, c).unwrap();
        seed("rosbag1", name, &std::fs::read(&p).unwrap());
    }
    let bag = read("tests/data/rosbag1-sim/sim.bag");
    seed("rosbag1", "sim-cut", &bag[..60_000]);
    let p = dir.path().join("povins.mcap");
    povins::platform::mcap_io::write_dataset(&p, &ds).unwrap();
    seed("mcap", "povins", &std::fs::read(&p).unwrap());
    seed("mcap", "ros1", &read("tests/data/ros2-sim/ros1.mcap"));
    seed(
        "mcap",
        "cdr-nosummary",
        &read("tests/data/ros2-sim/cdr-nosummary.mcap"),
    );
    // ros_msgs: the first message of each topic of the small containers.
    for path in [
        "tests/data/ros2-sim/ros1.mcap",
        "tests/data/ros2-sim/cdr-nosummary.mcap",
    ] {
        let log = povins::platform::containers::open_log(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join(path),
        )
        .unwrap();
        for t in log.topics() {
            let Some(sel) = entry::msg_selector(&t.msg_type, t.encoding) else {
                continue;
            };
            let Some(Ok(m)) = log.messages(&t.topic).next() else {
                continue;
            };
            if m.data.len() >= 100_000 {
                continue;
            }
            let enc = if t.encoding == Encoding::Cdr {
                "cdr"
            } else {
                "ros1"
            };
            let name = format!("{enc}-{}", t.msg_type.replace('/', "_"));
            seed("ros_msgs", &name, &with_sel(sel, &m.data));
        }
    }
    let bag = povins::platform::containers::open_log(&dir.path().join("small.bag")).unwrap();
    for t in bag.topics() {
        let Some(sel) = entry::msg_selector(&t.msg_type, t.encoding) else {
            continue;
        };
        let Some(Ok(m)) = bag.messages(&t.topic).next() else {
            continue;
        };
        seed(
            "ros_msgs",
            &format!("bag-{}", t.msg_type.replace('/', "_")),
            &with_sel(sel, &m.data),
        );
    }
    // ros_msgs: a small sweep in every LiDAR wire format, in both encodings.
    {
        use povins::platform::cloud::{livox::CustomMsg, Wire};
        use povins::platform::dataset::LidarScan;
        let t0 = 1_700_000_000_000_000_000;
        let sweep = LidarScan {
            t_ns: t0,
            points: (0..8)
                .map(|k| povins::core::lidar::LidarPoint {
                    t_ns: t0 + k * 10_000_000,
                    p_l: [k as f32, 1.0, 0.5 - k as f32 * 0.1],
                    intensity: 10.0 * k as f32,
                })
                .collect(),
        };
        for wire in Wire::all() {
            for enc in [Encoding::Ros1, Encoding::Cdr] {
                let (ty, bytes) = match (wire, enc) {
                    (Wire::Cloud(l), Encoding::Ros1) => (
                        "sensor_msgs/PointCloud2",
                        povins::platform::rosbag1::msgs::encode_point_cloud2_in(
                            l, &sweep, 0, "lidar",
                        )
                        .unwrap(),
                    ),
                    (Wire::Cloud(l), Encoding::Cdr) => (
                        "sensor_msgs/PointCloud2",
                        povins::platform::ros2::convert::lidar_to_msg_in(l, &sweep, "lidar")
                            .unwrap()
                            .encode()
                            .unwrap(),
                    ),
                    (_, _) => {
                        let m = CustomMsg::from_scan(&sweep, "livox").unwrap();
                        let b = match enc {
                            Encoding::Ros1 => {
                                povins::platform::rosbag1::msgs::encode_livox_custom_msg(&m, 0)
                                    .unwrap()
                            }
                            Encoding::Cdr => m.encode_cdr().unwrap(),
                        };
                        ("livox_ros_driver/CustomMsg", b)
                    }
                };
                let sel = entry::msg_selector(ty, enc).unwrap();
                let e = if enc == Encoding::Cdr { "cdr" } else { "ros1" };
                seed(
                    "ros_msgs",
                    &format!("lidar-{}-{e}", wire.name()),
                    &with_sel(sel, &bytes),
                );
            }
        }
    }
    // image: a small real PNG and JPEG, a raw mono8 header.
    let mut png = Vec::new();
    {
        let mut e = png::Encoder::new(&mut png, 16, 12);
        e.set_color(png::ColorType::Grayscale);
        e.set_depth(png::BitDepth::Eight);
        let mut w = e.write_header().unwrap();
        w.write_image_data(&ds.images[0].mono8).unwrap();
    }
    seed("image", "gray.png", &png);
    let mut jpg = Vec::new();
    jpeg_encoder::Encoder::new(&mut jpg, 90)
        .encode(&ds.images[0].mono8, 16, 12, jpeg_encoder::ColorType::Luma)
        .unwrap();
    seed("image", "gray.jpg", &jpg);
    let mut raw = vec![0u8];
    raw.extend_from_slice(&16u16.to_le_bytes());
    raw.extend_from_slice(&12u16.to_le_bytes());
    raw.extend_from_slice(&16u16.to_le_bytes());
    raw.push(0);
    raw.extend_from_slice(&ds.images[0].mono8);
    seed("image", "raw-mono8", &raw);
    // config_toml: the repository's configurations.
    for e in std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            seed(
                "config_toml",
                p.file_name().unwrap().to_str().unwrap(),
                &std::fs::read(&p).unwrap(),
            );
        }
    }
    // estimator (ops: see entry::OPS): 6 s of real data; with a NaN sample, a reset, a grid
    // frame and a LiDAR sweep between; an initialization with a zero quaternion.
    let replay = |n: usize| [5u8, 255].repeat(n);
    seed("estimator", "replay-6s", &replay(24));
    let mut v = replay(4);
    v.extend_from_slice(&[0, 0x88, 0x13, 0, 0, 0, 0, 0, 0, 0, 0]);
    v.extend(replay(2));
    v.push(7);
    v.extend(replay(6));
    v.extend_from_slice(&[3, 0x10, 0x27, 0, 0, 60, 5]);
    v.extend_from_slice(&[
        4, 2, 0x10, 0x27, 0, 0, 0, 0, 0x80, 0x3f, 0, 0, 0, 0x40, 0, 0, 0, 0, 0, 0, 0, 0,
    ]);
    v.extend(replay(4));
    seed("estimator", "replay-corrupt", &v);
    let mut v = vec![8, 0, 0, 0, 0];
    v.extend([16u8, 0, 0].repeat(16));
    v.extend(replay(8));
    seed("estimator", "initialize", &v);
}

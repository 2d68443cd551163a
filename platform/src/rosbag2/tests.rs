//! ROS 2 bags written by the Python `rosbags` package (scripts/make_ros_fixtures.py), and every
//! container of the same sequence read the same through [`RosRecording`].

use super::*;
use crate::containers::open_log;
use crate::dataset::ImageFrame;
use crate::mcap_log::tests::{euroc_calibration, fixture};
use crate::recording::Recording;
use crate::rosrec::recording::RosRecording;
use crate::rosrec::Encoding;
use povins_core::inertial::ImuSample;

fn reference_bag() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rosbag1-sim/sim.bag")
}

/// The IMU samples, the raw images and the PNG images of a recording, through the recording
/// layer; with its warnings.
fn samples(
    path: &Path,
) -> (
    Vec<ImuSample>,
    Vec<ImageFrame>,
    Vec<ImageFrame>,
    Vec<String>,
) {
    let read = |camera: &str| {
        let log = open_log(path).unwrap();
        RosRecording::new(
            log,
            euroc_calibration(),
            &crate::rosrec::topics::TopicChoice {
                image: Some(camera.into()),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let rec = read("/cam0/image_raw");
    let imu: Vec<_> = rec.imu().unwrap().map(Result::unwrap).collect();
    let raw: Vec<_> = rec.images().unwrap().map(Result::unwrap).collect();
    let png_rec = read("/cam0/gray_png");
    let png: Vec<_> = png_rec.images().unwrap().map(Result::unwrap).collect();
    let mut w = rec.warnings();
    w.extend(png_rec.warnings());
    (imu, raw, png, w)
}

#[test]
fn every_container_gives_the_samples_of_the_ros1_bag() {
    let (imu, raw, png, w) = samples(&reference_bag());
    assert!(w.is_empty(), "{w:?}");
    assert_eq!((imu.len(), raw.len()), (401, 14));
    assert_eq!(raw, png);
    for name in ["sqlite3", "mcap", "ros1.mcap", "cdr-nosummary.mcap"] {
        let (i, r, p, w) = samples(&fixture(name));
        assert!(w.is_empty(), "{name}: {w:?}");
        assert_eq!(i, imu, "{name}");
        assert_eq!(r, raw, "{name}");
        assert_eq!(p, png, "{name}");
    }
    // A bare .db3 file: the second half of the split bag.
    let (i, ..) = samples(&fixture("sqlite3/sqlite3_1.db3"));
    assert_eq!(i[..], imu[imu.len() - i.len()..]);
    assert!(i.len() > 150 && i[0].t_ns == 2_000_000_000);
}

#[test]
fn bag_folders_list_their_topics_and_storage() {
    for (name, storage) in [
        ("sqlite3", "sqlite3 storage, 2 files"),
        ("mcap", "mcap storage"),
    ] {
        let bag = Rosbag2::open(&fixture(name)).unwrap();
        assert!(bag.describe().contains(storage), "{}", bag.describe());
        assert!(bag.warnings().is_empty(), "{:?}", bag.warnings());
        let t: Vec<_> = bag
            .topics()
            .into_iter()
            .map(|t| (t.topic, t.msg_type, t.count, t.encoding, t.span_ns))
            .collect();
        let span = Some((1_000_000_000, 3_000_000_000));
        let cam_span = t[0].4;
        assert_eq!(
            t,
            [
                (
                    "/cam0/gray_png".into(),
                    "sensor_msgs/CompressedImage".into(),
                    14,
                    Encoding::Cdr,
                    cam_span
                ),
                (
                    "/cam0/image_raw".into(),
                    "sensor_msgs/Image".into(),
                    14,
                    Encoding::Cdr,
                    cam_span
                ),
                (
                    "/chatter".into(),
                    "std_msgs/String".into(),
                    14,
                    Encoding::Cdr,
                    cam_span
                ),
                (
                    "/imu0".into(),
                    "sensor_msgs/Imu".into(),
                    401,
                    Encoding::Cdr,
                    span
                ),
            ],
            "{name}"
        );
    }
}

/// A copy of the bag folder `name` whose `metadata.yaml` is changed by `edit`.
fn folder_with(name: &str, edit: impl FnOnce(String) -> String) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(fixture(name)).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, d.path().join(p.file_name().unwrap())).unwrap();
    }
    let m = d.path().join(METADATA_FILE);
    let text = std::fs::read_to_string(&m).unwrap();
    std::fs::write(&m, edit(text)).unwrap();
    d
}

#[test]
fn metadata_problems_are_named() {
    // A stale count: a warning naming the topic.
    let d = folder_with("sqlite3", |t| {
        t.replacen("message_count: 401", "message_count: 400", 1)
    });
    let bag = Rosbag2::open(d.path()).unwrap();
    let w = bag.warnings();
    assert!(
        w.iter()
            .any(|w| w.contains("/imu0") && w.contains("400") && w.contains("401")),
        "{w:?}"
    );
    // Another storage plugin.
    let d = folder_with("mcap", |t| {
        t.replace("storage_identifier: mcap", "storage_identifier: rosbag_v2")
    });
    let e = Rosbag2::open(d.path()).unwrap_err().to_string();
    assert!(
        e.contains("metadata.yaml") && e.contains("rosbag_v2"),
        "{e}"
    );
    // A missing storage file.
    let d = folder_with("sqlite3", |t| t.replace("sqlite3_1.db3", "gone.db3"));
    let e = Rosbag2::open(d.path()).unwrap_err().to_string();
    assert!(e.contains("gone.db3"), "{e}");
    // Not YAML.
    let d = folder_with("sqlite3", |_| "rosbag2_bagfile_information: [".into());
    let e = Rosbag2::open(d.path()).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml"), "{e}");
}

#[test]
fn a_damaged_db3_never_panics() {
    let bytes = std::fs::read(fixture("sqlite3/sqlite3_0.db3")).unwrap();
    let mut s = 0x1234_5677u32;
    let mut rng = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as usize
    };
    let f = tempfile::Builder::new().suffix(".db3").tempfile().unwrap();
    for k in 0..60 {
        let mut b = bytes.clone();
        if k % 3 == 0 {
            b.truncate(rng() % b.len());
        } else {
            for _ in 0..8 {
                let i = rng() % b.len();
                b[i] ^= 1 << (rng() % 8);
            }
        }
        std::fs::write(f.path(), &b).unwrap();
        let Ok(bag) = Rosbag2::open(f.path()) else {
            continue;
        };
        for t in bag.topics() {
            for m in bag.messages(&t.topic) {
                if let Err(e) = m {
                    assert!(e.to_string().contains("sqlite3 bag"), "{e}");
                }
            }
        }
    }
}

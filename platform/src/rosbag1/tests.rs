//! Tests on the real bags of `../shared/data/fixtures` (recorded by ROS) and on cut and
//! unindexed copies of them made here.

use super::*;
use crate::rosrec::{recording, topics, MessageLog};
use std::collections::HashSet;

fn fixture(name: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/fixtures")
        .join(name);
    assert!(
        p.exists(),
        "{} is missing: these tests need ../shared/data",
        p.display()
    );
    p
}

/// Every message of a bag as (receipt time, topic, bytes), in the order read.
fn all_messages(bag: &Bag) -> Vec<(i64, String, Vec<u8>)> {
    let conns: HashSet<u32> = bag.connections.keys().copied().collect();
    bag.conn_messages(conns)
        .map(|m| {
            let m = m.unwrap();
            (m.time_ns, bag.connections[&m.conn].topic.clone(), m.data)
        })
        .collect()
}

fn sorted(mut v: Vec<(i64, String, Vec<u8>)>) -> Vec<(i64, String, Vec<u8>)> {
    v.sort();
    v
}

/// A copy of `src` in a temporary file, changed by `edit`.
fn copy_with(src: &Path, edit: impl FnOnce(&mut Vec<u8>)) -> tempfile::NamedTempFile {
    let mut b = std::fs::read(src).unwrap();
    edit(&mut b);
    let f = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(f.path(), &b).unwrap();
    f
}

/// Offset of the `index_pos` value in the bag header (after `index_pos=`).
fn index_pos_field(b: &[u8]) -> usize {
    let key = b"index_pos=";
    b.windows(key.len()).position(|w| w == key).unwrap() + key.len()
}

// Counts and times from an independent reader (the Python `rosbags` package).
const TURTLE_MESSAGES: usize = 8647;
const TURTLE_START_NS: i64 = 1_396_293_887_844_783_943;
/// The last message (`rosbags` gives the end time exclusive: this + 1).
const TURTLE_LAST_NS: i64 = 1_396_293_909_544_870_199;

#[test]
#[ignore = "needs ../shared/data"]
fn turtlesim_bags_read_the_same_messages_uncompressed_bz2_lz4() {
    let plain = Bag::open(&fixture("rosbag/example.bag")).unwrap();
    assert!(
        plain.indexed && plain.warnings.is_empty(),
        "{:?}",
        plain.warnings
    );
    assert_eq!(plain.connections.len(), 12);
    let want = all_messages(&plain);
    assert_eq!(want.len(), TURTLE_MESSAGES);
    assert_eq!(want[0].0, TURTLE_START_NS);
    assert_eq!(want[want.len() - 1].0, TURTLE_LAST_NS);
    assert!(
        want.windows(2).all(|w| w[0].0 <= w[1].0),
        "not in time order"
    );
    let counts = plain.topics();
    let pose = counts.iter().find(|t| t.topic == "/turtle1/pose").unwrap();
    assert_eq!(
        (pose.msg_type.as_str(), pose.count),
        ("turtlesim/Pose", 1344)
    );
    let tf: u64 = counts
        .iter()
        .filter(|t| t.topic == "/tf")
        .map(|t| t.count)
        .sum();
    assert_eq!(tf, 2688);
    for name in ["rosbag/example-bz2.bag", "rosbag/example-lz4.bag"] {
        let bag = Bag::open(&fixture(name)).unwrap();
        assert!(bag.indexed && bag.warnings.is_empty(), "{name}");
        assert_eq!(bag.connections.len(), 9, "{name}");
        let got = all_messages(&bag);
        assert!(got.windows(2).all(|w| w[0].0 <= w[1].0), "{name}");
        assert_eq!(sorted(got), sorted(want.clone()), "{name}");
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn unsorted_chunks_come_out_in_time_order() {
    let bag = Bag::open(&fixture("rosbag/example-unsorted-chunks.bag")).unwrap();
    assert_eq!(bag.chunks.len(), 3);
    let starts: Vec<i64> = bag.chunks.iter().map(|c| c.start_ns).collect();
    assert!(
        starts.windows(2).any(|w| w[0] > w[1]),
        "chunks are in order: {starts:?}"
    );
    let got = all_messages(&bag);
    let times: Vec<i64> = got.iter().map(|m| m.0).collect();
    assert_eq!(times, [1_000_000_000, 2_000_000_000, 3_000_000_000]);
    assert!(got.iter().all(|m| m.1 == "foo"));
}

#[test]
#[ignore = "needs ../shared/data"]
fn empty_and_message_less_bags() {
    let e = Bag::open(&fixture("rosbag/empty-file.bag")).unwrap_err();
    assert!(
        e.to_string().contains("empty-file.bag") && e.to_string().contains("0 bytes"),
        "{e}"
    );
    let bag = Bag::open(&fixture("rosbag/no-messages.bag")).unwrap();
    assert!(bag.indexed && bag.chunks.is_empty() && bag.connections.is_empty());
    assert_eq!(all_messages(&bag).len(), 0);
    let sel = topics::select(&bag.topics(), None, None).unwrap();
    assert_eq!(
        sel,
        topics::Selection {
            imu: None,
            camera: None,
            accel: None,
            lidar: None,
            lidar_note: None,
        }
    );
}

#[test]
#[ignore = "needs ../shared/data"]
fn ouster_bag_lists_its_packet_topics() {
    let bag = Bag::open(&fixture("ouster/512x10_raw.bag")).unwrap();
    let t = bag.topics();
    let names: Vec<(&str, &str, u64)> = t
        .iter()
        .map(|t| (t.topic.as_str(), t.msg_type.as_str(), t.count))
        .collect();
    assert_eq!(
        names,
        [
            ("/os_node0/imu_packets", "ouster_ros/PacketMsg", 10),
            ("/os_node0/lidar_packets", "ouster_ros/PacketMsg", 32),
            ("/os_node0/metadata", "std_msgs/String", 1),
        ]
    );
    assert_eq!(all_messages(&bag).len(), 43);
}

#[test]
#[ignore = "needs ../shared/data"]
fn unindexed_bags_are_scanned() {
    for name in [
        "rosbag/example.bag",
        "rosbag/example-lz4.bag",
        "rosbag/example-unsorted-chunks.bag",
    ] {
        let full = Bag::open(&fixture(name)).unwrap();
        let want = sorted(all_messages(&full));
        // As a killed recorder leaves it: index_pos 0 and no index section.
        let f = copy_with(&fixture(name), |b| {
            let at = index_pos_field(b);
            let pos = u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
            b.truncate(pos);
            b[at..at + 8].copy_from_slice(&0u64.to_le_bytes());
        });
        let bag = Bag::open(f.path()).unwrap();
        assert!(!bag.indexed, "{name}");
        assert!(bag.warnings[0].contains("unindexed"), "{:?}", bag.warnings);
        assert_eq!(bag.chunks.len(), full.chunks.len(), "{name}");
        let got = all_messages(&bag);
        assert!(got.windows(2).all(|w| w[0].0 <= w[1].0), "{name}");
        assert_eq!(sorted(got), want, "{name}");
    }
}

/// Cut at `cut` bytes: opening gives an error naming the file (cut in the bag header) or the
/// messages before the cut, a subset of the whole bag's, and a warning.
fn check_cut(name: &str, want: &[(i64, String, Vec<u8>)], cut: usize) -> usize {
    let f = copy_with(&fixture(name), |b| b.truncate(cut));
    match Bag::open(f.path()) {
        Err(e) => {
            assert!(cut < 4200, "{name} cut at {cut}: {e}");
            assert!(
                e.to_string().contains(&f.path().display().to_string()),
                "{e}"
            );
            0
        }
        Ok(bag) => {
            let got = sorted(all_messages(&bag));
            assert!(!bag.warnings.is_empty(), "{name} cut at {cut}: no warning");
            let mut it = want.iter();
            for m in &got {
                assert!(
                    it.any(|w| w == m),
                    "{name} cut at {cut}: a message not in the bag"
                );
            }
            got.len()
        }
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn truncated_bags_give_the_messages_before_the_cut() {
    let name = "rosbag/example-unsorted-chunks.bag";
    let want = sorted(all_messages(&Bag::open(&fixture(name)).unwrap()));
    let len = std::fs::metadata(fixture(name)).unwrap().len() as usize;
    let mut last = 0;
    for cut in 0..len {
        let n = check_cut(name, &want, cut);
        assert!(
            n >= last || cut < 4200,
            "cut {cut}: {n} messages after {last}"
        );
        last = n;
    }
    assert_eq!(last, 3);
    for name in [
        "rosbag/example.bag",
        "rosbag/example-bz2.bag",
        "rosbag/example-lz4.bag",
    ] {
        let full = Bag::open(&fixture(name)).unwrap();
        let want = sorted(all_messages(&full));
        let len = full.file_len as usize;
        let mut counts = Vec::new();
        for k in 1..=20 {
            counts.push(check_cut(name, &want, len * k / 21));
        }
        // A cut inside the index keeps every message (the chunk section is whole).
        assert_eq!(check_cut(name, &want, len - 10), want.len(), "{name}");
        assert!(
            counts.windows(2).all(|w| w[0] <= w[1]),
            "{name}: {counts:?}"
        );
        assert_eq!(counts[19], want.len(), "{name}: {counts:?}");
        if name.ends_with("example.bag") {
            // One uncompressed chunk: the messages before the cut are recovered (a compressed
            // chunk cut inside its one compression block gives nothing).
            assert!(counts[0] > 200 && counts[10] > 4000, "{counts:?}");
        }
    }
}

/// The bag written by `scripts/make_rosbag1_fixture.py` (Python `rosbags`), in the repository.
fn sim_bag() -> Bag {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rosbag1-sim/sim.bag");
    Bag::open(&p).unwrap()
}

#[test]
fn sim_bag_topics_and_selection() {
    let bag = sim_bag();
    assert!(bag.indexed && bag.warnings.is_empty(), "{:?}", bag.warnings);
    assert_eq!(bag.chunks.len(), 15);
    let t: Vec<(String, String, u64)> = bag
        .topics()
        .into_iter()
        .map(|t| (t.topic, t.msg_type, t.count))
        .collect();
    let s = |a: &str, b: &str, n| (a.to_string(), b.to_string(), n);
    assert_eq!(
        t,
        [
            s("/cam0/gray_png", "sensor_msgs/CompressedImage", 14),
            s("/cam0/image_raw", "sensor_msgs/Image", 14),
            s("/chatter", "std_msgs/String", 14),
            s("/imu0", "sensor_msgs/Imu", 401),
        ]
    );
    // Two cameras: an error that lists both.
    let e = topics::select(&bag.topics(), None, None).unwrap_err();
    assert!(
        e.contains("/cam0/gray_png") && e.contains("/cam0/image_raw"),
        "{e}"
    );
    let sel = topics::select(&bag.topics(), None, Some("/cam0/image_raw")).unwrap();
    assert_eq!(sel.imu.unwrap().topic, "/imu0");
    assert_eq!(sel.camera.unwrap().topic, "/cam0/image_raw");
    let e = topics::select(&bag.topics(), Some("/chatter"), Some("/cam0/image_raw")).unwrap_err();
    assert!(e.contains("std_msgs/String"), "{e}");
    let e = topics::select(&bag.topics(), Some("/imu1"), None).unwrap_err();
    assert!(e.contains("not in the recording"), "{e}");
}

#[test]
fn sim_bag_imu_samples_are_the_simulated_ones() {
    let bag = sim_bag();
    let imu: Vec<_> = bag
        .conn_messages(bag.topic_conns("/imu0"))
        .map(|m| msgs::imu(&m.unwrap().data).unwrap())
        .collect();
    assert_eq!(imu.len(), 401);
    // The first row of the simulator's mav0/imu0/data.csv.
    assert_eq!(imu[0].t_ns, 1_000_000_000);
    let g = [
        0.009609999738764391,
        -0.009721961467076243,
        -0.00034230469319042073,
    ];
    let a = [-0.25878049970517975, 0.567036081959351, 9.77593441262786];
    assert_eq!(imu[0].gyro_rps.as_slice(), g);
    assert_eq!(imu[0].accel_mps2.as_slice(), a);
    assert!(imu.windows(2).all(|w| w[1].t_ns - w[0].t_ns == 5_000_000));
}

#[test]
fn sim_bag_raw_images_in_every_encoding_match_their_png() {
    let bag = sim_bag();
    let decode = |topic: &str| -> Vec<crate::dataset::ImageFrame> {
        let conns = bag.topic_conns(topic);
        let ty = bag.connections[conns.iter().next().unwrap()]
            .msg_type
            .clone();
        bag.conn_messages(conns)
            .map(|m| msgs::any_image(&ty, &m.unwrap().data).unwrap())
            .collect()
    };
    let raw = decode("/cam0/image_raw");
    let png = decode("/cam0/gray_png");
    assert_eq!(raw.len(), 14);
    assert_eq!(raw, png);
    assert!(raw.iter().all(|f| (f.width, f.height) == (64, 48)));
    assert!(
        raw.iter().any(|f| f.mono8.iter().any(|&v| v != f.mono8[0])),
        "blank images"
    );
    // The encodings the fixture cycles through are all there.
    let mut encodings = HashSet::new();
    for m in bag.conn_messages(bag.topic_conns("/cam0/image_raw")) {
        let d = m.unwrap().data;
        // header: seq, stamp, frame_id "cam0"; then height, width, encoding.
        let n = u32::from_le_bytes(d[28..32].try_into().unwrap()) as usize;
        encodings.insert(String::from_utf8(d[32..32 + n].to_vec()).unwrap());
    }
    assert_eq!(encodings.len(), 12, "{encodings:?}");
}

#[test]
fn sim_bag_cut_anywhere_gives_a_prefix_of_the_imu_stream() {
    let full = sim_bag();
    let imu = |bag: &Bag| -> Vec<i64> {
        bag.conn_messages(bag.topic_conns("/imu0"))
            .map(|m| msgs::imu(&m.unwrap().data).unwrap().t_ns)
            .collect()
    };
    let want = imu(&full);
    let mut last = 0;
    for k in 1..40 {
        let cut = full.file_len as usize * k / 40;
        let f = copy_with(&full.path, |b| b.truncate(cut));
        let Ok(bag) = Bag::open(f.path()) else {
            assert!(cut < 4200, "cut at {cut} refused");
            continue;
        };
        let got = imu(&bag);
        assert_eq!(got[..], want[..got.len()], "cut at {cut}");
        assert!(got.len() >= last, "cut at {cut}");
        assert!(bag
            .warnings
            .iter()
            .any(|w| w.contains("truncated") || w.contains("cut")));
        last = got.len();
    }
    assert!(last > 380, "{last}");
}

#[test]
fn sim_bag_as_a_recording_streams_imu_and_images() {
    use crate::recording::Recording;
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rosbag1-sim/sim.bag");
    let euroc = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/euroc-v101-30s-features");
    let calib = crate::euroc::EurocFolder::open(&euroc)
        .unwrap()
        .calibration()
        .clone();
    let e = recording::RosRecording::new(
        Box::new(Bag::open(&p).unwrap()),
        calib.clone(),
        &Default::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("2 camera topics"), "{e}");
    let rec = recording::RosRecording::new(
        Box::new(Bag::open(&p).unwrap()),
        calib,
        &topics::TopicChoice {
            image: Some("/cam0/image_raw".into()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(rec.name(), "sim");
    let c = rec.contents();
    assert!(c.imu && c.images && !c.lidar && c.image_count == Some(14));
    let imu: Vec<_> = rec.imu().unwrap().map(Result::unwrap).collect();
    assert_eq!(imu.len(), 401);
    let images: Vec<_> = rec.images().unwrap().map(Result::unwrap).collect();
    assert_eq!(images.len(), 14);
    assert_eq!(images[0].t_ns, 1_000_000_000);
    assert_eq!(images[0].mono8.len(), 64 * 48);
}

#[test]
fn sim_bag_with_flipped_bytes_never_panics() {
    let full = sim_bag();
    let bytes = std::fs::read(&full.path).unwrap();
    let mut s = 0x9E37_79B9u32;
    let mut rng = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as usize
    };
    let f = tempfile::NamedTempFile::new().unwrap();
    let (mut opened, mut errors) = (0, 0);
    for _ in 0..150 {
        let mut b = bytes.clone();
        for _ in 0..4 {
            let i = rng() % b.len();
            b[i] ^= 1 << (rng() % 8);
        }
        std::fs::write(f.path(), &b).unwrap();
        let Ok(bag) = Bag::open(f.path()) else {
            errors += 1;
            continue;
        };
        opened += 1;
        for (id, c) in &bag.connections {
            for m in bag.conn_messages([*id].into_iter().collect()) {
                match m {
                    Ok(m) if c.msg_type == msgs::IMU_TYPE => drop(msgs::imu(&m.data)),
                    Ok(m) => drop(msgs::any_image(&c.msg_type, &m.data)),
                    Err(e) => assert!(e.to_string().contains("byte offset"), "{e}"),
                }
            }
        }
    }
    assert!(opened > 0 && opened + errors == 150);
}

#[test]
fn one_topic_read_sparsely_is_the_same_as_filtered_from_all() {
    // Uncompressed chunks: a topic's messages are read record by record, the others' data
    // skipped (chunk::read_chunk_of); they must equal the topic's share of a full read.
    let bag = sim_bag();
    let all = all_messages(&bag);
    for (id, c) in &bag.connections {
        let got: Vec<(i64, Vec<u8>)> = bag
            .conn_messages([*id].into_iter().collect())
            .map(|m| {
                let m = m.unwrap();
                (m.time_ns, m.data)
            })
            .collect();
        let want: Vec<(i64, Vec<u8>)> = all
            .iter()
            .filter(|m| m.1 == c.topic)
            .map(|m| (m.0, m.2.clone()))
            .collect();
        assert!(!got.is_empty(), "{}", c.topic);
        assert_eq!(got, want, "{}", c.topic);
    }
}

#[test]
fn a_sparse_walk_reads_without_read_ahead_a_full_one_with() {
    // Uncompressed chunks where 100 kB "images" share chunks with 100-byte IMU records (the
    // bytes are not decoded: the read-ahead policy looks at the shares read). The IMU's walk
    // reads a small share of each chunk: read-ahead off; the images' walk and a walk over
    // everything keep it. Every walk still gets its messages.
    use write::{BagWriter, Compression};
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("sparse.bag");
    let mut w = BagWriter::create(&p, Compression::None).unwrap();
    let imu = w.add_connection("/imu", msgs::IMU_MSG);
    let cam = w.add_connection("/cam", msgs::IMAGE_MSG);
    for k in 0..200i64 {
        w.write(imu, 1_000_000 + k * 5_000_000, &[7; 100]).unwrap();
        if k % 10 == 0 {
            w.write(cam, 1_000_000 + k * 5_000_000, &vec![9; 100_000])
                .unwrap();
        }
    }
    w.finish().unwrap();
    let bag = Bag::open(&p).unwrap();
    assert!(bag.chunks.len() > 1, "{}", bag.chunks.len());
    let walk = |conns: HashSet<u32>, n: usize, random: bool| {
        let mut m = bag.conn_messages(conns);
        let got = m.by_ref().take(n).filter(|x| x.is_ok()).count();
        assert_eq!(got, n);
        assert_eq!(m.loader().is_random(), random);
        assert!(m.next().is_none());
    };
    walk(bag.topic_conns("/imu"), 200, true);
    walk(bag.topic_conns("/cam"), 20, false);
    walk(bag.connections.keys().copied().collect(), 220, false);
}

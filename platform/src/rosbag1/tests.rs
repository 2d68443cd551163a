//! Tests on the real bags of `../shared/data/fixtures` (recorded by ROS) and on cut and
//! unindexed copies of them made here.

use super::*;
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
    bag.messages(conns)
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
    let counts = topics::topics(&plain);
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
    let sel = topics::select(&bag, None, None).unwrap();
    assert_eq!(
        sel,
        topics::Selection {
            imu: None,
            camera: None
        }
    );
}

#[test]
#[ignore = "needs ../shared/data"]
fn ouster_bag_lists_its_packet_topics() {
    let bag = Bag::open(&fixture("ouster/512x10_raw.bag")).unwrap();
    let t = topics::topics(&bag);
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

//! Tests of the ROS 1 bag writer: our reader and, in an ignored test, the Python `rosbags`
//! package read back what it writes.

use super::super::msgs::{self, COMPRESSED_IMAGE_MSG, IMAGE_MSG, IMU_MSG, POINT_CLOUD2_MSG};
use super::super::Bag;
use super::*;
use crate::dataset::{ImageFrame, LidarScan};
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use povins_core::math::Vec3;
use std::collections::HashSet;

const T0: i64 = 1_700_000_000_123_456_789;

fn imu(k: i64) -> ImuSample {
    ImuSample {
        t_ns: T0 + k * 5_000_000,
        gyro_rps: Vec3::new(0.1 * k as f64, 1.0 / 3.0, -2e-300),
        accel_mps2: Vec3::new(-0.0, 9.81 + k as f64 * 1e-9, f64::MIN_POSITIVE),
    }
}

fn image(k: i64) -> ImageFrame {
    ImageFrame {
        t_ns: T0 + k * 50_000_000 + 1,
        width: 7,
        height: 5,
        mono8: (0..35).map(|i| (i * 7 + k * 3) as u8).collect(),
        path: None,
    }
}

fn sweep(k: i64) -> LidarScan {
    LidarScan {
        t_ns: T0 + k * 100_000_000,
        points: (0..4)
            .map(|i| LidarPoint {
                t_ns: T0 + k * 100_000_000 + i * 25_000,
                p_l: [1.0 / 3.0, i as f32, -2.5],
                intensity: 17.0,
            })
            .collect(),
    }
}

/// A bag of 200 IMU samples, 20 raw and 20 PNG images and 10 sweeps, written in time order.
fn write_bag(path: &Path, compression: Compression) {
    let mut w = BagWriter::create(path, compression).unwrap();
    w.chunk_threshold = 4096;
    let ci = w.add_connection("/camera/imu", IMU_MSG);
    let cr = w.add_connection("/camera/infra1/image_rect_raw", IMAGE_MSG);
    let cp = w.add_connection("/png", COMPRESSED_IMAGE_MSG);
    let cl = w.add_connection("/points", POINT_CLOUD2_MSG);
    let mut msgs: Vec<(i64, ConnId, Vec<u8>)> = Vec::new();
    for k in 0..200 {
        let s = imu(k);
        msgs.push((s.t_ns, ci, msgs::encode_imu(&s, k as u32, "imu").unwrap()));
    }
    for k in 0..20 {
        let im = image(k);
        let raw = msgs::encode_mono8(&im, k as u32, "cam").unwrap();
        msgs.push((im.t_ns, cr, raw));
        let png = msgs::encode_compressed_image(im.t_ns, 0, "cam", "png", &[k as u8; 9]);
        msgs.push((im.t_ns, cp, png.unwrap()));
    }
    for k in 0..10 {
        let s = sweep(k);
        let m = msgs::encode_point_cloud2(&s, k as u32, "lidar").unwrap();
        msgs.push((s.t_ns, cl, m));
    }
    msgs.sort_by_key(|m| m.0);
    for (t, c, d) in &msgs {
        w.write(*c, *t, d).unwrap();
    }
    assert_eq!(w.message_count(), 250);
    w.finish().unwrap();
}

fn topic_messages(bag: &Bag, topic: &str) -> Vec<(i64, Vec<u8>)> {
    bag.conn_messages(bag.topic_conns(topic))
        .map(|m| m.map(|m| (m.time_ns, m.data)).unwrap())
        .collect()
}

/// What our reader gets back from a bag written by [`write_bag`].
fn check_read_back(bag: &Bag) {
    let types: HashSet<(String, String, String)> = bag
        .connections
        .values()
        .map(|c| (c.topic.clone(), c.msg_type.clone(), c.md5sum.clone()))
        .collect();
    assert!(types.contains(&(
        "/camera/imu".into(),
        "sensor_msgs/Imu".into(),
        "6a62c6daae103f4ff57a132d6f95cec2".into()
    )));
    assert_eq!(types.len(), 4);
    let got: Vec<ImuSample> = topic_messages(bag, "/camera/imu")
        .iter()
        .map(|(t, d)| {
            let s = msgs::imu(d).unwrap();
            assert_eq!(*t, s.t_ns);
            s
        })
        .collect();
    let want: Vec<ImuSample> = (0..200).map(imu).collect();
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.t_ns, w.t_ns);
        for i in 0..3 {
            assert_eq!(g.gyro_rps[i].to_bits(), w.gyro_rps[i].to_bits());
            assert_eq!(g.accel_mps2[i].to_bits(), w.accel_mps2[i].to_bits());
        }
    }
    let images: Vec<ImageFrame> = topic_messages(bag, "/camera/infra1/image_rect_raw")
        .iter()
        .map(|(_, d)| msgs::image(d).unwrap())
        .collect();
    assert_eq!(images, (0..20).map(image).collect::<Vec<_>>());
    let png = topic_messages(bag, "/png");
    assert_eq!(png.len(), 20);
    assert_eq!(png[3].1[png[3].1.len() - 9..], [3u8; 9]);
    assert_eq!(topic_messages(bag, "/points").len(), 10);
}

#[test]
fn our_reader_reads_back_every_compression() {
    let dir = tempfile::tempdir().unwrap();
    for c in [Compression::None, Compression::Lz4, Compression::Bz2] {
        let p = dir.path().join(format!("{}.bag", c.name()));
        write_bag(&p, c);
        let bag = Bag::open(&p).unwrap();
        assert!(bag.indexed && bag.warnings.is_empty(), "{:?}", bag.warnings);
        assert!(bag.chunks.len() > 10, "{}", bag.chunks.len());
        check_read_back(&bag);
        // Without its index (as a killed recorder leaves it), the scan finds the same.
        let mut b = std::fs::read(&p).unwrap();
        let at = b.windows(10).position(|w| w == b"index_pos=").unwrap() + 10;
        b[at..at + 8].copy_from_slice(&0u64.to_le_bytes());
        let unindexed = dir.path().join("unindexed.bag");
        std::fs::write(&unindexed, &b).unwrap();
        let bag = Bag::open(&unindexed).unwrap();
        assert!(!bag.indexed);
        check_read_back(&bag);
    }
}

#[test]
fn compression_shrinks_the_chunks_and_the_header_is_4096_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let size = |c: Compression| {
        let p = dir.path().join(format!("{}.bag", c.name()));
        write_bag(&p, c);
        let b = std::fs::read(&p).unwrap();
        // Magic, then the bag header record padded to 4096 bytes, then the first chunk.
        let h = u32::from_le_bytes([b[13], b[14], b[15], b[16]]) as usize;
        let d = u32::from_le_bytes(b[17 + h..21 + h].try_into().unwrap()) as usize;
        assert_eq!(4 + h + 4 + d, BAG_HEADER_LEN);
        b.len()
    };
    let plain = size(Compression::None);
    assert!(size(Compression::Lz4) < plain);
    assert!(size(Compression::Bz2) < plain);
}

#[test]
fn point_cloud2_layout() {
    let s = sweep(2);
    let m = msgs::encode_point_cloud2(&s, 9, "os").unwrap();
    // header: seq, stamp, "os"; then height 1, width 4, 5 fields.
    let u32_at = |i: usize| u32::from_le_bytes(m[i..i + 4].try_into().unwrap());
    assert_eq!(
        (u32_at(0), u32_at(12), u32_at(18), u32_at(22)),
        (9, 2, 1, 4)
    );
    assert_eq!(u32_at(26), 5);
    // The last point: x y z intensity as f32, then t = 75 us after the stamp; is_dense.
    let p = &m[m.len() - 21..m.len() - 1];
    assert_eq!(f32::from_le_bytes(p[4..8].try_into().unwrap()), 3.0);
    assert_eq!(u32::from_le_bytes(p[16..20].try_into().unwrap()), 75_000);
    assert_eq!(m[m.len() - 1], 1);
    let mut early = sweep(0);
    early.points[1].t_ns = early.t_ns - 1;
    let e = msgs::encode_point_cloud2(&early, 0, "os").unwrap_err();
    assert!(e.msg.contains("point 1"), "{e:?}");
}

#[test]
fn times_a_ros_1_time_cannot_hold_are_refused_with_the_topic() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.bag");
    let mut w = BagWriter::create(&p, Compression::None).unwrap();
    let c = w.add_connection("/imu", IMU_MSG);
    w.write(c, 0, b"x").unwrap();
    let e = w.write(c, -1, b"x").unwrap_err().to_string();
    assert!(e.contains("t.bag") && e.contains("/imu message 1"), "{e}");
    let e = w.write(c, 1 << 62, b"x").unwrap_err().to_string();
    assert!(e.contains("not a ROS 1 time"), "{e}");
    let mut s = imu(0);
    s.t_ns = -5;
    assert!(msgs::encode_imu(&s, 0, "imu").is_err());
}
/// The Python interpreter with `rosbags`: `POVINS_ROSBAGS_PYTHON`, else a venv in
/// `<repo>/target/pyenv-rosbags` made on first use by `scripts/pyenv.sh` (`python3 -m venv`,
/// `pip install rosbags`: needs PyPI; without it the test fails saying so).
fn rosbags_python() -> PathBuf {
    if let Some(p) = std::env::var_os("POVINS_ROSBAGS_PYTHON") {
        return p.into();
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = std::process::Command::new("bash")
        .arg(root.join("scripts/pyenv.sh"))
        .arg(root.join("target/pyenv-rosbags"))
        .arg("rosbags")
        .args(["rosbags==0.11.9"])
        .output()
        .unwrap_or_else(|e| panic!("scripts/pyenv.sh: could not start bash: {e}"));
    assert!(
        out.status.success(),
        "scripts/pyenv.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

#[test]
#[ignore = "needs python3 and PyPI (installs rosbags into target/pyenv-rosbags)"]
fn python_rosbags_reads_our_bags() {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/check_rosbag1.py");
    let dir = tempfile::tempdir().unwrap();
    for c in [Compression::None, Compression::Lz4, Compression::Bz2] {
        let p = dir.path().join(format!("{}.bag", c.name()));
        write_bag(&p, c);
        let out = std::process::Command::new(rosbags_python())
            .arg(&script)
            .arg(&p)
            .output()
            .expect("python runs");
        assert!(
            out.status.success(),
            "{}: {}",
            c.name(),
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["connections"].as_array().unwrap().len(), 4);
        let m = &v["messages"];
        let imu_got = m["/camera/imu"].as_array().unwrap();
        assert_eq!(imu_got.len(), 200);
        for (k, g) in imu_got.iter().enumerate() {
            let s = imu(k as i64);
            assert_eq!(g["t"].as_i64(), Some(s.t_ns));
            assert_eq!(g["stamp"].as_i64(), Some(s.t_ns));
            assert_eq!(g["seq"].as_u64(), Some(k as u64));
            let hex = |v: f64| serde_json::Value::from(v.to_bits());
            for i in 0..3 {
                assert_eq!(g["gyro"][i], hex(s.gyro_rps[i]), "{k}");
                assert_eq!(g["accel"][i], hex(s.accel_mps2[i]), "{k}");
            }
            assert_eq!(g["ocov0"], hex(-1.0));
            assert_eq!(g["orientation"][3], hex(1.0));
        }
        let raw = m["/camera/infra1/image_rect_raw"].as_array().unwrap();
        assert_eq!(raw.len(), 20);
        for (k, g) in raw.iter().enumerate() {
            let im = image(k as i64);
            assert_eq!(g["stamp"].as_i64(), Some(im.t_ns));
            assert_eq!(
                (g["width"].as_u64(), g["height"].as_u64()),
                (Some(7), Some(5))
            );
            assert_eq!(
                (g["encoding"].as_str(), g["step"].as_u64()),
                (Some("mono8"), Some(7))
            );
            let data: String = im.mono8.iter().map(|b| format!("{b:02x}")).collect();
            assert_eq!(g["data"].as_str(), Some(data.as_str()));
        }
        let png = m["/png"].as_array().unwrap();
        assert_eq!(png[4]["format"].as_str(), Some("png"));
        assert_eq!(png[4]["data"].as_str(), Some("040404040404040404"));
        let pts = m["/points"].as_array().unwrap();
        assert_eq!(pts.len(), 10);
        let s = sweep(3);
        assert_eq!(pts[3]["stamp"].as_i64(), Some(s.t_ns));
        let fields = pts[3]["fields"].to_string();
        assert_eq!(
            fields,
            r#"[["x",0,7,1],["y",4,7,1],["z",8,7,1],["intensity",12,7,1],["t",16,6,1]]"#
        );
        for (i, p) in s.points.iter().enumerate() {
            let g = &pts[3]["points"][i];
            for j in 0..3 {
                assert_eq!(g[j], serde_json::Value::from(f64::from(p.p_l[j]).to_bits()));
            }
            assert_eq!(
                g[3],
                serde_json::Value::from(f64::from(p.intensity).to_bits())
            );
            assert_eq!(g[4].as_i64(), Some(p.t_ns - s.t_ns));
        }
    }
}

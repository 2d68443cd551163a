//! MCAP round trips, the message layout other tools see, and corrupt files.

mod common;

use common::{assert_same, shared, synthetic};
use povins_platform::cdr::CdrReader;
use povins_platform::mcap_io::{self, read_dataset, write_dataset};
use povins_platform::ros2::msgs;
use povins_platform::{euroc, IoError};
use std::collections::BTreeMap;

#[test]
fn synthetic_dataset_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("syn.mcap");
    let ds = synthetic("syn-name");
    write_dataset(&path, &ds).unwrap();
    let back = read_dataset(&path).unwrap();
    // Quaternions travel as their four doubles, so they come back bit-exact; the velocity is
    // rotated into the body frame (ROS twist convention) and back.
    assert_same(&ds, &back, 0.0, 1e-14);
    for (a, b) in ds.ground_truth.iter().zip(&back.ground_truth) {
        assert_eq!(a.q_wb, b.q_wb);
    }
    assert_eq!(ds.calib, back.calib);
    // A rolling shutter's readout travels in the calibration record.
    let mut rs = synthetic("rs");
    rs.calib.camera.readout_s = 0.025;
    let rs_path = dir.path().join("rs.mcap");
    write_dataset(&rs_path, &rs).unwrap();
    assert_eq!(read_dataset(&rs_path).unwrap().calib, rs.calib);
    // So does the LiDAR's time offset (`td_l_s`, the synthetic dataset's -4.2 ms, compared
    // above); one out of range is an error naming the key.
    let mut far = synthetic("far");
    far.calib.td_l_s = 5.0;
    let far_path = dir.path().join("far.mcap");
    write_dataset(&far_path, &far).unwrap();
    let e = read_dataset(&far_path).unwrap_err().to_string();
    assert!(e.contains("td_l_s") && e.contains("outside"), "{e}");
}

/// Raw messages per topic, with their schema name and encoding.
fn raw_topics(path: &std::path::Path) -> BTreeMap<String, (String, String, Vec<Vec<u8>>)> {
    let bytes = std::fs::read(path).unwrap();
    let mut out: BTreeMap<String, (String, String, Vec<Vec<u8>>)> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        // Every topic but the simulator's truth (JSON, schemaless) has a ROS 2 schema.
        let name = match m.channel.schema.as_ref() {
            Some(schema) => {
                assert_eq!(schema.encoding, "ros2msg");
                schema.name.clone()
            }
            None => {
                assert_eq!(
                    (
                        m.channel.topic.as_str(),
                        m.channel.message_encoding.as_str()
                    ),
                    (povins_platform::mcap_io::TOPIC_SIM_TRUTH, "json")
                );
                String::new()
            }
        };
        let e = out
            .entry(m.channel.topic.clone())
            .or_insert_with(|| (name, m.channel.message_encoding.clone(), Vec::new()));
        e.2.push(m.data.into_owned());
    }
    out
}

#[test]
fn messages_follow_the_documented_ros_conventions() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("syn.mcap");
    let ds = synthetic("syn");
    write_dataset(&path, &ds).unwrap();
    let topics = raw_topics(&path);
    let names: Vec<(&str, &str, usize)> = topics
        .iter()
        .map(|(t, (s, e, m))| {
            assert_eq!(e, if s.is_empty() { "json" } else { "cdr" });
            (t.as_str(), s.as_str(), m.len())
        })
        .collect();
    let truth_stamps = common::sim_truth_stamps(&ds);
    assert_eq!(
        names,
        vec![
            ("/cam0/features", "sensor_msgs/msg/PointCloud", 5),
            ("/cam0/image_raw", "sensor_msgs/msg/Image", 3),
            ("/groundtruth", "nav_msgs/msg/Odometry", 10),
            ("/groundtruth/imu_bias", "sensor_msgs/msg/Imu", 10),
            ("/imu0", "sensor_msgs/msg/Imu", 100),
            ("/lidar0/points", "sensor_msgs/msg/PointCloud2", 2),
            ("/povins/sim_truth/landmarks", "", truth_stamps.len()),
        ]
    );
    // Features: normalized undistorted points that project back to the raw pixels in u/v.
    let pc = msgs::PointCloud::decode(&topics["/cam0/features"].2[1]).unwrap();
    assert_eq!(pc.header.frame_id, "cam0");
    let names: Vec<&str> = pc.channels.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "id_of_point",
            "u_of_point",
            "v_of_point",
            "velocity_x_of_point",
            "velocity_y_of_point"
        ]
    );
    let obs = &ds.features[1].obs;
    for (k, o) in obs.iter().enumerate() {
        let p = pc.points[k];
        assert_eq!(p[2], 1.0);
        let px = ds
            .calib
            .camera
            .distort(&povins_core::camera::Vec2::new(p[0] as f64, p[1] as f64));
        let (u, v) = (px.x, px.y);
        // float32 normalized coordinates: ~1e-7 * 460 px.
        assert!(
            (u - o.u_px).abs() < 1e-3 && (v - o.v_px).abs() < 1e-3,
            "{u} {v} {o:?}"
        );
        assert_eq!(pc.channels[0].values[k], o.id as f32);
        assert_eq!(pc.channels[1].values[k], o.u_px as f32);
    }
    // Velocities: tracks seen in frame 0 move; new ones are zero.
    let prev_ids: Vec<u64> = ds.features[0].obs.iter().map(|o| o.id).collect();
    for (k, o) in obs.iter().enumerate() {
        let moving = pc.channels[3].values[k] != 0.0 || pc.channels[4].values[k] != 0.0;
        assert_eq!(moving, prev_ids.contains(&o.id), "id {}", o.id);
    }
    // Odometry: world/body frames, twist in the body frame.
    let od = msgs::Odometry::decode(&topics["/groundtruth"].2[3]).unwrap();
    let gt = &ds.ground_truth[3];
    assert_eq!(
        (od.header.frame_id.as_str(), od.child_frame_id.as_str()),
        ("world", "body")
    );
    assert_eq!(od.header.t_ns, gt.t_ns);
    let v_b = gt.q_wb.inverse() * gt.v_wb;
    assert_eq!(od.linear, [v_b.x, v_b.y, v_b.z]);
    assert_eq!(od.orientation, [gt.q_wb.i, gt.q_wb.j, gt.q_wb.k, gt.q_wb.w]);
    let bias = msgs::Imu::decode(&topics["/groundtruth/imu_bias"].2[3]).unwrap();
    assert_eq!(bias.angular_velocity, [gt.bg.x, gt.bg.y, gt.bg.z]);
    // IMU: no orientation by REP 145.
    let imu = msgs::Imu::decode(&topics["/imu0"].2[0]).unwrap();
    assert_eq!(imu.orientation_covariance[0], -1.0);
    assert_eq!(imu.linear_acceleration[2], ds.imu[0].accel_mps2.z);
    // LiDAR: the documented 20-byte layout with uint32 ns offsets.
    let pc2 = msgs::PointCloud2::decode(&topics["/lidar0/points"].2[1]).unwrap();
    assert_eq!((pc2.point_step, pc2.width, pc2.height), (20, 50, 1));
    let t3 = u32::from_le_bytes(pc2.data[3 * 20 + 16..3 * 20 + 20].try_into().unwrap());
    assert_eq!(t3, 3 * 1_999_999);
    // Image.
    let im = msgs::Image::decode(&topics["/cam0/image_raw"].2[2]).unwrap();
    assert_eq!(
        (im.encoding.as_str(), im.step, im.data.len()),
        ("mono8", 16, 192)
    );
    assert_eq!(im.data, ds.images[2].mono8);
    // Every CDR message starts with the little-endian CDR header.
    for (_, _, ms) in topics.values().filter(|t| t.1 == "cdr") {
        for m in ms {
            assert!(CdrReader::new(m).is_ok());
        }
    }
}

#[test]
#[ignore = "needs ../shared/data/euroc-v101-images-at-rest (large shared sequence; CI runs it with --ignored)"]
fn real_euroc_sequences_convert_to_mcap_and_back() {
    let ds = euroc::read_dataset(&shared("euroc-v101-30s-features")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v101.mcap");
    write_dataset(&path, &ds).unwrap();
    let back = read_dataset(&path).unwrap();
    assert_eq!(back.name, ds.name);
    assert_eq!(back.imu, ds.imu);
    assert_eq!(back.calib, ds.calib);
    assert_eq!(back.features.len(), 601);
    for (a, b) in ds.features.iter().zip(&back.features) {
        assert_eq!(a.t_ns, b.t_ns);
        for (x, y) in a.obs.iter().zip(&b.obs) {
            assert_eq!(x.id, y.id);
            assert_eq!(y.u_px, x.u_px as f32 as f64);
            assert_eq!(y.v_px, x.v_px as f32 as f64);
        }
    }
    assert_eq!(back.ground_truth.len(), 603);

    // Images referenced by path are loaded from their PNGs while writing.
    let mut ds = euroc::read_dataset(&shared("euroc-v101-images-at-rest")).unwrap();
    ds.imu.truncate(400);
    ds.ground_truth.truncate(40);
    ds.images.truncate(3);
    let path = dir.path().join("images.mcap");
    write_dataset(&path, &ds).unwrap();
    let back = read_dataset(&path).unwrap();
    euroc::read_images(&mut ds).unwrap();
    assert_eq!(back.images.len(), 3);
    for (a, b) in ds.images.iter().zip(&back.images) {
        assert_eq!((a.t_ns, a.width, a.height), (b.t_ns, b.width, b.height));
        assert!(a.mono8 == b.mono8);
    }
}

#[test]
fn corrupt_files_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("syn.mcap");
    let mut ds = synthetic("syn");
    ds.images.truncate(1);
    write_dataset(&path, &ds).unwrap();
    let good = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.mcap");
    let mut errors = 0;
    // Truncations at many points, then single-byte flips; the reader may still succeed when the
    // damage hits padding or a float, but must never panic.
    let step = (good.len() / 300).max(1);
    for cut in (0..good.len()).step_by(step) {
        std::fs::write(&bad, &good[..cut]).unwrap();
        errors += usize::from(read_dataset(&bad).is_err());
    }
    let mut x: u64 = 0x2545_f491_4f6c_dd1d;
    for _ in 0..300 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let mut c = good.clone();
        c[(x as usize) % good.len()] ^= 1 << (x >> 60 & 7);
        std::fs::write(&bad, &c).unwrap();
        errors += usize::from(read_dataset(&bad).is_err());
    }
    assert!(errors > 250, "{errors}");
}

#[test]
fn a_truncated_message_names_topic_and_offset() {
    // Build a file by hand whose only IMU message is cut short.
    let dir = tempfile::tempdir().unwrap();
    let good_path = dir.path().join("good.mcap");
    let mut ds = synthetic("syn");
    ds.imu.truncate(1);
    write_dataset(&good_path, &ds).unwrap();
    let bytes = std::fs::read(&good_path).unwrap();
    let path = dir.path().join("cut.mcap");
    let mut w = mcap::Writer::new(std::io::BufWriter::new(
        std::fs::File::create(&path).unwrap(),
    ))
    .unwrap();
    let mut meta = None;
    for rec in mcap::read::ChunkFlattener::new(&bytes).unwrap() {
        if let mcap::records::Record::Metadata(m) = rec.unwrap() {
            meta = Some(m);
        }
    }
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let mut m = m.unwrap();
        if m.channel.topic == "/imu0" {
            m.data = std::borrow::Cow::Owned(m.data[..100].to_vec());
        }
        w.write(&m).unwrap();
    }
    w.write_metadata(&meta.unwrap()).unwrap();
    w.finish().unwrap();
    drop(w);
    match read_dataset(&path) {
        Err(IoError::Corrupt {
            what, offset, msg, ..
        }) => {
            assert_eq!(what, "/imu0 message 1");
            assert_eq!(offset, 100, "{msg}");
            assert!(msg.contains("truncated"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn unwritable_values_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.mcap");
    let mut ds = synthetic("syn");
    ds.features[0].obs[0].id = 1 << 24;
    assert!(matches!(
        write_dataset(&path, &ds),
        Err(IoError::Invalid { .. })
    ));
    let mut ds = synthetic("syn");
    ds.lidar[0].points[0].t_ns = ds.lidar[0].t_ns - 1;
    assert!(matches!(
        write_dataset(&path, &ds),
        Err(IoError::Invalid { .. })
    ));
    let mut ds = synthetic("syn");
    ds.images[0].mono8.pop();
    assert!(matches!(
        write_dataset(&path, &ds),
        Err(IoError::Invalid { .. })
    ));
    // No calibration record: not a povins file.
    let mut w = mcap::Writer::new(std::io::BufWriter::new(
        std::fs::File::create(&path).unwrap(),
    ))
    .unwrap();
    w.finish().unwrap();
    drop(w);
    match read_dataset(&path) {
        Err(IoError::Invalid { msg, .. }) => assert!(msg.contains(mcap_io::CALIBRATION_METADATA)),
        other => panic!("{other:?}"),
    }
}

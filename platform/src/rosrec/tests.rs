//! The recording layer's rules on a message log in memory: stamps checked, zero stamps
//! replaced, corrupt parts skipped, a mostly-out-of-order topic refused.

use super::recording::RosRecording;
use super::*;
use crate::recording::Recording;
use std::path::PathBuf;

/// A log of one IMU topic: `Ok((log_time, stamp))` messages and `Err(offset)` corrupt parts.
#[derive(Debug)]
struct MemLog {
    path: PathBuf,
    items: Vec<Result<(i64, i64), u64>>,
}

/// A ROS 1 `sensor_msgs/Imu` with `stamp_ns` and gyro x = `stamp_ns` in ms.
fn imu_msg(stamp_ns: i64) -> Vec<u8> {
    let mut b = 0u32.to_le_bytes().to_vec();
    b.extend(((stamp_ns / 1_000_000_000) as u32).to_le_bytes());
    b.extend(((stamp_ns % 1_000_000_000) as u32).to_le_bytes());
    b.extend(3u32.to_le_bytes());
    b.extend(b"imu");
    let mut vals = [0.0f64; 37];
    vals[13] = stamp_ns as f64 * 1e-6;
    vals[27] = 9.81;
    for v in vals {
        b.extend(v.to_le_bytes());
    }
    b
}

impl MessageLog for MemLog {
    fn path(&self) -> &Path {
        &self.path
    }
    fn describe(&self) -> String {
        "memory".into()
    }
    fn topics(&self) -> Vec<TopicInfo> {
        vec![TopicInfo {
            topic: "/imu".into(),
            msg_type: "sensor_msgs/Imu".into(),
            encoding: Encoding::Ros1,
            count: self.items.len() as u64,
            span_ns: None,
        }]
    }
    fn messages(&self, _topic: &str) -> LogStream<'_> {
        let path = self.path.clone();
        Box::new(self.items.clone().into_iter().map(move |it| match it {
            Ok((log, stamp)) => Ok(LogMessage {
                log_time_ns: log,
                offset: 100,
                data: imu_msg(stamp),
            }),
            Err(offset) => Err(IoError::Corrupt {
                file: path.clone(),
                what: "chunk".into(),
                offset,
                msg: "bad CRC".into(),
            }),
        }))
    }
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
}

fn calib() -> crate::dataset::Calibration {
    use crate::dataset::{Calibration, Extrinsic};
    use povins_core::{camera::PinholeCamera, inertial::ImuNoise};
    Calibration {
        camera: PinholeCamera::EUROC_CAM0,
        t_bc: Extrinsic::identity(),
        td_s: 0.0,
        camera_rate_hz: 20.0,
        imu_noise: ImuNoise {
            gyro_noise_density: 1e-4,
            accel_noise_density: 1e-3,
            gyro_bias_rw: 1e-5,
            accel_bias_rw: 1e-4,
            bias_corr_time_s: None,
        },
        imu_rate_hz: 200.0,
        gravity_mps2: 9.81,
        t_bl: None,
        td_l_s: 0.0,
    }
}

fn recording(items: Vec<Result<(i64, i64), u64>>) -> RosRecording {
    let log = MemLog {
        path: "mem.bag".into(),
        items,
    };
    RosRecording::new(Box::new(log), calib(), &Default::default()).unwrap()
}

#[test]
fn duplicated_and_backward_stamps_are_dropped_and_counted() {
    let ms = 1_000_000;
    let stamps = [10, 15, 15, 20, 12, 25, 30];
    let rec = recording(stamps.iter().map(|&t| Ok((t * ms, t * ms))).collect());
    let got: Vec<i64> = rec.imu().unwrap().map(|s| s.unwrap().t_ns / ms).collect();
    assert_eq!(got, [10, 15, 20, 25, 30]);
    let w = rec.warnings().join("\n");
    assert!(
        w.contains("/imu: 2 of 7 samples dropped (1 duplicated and 1 backward stamps)"),
        "{w}"
    );
}

#[test]
fn zero_stamps_take_the_log_time_with_one_warning() {
    let rec = recording(vec![Ok((5, 0)), Ok((6, 0)), Ok((7, 8))]);
    let got: Vec<i64> = rec.imu().unwrap().map(|s| s.unwrap().t_ns).collect();
    assert_eq!(got, [5, 6, 8]);
    let w = rec.warnings();
    assert_eq!(
        w.iter().filter(|w| w.contains("stamp is zero")).count(),
        1,
        "{w:?}"
    );
}

#[test]
fn corrupt_parts_are_skipped_with_their_offset() {
    let rec = recording(vec![Ok((1, 1)), Err(4096), Ok((3, 3))]);
    let got: Vec<i64> = rec.imu().unwrap().map(|s| s.unwrap().t_ns).collect();
    assert_eq!(got, [1, 3]);
    let w = rec.warnings().join("\n");
    assert!(
        w.contains("chunk at byte offset 4096 skipped: bad CRC") && w.contains("1 unreadable"),
        "{w}"
    );
}

#[test]
fn a_mostly_backward_topic_is_refused() {
    let items = (0..40).map(|k| Ok((k, 1_000 - k))).collect();
    let rec = recording(items);
    let r: Result<Vec<_>, _> = rec.imu().unwrap().collect();
    let e = r.unwrap_err().to_string();
    assert!(
        e.contains("mostly out of order") && e.contains("mem.bag"),
        "{e}"
    );
}

#[test]
fn a_message_that_does_not_decode_names_topic_index_and_offsets() {
    #[derive(Debug)]
    struct Bad(MemLog);
    impl MessageLog for Bad {
        fn path(&self) -> &Path {
            self.0.path()
        }
        fn describe(&self) -> String {
            self.0.describe()
        }
        fn topics(&self) -> Vec<TopicInfo> {
            self.0.topics()
        }
        fn messages(&self, t: &str) -> LogStream<'_> {
            Box::new(self.0.messages(t).map(|m| {
                m.map(|mut m| {
                    if m.log_time_ns == 2 {
                        m.data.truncate(40);
                    }
                    m
                })
            }))
        }
        fn warnings(&self) -> Vec<String> {
            Vec::new()
        }
    }
    let log = Bad(MemLog {
        path: "mem.bag".into(),
        items: vec![Ok((1, 1)), Ok((2, 2))],
    });
    let rec = RosRecording::new(Box::new(log), calib(), &Default::default()).unwrap();
    let r: Result<Vec<_>, _> = rec.imu().unwrap().collect();
    let e = r.unwrap_err().to_string();
    assert!(
        e.contains("mem.bag") && e.contains("/imu message 1") && e.contains("byte offset 100"),
        "{e}"
    );
}

#[test]
fn ros2_type_names_become_ros1_names() {
    assert_eq!(normalize_type("sensor_msgs/msg/Imu"), "sensor_msgs/Imu");
    assert_eq!(normalize_type("sensor_msgs/Imu"), "sensor_msgs/Imu");
    assert_eq!(normalize_type("a/msg/b/c"), "a/msg/b/c");
}

/// A RealSense-like log: gyro and accelerometer apart, the accelerometer in `accel_z` units.
#[derive(Debug)]
struct PairLog {
    path: PathBuf,
    accel_z: f64,
}

/// A ROS 1 `sensor_msgs/Imu` with the given gyro x and accel z.
fn imu_msg_with(stamp_ns: i64, gyro_x: f64, accel_z: f64) -> Vec<u8> {
    let mut b = imu_msg(stamp_ns);
    let at = b.len() - 37 * 8;
    b[at + 13 * 8..at + 14 * 8].copy_from_slice(&gyro_x.to_le_bytes());
    b[at + 27 * 8..at + 28 * 8].copy_from_slice(&accel_z.to_le_bytes());
    b
}

impl MessageLog for PairLog {
    fn path(&self) -> &Path {
        &self.path
    }
    fn describe(&self) -> String {
        "memory".into()
    }
    fn topics(&self) -> Vec<TopicInfo> {
        let t = |name: &str, n| TopicInfo {
            topic: name.into(),
            msg_type: "sensor_msgs/Imu".into(),
            encoding: Encoding::Ros1,
            count: n,
            span_ns: None,
        };
        vec![t("/camera/accel/sample", 30), t("/camera/gyro/sample", 60)]
    }
    fn messages(&self, topic: &str) -> LogStream<'_> {
        let ms = 1_000_000;
        let msgs: Vec<_> = if topic.contains("gyro") {
            (0..60)
                .map(|k| imu_msg_with(k * 5 * ms, k as f64, 0.0))
                .collect()
        } else {
            // z rises by one unit per 10 ms from `accel_z`.
            (0..30)
                .map(|k| imu_msg_with(k * 10 * ms, 0.0, self.accel_z + k as f64 * 1e-3))
                .collect()
        };
        Box::new(msgs.into_iter().map(|data| {
            let t = crate::rosbag1::msgs::imu(&data).unwrap().t_ns;
            Ok(LogMessage {
                log_time_ns: t,
                offset: 0,
                data,
            })
        }))
    }
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
}

#[test]
fn a_realsense_pair_is_found_merged_and_its_unit_told() {
    for (accel_z, scale) in [(9.81, 1.0), (1.0, merge::STANDARD_GRAVITY_MPS2)] {
        let log = PairLog {
            path: "rs.bag".into(),
            accel_z,
        };
        let rec = RosRecording::new(Box::new(log), calib(), &Default::default()).unwrap();
        assert_eq!(rec.imu_topic().topic, "/camera/gyro/sample");
        assert_eq!(rec.accel_topic().unwrap().topic, "/camera/accel/sample");
        let got: Vec<_> = rec.imu().unwrap().map(Result::unwrap).collect();
        // Gyro at 0..295 ms; accel at 0..290 ms: the last gyro sample (295 ms) is dropped.
        assert_eq!(got.len(), 59);
        let s = got[3]; // 15 ms: halfway between accel samples 1 and 2.
        assert_eq!(s.gyro_rps.x, 3.0);
        let want = (accel_z + 1.5e-3) * scale;
        assert!(
            (s.accel_mps2.z - want).abs() < 1e-12,
            "{} vs {want}",
            s.accel_mps2.z
        );
        let w = rec.warnings().join("\n");
        assert!(w.contains("1 gyro samples outside"), "{w}");
    }
}

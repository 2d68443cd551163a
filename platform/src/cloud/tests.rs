use super::livox::{self, CustomMsg};
use super::*;
use crate::ros2::msgs::PointCloud2;
use crate::rosbag1::msgs as ros1_msgs;
use povins_core::lidar::LidarPoint;

/// A sweep of `n` points over 0.1 s after `t0_ns`, at 1-40 m in every direction.
fn sweep(t0_ns: i64, n: usize) -> LidarScan {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let points = (0..n)
        .map(|k| {
            let (az, el, r) = (
                rnd() * std::f64::consts::TAU,
                rnd() - 0.5,
                1.0 + 39.0 * rnd(),
            );
            LidarPoint {
                t_ns: t0_ns + (k as i64 * 100_000_000) / n as i64 + (rnd() * 999.0) as i64,
                p_l: [
                    (r * el.cos() * az.cos()) as f32,
                    (r * el.cos() * az.sin()) as f32,
                    (r * el.sin()) as f32,
                ],
                intensity: (rnd() * 200.0).round() as f32,
            }
        })
        .collect();
    LidarScan {
        t_ns: t0_ns,
        points,
    }
}

fn cloud(layout: Layout, s: &LidarScan) -> PointCloud2 {
    crate::ros2::convert::lidar_to_msg_in(layout, s, "lidar").unwrap()
}

fn assert_same(layout: &str, a: &LidarScan, b: &LidarScan) {
    assert_eq!(a.t_ns, b.t_ns, "{layout}: stamp");
    assert_eq!(a.points.len(), b.points.len(), "{layout}: points");
    for (k, (p, q)) in a.points.iter().zip(&b.points).enumerate() {
        for i in 0..3 {
            assert!(
                (p.p_l[i] - q.p_l[i]).abs() <= 1e-4,
                "{layout}: point {k} {:?} {:?}",
                p.p_l,
                q.p_l
            );
        }
        assert!(
            (p.t_ns - q.t_ns).abs() <= 1_000,
            "{layout}: point {k} time {} {}",
            p.t_ns,
            q.t_ns
        );
    }
}

/// Stamps like a recording's (2024) and like the simulator's (1 s after the epoch).
const STAMPS: [i64; 2] = [1_718_000_000_123_456_789, 1_000_000_000];

#[test]
fn every_layout_gives_the_same_points_and_times_in_both_encodings() {
    for t0 in STAMPS {
        let s = sweep(t0, 2000);
        for layout in Layout::ALL {
            let m = cloud(layout, &s);
            assert_eq!(m.point_step, layout.point_step());
            let d = decode_point_cloud2(&m, &CloudOptions::default()).unwrap();
            assert_eq!(
                d.time,
                TimeSource::Field {
                    spec: layout.time(),
                    expected: true
                },
                "{} at {t0}",
                layout.name()
            );
            assert_eq!(d.counts.dropped(), 0);
            assert_same(layout.name(), &s, &d.scan);
            // Both encodings carry the same cloud.
            let cdr = m.encode().unwrap();
            let back = PointCloud2::decode(&cdr).unwrap();
            assert_eq!(back, m);
            let ros1 =
                crate::rosbag1::msgs::encode_point_cloud2_in(layout, &s, 3, "lidar").unwrap();
            let back = crate::rosbag1::msgs::point_cloud2(&ros1).unwrap();
            assert_eq!(
                back,
                PointCloud2 {
                    is_dense: true,
                    ..m.clone()
                }
            );
            // A forced layout reads it the same.
            let forced = CloudOptions {
                layout: Some(layout),
                ..CloudOptions::default()
            };
            assert_eq!(decode_point_cloud2(&m, &forced).unwrap().scan, d.scan);
        }
        // Integer times are exact.
        let d = decode_point_cloud2(&cloud(Layout::Ouster, &s), &CloudOptions::default()).unwrap();
        assert_eq!(d.scan, s);
    }
}

#[test]
fn both_livox_custom_messages_give_the_same_points_and_times() {
    for t0 in STAMPS {
        let s = sweep(t0, 500);
        let m = CustomMsg::from_scan(&s, "livox_frame").unwrap();
        let ros1 = ros1_msgs::livox_custom_msg(&ros1_msgs::encode_livox_custom_msg(&m, 4).unwrap())
            .unwrap();
        let cdr = CustomMsg::decode_cdr(&m.encode_cdr().unwrap()).unwrap();
        assert_eq!(ros1, m);
        assert_eq!(cdr, m);
        let d = m.decode().unwrap();
        assert_eq!(d.counts.dropped(), 0);
        // Stamped with the first point's time; every point exact.
        let first = s.points.iter().map(|p| p.t_ns).min().unwrap();
        assert_eq!(d.scan.t_ns, first);
        assert_eq!(d.scan.points.len(), s.points.len());
        for (p, q) in s.points.iter().zip(&d.scan.points) {
            assert_eq!((p.t_ns, p.p_l), (q.t_ns, q.p_l));
        }
    }
}

#[test]
fn livox_noise_flags() {
    assert!(!livox::is_noise(0));
    assert!(!livox::is_noise(0b0001_0000)); // return 1
    assert!(!livox::is_noise(0b0000_0011)); // low-confidence spatial noise is kept
    assert!(livox::is_noise(0b0000_0001));
    assert!(livox::is_noise(0b0000_0010));
    assert!(livox::is_noise(0b0000_0100));
    assert!(livox::is_noise(0b0100_0000));
}

#[test]
fn bad_points_are_dropped_and_counted() {
    let mut s = sweep(STAMPS[0], 10);
    s.points[1].p_l[0] = f32::NAN;
    s.points[2].p_l = [0.0; 3];
    s.points[3].t_ns = s.t_ns + 2_000_000_000;
    let d = decode_point_cloud2(&cloud(Layout::Hesai, &s), &CloudOptions::default()).unwrap();
    let c = d.counts;
    assert_eq!(
        (c.points, c.non_finite, c.no_return, c.out_of_sweep),
        (10, 1, 1, 1)
    );
    assert_eq!(d.scan.points.len(), 7);
    assert!(
        c.describe().starts_with("3 of 10 points dropped"),
        "{}",
        c.describe()
    );
    // Livox tags, in the PointCloud2 and in the CustomMsg.
    let s = sweep(STAMPS[0], 4);
    let mut m = cloud(Layout::Livox2, &s);
    m.data[26 + 16] = 0b01;
    let d = decode_point_cloud2(&m, &CloudOptions::default()).unwrap();
    assert_eq!((d.counts.flagged_noise, d.scan.points.len()), (1, 3));
    let mut m = CustomMsg::from_scan(&s, "l").unwrap();
    m.points[0].tag = 0b10;
    m.points[1].p_l[2] = f32::INFINITY;
    let d = m.decode().unwrap();
    assert_eq!((d.counts.flagged_noise, d.counts.non_finite), (1, 1));
}

#[test]
fn a_time_field_holding_an_unexpected_unit_is_found_and_said() {
    // `timestamp` float64 holding seconds after the stamp instead of since the epoch.
    let s = sweep(STAMPS[0], 50);
    let mut m = cloud(Layout::Hesai, &s);
    for (k, p) in s.points.iter().enumerate() {
        let o = k * 48 + 24;
        m.data[o..o + 8].copy_from_slice(&(((p.t_ns - s.t_ns) as f64) * 1e-9).to_le_bytes());
    }
    let d = decode_point_cloud2(&m, &CloudOptions::default()).unwrap();
    let TimeSource::Field { spec, expected } = d.time else {
        panic!("{:?}", d.time)
    };
    assert!(!expected);
    assert_eq!((spec.unit, spec.reference), (TimeUnit::S, TimeRef::Header));
    assert_same("hesai relative", &s, &d.scan);
    // Values no reading fits: an error naming the field.
    for (k, _) in s.points.iter().enumerate() {
        let o = k * 48 + 24;
        m.data[o..o + 8].copy_from_slice(&5e11f64.to_le_bytes());
    }
    let e = decode_point_cloud2(&m, &CloudOptions::default()).unwrap_err();
    assert!(
        e.contains("\"timestamp\"") && e.contains("500000000000"),
        "{e}"
    );
}

#[test]
fn a_cloud_without_time_is_read_under_the_stated_assumption() {
    let s = sweep(STAMPS[0], 100);
    let mut m = cloud(Layout::Compact, &s);
    m.fields.retain(|f| f.name != "t");
    let d = decode_point_cloud2(&m, &CloudOptions::default()).unwrap();
    assert_eq!(d.time, TimeSource::Assumed(NoTime::Stamp));
    assert!(d.scan.points.iter().all(|p| p.t_ns == s.t_ns));
    let spin = NoTime::Spin {
        period_ns: 100_000_000,
        clockwise: false,
        stamp_is_end: true,
    };
    let opts = CloudOptions {
        no_time: spin,
        ..CloudOptions::default()
    };
    let d = decode_point_cloud2(&m, &opts).unwrap();
    assert!(d.time.to_string().contains("azimuth"), "{}", d.time);
    let p0 = &d.scan.points[0];
    assert_eq!(p0.t_ns, s.t_ns - 100_000_000);
    for p in &d.scan.points {
        assert!((s.t_ns - 100_000_000..=s.t_ns).contains(&p.t_ns));
        let az = f64::from(p.p_l[1]).atan2(f64::from(p.p_l[0]));
        let a0 = f64::from(p0.p_l[1]).atan2(f64::from(p0.p_l[0]));
        let frac = (az - a0).rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU;
        assert!(((p.t_ns - p0.t_ns) as f64 - frac * 1e8).abs() <= 1.0);
    }
}

#[test]
fn malformed_clouds_are_errors_never_panics() {
    let s = sweep(STAMPS[0], 8);
    let good = cloud(Layout::Velodyne, &s);
    let opts = CloudOptions::default();
    let err = |m: &PointCloud2| decode_point_cloud2(m, &opts).unwrap_err();
    let mut m = good.clone();
    m.fields.retain(|f| f.name != "y");
    assert!(err(&m).contains("\"y\" is missing"), "{}", err(&m));
    let mut m = good.clone();
    m.point_step = 20;
    m.row_step = 20 * 8;
    assert!(
        err(&m).contains("does not fit the point_step 20"),
        "{}",
        err(&m)
    );
    let mut m = good.clone();
    m.row_step = 10;
    assert!(err(&m).contains("exceeds row_step"), "{}", err(&m));
    let mut m = good.clone();
    m.data.truncate(100);
    assert!(err(&m).contains("exceed the 100 data bytes"), "{}", err(&m));
    let mut m = good.clone();
    m.fields[0].datatype = 9;
    assert!(err(&m).contains("unknown datatype 9"), "{}", err(&m));
    let mut m = good.clone();
    m.fields[0].datatype = datatype::UINT16;
    assert!(err(&m).contains("expected float32"), "{}", err(&m));
    let mut m = good.clone();
    m.is_bigendian = true;
    assert!(err(&m).contains("big-endian"), "{}", err(&m));
    let mut m = good.clone();
    m.width = u32::MAX;
    m.height = u32::MAX;
    assert!(decode_point_cloud2(&m, &opts).is_err());
    let forced = CloudOptions {
        layout: Some(Layout::Hesai),
        ..opts
    };
    let e = decode_point_cloud2(&good, &forced).unwrap_err();
    assert!(e.contains("layout hesai") && e.contains("timestamp"), "{e}");
    // Every cut of every encoding is an error.
    let ros1 = crate::rosbag1::msgs::encode_point_cloud2_in(Layout::Velodyne, &s, 0, "l").unwrap();
    for cut in 0..ros1.len() {
        assert!(crate::rosbag1::msgs::point_cloud2(&ros1[..cut]).is_err());
    }
    let m = CustomMsg::from_scan(&s, "l").unwrap();
    let (r1, cdr) = (
        ros1_msgs::encode_livox_custom_msg(&m, 0).unwrap(),
        m.encode_cdr().unwrap(),
    );
    for cut in 0..r1.len() {
        assert!(ros1_msgs::livox_custom_msg(&r1[..cut]).is_err());
    }
    for cut in 0..cdr.len() {
        assert!(CustomMsg::decode_cdr(&cdr[..cut]).is_err(), "cut {cut}");
    }
}

#[test]
fn epoch_seconds_keep_their_nanoseconds_within_float64() {
    for t in [0, 1, 999_999_999, 1_718_000_000_123_456_789, -5] {
        let back = f64_s_to_ns(ns_to_f64_s(t)).unwrap();
        assert!((back - t).abs() <= 250, "{t} {back}");
    }
    assert_eq!(f64_s_to_ns(f64::NAN), None);
    assert_eq!(f64_s_to_ns(1e300), None);
}

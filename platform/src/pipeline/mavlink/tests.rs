//! The sink over loopback UDP, decoded with the `mavlink` crate (the independent receiver is
//! Python's pymavlink, in host-tools' ignored test).

use super::*;
use ::mavlink::MavlinkReader;
use povins_core::estimator::KeyframeReport;
use povins_core::inertial::NavState;
use povins_core::math::{Quat, Vec3};
use std::net::UdpSocket;

/// The stamps' origin (an IMU clock of about 17 minutes since power-on).
const T0_NS: i64 = 1_000_000_000_000;

fn nav(t_ns: i64) -> NavState {
    let s = (t_ns - T0_NS) as f64 * 1e-9;
    NavState {
        t_ns,
        p_wb: Vec3::new(s, 2.0 * s, 0.5),
        q_wb: Quat::from_euler_angles(0.1, 0.0, s),
        v_wb: Vec3::new(1.0, 2.0, 0.0),
        bg: Vec3::zeros(),
        ba: Vec3::zeros(),
    }
}

fn pose(t_ns: i64) -> PoseOut {
    PoseOut {
        nav: nav(t_ns),
        latency_ns: 1000,
        stamp_latency_ns: Some(2000),
        covariance: None,
    }
}

/// A covariance with every block coupled (what the estimator hands the second half's poses).
fn covariance() -> povins_core::inertial::InsCovariance {
    let mut p = povins_core::inertial::Mat15::zeros();
    for i in 0..15 {
        for j in 0..15 {
            p[(i, j)] = if i == j { 1e-3 * (1 + i) as f64 } else { 1e-5 };
        }
    }
    let noise = povins_core::inertial::ImuNoise {
        gyro_noise_density: 1e-3,
        accel_noise_density: 1e-2,
        gyro_bias_rw: 1e-5,
        accel_bias_rw: 1e-4,
        bias_corr_time_s: None,
    };
    povins_core::inertial::InsCovariance::new(&p, noise).unwrap()
}

fn keyframe(decision: KeyframeDecision, used: u32) -> KeyframeOut {
    KeyframeOut {
        report: KeyframeReport {
            decision,
            landmarks_used: used,
            ..Default::default()
        },
        state: None,
    }
}

/// Every message `rx` receives until `n` ODOMETRY arrived (or a second passed), and those
/// arriving within 200 ms after.
fn receive(rx: &UdpSocket, n: usize) -> Vec<MavMessage> {
    rx.set_read_timeout(Some(Duration::from_millis(1000)))
        .unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; 2048];
    while out
        .iter()
        .filter(|m| matches!(m, MavMessage::ODOMETRY(_)))
        .count()
        < n
    {
        let Ok(len) = rx.recv(&mut buf) else { break };
        let mut r = MavlinkReader::new(&buf[..len]);
        while let Ok((_, m)) = r.read_any_message::<MavMessage>() {
            out.push(m);
        }
    }
    rx.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    while let Ok(len) = rx.recv(&mut buf) {
        let mut r = MavlinkReader::new(&buf[..len]);
        while let Ok((_, m)) = r.read_any_message::<MavMessage>() {
            out.push(m);
        }
    }
    out
}

/// Sends `n` 200 Hz poses from `T0_NS` through a sink with `opts` (a first keyframe, and a
/// re-initialization at pose `n / 2`, after which the poses carry [`covariance`]), and returns what `rx` received until `expect` ODOMETRY
/// arrived, and the sink (finished).
fn run_sink(
    rx: &UdpSocket,
    opts: MavlinkOptions,
    n: i64,
    expect: usize,
) -> (Vec<MavMessage>, MavlinkSink) {
    let mut sink = MavlinkSink::new(opts).unwrap();
    sink.keyframe(&keyframe(KeyframeDecision::First, 10));
    for i in 0..n {
        if i == n / 2 {
            sink.keyframe(&keyframe(KeyframeDecision::First, 80));
        }
        let mut p = pose(T0_NS + i * 5_000_000);
        if i >= n / 2 {
            p.covariance = Some(covariance());
        }
        sink.pose(&p);
    }
    let msgs = receive(rx, expect);
    sink.finish().unwrap();
    (msgs, sink)
}

/// The ODOMETRY messages of `msgs`.
fn odometry_of(msgs: &[MavMessage]) -> Vec<&ODOMETRY_DATA> {
    msgs.iter()
        .filter_map(|m| match m {
            MavMessage::ODOMETRY(o) => Some(o),
            _ => None,
        })
        .collect()
}

#[test]
fn odometry_at_the_rate_in_frd_with_resets_and_quality() {
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let t0 = T0_NS;
    // One second of 200 Hz poses; a re-initialization half way.
    let opts = MavlinkOptions::new(Endpoint::UdpOut(rx.local_addr().unwrap()));
    let (msgs, sink) = run_sink(&rx, opts, 200, 30);
    let odo = odometry_of(&msgs);
    assert!(
        msgs.iter().any(|m| matches!(m, MavMessage::HEARTBEAT(_))),
        "{} messages, {:?}",
        msgs.len(),
        sink.counts()
    );
    // 30 Hz over 1 s of stamps: a pose every 33.3 ms on a 5 ms grid.
    assert_eq!(odo.len(), 30, "{odo:?}");
    let c = sink.counts();
    assert_eq!((c.odometry_sent, c.resets, c.errors), (30, 1, 0));
    for o in &odo {
        let t_ns = o.time_usec as i64 * 1000;
        assert_eq!((t_ns - t0) % 5_000_000, 0);
        assert_eq!(o.frame_id, MavFrame::MAV_FRAME_LOCAL_FRD);
        assert_eq!(o.child_frame_id, MavFrame::MAV_FRAME_BODY_FRD);
        let q = Quat::from_quaternion(nalgebra::Quaternion::new(
            f64::from(o.q[0]),
            f64::from(o.q[1]),
            f64::from(o.q[2]),
            f64::from(o.q[3]),
        ));
        let f = FrdPose {
            p_l: Vec3::new(f64::from(o.x), f64::from(o.y), f64::from(o.z)),
            q_lv: q,
            v_v: Vec3::new(f64::from(o.vx), f64::from(o.vy), f64::from(o.vz)),
        };
        let (p, q, v) = from_frd(&f, &BodyAxes::default());
        let want = nav(t_ns);
        assert!((p - want.p_wb).norm() < 1e-5);
        assert!(q.angle_to(&want.q_wb) < 1e-6);
        assert!((v - want.v_wb).norm() < 1e-5);
        let second = t_ns >= t0 + 500_000_000;
        assert_eq!(o.reset_counter, u8::from(second));
        assert_eq!(o.quality, if second { 100 } else { 20 });
        if second {
            let c = covariance_to_frd(&want, &covariance(), &BodyAxes::default());
            assert_eq!(o.pose_covariance, c.pose);
            assert_eq!(o.velocity_covariance[..3], c.velocity[..3]);
            assert!(o.pose_covariance.iter().all(|v| v.is_finite()));
            assert!(o.velocity_covariance[3].is_nan());
        } else {
            assert!(o.pose_covariance[0].is_nan() && o.velocity_covariance[0].is_nan());
        }
    }
    let gaps: Vec<i64> = odo
        .windows(2)
        .map(|w| (w[1].time_usec - w[0].time_usec) as i64)
        .collect();
    assert!(
        gaps.iter().all(|g| (30_000..=35_000).contains(g)),
        "{gaps:?}"
    );
}

/// With `vision_position`, each ODOMETRY is followed by a VISION_POSITION_ESTIMATE of the same
/// stamp, position and attitude (roll, pitch, yaw of the same quaternion) and reset counter.
#[test]
fn vision_position_estimate_follows_each_odometry() {
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let opts = MavlinkOptions {
        vision_position: true,
        ..MavlinkOptions::new(Endpoint::UdpOut(rx.local_addr().unwrap()))
    };
    let (msgs, sink) = run_sink(&rx, opts, 100, 15);
    let odo = odometry_of(&msgs);
    let vis: Vec<&VISION_POSITION_ESTIMATE_DATA> = msgs
        .iter()
        .filter_map(|m| match m {
            MavMessage::VISION_POSITION_ESTIMATE(v) => Some(v),
            _ => None,
        })
        .collect();
    assert_eq!((odo.len(), vis.len()), (15, 15));
    assert_eq!(sink.counts().vision_position_sent, 15);
    for (o, v) in odo.iter().zip(&vis) {
        assert_eq!(o.time_usec, v.usec);
        assert_eq!((o.x, o.y, o.z), (v.x, v.y, v.z));
        assert_eq!(o.reset_counter, v.reset_counter);
        let q = Quat::from_quaternion(nalgebra::Quaternion::new(
            f64::from(o.q[0]),
            f64::from(o.q[1]),
            f64::from(o.q[2]),
            f64::from(o.q[3]),
        ));
        let e = Quat::from_euler_angles(f64::from(v.roll), f64::from(v.pitch), f64::from(v.yaw));
        assert!(q.angle_to(&e) < 1e-6, "{q:?} vs roll/pitch/yaw {e:?}");
        if v.reset_counter == 0 {
            assert!(v.covariance[0].is_nan());
        } else {
            assert_eq!(v.covariance, o.pose_covariance);
        }
    }
    assert!(vis.iter().any(|v| v.reset_counter == 1));
}

#[test]
fn timesync_requests_are_answered_on_the_sensor_clock() {
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut sink = MavlinkSink::new(MavlinkOptions::new(Endpoint::UdpOut(
        rx.local_addr().unwrap(),
    )))
    .unwrap();
    let Link::Udp { socket, .. } = &*sink.link else {
        panic!("not UDP")
    };
    let povins_addr = socket.local_addr().unwrap();
    let request = |ts1: i64| {
        let mut buf = Vec::new();
        let h = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let m = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1,
            target_system: 0,
            target_component: 0,
        });
        ::mavlink::write_v2_msg(&mut buf, h, &m).unwrap();
        rx.send_to(&buf, povins_addr).unwrap();
    };
    let answers = |rx: &UdpSocket| -> Vec<TIMESYNC_DATA> {
        rx.set_read_timeout(Some(Duration::from_millis(300)))
            .unwrap();
        let mut out = Vec::new();
        let mut buf = [0u8; 2048];
        while let Ok(len) = rx.recv(&mut buf) {
            let mut r = MavlinkReader::new(&buf[..len]);
            while let Ok((_, m)) = r.read_any_message::<MavMessage>() {
                if let MavMessage::TIMESYNC(t) = m {
                    out.push(t);
                }
            }
        }
        out
    };
    // Before any pose there is no clock: not answered.
    request(7);
    assert!(answers(&rx).is_empty());
    let t = 5_000_000_000_000i64;
    sink.pose(&pose(t));
    let sent = Instant::now();
    request(42);
    let a = answers(&rx);
    assert_eq!(a.len(), 1, "{a:?}");
    assert_eq!(
        (a[0].ts1, a[0].target_system, a[0].target_component),
        (42, 1, 1)
    );
    // tc1 = the pose's stamp + 2 us since it was due + the time since.
    let since = sent.elapsed().as_nanos() as i64;
    assert!(
        a[0].tc1 >= t + 2000 && a[0].tc1 <= t + 2000 + since + 1_000_000,
        "{a:?}"
    );
    sink.finish().unwrap();
    let c = sink.counts();
    assert_eq!((c.timesync_answered, c.timesync_unanswered), (1, 1));
}

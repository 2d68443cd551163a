//! The live UDP source against the offline assembler: synthetic packets sent over loopback with
//! drops, reorderings, a late packet, a duplicate and garbage.

use super::live::{imu_sample, Live, LiveCounts, LiveOptions, OusterUdp, StreamDecoder};
use super::tests::{build, meta, small_meta};
use super::*;
use crate::source::{SensorEvent, Source};
use povins_core::inertial::ImuSample;
use povins_core::math::Vec3;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

/// 16 columns per frame, 4 per packet: 4 packets a frame.
fn live_meta() -> Metadata {
    small_meta(LidarProfile::Single, 4, 16)
}

/// Packet `k` (0..4) of frame `f`: ranges differ by frame, column and row; column times increase
/// with the measurement id.
fn packet(m: &Metadata, f: u16, k: u16) -> Vec<u8> {
    build(m, f.into(), 4 * k, true, |c, r| {
        1000 + 100 * u32::from(f) + 10 * c as u32 + r as u32
    })
}

fn imu_packet(t_ns: u64, gyro_z_dps: f32) -> Vec<u8> {
    let mut b = Vec::new();
    for t in [t_ns - 3, t_ns - 1, t_ns] {
        b.extend_from_slice(&t.to_le_bytes());
    }
    for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, gyro_z_dps] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

/// What is sent, in order: `(to the lidar port, payload)`.
fn schedule(m: &Metadata) -> Vec<(bool, Vec<u8>)> {
    let p = |f, k| (true, packet(m, f, k));
    let imu = |t_ms: u64| (false, imu_packet(t_ms * 1_000_000, t_ms as f32));
    let mut bad_type = packet(m, 1, 0);
    bad_type[0] = 7;
    vec![
        // Frame 0 reordered within the frame.
        p(0, 0),
        imu(1),
        p(0, 2),
        p(0, 1),
        p(0, 3),
        imu(2),
        // Frame 1 without its packet 2; garbage on both ports.
        p(1, 0),
        p(1, 1),
        (true, vec![0xAB; 10]),
        (false, vec![1, 2, 3, 4, 5]),
        (true, bad_type),
        imu(3),
        imu(3), // a repeated IMU time: out of order
        p(1, 3),
        // Frame 2, then frame 1's packet 2 arrives late; frame 2's packet 3 twice.
        p(2, 0),
        p(2, 1),
        p(1, 2),
        p(2, 2),
        p(2, 3),
        p(2, 3),
        imu(4),
        // Frame 3 backwards.
        p(3, 3),
        p(3, 2),
        p(3, 1),
        p(3, 0),
        imu(5),
    ]
}

/// The sweeps of the same packets in order, without the dropped one, from the offline
/// assembler.
fn expected_sweeps(m: &Metadata) -> Vec<LidarScan> {
    let dec = Decoder::new(m);
    let mut asm = SweepAssembler::new(m);
    let mut out = Vec::new();
    for (f, k) in (0..4u16).flat_map(|f| (0..4u16).map(move |k| (f, k))) {
        if (f, k) == (1, 2) {
            continue;
        }
        out.extend(asm.push(&dec.decode_lidar(&packet(m, f, k)).unwrap()));
    }
    out.extend(asm.finish());
    out
}

/// Receives until `n` datagrams arrived (or 10 s), then stops and drains.
fn receive_all(src: &mut OusterUdp, n: u64) -> (Vec<LidarScan>, Vec<ImuSample>) {
    let (mut sweeps, mut imu) = (Vec::new(), Vec::new());
    let give_up = Instant::now() + Duration::from_secs(10);
    loop {
        if src.counts().datagrams() >= n || Instant::now() > give_up {
            src.stop();
        }
        match src.poll(Duration::from_millis(20)).unwrap() {
            Live::Sweep(s) => sweeps.push(s),
            Live::Imu(s) => imu.push(s),
            Live::Idle => {}
            Live::End => return (sweeps, imu),
        }
    }
}

fn send(to: (SocketAddr, SocketAddr), items: &[(bool, Vec<u8>)]) {
    let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
    for (lidar, b) in items {
        tx.send_to(b, if *lidar { to.0 } else { to.1 }).unwrap();
        // Loopback keeps one socket's order; the pause keeps the two ports' relative order too.
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn loopback() -> LiveOptions {
    LiveOptions {
        lidar_port: 0,
        imu_port: 0,
        ..LiveOptions::default()
    }
}

#[test]
fn loopback_sweeps_equal_the_offline_assembler_with_losses_counted() {
    let m = live_meta();
    let mut src = OusterUdp::bind(&m, loopback()).unwrap();
    assert!(src.is_realtime());
    let items = schedule(&m);
    send(src.local_addrs(), &items);
    let (sweeps, imu) = receive_all(&mut src, items.len() as u64);
    let c: LiveCounts = src.counts();

    assert_eq!(
        sweeps,
        expected_sweeps(&m),
        "sweeps vs the in-order assembly"
    );
    assert_eq!(sweeps.len(), 4);
    let imu_t: Vec<i64> = imu.iter().map(|s| s.t_ns).collect();
    assert_eq!(imu_t, [1, 2, 3, 4, 5].map(|t| t * 1_000_000), "gyro times");
    assert_eq!(imu[2].accel_mps2.z, G_MPS2);
    assert!((imu[2].gyro_rps.z - 3f64.to_radians()).abs() < 1e-12);

    let lidar = items.iter().filter(|i| i.0).count() as u64;
    assert_eq!(c.lidar_datagrams, lidar);
    assert_eq!(c.imu_datagrams, items.len() as u64 - lidar);
    assert_eq!(c.bad_datagrams, 3, "{:?}", c.first_error);
    let first = c.first_error.clone().unwrap();
    assert!(
        first.contains("lidar port") && first.contains("10 bytes"),
        "{first}"
    );
    assert_eq!((c.imu_samples, c.imu_out_of_order), (5, 1));
    assert_eq!((c.sweeps, c.empty_sweeps, c.queue_overflows), (4, 0, 0));
    let a = c.assembler;
    assert_eq!(a.packets, lidar - 2);
    assert_eq!(a.late_packets, 1);
    assert_eq!((a.dropped_packets, a.missing_columns), (1, 4));
    assert_eq!(a.duplicate_columns, 4);
}

#[test]
fn source_yields_imu_and_sweeps_and_ends_at_the_deadline() {
    let m = live_meta();
    let mut src = OusterUdp::bind(&m, loopback()).unwrap();
    let items: Vec<_> = (0..4u16)
        .map(|k| (true, packet(&m, 0, k)))
        .chain([(false, imu_packet(7_000_000, 0.0))])
        .collect();
    send(src.local_addrs(), &items);
    src.set_deadline(Instant::now() + Duration::from_millis(300));
    let mut events = Vec::new();
    while let Some(ev) = src.next().unwrap() {
        events.push(ev);
    }
    let imu = events
        .iter()
        .filter(|e| matches!(e, SensorEvent::Imu(s) if s.t_ns == 7_000_000))
        .count();
    let sweeps: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            SensorEvent::Lidar(p) => Some(p.clone()),
            _ => None,
        })
        .collect();
    assert_eq!((imu, sweeps.len()), (1, 1), "{events:?}");
    assert_eq!(sweeps[0].len(), 16 * 4);
    assert_eq!(src.counts().assembler.dropped_packets, 0);
}

#[test]
fn a_taken_port_is_an_error_naming_it() {
    let m = live_meta();
    let taken = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let opts = LiveOptions {
        lidar_port: port,
        imu_port: 0,
        ..LiveOptions::default()
    };
    let e = OusterUdp::bind(&m, opts).unwrap_err().to_string();
    assert!(
        e.contains(&format!("127.0.0.1:{port}")) && e.contains("lidar"),
        "{e}"
    );
}

#[test]
fn garbage_datagrams_are_counted_never_a_panic() {
    let m = meta();
    let size = Decoder::new(&m).lidar_packet_bytes();
    let mut dec = StreamDecoder::new(&m);
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let mut n = 0;
    for k in 0..300 {
        let len = match k % 3 {
            0 => size,
            1 => 48,
            _ => (next() % 9000) as usize,
        };
        let b: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        if k % 2 == 0 {
            dec.lidar(&b, 7502);
        } else {
            dec.imu(&b, 7503);
        }
        while dec.pop().is_some() {
            n += 1;
        }
    }
    dec.finish();
    let c = dec.counts();
    assert_eq!(c.datagrams(), 300);
    assert!(c.bad_datagrams >= 150, "{c:?}");
    assert!(n <= 300);
}

#[test]
fn imu_samples_are_the_gyro_time_and_finite() {
    let p = decode_imu(&imu_packet(9, 45.0)).unwrap();
    let s = imu_sample(&p).unwrap();
    assert_eq!(s.t_ns, 9);
    assert_eq!((p.accel_t_ns, p.gyro_t_ns), (8, 9));
    let mut b = imu_packet(9, 45.0);
    b[24..28].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(imu_sample(&decode_imu(&b).unwrap()).is_none());
}

#[test]
fn the_lidar_extrinsic_inverts_imu_to_sensor() {
    let m = meta();
    let t = t_imu_sensor(&m);
    let a = m.imu_to_sensor_m();
    // p_sensor = A p_imu; T_bl maps p_sensor back to p_imu.
    let p_imu = Vec3::new(0.3, -0.2, 1.0);
    let p_sensor = Vec3::new(
        a[0][0] * p_imu.x + a[0][1] * p_imu.y + a[0][2] * p_imu.z + a[0][3],
        a[1][0] * p_imu.x + a[1][1] * p_imu.y + a[1][2] * p_imu.z + a[1][3],
        a[2][0] * p_imu.x + a[2][1] * p_imu.y + a[2][2] * p_imu.z + a[2][3],
    );
    let back = t.q_ab * p_sensor + t.p_ab;
    assert!((back - p_imu).norm() < 1e-12, "{back:?}");
    let c = calibration(&m);
    assert_eq!((c.camera.width, c.t_bl), (0, Some(t)));
}

/// Issue 34 bar 6: a million random and truncated datagrams on both ports: every one counted
/// (bad, or a packet that decoded), none a panic. Sent in bursts of 1000, each waited for, so
/// that the kernel's buffer does not drop any.
#[test]
fn a_million_random_and_truncated_datagrams_are_counted_never_a_panic() {
    let m = live_meta();
    let mut src = OusterUdp::bind(&m, loopback()).unwrap();
    let (lidar, imu) = src.local_addrs();
    let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let good = packet(&m, 0, 0);
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = move || {
        // xorshift64*: a fixed sequence, no dependency.
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    };
    let total: u64 = 1_000_000;
    let mut sent = 0u64;
    let mut buf = vec![0u8; 9000];
    while sent < total {
        for _ in 0..1000 {
            let r = next();
            let to = if r & 1 == 0 { lidar } else { imu };
            let payload: &[u8] = match (r >> 1) % 4 {
                // A valid packet cut short (or whole), possibly with a byte flipped.
                0 | 1 => {
                    let n = (r >> 8) as usize % (good.len() + 1);
                    buf[..n].copy_from_slice(&good[..n]);
                    if n > 0 && (r >> 40) & 1 == 1 {
                        buf[(r >> 20) as usize % n] ^= 0x5A;
                    }
                    &buf[..n]
                }
                // Random bytes of a random length.
                _ => {
                    let n = (r >> 8) as usize % buf.len();
                    for b in &mut buf[..n] {
                        *b = next() as u8;
                    }
                    &buf[..n]
                }
            };
            tx.send_to(payload, to).unwrap();
            sent += 1;
        }
        let until = Instant::now() + Duration::from_secs(10);
        while src.counts().datagrams() + src.counts().queue_overflows < sent {
            assert!(Instant::now() < until, "{:?} of {sent}", src.counts());
            let _ = src.poll(Duration::from_millis(1)).unwrap();
        }
    }
    src.stop();
    while !matches!(src.poll(Duration::from_millis(10)).unwrap(), Live::End) {}
    let c = src.counts();
    eprintln!("{total} datagrams: {c:?}");
    assert_eq!(c.datagrams() + c.queue_overflows, total);
    assert!(c.bad_datagrams > total / 2, "{c:?}");
}

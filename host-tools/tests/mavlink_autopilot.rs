//! Issue 34 bar 1: an autopilot's side that is not ours (Python `pymavlink`,
//! `scripts/mavlink_receiver.py`) receives `povins replay --realtime --mavlink` on a loopback
//! port: the ODOMETRY it decodes, converted back to povins' frames and matched by `time_usec`,
//! equal `trajectory.tum`; the rate is the one asked for; its TIMESYNC requests are answered on
//! a clock that maps povins' stamps onto its own; the velocity covariance it receives describes
//! the velocity's error against the simulator's truth (NEES). The same over a serial line (a
//! pseudo-terminal).

mod common;

use povins_core::math::{Quat, Vec3};
use povins_platform::pipeline::mavlink::{from_frd, BodyAxes, FrdPose};
use povins_platform::trajectory::read_tum;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
#[ignore = "needs PyPI (pymavlink) and runs 15 s in real time"]
fn pymavlink_receives_the_trajectory_and_timesync_maps_the_clock() {
    receive_and_check(false);
}

/// The same over a serial line (`--mavlink serial:DEVICE:BAUD`, the `mavlink` crate's serial
/// transport, as to an autopilot's UART): the device is a pseudo-terminal whose other side the
/// receiver reads, so the port's configuration (8N1, the baud rate) and the byte stream's framing
/// are those of a real line, without the line.
#[test]
#[ignore = "needs PyPI (pymavlink) and runs 15 s in real time"]
fn pymavlink_receives_the_trajectory_over_a_serial_line() {
    receive_and_check(true);
}

/// Simulates 15 s, replays it in real time to the receiver (over loopback UDP, or `serial`:
/// a pseudo-terminal) and checks what it received.
fn receive_and_check(serial: bool) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("seq");
    let (ok, _, err) = common::povins(&[
        "simulate",
        "--seed",
        "3",
        "--duration",
        "15",
        "--lidar",
        "none",
        "--format",
        "euroc",
        "--out",
        data.to_str().unwrap(),
    ]);
    assert!(ok, "simulate: {err}");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let json = tmp.path().join("received.json");
    let script =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/mavlink_receiver.py");
    let mut rx = Command::new(common::pymavlink_python())
        .arg(script)
        .arg(if serial {
            "pty".to_string()
        } else {
            format!("udpin:127.0.0.1:{port}")
        })
        .arg(&json)
        // The end of the stream is 10 s without a message: a replay starved for a few seconds
        // on a loaded machine (CI's parallel tests) must not end it early (the counts are by
        // stamp, not by wall time). 120 s at most.
        .args(["10", "120"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("python");
    let mut lines = BufReader::new(rx.stdout.take().unwrap()).lines();
    let ready = lines.next().unwrap().unwrap();
    let link = match ready.strip_prefix("ready ") {
        Some(dev) if serial => format!("serial:{dev}:921600"),
        _ => {
            assert_eq!(ready, "ready");
            format!("udpout:127.0.0.1:{port}")
        }
    };
    let out = tmp.path().join("out");
    let (ok, stdout, err) = common::povins(&[
        "replay",
        "--realtime",
        data.to_str().unwrap(),
        "--no-rt",
        "--out",
        out.to_str().unwrap(),
        "--mavlink",
        &link,
        "--mavlink-rate",
        "30",
        "--mavlink-vision-position",
    ]);
    assert!(ok, "replay: {err}");
    assert!(rx.wait().unwrap().success());
    let summary: Vec<String> = lines.map_while(Result::ok).collect();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let odo = v["odometry"].as_array().unwrap();
    let traj = read_tum(&out.join("trajectory.tum")).unwrap();
    let line = stdout
        .lines()
        .find(|l| l.starts_with("mavlink"))
        .unwrap_or_default()
        .to_string();
    eprintln!("{line}\npymavlink: {summary:?}");

    // Rate: povins sent 30 per second of published poses (decimated by stamp, so whatever the
    // machine's load), and the link lost none of them.
    let span_s = (traj.last().unwrap().t_ns - traj[0].t_ns) as f64 * 1e-9;
    let expected = span_s * 30.0;
    let sent = count_before(&line, " ODOMETRY");
    assert!(
        (sent as f64 - expected).abs() <= 0.02 * expected + 1.0,
        "povins sent {sent} ODOMETRY over {span_s:.2} s of poses: {line}"
    );
    assert_eq!(odo.len(), sent, "ODOMETRY received against sent: {line}");
    assert!(v["heartbeats"].as_u64().unwrap() >= (span_s as u64).saturating_sub(1));

    // Every ODOMETRY equals the trajectory's pose at its time_usec.
    let by_us: std::collections::HashMap<i64, usize> = traj
        .iter()
        .enumerate()
        .map(|(i, p)| (p.t_ns / 1000, i))
        .collect();
    // The numbers of one message as the receiver recorded them.
    let numbers = |o: &serde_json::Value| -> Vec<f64> {
        o.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap_or(f64::NAN))
            .collect()
    };
    let (mut max_p, mut max_deg) = (0f64, 0f64);
    for o in odo {
        let f = numbers(o);
        assert_eq!(
            (f[13], f[14], f[15]),
            (20.0, 12.0, 3.0),
            "LOCAL_FRD, BODY_FRD, VIO"
        );
        assert_eq!((f[17], f[18]), (1.0, 197.0), "system 1, component VIO");
        assert_eq!(f[11], 0.0, "no reset in this run");
        let i = by_us[&(f[0] as i64)];
        let frd = FrdPose {
            p_l: Vec3::new(f[1], f[2], f[3]),
            q_lv: Quat::from_quaternion(nalgebra::Quaternion::new(f[4], f[5], f[6], f[7])),
            v_v: Vec3::new(f[8], f[9], f[10]),
        };
        let (p, q, _) = from_frd(&frd, &BodyAxes::default());
        max_p = max_p.max((p - traj[i].p_wb).norm());
        max_deg = max_deg.max(q.angle_to(&traj[i].q_wb).to_degrees());
    }
    eprintln!(
        "{} ODOMETRY: max position difference {max_p:.2e} m, attitude {max_deg:.2e} deg",
        odo.len()
    );
    assert!(max_p < 1e-3 && max_deg < 0.01);
    check_velocity_covariance(odo.iter().map(numbers).collect(), &data);

    // VISION_POSITION_ESTIMATE (ArduPilot's message): one per ODOMETRY, the same pose, the
    // attitude as roll, pitch, yaw of the vehicle's FRD body in the local FRD frame.
    let vis = v["vision"].as_array().unwrap();
    assert_eq!(
        vis.len(),
        odo.len(),
        "one VISION_POSITION_ESTIMATE per ODOMETRY"
    );
    let (mut vmax_p, mut vmax_deg) = (0f64, 0f64);
    for o in vis {
        let f = numbers(o);
        assert_eq!(f[7], 0.0, "no reset in this run");
        let i = by_us[&(f[0] as i64)];
        let frd = FrdPose {
            p_l: Vec3::new(f[1], f[2], f[3]),
            q_lv: Quat::from_euler_angles(f[4], f[5], f[6]),
            v_v: Vec3::zeros(),
        };
        let (p, q, _) = from_frd(&frd, &BodyAxes::default());
        vmax_p = vmax_p.max((p - traj[i].p_wb).norm());
        vmax_deg = vmax_deg.max(q.angle_to(&traj[i].q_wb).to_degrees());
    }
    eprintln!(
        "{} VISION_POSITION_ESTIMATE: max position difference {vmax_p:.2e} m, attitude \
         {vmax_deg:.2e} deg",
        vis.len()
    );
    assert!(vmax_p < 1e-3 && vmax_deg < 0.01);

    // TIMESYNC: offset = tc1 - (ts1 + recv) / 2 on each answer (loopback: symmetric paths).
    // Converged: the median offset of the second quarter of the answers and of the last
    // quarter agree within 0.5 ms; with it povins' stamps map onto the receiver's clock with a
    // small, positive latency.
    let ts: Vec<[f64; 3]> = v["timesync"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            let a = a.as_array().unwrap();
            [0, 1, 2].map(|k| a[k].as_i64().unwrap() as f64)
        })
        .collect();
    // Every request the receiver sent while povins ran was answered, except those before
    // its first pose (no clock yet; povins counts them) and those in flight at its end. The
    // receiver aims at 10 Hz; on a loaded machine its Python loop sends fewer (13 runs beside
    // four busy loops on this 2-core VM: 110-126 over 14 s), so the rate is not the check.
    let last_recv_ns = odo.last().unwrap().as_array().unwrap()[16]
        .as_i64()
        .unwrap();
    let requests = v["timesync_sent_ns"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t.as_i64().unwrap() < last_recv_ns - 200_000_000)
        .count();
    let unanswered = count_before(&line, " before the first pose");
    assert!(
        ts.len() + unanswered + 2 >= requests && ts.len() as f64 >= span_s * 5.0,
        "{} TIMESYNC answers to {requests} requests while povins ran ({unanswered} before its \
         first pose): {line}",
        ts.len()
    );
    let offsets: Vec<f64> = ts.iter().map(|a| a[0] - 0.5 * (a[1] + a[2])).collect();
    let q = offsets.len() / 4;
    let early = median(&mut offsets[q..2 * q].to_vec());
    let off = median(&mut offsets[3 * q..].to_vec());
    let spread = (off - early).abs();
    let mut lat_ms: Vec<f64> = odo
        .iter()
        .map(|o| {
            let a = o.as_array().unwrap();
            let stamp_ns = a[0].as_f64().unwrap() * 1000.0;
            (a[16].as_f64().unwrap() - (stamp_ns - off)) * 1e-6
        })
        .collect();
    let lat = median(&mut lat_ms);
    eprintln!(
        "TIMESYNC: {} answers to {requests} requests, offset drift {:.3} ms between quarters; stamp-to-receipt latency median {lat:.3} ms",
        ts.len(),
        spread * 1e-6
    );
    assert!(
        spread < 0.5e6,
        "the offset moved {spread} ns between quarters"
    );
    assert!((0.0..50.0).contains(&lat), "median latency {lat} ms");
}

/// The number just before `what` in povins' `mavlink` summary line (e.g. `420 ODOMETRY`,
/// `(8 before the first pose)`).
fn count_before(line: &str, what: &str) -> usize {
    let head = &line[..line
        .find(what)
        .unwrap_or_else(|| panic!("{what:?} in {line:?}"))];
    let digits: String = head
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    digits
        .parse()
        .unwrap_or_else(|_| panic!("a count before {what:?} in {line:?}"))
}

/// The body velocity's covariance in the ODOMETRY the receiver decoded (`f`: its numbers),
/// against the simulator's ground truth in `data`: known once the estimator has solved (all but
/// the first messages), positive definite, and of the order of the actual error: the mean NEES
/// (3 when consistent) within [1, 60]. The estimator is overconfident (BENCHMARKS.md, "The
/// covariance sent": body-velocity NEES 3.5-22 over the scenarios; this 15 s start without
/// LiDAR measured 21.5); a covariance in the wrong frame, units or order is off by orders of
/// magnitude (a body velocity of 1 m/s against a 1 cm/s standard deviation: 10^4).
fn check_velocity_covariance(odo: Vec<Vec<f64>>, data: &std::path::Path) {
    let gt_csv = data.join("mav0/state_groundtruth_estimate0/data.csv");
    let gt: std::collections::HashMap<i64, (Quat, Vec3)> = std::fs::read_to_string(gt_csv)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let f: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
            let q = Quat::from_quaternion(nalgebra::Quaternion::new(f[4], f[5], f[6], f[7]));
            (f[0] as i64, (q, Vec3::new(f[8], f[9], f[10])))
        })
        .collect();
    let r_bv = BodyAxes::default().r_bv;
    let known: Vec<&Vec<f64>> = odo.iter().filter(|f| f[19] == 1.0).collect();
    assert!(
        known.len() * 10 >= odo.len() * 9,
        "{} of {} ODOMETRY with a covariance",
        known.len(),
        odo.len()
    );
    let mut nees = Vec::new();
    for f in known {
        let Some((q, v)) = gt.get(&((f[0] as i64) * 1000)) else {
            continue;
        };
        let v_v = r_bv.transpose() * (q.inverse() * v);
        let e = Vec3::new(f[8], f[9], f[10]) - v_v;
        let c = nalgebra::Matrix3::new(
            f[20], f[21], f[22], f[21], f[23], f[24], f[22], f[24], f[25],
        );
        let chol = c
            .cholesky()
            .expect("a positive definite velocity covariance");
        nees.push(e.dot(&chol.solve(&e)));
        assert!(f[26..32].iter().all(|x| x.is_finite() && *x > 0.0), "{f:?}");
    }
    assert!(nees.len() > 100, "{} compared", nees.len());
    let mean = nees.iter().sum::<f64>() / nees.len() as f64;
    eprintln!(
        "velocity covariance: body-velocity NEES mean {mean:.2}, median {:.2} over {} ODOMETRY",
        median(&mut nees),
        nees.len()
    );
    // Measured 7.77 (BENCHMARKS, session 52; 21.5 before the anchors' bearings were solved
    // for): a covariance in the wrong frame or units misses by orders of magnitude, and the
    // window's overcounted visual information (2x the squared error) would be back above 20.
    assert!((1.0..20.0).contains(&mean), "NEES {mean}");
}

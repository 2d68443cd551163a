//! `povins record` end to end: the built binary listens on loopback, the fixture capture's
//! datagrams (OS1-128, 192 lidar and 30 IMU packets) are replayed to it packet by packet at the
//! recorded pace, and the EuRoC folder it writes is compared with the Ouster SDK's decoding of
//! the capture (Python `ouster-sdk`, `scripts/ouster_reference.py`): every packet received,
//! every point within 1 mm at the same time, every IMU sample equal. A second replay drops,
//! reorders, repeats and delays packets and adds garbage; its counts are checked, and the frame
//! that was only reordered still equals the SDK's.
//!
//! Run with `cargo test -p povins-host-tools --test ouster_record -- --ignored`. Python is the
//! venv `target/pyenv-ouster` (made on first use by `scripts/pyenv.sh`, needs PyPI) or
//! `$POVINS_OUSTER_PYTHON`.

mod common;

use povins_platform::ouster::{read_pcap, t_imu_sensor, Decoder, Metadata, PcapUdp};
use povins_platform::recording::Recording;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/fixtures/ouster")
}

fn capture() -> PathBuf {
    fixtures().join("OS-1-128_v2.3.0_1024x10_lb_n3.pcap")
}

fn meta_path() -> PathBuf {
    fixtures().join("OS-1-128_v2.3.0_1024x10.json")
}

/// Python with `ouster-sdk` 1.0.1 (as `platform/tests/ouster_sdk.rs`).
fn python() -> String {
    common::ouster_python().to_string_lossy().into_owned()
}

/// The SDK's decoding of the capture (sweeps.csv, points.bin, imu.csv) in a temporary folder.
fn sdk_reference() -> tempfile::TempDir {
    let out = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/ouster_reference.py");
    let py = python();
    let run = Command::new(&py)
        .arg(&script)
        .arg(capture())
        .arg(meta_path())
        .arg(out.path())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {py}: {e}"));
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    out
}

/// One datagram to replay: to the lidar port?, capture time, payload.
type Item = (bool, i64, Vec<u8>);

fn datagrams() -> Vec<Item> {
    let udp = PcapUdp::open(&capture()).unwrap().ports(&[7502, 7503]);
    udp.map(|d| {
        let d = d.unwrap();
        (d.dst_port == 7502, d.t_capture_ns, d.payload)
    })
    .collect()
}

/// Starts `povins record` on free loopback ports, replays `items` at their capture pace, and
/// returns the summary's counts and the output folder.
fn record(items: &[Item], dir: &Path) -> BTreeMap<String, u64> {
    record_until(items, dir, Some("3"))
}

/// `povins record` with `--duration` when given; without, it is ended by `SIGINT` (Ctrl-C)
/// once every datagram was sent and the last one has had time to be read.
fn record_until(items: &[Item], dir: &Path, duration: Option<&str>) -> BTreeMap<String, u64> {
    let out = dir.join("rec");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_povins"));
    cmd.args(["record", "--ouster-meta"])
        .arg(meta_path())
        .args(["--lidar-port", "0", "--imu-port", "0"]);
    if let Some(d) = duration {
        cmd.args(["--duration", d]);
    }
    let mut child = cmd
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = mpsc::channel();
    let stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines() {
            let line = line.unwrap();
            eprintln!("  | {line}");
            let _ = tx.send(line);
        }
    });
    let listening = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("povins record did not start listening");
    let addrs: Vec<SocketAddr> = listening
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    assert_eq!(addrs.len(), 2, "{listening}");
    let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let (t0, w0) = (items[0].1, Instant::now());
    for (lidar, t, b) in items {
        let due = w0 + Duration::from_nanos((t - t0).max(0) as u64);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        tx.send_to(b, addrs[usize::from(!lidar)]).unwrap();
    }
    if duration.is_none() {
        // The receivers read within their poll period (100 ms); give them ample time.
        std::thread::sleep(Duration::from_millis(500));
        sigint(child.id());
    }
    let done = child.wait_with_output().unwrap();
    reader.join().unwrap();
    let stdout = String::from_utf8_lossy(&done.stdout).to_string();
    assert!(done.status.success(), "povins record failed: {stdout}");
    eprintln!("{stdout}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("record summary:"))
        .expect("no summary");
    line.split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.parse().unwrap()))
        .collect()
}

/// Sends `SIGINT` (what Ctrl-C sends) to process `pid`.
fn sigint(pid: u32) {
    let ok = Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status()
        .expect("kill runs")
        .success();
    assert!(ok, "kill -INT {pid}");
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// The recorded sweeps: `(sweep t_ns, [(point t_ns, [x, y, z])])` from `lidar0/data.csv`.
type Sweep = (i64, Vec<(i64, [f64; 3])>);

fn recorded_sweeps(out: &Path) -> Vec<Sweep> {
    let mut sweeps: Vec<Sweep> = Vec::new();
    for r in csv_rows(&out.join("mav0/lidar0/data.csv")) {
        let t: i64 = r[0].parse().unwrap();
        let p = (
            r[1].parse().unwrap(),
            [2, 3, 4].map(|i| r[i].parse().unwrap()),
        );
        match sweeps.last_mut() {
            Some(s) if s.0 == t => s.1.push(p),
            _ => sweeps.push((t, vec![p])),
        }
    }
    sweeps
}

/// The SDK's sweeps: `(frame id, first valid t_ns, points (t_ns, p))`.
fn sdk_sweeps(out: &Path) -> Vec<(i64, Sweep)> {
    let b = std::fs::read(out.join("points.bin")).unwrap();
    let i64_at = |o: usize| i64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let mut k = 0;
    let mut all = Vec::new();
    for row in csv_rows(&out.join("sweeps.csv")) {
        let (fid, n, t): (i64, usize, i64) = (
            row[0].parse().unwrap(),
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
        );
        let pts = (k..k + n)
            .map(|j| {
                let o = 40 * j;
                assert_eq!(i64_at(o), fid);
                (i64_at(o + 8), [16, 24, 32].map(|d| f64_at(o + d)))
            })
            .collect();
        k += n;
        all.push((fid, (t, pts)));
    }
    all
}

/// Asserts a recorded sweep equals the SDK's: same time, same points in order, times exact,
/// positions within 1 mm. Returns the largest difference, m.
fn same_sweep(ours: &Sweep, sdk: &Sweep, what: &str) -> f64 {
    assert_eq!(ours.0, sdk.0, "{what}: sweep time");
    assert_eq!(ours.1.len(), sdk.1.len(), "{what}: points");
    let mut max_d = 0f64;
    for (k, (a, b)) in ours.1.iter().zip(&sdk.1).enumerate() {
        assert_eq!(a.0, b.0, "{what} point {k}: time");
        let d = (0..3)
            .map(|i| (a.1[i] - b.1[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(d < 1e-3, "{what} point {k}: {:?} vs {:?}", a.1, b.1);
        max_d = max_d.max(d);
    }
    max_d
}

#[test]
#[ignore = "needs ../shared/data and PyPI (ouster-sdk)"]
fn recorded_stream_equals_the_ouster_sdk() {
    let sdk = sdk_reference();
    let items = datagrams();
    let meta = Metadata::from_file(&meta_path()).unwrap();
    let offline = read_pcap(&capture(), &meta).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let c = record(&items, dir.path());
    let out = dir.path().join("rec");

    let n_lidar = items.iter().filter(|i| i.0).count() as u64;
    assert_eq!((n_lidar, items.len() as u64 - n_lidar), (192, 30));
    assert_eq!(c["lidar_datagrams"], 192, "{c:?}");
    assert_eq!(c["imu_datagrams"], 30, "{c:?}");
    assert_eq!(c["bad_datagrams"] + c["queue_overflows"], 0);
    let o = offline.counts;
    assert_eq!(
        [
            c["dropped_packets"],
            c["late_packets"],
            c["duplicate_columns"],
            c["points"]
        ],
        [
            o.dropped_packets,
            o.late_packets,
            o.duplicate_columns,
            o.points
        ],
        "counts as the offline reading of the capture"
    );

    let ours = recorded_sweeps(&out);
    let sdk_sw = sdk_sweeps(sdk.path());
    assert_eq!(ours.len(), sdk_sw.len());
    let (mut max_d, mut n_points) = (0f64, 0);
    for (s, (fid, r)) in ours.iter().zip(&sdk_sw) {
        max_d = max_d.max(same_sweep(s, r, &format!("frame {fid}")));
        n_points += s.1.len();
    }

    let imu = csv_rows(&out.join("mav0/imu0/data.csv"));
    let sdk_imu = csv_rows(&sdk.path().join("imu.csv"));
    assert_eq!(imu.len(), sdk_imu.len());
    let mut max_rel = 0f64;
    for (a, b) in imu.iter().zip(&sdk_imu) {
        assert_eq!(a[0], b[2], "IMU time = the gyro time");
        // Ours: gyro then accel; the SDK's: accel then gyro.
        for (x, y) in a[1..7].iter().zip(b[6..9].iter().chain(&b[3..6])) {
            let (x, y): (f64, f64) = (x.parse().unwrap(), y.parse().unwrap());
            let rel = (x - y).abs() / y.abs().max(1e-3);
            assert!(rel < 1e-6, "IMU {x} vs SDK {y}");
            max_rel = max_rel.max(rel);
        }
    }

    // `povins run` reads the folder with T_bl = imu_to_sensor^-1.
    let folder = povins_platform::euroc::EurocFolder::open(&out).unwrap();
    let t_bl = folder.calibration().t_bl.expect("lidar0/sensor.yaml");
    let want = t_imu_sensor(&meta);
    assert!((t_bl.p_ab - want.p_ab).norm() < 1e-12 && t_bl.q_ab.angle_to(&want.q_ab) < 1e-12);
    assert!(out.join("ouster_metadata.json").is_file());
    eprintln!(
        "record vs ouster-sdk: {} + {} datagrams received, {} sweeps, {n_points} points, \
         max |dp| {max_d:.3e} m, times equal; {} IMU samples, max relative difference \
         {max_rel:.1e}",
        c["lidar_datagrams"],
        c["imu_datagrams"],
        ours.len(),
        imu.len()
    );
}

#[test]
#[ignore = "needs ../shared/data and PyPI (ouster-sdk)"]
fn drops_reorderings_and_garbage_are_counted() {
    let sdk = sdk_reference();
    let items = datagrams();
    let meta = Metadata::from_file(&meta_path()).unwrap();
    let base = read_pcap(&capture(), &meta).unwrap().counts;
    let dec = Decoder::new(&meta);
    // Lidar packets with their frame ids; the frames' first packets.
    let mut lidar: Vec<Item> = items.iter().filter(|i| i.0).cloned().collect();
    let mut imu: Vec<Item> = items.iter().filter(|i| !i.0).cloned().collect();
    let fids: Vec<u32> = lidar
        .iter()
        .map(|i| dec.decode_lidar(&i.2).unwrap().frame_id)
        .collect();
    let starts: Vec<usize> = (0..fids.len())
        .filter(|&k| k == 0 || fids[k] != fids[k - 1])
        .collect();
    assert_eq!(starts.len(), 3, "{starts:?}");
    let (s1, s2) = (starts[1], starts[2]);
    // Frame 1 only reordered within itself.
    lidar.swap(s1 + 20, s1 + 21);
    lidar.swap(s1 + 30, s1 + 35);
    // Frame 2: one packet twice, one dropped (drop after the copy: the indices shift).
    let dup = lidar[s2 + 50].clone();
    lidar.insert(s2 + 51, dup);
    lidar.remove(s2 + 40);
    // Frame 0's last packet after frame 1's third (late); frame 0's packet 10 dropped.
    let last0 = lidar.remove(s1 - 1);
    lidar.insert(s1 + 2, last0);
    lidar.remove(10);
    // Garbage on both ports, one IMU packet lost.
    imu.remove(5);
    let t_mid = lidar[100].1;
    lidar.insert(100, (true, t_mid, vec![0x55; 100]));
    imu.insert(10, (false, imu[10].1, vec![1, 2, 3, 4, 5, 6, 7]));
    // The k-th lidar datagram goes at the k-th original lidar time, so the order above stays.
    let times: Vec<i64> = items.iter().filter(|i| i.0).map(|i| i.1).collect();
    for (k, item) in lidar.iter_mut().enumerate() {
        item.1 = times[k.min(times.len() - 1)];
    }
    let mut all: Vec<Item> = lidar.into_iter().chain(imu).collect();
    all.sort_by_key(|i| i.1); // stable

    let dir = tempfile::tempdir().unwrap();
    let c = record(&all, dir.path());
    let out = dir.path().join("rec");
    let got = [
        c["lidar_datagrams"],
        c["imu_datagrams"],
        c["bad_datagrams"],
        c["imu_samples"],
        c["sweeps"],
        c["late_packets"],
        c["dropped_packets"],
        c["duplicate_columns"],
        c["queue_overflows"],
    ];
    let want = [
        192 - 2 + 1 + 1,
        30 - 1 + 1,
        2,
        29,
        3,
        base.late_packets + 1,
        base.dropped_packets + 3,
        base.duplicate_columns + meta.columns_per_packet as u64,
        0,
    ];
    assert_eq!(got, want, "{c:?}");
    let ours = recorded_sweeps(&out);
    let sdk_sw = sdk_sweeps(sdk.path());
    let d = same_sweep(&ours[1], &sdk_sw[1].1, "reordered frame 1");
    eprintln!(
        "record with losses: counts {c:?}; the reordered frame equals the SDK's (max |dp| \
         {d:.3e} m)"
    );
}

fn povins(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_povins"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

#[test]
#[ignore = "needs ../shared/data"]
fn pcap_conversion_gives_the_same_files_in_both_formats() {
    let dir = tempfile::tempdir().unwrap();
    let (e, m) = (dir.path().join("e"), dir.path().join("m"));
    for (out, format) in [(&e, "euroc"), (&m, "mcap")] {
        let o = povins(&[
            "record".as_ref(),
            "--ouster-meta".as_ref(),
            meta_path().as_os_str(),
            "--pcap".as_ref(),
            capture().as_os_str(),
            "--format".as_ref(),
            format.as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let euroc = povins_platform::euroc::EurocFolder::open(&e).unwrap();
    let mcap = povins_platform::mcap_io::McapRecording::open(&m.join("recording.mcap")).unwrap();
    let sweeps = |r: &dyn Recording| r.sweeps().unwrap().map(Result::unwrap).collect::<Vec<_>>();
    let imu = |r: &dyn Recording| r.imu().unwrap().map(Result::unwrap).collect::<Vec<_>>();
    let (se, sm) = (sweeps(&euroc), sweeps(&mcap));
    assert_eq!((se.len(), imu(&euroc).len()), (3, 30));
    assert_eq!(se, sm, "EuRoC vs MCAP sweeps");
    assert_eq!(imu(&euroc), imu(&mcap), "EuRoC vs MCAP IMU");
    assert_eq!(euroc.calibration().t_bl, mcap.calibration().t_bl);
    // The offline conversion's sweeps are the capture's as read_pcap assembles them.
    let meta = Metadata::from_file(&meta_path()).unwrap();
    assert_eq!(se, read_pcap(&capture(), &meta).unwrap().scans);
}

#[test]
fn nothing_received_is_an_error_naming_the_ports() {
    let meta = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../platform/src/ouster/testdata/os1-128_v2.3.0_1024x10.json");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec");
    let base: Vec<&std::ffi::OsStr> = vec![
        "record".as_ref(),
        "--ouster-meta".as_ref(),
        meta.as_os_str(),
        "--lidar-port".as_ref(),
        "0".as_ref(),
        "--imu-port".as_ref(),
        "0".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ];
    let o = povins(&[&base[..], &["--duration".as_ref(), "0.3".as_ref()]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("nothing received on udp 127.0.0.1:") && err.contains("(IMU) in 0.3 s"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
    // Without --duration it listens until Ctrl-C; interrupted with nothing received, it says
    // so and writes nothing.
    let mut child = Command::new(env!("CARGO_BIN_EXE_povins"))
        .args(&base)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    err.read_line(&mut line).unwrap();
    assert!(line.contains("until Ctrl-C"), "{line}");
    sigint(child.id());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success());
    assert!(
        rest.contains("record: interrupted") && rest.contains("nothing received on udp 127.0.0.1:"),
        "{rest}"
    );
    assert!(!out.exists(), "nothing written");
}

/// Ctrl-C ends a recording without --duration, and what was received is written: the same
/// sweeps and IMU samples as a timed recording of the same datagrams.
#[test]
#[ignore = "needs ../shared/data"]
fn an_interrupted_recording_keeps_what_it_received() {
    let items = datagrams();
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let timed = record(&items, a.path());
    let interrupted = record_until(&items, b.path(), None);
    assert_eq!(timed, interrupted, "the counts");
    assert_eq!(
        (interrupted["lidar_datagrams"], interrupted["imu_datagrams"]),
        (192, 30),
        "{interrupted:?}"
    );
    let (sa, sb) = (
        recorded_sweeps(&a.path().join("rec")),
        recorded_sweeps(&b.path().join("rec")),
    );
    assert_eq!(sa.len(), 3);
    assert_eq!(sa, sb, "the sweeps");
    let imu = |d: &Path| csv_rows(&d.join("rec/mav0/imu0/data.csv"));
    assert_eq!(imu(a.path()), imu(b.path()), "the IMU samples");
}

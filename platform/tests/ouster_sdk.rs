//! povins' Ouster decoder against the Ouster SDK (Python `ouster-sdk`, the independent
//! reference): the OS1-128 sample capture of shared/data decoded by both, every point compared.
//!
//! The same for the ROS 1 bag of raw `ouster_ros` packets (512x10, metadata in the bag).
//!
//! Run with `cargo test -p povins-platform --test ouster_sdk -- --ignored`. Python is a venv
//! made on first use (`target/pyenv-ouster`, `ouster-sdk` 1.0.1 from PyPI). A missing package or capture fails the test.

use povins_platform::ouster::{read_pcap, rosbag::read_bag, Metadata, OusterCapture};
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/fixtures/ouster")
}

/// Python with `ouster-sdk` (pinned), in its own venv `target/pyenv-ouster` made on first use by
/// `scripts/pyenv.sh` (it pins `rosbags` 0.9, which the rosbags tests' venv must not get), or
/// `$POVINS_OUSTER_PYTHON`.
fn python() -> String {
    if let Ok(p) = std::env::var("POVINS_OUSTER_PYTHON") {
        return p;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = Command::new("bash")
        .arg(root.join("scripts/pyenv.sh"))
        .arg(root.join("target/pyenv-ouster"))
        .arg("ouster.sdk.pcap, numpy")
        .arg("ouster-sdk==1.0.1")
        .output()
        .unwrap_or_else(|e| panic!("scripts/pyenv.sh: could not start bash: {e}"));
    assert!(
        out.status.success(),
        "scripts/pyenv.sh failed (needs PyPI for ouster-sdk): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

/// One reference point: frame id, column time, position (m, sensor frame).
struct RefPoint {
    frame_id: i64,
    t_ns: i64,
    p: [f64; 3],
}

fn read_points(path: &Path) -> Vec<RefPoint> {
    let b = std::fs::read(path).unwrap();
    assert_eq!(b.len() % 40, 0, "{}: not whole records", path.display());
    let i64_at = |o: usize| i64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    (0..b.len() / 40)
        .map(|k| {
            let o = 40 * k;
            RefPoint {
                frame_id: i64_at(o),
                t_ns: i64_at(o + 8),
                p: [f64_at(o + 16), f64_at(o + 24), f64_at(o + 32)],
            }
        })
        .collect()
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// Runs the reference script with `args` (the output folder appended) into a temporary folder.
fn reference(args: &[&Path]) -> tempfile::TempDir {
    for a in args.iter().filter(|a| a.extension().is_some()) {
        assert!(a.exists(), "missing {}", a.display());
    }
    let out = tempfile::tempdir().unwrap();
    run_script("ouster_reference.py", args, out.path());
    out
}

/// Runs `scripts/NAME` with the SDK's Python, `args` and then `out` as arguments; panics with
/// its standard error when it fails.
fn run_script(name: &str, args: &[&Path], out: &Path) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scripts")
        .join(name);
    let py = python();
    let run = Command::new(&py)
        .arg(&script)
        .args(args)
        .arg(out)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {py}: {e} "));
    assert!(
        run.status.success(),
        "{py} {} failed :\n{}",
        script.display(),
        String::from_utf8_lossy(&run.stderr)
    );
}

/// Asserts `ours` equals the reference in `out`: every point within 1 mm and at the same time,
/// every IMU packet's times equal and values within f32 rounding. Returns a summary.
fn compare(ours: &OusterCapture, out: &Path) -> String {
    assert_eq!(ours.bad_packets, 0, "{:?}", ours.first_error);
    let sweeps = csv_rows(&out.join("sweeps.csv"));
    let refs = read_points(&out.join("points.bin"));
    assert_eq!(ours.scans.len(), sweeps.len(), "sweeps: ours vs the SDK's");
    let (mut k, mut max_d, mut n_points) = (0usize, 0f64, 0usize);
    for (scan, row) in ours.scans.iter().zip(&sweeps) {
        let (frame_id, n): (i64, usize) = (row[0].parse().unwrap(), row[2].parse().unwrap());
        assert_eq!(scan.points.len(), n, "frame {frame_id}: points");
        assert_eq!(
            scan.t_ns,
            row[3].parse::<i64>().unwrap(),
            "frame {frame_id}: t_ns"
        );
        for p in &scan.points {
            let r = &refs[k];
            assert_eq!(r.frame_id, frame_id);
            assert_eq!(p.t_ns, r.t_ns, "frame {frame_id} point {k}: time");
            let d = (0..3)
                .map(|i| (f64::from(p.p_l[i]) - r.p[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            max_d = max_d.max(d);
            assert!(
                d < 1e-3,
                "frame {frame_id} point {k}: {:?} vs {:?}",
                p.p_l,
                r.p
            );
            k += 1;
        }
        n_points += n;
    }
    assert_eq!(k, refs.len());

    let imu = csv_rows(&out.join("imu.csv"));
    assert_eq!(ours.imu.len(), imu.len(), "IMU packets");
    let mut max_rel = 0f64;
    for (p, r) in ours.imu.iter().zip(&imu) {
        let t: Vec<i64> = r[..3].iter().map(|s| s.parse().unwrap()).collect();
        assert_eq!([p.sys_t_ns, p.accel_t_ns, p.gyro_t_ns], [t[0], t[1], t[2]]);
        let v: Vec<f64> = r[3..9].iter().map(|s| s.parse().unwrap()).collect();
        // The SDK gives f32 m/s^2 and rad/s; ours are f64 of the same f32 readings.
        for (a, b) in p.accel_mps2.iter().chain(&p.gyro_rps).zip(&v) {
            let rel = (a - b).abs() / b.abs().max(1e-3);
            max_rel = max_rel.max(rel);
            assert!(rel < 1e-6, "IMU {a} vs SDK {b}");
        }
    }
    format!(
        "{} sweeps, {n_points} points, max |dp| {max_d:.3e} m, times equal; {} IMU packets, \
         max relative difference {max_rel:.1e}; counts {:?}",
        sweeps.len(),
        imu.len(),
        ours.counts
    )
}

#[test]
#[ignore = "needs ../shared/data and the Python package ouster-sdk"]
fn pcap_sweeps_and_imu_equal_the_ouster_sdk() {
    let dir = fixtures();
    let capture = dir.join("OS-1-128_v2.3.0_1024x10_lb_n3.pcap");
    let meta_path = dir.join("OS-1-128_v2.3.0_1024x10.json");
    let out = reference(&[&capture, &meta_path]);
    let meta = Metadata::from_file(&meta_path).unwrap();
    let ours = read_pcap(&capture, &meta).unwrap();
    assert_eq!(
        (ours.scans.len(), ours.imu.len(), ours.counts.packets),
        (3, 30, 192)
    );
    eprintln!("ouster-sdk agreement, pcap: {}", compare(&ours, out.path()));
}

#[test]
#[ignore = "needs ../shared/data and the Python package ouster-sdk"]
fn bag_sweeps_and_imu_equal_the_ouster_sdk() {
    let bag = fixtures().join("512x10_raw.bag");
    let out = reference(&[Path::new("--bag"), &bag]);
    let (meta, ours) = read_bag(&bag).unwrap();
    assert_eq!(
        (meta.columns_per_frame, meta.prod_line.as_str()),
        (512, "OS-0-128")
    );
    assert_eq!(
        (ours.scans.len(), ours.imu.len(), ours.counts.packets),
        (1, 10, 32)
    );
    eprintln!("ouster-sdk agreement, bag: {}", compare(&ours, out.path()));
}

/// Firmware 3.1's `FUSA` packet header (8-bit packet type, 32-bit frame id): no such capture is
/// in shared/data, so the SDK writes one (`scripts/ouster_fusa_capture.py`: the fixture's sweeps
/// re-packetized in the FUSA format, frame ids 65535-65537 across 16 bits) and decodes it; ours
/// reads the same file with the metadata the SDK wrote.
#[test]
#[ignore = "needs ../shared/data and the Python package ouster-sdk"]
fn fusa_header_capture_equals_the_ouster_sdk() {
    use povins_platform::ouster::{Decoder, HeaderType, PcapUdp};
    let dir = fixtures();
    let gen = tempfile::tempdir().unwrap();
    let (pcap_in, meta_in) = (
        dir.join("OS-1-128_v2.3.0_1024x10_lb_n3.pcap"),
        dir.join("OS-1-128_v2.3.0_1024x10.json"),
    );
    run_script("ouster_fusa_capture.py", &[&pcap_in, &meta_in], gen.path());
    let (capture, meta_path) = (gen.path().join("fusa.pcap"), gen.path().join("fusa.json"));
    let out = reference(&[&capture, &meta_path]);
    let meta = Metadata::from_file(&meta_path).unwrap();
    assert_eq!(meta.header_type, HeaderType::Fusa);
    let ours = read_pcap(&capture, &meta).unwrap();
    assert_eq!(
        (ours.scans.len(), ours.imu.len(), ours.counts.packets),
        (3, 30, 192)
    );
    // The header's fields, packet by packet: the frame ids past 16 bits, the metadata's
    // serial number.
    let dec = Decoder::new(&meta);
    let mut frames = Vec::new();
    for d in PcapUdp::open(&capture).unwrap().ports(&[7502]) {
        let p = dec.decode_lidar(&d.unwrap().payload).unwrap();
        assert_eq!(p.prod_sn, Some(meta.prod_sn.parse().unwrap()));
        if frames.last() != Some(&p.frame_id) {
            frames.push(p.frame_id);
        }
    }
    assert_eq!(frames, [65_535, 65_536, 65_537]);
    eprintln!("ouster-sdk agreement, FUSA: {}", compare(&ours, out.path()));
}

//! `povins convert` and `povins simulate --format rosbag1`, through the binary:
//! - the repository's ROS 1 bag (written by Python `rosbags`) converted to EuRoC replays to the
//!   bag's trajectory byte for byte; an EuRoC folder converted gives back its streams;
//! - a simulated sequence written as a ROS 1 bag (plain and lz4) by our writer replays to the
//!   EuRoC folder's trajectory of the same simulation byte for byte, and so does the bag after
//!   `convert`;
//! - a non-empty `--out` is refused.

mod common;

use common::{povins, simulate_handheld};
use povins_platform::recording::Recording;
use std::path::Path;

const SIM_BAG: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/rosbag1-sim/sim.bag"
);
const EUROC: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/euroc-v101-30s-features"
);

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A calibration folder for `sim.bag`'s 64x48 images (EuRoC `sensor.yaml` files, a rotated
/// and shifted camera).
fn sim_bag_calibration(dir: &Path) {
    let imu = dir.join("mav0/imu0");
    let cam = dir.join("mav0/cam0");
    std::fs::create_dir_all(&imu).unwrap();
    std::fs::create_dir_all(&cam).unwrap();
    std::fs::write(imu.join("data.csv"), "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n").unwrap();
    std::fs::write(
        imu.join("sensor.yaml"),
        "rate_hz: 200\ngyroscope_noise_density: 1.6968e-04\ngyroscope_random_walk: 1.9393e-05\n\
         accelerometer_noise_density: 2.0000e-3\naccelerometer_random_walk: 3.0000e-3\n",
    )
    .unwrap();
    std::fs::write(
        cam.join("sensor.yaml"),
        "T_BS:\n  cols: 4\n  rows: 4\n  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,\n         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,\n         -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,\n         0.0, 0.0, 0.0, 1.0]\n\
         rate_hz: 20\nresolution: [64, 48]\ncamera_model: pinhole\nintrinsics: [39.9, 40.1, 31.7, 23.6]\n\
         distortion_model: radial-tangential\ndistortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]\n",
    )
    .unwrap();
}

fn run(recording: &[&str], out: &Path) -> Vec<u8> {
    let mut args = vec!["run"];
    args.extend_from_slice(recording);
    // 2 s recordings, half of them the rest before the start: partial by design.
    args.extend_from_slice(&["--allow-partial", "--out", s(out)]);
    let (ok, _, err) = povins(&args);
    assert!(ok, "povins {args:?} failed: {err}");
    std::fs::read(out.join("trajectory.tum")).expect("trajectory.tum")
}

#[test]
fn a_converted_bag_replays_to_the_bags_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let calib = dir.path().join("calib");
    sim_bag_calibration(&calib);
    let euroc = dir.path().join("euroc");
    let bag_args = [
        SIM_BAG,
        "--calib",
        s(&calib),
        "--image-topic",
        "/cam0/image_raw",
    ];
    let mut args = vec!["convert"];
    args.extend_from_slice(&bag_args);
    args.extend_from_slice(&["--out", s(&euroc)]);
    let (ok, out, err) = povins(&args);
    assert!(ok, "convert failed: {err}");
    assert!(out.contains("401 IMU samples, 14 images"), "{out}");
    let pngs = std::fs::read_dir(euroc.join("mav0/cam0/data"))
        .unwrap()
        .count();
    assert_eq!(pngs, 14);
    let a = run(&bag_args, &dir.path().join("run-bag"));
    let b = run(&[s(&euroc)], &dir.path().join("run-euroc"));
    assert!(a.len() > 10_000, "trajectory too short: {} bytes", a.len());
    assert!(
        a == b,
        "the converted folder's trajectory differs from the bag's"
    );

    // A non-empty --out is refused, naming it; nothing is written into it.
    args.truncate(args.len() - 1);
    args.push(s(&calib));
    let (ok, _, err) = povins(&args);
    assert!(!ok, "convert into a non-empty folder succeeded");
    assert!(err.contains("not empty") && err.contains("calib"), "{err}");
    assert!(!calib.join("mav0/cam0/data").exists());
}

#[test]
fn a_converted_euroc_folder_gives_back_its_streams() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("copy");
    let (ok, stdout, err) = povins(&["convert", EUROC, "--out", s(&out)]);
    assert!(ok, "convert failed: {err}");
    assert!(stdout.contains("feature frames") && stdout.contains("ground-truth states"));
    let a = povins_platform::read_dataset(Path::new(EUROC)).unwrap();
    let b = povins_platform::read_dataset(&out).unwrap();
    assert_eq!(a.imu, b.imu);
    assert_eq!(a.features, b.features);
    assert_eq!(a.calib.camera, b.calib.camera);
    assert_eq!(a.ground_truth.len(), b.ground_truth.len());
    for (x, y) in a.ground_truth.iter().zip(&b.ground_truth) {
        assert_eq!((x.t_ns, x.p_wb, x.v_wb), (y.t_ns, y.p_wb, y.v_wb));
        assert!(x.q_wb.angle_to(&y.q_wb) < 1e-12);
    }
    let rec = povins_platform::euroc::EurocFolder::open(&out).unwrap();
    assert!(rec.contents().ground_truth && rec.contents().frames);
}

/// The simulator's sequence as an EuRoC folder and as ROS 1 bags (plain, lz4): the same
/// trajectory byte for byte from each, and from the bag after `convert`.
#[test]
fn a_simulated_bag_replays_to_the_euroc_folders_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let sim = |format: &str, out: &Path, extra: &[&str]| {
        let mut args = vec!["--lidar", "none"];
        args.extend_from_slice(extra);
        simulate_handheld(format, out, "4", &args);
    };
    let euroc = dir.path().join("euroc");
    sim("euroc", &euroc, &[]);
    let want = run(&[s(&euroc)], &dir.path().join("run-euroc"));
    assert!(
        want.len() > 20_000,
        "trajectory too short: {} bytes",
        want.len()
    );
    for compression in ["none", "lz4"] {
        let bag = dir.path().join(format!("sim-{compression}.bag"));
        sim("rosbag1", &bag, &["--compression", compression]);
        let calib = dir.path().join(format!("sim-{compression}-calib"));
        assert!(calib.join("mav0/cam0/sensor.yaml").is_file());
        let got = run(
            &[s(&bag), "--calib", s(&euroc)],
            &dir.path().join(format!("run-{compression}")),
        );
        assert!(
            got == want,
            "{compression} bag: trajectory differs from the folder's"
        );
        let got = run(
            &[s(&bag), "--calib", s(&calib)],
            &dir.path().join(format!("run-{compression}-own-calib")),
        );
        assert!(
            got == want,
            "{compression} bag with the calibration beside it"
        );
    }
    let converted = dir.path().join("converted");
    let bag = dir.path().join("sim-lz4.bag");
    let (ok, _, err) = povins(&[
        "convert",
        s(&bag),
        "--calib",
        s(&euroc),
        "--out",
        s(&converted),
    ]);
    assert!(ok, "convert failed: {err}");
    let got = run(&[s(&converted)], &dir.path().join("run-converted"));
    assert!(got == want, "the converted bag's trajectory differs");
}

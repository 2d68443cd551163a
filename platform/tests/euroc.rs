//! EuRoC folders: every shared dataset, the write/read round trip, and corrupt input.

mod common;

use common::{assert_same, shared, synthetic};
use povins_core::camera::Distortion;
use povins_platform::euroc::{read_dataset, read_images, write_dataset};
use povins_platform::IoError;
use std::path::Path;

#[test]
fn reads_euroc_v101_30s_features() {
    let ds = read_dataset(&shared("euroc-v101-30s-features")).unwrap();
    assert_eq!(ds.name, "euroc-v101-30s-features");
    assert_eq!(ds.imu.len(), 6021);
    assert_eq!(ds.features.len(), 601);
    assert_eq!(
        ds.features.iter().map(|f| f.obs.len()).sum::<usize>(),
        13316
    );
    let counts: Vec<usize> = ds.features.iter().map(|f| f.obs.len()).collect();
    assert_eq!(counts.iter().min(), Some(&12));
    assert_eq!(counts.iter().max(), Some(&38));
    assert_eq!(ds.ground_truth.len(), 603);
    assert!(ds.images.is_empty() && ds.lidar.is_empty() && ds.calib.t_bl.is_none());
    // First rows of the files, exactly.
    let s = &ds.imu[0];
    assert_eq!(s.t_ns, 1_403_715_273_262_142_976);
    assert_eq!(s.gyro_rps.x, -0.0020943951023931952);
    // The file's text, parsed the way Rust parses it (more digits than an f64 holds).
    assert_eq!(
        s.accel_mps2.z,
        "-3.6938381666666662".parse::<f64>().unwrap()
    );
    let o = &ds.features[0].obs[1];
    assert_eq!((o.id, o.u_px, o.v_px), (2, 519.0212, 442.0211));
    assert_eq!(ds.features[600].t_ns, 1_403_715_303_262_142_976);
    // Calibration.
    let c = &ds.calib;
    assert_eq!((c.camera.width, c.camera.height), (752, 480));
    assert_eq!((c.camera.fx, c.camera.cy), (458.654, 248.375));
    assert_eq!(
        c.camera.distortion,
        Distortion::RadTan {
            k1: -0.28340811,
            k2: 0.07395907,
            p1: 0.00019359,
            p2: 1.76187114e-05
        }
    );
    assert_eq!(c.t_bc.p_ab.x, -0.0216401454975);
    assert_eq!(c.t_bc.p_ab.z, 0.00981073058949);
    // R_bc column 2 (camera z axis in the body) is the third column of T_BS.
    let r = c.t_bc.q_ab.to_rotation_matrix();
    assert!((r[(0, 2)] - 0.00414029679422).abs() < 1e-9);
    assert!((r[(2, 2)] - 0.999660727178).abs() < 1e-9);
    assert_eq!(c.imu_noise.gyro_noise_density, 1.6968e-04);
    assert_eq!(c.imu_noise.accel_bias_rw, 3.0e-3);
    assert_eq!(c.imu_noise.bias_corr_time_s, None);
    assert_eq!(
        (c.imu_rate_hz, c.camera_rate_hz, c.td_s),
        (200.0, 20.0, 0.0)
    );
    assert_eq!(c.gravity_mps2, 9.81);
}

#[test]
#[ignore = "needs ../shared/data/euroc-v101-images-at-rest (large shared sequence; CI runs it with --ignored)"]
fn reads_euroc_v101_images_at_rest_and_decodes_pngs() {
    let mut ds = read_dataset(&shared("euroc-v101-images-at-rest/mav0")).unwrap();
    assert_eq!(ds.name, "euroc-v101-images-at-rest");
    assert_eq!(ds.imu.len(), 29120);
    assert_eq!(ds.ground_truth.len(), 2895);
    assert_eq!(ds.images.len(), 95);
    assert!(ds.features.is_empty());
    assert!(ds
        .images
        .iter()
        .all(|i| i.mono8.is_empty() && i.path.is_some()));
    assert_eq!(ds.images[1].t_ns, 1_403_715_273_312_143_104);
    read_images(&mut ds).unwrap();
    for im in &ds.images {
        assert_eq!((im.width, im.height, im.mono8.len()), (752, 480, 752 * 480));
    }
    // A real image: not constant, with a plausible mean brightness.
    let px = &ds.images[0].mono8;
    let mean = px.iter().map(|&p| p as f64).sum::<f64>() / px.len() as f64;
    let (lo, hi) = (px.iter().min().unwrap(), px.iter().max().unwrap());
    assert!(
        mean > 20.0 && mean < 235.0 && hi - lo > 100,
        "{mean} {lo} {hi}"
    );
}

#[test]
#[ignore = "needs ../shared/data/openvins-sim-corridor-mono (large shared sequence; CI runs it with --ignored)"]
fn reads_openvins_sim_corridor_mono() {
    let ds = read_dataset(&shared("openvins-sim-corridor-mono")).unwrap();
    assert_eq!(ds.imu.len(), 116_881);
    assert_eq!(ds.features.len(), 2922);
    assert_eq!(
        ds.features.iter().map(|f| f.obs.len()).sum::<usize>(),
        730_412
    );
    assert!(ds.features.iter().all(|f| f.obs.len() <= 250));
    assert_eq!(ds.ground_truth.len(), 29_221);
    assert_eq!(ds.calib.gravity_mps2, 9.81);
    assert_eq!(ds.calib.imu_rate_hz, 400.0);
    assert_eq!(ds.calib.camera_rate_hz, 10.0);
    assert_eq!(ds.imu[1].accel_mps2.z, 1.331488342e+01);
    let o = ds.features[0].obs[0];
    assert_eq!((o.id, o.u_px, o.v_px), (6734, 602.789429, 476.589264));
}

#[test]
fn synthetic_dataset_round_trips_through_a_folder() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("synthetic-seq");
    let mut ds = synthetic("synthetic-seq");
    ds.sim_truth = None; // not stored in folders
    write_dataset(&root, &ds).unwrap();
    let mut back = read_dataset(&root).unwrap();
    assert!(back.images.iter().all(|i| i.mono8.is_empty()));
    read_images(&mut back).unwrap();
    assert_same(&ds, &back, 1e-15, 0.0);

    // A rolling shutter's readout travels in `cam0/sensor.yaml` (absent for a global shutter);
    // one out of range is an error naming the file's line.
    let yaml = |r: &std::path::Path| std::fs::read_to_string(r.join("mav0/cam0/sensor.yaml"));
    assert!(!yaml(&root).unwrap().contains("readout_s"));
    let mut rs = synthetic("rs");
    rs.sim_truth = None;
    rs.calib.camera.readout_s = 0.025;
    let rs_root = dir.path().join("rs");
    write_dataset(&rs_root, &rs).unwrap();
    assert_eq!(
        read_dataset(&rs_root).unwrap().calib.camera.readout_s,
        0.025
    );
    let bad = yaml(&rs_root)
        .unwrap()
        .replace("readout_s: 0.025", "readout_s: 25.0");
    std::fs::write(rs_root.join("mav0/cam0/sensor.yaml"), bad).unwrap();
    let e = read_dataset(&rs_root).unwrap_err().to_string();
    assert!(
        e.contains("sensor.yaml") && e.contains("readout_s 25"),
        "{e}"
    );

    // The LiDAR's time offset travels in `lidar0/sensor.yaml` (`timeshift_lidar_imu`, the
    // synthetic dataset's -4.2 ms, compared by `assert_same`); one out of range is an error
    // naming the file's line.
    let lidar_yaml = root.join("mav0/lidar0/sensor.yaml");
    let y = std::fs::read_to_string(&lidar_yaml).unwrap();
    assert!(y.contains("timeshift_lidar_imu: -0.0042"), "{y}");
    let far = dir.path().join("far");
    write_dataset(&far, &ds).unwrap();
    let far_yaml = far.join("mav0/lidar0/sensor.yaml");
    std::fs::write(&far_yaml, y.replace("-0.0042", "-4.2")).unwrap();
    let e = read_dataset(&far).unwrap_err().to_string();
    assert!(
        e.contains("lidar0/sensor.yaml") && e.contains("timeshift_lidar_imu -4.2"),
        "{e}"
    );

    // A dataset without a camera (a LiDAR-inertial recording: the zero-size placeholder) is
    // written without cam0, and reads back as one without a camera.
    let mut li = synthetic("li");
    li.sim_truth = None;
    li.calib.camera = povins_platform::dataset::no_camera();
    li.images.clear();
    li.features.clear();
    let li_root = dir.path().join("li");
    write_dataset(&li_root, &li).unwrap();
    assert!(!li_root.join("mav0/cam0").exists(), "no cam0 folder");
    assert_eq!(read_dataset(&li_root).unwrap().calib.camera.width, 0);

    // Writing what was read (images referenced by path only) copies the PNGs.
    let mut listed = read_dataset(&root).unwrap();
    let copy = dir.path().join("copy").join("synthetic-seq");
    write_dataset(&copy, &listed).unwrap();
    let mut back2 = read_dataset(&copy).unwrap();
    read_images(&mut back2).unwrap();
    read_images(&mut listed).unwrap();
    assert_eq!(back2.images, {
        let mut v = listed.images.clone();
        for (a, b) in v.iter_mut().zip(&back2.images) {
            a.path = b.path.clone();
        }
        v
    });
}

#[test]
fn real_folder_round_trips() {
    let ds = read_dataset(&shared("euroc-v101-30s-features")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("euroc-v101-30s-features");
    write_dataset(&root, &ds).unwrap();
    let back = read_dataset(&root).unwrap();
    assert_same(&ds, &back, 1e-15, 0.0);
}

/// Writes a good folder, overwrites one file with `text`, and expects a parse error at `line`
/// whose message contains `msg`.
fn expect_parse_error(rel: &str, text: &str, line: usize, msg: &str) {
    let dir = tempfile::tempdir().unwrap();
    let mut ds = synthetic("x");
    ds.sim_truth = None;
    write_dataset(dir.path(), &ds).unwrap();
    let file = dir.path().join("mav0").join(rel);
    std::fs::write(&file, text).unwrap();
    match read_dataset(dir.path()) {
        Err(IoError::Parse {
            path,
            line: l,
            msg: m,
        }) => {
            assert_eq!(path, file, "{rel}");
            assert_eq!(l, line, "{rel}: {m}");
            assert!(m.contains(msg), "{rel}: {m:?} lacks {msg:?}");
        }
        other => panic!("{rel}: expected a parse error, got {other:?}"),
    }
}

const IMU_HEAD: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n";

#[test]
fn corrupt_imu_csv_reports_the_line() {
    let ok = "1000,0.1,0.2,0.3,0.0,0.0,9.8\n";
    let cases = [
        // Truncated line.
        (
            format!("{IMU_HEAD}{ok}2000,0.1,0.2\n"),
            3,
            "expected 7 fields, found 3",
        ),
        // Non-numeric field.
        (
            format!("{IMU_HEAD}{ok}2000,0.1,abc,0.3,0,0,9.8\n"),
            3,
            "field 3 (\"abc\")",
        ),
        // Non-finite value.
        (
            format!("{IMU_HEAD}{ok}2000,0.1,NaN,0.3,0,0,9.8\n"),
            3,
            "not a finite number",
        ),
        // Time going backwards, then repeating.
        (
            format!("{IMU_HEAD}{ok}999,0.1,0.2,0.3,0,0,9.8\n"),
            3,
            "does not increase",
        ),
        (format!("{IMU_HEAD}{ok}{ok}"), 3, "does not increase"),
        // Fractional timestamp.
        (
            format!("{IMU_HEAD}1000.5,0.1,0.2,0.3,0,0,9.8\n"),
            2,
            "integer nanoseconds",
        ),
        // A comment inside the data and a blank line inside the data.
        (format!("{IMU_HEAD}{ok}# note\n"), 3, "only line 1"),
        (
            format!("{IMU_HEAD}{ok}\n2000,0,0,0,0,0,9.8\n"),
            3,
            "blank line",
        ),
        // Wrong file (a 4-column header).
        (
            format!("#timestamp [ns],feature_id,u [px],v [px]\n{ok}"),
            1,
            "header has 4 columns",
        ),
    ];
    for (text, line, msg) in cases {
        expect_parse_error("imu0/data.csv", &text, line, msg);
    }
    // Trailing blank lines are fine.
    let dir = tempfile::tempdir().unwrap();
    let mut ds = synthetic("x");
    ds.sim_truth = None;
    write_dataset(dir.path(), &ds).unwrap();
    std::fs::write(
        dir.path().join("mav0/imu0/data.csv"),
        format!("{IMU_HEAD}{ok}\n\n"),
    )
    .unwrap();
    assert_eq!(read_dataset(dir.path()).unwrap().imu.len(), 1);
}

#[test]
fn corrupt_features_and_images_report_the_line() {
    let head = "#timestamp [ns],feature_id,u [px],v [px]\n";
    let cases = [
        (
            format!("{head}10,1,2.0,3.0\n10,2,2.0\n"),
            3,
            "expected 4 fields",
        ),
        (
            format!("{head}10,1,2.0,3.0\n10,-2,2.0,3.0\n"),
            3,
            "unsigned integer",
        ),
        (
            format!("{head}10,1,2.0,3.0\n20,1,2.0,3.0\n15,1,2.0,3.0\n"),
            4,
            "does not increase",
        ),
        (format!("{head}10,1,2.0,3.0\n10,1,4.0,3.0\n"), 3, "repeated"),
        (format!("{head}10,1,2.0,x\n"), 2, "field 4"),
    ];
    for (text, line, msg) in cases {
        expect_parse_error("features0/data.csv", &text, line, msg);
    }
    expect_parse_error(
        "cam0/data.csv",
        "#timestamp [ns],filename\n10,a.png\n10,b.png\n",
        3,
        "does not increase",
    );
    expect_parse_error(
        "lidar0/data.csv",
        "#timestamp [ns],point_timestamp [ns],x [m],y [m],z [m],intensity\n10,11,1,2,3\n",
        2,
        "expected 6 fields",
    );
}

#[test]
fn bad_yaml_reports_the_line() {
    let cam = |intr: &str, model: &str| {
        format!(
            "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0,\n         0.0, 1.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n         0.0, 0.0, 0.0, 1.0]\nrate_hz: 20\nresolution: [752, 480]\nintrinsics: {intr}\ndistortion_model: {model}\ndistortion_coefficients: [0.1, 0.0, 0.0, 0.0]\n"
        )
    };
    // Sanity: the template itself is valid with a known model.
    let dir = tempfile::tempdir().unwrap();
    let mut ds = synthetic("x");
    ds.sim_truth = None;
    write_dataset(dir.path(), &ds).unwrap();
    std::fs::write(
        dir.path().join("mav0/cam0/sensor.yaml"),
        cam("[1.0, 2.0, 3.0, 4.0]", "radial-tangential"),
    )
    .unwrap();
    let back = read_dataset(dir.path()).unwrap();
    assert_eq!(back.calib.camera.fx, 1.0);

    expect_parse_error(
        "cam0/sensor.yaml",
        &cam("[1.0, 2.0, 3.0]", "equidistant"),
        12,
        "needs 4 values",
    );
    expect_parse_error(
        "cam0/sensor.yaml",
        &cam("[1.0, 2.0, 3.0, fu]", "equidistant"),
        12,
        "\"fu\"",
    );
    expect_parse_error(
        "cam0/sensor.yaml",
        &cam("[1.0, 2.0, 3.0, 4.0", "equidistant"),
        13,
        "missing comma",
    );
    let open_list = format!(
        "{}intrinsics: [1.0, 2.0,\n   3.0\n",
        cam("[1.0, 2.0, 3.0, 4.0]", "none").replace("intrinsics: [1.0, 2.0, 3.0, 4.0]\n", "")
    );
    expect_parse_error("cam0/sensor.yaml", &open_list, 14, "unterminated");
    expect_parse_error(
        "cam0/sensor.yaml",
        &cam("[1.0, 2.0, 3.0, 4.0]", "kannala"),
        13,
        "unsupported",
    );
    let rotated =
        cam("[1.0, 2.0, 3.0, 4.0]", "none").replace("0.0, 1.0, 0.0, 0.0,", "0.0, 2.0, 0.0, 0.0,");
    expect_parse_error("cam0/sensor.yaml", &rotated, 3, "not a rotation");
    expect_parse_error(
        "imu0/sensor.yaml",
        "%YAML:1.0\nrate_hz: 200\ngyroscope_noise_density: 1e-4\ngyroscope_random_walk: 1e-5\naccelerometer_noise_density: 2e-3\n",
        5,
        "accelerometer_random_walk",
    );
    expect_parse_error(
        "imu0/sensor.yaml",
        "rate_hz 200\n",
        1,
        "expected `key: value`",
    );
}

#[test]
fn missing_imu_is_an_error_and_missing_optional_sensors_are_empty() {
    let dir = tempfile::tempdir().unwrap();
    let mut ds = synthetic("x");
    ds.sim_truth = None;
    write_dataset(dir.path(), &ds).unwrap();
    let mav0 = dir.path().join("mav0");
    for sub in ["features0", "lidar0", "state_groundtruth_estimate0"] {
        std::fs::remove_dir_all(mav0.join(sub)).unwrap();
    }
    std::fs::remove_file(mav0.join("cam0/data.csv")).unwrap();
    let back = read_dataset(dir.path()).unwrap();
    assert!(back.features.is_empty() && back.lidar.is_empty() && back.images.is_empty());
    assert!(back.ground_truth.is_empty() && back.calib.t_bl.is_none());
    assert_eq!(back.imu.len(), 100);
    std::fs::remove_file(mav0.join("imu0/data.csv")).unwrap();
    match read_dataset(dir.path()) {
        Err(IoError::Invalid { msg, .. }) => assert!(msg.contains("imu0"), "{msg}"),
        other => panic!("{other:?}"),
    }
    assert!(read_dataset(Path::new("/nonexistent/povins")).is_err());
}

#[test]
fn extrinsics_are_re_expressed_in_the_imu_frame() {
    let dir = tempfile::tempdir().unwrap();
    let mut ds = synthetic("x");
    ds.sim_truth = None;
    write_dataset(dir.path(), &ds).unwrap();
    // IMU rotated +90 deg about z and offset in EuRoC's body frame B: T_B_imu.
    let yaml = dir.path().join("mav0/imu0/sensor.yaml");
    let text = std::fs::read_to_string(&yaml).unwrap();
    let start = text.find("T_BS:").unwrap();
    let end = text.find("rate_hz").unwrap();
    let t_b_imu = "T_BS:\n  cols: 4\n  rows: 4\n  data: [0.0, -1.0, 0.0, 0.5,\n         1.0, 0.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n         0.0, 0.0, 0.0, 1.0]\n";
    std::fs::write(
        &yaml,
        format!("{}{t_b_imu}{}", &text[..start], &text[end..]),
    )
    .unwrap();
    let back = read_dataset(dir.path()).unwrap();
    // p_imu_cam = R_B_imu^T (p_B_cam - p_B_imu): rotating by -90 deg maps (x, y) -> (y, -x).
    let p = ds.calib.t_bc.p_ab;
    let q = back.calib.t_bc.p_ab;
    assert!((q.x - p.y).abs() < 1e-15 && (q.y + (p.x - 0.5)).abs() < 1e-15 && q.z == p.z);
    let r_imu_cam = back.calib.t_bc.q_ab.to_rotation_matrix();
    let r_b_cam = ds.calib.t_bc.q_ab.to_rotation_matrix();
    let r_b_imu = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Vector3::z_axis(),
        std::f64::consts::FRAC_PI_2,
    );
    assert!((r_b_imu * r_imu_cam)
        .matrix()
        .relative_eq(r_b_cam.matrix(), 1e-12, 1e-12));
}

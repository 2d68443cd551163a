use super::*;
use crate::recording::Recording;
use std::path::PathBuf;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data")
        .join(name)
}

const P: &str = "x.yaml";

/// A complete camera in block lists (as Kalibr writes `T_cam_imu`), identity extrinsic.
const CAM_BLOCK: &str = "\
cam0:
  camera_model: pinhole
  intrinsics:
  - 400.0
  - 401.0
  - 320.0
  - 240.0
  distortion_model: equidistant
  distortion_coeffs:
  - 0.1
  - -0.01
  - 0.001
  - 0.0
  T_cam_imu:
  - - 1.0
    - 0.0
    - 0.0
    - 0.5
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  timeshift_cam_imu: 0.002
  rostopic: /camera/image
  resolution:
  - 640
  - 480
";

const IMU: &str = "\
accelerometer_noise_density: 0.01
accelerometer_random_walk: 0.0002
gyroscope_noise_density: 0.005
gyroscope_random_walk: 4.0e-06
rostopic: /imu
update_rate: 200
";

fn cam_err(text: &str, camera: &str) -> String {
    match camchain_from_str(Path::new(P), text, camera) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => e.to_string(),
    }
}

fn imu_err(text: &str) -> String {
    match imu_from_str(Path::new(P), text) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn block_lists_read_like_flow_lists() {
    let c = camchain_from_str(Path::new(P), CAM_BLOCK, "cam0").expect("block lists");
    assert_eq!((c.camera.width, c.camera.height), (640, 480));
    assert_eq!(
        (c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy),
        (400.0, 401.0, 320.0, 240.0)
    );
    assert_eq!(
        c.camera.distortion,
        Distortion::Equidistant {
            k: [0.1, -0.01, 0.001, 0.0]
        }
    );
    // T_cam_imu puts the IMU origin at x = 0.5 in the camera: the camera is at -0.5 in the IMU.
    assert_eq!(c.t_bc.p_ab, Vec3::new(-0.5, 0.0, 0.0));
    assert_eq!(c.t_bc.q_ab, UnitQuaternion::identity());
    assert_eq!(c.td_s, 0.002);
    assert_eq!(c.rate_hz, 0.0);
    assert_eq!(c.rostopic.as_deref(), Some("/camera/image"));
    let flow = "cam0: {camera_model: pinhole, intrinsics: [400.0, 401.0, 320.0, 240.0], \
                distortion_model: equidistant, distortion_coeffs: [0.1, -0.01, 0.001, 0.0], \
                T_cam_imu: [[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], \
                [0.0, 0.0, 0.0, 1.0]], timeshift_cam_imu: 0.002, rostopic: /camera/image, \
                resolution: [640, 480]}";
    assert_eq!(
        camchain_from_str(Path::new(P), flow, "cam0").expect("flow"),
        c
    );
}

#[test]
fn the_wiki_layout_reads_and_other_models_are_refused() {
    let path = data("kalibr/wiki-camchain-imucam.yaml");
    let c = read_camchain(&path, "cam0").expect("cam0");
    assert_eq!(c.camera.fx, 461.629);
    assert_eq!(
        c.camera.distortion,
        Distortion::RadTan {
            k1: -0.27695497,
            k2: 0.06712482,
            p1: 0.00087538,
            p2: 0.00011556
        }
    );
    assert_eq!(c.td_s, -8.121e-05);
    // T_bc is the inverse: R_bc = R_cb^T (within the 8 printed digits), p_bc = -R_bc p_cb.
    let r_bc = c.t_bc.q_ab.to_rotation_matrix();
    assert!((r_bc[(0, 1)] - -0.9998017).abs() < 1e-6, "{r_bc}");
    assert!((r_bc[(1, 0)] - 0.99967549).abs() < 1e-6, "{r_bc}");
    let p_cb = Vec3::new(0.07008565, -0.01771023, 0.00399246);
    assert!(
        (c.t_bc.p_ab + r_bc * p_cb).norm() < 1e-6,
        "{:?}",
        c.t_bc.p_ab
    );
    let e = read_camchain(&path, "cam1").expect_err("omni");
    let e = e.to_string();
    assert!(
        e.contains("wiki-camchain-imucam.yaml") && e.contains("`cam1.camera_model`"),
        "{e}"
    );
    assert!(e.contains("\"omni\""), "{e}");
    let e = read_camchain(&path, "cam2")
        .expect_err("no cam2")
        .to_string();
    assert!(
        e.contains("no camera `cam2` (the file has: cam0, cam1)"),
        "{e}"
    );
    let imu = read_imu(&data("kalibr/wiki-imu.yaml")).expect("imu");
    assert_eq!(imu.noise.accel_noise_density, 1.86e-03);
    assert_eq!(imu.noise.gyro_bias_rw, 2.66e-05);
    assert_eq!((imu.rate_hz, imu.gravity_mps2), (200.0, 9.81));
    assert_eq!(imu.rostopic.as_deref(), Some("/imu0"));
}

#[test]
fn imu_keys_nested_under_imu0_read_alike() {
    let top = imu_from_str(Path::new(P), IMU).expect("top level");
    let nested: String = IMU.lines().map(|l| format!("  {l}\n")).collect();
    let nested = format!("imu0:\n{nested}  model: calibrated\n  time_offset: 0.0\n");
    assert_eq!(imu_from_str(Path::new(P), &nested).expect("nested"), top);
    assert_eq!(top.noise.gyro_noise_density, 0.005);
    assert_eq!(top.noise.bias_corr_time_s, None);
    assert_eq!(top.rate_hz, 200.0);
}

#[test]
fn each_missing_key_is_named_with_where_it_was_looked_for() {
    for key in [
        "camera_model",
        "intrinsics",
        "distortion_model",
        "T_cam_imu",
        "resolution",
    ] {
        let text = drop_key(CAM_BLOCK, key);
        let e = cam_err(&text, "cam0");
        assert!(
            e.starts_with("x.yaml: ")
                && e.contains(&format!("missing key `{key}` (looked for under `cam0:`)")),
            "{key}: {e}"
        );
    }
    // Optional: the time shift and the topic.
    for key in ["timeshift_cam_imu", "rostopic"] {
        camchain_from_str(Path::new(P), &drop_key(CAM_BLOCK, key), "cam0").expect(key);
    }
    for key in [
        "accelerometer_noise_density",
        "accelerometer_random_walk",
        "gyroscope_noise_density",
        "gyroscope_random_walk",
        "update_rate",
    ] {
        let e = imu_err(&drop_key(IMU, key));
        assert!(
            e.contains(&format!(
                "missing key `{key}` (looked for at the top level or under `imu0:`)"
            )),
            "{key}: {e}"
        );
        let nested = format!("imu0:\n  {}", drop_key(IMU, key).replace('\n', "\n  "));
        let e = imu_err(&nested);
        assert!(
            e.contains(&format!("missing key `{key}` (looked for under `imu0:`)")),
            "{key}: {e}"
        );
    }
}

/// `text` without the line of `key` and its indented continuation lines.
fn drop_key(text: &str, key: &str) -> String {
    let mut out = String::new();
    let mut skipping = None;
    for l in text.lines() {
        let indent = l.len() - l.trim_start().len();
        if let Some(i) = skipping {
            if indent > i || (indent == i && l.trim_start().starts_with('-')) {
                continue;
            }
            skipping = None;
        }
        if l.trim_start().starts_with(&format!("{key}:")) {
            skipping = Some(indent);
            continue;
        }
        out.push_str(l);
        out.push('\n');
    }
    assert_ne!(out, text, "{key} not in the text");
    out
}

#[test]
fn bad_values_are_refused_naming_the_key() {
    let cases = [
        (
            "distortion_model: equidistant",
            "distortion_model: fov",
            "`cam0.distortion_model`: \"fov\" is not supported",
        ),
        (
            "- 0.001\n  - 0.0\n",
            "- 0.001\n",
            "`cam0.distortion_coeffs`: 3 values; equidistant needs 4",
        ),
        ("  - 400.0\n", "", "`cam0.intrinsics`: 3 values"),
        (
            "- 640\n",
            "- 640.5\n",
            "`cam0.resolution`: [640.5, 480.0] is not two positive integers",
        ),
        (
            "[0.0, 0.0, 0.0, 1.0]",
            "[0.0, 0.0, 0.1, 1.0]",
            "`cam0.T_cam_imu`: not rigid: the last row",
        ),
        (
            "[0.0, 1.0, 0.0, 0.0]",
            "[0.0, 2.0, 0.0, 0.0]",
            "`cam0.T_cam_imu`: not rigid: the rotation is not a rotation",
        ),
        (
            "[0.0, 0.0, 1.0, 0.0]",
            "[0.0, 0.0, -1.0, 0.0]",
            "`cam0.T_cam_imu`: not rigid",
        ),
        (
            "[0.0, 0.0, 1.0, 0.0]",
            "[0.0, 0.0, 1.0]",
            "`cam0.T_cam_imu`: expected 4 rows of 4 numbers",
        ),
    ];
    for (from, to, want) in cases {
        assert!(CAM_BLOCK.contains(from), "{from}");
        let e = cam_err(&CAM_BLOCK.replacen(from, to, 1), "cam0");
        assert!(e.starts_with("x.yaml: ") && e.contains(want), "{want}: {e}");
    }
    let e = cam_err("cam0: [1, 2]", "cam0");
    assert!(e.starts_with("x.yaml:1: not a Kalibr camchain"), "{e}");
    let e = cam_err("cam0:\n  intrinsics: fast\n", "cam0");
    assert!(e.starts_with("x.yaml:2: not a Kalibr camchain"), "{e}");
    let e = imu_err(&IMU.replace("0.005", "-0.005"));
    assert!(
        e.contains("`gyroscope_noise_density`: -0.005 is not a non-negative"),
        "{e}"
    );
    let e = imu_err(&IMU.replace("update_rate: 200", "update_rate: 0"));
    assert!(e.contains("`update_rate` must be positive"), "{e}");
}

#[test]
fn euroc_transcribed_to_kalibr_gives_the_euroc_calibration() {
    // tests/data/kalibr/euroc-v101-*.yaml: EuRoC V1_01's own cam0/imu0 sensor.yaml, inverted
    // and written by PyYAML (scripts/make_rosbag1_fixture.py --kalibr ... --nested).
    let euroc = crate::euroc::EurocFolder::open(&data("euroc-v101-30s-features"))
        .expect("EuRoC folder")
        .calibration()
        .clone();
    let k = read(
        &data("kalibr/euroc-v101-camchain-imucam.yaml"),
        &data("kalibr/euroc-v101-imu.yaml"),
        "cam0",
    )
    .expect("Kalibr files");
    let c = &k.calib;
    assert_eq!(c.camera, euroc.camera);
    assert_eq!(
        (c.td_s, c.camera_rate_hz),
        (euroc.td_s, euroc.camera_rate_hz)
    );
    assert_eq!(c.imu_noise, euroc.imu_noise);
    assert_eq!(
        (c.imu_rate_hz, c.gravity_mps2),
        (euroc.imu_rate_hz, euroc.gravity_mps2)
    );
    assert_eq!(c.t_bl, None);
    assert!(
        c.t_bc.q_ab.angle_to(&euroc.t_bc.q_ab) < 1e-12,
        "{:?}",
        c.t_bc
    );
    assert!(
        (c.t_bc.p_ab - euroc.t_bc.p_ab).amax() < 1e-12,
        "{:?}",
        c.t_bc
    );
    // The expected numbers, from EuRoC's T_BS.
    assert_eq!(
        euroc.t_bc.p_ab,
        Vec3::new(-0.0216401454975, -0.064676986768, 0.00981073058949)
    );
    assert_eq!(k.image_topic.as_deref(), Some("/cam0/image_raw"));
    assert_eq!(k.imu_topic.as_deref(), Some("/imu0"));
}

#[test]
fn written_files_read_back() {
    let euroc = crate::euroc::EurocFolder::open(&data("euroc-v101-30s-features"))
        .expect("EuRoC folder")
        .calibration()
        .clone();
    let mut variants = vec![euroc.clone()];
    let mut c = euroc.clone();
    c.camera.distortion = Distortion::Equidistant {
        k: [0.1, -0.02, 0.003, -4e-4],
    };
    c.td_s = -1.25e-3;
    c.gravity_mps2 = 9.80665;
    c.imu_noise.bias_corr_time_s = Some(300.0);
    c.t_bc.q_ab = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.9);
    c.t_bc.p_ab = Vec3::new(0.1, -0.2, 0.05);
    variants.push(c.clone());
    c.camera.distortion = Distortion::None;
    variants.push(c);
    let dir = tempfile::tempdir().expect("temp dir");
    for c in variants {
        let (cp, ip) = (
            dir.path().join("camchain.yaml"),
            dir.path().join("imu.yaml"),
        );
        write_camchain(&cp, &c, Some("/cam")).expect("camchain");
        write_imu(&ip, &c, None).expect("imu");
        let k = read(&cp, &ip, "cam0").expect("reads back");
        assert_eq!(
            (k.image_topic.as_deref(), k.imu_topic),
            (Some("/cam"), None)
        );
        let back = k.calib;
        assert!(
            back.t_bc.q_ab.angle_to(&c.t_bc.q_ab) < 1e-14,
            "{:?}",
            back.t_bc
        );
        assert!(
            (back.t_bc.p_ab - c.t_bc.p_ab).amax() < 1e-15,
            "{:?}",
            back.t_bc
        );
        // Everything else exactly.
        let same = Calibration {
            t_bc: c.t_bc,
            ..back
        };
        assert_eq!(same, c);
    }
}

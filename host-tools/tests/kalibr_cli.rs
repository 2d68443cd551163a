//! `povins run BAG --calib CAMCHAIN --imu-calib IMU` and `povins info` on the repository's ROS 1
//! bag with Kalibr files written by PyYAML (tests/data/kalibr, scripts/make_rosbag1_fixture.py):
//! the run goes through, the Kalibr `rostopic` chooses the camera among the bag's two, a missing
//! IMU noise is an error naming where it was looked for, the TOML's `[input]` and `[imu_noise]`
//! do the same as the switches, and an EuRoC folder is still accepted.

mod common;

use common::povins;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data");

fn p(rel: &str) -> String {
    format!("{DATA}/{rel}")
}

#[test]
fn a_bag_runs_with_kalibr_files_and_the_toml_input_table() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("k");
    let (bag, cam, imu) = (
        p("rosbag1-sim/sim.bag"),
        p("kalibr/sim-camchain-imucam.yaml"),
        p("kalibr/sim-imu.yaml"),
    );
    let o = out.to_str().expect("utf-8");
    let (ok, _, err) = povins(&[
        "run",
        &bag,
        "--calib",
        &cam,
        "--imu-calib",
        &imu,
        // A 2 s recording, half of it the rest before the start: partial by design.
        "--allow-partial",
        "--out",
        o,
    ]);
    assert!(ok, "run failed: {err}");
    let tum = std::fs::read_to_string(out.join("trajectory.tum")).expect("trajectory");
    assert!(tum.lines().count() > 100, "{tum}");
    let frontend = std::fs::read_to_string(out.join("frontend.csv")).expect("frontend.csv");
    // /cam0/gray_png (the camchain's rostopic) has 14 images.
    assert_eq!(frontend.lines().count(), 1 + 14, "{frontend}");

    // Without --imu-calib: refused, naming what is missing and where it was looked for.
    let (ok, _, err) = povins(&["run", &bag, "--calib", &cam, "--out", o]);
    assert!(!ok);
    assert!(
        err.contains("IMU noise missing")
            && err.contains("--imu-calib")
            && err.contains("sim-camchain-imucam.yaml"),
        "{err}"
    );

    // The same from the TOML: [input] paths relative to the file, [imu_noise] as the noise.
    std::fs::copy(&cam, dir.path().join("cam.yaml")).expect("copy");
    let toml = dir.path().join("run.toml");
    std::fs::write(
        &toml,
        "[input]\ncalib = \"cam.yaml\"\ncamera = \"cam0\"\naccel_unit = \"mps2\"\n\
         [imu_noise]\ngyro_noise_density = 0.00016968\naccel_noise_density = 0.002\n\
         gyro_bias_rw = 1.9393e-05\naccel_bias_rw = 0.003\n",
    )
    .expect("toml");
    let out2 = dir.path().join("t");
    let t = toml.to_str().expect("utf-8");
    let (ok, _, err) = povins(&[
        "run",
        &bag,
        "--config",
        t,
        "--allow-partial",
        "--out",
        out2.to_str().expect("utf-8"),
    ]);
    assert!(ok, "run with [input] failed: {err}");
    // accel_unit is used now: no "not used yet" note for it.
    assert!(!err.contains("not used yet"), "{err}");
    let tum2 = std::fs::read_to_string(out2.join("trajectory.tum")).expect("trajectory");
    assert_eq!(
        tum, tum2,
        "the TOML's noise equals imu.yaml's: the same run"
    );

    // A switch overrides the table: a camera the file does not have.
    let (ok, _, err) = povins(&["run", &bag, "--config", t, "--camera", "cam1", "--out", o]);
    assert!(!ok);
    assert!(
        err.contains("no camera `cam1` (the file has: cam0)"),
        "{err}"
    );
    std::fs::write(
        dir.path().join("bad.toml"),
        "[input]\nimu_topics = \"/imu\"\n",
    )
    .expect("toml");
    let bad = dir.path().join("bad.toml");
    let (ok, _, err) = povins(&[
        "run",
        &bag,
        "--config",
        bad.to_str().expect("utf-8"),
        "--out",
        o,
    ]);
    assert!(!ok);
    assert!(
        err.contains("bad.toml") && err.contains("unknown field `imu_topics`"),
        "{err}"
    );
}

#[test]
fn an_euroc_folder_is_still_a_calibration_and_info_prints_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bag = p("rosbag1-sim/sim.bag");
    let (ok, out, err) = povins(&[
        "info",
        &bag,
        "--calib",
        &p("kalibr/euroc-v101-camchain-imucam.yaml"),
        "--imu-calib",
        &p("kalibr/euroc-v101-imu.yaml"),
    ]);
    assert!(ok, "{err}");
    assert!(
        out.contains("camera    752x480 fx 458.654 fy 457.296"),
        "{out}"
    );
    assert!(
        out.contains("IMU       gyro 0.00016968 rad/s/sqrt(Hz)"),
        "{out}"
    );
    // The camchain names /cam0/image_raw, which the bag has: the choice among its two cameras.
    assert!(
        out.contains("run uses  IMU /imu0, camera /cam0/image_raw"),
        "{out}"
    );
    // An EuRoC folder (a directory) with a bag: accepted as before (the images do not match its
    // 752x480 camera: the run reports the images, writes its files and fails: no estimate).
    let o = dir.path().join("e");
    let (ok, _, err) = povins(&[
        "run",
        &bag,
        "--calib",
        &p("euroc-v101-30s-features"),
        "--image-topic",
        "/cam0/gray_png",
        "--out",
        o.to_str().expect("utf-8"),
    ]);
    assert!(!ok, "a run without an estimate exited 0");
    assert!(
        err.contains("(64x48) refused")
            && err.contains("no camera data reached the estimator")
            && err.contains("every image was refused"),
        "{err}"
    );
    assert!(o.join("trajectory.tum").is_file() && o.join("summary.json").is_file());
}

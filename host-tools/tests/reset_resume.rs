//! Issue 31 item 2: a full reset in motion (an IMU gap on a flying drone) no longer ends the
//! run. The estimator starts again without rest (the in-motion initializer), `povins run` says
//! when it was lost and when it was back, and the new start continues from the last estimate's
//! position and yaw, moved by the rotation and the path the frames during the outage show
//! (`estimator::outage_heading`), so what an autopilot reads does not jump.

mod common;

use common::povins;
use std::path::Path;

const EUROC: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/euroc-v101-30s-features"
);

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// The poses of a TUM file: (t s, position, yaw rad).
fn poses(p: &Path) -> Vec<(f64, [f64; 3], f64)> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            let (x, y, z, w) = (v[4], v[5], v[6], v[7]);
            let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
            (v[0], [v[1], v[2], v[3]], yaw)
        })
        .collect()
}

/// The ground truth of an EuRoC folder at the stamp nearest `t_s`: (position, yaw rad).
fn truth_at(folder: &Path, t_s: f64) -> ([f64; 3], f64) {
    let text =
        std::fs::read_to_string(folder.join("mav0/state_groundtruth_estimate0/data.csv")).unwrap();
    let row: Vec<f64> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            l.split(',')
                .map(|x| x.trim().parse().unwrap())
                .collect::<Vec<f64>>()
        })
        .min_by(|a, b| {
            (a[0] * 1e-9 - t_s)
                .abs()
                .total_cmp(&(b[0] * 1e-9 - t_s).abs())
        })
        .unwrap();
    let (w, x, y, z) = (row[4], row[5], row[6], row[7]);
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    ([row[1], row[2], row[3]], yaw)
}

/// `a - b` wrapped to (-pi, pi].
fn angle_diff(a: f64, b: f64) -> f64 {
    (a - b + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// The stamp of the first data row of an EuRoC CSV file, ns.
fn first_stamp(text: &str) -> i64 {
    text.lines()
        .find(|l| !l.starts_with('#'))
        .and_then(|l| l.split(',').next())
        .and_then(|t| t.parse().ok())
        .unwrap()
}

/// A copy of the EuRoC sequence with the IMU samples from 15 s to 15 s + `gap_s` removed, and
/// `povins run` on it: (success, stdout, stderr, summary.json, output folder).
fn run_with_gap(
    tmp: &Path,
    gap_s: f64,
) -> (bool, String, String, serde_json::Value, std::path::PathBuf) {
    run_with_gap_in(Path::new(EUROC), tmp, gap_s, &[])
}

/// [`run_with_gap`] on a copy of the EuRoC folder `src` (`gap_s` 0: no gap), `extra` arguments
/// to `povins run`.
fn run_with_gap_in(
    src: &Path,
    tmp: &Path,
    gap_s: f64,
    extra: &[&str],
) -> (bool, String, String, serde_json::Value, std::path::PathBuf) {
    run_with_gap_at(src, tmp, 15.0, gap_s, extra)
}

/// [`run_with_gap_in`] with the gap from `start_s` after the first IMU sample.
fn run_with_gap_at(
    src: &Path,
    tmp: &Path,
    start_s: f64,
    gap_s: f64,
    extra: &[&str],
) -> (bool, String, String, serde_json::Value, std::path::PathBuf) {
    let data = tmp.join("gap");
    copy_dir(src, &data);
    let imu = data.join("mav0/imu0/data.csv");
    let text = std::fs::read_to_string(&imu).unwrap();
    let t0 = first_stamp(&text);
    let a = t0 + (start_s * 1e9) as i64;
    let b = a + (gap_s * 1e9) as i64;
    let kept: String = text
        .lines()
        .filter(|l| {
            l.starts_with('#')
                || l.split(',')
                    .next()
                    .and_then(|t| t.parse::<i64>().ok())
                    .is_some_and(|t| t < a || t >= b)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&imu, kept).unwrap();
    let out = tmp.join("out");
    let mut args = vec![
        "run",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (ok, stdout, stderr) = povins(&args);
    let s = std::fs::read_to_string(out.join("summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::Value::Null);
    (ok, stdout, stderr, s, out)
}

/// Issue 32 item 1: a 100 ms IMU gap in flight is bridged (`imu_gap`): no reset, the gap is
/// reported on screen and counted in `summary.json`, and the output covers the run.
#[test]
fn a_short_imu_gap_in_flight_is_bridged() {
    let tmp = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr, s, _) = run_with_gap(tmp.path(), 0.1);
    assert!(ok, "povins run failed: {stderr}");
    assert!(stderr.contains("IMU gap of 0.10"), "{stderr}");
    assert!(stderr.contains("bridged"), "{stderr}");
    assert!(!stderr.contains("estimator reset at"), "{stderr}");
    assert!(stdout.contains("1 IMU gaps bridged"), "{stdout}");
    assert_eq!(s["counters"]["resets"].as_u64(), Some(0), "{stdout}");
    assert_eq!(
        s["counters"]["imu_gaps_bridged"].as_u64(),
        Some(1),
        "{stdout}"
    );
    let coverage = s["coverage"].as_f64().unwrap();
    assert!(coverage > 0.95, "coverage {coverage}: {stdout}");
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap();
    assert!(ate < 0.06, "ATE {ate} m over the whole run");
}

/// Issue 32 item 1: a 1 s IMU gap is longer than `imu_gap.bridge_max_s`, but the flight before
/// it was smooth enough for the line (`imu_gap.long_bridge_max_s`: its departure over 1 s
/// windows of the 9.6 s before predicts at most 0.1 rad and 0.6 m/s): bridged, no reset, the
/// output covers the run (a reset here covered 0.794 at 0.842 m; bridged 0.935 at 0.036 m,
/// the clean run 0.029 m).
#[test]
fn a_one_second_imu_gap_after_smooth_flight_is_bridged() {
    let tmp = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr, s, _) = run_with_gap(tmp.path(), 1.0);
    assert!(ok, "povins run failed: {stderr}");
    assert!(stderr.contains("IMU gap of 1.00"), "{stderr}");
    assert!(
        stderr.contains("the estimate is withheld until keyframes after it correct the INS"),
        "{stderr}"
    );
    assert!(!stderr.contains("estimator reset at"), "{stderr}");
    assert_eq!(s["counters"]["resets"].as_u64(), Some(0), "{stdout}");
    assert_eq!(
        s["counters"]["imu_gaps_bridged_long"].as_u64(),
        Some(1),
        "{stdout}"
    );
    let coverage = s["coverage"].as_f64().unwrap();
    assert!(coverage > 0.9, "coverage {coverage}: {stdout}");
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap();
    assert!(ate < 0.06, "ATE {ate} m over the whole run");
}

/// Issue 32 item 1, both sides of the long-gap decision on the simulator (30 s, no LiDAR, seed
/// 1, 2 s of IMU removed 15 s in): the wheeled robot's smooth motion is bridged (no reset, the
/// ATE at the fault-free run's: 0.174 against 0.168 m), the hand-held rig's is not (its line
/// would miss by radians: a reset, the in-motion restart, turned and moved by the images).
#[test]
fn a_two_second_imu_gap_is_bridged_after_smooth_motion_only() {
    for (scenario, bridged) in [("robot", true), ("handheld", false)] {
        let tmp = tempfile::tempdir().unwrap();
        let (c, (_, stdout, stderr, s, out)) = simulated_gap(tmp.path(), scenario, "1", 15.0, 2.0);
        let n = |k: &str| s["counters"][k].as_u64();
        let (ate, ate_clean) = (
            s["ate_pos_rmse_m"].as_f64().unwrap_or(f64::INFINITY),
            c["ate_pos_rmse_m"].as_f64().unwrap(),
        );
        let coverage = s["coverage"].as_f64().unwrap_or(0.0);
        println!("{scenario}: ATE {ate:.4} m (clean {ate_clean:.4}), coverage {coverage:.3}");
        if bridged {
            // The robot's tracks outlive the gap: no keyframe inside it.
            assert!(keyframes_in_gap(&out).is_empty(), "{scenario}");
            assert!(stderr.contains("IMU gap of 2.00"), "{stderr}");
            assert_eq!(n("imu_gaps_bridged_long"), Some(1), "{stdout}");
            assert_eq!(n("resets"), Some(0), "{stdout}");
            // Issue 32's bar: coverage 0.95, the gap itself excepted (its 2 s of the 29 s after
            // the first camera frame); the 0.35 s withheld after it count against it.
            let gap_share = 2.0 / 29.0;
            assert!(
                coverage + gap_share > 0.95,
                "{scenario}: coverage {coverage}"
            );
            assert!(
                ate < 1.5 * ate_clean,
                "{scenario}: ATE {ate} vs {ate_clean}"
            );
        } else {
            assert!(stderr.contains("estimator reset at"), "{stderr}");
            assert_eq!(n("imu_gaps_bridged_long"), Some(0), "{stdout}");
            assert_eq!(n("imu_gap_resets"), Some(1), "{stdout}");
            // The restart takes the turn and the path the frames during the outage show
            // (`estimator::outage_heading`): within issue 32's bar for a 2 s gap (3x the
            // fault-free ATE: 0.198 m against 0.126); keeping the old yaw and position gave
            // 2.43 m.
            assert_eq!(n("outage_motion_from_images"), Some(1), "{stdout}");
            assert!(
                ate < 3.0 * ate_clean,
                "{scenario}: ATE {ate} vs {ate_clean}"
            );
        }
    }
}

/// Issue 32: a 0.5 s IMU gap while the hand-held camera turns (seed 3, 30 s, no LiDAR, the gap
/// 25 s in). The line across the gap misses the turn; before, the window then settled on a
/// velocity several times the true one (3.50 m against 0.107 m). At the first frame after the gap
/// the images' pose is taken (`estimator::gap_pose`): counted, no reset, the ATE near the
/// fault-free run's.
#[test]
fn after_a_short_gap_in_a_turn_the_images_pose_is_taken() {
    let tmp = tempfile::tempdir().unwrap();
    let (c, (ok, stdout, stderr, s, _)) = simulated_gap(tmp.path(), "handheld", "3", 25.0, 0.5);
    assert!(ok, "{stderr}");
    let n = |k: &str| s["counters"][k].as_u64();
    assert_eq!(n("imu_gaps_bridged"), Some(1), "{stdout}");
    assert_eq!(n("imu_gap_poses_from_images"), Some(1), "{stdout}");
    assert_eq!(
        (n("resets"), n("reinitializations")),
        (Some(0), Some(0)),
        "{stdout}"
    );
    assert!(
        stdout.contains("(0 long, 1 posed from the images after it)"),
        "{stdout}"
    );
    let (ate, ate_clean) = (
        s["ate_pos_rmse_m"].as_f64().unwrap(),
        c["ate_pos_rmse_m"].as_f64().unwrap(),
    );
    println!("ATE {ate:.4} m (clean {ate_clean:.4})");
    assert!(ate < 1.5 * ate_clean, "ATE {ate} vs {ate_clean}");
}

/// A 30 s simulated `scenario` run (`seed`, no LiDAR) in `tmp`: the fault-free run's
/// `summary.json` (its success asserted), and [`run_with_gap_at`] with the gap from `start_s`.
fn simulated_gap(
    tmp: &Path,
    scenario: &str,
    seed: &str,
    start_s: f64,
    gap_s: f64,
) -> (
    serde_json::Value,
    (bool, String, String, serde_json::Value, std::path::PathBuf),
) {
    let src = tmp.join("sim");
    common::simulate(scenario, seed, "30", "euroc", &src, &["--lidar", "none"]);
    let clean = tmp.join("clean");
    std::fs::create_dir_all(&clean).unwrap();
    let (ok, _, stderr, c, _) = run_with_gap_in(&src, &clean, 0.0, &[]);
    assert!(ok, "{scenario} clean: {stderr}");
    let gap = tmp.join("with-gap");
    std::fs::create_dir_all(&gap).unwrap();
    (c, run_with_gap_at(&src, &gap, start_s, gap_s, &[]))
}

/// The stamps of `out/keyframes.tum` inside the gap [`run_with_gap_in`] makes (15 to 17 s after
/// the first IMU sample, which the simulator stamps at 1 s).
fn keyframes_in_gap(out: &Path) -> Vec<f64> {
    poses(&out.join("keyframes.tum"))
        .into_iter()
        .map(|p| p.0)
        .filter(|&t| t > 16.0 && t < 18.0)
        .collect()
}

/// Inside a long gap the car loses every track (they last 0.7 s): a keyframe is taken there, so
/// the images carry its heading across (seed 5, 30 s, 3% wrong tracks, 8 ms delay, no LiDAR, from
/// the true state: 1.56 m, against 2.77 m with the line alone carrying the rotation; 0.42 m
/// without the gap).
#[test]
fn a_car_that_loses_its_tracks_in_a_long_gap_takes_a_keyframe_there() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("sim");
    let extra = [
        "--lidar",
        "none",
        "--td-ms",
        "8",
        "--wrong-track-rate",
        "0.03",
    ];
    common::simulate("vehicle", "5", "30", "euroc", &src, &extra);
    let (ok, stdout, stderr, s, out) =
        run_with_gap_in(&src, tmp.path(), 2.0, &["--init", "groundtruth"]);
    assert!(ok, "{stderr}");
    assert_eq!(
        s["counters"]["imu_gaps_bridged_long"].as_u64(),
        Some(1),
        "{stdout}"
    );
    let inside = keyframes_in_gap(&out);
    assert!(!inside.is_empty(), "no keyframe inside the gap");
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap_or(f64::INFINITY);
    assert!(
        ate < 2.0,
        "ATE {ate} m (keyframes inside the gap at {inside:?})"
    );
}

#[test]
fn an_imu_gap_in_flight_restarts_in_motion_where_the_estimate_was() {
    let tmp = tempfile::tempdir().unwrap();
    // 2 s of IMU removed 15 s in: longer than `imu_gap.bridge_max_s`, and the line over 2 s
    // of this flight's vibrating accelerometer would miss by more than the long-gap limits: the
    // estimator resets while flying.
    let (ok, stdout, stderr, s, out) = run_with_gap(tmp.path(), 2.0);
    assert!(ok, "povins run failed: {stderr}");
    assert!(stderr.contains("estimator reset at 17.0"), "{stderr}");
    assert!(stderr.contains("estimator back at"), "{stderr}");
    assert_eq!(s["counters"]["resets"].as_u64(), Some(1), "{stdout}");
    assert_eq!(
        s["counters"]["imu_gap_resets"].as_u64(),
        Some(1),
        "{stdout}"
    );
    assert_eq!(s["counters"]["motion_inits"].as_u64(), Some(1), "{stdout}");
    let coverage = s["coverage"].as_f64().unwrap();
    assert!(coverage > 0.75, "coverage {coverage}: {stdout}");

    // Across the outage (5.3 s: the gap and the in-motion start after it) the drone turned
    // 20 degrees and moved 1.7 m. The first estimate after it continues from the last one
    // before, turned and moved by what the frames during the outage show (measured: 14.6
    // degrees, and 1.0 m from the truth's end: the images give the direction; the length is the
    // speed before the gap times the outage, and the drone sped up). Before, the start kept the
    // old yaw and position: 20 degrees and 1.7 m off, an ATE of 0.84 m (now 0.49).
    assert_eq!(
        s["counters"]["outage_motion_from_images"].as_u64(),
        Some(1),
        "{stdout}"
    );
    let p = poses(&out.join("trajectory.tum"));
    let k = p
        .windows(2)
        .position(|w| w[1].0 - w[0].0 > 1.0)
        .expect("an outage in the trajectory");
    let (before, after) = (p[k], p[k + 1]);
    let data = out.parent().unwrap().join("gap");
    let (t_before, t_after) = (truth_at(&data, before.0), truth_at(&data, after.0));
    // The truth's motion in the frame of the estimate before the outage (yaw and position are
    // the estimate's gauge).
    let turn = angle_diff(t_after.1, t_before.1);
    let est_turn = angle_diff(after.2, before.2);
    let rot = |d: [f64; 3], yaw: f64| {
        let (c, s) = (yaw.cos(), yaw.sin());
        [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]]
    };
    let d_true = rot([0, 1, 2].map(|i| t_after.0[i] - t_before.0[i]), -t_before.1);
    let d_est = rot([0, 1, 2].map(|i| after.1[i] - before.1[i]), -before.2);
    let norm = |d: [f64; 3]| d.iter().map(|x| x * x).sum::<f64>().sqrt();
    let miss = norm([0, 1, 2].map(|i| d_est[i] - d_true[i]));
    println!(
        "turn {:.1} deg (true {:.1}), moved {:.2} m (true {:.2}), missed by {miss:.2} m",
        est_turn.to_degrees(),
        turn.to_degrees(),
        norm(d_est),
        norm(d_true)
    );
    assert!(turn.abs() > 0.2, "the test needs a turn: {turn}");
    assert!(
        angle_diff(est_turn, turn).abs() < 0.5 * turn.abs(),
        "turn {est_turn} against {turn}"
    );
    assert!(
        miss < 0.75 * norm(d_true),
        "missed by {miss} m of {d_true:?}"
    );
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap();
    assert!(ate < 0.65, "ATE {ate} m over the whole run");
}

/// A clock jump (`estimator::clock_jump`): every stamp of every file of the EuRoC copy from 15 s
/// on moved by +1 h. `povins run` says so, goes on (no reset, no re-initialization), counts it
/// in `summary.json`, and the output, on the files' clock, covers the run at the accuracy of the
/// run without it.
#[test]
fn a_clock_jump_in_every_stream_is_told_and_survived() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("jump");
    copy_dir(Path::new(EUROC), &data);
    let imu = std::fs::read_to_string(data.join("mav0/imu0/data.csv")).unwrap();
    let at = first_stamp(&imu) + 15_000_000_000;
    for f in [
        "imu0/data.csv",
        "features0/data.csv",
        "state_groundtruth_estimate0/data.csv",
    ] {
        let p = data.join("mav0").join(f);
        let text = std::fs::read_to_string(&p).unwrap();
        let moved: String = text
            .lines()
            .map(|l| match l.split_once(',') {
                Some((t, rest)) if !l.starts_with('#') => {
                    let t: i64 = t.parse().unwrap();
                    let t = if t >= at { t + 3_600_000_000_000 } else { t };
                    format!("{t},{rest}\n")
                }
                _ => format!("{l}\n"),
            })
            .collect();
        std::fs::write(&p, moved).unwrap();
    }
    let out = tmp.path().join("out");
    let (ok, stdout, stderr) = povins(&[
        "run",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "povins run failed: {stderr}");
    assert!(
        stderr.contains("clock jump of +3600.000 s in every stream"),
        "{stderr}"
    );
    assert!(!stderr.contains("estimator reset at"), "{stderr}");
    assert!(stdout.contains("1 clock jumps"), "{stdout}");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["counters"]["clock_jumps"].as_u64(), Some(1), "{stdout}");
    assert_eq!(s["counters"]["resets"].as_u64(), Some(0), "{stdout}");
    assert_eq!(
        s["counters"]["reinitializations"].as_u64(),
        Some(0),
        "{stdout}"
    );
    let coverage = s["coverage"].as_f64().unwrap();
    assert!(coverage > 0.95, "coverage {coverage}: {stdout}");
    // The hour the clock skipped is no input's time (a recording without ground truth is
    // judged by this one).
    let input = s["input_coverage"].as_f64().unwrap();
    assert!(input > 0.95, "input coverage {input}: {stdout}");
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap();
    assert!(
        ate < 0.035,
        "ATE {ate} m over the whole run (0.029 m without the jump)"
    );
}

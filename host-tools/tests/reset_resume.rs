//! Issue 31 item 2: a full reset in motion (an IMU gap on a flying drone) no longer ends the
//! run. The estimator starts again without rest (the in-motion initializer), `povins run` says
//! when it was lost and when it was back, and the new start continues from the last estimate's
//! position and yaw, so what an autopilot reads does not jump.

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

/// A copy of the EuRoC sequence with the IMU samples from 15 s to 15 s + `gap_s` removed, and
/// `povins run` on it: (success, stdout, stderr, summary.json, output folder).
fn run_with_gap(
    tmp: &Path,
    gap_s: f64,
) -> (bool, String, String, serde_json::Value, std::path::PathBuf) {
    let data = tmp.join("gap");
    copy_dir(Path::new(EUROC), &data);
    let imu = data.join("mav0/imu0/data.csv");
    let text = std::fs::read_to_string(&imu).unwrap();
    let t0: i64 = text
        .lines()
        .find(|l| !l.starts_with('#'))
        .and_then(|l| l.split(',').next())
        .and_then(|t| t.parse().ok())
        .unwrap();
    let (a, b) = (
        t0 + 15_000_000_000,
        t0 + 15_000_000_000 + (gap_s * 1e9) as i64,
    );
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
    let (ok, stdout, stderr) = povins(&[
        "run",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
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

#[test]
fn an_imu_gap_in_flight_restarts_in_motion_where_the_estimate_was() {
    let tmp = tempfile::tempdir().unwrap();
    // 1 s of IMU removed 15 s in: longer than `imu_gap.bridge_max_s`, the estimator resets
    // while flying.
    let (ok, stdout, stderr, s, out) = run_with_gap(tmp.path(), 1.0);
    assert!(ok, "povins run failed: {stderr}");
    assert!(stderr.contains("estimator reset at 16.0"), "{stderr}");
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

    // No jump across the outage: the first estimate after it is where the last one before was,
    // with the same heading.
    let p = poses(&out.join("trajectory.tum"));
    let k = p
        .windows(2)
        .position(|w| w[1].0 - w[0].0 > 1.0)
        .expect("an outage in the trajectory");
    let (before, after) = (p[k], p[k + 1]);
    let jump: f64 = (0..3)
        .map(|i| (after.1[i] - before.1[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let dyaw = (after.2 - before.2 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
        - std::f64::consts::PI;
    assert!(jump < 0.05, "position jump {jump} m");
    assert!(dyaw.abs() < 0.05, "yaw jump {dyaw} rad");
    let ate = s["ate_pos_rmse_m"].as_f64().unwrap();
    assert!(ate < 1.0, "ATE {ate} m over the whole run");
}

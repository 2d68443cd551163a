//! `povins eval` end to end: JSON keys and values on real ground truth, and error messages.

mod common;
use common::povins;

use povins_core::math::Vec3;
use povins_platform::trajectory::{read_trajectory, write_tum, StampedPose};
use std::path::{Path, PathBuf};

/// The repository's copy (`tests/data`) when there is one, else `../shared/data` (tests on it
/// are `#[ignore]`d); fails when missing.
fn shared(rel: &str) -> PathBuf {
    let repo = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data")).join(rel);
    if repo.exists() {
        return repo;
    }
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")).join(rel);
    assert!(
        p.exists(),
        "shared data not found at {} (clone the repo next to shared/)",
        p.display()
    );
    p
}

fn gt_path() -> PathBuf {
    shared("euroc-v101-30s-features/mav0/state_groundtruth_estimate0/data.csv")
}

#[test]
fn json_reports_known_constant_offset_error() {
    let gt = read_trajectory(&gt_path()).unwrap();
    // Alternating +-2 cm in z on a time-shifted copy: no alignment can remove a zero-mean
    // vertical error (an even count keeps its mean at zero), so every mode reports 2 cm.
    let n = gt.len() / 2 * 2;
    let est: Vec<StampedPose> = gt[..n]
        .iter()
        .enumerate()
        .map(|(k, p)| StampedPose {
            t_ns: p.t_ns + 3_000_000_000,
            p_wb: p.p_wb + Vec3::new(0.0, 0.0, if k % 2 == 0 { 0.02 } else { -0.02 }),
            ..*p
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let est_path = dir.path().join("est.tum");
    write_tum(&est_path, &est).unwrap();
    let gt_s = gt_path().to_string_lossy().into_owned();
    let est_s = est_path.to_string_lossy().into_owned();
    for align in ["none", "posyaw"] {
        let (ok, stdout, stderr) = povins(&[
            "eval",
            "--gt",
            &gt_s,
            "--est",
            &est_s,
            "--align",
            align,
            "--t-offset",
            "-3",
            "--json",
        ]);
        assert!(ok, "{stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(v["alignment"], align);
        assert_eq!(v["matched_poses"], n);
        let rmse = v["ate_pos_rmse_m"].as_f64().unwrap();
        assert!((rmse - 0.02).abs() < 1e-9, "{align}: {rmse}");
        assert!(v["ate_rot_rmse_deg"].as_f64().unwrap() < 1e-6);
        for key in [
            "ate_pos_median_m",
            "ate_pos_max_m",
            "ate_rot_mean_deg",
            "align_scale",
        ] {
            assert!(v[key].is_number(), "{key} missing");
        }
        let rte = v["rte"].as_array().unwrap();
        assert_eq!(rte.len(), 5);
        assert_eq!(rte[0]["segment_m"], 8.0);
        // V1_01's first 30 s cover about 10 m: 8 m segments exist, 16 m ones do not.
        assert!(rte[0]["pairs"].as_u64().unwrap() > 50);
        assert!(rte[0]["pos_rmse_m"].as_f64().unwrap() < 0.041);
        assert_eq!(rte[1]["pairs"], 0);
        assert!(rte[1]["pos_rmse_m"].is_null());
    }
    // The table names the alignment and the numbers.
    let (ok, stdout, _) = povins(&["eval", "--gt", &gt_s, "--est", &est_s, "--t-offset", "-3"]);
    assert!(ok);
    assert!(
        stdout.contains("alignment posyaw") && stdout.contains("position [m]         0.020000"),
        "{stdout}"
    );
}

#[test]
fn errors_name_the_problem() {
    let gt_s = gt_path().to_string_lossy().into_owned();
    let dir = tempfile::tempdir().unwrap();
    // Unreadable file: the path is in the message.
    let missing = dir.path().join("nope.tum");
    let (ok, _, stderr) = povins(&["eval", "--gt", &gt_s, "--est", &missing.to_string_lossy()]);
    assert!(
        !ok && stderr.contains("nope.tum") && stderr.contains("estimated"),
        "{stderr}"
    );
    // Malformed line: path and line number.
    let bad = dir.path().join("bad.tum");
    std::fs::write(
        &bad,
        "# header\n1403715273.262142976 0 0 0 0 0 0 1\n1403715273.3 0 0 0 0 0 1\n",
    )
    .unwrap();
    let (ok, _, stderr) = povins(&["eval", "--gt", &gt_s, "--est", &bad.to_string_lossy()]);
    assert!(!ok && stderr.contains("bad.tum:3"), "{stderr}");
    // No overlap in time.
    let far = dir.path().join("far.tum");
    std::fs::write(
        &far,
        "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n",
    )
    .unwrap();
    let (ok, _, stderr) = povins(&["eval", "--gt", &gt_s, "--est", &far.to_string_lossy()]);
    assert!(!ok && stderr.contains("no overlap in time"), "{stderr}");
    // Overlap but too few matches.
    let gt = read_trajectory(&gt_path()).unwrap();
    let two: Vec<StampedPose> = gt[100..102].to_vec();
    let few = dir.path().join("few.tum");
    write_tum(&few, &two).unwrap();
    let (ok, _, stderr) = povins(&["eval", "--gt", &gt_s, "--est", &few.to_string_lossy()]);
    assert!(
        !ok && stderr.contains("only 2 pose(s)") && stderr.contains("at least 3"),
        "{stderr}"
    );
}

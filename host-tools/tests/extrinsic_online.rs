//! The camera-IMU extrinsic estimated online converges (issue 31, item 5): a simulated
//! aggressive flight (`--scenario fast`, 12 s), started with `T_bc` 2 cm and 2 degrees off the
//! truth and `estimate_extrinsic = true`, ends within a few millimetres and a tenth of a degree of
//! the truth. The estimate is read from `stats.csv`'s extrinsic columns (`T_bc` after each
//! keyframe's solve), and its marginal standard deviations (`p_bc_sd_*_m`, `r_bc_sd_*_rad`)
//! shrink and match the error it ends with. `scripts/extrinsic_conv.sh` measures the same over
//! scenarios and seeds.

mod common;

use common::povins;
use povins_core::math::{Quat, Vec3};
use std::path::Path;

/// The last keyframe's `T_bc` of a run's `stats.csv`, read by column name.
fn last_extrinsic(stats: &Path) -> (Vec3, Quat) {
    let text = std::fs::read_to_string(stats).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let names = [
        "p_bc_x_m", "p_bc_y_m", "p_bc_z_m", "q_bc_w", "q_bc_x", "q_bc_y", "q_bc_z",
    ];
    let cols: Vec<usize> = names.iter().copied().map(col).collect();
    let last = lines
        .rfind(|l| l.split(',').nth(cols[0]).is_some_and(|v| !v.is_empty()))
        .expect("a keyframe with an extrinsic");
    let f: Vec<f64> = {
        let fields: Vec<&str> = last.split(',').collect();
        cols.iter().map(|&c| fields[c].parse().unwrap()).collect()
    };
    let q = Quat::from_quaternion(nalgebra::Quaternion::new(f[3], f[4], f[5], f[6]));
    (Vec3::new(f[0], f[1], f[2]), q)
}

/// The extrinsic's standard deviations (translation m, rotation rad) at the first and the last
/// keyframe that has them.
fn first_and_last_sd(stats: &Path) -> ([f64; 6], [f64; 6]) {
    let text = std::fs::read_to_string(stats).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let names = [
        "p_bc_sd_x_m",
        "p_bc_sd_y_m",
        "p_bc_sd_z_m",
        "r_bc_sd_x_rad",
        "r_bc_sd_y_rad",
        "r_bc_sd_z_rad",
    ];
    let cols: Vec<usize> = names
        .iter()
        .map(|n| header.iter().position(|h| h == n).unwrap())
        .collect();
    let rows: Vec<[f64; 6]> = lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let v: Vec<f64> = cols.iter().filter_map(|&c| f[c].parse().ok()).collect();
            v.try_into().ok()
        })
        .collect();
    (
        *rows
            .first()
            .expect("a keyframe with the extrinsic's deviations"),
        *rows.last().unwrap(),
    )
}

#[test]
fn perturbed_extrinsic_converges_on_a_simulated_fast_flight() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("fast");
    let d = data.to_str().unwrap();
    let (ok, _, err) = povins(&[
        "simulate",
        "--scenario",
        "fast",
        "--seed",
        "1",
        "--duration",
        "12",
        "--lidar",
        "none",
        "--format",
        "euroc",
        "--out",
        d,
    ]);
    assert!(ok, "simulate failed: {err}");
    let truth = povins_platform::read_dataset(&data).unwrap().calib.t_bc;

    // 2 cm along (1, -1, 1)/sqrt(3), 2 degrees about (1, 2, -1)/sqrt(6), in the body frame.
    let p0 = truth.p_ab + Vec3::new(1.0, -1.0, 1.0).normalize() * 0.02;
    let q0 = Quat::from_scaled_axis(Vec3::new(1.0, 2.0, -1.0).normalize() * 2f64.to_radians())
        * truth.q_ab;
    let q = q0.quaternion();
    let config = tmp.path().join("perturbed.toml");
    let text = format!(
        "estimate_extrinsic = true\n[extrinsic]\np_bc = [{:?}, {:?}, {:?}]\n\
         q_bc = [{:?}, {:?}, {:?}, {:?}]\n",
        p0.x, p0.y, p0.z, q.i, q.j, q.k, q.w
    );
    std::fs::write(&config, &text).unwrap();
    let out = tmp.path().join("run");
    let (ok, stdout, err) = povins(&[
        "run",
        d,
        "--frontend",
        "tracks",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "run failed: {stdout}\n{err}");

    let (p, q) = last_extrinsic(&out.join("stats.csv"));
    let dp_cm = (p - truth.p_ab).norm() * 100.0;
    let dr_deg = (q * truth.q_ab.inverse()).angle().to_degrees();
    // Measured here 0.68 cm / 0.043 deg; the same start rounded differently in its last bit
    // (scripts/extrinsic_conv.sh's configuration) ends at 0.26 cm / 0.04 deg: on 12 s the
    // translation is known to a few millimetres only (60 s runs over seeds 1-3: 0.23-0.41 cm,
    // <= 0.02 deg). The bounds are half the initial translation error, 1/13 of the rotation's.
    assert!(
        dp_cm < 1.0 && dr_deg < 0.15,
        "extrinsic did not converge from 2 cm / 2 deg: {dp_cm:.2} cm, {dr_deg:.3} deg off at the end\n{text}"
    );

    // Its marginal standard deviations: positive and finite, shrinking as the flight shows
    // the extrinsic, and of the size of the error it ends with (translation NEES per axis,
    // correlations left out: 3 when consistent; the estimator is overconfident on this
    // scenario, BENCHMARKS.md "its NEES": 60 s runs 8.8-9.6 at the median, so the bound is
    // loose, but a deviation in the wrong unit or of the wrong block is off by orders).
    // The run's summary says where it ended: the same `T_bc` and deviations, on screen and in
    // `summary.json`.
    let line = stdout
        .lines()
        .find(|l| l.starts_with("extrinsic p_bc"))
        .unwrap_or_else(|| panic!("no extrinsic line in\n{stdout}"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let end = &summary["extrinsic_end"];
    let num = |v: &serde_json::Value, i: usize| v[i].as_f64().unwrap();
    for i in 0..3 {
        assert!(
            (num(&end["p_bc_m"], i) - p[i]).abs() < 1e-9,
            "{end} against {p:?}"
        );
    }
    assert!(line.contains(&format!("{:.2}", 100.0 * p.x)), "{line}");

    let (first, last) = first_and_last_sd(&out.join("stats.csv"));
    assert!(
        first.iter().chain(&last).all(|v| v.is_finite() && *v > 0.0),
        "{first:?} {last:?}"
    );
    for i in 0..3 {
        assert!(
            (num(&end["p_bc_sd_m"], i) - last[i]).abs() <= 1e-6 * last[i],
            "{end}"
        );
        assert!((num(&end["r_bc_sd_rad"], i) - last[3 + i]).abs() <= 1e-6 * last[3 + i]);
    }
    assert!(
        (0..3).all(|i| last[i] < first[i]) && (3..6).all(|i| last[i] < first[i]),
        "the deviations did not shrink: {first:?} -> {last:?}"
    );
    let dp = p - truth.p_ab;
    let nees: f64 = (0..3).map(|i| (dp[i] / last[i]).powi(2)).sum();
    eprintln!("extrinsic deviations first {first:?}, last {last:?}; translation NEES {nees:.2}");
    assert!(
        (0.01..60.0).contains(&nees),
        "translation error {dp:?} m against deviations {:?} m: NEES {nees}",
        &last[..3]
    );
}

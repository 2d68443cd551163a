//! Issue 31: an in-motion start given the IMU's biases (`povins run --biases-from
//! RUN/keyframes_state.csv`, `[init.biases]`). A start in motion cannot tell a second of
//! accelerometer bias from tilt and scale; a previous run on the same powered IMU knows it.

mod common;

use common::{povins, simulate};
use std::path::Path;

/// ATE (m) of a run's `summary.json`.
fn ate(out: &Path) -> f64 {
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    s["ate_pos_rmse_m"].as_f64().expect("ATE in summary.json")
}

/// The bias columns of a `keyframes_state.csv` row (`first` or last).
fn biases(path: &Path, first: bool) -> [f64; 6] {
    let text = std::fs::read_to_string(path).unwrap();
    let mut rows = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty());
    let row = if first { rows.next() } else { rows.next_back() }.unwrap();
    let v: Vec<f64> = row.split(',').map(|x| x.parse().unwrap()).collect();
    v[11..17].try_into().unwrap()
}

/// The simulated calm flight, seed 4, whose in-motion start (the rest and the ramp cut away)
/// misjudges the scale from its first second: its vertical accelerometer bias (-0.15 m/s^2) is
/// as large as the flight's accelerations. Given the biases the run from rest ended with, the
/// same start is as good as the run from rest.
#[test]
fn an_in_motion_start_given_the_previous_runs_biases_is_as_good_as_one_from_rest() {
    let dir = tempfile::tempdir().unwrap();
    let (rest, motion) = (dir.path().join("rest"), dir.path().join("motion"));
    let sim = ["--wrong-track-rate", "0.03", "--lidar", "none"];
    simulate("flight", "4", "30", "euroc", &rest, &sim);
    let mut cut = sim.to_vec();
    cut.extend(["--start-s", "motion"]);
    simulate("flight", "4", "30", "euroc", &motion, &cut);
    let run = |data: &Path, out: &Path, extra: &[&str]| {
        let mut args = vec![
            "run",
            data.to_str().unwrap(),
            "--frontend",
            "tracks",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let (ok, stdout, err) = povins(&args);
        assert!(ok, "run {args:?}: {stdout}\n{err}");
        err
    };
    let out = |n: &str| dir.path().join(n);
    run(&rest, &out("from-rest"), &[]);
    run(&motion, &out("blind"), &[]);
    let states = out("from-rest").join("keyframes_state.csv");
    let err = run(
        &motion,
        &out("given"),
        &["--biases-from", states.to_str().unwrap()],
    );
    // The simulator's cut sequence keeps the clock of the full one: the rest run ends after the
    // cut one starts, which the user is warned about.
    assert!(
        err.contains("is after this recording's first IMU sample"),
        "{err}"
    );
    let (a_rest, a_blind, a_given) = (
        ate(&out("from-rest")),
        ate(&out("blind")),
        ate(&out("given")),
    );
    eprintln!(
        "ATE from rest {a_rest:.4} m, in motion {a_blind:.4} m, given the biases {a_given:.4} m"
    );
    assert!(
        a_given <= 1.5 * a_rest,
        "given the biases {a_given:.4} m against {a_rest:.4} m from rest (blind: {a_blind:.4} m)"
    );
    // The run took them: written back into its configuration, and its first keyframe within
    // three standard deviations of them (0.0005 rad/s, 0.02 m/s^2).
    let cfg = std::fs::read_to_string(out("given").join("config.toml")).unwrap();
    assert!(cfg.contains("[init.biases]"), "{cfg}");
    let (given, first) = (
        biases(&states, false),
        biases(&out("given").join("keyframes_state.csv"), true),
    );
    for i in 0..6 {
        let sd = if i < 3 { 5e-4 } else { 0.02 };
        assert!(
            (given[i] - first[i]).abs() <= 3.0 * sd,
            "bias {i}: first keyframe {} against the given {}",
            first[i],
            given[i]
        );
    }
    // A config file that gives only the standard deviations: the file's biases with them.
    let sds = dir.path().join("sd.toml");
    std::fs::write(
        &sds,
        "[init.biases]\ngyro_sd_rps = 0.001\naccel_sd_mps2 = 0.03\n",
    )
    .unwrap();
    run(
        &motion,
        &out("sd"),
        &[
            "--biases-from",
            states.to_str().unwrap(),
            "--config",
            sds.to_str().unwrap(),
        ],
    );
    let cfg: toml::Table =
        toml::from_str(&std::fs::read_to_string(out("sd").join("config.toml")).unwrap()).unwrap();
    let b = &cfg["init"]["biases"];
    assert_eq!(b["gyro_sd_rps"].as_float(), Some(0.001));
    assert_eq!(b["accel_sd_mps2"].as_float(), Some(0.03));
    let accel: Vec<f64> = b["accel_mps2"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_float().unwrap())
        .collect();
    assert_eq!(accel, given[3..]);
}

/// A file that is not a `keyframes_state.csv` is refused, naming the file, the line and the
/// column.
#[test]
fn biases_from_a_bad_file_name_the_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let data = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tests/data/euroc-v101-30s-features"
    );
    let header = "#timestamp [ns],p_wb_x [m],p_wb_y [m],p_wb_z [m],q_wb_w [],q_wb_x [],q_wb_y [],q_wb_z [],v_wb_x [m s^-1],v_wb_y [m s^-1],v_wb_z [m s^-1],bg_x [rad s^-1],bg_y [rad s^-1],bg_z [rad s^-1],ba_x [m s^-2],ba_y [m s^-2],ba_z [m s^-2]";
    let cases = [
        (format!("{header}\n"), "no state row"),
        (
            format!("{header}\n1,2,3\n"),
            ":2: 3 columns, expected the 17",
        ),
        (
            format!("{header}\n1{}\n1{},nan\n", ",0".repeat(16), ",0".repeat(15)),
            ":3: column 17 (ba_z [m s^-2]) is \"nan\", not a finite number",
        ),
    ];
    for (i, (text, want)) in cases.iter().enumerate() {
        let f = dir.path().join(format!("states{i}.csv"));
        std::fs::write(&f, text).unwrap();
        let (ok, _, err) = povins(&[
            "run",
            data,
            "--biases-from",
            f.to_str().unwrap(),
            "--out",
            dir.path().join("out").to_str().unwrap(),
        ]);
        assert!(!ok, "case {i} ran");
        assert!(
            err.contains(f.to_str().unwrap()) && err.contains(want),
            "case {i}: {err}"
        );
    }
}

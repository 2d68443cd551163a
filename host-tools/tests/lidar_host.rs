//! LiDAR in the host tools: the `run` switches reach the estimator configuration, the replay
//! pushes each sweep once the IMU has passed its last point, the simulator's MCAP carries the
//! sweeps with per-point times, `stats.csv` / `summary.json` carry the LiDAR numbers, and
//! `povins ablation` / `povins demo` run end to end, a LiDAR time offset in the recording is
//! applied, and a LiDAR faster than the buffer is thinned. (What the LiDAR does for accuracy is
//! measured by `povins ablation`, BENCHMARKS.md, not asserted here.)

mod common;
use common::povins;

use clap::Parser;
use povins_core::camera::PinholeCamera;
use povins_core::inertial::{ImuNoise, ImuSample};
use povins_core::lidar::{LdmMode, LidarPoint};
use povins_core::math::{Quat, Vec3};
use povins_host_tools::ablation::{run_ablation, AblationConfig, Variant};
use povins_host_tools::progress::Progress;
use povins_host_tools::report::STATS_LIDAR_COLUMNS;
use povins_host_tools::runner::{config_for, replay, InitMode};
use povins_host_tools::setup::{RunArgs, RunSetup};
use povins_host_tools::sim::{self, LidarKind, Scenario, SimConfig};
use povins_platform::dataset::{Calibration, Dataset, Extrinsic, LidarScan};
use povins_platform::recording::Recording;
use std::path::Path;

const T0_NS: i64 = 1_000_000_000;
const MS: i64 = 1_000_000;

fn quiet() -> Progress {
    Progress::with_visibility(0, "", false)
}

/// The estimator is built on the stack before it is boxed: run on a thread with room.
fn big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    match std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .expect("spawn a test thread")
        .join()
    {
        Ok(v) => v,
        Err(p) => std::panic::resume_unwind(p),
    }
}

/// A scan starting at `t0_ns` with `n` points spaced `dt_ns`, times permuted so the last point
/// in the list is not the latest.
fn scan(t0_ns: i64, n: usize, dt_ns: i64) -> LidarScan {
    let mut points: Vec<LidarPoint> = (0..n)
        .map(|k| LidarPoint {
            t_ns: t0_ns + k as i64 * dt_ns,
            p_l: [5.0, k as f32 * 0.01, 0.0],
            intensity: 1.0,
        })
        .collect();
    points.swap(0, n - 1);
    LidarScan {
        t_ns: t0_ns,
        points,
    }
}

/// 2 s at rest at 200 Hz and three sweeps, at 0.2-0.29 s, 0.5-0.59 s and 1.95-2.04 s after the
/// first IMU sample; the last one ends after the last IMU sample (2.0 s).
fn fake_dataset() -> Dataset {
    let imu: Vec<ImuSample> = (0..=400)
        .map(|k| ImuSample {
            t_ns: T0_NS + k * 5 * MS,
            gyro_rps: Vec3::zeros(),
            accel_mps2: Vec3::new(0.0, 0.0, 9.81),
        })
        .collect();
    Dataset {
        name: "fake".into(),
        calib: Calibration {
            camera: PinholeCamera::EUROC_CAM0,
            t_bc: Extrinsic::identity(),
            td_s: 0.0,
            camera_rate_hz: 20.0,
            imu_noise: ImuNoise::EUROC_ADIS16448,
            imu_rate_hz: 200.0,
            gravity_mps2: 9.81,
            t_bl: Some(Extrinsic {
                q_ab: Quat::from_euler_angles(0.0, 0.0, 0.5),
                p_ab: Vec3::new(0.1, 0.2, 0.3),
            }),
            td_l_s: 0.0,
        },
        imu,
        features: Vec::new(),
        images: Vec::new(),
        lidar: vec![
            scan(T0_NS + 200 * MS, 10, 10 * MS),
            scan(T0_NS + 500 * MS, 7, 15 * MS),
            scan(T0_NS + 1950 * MS, 10, 10 * MS),
        ],
        ground_truth: Vec::new(),
        sim_truth: None,
    }
}

#[test]
fn config_for_enables_lidar_with_the_datasets_extrinsic() {
    let ds = fake_dataset();
    let cfg = config_for(&ds);
    assert!(cfg.lidar.enabled);
    assert_eq!(cfg.lidar.extrinsic.p_bl, Vec3::new(0.1, 0.2, 0.3));
    assert_eq!(
        cfg.lidar.extrinsic.q_bl,
        Quat::from_euler_angles(0.0, 0.0, 0.5)
    );
    // No sweeps, or no T_bl: LiDAR stays off.
    let mut no_scans = fake_dataset();
    no_scans.lidar.clear();
    assert!(!config_for(&no_scans).lidar.enabled);
    let mut no_tbl = fake_dataset();
    no_tbl.calib.t_bl = None;
    assert!(!config_for(&no_tbl).lidar.enabled);
}

/// The estimator configuration `povins run` builds from `args` over `rec`.
fn estimator_config(
    args: &RunArgs,
    rec: &dyn Recording,
) -> anyhow::Result<povins_core::estimator::EstimatorConfig> {
    Ok(RunSetup::from_args(rec, args)?.estimator)
}

#[derive(Parser)]
struct RunCli {
    #[command(flatten)]
    args: RunArgs,
}

fn run_args(argv: &[&str]) -> RunArgs {
    RunCli::try_parse_from(std::iter::once("run").chain(argv.iter().copied()))
        .unwrap_or_else(|e| panic!("{argv:?}: {e}"))
        .args
}

#[test]
fn run_switches_reach_the_estimator_config_and_override_the_file() {
    let ds = fake_dataset();
    let dir = tempfile::tempdir().unwrap();
    let toml = dir.path().join("c.toml");
    std::fs::write(
        &toml,
        "[lidar]\nldm = \"direct\"\nsigma_dr_m = 0.25\n[lidar.association]\nneighbours = 7\n",
    )
    .unwrap();
    let toml = toml.to_str().unwrap();

    let cfg = estimator_config(&run_args(&["d.mcap"]), &ds).unwrap();
    let l = cfg.lidar;
    assert!(l.enabled && l.depth_outlier_rejection && l.depth_only_opt);
    assert_eq!(l.ldm, LdmMode::Msc);

    let cfg = estimator_config(&run_args(&["d.mcap", "--config", toml]), &ds).unwrap();
    assert_eq!(cfg.lidar.ldm, LdmMode::Direct);
    assert_eq!(cfg.lidar.sigma_dr_m, 0.25);
    assert_eq!(cfg.lidar.association.neighbours, 7);

    let cfg = estimator_config(
        &run_args(&[
            "d.mcap",
            "--config",
            toml,
            "--ldm",
            "msc",
            "--no-depth-outlier-rejection",
            "--no-depth-only-opt",
        ]),
        &ds,
    )
    .unwrap();
    let l = cfg.lidar;
    assert_eq!(l.ldm, LdmMode::Msc, "the switch overrides the file");
    assert!(l.enabled && !l.depth_outlier_rejection && !l.depth_only_opt);
    assert_eq!(
        l.sigma_dr_m, 0.25,
        "keys without a switch keep the file's value"
    );

    let cfg = estimator_config(&run_args(&["d.mcap", "--no-lidar"]), &ds).unwrap();
    assert!(!cfg.lidar.enabled);
    assert!(RunCli::try_parse_from(["run", "d.mcap", "--ldm", "msc-based"]).is_err());
}

#[test]
fn replay_pushes_each_sweep_after_the_imu_passed_its_last_point() {
    big_stack(replay_pushes_sweeps);
}

fn replay_pushes_sweeps() {
    let ds = fake_dataset();
    // Triggers are the latest point times, not the last listed point's.
    let due = |td_l_s| -> Vec<Option<i64>> {
        ds.lidar
            .iter()
            .map(|s| povins_core::lidar::sweep_due_ns(&s.points, td_l_s))
            .collect()
    };
    assert_eq!(
        due(0.0),
        [
            Some(T0_NS + 290 * MS),
            Some(T0_NS + 590 * MS),
            Some(T0_NS + 2040 * MS)
        ]
    );
    assert_eq!(due(-0.1)[2], Some(T0_NS + 1940 * MS));

    let cfg = config_for(&ds);
    let out = replay(&ds, cfg, InitMode::Static, &quiet()).unwrap();
    // The third sweep ends 2.04 s after the start, past the last IMU sample (2.0 s): never
    // pushed.
    assert_eq!(out.counters.lidar_scans, 2);
    assert_eq!(out.counters.lidar_points_received, 17);
    assert_eq!(out.lidar_scans, 3);
    assert_eq!(out.lidar, cfg.lidar);

    // With t_imu = t_lidar - 0.1 s the third sweep is complete at IMU time 1.94 s.
    let mut cfg = config_for(&ds);
    cfg.lidar.td_l_s = -0.1;
    let out = replay(&ds, cfg, InitMode::Static, &quiet()).unwrap();
    assert_eq!(out.counters.lidar_scans, 3);
    assert_eq!(out.counters.lidar_points_received, 27);
}

fn simulate(scenario: Scenario, seconds: f64, lidar: Option<LidarKind>) -> Dataset {
    let mut cfg = SimConfig::new(scenario, 5, seconds);
    cfg.lidar = lidar;
    sim::simulate(&cfg, &|_, _, _| {})
        .expect("simulate")
        .dataset
}

#[test]
fn simulator_mcap_round_trip_keeps_sweeps_with_per_point_times() {
    big_stack(mcap_round_trip);
}

fn mcap_round_trip() {
    let ds = simulate(Scenario::Robot, 3.0, None);
    assert!(ds.lidar.len() >= 29, "{} sweeps", ds.lidar.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("robot.mcap");
    povins_platform::mcap_io::write_dataset(&path, &ds).unwrap();
    let back = povins_platform::mcap_io::read_dataset(&path).unwrap();
    assert_eq!(back.lidar, ds.lidar);
    assert_eq!(back.calib.t_bl, ds.calib.t_bl);
    // The evaluation's truth; the per-point LiDAR edge flags (the simulator's statistics) are
    // not written.
    let truth = ds
        .sim_truth
        .clone()
        .map(|t| povins_platform::dataset::SimTruth {
            lidar_edge_points: Vec::new(),
            ..t
        });
    assert_eq!(back.sim_truth, truth);
    // Per-point times span the 100 ms sweep (de-skewing needs them).
    for s in &back.lidar {
        let (lo, hi) = s.points.iter().fold((i64::MAX, i64::MIN), |(lo, hi), p| {
            (lo.min(p.t_ns), hi.max(p.t_ns))
        });
        assert!(
            lo >= s.t_ns && hi < s.t_ns + 100 * MS,
            "{lo} {hi} {}",
            s.t_ns
        );
        assert!(
            hi - lo > 80 * MS,
            "sweep {} spans only {} ns",
            s.t_ns,
            hi - lo
        );
    }
    // And the replay of the file pushes every complete sweep.
    let out = replay(&back, config_for(&back), InitMode::Groundtruth, &quiet()).unwrap();
    let t_last = back.imu.last().unwrap().t_ns;
    let t_first = back.imu.first().unwrap().t_ns;
    let expected: Vec<usize> = back
        .lidar
        .iter()
        .filter(|s| {
            let t = povins_core::lidar::sweep_due_ns(&s.points, 0.0).unwrap_or(s.t_ns);
            t >= t_first && t <= t_last
        })
        .map(|s| s.points.len())
        .collect();
    assert_eq!(out.counters.lidar_scans, expected.len() as u64);
    assert_eq!(
        out.counters.lidar_points_received,
        expected.iter().sum::<usize>() as u64
    );
}

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap()
}

/// `keyframes_state.csv` holds the keyframes of `keyframes.tum` (same stamps and positions) with
/// velocities and biases; from the true initial state they stay near the simulator's truth.
fn check_keyframe_states(out: &Path, ds: &Dataset) {
    let text = std::fs::read_to_string(out.join("keyframes_state.csv")).unwrap();
    let tum = std::fs::read_to_string(out.join("keyframes.tum")).unwrap();
    let tum: Vec<Vec<f64>> = tum
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(text.starts_with("#timestamp [ns],p_wb_x [m]"), "{text}");
    assert_eq!(rows.len(), tum.len());
    assert!(rows.len() > 5);
    for (r, t) in rows.iter().zip(&tum) {
        assert_eq!(r.len(), 17);
        assert!(
            (r[0] * 1e-9 - t[0]).abs() < 1e-6,
            "stamps {} vs {}",
            r[0],
            t[0]
        );
        for k in 0..3 {
            assert!(
                (r[1 + k] - t[1 + k]).abs() < 1e-6,
                "position {r:?} vs {t:?}"
            );
        }
        let g =
            povins_host_tools::runner::interpolate_state(&ds.ground_truth, r[0] as i64).unwrap();
        let dv = (Vec3::new(r[8], r[9], r[10]) - g.v_wb).norm();
        let dba = (Vec3::new(r[14], r[15], r[16]) - g.ba).norm();
        assert!(dv < 0.1, "velocity error {dv} m/s at {}", r[0]);
        assert!(
            dba < 0.1,
            "accelerometer bias error {dba} m/s^2 at {}",
            r[0]
        );
        // A zero column (e.g. a velocity never written) would not be near a moving truth.
        assert!(r[8..11].iter().any(|v| *v != 0.0));
    }
}

#[test]
fn run_writes_the_lidar_columns_and_summary_keys() {
    let dir = tempfile::tempdir().unwrap();
    let mcap = dir.path().join("robot.mcap");
    let ds = simulate(Scenario::Robot, 6.0, None);
    povins_platform::mcap_io::write_dataset(&mcap, &ds).unwrap();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = povins(&[
        "run",
        mcap.to_str().unwrap(),
        "--init",
        "groundtruth",
        "--ldm",
        "direct",
        "--no-depth-only-opt",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("LiDAR     60 sweeps, DIRECT LDM, rejection on, depth-only opt off"),
        "{stdout}"
    );
    assert!(stdout.contains("assoc     "), "{stdout}");

    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    let header: Vec<&str> = stats.lines().next().unwrap().split(',').collect();
    assert_eq!(header[0], "t_s");
    assert_eq!(
        header[19], "termination",
        "existing columns keep their place"
    );
    let lidar: Vec<&str> = STATS_LIDAR_COLUMNS.split(',').collect();
    assert_eq!(&header[20..20 + lidar.len()], &lidar[..]);
    assert_eq!(
        lidar,
        [
            "lidar_points",
            "depths_associated",
            "depths_rejected",
            "ldm_count",
            "association_ms",
            "rejection_ms",
            "depth_opt_ms",
            "lidar_cropped",
            "lidar_lost",
            "lidar_thinned"
        ]
    );
    let rows: Vec<&str> = stats.lines().skip(1).collect();
    assert!(rows.len() > 5);
    assert!(rows.iter().all(|r| r.split(',').count() == header.len()));
    // `povins plot` reads it by column name.
    let samples = povins_host_tools::plot::read_stats_csv(&out.join("stats.csv")).unwrap();
    assert_eq!(samples.len(), rows.len());

    check_keyframe_states(&out, &ds);

    // `config.toml` is the run's effective configuration: given back as `--config` (without the
    // switches), it gives the same configuration, bit for bit.
    let loaded = povins_platform::read_dataset(&mcap).unwrap();
    let m = mcap.to_str().unwrap();
    let effective = out.join("config.toml");
    let text = std::fs::read_to_string(&effective).unwrap();
    assert!(text.contains("[lidar.association]"), "{text}");
    let cfg = estimator_config(
        &run_args(&[m, "--ldm", "direct", "--no-depth-only-opt"]),
        &loaded,
    );
    let back = estimator_config(
        &run_args(&[m, "--config", effective.to_str().unwrap()]),
        &loaded,
    );
    assert_eq!(
        format!("{:?}", cfg.unwrap()),
        format!("{:?}", back.unwrap())
    );

    let s = json(&out.join("summary.json"));
    assert_eq!(s["lidar"], true);
    assert_eq!(s["ldm"], "direct");
    assert_eq!(s["depth_outlier_rejection"], true);
    assert_eq!(s["depth_only_opt"], false);
    assert_eq!(s["lidar_scans"], 60);
    for k in [
        "depths_associated_per_kf",
        "depths_rejected_per_kf",
        "ldm_per_kf",
        "association_ms_median",
        "rejection_ms_median",
        "rejection_ms_max",
        "depth_opt_ms_median",
        "depth_opt_ms_max",
    ] {
        assert!(s[k].as_f64().is_some_and(f64::is_finite), "{k}: {}", s[k]);
    }
    // Simulator truth is in the MCAP: the association check is reported.
    assert!(s["assoc_checked"].as_u64().is_some(), "{s}");
    for k in [
        "assoc_within_3sigma_before",
        "assoc_within_3sigma_after",
        "edge_share_before",
        "edge_share_after",
    ] {
        assert!(s.get(k).is_some(), "{k} missing");
    }
}

#[test]
fn lidar_switches_on_a_dataset_without_lidar_only_note_it() {
    let dir = tempfile::tempdir().unwrap();
    let mcap = dir.path().join("nolidar.mcap");
    let ds = simulate(Scenario::Robot, 3.0, Some(LidarKind::None));
    assert!(ds.lidar.is_empty());
    povins_platform::mcap_io::write_dataset(&mcap, &ds).unwrap();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = povins(&[
        "run",
        mcap.to_str().unwrap(),
        "--init",
        "groundtruth",
        "--no-depth-outlier-rejection",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("no LiDAR in dataset"), "{stderr}");
    assert!(stdout.contains("LiDAR     none in the dataset"), "{stdout}");
    let s = json(&out.join("summary.json"));
    assert_eq!(s["lidar"], false);
    assert_eq!(s["lidar_scans"], 0);
}

#[test]
fn demo_runs_with_lidar_by_default_and_without_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = out.to_str().unwrap();
    let (ok, stdout, stderr) = povins(&["demo", "--duration", "4", "--out", o]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("LiDAR     40 sweeps, MSC LDM, rejection on, depth-only opt on"),
        "{stdout}"
    );
    assert_eq!(json(&out.join("summary.json"))["lidar"], true);
    let (ok, stdout, stderr) = povins(&["demo", "--duration", "4", "--out", o, "--no-lidar"]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("LiDAR     off (40 sweeps"), "{stdout}");
    assert_eq!(json(&out.join("summary.json"))["lidar"], false);
}

#[test]
fn ablation_runs_every_variant_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("abl");
    let (ok, stdout, stderr) = povins(&[
        "ablation",
        "--scenarios",
        "robot",
        "--seeds",
        "3",
        "--duration",
        "8",
        "--jobs",
        "2",
        "--lidar",
        "vlp16",
        "--json",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let printed: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let j = json(&out.join("ablation.json"));
    assert_eq!(printed, j);
    assert_eq!(j["lidar"], "vlp16");
    let names: Vec<&str> = Variant::ALL.iter().map(|v| v.name()).collect();
    let rows: Vec<&str> = j["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["variant"].as_str().unwrap())
        .collect();
    assert_eq!(rows, names);
    let runs = j["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 5);
    for (r, name) in runs.iter().zip(&names) {
        assert_eq!(r["variant"], *name);
        assert_eq!(
            (r["scenario"].as_str(), r["seed"].as_u64()),
            (Some("robot"), Some(3))
        );
        assert!(r["keyframes"].as_u64().unwrap() > 10, "{r}");
        let ate = r["ate_pos_rmse_m"].as_f64().unwrap();
        assert!(ate.is_finite() && ate > 0.0 && ate < 5.0, "{r}");
        // Every variant is offered every complete sweep (PO-VINS-WO refuses them).
        assert_eq!(r["lidar_scans_pushed"], 80, "{r}");
        assert!(r["assoc"].is_object(), "{r}");
    }
    for row in j["rows"].as_array().unwrap() {
        assert_eq!(row["ate"][0]["scenario"], "robot");
        assert_eq!(row["ate"][0]["evaluated"], 1);
    }
    assert_eq!(j["rows"][0]["ate_change_vs_po_vins_pct"], 0.0);
    let md = std::fs::read_to_string(out.join("ablation.md")).unwrap();
    for n in &names {
        assert!(md.contains(&format!("| {n} |")), "{n} missing:\n{md}");
    }
    assert!(stderr.contains("robot seed 3 po-vins-wo"), "{stderr}");
    assert!(md.contains("LiDAR vlp16;"), "{md}");
}

#[test]
fn ablation_accuracy_does_not_depend_on_jobs() {
    let run = |jobs| {
        let cfg = AblationConfig {
            scenarios: vec![Scenario::Handheld],
            seeds: vec![2, 4],
            duration_s: 5.0,
            jobs,
            lidar_extrinsic_error_deg: 0.5,
            foliage_porosity: 0.0,
            lidar: None,
        };
        run_ablation(&cfg, None, &quiet()).expect("ablation")
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.runs.len(), 10);
    // Stored seed-major in variant order whatever order the workers ran them in.
    for (k, (x, y)) in a.runs.iter().zip(&b.runs).enumerate() {
        assert_eq!(x.variant, Variant::ALL[k % 5]);
        assert_eq!(x.seed, [2, 4][k / 5]);
        assert_eq!((x.variant, x.seed), (y.variant, y.seed));
        assert_eq!(x.keyframes, y.keyframes);
        assert_eq!(
            x.ate_pos_rmse_m.map(f64::to_bits),
            y.ate_pos_rmse_m.map(f64::to_bits),
            "{:?}",
            x.variant
        );
        assert_eq!(x.assoc, y.assoc);
        assert_eq!(
            (x.depths_associated, x.depths_rejected, x.ldm_total),
            (y.depths_associated, y.depths_rejected, y.ldm_total)
        );
    }
    // A mix-up of the result slots would show: the seeds' sequences differ.
    assert_ne!(a.runs[0].ate_pos_rmse_m, a.runs[5].ate_pos_rmse_m);
    for (x, y) in a.rows.iter().zip(&b.rows) {
        assert_eq!(
            x.ate_mean_m.map(f64::to_bits),
            y.ate_mean_m.map(f64::to_bits)
        );
    }
    assert!(run_ablation(
        &AblationConfig {
            scenarios: vec![Scenario::Robot, Scenario::Robot],
            seeds: vec![1],
            duration_s: 2.0,
            jobs: 1,
            lidar_extrinsic_error_deg: 0.5,
            foliage_porosity: 0.0,
            lidar: None,
        },
        None,
        &quiet()
    )
    .is_err());
}

/// An OS1-128 (1024 x 128 at 10 Hz: about 56,000 points a sweep inside the crop to the camera's
/// view, 280,000 in the association's 0.5 s against the buffer's 131,072) is thinned, not
/// evicted: nothing younger than the span is lost, the depths are still associated, and each
/// keyframe's `lidar_points_thinned_total` counts what its sweeps dropped. The robot's Livox
/// (below the rate the buffer holds) is not thinned.
#[test]
fn a_lidar_faster_than_the_buffer_is_thinned_not_evicted() {
    big_stack(thinned_not_evicted);
}

fn thinned_not_evicted() {
    let ds = simulate(Scenario::Robot, 3.0, Some(LidarKind::Os1_128));
    let out = replay(&ds, config_for(&ds), InitMode::Groundtruth, &quiet()).unwrap();
    let c = &out.counters;
    assert!(c.lidar_points_thinned > c.lidar_points_accepted, "{c:?}");
    assert_eq!(c.lidar_points_evicted_in_span, 0, "{c:?}");
    assert!(
        c.lidar_points_outside_view + c.lidar_points_thinned + c.lidar_points_accepted
            <= c.lidar_points_received,
        "{c:?}"
    );
    let depths: u32 = out.reports.iter().map(|r| r.depths_associated).sum();
    assert!(
        depths as usize > 10 * out.reports.len(),
        "{depths} depths over {} keyframes",
        out.reports.len()
    );
    let last = out.reports.last().unwrap();
    assert!(last.lidar_points_thinned_total > 0);
    assert!(last.lidar_points_thinned_total <= c.lidar_points_thinned);

    let livox = simulate(Scenario::Robot, 3.0, None);
    let out = replay(&livox, config_for(&livox), InitMode::Groundtruth, &quiet()).unwrap();
    assert_eq!(out.counters.lidar_points_thinned, 0, "{:?}", out.counters);
    assert!(out.counters.lidar_points_accepted > 0);
}

/// A LiDAR whose clock runs 40 ms behind the IMU's (`povins simulate --lidar-td-ms 40`): the
/// recording's calibration carries the offset (MCAP `td_l_s`), the run applies it, and the
/// estimate is the one of the same sequence without an offset, bit for bit (every point is on
/// the same IMU-clock instant); the offset ignored (`[lidar] td_l_s = 0`), it is not.
#[test]
fn a_lidar_time_offset_in_the_recording_is_applied() {
    big_stack(lidar_time_offset);
}

fn lidar_time_offset() {
    let sim = |td_l_s: f64| {
        let mut cfg = SimConfig::new(Scenario::Robot, 5, 6.0);
        cfg.lidar_td_s = td_l_s;
        sim::simulate(&cfg, &|_, _, _| {})
            .expect("simulate")
            .dataset
    };
    let (zero, late) = (sim(0.0), sim(0.04));
    assert_eq!(late.calib.td_l_s, 0.04);
    let stamps = |ds: &Dataset| ds.lidar.iter().map(|s| s.t_ns).collect::<Vec<_>>();
    let shifted: Vec<i64> = stamps(&zero).iter().map(|t| t - 40 * MS).collect();
    assert_eq!(stamps(&late), shifted);
    // Both through MCAP (feature pixels travel as float32).
    let dir = tempfile::tempdir().unwrap();
    let through_mcap = |ds: &Dataset, name: &str| {
        let path = dir.path().join(name);
        povins_platform::mcap_io::write_dataset(&path, ds).unwrap();
        povins_platform::mcap_io::read_dataset(&path).unwrap()
    };
    let (zero, back) = (
        through_mcap(&zero, "zero.mcap"),
        through_mcap(&late, "late.mcap"),
    );
    assert_eq!(back.calib.td_l_s, 0.04);
    let cfg = config_for(&back);
    assert_eq!(cfg.lidar.td_l_s, 0.04);

    let run = |ds: &Dataset, cfg| replay(ds, cfg, InitMode::Groundtruth, &quiet()).unwrap();
    let reference = run(&zero, config_for(&zero));
    let applied = run(&back, cfg);
    assert!(
        reference
            .lidar_events
            .iter()
            .map(|k| k.events.len())
            .sum::<usize>()
            > 100
    );
    // (Compared as booleans: the events' Debug form runs to megabytes.)
    assert!(applied.lidar_events == reference.lidar_events);
    assert!(applied.keyframe_states == reference.keyframe_states);
    let mut ignored_cfg = cfg;
    ignored_cfg.lidar.td_l_s = 0.0;
    let ignored = run(&back, ignored_cfg);
    assert!(ignored.keyframe_states != reference.keyframe_states);
}

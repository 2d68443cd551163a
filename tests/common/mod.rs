//! Helpers shared by the estimator integration tests: data loading (failing loudly, naming the
//! path, when the shared data is missing), the EuRoC configuration, ground-truth starts, a
//! replay loop identical in its ordering to `runner::replay` (a frame is offered once the IMU
//! stream has reached its stamp), and ATE.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code)]

pub mod golden;

use povins::core::estimator::{EstimatorConfig, ImuOutput, PoVins, VisualMode};
use povins::core::inertial::{ImuSample, NavState};
use povins::core::lidar::{sweep_due_ns, LidarPoint};
use povins::host_tools::config::RunConfigFile;
use povins::host_tools::eval::{evaluate, EvalOptions};
use povins::host_tools::progress::Progress;
use povins::host_tools::runner::{config_for, interpolate_state};
use povins::host_tools::sim::{simulate, LidarKind, Scenario, SimConfig};
use povins::platform::dataset::Dataset;
use povins::platform::trajectory::StampedPose;
use std::path::{Path, PathBuf};

/// The shared data folder (large sequences), relative to the repository root.
pub const DATA_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");
/// Small sequences kept in the repository (`tests/data/README.md`).
pub const REPO_DATA_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");
/// The EuRoC settings every EuRoC run uses.
pub const EUROC_TOML: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/euroc.toml");
/// EuRoC V1_01, first 30 s, with a real front end's tracks.
pub const EUROC_30S: &str = "euroc-v101-30s-features";
/// The OpenVINS simulator's corridor sequence (mono tracks, 400 Hz IMU).
pub const OPENVINS_CORRIDOR: &str = "openvins-sim-corridor-mono";

/// A data set folder: the repository's copy (`tests/data`) when there is one, else the shared
/// one; panics naming the path when it is missing (tests on shared data are `#[ignore]`d).
pub fn data_dir(name: &str) -> PathBuf {
    let repo = Path::new(REPO_DATA_DIR).join(name);
    if repo.join("mav0").is_dir() {
        return repo;
    }
    let p = Path::new(DATA_DIR).join(name);
    assert!(
        p.join("mav0").is_dir(),
        "shared data set {} is missing (expected an EuRoC ASL folder with mav0/)",
        p.display()
    );
    p
}

/// Reads a shared EuRoC-layout data set.
pub fn load(name: &str) -> Dataset {
    let dir = data_dir(name);
    povins::platform::euroc::read_dataset(&dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
}

/// Keeps only the first `secs` seconds (from the first IMU sample) of every stream.
pub fn truncate(ds: &mut Dataset, secs: f64) {
    let t_end = ds.imu[0].t_ns + (secs * 1e9) as i64;
    ds.imu.retain(|s| s.t_ns <= t_end);
    ds.features.retain(|f| f.t_ns <= t_end);
    ds.ground_truth.retain(|g| g.t_ns <= t_end);
    ds.lidar.retain(|l| l.t_ns <= t_end);
}

/// `config_for` + `configs/euroc.toml`, in the given visual mode.
pub fn euroc_config(ds: &Dataset, mode: VisualMode) -> EstimatorConfig {
    let mut cfg = config_for(ds);
    let file = RunConfigFile::read(Path::new(EUROC_TOML))
        .unwrap_or_else(|e| panic!("cannot read {EUROC_TOML}: {e:#}"));
    file.apply(&mut cfg)
        .unwrap_or_else(|e| panic!("cannot apply {EUROC_TOML}: {e:#}"));
    cfg.mode = mode;
    cfg
}

/// A simulated robot run without LiDAR (the estimator does not use it; this saves time).
pub fn simulate_robot(seed: u64, secs: f64) -> Dataset {
    let mut sc = SimConfig::new(Scenario::Robot, seed, secs);
    sc.lidar = Some(LidarKind::None);
    simulate(&sc, &|_, _, _| {})
        .unwrap_or_else(|e| panic!("simulation failed: {e:#}"))
        .dataset
}

/// A progress bar that draws nothing.
pub fn quiet() -> Progress {
    Progress::with_visibility(0, "", false)
}

/// The ground-truth start as `runner::replay` does it for `--init groundtruth`: the index of
/// the first IMU sample covered by ground truth and the interpolated true state there. Also
/// tightens the first keyframe's prior the same way.
pub fn gt_start(ds: &Dataset, cfg: &mut EstimatorConfig) -> (usize, NavState) {
    let g0 = ds
        .ground_truth
        .first()
        .expect("the data set has ground truth");
    let start = ds
        .imu
        .iter()
        .position(|s| s.t_ns >= g0.t_ns)
        .expect("an IMU sample after the first ground-truth state");
    let t = ds.imu[start].t_ns;
    let st = interpolate_state(&ds.ground_truth, t).expect("ground truth at the start");
    cfg.first_prior.theta_rad = 2e-3;
    cfg.first_prior.v_mps = 0.01;
    cfg.first_prior.bg_rps = 1e-4;
    cfg.first_prior.ba_mps2 = 0.01;
    (start, NavState { t_ns: t, ..st })
}

/// Replays `imu[start..]` with the frames in time order, as `runner::replay` does: every frame
/// whose stamp the current IMU sample has reached is pushed before the sample, then the sample,
/// and the estimator's queue is drained (`update`). `on_out` sees every processed sample's output
/// (and the estimator after it) and returns `false` to stop. Allocation-free itself.
pub fn drive(
    est: &mut PoVins,
    imu: &[ImuSample],
    frames: &[(i64, &[povins::core::camera::FeatureObs])],
    on_out: impl FnMut(&mut PoVins, &ImuSample, &ImuOutput) -> bool,
) {
    drive_lidar(est, imu, frames, &[], on_out)
}

/// [`drive`] with LiDAR sweeps `(t_last_point_ns, points)` (sorted by time): a sweep is pushed
/// once the IMU stream has reached its last point, as `runner::replay` does (the core de-skews it
/// when it processes that sample).
pub fn drive_lidar(
    est: &mut PoVins,
    imu: &[ImuSample],
    frames: &[(i64, &[povins::core::camera::FeatureObs])],
    sweeps: &[(i64, &[LidarPoint])],
    mut on_out: impl FnMut(&mut PoVins, &ImuSample, &ImuOutput) -> bool,
) {
    let t0 = imu.first().map_or(i64::MIN, |s| s.t_ns);
    let mut fi = frames.partition_point(|f| f.0 < t0);
    let mut li = sweeps.partition_point(|w| w.0 < t0);
    for s in imu {
        while let Some(f) = frames.get(fi).filter(|f| f.0 <= s.t_ns) {
            let _ = est.push_frame(f.0, f.1);
            fi += 1;
        }
        let _ = est.push_imu(s);
        while let Some(w) = sweeps.get(li).filter(|w| w.0 <= s.t_ns) {
            let _ = est.push_lidar(w.1);
            li += 1;
        }
        while let Some(o) = step(est) {
            if !on_out(est, s, &o) {
                return;
            }
        }
    }
}

/// The output of the estimator's next due sample (errors skipped, as a replay does).
pub fn step(est: &mut PoVins) -> Option<ImuOutput> {
    loop {
        match est.update() {
            Ok(o) => return o,
            Err(_) => continue,
        }
    }
}

/// The LiDAR sweeps of a data set as `(when the sweep is due, points)`, sorted, for
/// [`drive_lidar`]: due as the core decides it ([`sweep_due_ns`], with the LiDAR delay of the
/// data set's configuration), the sweep's own stamp for a sweep without points.
pub fn sweeps_of(ds: &Dataset) -> Vec<(i64, &[LidarPoint])> {
    let td_l_s = config_for(ds).lidar.td_l_s;
    let mut v: Vec<(i64, &[LidarPoint])> = ds
        .lidar
        .iter()
        .map(|s| {
            let t = sweep_due_ns(&s.points, td_l_s).unwrap_or(s.t_ns);
            (t, s.points.as_slice())
        })
        .collect();
    v.sort_by_key(|w| w.0);
    v
}

/// A simulated run with the scenario's default LiDAR (edge outliers on).
pub fn simulate_with_lidar(sc: Scenario, seed: u64, secs: f64) -> Dataset {
    simulate(&SimConfig::new(sc, seed, secs), &|_, _, _| {})
        .unwrap_or_else(|e| panic!("simulation failed: {e:#}"))
        .dataset
}

/// The configuration for a simulated data set with LiDAR enhancement on or off (the paper's
/// defaults: MSC LDM, rejection and depth-only optimization on).
pub fn sim_lidar_config(ds: &Dataset, on: bool) -> EstimatorConfig {
    let mut cfg = config_for(ds);
    let t_bl = ds.calib.t_bl.expect("the simulated data set has a LiDAR");
    cfg.lidar.enabled = on;
    cfg.lidar.extrinsic = povins::core::lidar::LidarExtrinsic {
        q_bl: t_bl.q_ab,
        p_bl: t_bl.p_ab,
    };
    cfg
}

/// The frames of a data set as `(t_cam_ns, observations)` slices for [`drive`].
pub fn frames_of(ds: &Dataset) -> Vec<(i64, &[povins::core::camera::FeatureObs])> {
    ds.features
        .iter()
        .map(|f| (f.t_ns, f.obs.as_slice()))
        .collect()
}

/// Bit patterns of a whole state (time, position, attitude, velocity, biases) for exact
/// comparison (`NaN`-safe, `-0.0 != 0.0`).
pub fn state_bits(s: &NavState) -> Vec<u64> {
    let mut b = vec![s.t_ns as u64];
    b.extend(
        s.p_wb
            .iter()
            .chain(s.q_wb.coords.iter())
            .chain(s.v_wb.iter())
            .chain(s.bg.iter())
            .chain(s.ba.iter())
            .map(|v| v.to_bits()),
    );
    b
}

/// A new boxed estimator.
pub fn new_estimator(cfg: EstimatorConfig) -> Box<PoVins> {
    povins::platform::boxed::boxed_povins(cfg).expect("a valid estimator configuration")
}

/// Position ATE RMSE (position + yaw alignment, evo's matching rules) of `states` against the
/// data set's ground truth.
pub fn ate_m(ds: &Dataset, states: &[NavState]) -> f64 {
    let gt: Vec<StampedPose> = ds.ground_truth.iter().map(StampedPose::from).collect();
    let est: Vec<StampedPose> = states.iter().map(StampedPose::from).collect();
    evaluate(&gt, &est, &EvalOptions::default())
        .unwrap_or_else(|e| panic!("evaluation failed: {e:#}"))
        .ate_pos_m
        .rmse
}

/// Position ATE RMSE after an SE3 alignment (evo's `-a`, the figure issue 13's bar uses).
pub fn ate_se3_m(ds: &Dataset, states: &[NavState]) -> f64 {
    let gt: Vec<StampedPose> = ds.ground_truth.iter().map(StampedPose::from).collect();
    let est: Vec<StampedPose> = states.iter().map(StampedPose::from).collect();
    let opts = EvalOptions {
        alignment: povins::host_tools::eval::Alignment::Se3,
        ..EvalOptions::default()
    };
    evaluate(&gt, &est, &opts)
        .unwrap_or_else(|e| panic!("evaluation failed: {e:#}"))
        .ate_pos_m
        .rmse
}

/// True when every number of the state is finite.
pub fn state_is_finite(s: &NavState) -> bool {
    [s.p_wb, s.v_wb, s.bg, s.ba]
        .iter()
        .all(|v| v.iter().all(|x| x.is_finite()))
        && s.q_wb.coords.iter().all(|x| x.is_finite())
}

/// Stack of the threads the tests run the estimator on: half the test harness's default. The
/// estimator (5.6 MB) and the image front end are built on the heap ([`new_estimator`],
/// `povins::platform::boxed`), so a test that overflows this has put one on the stack.
pub const TEST_STACK: usize = 1 << 20;

/// Runs `f` on a thread with a `bytes` stack and propagates its panic.
pub fn on_stack<T: Send>(bytes: usize, f: impl FnOnce() -> T + Send) -> T {
    std::thread::scope(|s| {
        let h = std::thread::Builder::new()
            .stack_size(bytes)
            .spawn_scoped(s, f)
            .expect("spawn a test thread");
        match h.join() {
            Ok(v) => v,
            Err(p) => std::panic::resume_unwind(p),
        }
    })
}

/// Runs `f` on a thread with a [`TEST_STACK`] stack and propagates its panic.
pub fn small_stack<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    on_stack(TEST_STACK, f)
}

/// Every stamp at or after `at_ns` moved by `by_ns`, in every stream and the ground truth.
pub fn jumped(ds: &Dataset, at_ns: i64, by_ns: i64) -> Dataset {
    let mut d = ds.clone();
    let shift = |t: &mut i64| {
        if *t >= at_ns {
            *t += by_ns;
        }
    };
    d.imu.iter_mut().for_each(|s| shift(&mut s.t_ns));
    d.features.iter_mut().for_each(|f| shift(&mut f.t_ns));
    d.ground_truth.iter_mut().for_each(|g| shift(&mut g.t_ns));
    d
}

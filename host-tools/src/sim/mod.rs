//! Deterministic simulator of camera + IMU + LiDAR sequences with ground truth.
//!
//! Pipeline: a carrier [`trajectory`] with exact derivatives drives the [`imu`] model and gives
//! the ground truth at IMU rate; a procedural [`scene`] is built around the path; the [`camera`]
//! tracker and the [`lidar`] both ray-cast the same [`world`], and [`render`] draws grayscale
//! camera images of it (on request, after the simulation) with ground truth for image tracking. Everything random comes from
//! [`rng`] streams derived from the seed, so a seed fully determines the output (independent of
//! the number of threads used for the LiDAR sweeps).
//!
//! Clocks: the IMU and the LiDAR share the reference clock, starting at [`T0_NS`]. Images are
//! taken on the IMU sample grid and stamped on the camera clock `t_cam = t_imu - td`
//! (LE-VINS convention `t_imu = t_cam + td`), the true `td` is stored in the calibration (with a
//! [`TdStep`], the delay before the step). A sequence can start in motion: [`window`] drops
//! what precedes [`SimConfig::start_s`].
//! The LiDAR is cast with the true mounting `T_bl * Exp(err)`, while the calibration stores the
//! nominal `T_bl`, so LiDAR depth attached to features near object edges can hit the background.

pub mod camera;
pub mod imu;
pub mod lidar;
pub mod render;
pub mod rng;
pub mod scenario;
pub mod scene;
pub mod trajectory;
pub mod window;
pub mod world;

pub use scenario::{LidarKind, Scenario};
pub use window::{motion_start_s, KeptFrames, TdStep};

use camera::{CameraSim, CameraTruth};
use lidar::{LidarParams, SweepOut};
use povins_core::math::{quat_exp, Vec3};
use povins_platform::dataset::{Calibration, Dataset, Extrinsic, FeatureFrame, SimTruth};
use rng::Rng;
use trajectory::Trajectory;
use world::World;

/// Time of the first IMU sample, ns (non-zero so consumers cannot rely on a zero origin).
pub const T0_NS: i64 = 1_000_000_000;

const STREAM_IMU: u64 = 1;
const STREAM_WORLD: u64 = 2;
const STREAM_LANDMARKS: u64 = 3;
const STREAM_CAMERA: u64 = 4;
const STREAM_LIDAR: u64 = 5;
const STREAM_EXTRINSIC: u64 = 6;

/// Simulation settings. [`SimConfig::new`] gives the scenario defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Carrier kind.
    pub scenario: Scenario,
    /// Random seed.
    pub seed: u64,
    /// Sequence length, s.
    pub duration_s: f64,
    /// Time at rest at the start, s.
    pub static_s: f64,
    /// Camera-IMU time offset `td` (`t_imu = t_cam + td`), s.
    pub td_s: f64,
    /// A step of `td` during the run (`None`: constant).
    pub td_step: Option<TdStep>,
    /// Rolling-shutter readout time of the camera, s (0: global shutter): each feature is seen
    /// at the time of its row ([`povins_core::camera::PinholeCamera::row_time_s`]), and the
    /// dataset's camera carries the value.
    pub readout_s: f64,
    /// Time dropped at the start, s (seconds from the first IMU sample; 0: the whole sequence,
    /// from the rest). See [`window`].
    pub start_s: f64,
    /// LiDAR-IMU time offset `td_l` (`t_imu = t_lidar + td_l`), s: each LiDAR point is
    /// stamped with its instant on the IMU clock minus `td_l`; the calibration carries it.
    pub lidar_td_s: f64,
    /// LiDAR to simulate (`None` = scenario default).
    pub lidar: Option<LidarKind>,
    /// Points per sweep (rosette) or points per sweep rounded to whole columns (spinning).
    pub lidar_points: Option<usize>,
    /// Rotation error of the true LiDAR mounting w.r.t. the nominal calibration, deg.
    pub lidar_extrinsic_error_deg: f64,
    /// Translation error of the true LiDAR mounting, m.
    pub lidar_extrinsic_error_m: f64,
    /// LiDAR range noise (1 sigma), m.
    pub lidar_range_noise_m: f64,
    /// Probability that a LiDAR ray passes through a tree crown, in `[0, 1]`.
    pub foliage_porosity: f64,
    /// Fraction of new tracks that become wrong tracks (`None` = scenario default).
    pub wrong_track_rate: Option<f64>,
    /// Tracked-feature cap (`None` = scenario default).
    pub max_features: Option<usize>,
    /// Pixel noise (1 sigma), px.
    pub pixel_noise_px: f64,
    /// Worker threads for the LiDAR (0 = all available).
    pub threads: usize,
}

impl SimConfig {
    /// Defaults for a scenario.
    pub fn new(scenario: Scenario, seed: u64, duration_s: f64) -> Self {
        SimConfig {
            scenario,
            seed,
            duration_s,
            static_s: 1.0,
            td_s: 0.0,
            td_step: None,
            readout_s: 0.0,
            start_s: 0.0,
            lidar_td_s: 0.0,
            lidar: None,
            lidar_points: None,
            lidar_extrinsic_error_deg: 0.5,
            lidar_extrinsic_error_m: 0.03,
            lidar_range_noise_m: 0.02,
            foliage_porosity: 0.0,
            wrong_track_rate: None,
            max_features: None,
            pixel_noise_px: 1.0,
            threads: 0,
        }
    }
}

/// Numbers describing a simulated sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Sequence length, s.
    pub duration_s: f64,
    /// Path length, m.
    pub distance_m: f64,
    /// Speed range after the start-up ramp, m/s.
    pub speed_range_mps: (f64, f64),
    /// Largest body angular rate, rad/s.
    pub max_rate_rps: f64,
    /// IMU samples.
    pub imu_samples: usize,
    /// Camera frames.
    pub frames: usize,
    /// Mean features per frame.
    pub mean_features: f64,
    /// Feature tracks (ids).
    pub tracks: usize,
    /// Mean observations per track.
    pub mean_track_len: f64,
    /// Landmarks in the world.
    pub landmarks: usize,
    /// Primitives in the world.
    pub primitives: usize,
    /// LiDAR sweeps.
    pub scans: usize,
    /// LiDAR points.
    pub points: usize,
    /// Wrong tracks.
    pub wrong_tracks: usize,
    /// Features on occlusion edges.
    pub edge_features: usize,
    /// LiDAR points on depth discontinuities.
    pub lidar_edge_points: usize,
    /// LiDAR returns (before `--start-s`) that their beam's footprint moved more than 5 cm off
    /// the axis ray's surface: mixed returns, or the stronger of two surfaces.
    pub lidar_footprint_moved: usize,
}

impl core::fmt::Display for Summary {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        writeln!(f, "duration        {:.1} s", self.duration_s)?;
        writeln!(
            f,
            "distance        {:.1} m (speed {:.2}-{:.2} m/s after start-up, max rate {:.0} deg/s)",
            self.distance_m,
            self.speed_range_mps.0,
            self.speed_range_mps.1,
            self.max_rate_rps.to_degrees()
        )?;
        writeln!(
            f,
            "world           {} primitives, {} landmarks",
            self.primitives, self.landmarks
        )?;
        writeln!(f, "IMU             {} samples", self.imu_samples)?;
        writeln!(
            f,
            "camera          {} frames, {:.1} features/frame",
            self.frames, self.mean_features
        )?;
        writeln!(
            f,
            "tracks          {} (mean length {:.1} frames)",
            self.tracks, self.mean_track_len
        )?;
        writeln!(
            f,
            "LiDAR           {} scans, {} points",
            self.scans, self.points
        )?;
        write!(
            f,
            "edge cases      {} wrong tracks, {} edge features, {} LiDAR edge points ({} moved \
             by their beam's footprint: mixed returns)",
            self.wrong_tracks,
            self.edge_features,
            self.lidar_edge_points,
            self.lidar_footprint_moved
        )
    }
}

/// A simulated sequence plus what evaluation and tests need beyond the [`Dataset`].
#[derive(Debug, Clone)]
pub struct SimOutput {
    /// The sequence.
    pub dataset: Dataset,
    /// The carrier trajectory (trajectory time 0 = [`T0_NS`]).
    pub trajectory: Trajectory,
    /// The world geometry.
    pub world: World,
    /// The true LiDAR mounting used for casting (the calibration holds the nominal one).
    pub t_bl_true: Option<Extrinsic>,
    /// Summary numbers.
    pub summary: Summary,
    /// The camera frames of `dataset.features`: their exposure times on the IMU clock and index
    /// in the uncropped sequence.
    pub frames: KeptFrames,
}

/// Progress report: `(stage, done, total)`.
pub type Progress<'a> = &'a (dyn Fn(&'static str, usize, usize) + Sync);

/// Samples the path about every metre, from the start to `lookahead_m` beyond the end of the
/// sequence (the camera sees ahead of the carrier).
fn path_samples(traj: &Trajectory, duration_s: f64, lookahead_m: f64) -> Vec<Vec3> {
    let s_last = traj.warp.eval(duration_s)[0];
    let s_end = s_last + lookahead_m / traj.path(s_last)[1].norm().max(0.05);
    let mut out = vec![traj.path(0.0)[0]];
    let mut s = 0.0;
    while s < s_end {
        let speed = traj.path(s)[1].norm().max(0.05);
        s = (s + 1.0 / speed).min(s_end.max(s + 1e-3));
        out.push(traj.path(s)[0]);
    }
    if out.len() < 2 {
        out.push(out[0] + Vec3::new(1.0, 0.0, 0.0));
    }
    out
}

/// Runs the whole simulation.
pub fn simulate(cfg: &SimConfig, progress: Progress<'_>) -> anyhow::Result<SimOutput> {
    anyhow::ensure!(
        cfg.duration_s.is_finite() && cfg.duration_s > 0.0,
        "duration must be positive"
    );
    anyhow::ensure!(
        cfg.static_s.is_finite() && cfg.static_s >= 0.0,
        "static time must be >= 0"
    );
    anyhow::ensure!(
        cfg.td_s.is_finite() && cfg.td_s.abs() < 1.0,
        "|td| must be < 1 s"
    );
    anyhow::ensure!(
        cfg.lidar_td_s.is_finite() && cfg.lidar_td_s.abs() < 1.0,
        "|LiDAR td| must be < 1 s"
    );
    anyhow::ensure!(
        cfg.start_s.is_finite() && cfg.start_s >= 0.0 && cfg.start_s < cfg.duration_s,
        "the start ({} s) must be within [0, duration = {} s)",
        cfg.start_s,
        cfg.duration_s
    );
    if let Some(st) = &cfg.td_step {
        anyhow::ensure!(
            st.step_s.is_finite() && (cfg.td_s + st.step_s).abs() < 1.0,
            "|td + step| must be < 1 s"
        );
        anyhow::ensure!(
            st.at_s.is_finite() && st.at_s >= 0.0,
            "the delay step's time must be >= 0"
        );
    }
    anyhow::ensure!(
        (0.0..=povins_core::camera::MAX_READOUT_S).contains(&cfg.readout_s),
        "the readout time ({} s) must be within [0, {} s]",
        cfg.readout_s,
        povins_core::camera::MAX_READOUT_S
    );
    let mut pre = scenario::preset(cfg.scenario, cfg.static_s);
    pre.camera.readout_s = cfg.readout_s;
    anyhow::ensure!(
        (0.0..=1.0).contains(&cfg.foliage_porosity),
        "foliage porosity must be in [0, 1], got {}",
        cfg.foliage_porosity
    );
    if let Some(r) = cfg.wrong_track_rate {
        anyhow::ensure!(
            (0.0..=1.0).contains(&r),
            "wrong-track rate must be in [0, 1]"
        );
        pre.tracker.wrong_track_rate = r;
    }
    if let Some(m) = cfg.max_features {
        pre.tracker.max_features = m;
    }
    pre.tracker.pixel_noise_px = cfg.pixel_noise_px;
    let traj = pre.trajectory.clone();
    let imu_rate_hz = 200.0;
    let gravity = 9.81;

    // IMU and ground truth.
    let n_imu = (cfg.duration_s * imu_rate_hz).floor() as usize + 1;
    let mut rng_imu = Rng::stream(cfg.seed, STREAM_IMU, 0);
    let run = imu::simulate_imu(
        &traj,
        &pre.imu,
        imu_rate_hz,
        n_imu,
        T0_NS,
        gravity,
        &mut rng_imu,
    );

    // World and landmarks.
    let path = path_samples(&traj, cfg.duration_s, 2.0 * pre.tracker.depth_range_m.1);
    let world = scene::build_world(
        &path,
        &pre.scene,
        &mut Rng::stream(cfg.seed, STREAM_WORLD, 0),
    );
    let lms = scene::sample_landmarks(
        &world,
        &path,
        &pre.scene,
        &mut Rng::stream(cfg.seed, STREAM_LANDMARKS, 0),
    );

    // LiDAR setup: true mounting = nominal * (rotation error, translation error).
    let kind = cfg.lidar.unwrap_or(pre.lidar);
    let lidar_params = scenario::lidar_pattern(cfg.scenario, kind).map(|(mut pattern, range)| {
        if let Some(n) = cfg.lidar_points {
            match &mut pattern {
                lidar::LidarPattern::Rosette { points, .. } => *points = n.max(1),
                lidar::LidarPattern::Spinning { beams, columns, .. } => {
                    *columns = (n / *beams).max(1)
                }
            }
        }
        LidarParams {
            pattern,
            rate_hz: 10.0,
            range_noise_m: cfg.lidar_range_noise_m,
            range_m: range,
            edge_angle_rad: 0.5f64.to_radians(),
            foliage_porosity: cfg.foliage_porosity,
            footprint: scenario::lidar_footprint(kind),
        }
    });
    let t_bl_true = lidar_params.as_ref().map(|_| {
        let mut r = Rng::stream(cfg.seed, STREAM_EXTRINSIC, 0);
        let rot = r.unit3() * cfg.lidar_extrinsic_error_deg.to_radians();
        let dp = r.unit3() * cfg.lidar_extrinsic_error_m;
        Extrinsic {
            q_ab: pre.t_bl.q_ab * quat_exp(&rot),
            p_ab: pre.t_bl.p_ab + dp,
        }
    });

    // Camera frames on the IMU grid.
    let cam_dt_ns = (1e9 / pre.camera_rate_hz).round() as i64;
    let td_ns = (cfg.td_s * 1e9).round() as i64;
    let td_l_ns = (cfg.lidar_td_s * 1e9).round() as i64;
    let n_frames = (cfg.duration_s * 1e9 / cam_dt_ns as f64).floor() as usize + 1;
    let sweep_ns = 100_000_000i64;
    let n_scans = if lidar_params.is_some() {
        ((cfg.duration_s * 1e9) as i64 / sweep_ns) as usize
    } else {
        0
    };
    let threads = if cfg.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cfg.threads
    }
    .clamp(1, 16);

    let done = std::sync::atomic::AtomicUsize::new(0);
    let (frames, cam_truth, sweeps) = std::thread::scope(|sc| {
        let cam_job = sc.spawn(|| {
            let mut cam = CameraSim::new(
                &world,
                &lms,
                pre.camera,
                &pre.t_bc,
                pre.tracker,
                Rng::stream(cfg.seed, STREAM_CAMERA, 0),
            );
            let mut frames: Vec<FeatureFrame> = Vec::with_capacity(n_frames);
            for k in 0..n_frames {
                let t_rel_ns = k as i64 * cam_dt_ns;
                let t_s = t_rel_ns as f64 * 1e-9;
                let kin = traj.eval(t_s);
                let td_k_ns = window::frame_td_ns(td_ns, cfg.td_step.as_ref(), t_rel_ns);
                let at_row = |row_s: f64| traj.eval(t_s + row_s);
                frames.push(cam.step(&kin, T0_NS + t_rel_ns - td_k_ns, &at_row));
                progress("camera", k + 1, n_frames);
            }
            (frames, cam.finish())
        });
        let mut sweeps: Vec<Option<SweepOut>> = (0..n_scans).map(|_| None).collect();
        if let (Some(lp), Some(tbl)) = (lidar_params.as_ref(), t_bl_true.as_ref()) {
            let workers: Vec<_> = (0..threads)
                .map(|w| {
                    let (world, traj, done) = (&world, &traj, &done);
                    sc.spawn(move || {
                        let mut out = Vec::new();
                        for j in (w..n_scans).step_by(threads) {
                            let t_rel_ns = j as i64 * sweep_ns;
                            let mut r = Rng::stream(cfg.seed, STREAM_LIDAR, j as u64);
                            out.push((
                                j,
                                lidar::simulate_sweep(
                                    world,
                                    traj,
                                    tbl,
                                    lp,
                                    t_rel_ns as f64 * 1e-9,
                                    T0_NS + t_rel_ns - td_l_ns,
                                    &mut r,
                                ),
                            ));
                            let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                            progress("lidar", d, n_scans);
                        }
                        out
                    })
                })
                .collect();
            for wk in workers {
                for (j, s) in wk.join().unwrap_or_default() {
                    sweeps[j] = Some(s);
                }
            }
        }
        let (frames, truth) = cam_job
            .join()
            .unwrap_or_else(|_| (Vec::new(), CameraTruth::default()));
        (frames, truth, sweeps)
    });
    anyhow::ensure!(frames.len() == n_frames, "camera simulation failed");
    window::check_stamps(&frames)?;
    anyhow::ensure!(
        sweeps.iter().all(Option::is_some),
        "LiDAR simulation failed"
    );
    let footprint_moved = sweeps.iter().flatten().map(|s| s.footprint_moved).sum();
    let (lidar_scans, lidar_edges): (Vec<_>, Vec<_>) = sweeps
        .into_iter()
        .flatten()
        .map(|s| (s.scan, s.edge))
        .unzip();

    let mut dataset = Dataset {
        name: format!("sim-{}-seed{}", cfg.scenario.name(), cfg.seed),
        calib: Calibration {
            camera: pre.camera,
            t_bc: pre.t_bc,
            td_s: td_ns as f64 * 1e-9,
            camera_rate_hz: pre.camera_rate_hz,
            imu_noise: pre.imu.noise,
            imu_rate_hz,
            gravity_mps2: gravity,
            t_bl: lidar_params.as_ref().map(|_| pre.t_bl),
            td_l_s: lidar_params.as_ref().map_or(0.0, |_| td_l_ns as f64 / 1e9),
        },
        imu: run.imu,
        features: frames,
        images: Vec::new(),
        lidar: lidar_scans,
        ground_truth: run.ground_truth,
        sim_truth: Some(SimTruth {
            landmarks_w: cam_truth.landmarks_w,
            wrong_tracks: cam_truth.wrong_tracks,
            edge_features: cam_truth.edge_features,
            lidar_edge_points: lidar_edges,
        }),
    };
    let frame_t_rel_ns: Vec<i64> = (0..n_frames).map(|k| k as i64 * cam_dt_ns).collect();
    let frames = window::crop(&mut dataset, &frame_t_rel_ns, cfg.start_s);
    let mut summary = summarize(cfg, &traj, &dataset, &world, lms.len());
    summary.lidar_footprint_moved = footprint_moved;
    Ok(SimOutput {
        dataset,
        trajectory: traj,
        world,
        t_bl_true,
        summary,
        frames,
    })
}

fn summarize(
    cfg: &SimConfig,
    traj: &Trajectory,
    ds: &Dataset,
    world: &World,
    landmarks: usize,
) -> Summary {
    let (gt, frames, scans) = (&ds.ground_truth, &ds.features, &ds.lidar);
    let no_truth = SimTruth::default();
    let truth = ds.sim_truth.as_ref().unwrap_or(&no_truth);
    let edges = &truth.lidar_edge_points;
    let distance_m = gt.windows(2).map(|w| (w[1].p_wb - w[0].p_wb).norm()).sum();
    let t_moving = traj.warp.t_static + traj.warp.t_ramp;
    let mut speed = (f64::INFINITY, 0.0f64);
    let mut max_rate = 0.0f64;
    for (k, s) in gt.iter().enumerate() {
        let t = (s.t_ns - T0_NS) as f64 * 1e-9;
        if t >= t_moving {
            let v = s.v_wb.norm();
            speed = (speed.0.min(v), speed.1.max(v));
        }
        if k % 4 == 0 {
            max_rate = max_rate.max(traj.eval(t).omega_b.norm());
        }
    }
    if !speed.0.is_finite() {
        speed.0 = 0.0;
    }
    let n_obs: usize = frames.iter().map(|f| f.obs.len()).sum();
    let tracks = truth.landmarks_w.len();
    Summary {
        duration_s: cfg.duration_s - cfg.start_s,
        distance_m,
        speed_range_mps: speed,
        max_rate_rps: max_rate,
        imu_samples: gt.len(),
        frames: frames.len(),
        mean_features: n_obs as f64 / frames.len().max(1) as f64,
        tracks,
        mean_track_len: n_obs as f64 / tracks.max(1) as f64,
        landmarks,
        primitives: world.primitives().len(),
        scans: scans.len(),
        points: scans.iter().map(|s| s.points.len()).sum(),
        wrong_tracks: truth.wrong_tracks.len(),
        edge_features: truth.edge_features.len(),
        lidar_edge_points: edges.iter().map(|e| e.iter().filter(|&&b| b).count()).sum(),
        lidar_footprint_moved: 0,
    }
}

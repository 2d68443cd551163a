//! `povins simulate --start-s` (a sequence that starts in motion) and `--td-step-ms
//! --td-step-at-s` (a camera-IMU delay that steps): issue 31, item 6.
//!
//! The references are the full sequence of the same seed: a cropped sequence must be exactly
//! its tail (every stream cut at the same instant of the IMU clock), and a stepped delay must
//! move exactly the stamps of the frames exposed from the step on.

use clap::Parser;
use povins_host_tools::cmd::simulate;
use povins_host_tools::sim::render::truth::camera_frames;
use povins_host_tools::sim::render::{sequence, RenderOptions};
use povins_host_tools::sim::{
    motion_start_s, simulate as run_sim, LidarKind, Scenario, SimConfig, SimOutput, TdStep, T0_NS,
};
use std::sync::Mutex;

fn sim(cfg: &SimConfig) -> SimOutput {
    run_sim(cfg, &|_, _, _| {}).expect("simulate")
}

fn config(scenario: Scenario, td_ms: f64, duration_s: f64) -> SimConfig {
    let mut c = SimConfig::new(scenario, 4, duration_s);
    c.td_s = td_ms * 1e-3;
    c.lidar_points = Some(2_000);
    c.threads = 1;
    c
}

/// Every stream of the cropped sequence is the full sequence's tail from `T0 + start`: IMU,
/// ground truth and LiDAR sweeps by stamp, camera frames by exposure instant (stamp + td; the
/// delay is 8 ms so a cut by stamp would keep one frame less).
#[test]
fn start_drops_exactly_what_is_before_t_in_every_stream() {
    let full = sim(&config(Scenario::Handheld, 8.0, 4.0));
    // Less than td before the frame exposed at 2.0 s (20 Hz): a cut by stamp would drop it.
    let start_s = 1.996;
    let mut c = config(Scenario::Handheld, 8.0, 4.0);
    c.start_s = start_s;
    let cut = sim(&c);
    let (f, k) = (&full.dataset, &cut.dataset);
    let t_cut = T0_NS + 1_996_000_000;
    let td_ns = 8_000_000;

    let tail = |n: usize, first: usize| n - first;
    let first_imu = f.imu.iter().position(|s| s.t_ns >= t_cut).unwrap();
    assert!(first_imu > 0);
    assert_eq!(k.imu, f.imu[first_imu..], "IMU");
    assert_eq!(k.imu.len(), tail(f.imu.len(), first_imu));
    let first_gt = f.ground_truth.iter().position(|s| s.t_ns >= t_cut).unwrap();
    assert_eq!(k.ground_truth, f.ground_truth[first_gt..], "ground truth");
    let first_scan = f.lidar.iter().position(|s| s.t_ns >= t_cut).unwrap();
    assert!(first_scan > 0 && !k.lidar.is_empty());
    assert_eq!(k.lidar, f.lidar[first_scan..], "LiDAR sweeps");
    let (ft, kt) = (f.sim_truth.as_ref().unwrap(), k.sim_truth.as_ref().unwrap());
    assert_eq!(
        kt.lidar_edge_points,
        ft.lidar_edge_points[first_scan..],
        "LiDAR edge flags follow their sweeps"
    );
    let first_frame = f
        .features
        .iter()
        .position(|fr| fr.t_ns + td_ns >= t_cut)
        .unwrap();
    let by_stamp = f.features.iter().position(|fr| fr.t_ns >= t_cut).unwrap();
    assert_eq!(
        by_stamp,
        first_frame + 1,
        "the test's cut separates the two"
    );
    assert_eq!(k.features, f.features[first_frame..], "camera frames");
    assert_eq!(cut.frames.first, first_frame);
    assert_eq!(camera_frames(&cut), camera_frames(&full)[first_frame..]);
    // Stamps are not shifted; the calibration is the same.
    assert_eq!(k.calib, f.calib);
    assert!(k.imu[0].t_ns >= t_cut && k.imu[0].t_ns - t_cut < 5_000_000);
    // The truth by id keeps the tracks still seen, and all of them.
    let seen = |id: u64| {
        k.features
            .iter()
            .any(|fr| fr.obs.iter().any(|o| o.id == id))
    };
    assert!(kt.landmarks_w.iter().all(|(id, _)| seen(*id)));
    let n_seen = ft.landmarks_w.iter().filter(|(id, _)| seen(*id)).count();
    assert_eq!(kt.landmarks_w.len(), n_seen);
    assert!(
        n_seen < ft.landmarks_w.len(),
        "some tracks ended before the cut"
    );
    assert!(kt.wrong_tracks.iter().all(|id| seen(*id)));
    assert!(cut.summary.imu_samples == k.imu.len() && cut.summary.frames == k.features.len());
}

/// The images of a cropped sequence are the full sequence's images of the same frames (the
/// noise of a frame is drawn from its index in the full sequence).
#[test]
fn cropped_images_are_the_full_sequence_images() {
    let render = |out: &SimOutput| {
        let opts = RenderOptions {
            noise_grey: 2.0,
            ..RenderOptions::default()
        };
        let slots = Mutex::new(vec![Vec::new(); out.dataset.features.len()]);
        sequence::render_sequence(out, &opts, 4, 2, &|_, _, _| {}, &|k, _, px| {
            slots.lock().unwrap()[k] = px;
            Ok(())
        })
        .unwrap();
        slots.into_inner().unwrap()
    };
    let mut c = config(Scenario::Robot, -5.0, 0.6);
    c.lidar = Some(LidarKind::None);
    let full = sim(&c);
    c.start_s = 0.45;
    let cut = sim(&c);
    let (a, b) = (render(&full), render(&cut));
    let n = camera_frames(&full).iter().filter(|f| f.1 >= 0.45).count();
    assert!(
        n >= 2 && b.len() == n,
        "{} frames kept, {n} expected",
        b.len()
    );
    assert!(b == a[a.len() - n..], "cropped images differ");
}

/// With a step of the delay, the frames exposed from the step on are stamped D earlier (the
/// IMU, the ground truth and the tracks themselves do not change); the calibration keeps the
/// delay before the step.
#[test]
fn td_step_moves_the_camera_stamps_by_d_from_t() {
    let mut c = config(Scenario::Flight, 8.0, 3.0);
    c.lidar = Some(LidarKind::None);
    let base = sim(&c);
    c.td_step = Some(TdStep {
        step_s: 0.010,
        at_s: 1.5,
    });
    let step = sim(&c);
    let (a, b) = (&base.dataset, &step.dataset);
    assert_eq!(a.imu, b.imu);
    assert_eq!(a.ground_truth, b.ground_truth);
    assert_eq!(a.calib, b.calib, "the calibration holds td before the step");
    assert_eq!(a.features.len(), b.features.len());
    let mut moved = 0;
    for (fa, fb) in a.features.iter().zip(&b.features) {
        assert_eq!(fa.obs, fb.obs, "the tracks do not depend on the stamps");
        let exposure_ns = fa.t_ns + 8_000_000 - T0_NS;
        if exposure_ns >= 1_500_000_000 {
            assert_eq!(fb.t_ns, fa.t_ns - 10_000_000, "stamp after the step");
            moved += 1;
        } else {
            assert_eq!(fb.t_ns, fa.t_ns, "stamp before the step");
        }
    }
    assert_eq!(
        moved,
        a.features.len() - 30,
        "frames 30.. are exposed from 1.5 s on"
    );
    // The image truth (and the rendered images) follow the exposure, not the stamp.
    let (ta, tb) = (camera_frames(&base), camera_frames(&step));
    assert!(ta.iter().zip(&tb).all(|(x, y)| x.1 == y.1));

    // A step as large as the frame period would send the stamps back in time.
    c.td_step = Some(TdStep {
        step_s: 0.050,
        at_s: 1.5,
    });
    let e = run_sim(&c, &|_, _, _| {}).unwrap_err().to_string();
    assert!(e.contains("frame period"), "{e}");
}

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: simulate::Args,
}

/// `--start-s motion` is the scenario's rest plus its ramp; the flags reach the written files.
#[test]
fn cli_start_in_motion_and_td_step() {
    assert_eq!(motion_start_s(Scenario::Flight, 1.0), 3.0);
    assert_eq!(motion_start_s(Scenario::Vehicle, 1.0), 9.0);
    assert_eq!(motion_start_s(Scenario::Robot, 0.5), 2.5);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("seq");
    let argv = [
        "povins",
        "--scenario",
        "flight",
        "--duration",
        "4",
        "--lidar",
        "none",
        "--td-ms",
        "-5",
        "--start-s",
        "motion",
        "--td-step-ms",
        "10",
        "--td-step-at-s",
        "3.5",
        "--format",
        "euroc",
        "--out",
        out.to_str().unwrap(),
    ];
    simulate::run(Cli::try_parse_from(argv).unwrap().args).unwrap();
    let ds = povins_platform::euroc::read_dataset(&out).unwrap();
    assert_eq!(ds.imu[0].t_ns, T0_NS + 3_000_000_000);
    assert_eq!(ds.ground_truth[0].t_ns, T0_NS + 3_000_000_000);
    // td = -5 ms: the frame exposed at 3.0 s is stamped 3.005 s; from 3.5 s on td = +5 ms.
    assert_eq!(ds.features[0].t_ns, T0_NS + 3_005_000_000);
    let stamps: Vec<i64> = ds.features.iter().map(|f| f.t_ns - T0_NS).collect();
    assert!(stamps.contains(&3_455_000_000) && stamps.contains(&3_495_000_000));
    assert!(!stamps.contains(&3_505_000_000));
    assert!((ds.calib.td_s + 0.005).abs() < 1e-12);

    for bad in [["--start-s", "-1"], ["--start-s", "soon"]] {
        let mut v = argv.to_vec();
        v.extend_from_slice(&bad);
        assert!(Cli::try_parse_from(v).is_err(), "{bad:?} accepted");
    }
    let mut v: Vec<&str> = argv[..7].to_vec();
    v.extend_from_slice(&["--td-step-ms", "5", "--out", "x"]);
    let e = Cli::try_parse_from(v).err().unwrap().to_string();
    assert!(e.contains("--td-step-at-s"), "{e}");
    let mut v: Vec<&str> = argv[..7].to_vec();
    v.extend_from_slice(&["--start-s", "4", "--out", "x"]);
    let e = simulate::run(Cli::try_parse_from(v).unwrap().args)
        .unwrap_err()
        .to_string();
    assert!(e.contains("start"), "{e}");
}

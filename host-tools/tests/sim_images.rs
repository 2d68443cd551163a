//! Rendered images end to end: `povins simulate --images` in both formats, read back; the
//! image truth scores the simulator's own (exact) feature tracks as exact.

use clap::Parser;
use povins_host_tools::cmd::simulate;
use povins_host_tools::eval::tracks::score_tracks;
use povins_host_tools::sim::render::truth::{camera_frames, ImageTruth};
use povins_host_tools::sim::render::{RenderOptions, Renderer};
use povins_host_tools::sim::{simulate as run_sim, LidarKind, Scenario, SimConfig};

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: simulate::Args,
}

fn args(extra: &[&str]) -> simulate::Args {
    let mut v = vec![
        "povins",
        "--scenario",
        "robot",
        "--seed",
        "3",
        "--duration",
        "0.5",
    ];
    v.extend_from_slice(&["--lidar", "none"]);
    v.extend_from_slice(extra);
    Cli::try_parse_from(v).expect("arguments").args
}

/// The frames `simulate` wrote equal a direct render with the same seed and options.
fn check_images(images: &[povins_platform::dataset::ImageFrame], noise: f64) {
    let out = run_sim(
        &{
            let mut c = SimConfig::new(Scenario::Robot, 3, 0.5);
            c.lidar = Some(LidarKind::None);
            c
        },
        &|_, _, _| {},
    )
    .unwrap();
    let frames = camera_frames(&out);
    assert_eq!(images.len(), frames.len());
    assert_eq!(images.len(), out.dataset.features.len());
    let c = &out.dataset.calib;
    let r = Renderer::new(&out.world, c.camera, &c.t_bc);
    let opts = RenderOptions {
        noise_grey: noise,
        ..RenderOptions::default()
    };
    for (k, im) in images.iter().enumerate() {
        assert_eq!(im.t_ns, frames[k].0);
        assert_eq!((im.width, im.height), (752, 480));
        assert_eq!(im.mono8.len(), 752 * 480);
        if k == 4 {
            let px = r.render_frame(&out.trajectory, frames[k].1, k as u64, 3, &opts);
            assert!(px == im.mono8, "frame {k} differs from a direct render");
        }
    }
    let (lo, hi) = images[0]
        .mono8
        .iter()
        .fold((255u8, 0u8), |(a, b), &p| (a.min(p), b.max(p)));
    assert!(hi - lo > 100, "flat image {lo}..{hi}");
}

#[test]
fn simulate_images_euroc_and_mcap() {
    let dir = tempfile::tempdir().unwrap();
    let euroc = dir.path().join("seq");
    let e = euroc.to_str().unwrap();
    let a = args(&[
        "--images",
        "--image-noise",
        "1.5",
        "--format",
        "euroc",
        "--out",
        e,
    ]);
    simulate::run(a).unwrap();
    let mut ds = povins_platform::euroc::read_dataset(&euroc).unwrap();
    assert_eq!(ds.images.len(), 11);
    assert!(euroc.join("mav0/cam0/data.csv").exists());
    povins_platform::euroc::read_images(&mut ds).unwrap();
    assert_eq!(ds.features.len(), 11, "features0 still written");
    check_images(&ds.images, 1.5);

    let mcap = dir.path().join("seq.mcap");
    let a = args(&[
        "--images",
        "--image-noise",
        "1.5",
        "--out",
        mcap.to_str().unwrap(),
    ]);
    simulate::run(a).unwrap();
    let ds = povins_platform::mcap_io::read_dataset(&mcap).unwrap();
    assert_eq!(ds.features.len(), 11);
    check_images(&ds.images, 1.5);
}

#[test]
fn render_flags_need_images() {
    let a = args(&["--motion-blur-ms", "5", "--out", "x"]);
    let e = a.render_options().unwrap_err().to_string();
    assert!(e.contains("--images"), "{e}");
    assert!(args(&["--out", "x"]).render_options().unwrap().is_none());
    let bad = args(&["--images", "--image-noise=-1", "--out", "x"]);
    assert!(bad.render_options().is_err());
}

/// The simulator's noise-free tracks follow their landmarks exactly: the image truth (ray cast of
/// the first observation, projected into later frames) reproduces them, and flags the
/// simulator's deliberate wrong tracks; with a camera-IMU delay too.
#[test]
fn image_truth_scores_the_simulated_tracks() {
    let mut cfg = SimConfig::new(Scenario::Robot, 5, 12.0);
    cfg.lidar = Some(LidarKind::None);
    cfg.pixel_noise_px = 0.0;
    cfg.wrong_track_rate = Some(0.05);
    // A camera-IMU delay: the truth must render each frame at its true time `stamp - T0 + td`.
    cfg.td_s = 0.013;
    let out = run_sim(&cfg, &|_, _, _| {}).unwrap();
    let truth = ImageTruth::new(&out);
    let s = score_tracks(
        &out.dataset.features,
        |i, uv, j| truth.transfer(i, uv, j),
        2.0,
    );
    let sim_wrong = out.dataset.sim_truth.as_ref().unwrap().wrong_tracks.len();
    eprintln!("{s:?}, simulator wrong tracks {sim_wrong}");
    assert!(s.tracks > 1000 && sim_wrong > 30);
    assert!(s.inlier_median_px < 1e-6 && s.inlier_p90_px < 1e-5, "{s:?}");
    assert!(
        s.wrong_tracks >= sim_wrong,
        "{} < {sim_wrong}",
        s.wrong_tracks
    );
    assert!(
        s.wrong_tracks <= sim_wrong + s.tracks / 100,
        "{} wrong vs {sim_wrong} simulated",
        s.wrong_tracks
    );
}

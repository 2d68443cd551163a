//! The host path needs no large stack: `runner::replay` (the estimator and the image front end
//! built in place on the heap by `povins_platform::boxed`) and the threaded pipeline
//! (`realtime::run_dataset`) run EuRoC V1_01 30 s on a thread with a 512 KiB stack, with the
//! golden output. The estimator alone is about ten times that stack. The largest image
//! front end (1920x1200, `WuxgaVio`, about 24 times that stack) is built and tracks images there
//! too.

mod common;

use common::golden::{check_golden_of, RunView};
use common::*;
use povins::core::estimator::{PoVins, VisualMode};
use povins::core::frontend::image::{ImageView, TrackerConfig};
use povins::core::vio::{VioAiding, WuxgaVio};
use povins::host_tools::progress::Progress;
use povins::host_tools::realtime::{run_dataset, RealtimeOptions};
use povins::host_tools::runner::{replay, InitMode};
use povins::platform::odometry::{boxed_odometry, FrontEnd};
use povins::platform::pipeline::{CallbackSink, Pacing, PoseOut};

const SMALL_STACK: usize = 512 * 1024;

#[test]
fn host_replay_and_pipeline_run_on_a_small_stack() {
    assert!(std::mem::size_of::<PoVins>() > 8 * SMALL_STACK);
    let ds = load(EUROC_30S);
    let cfg = euroc_config(&ds, VisualMode::PoseOnly);
    let quiet = || Progress::with_visibility(0, "test", false);
    let out = on_stack(SMALL_STACK, || {
        replay(&ds, cfg, InitMode::Static, &quiet()).expect("replay")
    });
    check_golden_of("euroc-v101-30s-static", &RunView::of(&out), false);
    let poses = on_stack(SMALL_STACK, || {
        let mut poses = Vec::new();
        let opts = RealtimeOptions {
            pacing: Pacing::AsFastAsPossible,
            deterministic: true,
            realtime_priority: false,
            smooth_horizon_s: None,
        };
        {
            let mut sink = CallbackSink::poses(|p: &PoseOut| poses.push(p.nav));
            run_dataset(&ds, cfg, InitMode::Static, &opts, &mut sink, &quiet()).expect("pipeline");
        }
        poses
    });
    assert_eq!(poses.len(), out.imu_rate.len());
    for (k, (g, w)) in poses.iter().zip(&out.imu_rate).enumerate() {
        assert_eq!(state_bits(g), state_bits(w), "pose {k} differs");
    }
}

/// A 1920x1200 camera: the odometry with the largest front end is built on the heap and tracks
/// a textured image shifted by 6 px, all on the small stack.
#[test]
fn the_1920x1200_odometry_runs_on_a_small_stack() {
    const W: usize = 1920;
    const H: usize = 1200;
    assert!(std::mem::size_of::<WuxgaVio>() > 20 * SMALL_STACK);
    let ds = load(EUROC_30S);
    let mut cfg = euroc_config(&ds, VisualMode::PoseOnly);
    cfg.camera.width = W as u32;
    cfg.camera.height = H as u32;
    // Texture with corners at several scales; the second image is the first moved 6 px right.
    let texture = |x: usize, y: usize| -> u8 {
        let (a, b) = (x / 37 + y / 29, (x / 11) ^ (y / 13));
        ((a * 53 + b * 31) % 200 + 28) as u8
    };
    let frame = |dx: usize| -> Vec<u8> {
        (0..H)
            .flat_map(|y| (0..W).map(move |x| texture(x + 100 - dx, y)))
            .collect()
    };
    let (a, b) = (frame(0), frame(6));
    let fe = FrontEnd::Images {
        tracker: TrackerConfig::default(),
        aiding: VioAiding::default(),
    };
    let (first, second) = on_stack(SMALL_STACK, || {
        let mut odo = boxed_odometry(cfg, &fe, None).expect("1920x1200 fits the front end");
        let mut push = |t_ns: i64, img: &[u8]| {
            let view = ImageView::new(img, W, H, W).expect("a valid view");
            let out = odo
                .push_image(t_ns, &view)
                .expect("an image of the camera's size");
            out.image.expect("a front-end report").track
        };
        (push(0, &a), push(50_000_000, &b))
    });
    assert!(first.detected >= 100, "{first:?}");
    assert!(second.tracked >= 80, "{second:?}");
}

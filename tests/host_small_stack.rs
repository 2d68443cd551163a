//! The host path needs no large stack: `runner::replay` (the estimator and the image front end
//! built in place on the heap by `povins_platform::boxed`) and the threaded pipeline
//! (`realtime::run_dataset`) run EuRoC V1_01 30 s on a thread with a 512 KiB stack, with the
//! golden output. The estimator alone is about ten times that stack.

mod common;

use common::golden::{check_golden_of, RunView};
use common::*;
use povins::core::estimator::{PoVins, VisualMode};
use povins::host_tools::progress::Progress;
use povins::host_tools::realtime::{run_dataset, RealtimeOptions};
use povins::host_tools::runner::{replay, InitMode};
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

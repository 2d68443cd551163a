//! Criterion benches of the estimator's back end on the OpenVINS corridor sequence (150-250
//! landmarks per window, as the speed bar asks), from the same snapshot in the pose-only and the
//! inverse-depth mode: one LM iteration, one marginalization, and one whole keyframe step
//! (marginalization, both LM passes, culling).
//!
//! And the same step on the simulated robot (Livox rosette) with LiDAR enhancement off, with the
//! MSC LDM and with the direct LDM (association, rejection, LDM, depth-only optimization).
//!
//! Run: `cargo bench --bench estimator` (needs ../shared/data).

use criterion::{criterion_group, BatchSize, Criterion};
use povins::core::estimator::{EstimatorConfig, PoVins, VisualMode};
use povins::core::inertial::ImuSample;
use povins::host_tools::runner::config_for;
use povins::platform::driver::{handle, Handled};
use povins::platform::source::{CameraInput, MergeOptions, MergedSource, SensorEvent, Source};
use povins::platform::Dataset;
use std::path::Path;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");

fn load() -> Dataset {
    let dir = Path::new(DATA).join("openvins-sim-corridor-mono");
    assert!(dir.exists(), "shared data missing at {}", dir.display());
    povins::platform::euroc::read_dataset(&dir).expect("corridor dataset")
}

/// Replays `ds` (IMU, frames and LiDAR sweeps in the replay's order, from the ground-truth
/// start, through the one driver step) with `cfg` until just before the IMU sample that produces
/// keyframe `k` (frames and sweeps due at that sample already offered); returns the estimator
/// and that sample.
fn snapshot(ds: &Dataset, cfg: EstimatorConfig, k: usize) -> (Box<PoVins>, ImuSample) {
    let run = |stop: Option<i64>| -> (Box<PoVins>, Vec<ImuSample>) {
        let mut est = Box::new(PoVins::new(cfg).expect("config"));
        let g0 = ds.ground_truth[0];
        let start = ds.imu.partition_point(|s| s.t_ns < g0.t_ns);
        est.initialize(povins::core::inertial::NavState {
            t_ns: ds.imu[start].t_ns,
            ..g0
        })
        .expect("init");
        let opts = MergeOptions {
            start_ns: ds.imu[start].t_ns,
            td_l_s: cfg.lidar.td_l_s,
            ..MergeOptions::new(CameraInput::Frames)
        };
        let mut source = MergedSource::new(ds, &opts).expect("source");
        let mut kf_at = Vec::new();
        while let Some(ev) = source.next().expect("in-memory streams do not fail") {
            let sample = match &ev {
                SensorEvent::Imu(s) if Some(s.t_ns) == stop => break,
                SensorEvent::Imu(s) => Some(*s),
                _ => None,
            };
            let handled = handle(&mut *est, &ev, &mut ());
            if let (Some(s), Handled::Imu { keyframe: true, .. }) = (sample, handled) {
                kf_at.push(s);
                if kf_at.len() == k && stop.is_none() {
                    break;
                }
            }
        }
        (est, kf_at)
    };
    let (_, kf_at) = run(None);
    let s = *kf_at.last().expect("keyframes");
    let (est, _) = run(Some(s.t_ns));
    (est, s)
}

fn bench_keyframe(c: &mut Criterion) {
    let ds = load();
    for (name, mode) in [
        ("pose_only", VisualMode::PoseOnly),
        ("inverse_depth", VisualMode::InverseDepth),
    ] {
        let mut cfg = config_for(&ds);
        cfg.mode = mode;
        let (est, sample) = snapshot(&ds, cfg, 200);
        on_clone(
            c,
            &format!("estimator/lm_iteration_{name}_corridor"),
            &est,
            |e| {
                e.lm_iteration().expect("one LM iteration");
            },
        );
        on_clone(
            c,
            &format!("estimator/marginalization_{name}_corridor"),
            &est,
            |e| {
                e.marginalize_oldest_now().expect("marginalization");
            },
        );
        on_clone(
            c,
            &format!("estimator/keyframe_step_{name}_corridor"),
            &est,
            |e| {
                e.push_imu(&sample).expect("sample");
                let out = e.update().expect("processed").expect("due");
                assert!(out.keyframe.is_some());
            },
        );
    }
}

/// Times `step` on a fresh clone of `est` (the clone is set-up, not timed).
fn on_clone(c: &mut Criterion, id: &str, est: &PoVins, step: impl Fn(&mut PoVins)) {
    c.bench_function(id, |b| {
        b.iter_batched(
            || Box::new(est.clone()),
            |mut e| {
                step(&mut e);
                e
            },
            BatchSize::LargeInput,
        )
    });
}

fn bench_keyframe_lidar(c: &mut Criterion) {
    use povins::core::lidar::LdmMode;
    use povins::host_tools::sim::{simulate, Scenario, SimConfig};
    let ds = simulate(&SimConfig::new(Scenario::Robot, 1, 30.0), &|_, _, _| {})
        .expect("simulate")
        .dataset;
    for (name, lidar) in [
        ("no_lidar", None),
        ("lidar_msc", Some(LdmMode::Msc)),
        ("lidar_direct", Some(LdmMode::Direct)),
    ] {
        let mut cfg = config_for(&ds);
        cfg.lidar.enabled = lidar.is_some();
        if let Some(m) = lidar {
            cfg.lidar.ldm = m;
        }
        let (est, sample) = snapshot(&ds, cfg, 60);
        if lidar == Some(LdmMode::Msc) {
            // The tracker's per-image call: every window landmark with a depth, predicted.
            let mut buf = [povins::core::estimator::FeaturePrediction::EMPTY; 200];
            let t = sample.t_ns;
            c.bench_function("estimator/predict_features_lidar_msc_sim_robot", |b| {
                b.iter(|| est.predict_features(t, &mut buf).expect("prediction"))
            });
        }
        on_clone(
            c,
            &format!("estimator/keyframe_step_{name}_sim_robot"),
            &est,
            |e| {
                e.push_imu(&sample).expect("sample");
                let out = e.update().expect("processed").expect("due");
                assert!(out.keyframe.is_some());
            },
        );
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench_keyframe, bench_keyframe_lidar
}
// The estimator (several MB) is built by value before it is boxed: run on a big stack.
fn main() {
    let worker = std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(|| {
            benches();
            Criterion::default().configure_from_args().final_summary();
        })
        .expect("spawn the bench thread");
    if let Err(p) = worker.join() {
        std::panic::resume_unwind(p);
    }
}

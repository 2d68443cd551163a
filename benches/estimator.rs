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
use povins::host_tools::runner::config_for;
use povins::platform::Dataset;
use std::path::Path;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");

fn load() -> Dataset {
    let dir = Path::new(DATA).join("openvins-sim-corridor-mono");
    assert!(dir.exists(), "shared data missing at {}", dir.display());
    povins::platform::euroc::read_dataset(&dir).expect("corridor dataset")
}

/// Replays `ds` (IMU, frames and LiDAR sweeps in time order, from the ground-truth start) with
/// `cfg` until just before the IMU sample that produces keyframe `k` (frames due at that sample
/// already offered); returns the estimator and that sample's index.
fn snapshot(ds: &Dataset, cfg: EstimatorConfig, k: usize) -> (Box<PoVins>, usize) {
    let run = |stop: Option<usize>| -> (Box<PoVins>, Vec<usize>) {
        let mut est = Box::new(PoVins::new(cfg).expect("config"));
        let g0 = ds.ground_truth[0];
        let start = ds.imu.partition_point(|s| s.t_ns < g0.t_ns);
        est.initialize(povins::core::inertial::NavState {
            t_ns: ds.imu[start].t_ns,
            ..g0
        })
        .expect("init");
        let sweeps = povins::host_tools::runner::lidar_schedule(ds, cfg.lidar.td_l_s);
        let mut fi = ds.features.partition_point(|f| f.t_ns < ds.imu[start].t_ns);
        let mut li = sweeps.partition_point(|w| w.0 < ds.imu[start].t_ns);
        let mut kf_at = Vec::new();
        for (i, s) in ds.imu.iter().enumerate().skip(start) {
            while let Some(f) = ds.features.get(fi).filter(|f| f.t_ns <= s.t_ns) {
                let _ = est.push_frame(f.t_ns, &f.obs);
                fi += 1;
            }
            if Some(i) == stop {
                break;
            }
            let _ = est.push_imu(s);
            while let Some(w) = sweeps.get(li).filter(|w| w.0 <= s.t_ns) {
                let _ = est.push_lidar(&ds.lidar[w.1].points);
                li += 1;
            }
            if next_output(&mut est).is_some_and(|o| o.keyframe.is_some()) {
                kf_at.push(i);
                if kf_at.len() == k && stop.is_none() {
                    break;
                }
            }
        }
        (est, kf_at)
    };
    let (_, kf_at) = run(None);
    let i = *kf_at.last().expect("keyframes");
    let (est, _) = run(Some(i));
    (est, i)
}

fn bench_keyframe(c: &mut Criterion) {
    let ds = load();
    for (name, mode) in [
        ("pose_only", VisualMode::PoseOnly),
        ("inverse_depth", VisualMode::InverseDepth),
    ] {
        let mut cfg = config_for(&ds);
        cfg.mode = mode;
        cfg.clock = None;
        let (est, i) = snapshot(&ds, cfg, 200);
        let sample = ds.imu[i];
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

/// The output of the sample just pushed (processed at once: no delay horizon).
fn next_output(est: &mut PoVins) -> Option<povins::core::estimator::ImuOutput> {
    est.update().ok().flatten()
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
        cfg.clock = None;
        cfg.lidar.enabled = lidar.is_some();
        if let Some(m) = lidar {
            cfg.lidar.ldm = m;
        }
        let (est, i) = snapshot(&ds, cfg, 60);
        let sample = ds.imu[i];
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

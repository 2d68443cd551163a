//! The estimator embedded as firmware would embed it: a `static` built by the `const`
//! [`Estimator::empty`](povins::core::estimator::Estimator::empty) (all zero bits: it lives in
//! `.bss`, never on a stack), configured in place and fed the whole EuRoC 30 s sequence from a
//! thread with a 256 KiB stack. Its output
//! must be bit-identical to the golden replay (`tests/golden/euroc-v101-30s-static.hash`, blessed
//! by `estimator_determinism` through `runner::replay`), and configuring the same static again
//! must give the same output again (a re-configured estimator is a fresh one).

mod common;

use common::golden::{check_golden_of, hashes_of, RunView};
use common::*;
use povins::core::estimator::{
    DepthEvent, EstimatorConfig, KeyframeReport, PoVins, Status, VisualMode,
};
use povins::core::inertial::{ImuSample, NavState};
use povins::core::Error;
use povins::platform::dataset::Dataset;
use std::collections::BTreeMap;
use std::sync::Mutex;

/// The stack of the thread that configures and runs the estimator.
const SMALL_STACK: usize = 256 * 1024;

/// Upper bound on `size_of::<PoVins>()` (every buffer inside, LiDAR ones and the sensor queues
/// included; the exact figures are the README's footprint table, `core/tests/footprint.rs`):
/// 8 MiB since the LiDAR buffer holds the association's span of a dense LiDAR (7.3 MiB), 9 MiB
/// since the thinning of a LiDAR faster than that span (8.1 MiB: 0.74 MiB of thinning cells,
/// `core::lidar::thin`).
const MAX_SIZE_BYTES: usize = 9 << 20;

static EST: Mutex<PoVins> = Mutex::new(PoVins::empty());

/// What a run produced, as `runner::replay` collects it.
struct Run {
    imu_rate: Vec<NavState>,
    reports: Vec<KeyframeReport>,
    lidar_events: Vec<Vec<DepthEvent>>,
    /// Every keyframe's last state in the window, by time.
    keyframe_states: Vec<NavState>,
}

impl Run {
    fn view(&self) -> RunView<'_> {
        RunView {
            imu_rate: &self.imu_rate,
            reports: &self.reports,
            lidar_events: self.lidar_events.iter().map(Vec::as_slice).collect(),
            keyframe_states: &self.keyframe_states,
        }
    }
}

/// Configures the static estimator with `cfg` and replays `ds` through it (IMU samples and
/// camera frames in time order, as `runner::replay` feeds them), on a small stack.
fn run_static(ds: &Dataset, cfg: EstimatorConfig) -> Run {
    let frames = frames_of(ds);
    on_stack(SMALL_STACK, || {
        let mut est = EST.lock().unwrap_or_else(|p| p.into_inner());
        est.configure(cfg).expect("a valid configuration");
        assert_eq!(est.status(), Status::WaitingForInit);
        let mut run = Run {
            imu_rate: Vec::with_capacity(ds.imu.len()),
            reports: Vec::new(),
            lidar_events: Vec::new(),
            keyframe_states: Vec::new(),
        };
        let mut kf_states = BTreeMap::new();
        drive(&mut est, &ds.imu, &frames, |est, _, o| {
            if let Some(r) = o.keyframe {
                run.lidar_events.push(est.lidar_events().to_vec());
                run.reports.push(r);
                for kf in est.keyframes() {
                    kf_states.insert(kf.state.t_ns, kf.state);
                }
            }
            if let Some(nav) = o.nav {
                run.imu_rate.push(nav);
            }
            true
        });
        run.keyframe_states = kf_states.into_values().collect();
        run
    })
}

#[test]
fn static_estimator_on_a_small_stack_matches_the_golden_replay() {
    let size = std::mem::size_of::<PoVins>();
    println!(
        "size_of::<PoVins>() = {size} bytes ({:.2} MiB); run on a {} KiB stack",
        size as f64 / (1 << 20) as f64,
        SMALL_STACK / 1024
    );
    assert!(
        size <= MAX_SIZE_BYTES,
        "PoVins grew to {size} bytes (bound {MAX_SIZE_BYTES})"
    );
    let ds = load(EUROC_30S);
    let cfg = euroc_config(&ds, VisualMode::PoseOnly);

    let first = run_static(&ds, cfg);
    assert!(
        first.reports.len() > 40,
        "only {} keyframes",
        first.reports.len()
    );
    check_golden_of("euroc-v101-30s-static", &first.view(), false);

    // The same static, used, configured again: the same bits as a fresh estimator.
    let second = run_static(&ds, cfg);
    assert_eq!(
        hashes_of(&first.view()),
        hashes_of(&second.view()),
        "the re-configured static estimator's output differs from its first run"
    );
    check_golden_of("euroc-v101-30s-static", &second.view(), false);
}

/// `PoVins::empty()` is all zero bits, so the `static` takes no space in the executable: the
/// linker puts it in `.bss` (between the symbols `__bss_start` and `_end` of GNU ld and lld).
#[cfg(target_os = "linux")]
#[test]
fn static_estimator_lives_in_bss() {
    extern "C" {
        static __bss_start: u8;
        static _end: u8;
    }
    // Only the addresses of the linker's symbols are taken, never their contents.
    let (lo, hi) = (
        std::ptr::addr_of!(__bss_start) as usize,
        std::ptr::addr_of!(_end) as usize,
    );
    let at = std::ptr::addr_of!(EST) as usize;
    let size = std::mem::size_of_val(&EST);
    println!("EST at {at:#x}, {size} bytes; .bss {lo:#x}..{hi:#x}");
    assert!(
        lo <= at && at + size <= hi,
        "the static estimator is not in .bss ({at:#x}+{size} outside {lo:#x}..{hi:#x}): \
         Estimator::empty() has non-zero bits"
    );
}

/// An unconfigured estimator refuses every input (and counts nothing); an invalid
/// configuration leaves it unconfigured; a valid one makes it wait for initialization.
#[test]
fn unconfigured_estimator_refuses_input_until_configured() {
    static FRESH: Mutex<PoVins> = Mutex::new(PoVins::empty());
    let ds = load(EUROC_30S);
    let cfg = euroc_config(&ds, VisualMode::PoseOnly);
    on_stack(SMALL_STACK, || {
        let mut est = FRESH.lock().unwrap_or_else(|p| p.into_inner());
        assert_eq!(est.status(), Status::Unconfigured);
        let s: ImuSample = ds.imu[0];
        assert_eq!(est.push_imu(&s), Err(Error::NotInitialized));
        assert_eq!(est.push_frame(s.t_ns, &[]), Err(Error::NotInitialized));
        assert_eq!(
            est.initialize(NavState::identity(s.t_ns)),
            Err(Error::NotInitialized)
        );
        est.reset();
        assert_eq!(est.status(), Status::Unconfigured);
        assert_eq!(est.counters().imu_samples, 0);
        assert_eq!(est.counters().frames, 0);
        assert_eq!(est.counters().resets, 0);

        let bad = EstimatorConfig {
            sigma_px: -1.0,
            ..cfg
        };
        assert_eq!(est.configure(bad), Err(Error::InvalidConfig));
        assert_eq!(est.status(), Status::Unconfigured);
        assert!(EstimatorConfig::PLACEHOLDER.validate().is_err());

        est.configure(cfg).expect("a valid configuration");
        assert_eq!(est.status(), Status::WaitingForInit);
        assert!(est.push_imu(&s).is_ok());
        assert_eq!(est.counters().imu_samples, 0, "queued, not processed yet");
        assert!(matches!(est.update(), Ok(Some(_))));
        assert_eq!(est.counters().imu_samples, 1);
        assert_eq!(est.update(), Ok(None));
    });
}

//! The whole estimator (INS, front-end bookkeeping, keyframe selection, LM solves,
//! marginalization, culling) never touches the heap: the data and the boxed estimator are
//! prepared first, then every IMU sample and frame is fed under a counting global allocator.

mod common;

use common::*;
use povins::core::estimator::VisualMode;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // Per-thread flag and count: the harness's threads (and other tests running in parallel)
    // cannot interfere. Const-initialized `Cell`s have no destructor, so touching them from the
    // allocator cannot allocate or recurse.
    static ACTIVE: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

fn note_alloc() {
    if ACTIVE.with(Cell::get) {
        COUNT.with(|c| c.set(c.get() + 1));
    }
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_alloc();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_alloc();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_alloc();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Counts the allocations `f` makes on this thread.
fn count_allocs(f: impl FnOnce()) -> usize {
    COUNT.with(|c| c.set(0));
    ACTIVE.with(|a| a.set(true));
    f();
    ACTIVE.with(|a| a.set(false));
    COUNT.with(Cell::get)
}

/// The counter itself works (otherwise every zero below would be meaningless).
#[test]
fn counter_sees_allocations() {
    let n = count_allocs(|| {
        let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(16));
        drop(v);
    });
    assert_eq!(n, 1);
}

fn euroc_alloc_free(mode: VisualMode) {
    small_stack(move || {
        let ds = load(EUROC_30S);
        let cfg = euroc_config(&ds, mode);
        let frames = frames_of(&ds);
        let mut est = new_estimator(cfg);
        let mut keyframes = 0usize;
        let mut last = None;
        let allocs = count_allocs(|| {
            drive(&mut est, &ds.imu, &frames, |_, _, o| {
                keyframes += usize::from(o.keyframe.is_some());
                last = o.nav;
                true
            });
        });
        let c = est.counters();
        println!("EuRoC {mode:?}: {keyframes} keyframes, {allocs} allocations, {c:?}");
        assert!(keyframes > 40, "only {keyframes} keyframes in {mode:?}");
        assert_eq!(c.keyframes as usize, keyframes);
        assert!(last.as_ref().is_some_and(state_is_finite));
        assert_eq!(
            allocs, 0,
            "the estimator allocated {allocs} times ({mode:?})"
        );
    });
}

/// With `covariance = true` (the newest keyframe's marginal covariance after each solve,
/// propagated at IMU rate) the estimator allocates nothing either.
#[test]
fn euroc_with_covariance_does_not_allocate() {
    small_stack(|| {
        let ds = load(EUROC_30S);
        let mut cfg = euroc_config(&ds, VisualMode::PoseOnly);
        cfg.covariance = true;
        let frames = frames_of(&ds);
        let mut est = new_estimator(cfg);
        let mut with_cov = 0usize;
        let allocs = count_allocs(|| {
            drive(&mut est, &ds.imu, &frames, |e, _, _| {
                with_cov += usize::from(e.nav_covariance().is_some());
                true
            });
        });
        println!("EuRoC with covariance: {with_cov} states with one, {allocs} allocations");
        assert!(with_cov > 4000, "only {with_cov} states with a covariance");
        assert_eq!(allocs, 0, "the estimator allocated {allocs} times");
    });
}

#[test]
fn euroc_pose_only_does_not_allocate() {
    euroc_alloc_free(VisualMode::PoseOnly);
}

#[test]
fn euroc_inverse_depth_does_not_allocate() {
    euroc_alloc_free(VisualMode::InverseDepth);
}

#[test]
fn simulated_robot_gt_init_does_not_allocate() {
    small_stack(|| {
        let ds = simulate_robot(3, 15.0);
        let mut cfg = povins::host_tools::runner::config_for(&ds);
        let (start, s0) = gt_start(&ds, &mut cfg);
        let frames = frames_of(&ds);
        let mut est = new_estimator(cfg);
        let mut keyframes = 0usize;
        let allocs = count_allocs(|| {
            est.initialize(s0).expect("initialize from ground truth");
            drive(&mut est, &ds.imu[start..], &frames, |_, _, o| {
                keyframes += usize::from(o.keyframe.is_some());
                true
            });
        });
        let c = est.counters();
        println!("simulated robot: {keyframes} keyframes, {allocs} allocations, {c:?}");
        assert!(keyframes > 40, "only {keyframes} keyframes");
        assert!(
            c.landmarks_evicted > 0,
            "the landmark capacity was not reached (no slot changed hands)"
        );
        assert_eq!(allocs, 0, "the estimator allocated {allocs} times");
    });
}

/// LiDAR enhancement on (sweep intake and de-skew, association, rejection, MSC and direct
/// LDM, depth-only optimization): still no heap.
fn lidar_alloc_free(ldm: povins::core::lidar::LdmMode) {
    small_stack(move || {
        let ds = simulate_with_lidar(povins::host_tools::sim::Scenario::Robot, 3, 15.0);
        let mut cfg = sim_lidar_config(&ds, true);
        cfg.lidar.ldm = ldm;
        let (start, s0) = gt_start(&ds, &mut cfg);
        let frames = frames_of(&ds);
        let sweeps = sweeps_of(&ds);
        let mut est = new_estimator(cfg);
        let (mut keyframes, mut ldm_used, mut predicted) = (0usize, 0u64, 0usize);
        // Feature prediction for the tracker (after each keyframe) is part of the hot loop too.
        let mut buf = [povins::core::estimator::FeaturePrediction::EMPTY; 200];
        let allocs = count_allocs(|| {
            est.initialize(s0).expect("initialize from ground truth");
            drive_lidar(&mut est, &ds.imu[start..], &frames, &sweeps, |e, s, o| {
                if let Some(r) = o.keyframe {
                    keyframes += 1;
                    ldm_used += u64::from(r.ldm_count);
                    predicted += e.predict_features(s.t_ns, &mut buf).unwrap_or(0);
                }
                true
            });
        });
        let c = est.counters();
        println!("robot with LiDAR ({ldm:?}): {keyframes} keyframes, {ldm_used} LDMs, {predicted} predictions, {allocs} allocations, {c:?}");
        assert!(keyframes > 40, "only {keyframes} keyframes");
        assert!(predicted > 1000, "only {predicted} feature predictions");
        assert!(c.lidar_points_accepted > 100_000, "{c:?}");
        assert!(ldm_used > 100, "LiDAR depths were not used: {ldm_used}");
        assert_eq!(allocs, 0, "the estimator allocated {allocs} times");
    });
}

#[test]
fn simulated_robot_with_lidar_msc_does_not_allocate() {
    lidar_alloc_free(povins::core::lidar::LdmMode::Msc);
}

#[test]
fn simulated_robot_with_lidar_direct_does_not_allocate() {
    lidar_alloc_free(povins::core::lidar::LdmMode::Direct);
}

/// The image entry point (`povins_core::vio`: INS predictions, gyro integration, pyramid, LK,
/// RANSAC, detection, then the whole estimator) on the first 15 s of the real DM-VIO hand-held
/// sequence (static initialization, delay estimation): the images are decoded first, then every
/// IMU sample and image is fed under the counting allocator.
#[test]
#[ignore = "needs ../shared/data/dmvio-realsense-handheld-60s"]
fn dmvio_images_through_vio_do_not_allocate() {
    use povins::core::frontend::image::{ImageView, TrackerConfig};
    use povins::core::vio::EurocVio;
    small_stack(|| {
        let mut ds = load("dmvio-realsense-handheld-60s");
        truncate(&mut ds, 16.0);
        ds.images
            .retain(|im| im.t_ns <= ds.imu.last().map_or(0, |s| s.t_ns));
        povins::platform::euroc::read_images(&mut ds).expect("decode the images");
        let mut cfg = povins::host_tools::runner::config_for(&ds);
        let toml = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/dmvio.toml");
        povins::host_tools::config::RunConfigFile::read(std::path::Path::new(toml))
            .expect("configs/dmvio.toml")
            .apply(&mut cfg)
            .expect("configs/dmvio.toml applies");
        let mut vio: Box<EurocVio> =
            povins::platform::boxed::boxed_vio(cfg, TrackerConfig::default()).expect("vio");
        let (mut keyframes, mut images, mut tracks, mut predicted) = (0usize, 0usize, 0u64, 0u64);
        let mut ii = 0usize;
        let allocs = count_allocs(|| {
            for s in &ds.imu {
                while let Some(im) = ds.images.get(ii).filter(|im| im.t_ns <= s.t_ns) {
                    let w = im.width as usize;
                    if let Ok(view) = ImageView::new(&im.mono8, w, im.height as usize, w) {
                        if let Ok(r) = vio.push_image(im.t_ns, &view) {
                            images += 1;
                            tracks += u64::from(r.tracks);
                            predicted += u64::from(r.predictions);
                        }
                    }
                    ii += 1;
                }
                let _ = vio.push_imu(s);
                while let Ok(Some(o)) = vio.update() {
                    keyframes += usize::from(o.keyframe.is_some());
                }
            }
        });
        let c = vio.estimator().counters();
        println!(
            "DM-VIO images: {images} images, {keyframes} keyframes, {} tracks and {} INS \
             predictions per image, {allocs} allocations, {c:?} {:?}",
            tracks / images.max(1) as u64,
            predicted / images.max(1) as u64,
            vio.counters()
        );
        assert!(images > 200, "{images} images");
        assert!(keyframes > 20, "only {keyframes} keyframes");
        assert!(tracks > 100 * images as u64, "{tracks} tracks");
        assert!(predicted > 30 * images as u64, "{predicted} predictions");
        assert_eq!(vio.counters().images_rejected, 0);
        assert_eq!(allocs, 0, "the image entry point allocated {allocs} times");
    });
}

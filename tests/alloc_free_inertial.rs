//! The inertial hot path never allocates: load the EuRoC IMU log first (allocation allowed),
//! then run INS, the INS window, preintegration in 0.5 s keyframe windows and the whitened
//! residual evaluation over the whole 145 s log under a counting global allocator.

use povins::core::inertial::{
    ImuNoise, ImuSample, Ins, InsConfig, InsWindow, Mat15, NavState, PreintConfig, Preintegration,
    Vec15,
};
use povins::core::math::Vec3;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static ALLOCS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    // Only this test's thread is counted, so the harness's own threads cannot interfere.
    static ACTIVE: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ACTIVE.with(|a| a.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ACTIVE.with(|a| a.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn load_imu() -> Vec<ImuSample> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/euroc-v101-imu-145s/mav0/imu0/data.csv"
    );
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("EuRoC IMU log {path} is missing: {e}"));
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').map(str::trim).collect();
            let v = |i: usize| f[i].parse::<f64>().unwrap();
            ImuSample {
                t_ns: f[0].parse().unwrap(),
                gyro_rps: Vec3::new(v(1), v(2), v(3)),
                accel_mps2: Vec3::new(v(4), v(5), v(6)),
            }
        })
        .collect()
}

#[test]
fn inertial_loop_does_not_allocate() {
    let imu = load_imu();
    assert!(imu.len() > 29_000);
    // Large state lives on the heap, allocated before counting starts.
    let mut pre = Box::new(
        Preintegration::<128>::new(
            ImuNoise::EUROC_ADIS16448,
            PreintConfig::DEFAULT,
            &imu[0],
            Vec3::zeros(),
            Vec3::zeros(),
        )
        .unwrap(),
    );
    let mut window = Box::new(InsWindow::<400>::new());
    let mut ins = Ins::new(InsConfig::DEFAULT, NavState::identity(imu[0].t_ns)).unwrap();
    let (mut r, mut ji, mut jj) = (
        Box::new(Vec15::zeros()),
        Box::new(Mat15::zeros()),
        Box::new(Mat15::zeros()),
    );

    ALLOCS.store(0, Ordering::SeqCst);
    ACTIVE.with(|a| a.set(true));
    let mut kf = *ins.state();
    let mut keyframes = 0usize;
    let mut cost = 0.0;
    for (k, s) in imu.iter().enumerate() {
        let st = *ins.propagate(s).unwrap();
        window.push(st).unwrap();
        if k == 0 {
            continue;
        }
        pre.push(s).unwrap();
        if k % 100 == 0 {
            pre.evaluate(&kf, &st, 9.81, &mut r, &mut ji, &mut jj)
                .unwrap();
            cost += r.norm_squared();
            let mid = window.oldest().unwrap().t_ns / 2 + st.t_ns / 2;
            window.pose_at(mid).unwrap();
            pre.update_linearization(&st.bg, &st.ba).unwrap();
            pre.reset(s, st.bg, st.ba).unwrap();
            kf = st;
            keyframes += 1;
        }
    }
    ACTIVE.with(|a| a.set(false));
    let allocs = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(keyframes, 291);
    // The INS keeps its two-sample history across keyframes while each preintegration starts
    // fresh, so the residual is small but not exactly zero.
    println!("whitened preintegration cost over 291 windows: {cost:.3e}");
    assert!(cost.is_finite());
    assert_eq!(allocs, 0, "the inertial loop allocated {allocs} times");
}

//! `povins run`'s memory does not grow with the recording: what the run keeps for its summary
//! ([`RunDigest`]) and the ATE computed over streams ([`ate_rmse`]) are measured under a global
//! allocator that tracks the bytes live on this thread. Keeping the poses (64 bytes each), as
//! the run once did, fails both tests by megabytes.

use povins_core::estimator::KeyframeReport;
use povins_core::inertial::NavState;
use povins_core::math::{Quat, Vec3};
use povins_host_tools::eval::streamed::{ate_rmse, PoseStream};
use povins_host_tools::eval::EvalOptions;
use povins_host_tools::report::RunDigest;
use povins_host_tools::runner::RunSink;
use povins_platform::trajectory::StampedPose;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Tracking;

thread_local! {
    // Per thread, const-initialized (no destructor, no allocation from the allocator).
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn add(bytes: isize) {
    LIVE.with(|l| {
        l.set(l.get() + bytes);
        PEAK.with(|p| p.set(p.get().max(l.get())));
    });
}

// SAFETY: forwards every call to the system allocator unchanged; only counts bytes.
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        add(layout.size() as isize);
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        add(layout.size() as isize);
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        add(-(layout.size() as isize));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        add(new_size as isize - layout.size() as isize);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Tracking = Tracking;

/// The most bytes live on this thread while `f` ran, above those live when it started.
fn peak_growth<T>(f: impl FnOnce() -> T) -> (T, isize) {
    let start = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(start));
    let out = f();
    (out, PEAK.with(Cell::get) - start)
}

/// The body on a circle at 200 Hz, `t` s into it.
fn state(k: i64) -> NavState {
    let t = k as f64 * 0.005;
    NavState {
        t_ns: k * 5_000_000,
        p_wb: Vec3::new(3.0 * (0.1 * t).cos(), 3.0 * (0.1 * t).sin(), 0.01 * t),
        q_wb: Quat::from_euler_angles(0.0, 0.0, 0.1 * t),
        v_wb: Vec3::zeros(),
        bg: Vec3::zeros(),
        ba: Vec3::zeros(),
    }
}

/// A run of `n` IMU-rate poses with ground truth: a keyframe every 40 poses, 30 prediction
/// errors a frame; the bytes the digest holds at the end.
fn digest_bytes(n: i64) -> isize {
    let (digest, bytes) = peak_growth(|| {
        let mut d = RunDigest::keeping_all();
        for k in 0..n {
            let s = state(k);
            d.nav(&s);
            if k % 10 == 0 {
                d.prediction_errors(&[0.7_f32; 30]);
            }
            if k % 40 == 0 {
                d.keyframe(&s);
                d.report(&KeyframeReport::default(), &[]);
            }
        }
        d
    });
    drop(digest);
    bytes
}

/// Ten times the run costs the per-keyframe figures (about 40 bytes each), not the poses.
#[test]
fn the_run_s_digest_does_not_hold_the_poses() {
    let (short, long) = (digest_bytes(12_000), digest_bytes(120_000));
    let keyframes = (120_000 - 12_000) / 40;
    assert!(
        long - short < 100 * keyframes,
        "the digest grew {} bytes over {} more poses (the poses alone are {})",
        long - short,
        108_000,
        108_000 * 64
    );
    // Not nothing: the counter sees what the digest keeps.
    assert!(short > 0);
}

/// The ATE of 200,000 poses against 200,000 ground-truth states, read as streams, in the memory
/// of a few buffers.
#[test]
fn the_ate_over_streams_holds_no_trajectory() {
    let n = 200_000;
    let pose = |k: i64, off: f64| {
        let s = state(k);
        StampedPose {
            t_ns: s.t_ns + 1_000,
            p_wb: s.p_wb + Vec3::new(off, 0.0, 0.0),
            q_wb: s.q_wb,
        }
    };
    let gt = || -> anyhow::Result<PoseStream<'static>> {
        Ok(Box::new((0..n).map(move |k| Ok(pose(k, 0.0)))))
    };
    let est = || -> anyhow::Result<PoseStream<'static>> {
        Ok(Box::new((0..n).map(move |k| {
            Ok(pose(k, if k % 2 == 0 { 0.01 } else { -0.01 }))
        })))
    };
    let (r, bytes) = peak_growth(|| ate_rmse(&gt, &est, &EvalOptions::default()));
    let r = r.expect("evaluation");
    assert_eq!(r.matched, n as usize);
    assert!((r.pos_rmse_m - 0.01).abs() < 1e-9, "{}", r.pos_rmse_m);
    assert!(bytes < 64 * 1024, "{bytes} bytes for {n} poses");
}

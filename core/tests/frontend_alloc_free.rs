//! The image front end never touches the heap: a tracker is built first, then frames are
//! tracked under a counting global allocator with every path exercised (pyramid with CLAHE,
//! detection, LK with gyro and INS seeds, forward-backward check, both RANSAC models, top-up,
//! odd images and errors). Synthetic frames, so it runs without the shared data.

mod counting_alloc;

use counting_alloc::count_allocs;
use povins_core::camera::PinholeCamera;
use povins_core::frontend::image::{
    Equalization, EurocTracker, ImageView, RansacConfig, RansacModel, TrackHints, TrackerConfig,
};
use povins_core::math::{exp_so3, Vec3};

const W: usize = 752;
const H: usize = 480;

/// A textured plane at infinity seen by a camera rotating about its y axis by `yaw` rad.
fn frame(yaw: f64) -> Vec<u8> {
    let c = PinholeCamera::EUROC_CAM0;
    let r = exp_so3(&Vec3::new(0.0, yaw, 0.0));
    let mut img = Vec::with_capacity(W * H);
    for v in 0..H {
        for u in 0..W {
            let d = r * Vec3::new((u as f64 - c.cx) / c.fx, (v as f64 - c.cy) / c.fy, 1.0);
            let (x, y) = (400.0 * d.x / d.z, 400.0 * d.y / d.z);
            let t = 128.0
                + 40.0 * libm::sin(0.11 * x + 0.05 * y)
                + 30.0 * libm::cos(0.13 * y - 0.04 * x)
                + 20.0 * libm::sin(0.23 * x - 0.17 * y)
                + 12.0 * libm::cos(0.31 * y + 0.19 * x);
            img.push(t.clamp(0.0, 255.0) as u8);
        }
    }
    img
}

#[test]
fn counter_sees_allocations() {
    let n = count_allocs(|| drop(std::hint::black_box(Vec::<u64>::with_capacity(16))));
    assert_eq!(n, 1);
}

#[test]
fn tracking_allocates_nothing() {
    let frames: Vec<Vec<u8>> = (0..12).map(|k| frame(0.004 * k as f64)).collect();
    let black = vec![0u8; W * H];
    let noise: Vec<u8> = (0..W * H)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    let preds: Vec<(u64, [f64; 2])> = (0..200).map(|i| (i, [300.0 + i as f64, 200.0])).collect();
    let r = exp_so3(&Vec3::new(0.0, -0.004, 0.0));
    let handle = std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(move || {
            let mut totals = Vec::new();
            for (model, eq) in [
                (RansacModel::Auto, Equalization::CLAHE_3_8X8),
                (RansacModel::EightPoint, Equalization::Global),
                (RansacModel::TwoPoint, Equalization::Off),
            ] {
                let cfg = TrackerConfig {
                    equalization: eq,
                    ransac: RansacConfig {
                        model,
                        ..RansacConfig::default()
                    },
                    ..TrackerConfig::default()
                };
                let mut t = Box::new(EurocTracker::new(cfg).unwrap());
                let cam = PinholeCamera::EUROC_CAM0;
                let mut total = 0u32;
                let allocs = count_allocs(|| {
                    for (k, f) in frames.iter().enumerate() {
                        let v = ImageView::new(f, W, H, W).unwrap();
                        let hints = TrackHints {
                            r_cur_prev: (k % 2 == 1).then_some(r),
                            predictions: if k % 3 == 2 { &preds } else { &[] },
                        };
                        total += t
                            .track(k as i64 * 50_000_000, &v, &hints, &cam)
                            .unwrap()
                            .tracked;
                    }
                    // Odd input: black and noise frames, a repeated stamp, a wrong size.
                    for (k, img) in [&black, &noise, &frames[0]].iter().enumerate() {
                        let v = ImageView::new(img, W, H, W).unwrap();
                        let _ = t.track(10_000_000_000 + k as i64, &v, &TrackHints::NONE, &cam);
                    }
                    let v = ImageView::new(&black, W, H, W).unwrap();
                    assert!(t.track(0, &v, &TrackHints::NONE, &cam).is_err());
                    let small = ImageView::new(&black[..100 * 100], 100, 100, 100).unwrap();
                    assert!(t
                        .track(20_000_000_000, &small, &TrackHints::NONE, &cam)
                        .is_err());
                });
                assert_eq!(allocs, 0, "{model:?}: {allocs} allocations while tracking");
                totals.push(total);
            }
            totals
        })
        .unwrap();
    let totals = handle.join().unwrap();
    // The frames were really tracked (the test would be empty otherwise).
    assert!(totals.iter().all(|&t| t > 11 * 100), "{totals:?}");
}

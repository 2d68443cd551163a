//! Synthetic images for the unit tests (std only).
extern crate std;
use std::vec::Vec;

/// Smooth texture with a falling spectrum like natural images (sinusoids of periods 12-60 px,
/// larger amplitudes at longer periods), grey levels about 30-225.
pub fn texture(x: f64, y: f64) -> f64 {
    128.0
        + 35.0 * libm::sin(0.11 * x + 0.05 * y)
        + 30.0 * libm::cos(0.13 * y - 0.04 * x + 1.0)
        + 20.0 * libm::sin(0.23 * x - 0.17 * y + 2.0)
        + 15.0 * libm::cos(0.31 * y + 0.19 * x)
        + 8.0 * libm::sin(0.47 * x + 0.21 * y + 0.5)
}

/// `w x h` image of `f` sampled at pixel centres shifted by `(dx, dy)`: `I(x, y) = f(x - dx,
/// y - dy)` (the content moves by `+(dx, dy)`), rounded to u8.
pub fn render(w: usize, h: usize, dx: f64, dy: f64, f: impl Fn(f64, f64) -> f64) -> Vec<u8> {
    let mut img = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let v = f(x as f64 - dx, y as f64 - dy);
            img.push(libm::round(v).clamp(0.0, 255.0) as u8);
        }
    }
    img
}

/// Checkerboard of `sq`-px squares (values 40 and 210) with vertices at multiples of `sq`
/// (between pixels `k sq - 1` and `k sq`, i.e. at `k sq - 0.5`).
pub fn checkerboard(w: usize, h: usize, sq: usize) -> Vec<u8> {
    let mut img = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            img.push(if (x / sq + y / sq).is_multiple_of(2) {
                40
            } else {
                210
            });
        }
    }
    img
}

/// Deterministic uniform noise image.
pub fn noise(w: usize, h: usize, seed: u64) -> Vec<u8> {
    let mut s = seed | 1;
    (0..w * h)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 56) as u8
        })
        .collect()
}

/// Runs `f` on a thread with a 64 MiB stack (the trackers are large values).
pub fn big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap()
}

/// Width of the unit tests' camera and images, px.
pub const TEST_W: usize = 320;
/// Height of the unit tests' camera and images, px.
pub const TEST_H: usize = 240;

/// The unit tests' pinhole camera: `TEST_W x TEST_H`, focal 300 px, centred, no distortion.
pub fn test_camera() -> crate::camera::PinholeCamera {
    crate::camera::PinholeCamera {
        readout_s: 0.0,
        width: TEST_W as u32,
        height: TEST_H as u32,
        fx: 300.0,
        fy: 300.0,
        cx: 159.5,
        cy: 119.5,
        distortion: crate::camera::Distortion::None,
    }
}

/// The [`texture`] on the plane `z = 1` of the world (300 px per unit) seen through
/// [`test_camera`] rotated by `r_world_cam`.
pub fn render_rotated(r_world_cam: &crate::math::Mat3) -> Vec<u8> {
    let c = test_camera();
    let mut img = Vec::with_capacity(TEST_W * TEST_H);
    for v in 0..TEST_H {
        for u in 0..TEST_W {
            let ray =
                crate::math::Vec3::new((u as f64 - c.cx) / c.fx, (v as f64 - c.cy) / c.fy, 1.0);
            let d = r_world_cam * ray;
            let val = texture(300.0 * d.x / d.z, 300.0 * d.y / d.z);
            img.push(libm::round(val).clamp(0.0, 255.0) as u8);
        }
    }
    img
}

/// The unit tests' small tracker: 40 features on a 4 x 3 grid, at most 5 per cell, 15 px apart.
pub fn small_tracker_config() -> super::TrackerConfig {
    super::TrackerConfig {
        max_features: 40,
        detector: super::DetectorConfig {
            grid_cols: 4,
            grid_rows: 3,
            max_per_cell: 5,
            min_distance_px: 15.0,
            ..super::DetectorConfig::default()
        },
        ..super::TrackerConfig::default()
    }
}

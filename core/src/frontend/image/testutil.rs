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

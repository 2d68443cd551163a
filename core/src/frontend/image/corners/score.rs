//! The corner response: 3x3 Sobel gradients, their products and 3x3 block sums (the structure
//! tensor), and its minimum eigenvalue.
//!
//! Response: the minimum eigenvalue of the 2x2 structure tensor summed over a 3x3 block of 3x3
//! Sobel gradients (OpenCV `goodFeaturesToTrack` with `blockSize = 3`). Gradients, products and
//! block sums are exact integers (`|sum| < 2^24`); the eigenvalue is evaluated once per pixel in
//! `f32` in a fixed order with a correctly rounded square root, so it is bit-identical on every
//! target. Responses are reported in `(grey level / px)^2` (the eigenvalue of the block's mean
//! gradient outer product): raw Sobel sums are `8 * 8 * 9 = 576` times that.

use super::super::view::ImageView;

/// Raw response at pixel `(x, y)` (0 within 3 px of the border).
pub(super) fn response_at(img: &ImageView, x: usize, y: usize) -> f32 {
    if x < 3 || y < 3 || x + 3 >= img.width() || y + 3 >= img.height() {
        return 0.0;
    }
    let (mut a, mut b, mut c) = (0i32, 0i32, 0i32);
    for yy in y - 1..=y + 1 {
        let (Some(ra), Some(rb), Some(rc)) = (
            img.span(x - 2, yy - 1, 5),
            img.span(x - 2, yy, 5),
            img.span(x - 2, yy + 1, 5),
        ) else {
            return 0.0;
        };
        let (mut gx, mut gy) = ([0i32; 3], [0i32; 3]);
        sobel_row(ra, rb, rc, &mut gx, &mut gy);
        for (x, y) in gx.iter().zip(&gy) {
            a += x * x;
            b += x * y;
            c += y * y;
        }
    }
    min_eig(a, b, c)
}

/// Minimum eigenvalue of `[[a, b], [b, c]]` (raw integer sums, exact in `f32`).
#[inline(always)]
fn min_eig(a: i32, b: i32, c: i32) -> f32 {
    let (a, b, c) = (a as f32, b as f32, c as f32);
    let d = a - c;
    0.5 * ((a + c) - libm::sqrtf(d * d + 4.0 * (b * b)))
}

/// `sqrt(x)` for `x >= 0` from IEEE `+ - * /` and integer bit operations only: an initial guess
/// from the exponent bits (within 4%) and three Newton steps, accurate to `f32` rounding. Unlike
/// `libm::sqrtf` (an opaque instruction) it vectorizes, and it is bit-identical on every IEEE
/// target (no fused multiply-add, no estimate instructions).
#[inline(always)]
pub(super) fn sqrt_newton(x: f32) -> f32 {
    let g = f32::from_bits((x.to_bits() >> 1) + 0x1fbd_1df5);
    let g = 0.5 * (g + x / g);
    let g = 0.5 * (g + x / g);
    0.5 * (g + x / g)
}

/// Responses of one row from the block sums: the minimum eigenvalue where it exceeds the floor
/// `f` (tested exactly: `a > f` and `(a - f)(c - f) > b^2`), else 0. The sums are exact integers
/// in `f32` (`< 2^24`). Branch-free so it vectorizes.
#[inline(always)]
pub(super) fn response_row(a: &[f32], b: &[f32], c: &[f32], f: f32, out: &mut [f32]) {
    for (((r, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        let (am, cm) = (a - f, c - f);
        let pass = (am > 0.0) & (am * cm > b * b);
        let d = a - c;
        let l = 0.5 * ((a + c) - sqrt_newton(d * d + 4.0 * (b * b)));
        *r = if pass { l } else { 0.0 };
    }
}

/// `out[k] = v[k] + v[k + 1] + v[k + 2]`.
#[inline(always)]
pub(super) fn hsum3(v: &[f32], out: &mut [f32]) {
    let n = out.len();
    let (Some(a), Some(b), Some(c)) = (v.get(..n), v.get(1..n + 1), v.get(2..n + 2)) else {
        return;
    };
    for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        *o = (a + b) + c;
    }
}

/// `out[k] = a[k] + b[k] + c[k]`.
#[inline(always)]
pub(super) fn vsum3(a: &[f32], b: &[f32], c: &[f32], out: &mut [f32]) {
    for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
        *o = (a + b) + c;
    }
}

/// 3x3 Sobel of the middle row `rb` (rows `ra`, `rc` above and below); `gx.len() + 2` pixels in.
#[inline(always)]
pub(super) fn sobel_row(ra: &[u8], rb: &[u8], rc: &[u8], gx: &mut [i32], gy: &mut [i32]) {
    let n = gx.len().min(gy.len());
    let (Some(a0), Some(a1), Some(a2)) = (ra.get(..n), ra.get(1..n + 1), ra.get(2..n + 2)) else {
        return;
    };
    let (Some(b0), Some(b2)) = (rb.get(..n), rb.get(2..n + 2)) else {
        return;
    };
    let (Some(c0), Some(c1), Some(c2)) = (rc.get(..n), rc.get(1..n + 2 - 1), rc.get(2..n + 2))
    else {
        return;
    };
    let it = gx
        .iter_mut()
        .zip(gy.iter_mut())
        .zip(a0.iter().zip(a1).zip(a2))
        .zip(b0.iter().zip(b2))
        .zip(c0.iter().zip(c1).zip(c2));
    for ((((ox, oy), ((&a0, &a1), &a2)), (&b0, &b2)), ((&c0, &c1), &c2)) in it {
        let (a0, a1, a2) = (i32::from(a0), i32::from(a1), i32::from(a2));
        let (b0, b2) = (i32::from(b0), i32::from(b2));
        let (c0, c1, c2) = (i32::from(c0), i32::from(c1), i32::from(c2));
        *ox = (a2 - a0) + 2 * (b2 - b0) + (c2 - c0);
        *oy = (c0 + 2 * c1 + c2) - (a0 + 2 * a1 + a2);
    }
}

//! Tests of the affine refinement (`affine.rs` includes this file as its `#[cfg(test)]`
//! module; the attribute below repeats that for readers of this file alone).
#[cfg(test)]
extern crate std;
use super::super::testutil::{render, texture};
use super::*;
use std::boxed::Box;
use std::vec::Vec;

const W: usize = 160;
const H: usize = 120;

/// The texture warped by `a` about `c` and moved by `s`: `b(c + s + a x) = tex(c + x)`.
fn warped(a: [f64; 4], c: [f64; 2], s: [f64; 2]) -> Vec<u8> {
    let det = a[0] * a[3] - a[1] * a[2];
    render(W, H, 0.0, 0.0, |x, y| {
        let (dx, dy) = (x - c[0] - s[0], y - c[1] - s[1]);
        let u = (a[3] * dx - a[1] * dy) / det;
        let v = (-a[2] * dx + a[0] * dy) / det;
        texture(c[0] + u, c[1] + v)
    })
}

fn rot(th: f64, k: f64) -> [f64; 4] {
    [
        k * libm::cos(th),
        -k * libm::sin(th),
        k * libm::sin(th),
        k * libm::cos(th),
    ]
}

/// Template of `img` for the point `p`: its centre pixel and the offset.
fn template(
    img: &[u8],
    p: [f64; 2],
    win: usize,
    photo: Photometric,
    g: &mut Gradients,
) -> (Box<Template>, [f64; 2]) {
    let v = ImageView::new(img, W, H, W).unwrap();
    let c = [libm::round(p[0]) as i64, libm::round(p[1]) as i64];
    let mut t = Box::new(Template::EMPTY);
    t.build(&v, c, win, photo, g);
    (t, [p[0] - c[0] as f64, p[1] - c[1] as f64])
}

#[test]
fn recovers_rotation_scale_and_shift() {
    let c = [80.3, 60.7];
    let reference = render(W, H, 0.0, 0.0, texture);
    let mut g = Box::new(Gradients::new());
    let a = rot(0.14, 1.06);
    let models = [Photometric::None, Photometric::GainOffset];
    for (win, photo) in [11, 15, 21]
        .into_iter()
        .flat_map(|w| models.map(|p| (w, p)))
    {
        let (tpl, delta) = template(&reference, c, win, photo, &mut g);
        assert!(tpl.is_valid());
        for &sh in &[[0.0, 0.0], [3.4, -2.2], [-0.37, 0.81]] {
            let img = warped(a, c, sh);
            let iv = ImageView::new(&img, W, H, W).unwrap();
            let truth = [c[0] + sh[0], c[1] + sh[1]];
            let init = Affine::through(rot(0.0, 1.0), delta, [truth[0] + 0.6, truth[1] - 0.5]);
            let fit = refine_affine(&tpl, &iv, init, 30, 0.01, &mut g).unwrap();
            let q = fit.warp.point(delta);
            let e = libm::hypot(q[0] - truth[0], q[1] - truth[1]);
            // The 6-parameter fit of an 11x11 window is noisier (rounded grey levels).
            let tol = if win == 11 { 0.05 } else { 0.03 };
            assert!(
                fit.converged && e < tol,
                "win {win} {sh:?}: {fit:?} error {e}"
            );
            // A gain absorbs part of a scale change: the 11x11 window's linear part is looser.
            let tol_a = if win == 11 && photo == Photometric::GainOffset {
                0.03
            } else {
                0.015
            };
            for (x, y) in fit.warp.a.iter().zip(&a) {
                assert!(
                    libm::fabs(x - y) < tol_a,
                    "win {win}: {:?} vs {a:?}",
                    fit.warp.a
                );
            }
            assert!(fit.residual < 2.0, "{fit:?}");
        }
    }
}

#[test]
fn warm_start_converges_in_few_iterations() {
    let c = [70.0, 55.2];
    let reference = render(W, H, 0.0, 0.0, texture);
    let mut g = Box::new(Gradients::new());
    let (tpl, delta) = template(&reference, c, 15, Photometric::GainOffset, &mut g);
    let a = rot(0.05, 0.97);
    let img = warped(a, c, [1.3, 0.4]);
    let iv = ImageView::new(&img, W, H, W).unwrap();
    let truth = [c[0] + 1.3, c[1] + 0.4];
    // Seeded at the truth with the right linear part: converged after one or two steps.
    let fit = refine_affine(
        &tpl,
        &iv,
        Affine::through(a, delta, truth),
        10,
        0.03,
        &mut g,
    )
    .unwrap();
    assert!(fit.converged && fit.iterations <= 2, "{fit:?}");
}

/// The same algorithm in plain `f64` (bilinear samples, exact gradients of the template pixels):
/// the reference the fixed-point kernel must agree with.
fn refine_f64(
    img: &[u8],
    tpl_img: &[u8],
    c: [i64; 2],
    win: usize,
    init: Affine,
    it: u32,
) -> Affine {
    let px = |im: &[u8], x: i64, y: i64| {
        f64::from(im[(y.clamp(0, H as i64 - 1) as usize) * W + x.clamp(0, W as i64 - 1) as usize])
    };
    let sample = |x: f64, y: f64| {
        let (fx, fy) = (libm::floor(x), libm::floor(y));
        let (ax, ay) = (x - fx, y - fy);
        let (ix, iy) = (fx as i64, fy as i64);
        let top = px(img, ix, iy) * (1.0 - ax) + px(img, ix + 1, iy) * ax;
        let bot = px(img, ix, iy + 1) * (1.0 - ax) + px(img, ix + 1, iy + 1) * ax;
        top * (1.0 - ay) + bot * ay
    };
    let half = (win / 2) as i64;
    let mut sds = Vec::new();
    let mut h = [[0.0f64; 6]; 6];
    for y in -half..=half {
        for x in -half..=half {
            let t = |dx: i64, dy: i64| px(tpl_img, c[0] + x + dx, c[1] + y + dy);
            let gx = (3.0 * (t(1, -1) - t(-1, -1))
                + 10.0 * (t(1, 0) - t(-1, 0))
                + 3.0 * (t(1, 1) - t(-1, 1)))
                / 32.0;
            let gy = (3.0 * (t(-1, 1) - t(-1, -1))
                + 10.0 * (t(0, 1) - t(0, -1))
                + 3.0 * (t(1, 1) - t(1, -1)))
                / 32.0;
            let (xf, yf) = (x as f64, y as f64);
            let sd = [gx * xf, gx * yf, gy * xf, gy * yf, gx, gy];
            for i in 0..6 {
                for j in 0..6 {
                    h[i][j] += sd[i] * sd[j];
                }
            }
            sds.push((xf, yf, t(0, 0), sd));
        }
    }
    // Gauss-Jordan inverse (test only).
    let mut m = h;
    let mut inv = [[0.0f64; 6]; 6];
    for (i, r) in inv.iter_mut().enumerate() {
        r[i] = 1.0;
    }
    for col in 0..6 {
        let p = m[col][col];
        for j in 0..6 {
            m[col][j] /= p;
            inv[col][j] /= p;
        }
        for r in 0..6 {
            if r != col {
                let f = m[r][col];
                for j in 0..6 {
                    m[r][j] -= f * m[col][j];
                    inv[r][j] -= f * inv[col][j];
                }
            }
        }
    }
    let mut w = init;
    for _ in 0..it {
        let mut b = [0.0f64; 6];
        for &(x, y, t, sd) in &sds {
            let e = sample(
                w.a[0] * x + w.a[1] * y + w.t[0],
                w.a[2] * x + w.a[3] * y + w.t[1],
            ) - t;
            for i in 0..6 {
                b[i] += sd[i] * e;
            }
        }
        let mut dp = [0.0f64; 6];
        for i in 0..6 {
            for j in 0..6 {
                dp[i] += inv[i][j] * b[j];
            }
        }
        let (d00, d01, d10, d11) = (1.0 + dp[0], dp[1], dp[2], 1.0 + dp[3]);
        let det = d00 * d11 - d01 * d10;
        let iv = [d11 / det, -d01 / det, -d10 / det, d00 / det];
        let a = w.a;
        let na = [
            a[0] * iv[0] + a[1] * iv[2],
            a[0] * iv[1] + a[1] * iv[3],
            a[2] * iv[0] + a[3] * iv[2],
            a[2] * iv[1] + a[3] * iv[3],
        ];
        w = Affine {
            a: na,
            t: [
                w.t[0] - (na[0] * dp[4] + na[1] * dp[5]),
                w.t[1] - (na[2] * dp[4] + na[3] * dp[5]),
            ],
        };
    }
    w
}

#[test]
fn fixed_point_agrees_with_f64() {
    let reference = render(W, H, 0.0, 0.0, texture);
    let mut g = Box::new(Gradients::new());
    let a = rot(-0.09, 1.03);
    // Interior and near the border (replicated pixels in the template and the target).
    for &(p, sh) in &[
        ([80.3, 60.7], [1.7, -0.6]),
        ([40.6, 30.1], [-2.2, 1.1]),
        ([6.2, 8.9], [0.4, 0.3]),
    ] {
        let img = warped(a, p, sh);
        let iv = ImageView::new(&img, W, H, W).unwrap();
        for win in [11, 15, 21] {
            let (tpl, delta) = template(&reference, p, win, Photometric::None, &mut g);
            let c = [libm::round(p[0]) as i64, libm::round(p[1]) as i64];
            let init = Affine::through(
                rot(0.0, 1.0),
                delta,
                [p[0] + sh[0] + 0.4, p[1] + sh[1] - 0.3],
            );
            for it in [1, 3, 8] {
                let fx = refine_affine(&tpl, &iv, init, it, 0.0, &mut g).unwrap();
                let fr = refine_f64(&img, &reference, c, win, init, it);
                let (qa, qb) = (fx.warp.point(delta), fr.point(delta));
                let e = libm::hypot(qa[0] - qb[0], qa[1] - qb[1]);
                assert!(e < 0.01, "{p:?} win {win} it {it}: {qa:?} vs {qb:?}");
                for (x, y) in fx.warp.a.iter().zip(&fr.a) {
                    assert!(libm::fabs(x - y) < 2e-3, "{:?} vs {:?}", fx.warp.a, fr.a);
                }
            }
        }
    }
}

#[test]
fn bad_inputs_give_none_or_invalid() {
    let reference = render(W, H, 0.0, 0.0, texture);
    let rv = ImageView::new(&reference, W, H, W).unwrap();
    let mut g = Box::new(Gradients::new());
    let mut t = Box::new(Template::EMPTY);
    for win in [4, 20, 23, 3] {
        t.build(&rv, [80, 60], win, Photometric::GainOffset, &mut g);
        assert!(!t.is_valid(), "window {win}");
    }
    assert!(refine_affine(
        &t,
        &rv,
        Affine::through(rot(0.0, 1.0), [0.0; 2], [80.0, 60.0]),
        5,
        0.01,
        &mut g
    )
    .is_none());
    let flat = std::vec![90u8; W * H];
    let fv = ImageView::new(&flat, W, H, W).unwrap();
    t.build(&fv, [80, 60], 15, Photometric::GainOffset, &mut g);
    assert!(!t.is_valid());
    // A vertical edge: one-dimensional texture, no affine fit.
    let edge: Vec<u8> = (0..W * H)
        .map(|i| if i % W < 80 { 40 } else { 200 })
        .collect();
    let ev = ImageView::new(&edge, W, H, W).unwrap();
    t.build(&ev, [80, 60], 15, Photometric::GainOffset, &mut g);
    assert!(!t.is_valid());
    t.build(&rv, [80, 60], 15, Photometric::GainOffset, &mut g);
    assert!(t.is_valid());
    let nan = Affine::through(rot(0.0, 1.0), [0.0; 2], [f64::NAN, 1.0]);
    assert!(refine_affine(&t, &rv, nan, 10, 0.01, &mut g).is_none());
    let far = Affine::through(rot(0.0, 1.0), [0.0; 2], [1e9, 1.0]);
    assert!(refine_affine(&t, &rv, far, 10, 0.01, &mut g).is_none());
    // Far outside but finite: clamped reads, never a panic.
    let out = Affine::through(rot(0.0, 1.0), [0.0; 2], [-500.0, 900.0]);
    let _ = refine_affine(&t, &rv, out, 10, 0.01, &mut g);
    let edge_img = ImageView::new(&reference, W, H, W).unwrap();
    t.build(&edge_img, [-40, 500], 15, Photometric::GainOffset, &mut g);
}

/// The row-wise gradient kernel gives the integers of the plain per-pixel Scharr formula.
#[test]
fn gradients_match_the_per_pixel_formula() {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut pix = [0u8; TEMPLATE_SIDE * TEMPLATE_SIDE];
    let mut g = Box::new(Gradients::new());
    for win in [5usize, 11, 15, 21] {
        for v in pix.iter_mut() {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            *v = (s >> 56) as u8;
        }
        g.compute(&pix, win);
        let p = |x: usize, y: usize| i16::from(pix[y * TEMPLATE_SIDE + x]);
        for r in 0..win {
            for c in 0..win {
                let (x, y) = (c + 1, r + 1);
                let gx = 3 * (p(x + 1, y - 1) - p(x - 1, y - 1))
                    + 10 * (p(x + 1, y) - p(x - 1, y))
                    + 3 * (p(x + 1, y + 1) - p(x - 1, y + 1));
                let gy = 3 * (p(x - 1, y + 1) - p(x - 1, y - 1))
                    + 10 * (p(x, y + 1) - p(x, y - 1))
                    + 3 * (p(x + 1, y + 1) - p(x + 1, y - 1));
                let k = r * win + c;
                assert_eq!(
                    (g.t8[k], g.gx[k], g.gy[k]),
                    (8 * p(x, y), gx, gy),
                    "{win} {r} {c}"
                );
            }
        }
    }
}

/// The one-product bilinear blend gives the integers of the plain four-weight formula.
#[test]
fn blend_matches_the_four_weight_formula() {
    let plain = |p: [u8; 4], fx: i32, fy: i32| {
        let top = i32::from(p[0]) * (256 - fx) + i32::from(p[1]) * fx;
        let bot = i32::from(p[2]) * (256 - fx) + i32::from(p[3]) * fx;
        (top * (256 - fy) + bot * fy + (1 << 12)) >> 13
    };
    let vals = [0u8, 1, 17, 128, 200, 254, 255];
    for &a in &vals {
        for &b in &vals {
            for &c in &vals {
                for &d in &vals {
                    for fx in (0..256).step_by(5) {
                        for fy in (0..256).step_by(7) {
                            let p = [a, b, c, d];
                            assert_eq!(blend(a, b, c, d, fx, fy), plain(p, fx, fy));
                        }
                    }
                }
            }
        }
    }
}

/// The previous kernel, row by row straight from the image with per-pixel bounds checks (kept
/// here as the reference the faster sampling must equal bit for bit).
fn sample_row_plain(
    img: &ImageView,
    (u, v): (i32, i32),
    (du, dv): (i32, i32),
    win: usize,
    t8: &[i16],
    e: &mut [i32],
) {
    let (mut uu, mut vv) = (u, v);
    for (ei, &t) in e.iter_mut().zip(t8).take(win) {
        let (ix, iy) = ((uu >> FRAC) as isize, (vv >> FRAC) as isize);
        let (fx, fy) = ((uu >> (FRAC - 8)) & 255, (vv >> (FRAC - 8)) & 255);
        let j = blend(
            img.clamped(ix, iy),
            img.clamped(ix + 1, iy),
            img.clamped(ix, iy + 1),
            img.clamped(ix + 1, iy + 1),
            fx,
            fy,
        );
        *ei = j - i32::from(t);
        uu = uu.wrapping_add(du);
        vv = vv.wrapping_add(dv);
    }
}

/// The previous `refine_affine` (per-row sums `sum gx e x` with `i32` products), the reference
/// for [`refine_affine`].
fn refine_affine_plain(
    tpl: &Template,
    img: &ImageView,
    init: Affine,
    max_iter: u32,
    eps_px: f64,
    g: &mut Gradients,
) -> Option<AffineFit> {
    let win = usize::from(tpl.win);
    if win == 0 {
        return None;
    }
    g.compute(&tpl.pix, win);
    let ps = PhotoSums::of(g, win)?;
    let ps = (tpl.photo != 0).then_some(&ps);
    let half = (win / 2) as i64;
    let hf = half as f64;
    let mut w = init;
    let mut fit = AffineFit {
        warp: w,
        residual: 0.0,
        converged: false,
        iterations: 0,
    };
    let mut e = [0i32; MAX_AFFINE_WINDOW];
    for _ in 0..max_iter {
        let mut b = [0i64; 6];
        let (mut se, mut ste, mut see) = (0i64, 0i64, 0i64);
        let step = (fixed(w.a[0])?, fixed(w.a[2])?);
        for r in 0..win {
            let y = r as i64 - half;
            let yf = y as f64;
            let start = (
                fixed(w.t[0] - w.a[0] * hf + w.a[1] * yf)?,
                fixed(w.t[1] - w.a[2] * hf + w.a[3] * yf)?,
            );
            let row = r * win..(r + 1) * win;
            let (t8, gx, gy) = (&g.t8[row.clone()], &g.gx[row.clone()], &g.gy[row]);
            sample_row_plain(img, start, step, win, t8, &mut e);
            let (mut sx, mut sxx, mut sy, mut syx) = (0i32, 0i32, 0i32, 0i32);
            for (c, (((&e, &gxv), &gyv), &t)) in e.iter().zip(gx).zip(gy).zip(t8).enumerate() {
                let x = c as i32 - half as i32;
                let (a, bb) = (i32::from(gxv) * e, i32::from(gyv) * e);
                sx += a;
                sxx += a * x;
                sy += bb;
                syx += bb * x;
                se += i64::from(e);
                ste += i64::from(t) * i64::from(e);
                see += i64::from(e) * i64::from(e);
            }
            b[0] += i64::from(sxx);
            b[1] += y * i64::from(sx);
            b[2] += i64::from(syx);
            b[3] += y * i64::from(sy);
            b[4] += i64::from(sx);
            b[5] += i64::from(sy);
        }
        fit.iterations += 1;
        let (dp, residual) = photometric_step(tpl, ps, &b, (se, ste, see), win * win);
        fit.residual = residual;
        let (nw, moved2) = compose(&w, &dp, hf)?;
        w = nw;
        if moved2 <= eps_px * eps_px {
            fit.converged = true;
            break;
        }
    }
    fit.warp = w;
    Some(fit)
}

/// The box-buffered, vectorizable kernel gives bit for bit the previous kernel's fits (each
/// photometric model): random
/// warps (rotation, scale up to 2x, shear), in the interior, across the border and outside the
/// image (replicated pixels), windows 5 to 21, 1 to 6 iterations.
#[test]
fn fast_kernel_equals_the_plain_kernel() {
    let img = warped(rot(0.21, 1.1), [80.0, 60.0], [0.0, 0.0]);
    let iv = ImageView::new(&img, W, H, W).unwrap();
    let reference = render(W, H, 0.0, 0.0, texture);
    let rv = ImageView::new(&reference, W, H, W).unwrap();
    let (mut g1, mut g2) = (Box::new(Gradients::new()), Box::new(Gradients::new()));
    let mut tpl = Box::new(Template::EMPTY);
    let mut s = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut boxed, mut direct, mut some) = (0, 0, 0);
    for k in 0..3000 {
        let win = [5usize, 7, 11, 15, 15, 15, 17, 19, 21][k % 9];
        let c = [(rnd() * 170.0) as i64 - 5, (rnd() * 130.0) as i64 - 5];
        let photo = [
            Photometric::None,
            Photometric::Offset,
            Photometric::GainOffset,
        ][k % 3];
        tpl.build(&rv, c, win, photo, &mut g1);
        if !tpl.is_valid() {
            continue;
        }
        let scale = if k % 5 == 0 {
            0.6 + 1.4 * rnd()
        } else {
            0.9 + 0.2 * rnd()
        };
        let mut a = rot(rnd() * 1.2 - 0.6, scale);
        a[1] += 0.2 * rnd() - 0.1;
        let q = [
            c[0] as f64 + 6.0 * rnd() - 3.0,
            c[1] as f64 + 6.0 * rnd() - 3.0,
        ];
        let init = Affine::through(a, [0.0; 2], q);
        let it = 1 + (k % 6) as u32;
        let eps = if k % 2 == 0 { 0.0 } else { 0.1 };
        let fast = refine_affine(&tpl, &iv, init, it, eps, &mut g1);
        let plain = refine_affine_plain(&tpl, &iv, init, it, eps, &mut g2);
        assert_eq!(fast, plain, "case {k}: win {win} at {c:?}, {init:?}");
        some += usize::from(fast.is_some());
        // Which sampling path the first iteration took.
        let half = (win / 2) as f64;
        let span = |p: f64, q: f64| (p.abs() + q.abs()) * 2.0 * half + 2.0;
        if span(a[0], a[1]) < BOX as f64 - 1.0 && span(a[2], a[3]) < BOX as f64 - 1.0 {
            boxed += 1;
        } else {
            direct += 1;
        }
    }
    assert!(
        some > 600 && boxed > 1500 && direct > 100,
        "{some} {boxed} {direct}"
    );
}

/// `x = M^-1 y` for a small dense symmetric positive definite `M` (Gaussian elimination).
#[allow(clippy::needless_range_loop)]
fn solve6(mut m: [[f64; 6]; 6], mut y: [f64; 6]) -> [f64; 6] {
    for c in 0..6 {
        for r in c + 1..6 {
            let f = m[r][c] / m[c][c];
            for k in c..6 {
                m[r][k] -= f * m[c][k];
            }
            y[r] -= f * y[c];
        }
    }
    let mut x = [0.0; 6];
    for r in (0..6).rev() {
        let mut s = y[r];
        for k in r + 1..6 {
            s -= m[r][k] * x[k];
        }
        x[r] = s / m[r][r];
    }
    x
}

/// The step and residual from the integer sums equal the explicit project-out computation:
/// steepest-descent images and error with their least-squares fit on `{1}` / `{1, T}` removed,
/// `dp = 4 (SDp^T SDp)^-1 SDp^T e` (the kernel's units), residual `|e - P e| / sqrt(n) / 8`.
#[test]
fn photometric_step_equals_the_explicit_projection() {
    let reference = render(W, H, 0.0, 0.0, texture);
    let rv = ImageView::new(&reference, W, H, W).unwrap();
    let mut g = Box::new(Gradients::new());
    let mut t = Box::new(Template::EMPTY);
    let mut s = 0x1234_5678_9abc_def1u64;
    let mut rnd = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for (case, photo) in [
        Photometric::None,
        Photometric::Offset,
        Photometric::GainOffset,
    ]
    .into_iter()
    .cycle()
    .take(12)
    .enumerate()
    {
        let win = [7usize, 11, 15, 21][case % 4];
        let c = [40 + (rnd() * 80.0) as i64, 30 + (rnd() * 60.0) as i64];
        t.build(&rv, c, win, photo, &mut g);
        assert!(t.is_valid(), "case {case}");
        g.compute(&t.pix, win);
        let n = win * win;
        let half = (win / 2) as f64;
        // Error: a gain and offset of the template plus noise, 1/8 grey.
        let (gain, off) = (rnd() * 0.6 - 0.3, rnd() * 200.0 - 100.0);
        let mut sd = std::vec![[0.0f64; 6]; n];
        let (mut tv, mut ev) = (std::vec![0.0f64; n], std::vec![0.0f64; n]);
        let mut b = [0i64; 6];
        let (mut se, mut ste, mut see) = (0i64, 0i64, 0i64);
        for k in 0..n {
            let (x, y) = ((k % win) as f64 - half, (k / win) as f64 - half);
            let (gx, gy, t8) = (g.gx[k] as f64, g.gy[k] as f64, g.t8[k] as f64);
            sd[k] = [gx * x, gx * y, gy * x, gy * y, gx, gy];
            let e = libm::round(gain * t8 + off + rnd() * 40.0 - 20.0);
            tv[k] = t8;
            ev[k] = e;
            for i in 0..6 {
                b[i] += (sd[k][i] * e) as i64;
            }
            se += e as i64;
            ste += (t8 * e) as i64;
            see += (e * e) as i64;
        }
        let ps = PhotoSums::of(&g, win).unwrap();
        let ps_opt = (photo != Photometric::None).then_some(&ps);
        let (dp, res) = photometric_step(&t, ps_opt, &b, (se, ste, see), n);
        // Explicit: orthonormal basis of the appearance span, projections removed.
        let mut basis: Vec<Vec<f64>> = Vec::new();
        if photo != Photometric::None {
            basis.push(std::vec![1.0 / libm::sqrt(n as f64); n]);
        }
        if photo == Photometric::GainOffset {
            let m = tv.iter().sum::<f64>() / n as f64;
            let c: Vec<f64> = tv.iter().map(|v| v - m).collect();
            let nrm = libm::sqrt(c.iter().map(|v| v * v).sum::<f64>());
            basis.push(c.iter().map(|v| v / nrm).collect());
        }
        let project = |v: &[f64]| -> Vec<f64> {
            let mut out = v.to_vec();
            for a in &basis {
                let d: f64 = a.iter().zip(v).map(|(p, q)| p * q).sum();
                for (o, p) in out.iter_mut().zip(a) {
                    *o -= d * p;
                }
            }
            out
        };
        let sdp: Vec<Vec<f64>> = (0..6)
            .map(|i| project(&sd.iter().map(|r| r[i]).collect::<Vec<_>>()))
            .collect();
        let ep = project(&ev);
        let mut hm = [[0.0f64; 6]; 6];
        let mut bp = [0.0f64; 6];
        for i in 0..6 {
            for j in 0..6 {
                hm[i][j] = sdp[i].iter().zip(&sdp[j]).map(|(p, q)| p * q).sum();
            }
            bp[i] = sdp[i].iter().zip(&ev).map(|(p, q)| p * q).sum();
        }
        let x = solve6(hm, bp);
        for i in 0..6 {
            let want = 4.0 * x[i];
            assert!(
                libm::fabs(dp[i] - want) <= 1e-7 * (1.0 + libm::fabs(want)),
                "case {case} {photo:?}: dp[{i}] {} vs {want}",
                dp[i]
            );
        }
        let want_res = libm::sqrt(ep.iter().map(|v| v * v).sum::<f64>() / n as f64) / 8.0;
        assert!(
            libm::fabs(res - want_res) < 1e-9 * (1.0 + want_res),
            "case {case} {photo:?}: residual {res} vs {want_res}"
        );
    }
}

/// A brightness change between the reference and the target: the uncompensated fit sees it as
/// a large residual; the compensated models absorb what they model and recover the position.
#[test]
fn compensation_absorbs_gain_and_offset() {
    let c = [80.3, 60.7];
    let reference = render(W, H, 0.0, 0.0, texture);
    let a = rot(0.08, 1.03);
    let sh = [1.4, -0.9];
    let truth = [c[0] + sh[0], c[1] + sh[1]];
    let base = warped(a, c, sh);
    let lit = |gain: f64, off: f64| -> Vec<u8> {
        base.iter()
            .map(|&v| libm::round(gain * v as f64 + off).clamp(0.0, 255.0) as u8)
            .collect()
    };
    let fit = |photo: Photometric, img: &[u8]| {
        let v = ImageView::new(&reference, W, H, W).unwrap();
        let cc = [libm::round(c[0]) as i64, libm::round(c[1]) as i64];
        let delta = [c[0] - cc[0] as f64, c[1] - cc[1] as f64];
        let mut t = Box::new(Template::EMPTY);
        let mut g2 = Box::new(Gradients::new());
        t.build(&v, cc, 15, photo, &mut g2);
        let iv = ImageView::new(img, W, H, W).unwrap();
        let init = Affine::through(rot(0.0, 1.0), delta, [truth[0] + 0.4, truth[1] - 0.3]);
        let f = refine_affine(&t, &iv, init, 30, 0.01, &mut g2).unwrap();
        let q = f.warp.point(delta);
        (libm::hypot(q[0] - truth[0], q[1] - truth[1]), f.residual)
    };
    let offset_only = lit(1.0, 25.0);
    let gain = lit(0.75, 12.0);
    let (e_none, r_none) = fit(Photometric::None, &offset_only);
    let (e_off, r_off) = fit(Photometric::Offset, &offset_only);
    let (e_go, r_go) = fit(Photometric::GainOffset, &gain);
    let (e_off_gain, r_off_gain) = fit(Photometric::Offset, &gain);
    assert!(r_none > 8.0, "uncompensated residual {r_none}");
    assert!(e_off < 0.03 && r_off < 1.5, "offset: {e_off} px, {r_off}");
    assert!(e_go < 0.03 && r_go < 1.5, "gain+offset: {e_go} px, {r_go}");
    assert!(
        r_off_gain > 3.0 * r_go,
        "offset alone under a gain: {r_off_gain} vs {r_go}"
    );
    // Without a change, every model recovers the position.
    for photo in [
        Photometric::None,
        Photometric::Offset,
        Photometric::GainOffset,
    ] {
        let (e, r) = fit(photo, &base);
        assert!(e < 0.03 && r < 1.5, "{photo:?}: {e} px, {r}");
    }
    let _ = (e_none, e_off_gain);
}

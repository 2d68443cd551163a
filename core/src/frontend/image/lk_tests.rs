//! Tests of the pyramidal LK (`lk.rs` includes this file as its `#[cfg(test)]` module).
extern crate std;
use super::super::equalize::Equalization;
use super::super::pyramid::pyramid_bytes;
use super::super::testutil::{render, texture};
use super::*;

const W: usize = 320;
const H: usize = 240;
type Pyr = Pyramid<{ pyramid_bytes(W, H, 4) }, 4>;

fn pyr(img: &[u8], filter: PyramidFilter) -> std::boxed::Box<Pyr> {
    let mut p = std::boxed::Box::new(Pyr::new());
    let v = ImageView::new(img, W, H, W).unwrap();
    p.build(&v, 4, filter, Equalization::Off).unwrap();
    p
}

/// Largest tracking error over a grid of points for a known sub-pixel shift.
fn max_error(dx: f64, dy: f64, filter: PyramidFilter, seeded: bool) -> (f64, u32) {
    let a = render(W, H, 0.0, 0.0, texture);
    let b = render(W, H, dx, dy, texture);
    let (pa, pb) = (pyr(&a, filter), pyr(&b, filter));
    let cfg = LkConfig::default();
    let mut s = std::boxed::Box::new(LkScratch::new());
    let mut worst = 0.0f64;
    let mut iters = 0;
    for y in (40..=200).step_by(40) {
        for x in (40..=280).step_by(40) {
            let p = [x as f64 + 0.37, y as f64 - 0.21];
            let (seed, levels) = if seeded {
                ([p[0] + dx + 0.8, p[1] + dy - 0.6], 0)
            } else {
                (p, 3)
            };
            let t = track_point(&pa, &pb, p, seed, levels, &cfg, &mut s).unwrap();
            let e = libm::hypot(t.pos[0] - p[0] - dx, t.pos[1] - p[1] - dy);
            worst = worst.max(e);
            iters += t.iterations;
            assert!(t.residual < 2.0, "residual {}", t.residual);
        }
    }
    (worst, iters)
}

/// Max error 0.0145 px, mean 0.005 px over 35 points x 5 shifts x 2 filters when written;
/// the Gaussian pyramid needs 8-10 iterations per point (4 levels), the box 10-14.
#[test]
fn recovers_known_subpixel_shifts() {
    for filter in [PyramidFilter::Gaussian5, PyramidFilter::Box2] {
        for &(dx, dy) in &[
            (0.3, -0.7),
            (2.25, 1.5),
            (-5.6, 3.3),
            (12.4, -9.8),
            (0.0, 0.0),
        ] {
            let (e, _) = max_error(dx, dy, filter, false);
            assert!(
                e < 0.02,
                "{filter:?} shift ({dx}, {dy}): max error {e:.4} px"
            );
        }
    }
}

#[test]
fn seeded_single_level_converges() {
    let (e, iters) = max_error(3.7, -2.2, PyramidFilter::Gaussian5, true);
    assert!(e < 0.02, "max error {e:.4} px");
    // 35 points, one level: a few iterations each.
    assert!(iters < 35 * 10, "{iters} iterations");
}

#[test]
fn border_block_replicates_edges() {
    let img: std::vec::Vec<u8> = (0..50u8).collect(); // 10 x 5, value = 10 y + x
    let v = ImageView::new(&img, 10, 5, 10).unwrap();
    let mut patch = [0u8; MAX_SRC_H * MAX_SRC_W];
    for &(ix, iy, cols, rows) in &[
        (-3i64, -2i64, 6usize, 4usize),
        (7, 3, 6, 4),
        (-4, 1, 18, 2),
        (12, 7, 3, 3),
        (-9, -9, 4, 4),
    ] {
        let mut want = std::vec::Vec::new();
        for r in 0..rows as i64 {
            for c in 0..cols as i64 {
                want.push(v.clamped((ix + c) as isize, (iy + r) as isize));
            }
        }
        let (src, stride, off) = source_block(&v, ix, iy, cols, rows, &mut patch);
        assert_eq!((stride, off), (cols, 0));
        assert_eq!(&src[..cols * rows], &want[..], "{ix} {iy} {cols} {rows}");
    }
}

#[test]
fn weights_sum_to_256() {
    for i in 0..=200 {
        for j in 0..=200 {
            let w = weights(f64::from(i) / 200.5, f64::from(j) / 200.5);
            assert_eq!(w.iter().map(|&v| u32::from(v)).sum::<u32>(), 256, "{i} {j}");
        }
    }
    assert_eq!(weights(0.0, 0.0), [256, 0, 0, 0]);
    assert_eq!(weights(0.5, 0.5), [64, 64, 64, 64]);
}

#[test]
fn flat_template_and_bad_input_fail() {
    let flat = std::vec![30u8; W * H];
    let tex = render(W, H, 0.0, 0.0, texture);
    let (pf, pt) = (
        pyr(&flat, PyramidFilter::Gaussian5),
        pyr(&tex, PyramidFilter::Gaussian5),
    );
    let cfg = LkConfig::default();
    let mut s = std::boxed::Box::new(LkScratch::new());
    assert_eq!(
        track_point(&pf, &pt, [100.0, 100.0], [100.0, 100.0], 3, &cfg, &mut s),
        Err(LkFailure::SmallEigen)
    );
    assert_eq!(
        track_point(&pt, &pt, [f64::NAN, 1.0], [1.0, 1.0], 3, &cfg, &mut s),
        Err(LkFailure::NonFinite)
    );
    assert_eq!(
        track_point(&pt, &pt, [100.0, 100.0], [1e6, 1.0], 0, &cfg, &mut s),
        Err(LkFailure::OutOfImage)
    );
    // Texture vs a flat target: converges nowhere useful; the residual check rejects it.
    let r = track_point(&pt, &pf, [100.0, 100.0], [100.0, 100.0], 0, &cfg, &mut s);
    assert!(r.is_err(), "{r:?}");
    // A point at the image corner uses replicated borders and still tracks a zero shift.
    let t = track_point(&pt, &pt, [1.0, 2.0], [1.0, 2.0], 3, &cfg, &mut s).unwrap();
    assert!(libm::hypot(t.pos[0] - 1.0, t.pos[1] - 2.0) < 0.01, "{t:?}");
    // An empty pyramid.
    let empty = std::boxed::Box::new(Pyr::new());
    assert_eq!(
        track_point(&empty, &pt, [10.0, 10.0], [10.0, 10.0], 3, &cfg, &mut s),
        Err(LkFailure::OutOfImage)
    );
}

/// Solves the 4x4 system `m x = v` by Gaussian elimination with partial pivoting.
#[allow(clippy::needless_range_loop)] // textbook indices
fn solve4(mut m: [[f64; 4]; 4], mut v: [f64; 4]) -> [f64; 4] {
    for c in 0..4 {
        let p = (c..4)
            .max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs()))
            .unwrap();
        m.swap(c, p);
        v.swap(c, p);
        for r in c + 1..4 {
            let f = m[r][c] / m[c][c];
            for k in c..4 {
                m[r][k] -= f * m[c][k];
            }
            v[r] -= f * v[c];
        }
    }
    let mut x = [0.0; 4];
    for c in (0..4).rev() {
        let mut s = v[c];
        for k in c + 1..4 {
            s -= m[c][k] * x[k];
        }
        x[c] = s / m[c][c];
    }
    x
}

/// Scratch holding the template of side `win` at `(x, y)` of `img`.
fn with_template(
    img: &ImageView,
    x: f64,
    y: f64,
    win: usize,
    photo: Photometric,
) -> std::boxed::Box<LkScratch> {
    let mut s = std::boxed::Box::new(LkScratch::new());
    let LkScratch {
        tmpl,
        interp,
        patch,
        ..
    } = &mut *s;
    tmpl.build(img, x, y, win, photo, interp, patch).unwrap();
    s
}

/// The projected step equals the translation part of the joint least-squares fit of
/// `e ~ g d + alpha T + beta` (Frisch-Waugh-Lovell), built here explicitly in `f64` from the
/// template's values, gradients and the window's differences; the compensated residual equals
/// the mean absolute residual of that joint fit's photometric part.
#[test]
#[allow(clippy::needless_range_loop)]
fn projected_step_equals_the_joint_least_squares_fit() {
    let a = render(W, H, 0.0, 0.0, texture);
    let b = render(W, H, 0.0, 0.0, |x, y| {
        1.13 * texture(x - 0.4, y + 0.3) - 9.0
    });
    let (va, vb) = (
        ImageView::new(&a, W, H, W).unwrap(),
        ImageView::new(&b, W, H, W).unwrap(),
    );
    for photo in [Photometric::Offset, Photometric::GainOffset] {
        for &(win, px, py, qx, qy) in &[
            (21usize, 100.3, 80.7, 100.1, 81.2),
            (15, 201.6, 150.2, 202.0, 149.9),
            (9, 60.0, 170.5, 60.5, 170.5),
        ] {
            let mut s = with_template(&va, px, py, win, photo);
            let LkScratch {
                tmpl, diff, patch, ..
            } = &mut *s;
            let half = (win / 2) as f64;
            let (xt, yt) = (qx - half, qy - half);
            let (fx, fy) = (libm::floor(xt), libm::floor(yt));
            let wgt = weights(xt - fx, yt - fy);
            let wp = padded(win);
            let (src, stride, off) =
                source_block(&vb, fx as i64, fy as i64, wp + 1, win + 1, patch);
            let sums = window_sums(src, stride, off, wgt, tmpl, win, true, diff).unwrap();
            let pr = tmpl.proj.unwrap();
            let (r, pe, k_fit) = pr.removed_gradient(sums.se, sums.ste);
            let (bx, by) = (sums.b[0] as f64 - r[0], sums.b[1] as f64 - r[1]);
            let det = tmpl.a11 * tmpl.a22 - tmpl.a12 * tmpl.a12;
            let d = [
                (tmpl.a22 * bx - tmpl.a12 * by) / det,
                (tmpl.a11 * by - tmpl.a12 * bx) / det,
            ];
            // Explicit joint fit over the window's pixels (padding excluded).
            let gain = photo == Photometric::GainOffset;
            let k = if gain { 4 } else { 3 };
            let (mut m, mut v) = ([[0.0f64; 4]; 4], [0.0f64; 4]);
            for row in 0..win {
                for col in 0..win {
                    let i = row * wp + col;
                    let t = f64::from(tmpl.t[i]);
                    let basis = [
                        f64::from(tmpl.gx[i]),
                        f64::from(tmpl.gy[i]),
                        1.0,
                        if gain { t } else { 0.0 },
                    ];
                    let e = f64::from(diff[i]);
                    for p in 0..k {
                        v[p] += basis[p] * e;
                        for q in 0..k {
                            m[p][q] += basis[p] * basis[q];
                        }
                    }
                }
            }
            if !gain {
                m[3][3] = 1.0;
            }
            let x = solve4(m, v);
            for c in 0..2 {
                assert!(
                    (d[c] - x[c]).abs() <= 1e-9 * (1.0 + x[c].abs()),
                    "{photo:?} win {win}: step {d:?} vs joint fit {x:?}"
                );
            }
            // P e: mean(e) + k (T - mean T) is the photometric part of the joint fit at the
            // same geometry, i.e. beta + alpha T once the gradients' share is removed; check
            // the residual against the explicit projection of e onto {1, T}.
            let n = (win * win) as f64;
            let t_mean = pr.sum_t as f64 / n;
            let (mut se, mut ste, mut stt) = (0.0, 0.0, 0.0);
            for row in 0..win {
                for col in 0..win {
                    let i = row * wp + col;
                    let (t, e) = (f64::from(tmpl.t[i]) - t_mean, f64::from(diff[i]));
                    se += e;
                    ste += t * e;
                    stt += t * t;
                }
            }
            assert!(
                (k_fit - ste / stt).abs() < 1e-12,
                "{k_fit} vs {}",
                ste / stt
            );
            let k_want = if gain { ste / stt } else { 0.0 };
            assert!((pe[0] - se / n).abs() < 1e-9, "{pe:?}");
            assert!((pe[1] - k_want).abs() < 1e-12, "{pe:?} vs {k_want}");
            let mut res = 0.0;
            for row in 0..win {
                for col in 0..win {
                    let i = row * wp + col;
                    let t = f64::from(tmpl.t[i]) - t_mean;
                    res += (f64::from(diff[i]) - se / n - k_want * t).abs();
                }
            }
            let res = res / (n * 8.0);
            let got = window_residual(diff, tmpl, win, pe);
            assert!((f64::from(got) - res).abs() < 1e-4, "{got} vs {res}");
        }
    }
}

/// Largest tracking error over the grid for a shift with a brightness change
/// `J = gain T + offset`.
fn max_error_photometric(photo: Photometric, gain: f64, offset: f64) -> f64 {
    let (dx, dy) = (2.25, -1.5);
    let a = render(W, H, 0.0, 0.0, texture);
    let b = render(W, H, dx, dy, |x, y| gain * texture(x, y) + offset);
    let (pa, pb) = (
        pyr(&a, PyramidFilter::Gaussian5),
        pyr(&b, PyramidFilter::Gaussian5),
    );
    let cfg = LkConfig {
        photometric: photo,
        ..LkConfig::default()
    };
    let mut s = std::boxed::Box::new(LkScratch::new());
    let mut worst = 0.0f64;
    for y in (40..=200).step_by(40) {
        for x in (40..=280).step_by(40) {
            let p = [x as f64 + 0.37, y as f64 - 0.21];
            let t = track_point(&pa, &pb, p, p, 3, &cfg, &mut s).unwrap();
            worst = worst.max(libm::hypot(t.pos[0] - p[0] - dx, t.pos[1] - p[1] - dy));
        }
    }
    worst
}

/// A 12% gain and a 20-grey offset between the frames: the compensated fit stays as accurate
/// as without the change; the uncompensated one is pulled off by the brightness change.
#[test]
fn compensation_recovers_shifts_under_gain_and_offset() {
    let plain = max_error_photometric(Photometric::GainOffset, 1.0, 0.0);
    let go = max_error_photometric(Photometric::GainOffset, 1.12, -20.0);
    let none = max_error_photometric(Photometric::None, 1.12, -20.0);
    let offset_only = max_error_photometric(Photometric::Offset, 1.0, 15.0);
    let offset_none = max_error_photometric(Photometric::None, 1.0, 15.0);
    assert!(plain < 0.02, "{plain}");
    assert!(go < 0.03, "gain + offset, compensated: {go}");
    assert!(offset_only < 0.03, "offset, compensated: {offset_only}");
    assert!(none > 3.0 * go.max(0.01), "uncompensated {none} vs {go}");
    assert!(
        offset_none > 3.0 * offset_only.max(0.01),
        "{offset_none} vs {offset_only}"
    );
}

/// Tracks a grid of points of the textured frame into uniform noise of `amplitude` grey levels
/// around mid-grey: `(tracked with the window inside the image, tracked at the border,
/// photometric failures)`.
fn onto_noise(photo: Photometric, contrast: f64, amplitude: u32) -> (u32, u32, u32) {
    let a = render(W, H, 0.0, 0.0, |x, y| {
        128.0 + contrast * (texture(x, y) - 128.0)
    });
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let b: std::vec::Vec<u8> = (0..W * H)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (128 - amplitude as i64 / 2 + ((s >> 32) % u64::from(amplitude + 1)) as i64) as u8
        })
        .collect();
    let (pa, pb) = (
        pyr(&a, PyramidFilter::Gaussian5),
        pyr(&b, PyramidFilter::Gaussian5),
    );
    let mut scratch = std::boxed::Box::new(LkScratch::new());
    let cfg = LkConfig {
        photometric: photo,
        ..LkConfig::default()
    };
    let (mut inside, mut border, mut residual) = (0, 0, 0);
    let half = (cfg.window / 2) as f64;
    for y in (20..=220).step_by(10) {
        for x in (20..=300).step_by(10) {
            let p = [x as f64 + 0.37, y as f64 - 0.21];
            match track_point(&pa, &pb, p, p, 3, &cfg, &mut scratch) {
                Ok(t) => {
                    let [u, v] = t.pos;
                    if u >= half
                        && v >= half
                        && u <= (W - 1) as f64 - half
                        && v <= (H - 1) as f64 - half
                    {
                        inside += 1;
                    } else {
                        border += 1;
                    }
                }
                Err(LkFailure::Residual) => residual += 1,
                Err(_) => {}
            }
        }
    }
    (inside, border, residual)
}

/// A textured frame followed by noise (a corrupted image): with the brightness removed, the
/// mean residual of noise is below `max_residual`, and against a weak template the fitted gain
/// is too noisy to fail the contrast range, so without the correlation test points are
/// "tracked" onto it (17 of 588 with a quarter of the texture's contrast when written; 1 with
/// a threshold of 0.3). No point whose window stays inside the image may be, and the failures
/// are photometric ([`LkFailure::Residual`]).
#[test]
fn noise_target_is_never_a_match_with_photometric_models() {
    for photo in [Photometric::Offset, Photometric::GainOffset] {
        for (contrast, amplitude) in [
            (1.0, 255),
            (0.25, 255),
            (0.15, 255),
            (0.15, 128),
            (0.1, 255),
        ] {
            let (inside, _border, residual) = onto_noise(photo, contrast, amplitude);
            assert_eq!(
                inside, 0,
                "{photo:?}, contrast {contrast}, amplitude {amplitude}"
            );
            assert!(residual > 300, "{photo:?}: {residual} photometric failures");
        }
    }
}

/// The correlation from the integer sums equals the one computed in `f64`, and is scale- and
/// offset-invariant: `J = 1.5 T` correlates 1, `J = 2040 - T` (x 8 grey) correlates -1.
#[test]
fn correlation_matches_the_float_formula() {
    let a = render(W, H, 0.0, 0.0, texture);
    let va = ImageView::new(&a, W, H, W).unwrap();
    let win = 21;
    let wp = padded(win);
    let mut s = with_template(&va, 100.3, 80.7, win, Photometric::Offset);
    let LkScratch { tmpl, diff, .. } = &mut *s;
    let pr = tmpl.proj.unwrap();
    for (case, f) in [
        (1.0, (|t: i16| 2 * t - t / 2) as fn(i16) -> i16),
        (-1.0, |t: i16| 2040 - t),
        (f64::NAN, |t: i16| ((t as i32 * 7919) % 2041) as i16),
    ] {
        let (mut jt, mut jj, mut tt) = (0.0f64, 0.0f64, 0.0f64);
        let (mut mt, mut mj) = (0.0f64, 0.0f64);
        for r in 0..win {
            for c in 0..win {
                let t = tmpl.t[r * wp + c];
                let j = f(t);
                diff[r * wp + c] = j - t;
                mt += f64::from(t);
                mj += f64::from(j);
            }
        }
        let n = (win * win) as f64;
        (mt, mj) = (mt / n, mj / n);
        for r in 0..win {
            for c in 0..win {
                let t = f64::from(tmpl.t[r * wp + c]);
                let j = t + f64::from(diff[r * wp + c]);
                jt += (j - mj) * (t - mt);
                jj += (j - mj) * (j - mj);
                tt += (t - mt) * (t - mt);
            }
        }
        let want = jt / (jj * tt).sqrt();
        let got = tmpl.correlation(diff, win, &pr);
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        if !case.is_nan() {
            assert!((got - case).abs() < 1e-3, "{got} vs {case}");
        }
    }
}

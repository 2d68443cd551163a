//! Raw pixels to the undistorted normalized plane, as VINS-Mono's feature tracker publishes its
//! points (`x = X/Z`, `y = Y/Z`, camera frame).
//!
//! Distortion maps a normalized point `m = (x, y)` to `m_d`:
//! - radial-tangential: `m_d = m (1 + k1 r^2 + k2 r^4) + [2 p1 x y + p2 (r^2 + 2x^2),
//!   p1 (r^2 + 2y^2) + 2 p2 x y]` with `r^2 = x^2 + y^2`;
//! - equidistant: `theta = atan(r)`, `theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
//!   k4 theta^8)`, `m_d = m theta_d / r`;
//!
//! and the pixel is `u = fx x_d + cx`, `v = fy y_d + cy`. Undistortion inverts it: for radtan with
//! the fixed-point iteration `m <- m_d - delta(m)` divided by the radial factor (OpenCV's
//! `undistortPoints`), for equidistant by Newton on `theta_d(theta)`.

use povins_core::camera::{Distortion, PinholeCamera};

/// Projects a normalized point to raw pixels (used to verify [`undistort_normalized`]).
pub fn distort_to_pixel(cam: &PinholeCamera, x: f64, y: f64) -> (f64, f64) {
    let (xd, yd) = match cam.distortion {
        Distortion::None => (x, y),
        Distortion::RadTan { k1, k2, p1, p2 } => {
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
            (
                x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            )
        }
        Distortion::Equidistant { k } => {
            let r = (x * x + y * y).sqrt();
            if r < 1e-12 {
                (x, y)
            } else {
                let th = r.atan();
                let t2 = th * th;
                let thd = th * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
                (x * thd / r, y * thd / r)
            }
        }
    };
    (cam.fx * xd + cam.cx, cam.fy * yd + cam.cy)
}

/// Raw pixel to the undistorted normalized plane.
pub fn undistort_normalized(cam: &PinholeCamera, u: f64, v: f64) -> (f64, f64) {
    let xd = (u - cam.cx) / cam.fx;
    let yd = (v - cam.cy) / cam.fy;
    match cam.distortion {
        Distortion::None => (xd, yd),
        Distortion::RadTan { k1, k2, p1, p2 } => {
            let (mut x, mut y) = (xd, yd);
            for _ in 0..30 {
                let r2 = x * x + y * y;
                let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
                let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
                let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
                if !(radial.is_finite() && radial > 1e-6) {
                    break;
                }
                x = (xd - dx) / radial;
                y = (yd - dy) / radial;
            }
            (x, y)
        }
        Distortion::Equidistant { k } => {
            let thd = (xd * xd + yd * yd).sqrt();
            if thd < 1e-12 {
                return (xd, yd);
            }
            let mut th = thd;
            for _ in 0..20 {
                let t2 = th * th;
                let f = th * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - thd;
                let df = 1.0
                    + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
                if !(df.is_finite() && df.abs() > 1e-12) {
                    break;
                }
                th -= f / df;
            }
            let s = th.tan() / thd;
            (xd * s, yd * s)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(distortion: Distortion) -> PinholeCamera {
        PinholeCamera {
            width: 752,
            height: 480,
            fx: 458.654,
            fy: 457.296,
            cx: 367.215,
            cy: 248.375,
            distortion,
        }
    }

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        let cams = [
            cam(Distortion::None),
            // EuRoC cam0.
            cam(Distortion::RadTan {
                k1: -0.28340811,
                k2: 0.07395907,
                p1: 0.00019359,
                p2: 1.76187114e-05,
            }),
            cam(Distortion::Equidistant {
                k: [-0.01, 0.02, -0.005, 0.001],
            }),
        ];
        for c in cams {
            for u in (0..=752).step_by(47) {
                for v in (0..=480).step_by(40) {
                    let (x, y) = undistort_normalized(&c, u as f64, v as f64);
                    let (u2, v2) = distort_to_pixel(&c, x, y);
                    assert!(
                        (u2 - u as f64).abs() < 1e-6 && (v2 - v as f64).abs() < 1e-6,
                        "{c:?} ({u},{v}) -> ({u2},{v2})"
                    );
                }
            }
        }
        // The principal point is the optical axis for every model.
        let c = cam(Distortion::RadTan {
            k1: -0.28,
            k2: 0.07,
            p1: 0.0,
            p2: 0.0,
        });
        assert_eq!(undistort_normalized(&c, c.cx, c.cy), (0.0, 0.0));
        // Barrel distortion pulls the corner in, so undistortion pushes it out.
        let (x, _) = undistort_normalized(&c, 0.0, c.cy);
        assert!(x < -c.cx / c.fx - 0.05, "{x}");
    }
}

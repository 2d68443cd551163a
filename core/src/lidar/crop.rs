//! The ingestion crop: the points of a sweep that cannot reach the camera's image are dropped
//! when the sweep is pushed, before they take room in the queue and the buffer. A LiDAR that
//! sees all around (an Ouster OS1-128: 131,072 points a sweep over 360 degrees) would otherwise
//! fill both with points behind the camera, and push out the ones the association needs.
//!
//! A point `p_l` is kept when its bearing in the camera frame at the sweep's pose,
//! `p_c = R_cl p_l + p_cl` (`R_cl = R_bc^T R_bl`, `p_cl = R_bc^T (p_bl - p_bc)`, the configured
//! extrinsics), lies within the camera's field of view widened by `m` =
//! [`LidarConfig::view_margin_rad`](super::LidarConfig::view_margin_rad) on every side, axis by
//! axis: `atan2(|x_c|, z_c) <= a_x + m` and `atan2(|y_c|, z_c) <= a_y + m`, where `a_x`, `a_y`
//! are the largest angles of the image border's bearings (the lens model inverted at
//! [`BORDER_SAMPLES`] points on each side). The margin covers the camera's rotation between a
//! point's time and the keyframes that use it (up to the association's span earlier), and the
//! online extrinsic's change. With `a + m` at or beyond 180 degrees the axis keeps everything.
//!
//! No trigonometry per point: for `θ = atan2(|x|, z)` in `[0, π]`, `θ <= A` is
//! `z >= cos(A) sqrt(x² + z²)`.

use crate::camera::{CameraExtrinsic, PinholeCamera};
use crate::math::{Mat3, Vec3};

use super::buffer::MIN_RANGE_M;
use super::LidarExtrinsic;

/// Points of each image side where the lens model is inverted to find the field of view.
pub const BORDER_SAMPLES: usize = 9;

/// The crop (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewCrop {
    r_cl: Mat3,
    p_cl: Vec3,
    /// `cos(a_x + m)`, `cos(a_y + m)` (`-1` when the angle reaches `π`: keep all).
    cos_x: f64,
    cos_y: f64,
}

impl ViewCrop {
    /// The crop of a camera with `margin_rad` on every side; `None` when no border point of
    /// the image can be inverted (nothing to crop against: keep every point).
    pub fn new(
        cam: &PinholeCamera,
        t_bc: &CameraExtrinsic,
        t_bl: &LidarExtrinsic,
        margin_rad: f64,
    ) -> Option<Self> {
        let (w, h) = (f64::from(cam.width) - 1.0, f64::from(cam.height) - 1.0);
        let (mut tx, mut ty, mut any) = (0.0f64, 0.0f64, false);
        let n = BORDER_SAMPLES.max(2);
        for k in 0..n {
            let f = k as f64 / (n - 1) as f64;
            for (u, v) in [(f * w, 0.0), (f * w, h), (0.0, f * h), (w, f * h)] {
                if let Ok(b) = cam.undistort(u, v) {
                    if b.x.is_finite() && b.y.is_finite() {
                        tx = tx.max(libm::fabs(b.x));
                        ty = ty.max(libm::fabs(b.y));
                        any = true;
                    }
                }
            }
        }
        if !any {
            return None;
        }
        let limit = |t: f64| {
            let a = libm::atan(t) + margin_rad;
            if a >= core::f64::consts::PI {
                -1.0
            } else {
                libm::cos(a)
            }
        };
        let r_bc_t = t_bc.q_bc.to_rotation_matrix().matrix().transpose();
        let r_bl = *t_bl.q_bl.to_rotation_matrix().matrix();
        Some(ViewCrop {
            r_cl: r_bc_t * r_bl,
            p_cl: r_bc_t * (t_bl.p_bl - t_bc.p_bc),
            cos_x: limit(tx),
            cos_y: limit(ty),
        })
    }

    /// Whether the point `p_l` (LiDAR frame) can reach the image (see the module docs).
    /// Invalid points (non-finite, or nearer than [`MIN_RANGE_M`]: "no return") are kept, for
    /// the buffer to reject and count them as such.
    pub fn keeps(&self, p_l: [f32; 3]) -> bool {
        let p_l = Vec3::new(f64::from(p_l[0]), f64::from(p_l[1]), f64::from(p_l[2]));
        let r2 = p_l.norm_squared();
        if r2.is_nan() || r2 < MIN_RANGE_M * MIN_RANGE_M {
            return true;
        }
        // Row by row (the same operations in the same order as `r_cl * p_l`, whose generic
        // product was 40% of this function's time on an OS1-128: BENCHMARKS "thinning").
        let (r, (x, y, z)) = (&self.r_cl, (p_l.x, p_l.y, p_l.z));
        let p = Vec3::new(
            r.m11 * x + r.m12 * y + r.m13 * z,
            r.m21 * x + r.m22 * y + r.m23 * z,
            r.m31 * x + r.m32 * y + r.m33 * z,
        ) + self.p_cl;
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return true;
        }
        let within = |a: f64, cos_lim: f64| p.z >= cos_lim * libm::sqrt(a * a + p.z * p.z);
        within(p.x, self.cos_x) && within(p.y, self.cos_y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;
    use crate::math::Quat;

    fn camera() -> PinholeCamera {
        // 90 x ~74 deg: fx = 320 over 640 px.
        PinholeCamera {
            fx: 320.0,
            fy: 320.0,
            cx: 320.0,
            cy: 240.0,
            width: 641,
            height: 481,
            distortion: Distortion::None,
            readout_s: 0.0,
        }
    }

    fn identity_cam() -> CameraExtrinsic {
        CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: Quat::identity(),
        }
    }

    /// A point at azimuth `ax` (about y, from +z towards +x) and elevation `ay`, in the camera.
    fn at(ax: f64, ay: f64) -> [f32; 3] {
        let (x, z) = (libm::sin(ax), libm::cos(ax));
        let y = libm::tan(ay) * libm::sqrt(x * x + z * z);
        [(5.0 * x) as f32, (5.0 * y) as f32, (5.0 * z) as f32]
    }

    #[test]
    fn keeps_the_field_of_view_and_its_margin_and_drops_the_rest() {
        let c = ViewCrop::new(&camera(), &identity_cam(), &LidarExtrinsic::IDENTITY, 0.3).unwrap();
        let half_x = libm::atan(320.0 / 320.0);
        let half_y = libm::atan(240.0 / 320.0);
        for (ax, ay, keep) in [
            (0.0, 0.0, true),
            (half_x + 0.29, 0.0, true),
            (-(half_x + 0.29), 0.0, true),
            (half_x + 0.31, 0.0, false),
            (0.0, half_y + 0.29, true),
            (0.0, -(half_y + 0.31), false),
            (core::f64::consts::PI, 0.0, false),
        ] {
            assert_eq!(c.keeps(at(ax, ay)), keep, "ax {ax} ay {ay}");
        }
        assert!(c.keeps([f32::NAN, 0.0, 1.0]));
        assert!(c.keeps([0.0, 0.0, 0.0]) && c.keeps([0.0, 0.0, -0.05]));
        // A margin that reaches behind the camera keeps that axis whole.
        let all =
            ViewCrop::new(&camera(), &identity_cam(), &LidarExtrinsic::IDENTITY, 3.0).unwrap();
        assert!(all.keeps(at(3.0, 0.0)));
    }

    #[test]
    fn the_extrinsics_turn_the_lidar_into_the_camera() {
        // LiDAR x forward, z up; camera z forward, x right, y down (R_bc maps camera -> body =
        // LiDAR here).
        let q_bc = Quat::from_matrix(&Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0));
        let t_bc = CameraExtrinsic {
            p_bc: Vec3::new(0.1, 0.0, 0.0),
            q_bc,
        };
        let c = ViewCrop::new(&camera(), &t_bc, &LidarExtrinsic::IDENTITY, 0.2).unwrap();
        assert!(c.keeps([10.0, 0.0, 0.0]));
        assert!(c.keeps([10.0, -5.0, 2.0]));
        assert!(!c.keeps([-10.0, 0.0, 0.0]));
        assert!(!c.keeps([0.0, 10.0, 0.0]));
        assert!(!c.keeps([0.5, 0.0, 10.0]));
    }
}

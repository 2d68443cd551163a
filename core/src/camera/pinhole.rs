//! Projection, lens distortion and undistortion of a [`PinholeCamera`].
//!
//! `pixel = (fx x_d + cx, fy y_d + cy)` with `x_d = distortion(x_n)`, so
//! `d pixel / d x_n = diag(fx, fy) * d x_d / d x_n`.

use super::{Mat2, PinholeCamera, Vec2};
use crate::math::Vec3;
use crate::Error;

/// Points closer than this to the camera plane (m, along z) are not projected.
const MIN_Z: f64 = 1e-9;

impl PinholeCamera {
    /// EuRoC MAV cam0 (MT9M034, `mav0/cam0/sensor.yaml`): 752x480, radial-tangential.
    pub const EUROC_CAM0: PinholeCamera = PinholeCamera {
        readout_s: 0.0,
        width: 752,
        height: 480,
        fx: 458.654,
        fy: 457.296,
        cx: 367.215,
        cy: 248.375,
        distortion: super::Distortion::RadTan {
            k1: -0.28340811,
            k2: 0.07395907,
            p1: 0.00019359,
            p2: 1.76187114e-05,
        },
    };

    /// Capture time of the row at pixel `v_px` relative to the frame's stamp (its middle row), s:
    /// `readout_s ((v + 0.5) / height - 0.5)`; 0 for a global shutter (`readout_s = 0`) or a
    /// camera without rows.
    #[inline]
    pub fn row_time_s(&self, v_px: f64) -> f64 {
        if self.readout_s == 0.0 || self.height == 0 {
            return 0.0;
        }
        self.readout_s * ((v_px + 0.5) / self.height as f64 - 0.5)
    }

    /// Focal lengths `(fx, fy)`, px.
    #[inline]
    pub fn focal(&self) -> Vec2 {
        Vec2::new(self.fx, self.fy)
    }

    /// Pixel of the camera-frame point `p_c`, or `None` when it is behind (or on) the camera
    /// plane or anything is non-finite. Does not check the image bounds (see [`Self::in_image`]).
    pub fn project(&self, p_c: &Vec3) -> Option<Vec2> {
        if !(p_c.x.is_finite() && p_c.y.is_finite() && p_c.z.is_finite()) || p_c.z < MIN_Z {
            return None;
        }
        let px = self.distort(&Vec2::new(p_c.x / p_c.z, p_c.y / p_c.z));
        (px.x.is_finite() && px.y.is_finite()).then_some(px)
    }

    /// Pixel of the undistorted normalized point `x_n` (z = 1 plane).
    #[inline]
    pub fn distort(&self, x_n: &Vec2) -> Vec2 {
        self.distort_with_jacobian(x_n).0
    }

    /// Pixel of `x_n` and its Jacobian `d pixel / d x_n` (px per normalized unit).
    pub fn distort_with_jacobian(&self, x_n: &Vec2) -> (Vec2, Mat2) {
        let (x_d, j) = self.distortion.distort_normalized_with_jacobian(x_n);
        let px = Vec2::new(self.fx * x_d.x + self.cx, self.fy * x_d.y + self.cy);
        let mut jp = j;
        jp.row_mut(0).scale_mut(self.fx);
        jp.row_mut(1).scale_mut(self.fy);
        (px, jp)
    }

    /// Undistorted normalized ray `(x, y, 1)` of the raw pixel `(u_px, v_px)`.
    ///
    /// Errors: [`Error::NonFinite`] for non-finite input, [`Error::InvalidConfig`] for a zero or
    /// non-finite focal length, [`Error::Degenerate`] when the lens model cannot be inverted there
    /// (see [`super::Distortion::undistort_normalized`]).
    pub fn undistort(&self, u_px: f64, v_px: f64) -> Result<Vec3, Error> {
        if !(u_px.is_finite() && v_px.is_finite()) {
            return Err(Error::NonFinite);
        }
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx != 0.0 && self.fy != 0.0) {
            return Err(Error::InvalidConfig);
        }
        let x_d = Vec2::new((u_px - self.cx) / self.fx, (v_px - self.cy) / self.fy);
        let x_n = self.distortion.undistort_normalized(&x_d)?;
        Ok(Vec3::new(x_n.x, x_n.y, 1.0))
    }

    /// Whether `(u, v)` lies within the span of pixel centres, `[0, width-1] x [0, height-1]`.
    /// Non-finite coordinates are outside.
    pub fn in_image(&self, u_px: f64, v_px: f64) -> bool {
        let w = self.width as f64 - 1.0;
        let h = self.height as f64 - 1.0;
        (0.0..=w).contains(&u_px) && (0.0..=h).contains(&v_px)
    }
}

//! Residual factors: pose-only visual reprojection, inverse-depth reprojection (BA baseline and
//! building block of the MSC LiDAR-depth measurement), LiDAR depth, Huber kernel, time-delay
//! random walk. (The IMU preintegration factor lives in `inertial::preintegration`.)
//!
//! Shared conventions of the visual factors:
//! - A keyframe enters as [`KeyframePose`]: the body pose in the world and its camera time delay.
//! - Pose Jacobians are w.r.t. the 6-dim error `[dp(3), dtheta(3)]` with `p_wb <- p_wb + dp`,
//!   `R_wb <- R_wb Exp(dtheta)`; extrinsic Jacobians w.r.t. `[dp_bc, dtheta_bc]` with
//!   `p_bc <- p_bc + dp_bc`, `R_bc <- R_bc Exp(dtheta_bc)`.
//! - Observations are undistorted normalized points with a feature velocity for the time-delay
//!   correction ([`TimedObs`]); residuals live on the normalized plane, whitened by `f / sigma_p`.
//! - Keyframe identifiers (`kf_*`) are only compared for equality (to detect shared poses).

pub mod inverse_depth_visual;
pub mod lidar_depth;
pub mod pose_only_visual;
pub mod robust;
pub mod td;

use crate::camera::{CameraExtrinsic, Vec2};
use crate::math::{skew, Mat3, Quat, Vec3};
use crate::Error;
use nalgebra::SMatrix;

/// Body pose of a keyframe in the world and the camera–IMU time delay estimated for it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframePose {
    /// Body origin in `w`, m.
    pub p_wb: Vec3,
    /// Rotation body -> world.
    pub q_wb: Quat,
    /// Current camera time delay `td` of this keyframe, s (LE-VINS: `t_imu = t_cam + td`).
    pub td: f64,
}

/// An undistorted feature observation with the data for the time-delay correction.
///
/// The corrected observation at delay `td` is `x' = x_n - (td - td0) * vel` (LE-VINS
/// convention, math notes sec. 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedObs {
    /// Undistorted point on the normalized plane of its camera (z = 1 implied).
    pub x_n: Vec2,
    /// Feature velocity on the normalized plane, 1/s.
    pub vel: Vec2,
    /// Time delay at which the feature was extracted, s.
    pub td0: f64,
}

impl TimedObs {
    /// Observation without velocity (time-delay correction disabled).
    pub fn still(x_n: Vec2) -> Self {
        TimedObs {
            x_n,
            vel: Vec2::zeros(),
            td0: 0.0,
        }
    }

    /// Corrected observation at delay `td`, as a 3-vector with z = 1.
    #[inline]
    pub fn corrected(&self, td: f64) -> Vec3 {
        let x = self.x_n - self.vel * (td - self.td0);
        Vec3::new(x.x, x.y, 1.0)
    }

    /// `d corrected / d td` as a 3-vector (z = 0).
    #[inline]
    pub fn d_corrected_d_td(&self) -> Vec3 {
        Vec3::new(-self.vel.x, -self.vel.y, 0.0)
    }

    fn is_finite(&self) -> bool {
        self.x_n
            .iter()
            .chain(self.vel.iter())
            .all(|v| v.is_finite())
            && self.td0.is_finite()
    }
}

/// Whitening of a normalized-plane residual: `f / sigma_p` per axis (`sigma_p` px).
///
/// Errors: [`Error::InvalidConfig`] unless the focal lengths and `sigma_px` are positive.
pub fn sqrt_info_from_pixels(focal: &Vec2, sigma_px: f64) -> Result<Vec2, Error> {
    let valid = focal.x > 0.0 && focal.y > 0.0 && sigma_px > 0.0 && (focal.x + focal.y).is_finite();
    if !valid {
        return Err(Error::InvalidConfig);
    }
    Ok(focal / sigma_px)
}

/// A keyframe's camera pose with the rotation matrices the Jacobian chain needs: `R_wb`, and the
/// camera's `R_wc = R_wb R_bc`, `p_wc = p_wb + R_wb p_bc`. Computing it once per keyframe and
/// passing it to the `*_with_frames` evaluations saves the conversions per residual.
#[derive(Debug, Clone, Copy)]
pub struct CamFrame {
    /// Body rotation `R_wb`.
    pub r_wb: Mat3,
    /// Camera rotation `R_wc`.
    pub r_wc: Mat3,
    /// Camera position `p_wc`, m.
    pub p_wc: Vec3,
    /// `R_bc^T` (the extrinsic's rotation, camera <- body), kept for the Jacobian chain.
    pub r_cb: Mat3,
    /// `R_wb [p_bc]x`, kept for the Jacobian chain.
    pub r_wb_pbc_x: Mat3,
}

impl CamFrame {
    /// The camera frame of a keyframe for an extrinsic.
    pub fn new(kf: &KeyframePose, ext: &CameraExtrinsic) -> Self {
        let r_wb = kf.q_wb.to_rotation_matrix().into_inner();
        let r_bc = ext.q_bc.to_rotation_matrix().into_inner();
        CamFrame {
            r_wb,
            r_wc: r_wb * r_bc,
            p_wc: kf.p_wb + r_wb * ext.p_bc,
            r_cb: r_bc.transpose(),
            r_wb_pbc_x: r_wb * skew(&ext.p_bc),
        }
    }

    /// `(R_ks, t_ks)` of camera `s` into this camera `k`.
    pub fn relative_from(&self, s: &CamFrame) -> (Mat3, Vec3) {
        let r_kw = self.r_wc.transpose();
        (r_kw * s.r_wc, r_kw * (s.p_wc - self.p_wc))
    }
}

/// Pushes derivatives w.r.t. a camera pose (`d_p`: world position `p_wc`, `d_th`: right
/// rotation of `R_wc`) to that keyframe's body pose and to the extrinsic.
///
/// `R_wc = R_wb R_bc`, `p_wc = p_wb + R_wb p_bc`, hence
/// body: `dp_wc = dp - R_wb [p_bc]x dtheta`, `dth_c = R_bc^T dtheta`;
/// extrinsic: `dp_wc = R_wb dp_bc`, `dth_c = dtheta_bc`.
pub(crate) fn cam_to_body_ext<const R: usize>(
    d_p: &SMatrix<f64, R, 3>,
    d_th: &SMatrix<f64, R, 3>,
    cam: &CamFrame,
) -> (SMatrix<f64, R, 6>, SMatrix<f64, R, 6>) {
    let mut body = SMatrix::<f64, R, 6>::zeros();
    body.fixed_columns_mut::<3>(0).copy_from(d_p);
    body.fixed_columns_mut::<3>(3)
        .copy_from(&(-(d_p * cam.r_wb_pbc_x) + d_th * cam.r_cb));
    let mut e = SMatrix::<f64, R, 6>::zeros();
    e.fixed_columns_mut::<3>(0).copy_from(&(d_p * cam.r_wb));
    e.fixed_columns_mut::<3>(3).copy_from(d_th);
    (body, e)
}

/// `d pi(P) / dP` for `pi(P) = (P_x/P_z, P_y/P_z)`.
#[inline]
pub(crate) fn d_pi(p: &Vec3) -> SMatrix<f64, 2, 3> {
    let iz = 1.0 / p.z;
    SMatrix::<f64, 2, 3>::new(iz, 0.0, -p.x * iz * iz, 0.0, iz, -p.y * iz * iz)
}

/// Relative tolerance for "in front of the camera": `P_z > MIN_Z_REL * |P|`.
pub(crate) const MIN_Z_REL: f64 = 1e-6;

pub(crate) fn all_finite_pose(kf: &KeyframePose) -> bool {
    kf.p_wb.iter().all(|v| v.is_finite())
        && kf.q_wb.coords.iter().all(|v| v.is_finite())
        && kf.td.is_finite()
}

pub(crate) fn all_finite_ext(ext: &CameraExtrinsic) -> bool {
    ext.p_bc.iter().all(|v| v.is_finite()) && ext.q_bc.coords.iter().all(|v| v.is_finite())
}

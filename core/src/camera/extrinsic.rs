//! Camera–IMU extrinsic and camera poses in the world (paper eq. 20).
//!
//! `P_b = R_bc P_c + p_bc`; the camera pose in `w` of a body pose `(p_wb, R_wb)` is
//! `R_wc = R_wb R_bc`, `p_wc = p_wb + R_wb p_bc`. The relative pose of camera `s` into camera
//! `e` (paper eq. 3) is `R_es = R_wc_e^T R_wc_s`, `t_es = R_wc_e^T (p_wc_s - p_wc_e)`, so that
//! `P_e = R_es P_s + t_es`.

use crate::math::{Mat3, Quat, Vec3};

/// Camera–IMU extrinsic: pose of the camera frame `c` in the body (IMU) frame `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct CameraExtrinsic {
    /// Camera origin in the body frame, m.
    pub p_bc: Vec3,
    /// Rotation camera -> body (serialized as `[x, y, z, w]`: `math::serde_quat_xyzw`).
    #[cfg_attr(feature = "serde", serde(with = "crate::math::serde_quat_xyzw"))]
    pub q_bc: Quat,
}

/// Pose of a camera frame `c` in the world frame `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// Camera origin in `w`, m.
    pub p_wc: Vec3,
    /// Rotation camera -> world.
    pub q_wc: Quat,
}

impl CameraExtrinsic {
    /// Camera pose in `w` for the body pose `(p_wb, q_wb)`.
    pub fn camera_pose(&self, p_wb: &Vec3, q_wb: &Quat) -> CameraPose {
        CameraPose {
            p_wc: p_wb + q_wb * self.p_bc,
            q_wc: q_wb * self.q_bc,
        }
    }
}

impl CameraPose {
    /// Relative pose `(R_es, t_es)` of camera `s` into this camera `e`: `P_e = R_es P_s + t_es`.
    pub fn relative_from(&self, s: &CameraPose) -> (Mat3, Vec3) {
        let r_ew = self.q_wc.to_rotation_matrix().into_inner().transpose();
        let r_es = r_ew * s.q_wc.to_rotation_matrix().into_inner();
        (r_es, r_ew * (s.p_wc - self.p_wc))
    }
}

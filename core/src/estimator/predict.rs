//! Feature prediction for INS-aided tracking (paper V.D: the updated landmark depths "facilitate
//! the outlier culling and the INS-aided feature tracking").
//!
//! A landmark with a depth `d` (z in its anchor camera `s`) sits at
//! `p_w = R_wc_s (d x_s) + p_wc_s`, with `x_s` its time-delay-corrected anchor observation
//! (z = 1). Its predicted pixel in the camera at time `t` is the projection (with distortion) of
//! `P_c = R_wc(t)^T (p_w - p_wc(t))`, where the camera pose at `t` comes from the INS pose at
//! `t + td` (`t_imu = t_cam + td`, the newest estimated `td`). A tracker (KLT) seeds its search
//! there, so the window is small and fast motion does not lose tracks. An image usually arrives
//! before the IMU samples that cover it, so up to [`MAX_EXTRAPOLATION_NS`] past the newest INS
//! state the pose is extrapolated with its velocity and the newest bias-corrected gyro rate.
//!
//! Depths, by landmark kind: a LiDAR landmark uses its depth-only optimized inverse depth (paper
//! V.D), so the LiDAR sharpens the prediction of new, low-parallax landmarks; an inverse-depth
//! mode landmark its estimated inverse depth; a pose-only landmark the pose-only depth of its
//! anchors `(s, e)` (paper eq. 19) for the current poses, only when the last solve admitted it
//! (parallax and depth-uncertainty gates). Landmarks without a depth are not predicted.
//!
//! A rolling shutter ([`crate::camera::PinholeCamera::readout_s`]) sees each row at its own time:
//! the prediction projects again with the pose at the time of the row the first projection fell
//! in.

use super::{corrected_obs, Estimator};
use crate::camera::CameraPose;
use crate::estimator::{Status, VisualMode};
use crate::landmarks::{Landmark, TwoView};
use crate::math::{quat_exp, Quat, Vec3};
use crate::Error;

/// Longest extrapolation of the INS pose past its newest state, ns.
pub const MAX_EXTRAPOLATION_NS: i64 = 50_000_000;

/// One predicted feature position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeaturePrediction {
    /// Feature (track) id, as in [`crate::camera::FeatureObs::id`].
    pub id: u64,
    /// Predicted raw (distorted) pixel `(u, v)`, px. May lie outside the image.
    pub uv_px: [f64; 2],
    /// Predicted depth, z in the camera at the prediction time, m.
    pub depth_m: f64,
    /// The depth came from LiDAR (depth-only optimized).
    pub lidar: bool,
}

impl FeaturePrediction {
    /// An all-zero prediction (to initialise a caller's buffer).
    pub const EMPTY: FeaturePrediction = FeaturePrediction {
        id: 0,
        uv_px: [0.0; 2],
        depth_m: 0.0,
        lidar: false,
    };
}

/// The parts of the estimator a prediction reads, borrowed field by field so the estimator's own
/// output buffers can be written beside them ([`predictor!`]).
pub(super) struct Predictor<'a, const N: usize, const L: usize> {
    pub cfg: &'a crate::estimator::EstimatorConfig,
    pub window: &'a super::window::Window<N>,
    pub lms: &'a super::problem::Landmarks<N, L>,
    pub ext: &'a crate::camera::CameraExtrinsic,
    pub ins_window: &'a crate::inertial::InsWindow<{ super::INS_WINDOW }>,
    pub last_imu: Option<crate::inertial::ImuSample>,
    /// The delay the estimator currently uses, s.
    pub td_s: f64,
}

/// A [`Predictor`] over `$e`'s fields (a macro, so that the borrow is per field).
macro_rules! predictor {
    ($e:expr) => {
        $crate::estimator::predict::Predictor {
            cfg: &$e.cfg,
            window: &$e.window,
            lms: &$e.lms,
            ext: &$e.ext,
            ins_window: &$e.ins_window,
            last_imu: $e.last_imu,
            td_s: $e.current_td(),
        }
    };
}
pub(super) use predictor;

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// The camera-IMU delay the estimator currently uses, s (`t_imu = t_cam + td`): the newest
    /// keyframe's estimate, or the configured one before the first keyframe. An image front end
    /// integrates the gyro over `[t_prev + td, t_cur + td]` for its rotation seed.
    pub fn td_s(&self) -> f64 {
        self.current_td()
    }

    /// Predicts where the window's landmarks appear in the image taken at `t_cam_ns` (camera
    /// clock). Writes up to `out.len()` predictions (a buffer of `L` always suffices) and returns
    /// how many it wrote, in landmark order.
    ///
    /// Errors: [`Error::NotInitialized`] before initialization; [`Error::OutOfRange`] when
    /// `t_cam_ns + td` lies before the buffered INS states (they cover the last
    /// [`super::INS_WINDOW`] IMU samples) or more than `MAX_EXTRAPOLATION_NS` (50 ms) after the newest.
    pub fn predict_features(
        &self,
        t_cam_ns: i64,
        out: &mut [FeaturePrediction],
    ) -> Result<usize, Error> {
        if self.status != Status::Running {
            return Err(Error::NotInitialized);
        }
        predictor!(self).predict(self.clock_map.inside(t_cam_ns), out)
    }
}

impl<const N: usize, const L: usize> Predictor<'_, N, L> {
    /// [`Estimator::predict_features`] once running.
    pub(super) fn predict(
        &self,
        t_cam_ns: i64,
        out: &mut [FeaturePrediction],
    ) -> Result<usize, Error> {
        let td_ns = libm::round(self.td_s * 1e9) as i64;
        let t_ns = t_cam_ns.saturating_add(td_ns);
        let (p_wb, q_wb) = self.body_pose_at(t_ns)?;
        let cam_t = self.ext.camera_pose(&p_wb, &q_wb);
        let q_cw = cam_t.q_wc.inverse();
        let cams = self.window_cameras();
        let mut n = 0;
        for lm in self.lms.landmarks() {
            let Some(slot) = out.get_mut(n) else { break };
            let Some((p_w, lidar)) = self.landmark_w(lm, &cams) else {
                continue;
            };
            let p_c = q_cw * (p_w - cam_t.p_wc);
            let Some(uv) = self.cfg.camera.project(&p_c) else {
                continue;
            };
            let (p_c, uv) = match self.rolling_shutter_projection(t_ns, &p_w, uv.y) {
                Some(rs) => rs,
                None => (p_c, uv),
            };
            *slot = FeaturePrediction {
                id: lm.id,
                uv_px: [uv.x, uv.y],
                depth_m: p_c.z,
                lidar,
            };
            n += 1;
        }
        Ok(n)
    }

    /// A rolling shutter's projection of `p_w` (camera frame and pixel): seen first at the
    /// stamp's pose (IMU time `t_ns`) in the row `v_px`, it is projected again with the pose at
    /// that row's time (one fixed-point step: the row moves by a fraction of a pixel per ms of
    /// readout). `None` for a global shutter, or when that pose or projection does not exist.
    fn rolling_shutter_projection(
        &self,
        t_ns: i64,
        p_w: &Vec3,
        v_px: f64,
    ) -> Option<(Vec3, crate::camera::Vec2)> {
        let row_s = self.cfg.camera.row_time_s(v_px);
        if row_s == 0.0 {
            return None;
        }
        let t_row_ns = t_ns.saturating_add(libm::round(row_s * 1e9) as i64);
        let (p_wb, q_wb) = self.body_pose_at(t_row_ns).ok()?;
        let cam = self.ext.camera_pose(&p_wb, &q_wb);
        let p_c = cam.q_wc.inverse() * (p_w - cam.p_wc);
        Some((p_c, self.cfg.camera.project(&p_c)?))
    }

    /// The camera pose of every window keyframe.
    pub(super) fn window_cameras(&self) -> [CameraPose; N] {
        let poses = self.window.poses();
        core::array::from_fn(|k| self.ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb))
    }

    /// Where landmark `lm` sits in the world by its depth, and whether the depth came from
    /// LiDAR (see the module docs), or `None` without a depth.
    pub(super) fn landmark_w(
        &self,
        lm: &Landmark<N>,
        cams: &[CameraPose; N],
    ) -> Option<(Vec3, bool)> {
        let td = |k: usize| self.window.get(k).map_or(0.0, |kf| kf.td_s);
        let s = lm.anchor_s as usize;
        let (Some(x_s), Some(c_s)) = (corrected_obs(lm, s, td(s)), cams.get(s)) else {
            return None;
        };
        let (d, lidar) = self.landmark_depth(lm, &x_s, c_s, cams, &td)?;
        Some((c_s.q_wc * (x_s * d) + c_s.p_wc, lidar))
    }

    /// Body pose at `t_ns`: interpolated in the INS window, or extrapolated a little past it.
    fn body_pose_at(&self, t_ns: i64) -> Result<(Vec3, Quat), Error> {
        let newest = self.ins_window.newest().ok_or(Error::OutOfRange)?;
        let dt_ns = t_ns.saturating_sub(newest.t_ns);
        if dt_ns <= 0 {
            return self.ins_window.pose_at(t_ns);
        }
        if dt_ns > MAX_EXTRAPOLATION_NS {
            return Err(Error::OutOfRange);
        }
        let dt = dt_ns as f64 * 1e-9;
        let w_b = self
            .last_imu
            .map_or(Vec3::zeros(), |s| s.gyro_rps - newest.bg);
        Ok((
            newest.p_wb + newest.v_wb * dt,
            newest.q_wb * quat_exp(&(w_b * dt)),
        ))
    }

    /// The landmark's depth in its anchor camera and whether it came from LiDAR (see the module
    /// docs), or `None`.
    fn landmark_depth(
        &self,
        lm: &Landmark<N>,
        x_s: &Vec3,
        c_s: &CameraPose,
        cams: &[CameraPose; N],
        td: &impl Fn(usize) -> f64,
    ) -> Option<(f64, bool)> {
        let by_inverse = lm.inv_depth > 0.0 && lm.inv_depth.is_finite();
        if lm.lidar.is_some() && self.cfg.lidar.enabled && by_inverse {
            return Some((1.0 / lm.inv_depth, true));
        }
        if !lm.usable {
            return None;
        }
        let d = if self.cfg.mode == VisualMode::InverseDepth {
            by_inverse.then(|| 1.0 / lm.inv_depth)?
        } else {
            let e = lm.anchor_e? as usize;
            let x_e = corrected_obs(lm, e, td(e))?;
            let (r_es, t_es) = cams.get(e)?.relative_from(c_s);
            TwoView::new(x_s, &x_e, &r_es, &t_es).signed_depth()
        };
        let (dmin, dmax) = self.cfg.depth_range_m;
        (d >= dmin && d <= dmax).then_some((d, false))
    }
}

//! The gyro rotation seed of the image front end: the last readings, integrated into the camera
//! rotation between two image times.

use crate::math::{exp_so3, Mat3, Vec3};
use heapless::Deque;

use super::{GYRO_EXTRAPOLATION_NS, MAX_ROTATION_INTERVAL_NS};

/// The last `S` gyro readings, integrated into the camera rotation between two image times
/// (the tracker's rotation seed). Used by [`Vio`]; usable alone for a front end without the
/// estimator.
#[derive(Debug, Clone)]
pub struct GyroIntegrator<const S: usize> {
    buf: Deque<(i64, Vec3), S>,
}

impl<const S: usize> Default for GyroIntegrator<S> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const S: usize> GyroIntegrator<S> {
    /// An empty buffer.
    pub const fn new() -> Self {
        GyroIntegrator { buf: Deque::new() }
    }

    /// Drops every reading.
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// Readings held.
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    /// True when no reading is held.
    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }

    /// Adds the gyro reading `gyro_rps` (body frame) taken at `t_ns`, dropping the oldest when
    /// full. A non-finite reading or one not after the newest is ignored (returns false).
    pub fn push(&mut self, t_ns: i64, gyro_rps: &Vec3) -> bool {
        if !gyro_rps.iter().all(|x| x.is_finite()) || self.buf.back().is_some_and(|b| t_ns <= b.0) {
            return false;
        }
        if self.buf.is_full() {
            let _ = self.buf.pop_front();
        }
        // Not full (made room above): cannot fail.
        self.buf.push_back((t_ns, *gyro_rps)).is_ok()
    }

    /// Body rotation `R_b0_b1` from `t0_ns` to `t1_ns` (IMU clock): the product of
    /// `Exp((w_k - bg) dt)` with each reading held until the next and the newest extrapolated up
    /// to [`GYRO_EXTRAPOLATION_NS`]. `None` when the readings do not cover `[t0, t1]`, the
    /// interval is empty or longer than [`MAX_ROTATION_INTERVAL_NS`], or `bg` is not finite.
    pub fn body_rotation(&self, t0_ns: i64, t1_ns: i64, bg: &Vec3) -> Option<Mat3> {
        let span = t1_ns.checked_sub(t0_ns)?;
        if span <= 0 || span > MAX_ROTATION_INTERVAL_NS || !bg.iter().all(|x| x.is_finite()) {
            return None;
        }
        let (oldest, newest) = (self.buf.front()?.0, self.buf.back()?.0);
        if t0_ns < oldest || t1_ns > newest.saturating_add(GYRO_EXTRAPOLATION_NS) {
            return None;
        }
        let mut r = Mat3::identity();
        let mut it = self.buf.iter().peekable();
        while let Some(&(tk, wk)) = it.next() {
            let t_next = it.peek().map_or(t1_ns, |n| n.0);
            let (a, b) = (tk.max(t0_ns), t_next.min(t1_ns));
            if b > a {
                r *= exp_so3(&((wk - bg) * ((b - a) as f64 * 1e-9)));
            }
            if t_next >= t1_ns {
                break;
            }
        }
        Some(r)
    }

    /// Rotation of the camera at image time `t0_cam_ns` into the camera at `t1_cam_ns`
    /// (`R_c1_c0 = R_bc^T R_b0_b1^T R_bc`), integrating over `[t0 + td, t1 + td]`
    /// (`t_imu = t_cam + td_s`) with the gyro bias `bg` and the camera-to-body rotation `r_bc`.
    /// `None` as [`Self::body_rotation`], or for a non-finite or above 1 s delay.
    pub fn camera_rotation(
        &self,
        t0_cam_ns: i64,
        t1_cam_ns: i64,
        td_s: f64,
        bg: &Vec3,
        r_bc: &Mat3,
    ) -> Option<Mat3> {
        if !td_s.is_finite() || libm::fabs(td_s) > 1.0 {
            return None;
        }
        let td_ns = libm::round(td_s * 1e9) as i64;
        let r_b0b1 = self.body_rotation(
            t0_cam_ns.saturating_add(td_ns),
            t1_cam_ns.saturating_add(td_ns),
            bg,
        )?;
        let r = r_bc.transpose() * r_b0b1.transpose() * r_bc;
        r.iter().all(|x| x.is_finite()).then_some(r)
    }
}

//! One camera frame at its IMU time: track validation and undistortion, the rest detector,
//! and the keyframe decision from the INS-predicted motion (parallax against the newest
//! keyframe, tracked share, interval length); a keyframe goes to [`super::keyframe`].

use super::window::MAX_INTERVAL_SAMPLES;
use super::{now, Estimator, KeyframeReport};
use crate::frontend::{mean_parallax_px, CameraMotion, KeyframeDecision, RestVerdict};
use crate::inertial::{ImuSample, NavState};
use crate::math::{log_so3, Vec3};
use crate::Error;

/// Inside an IMU gap longer than `imu_gap.bridge_max_s`, a keyframe is taken (where the selector
/// asks for one) once fewer than this share of the newest keyframe's features are still tracked:
/// otherwise no track would span the gap. Measured (BENCHMARKS.md, "Long IMU gaps bridged where
/// the motion was smooth"): at 0.1 the car's 2 s gaps cost 1.4-2.5x instead of 1.8-5.3x, and the
/// robot and the flight, whose tracks outlive the gap, take none (at 0.5 the robot took one and
/// lost up to 20x: a keyframe in a gap still hurts where tracks span it).
const LONG_GAP_KEYFRAME_TRACKED: f64 = 0.1;

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
    /// Moves the oldest pending frame into `self.frame` (swapped in place: a frame is too large
    /// to pass through the stack of the processing path). False when none is pending.
    #[inline(never)]
    pub(super) fn next_frame(&mut self) -> bool {
        let Some(front) = self.pending.front_mut() else {
            return false;
        };
        self.frame_dt_ns = front.t_cam_ns.saturating_sub(self.frame.t_cam_ns);
        core::mem::swap(front, &mut self.frame);
        // The previous frame, swapped into the queue, is dropped here.
        let _ = self.pending.pop_front();
        true
    }

    /// The camera's motion at `sample` (camera frame), for the track velocities: the gyro minus
    /// the bias, and the velocity of the camera's origin, both rotated by the current extrinsic;
    /// at rest before the INS starts (or if not finite).
    fn camera_motion(&self, sample: &ImuSample) -> CameraMotion {
        let Some(nav) = self.ins.as_ref().map(|i| i.state()) else {
            return CameraMotion::ZERO;
        };
        let w_b = sample.gyro_rps - nav.bg;
        let q_cb = self.ext.q_bc.inverse();
        let w_c = q_cb * w_b;
        let v_c = q_cb * (nav.q_wb.inverse() * nav.v_wb + w_b.cross(&self.ext.p_bc));
        let dw_c = q_cb * self.angular_accel(sample.t_ns);
        if w_c
            .iter()
            .chain(v_c.iter())
            .chain(dw_c.iter())
            .all(|v| v.is_finite())
        {
            CameraMotion {
                w_c_rps: [w_c.x, w_c.y, w_c.z],
                v_c_mps: [v_c.x, v_c.y, v_c.z],
                dw_c_rps2: [dw_c.x, dw_c.y, dw_c.z],
            }
        } else {
            CameraMotion::ZERO
        }
    }

    /// The body's angular acceleration at `t_ns`, rad/s^2: the least-squares slope of the gyro
    /// readings from [`super::ANGULAR_ACCEL_SPAN_NS`] before `t_ns` to the first after it (kept
    /// only for a rolling shutter; zero with fewer than three). Over 25 ms of 200 Hz readings, a
    /// gyro white noise of `s` rad/s per reading gives a slope noise of about `s / 0.008 s`.
    fn angular_accel(&self, t_ns: i64) -> Vec3 {
        let span = |t: i64| {
            t.saturating_sub(t_ns) <= super::ANGULAR_ACCEL_SPAN_NS / 2
                && t_ns.saturating_sub(t) <= super::ANGULAR_ACCEL_SPAN_NS
        };
        let (mut n, mut st) = (0.0, 0.0);
        for (t, _) in self.gyro_recent.iter().filter(|(t, _)| span(*t)) {
            n += 1.0;
            st += t.saturating_sub(t_ns) as f64 * 1e-9;
        }
        if n < 3.0 {
            return Vec3::zeros();
        }
        let t_mean = st / n;
        let (mut stt, mut stw) = (0.0, Vec3::zeros());
        for (t, w) in self.gyro_recent.iter().filter(|(t, _)| span(*t)) {
            let dt = t.saturating_sub(t_ns) as f64 * 1e-9 - t_mean;
            stt += dt * dt;
            stw += w * dt;
        }
        if stt > 0.0 {
            stw / stt
        } else {
            Vec3::zeros()
        }
    }

    /// Processes `self.frame` (see [`Self::next_frame`]) at `sample`.
    pub(super) fn process_frame(
        &mut self,
        sample: &ImuSample,
    ) -> Result<Option<KeyframeReport>, Error> {
        let t0 = now(self.clock);
        let t_cam_ns = self.frame.t_cam_ns;
        let motion = self.camera_motion(sample);
        let st = match self.tracks.process(
            t_cam_ns,
            &self.frame.obs,
            &self.cfg.camera,
            motion,
            &mut self.frame_obs,
        ) {
            Ok(st) => st,
            Err(Error::TimeNotIncreasing) => {
                self.counters.frames_rejected_time += 1;
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        self.counters.features_received += u64::from(st.received);
        self.counters.features_rejected += u64::from(st.received - st.accepted);
        self.rest.push(t_cam_ns, &self.frame_obs, self.focal_px());
        let Some(ins) = self.ins.as_ref() else {
            return Ok(None);
        };
        let nav = self.pose_after_gap(*ins.state(), sample);

        let mut tracked_share = 1.0;
        let decision = match self.window.last() {
            None => KeyframeDecision::First,
            Some(last) => {
                let dt_s = nav.t_ns.saturating_sub(last.state.t_ns) as f64 * 1e-9;
                let dp = (nav.p_wb - last.state.p_wb).norm();
                let dr = log_so3(&(last.state.q_wb.inverse() * nav.q_wb)).norm();
                let (parallax, tracked) = self.parallax_and_tracked(&nav);
                tracked_share = tracked;
                let nearly_full = self
                    .open()
                    .is_some_and(|o| o.len() + 16 >= MAX_INTERVAL_SAMPLES);
                match self.selector.decide(dt_s, dp, dr, parallax, tracked) {
                    KeyframeDecision::No
                        if nearly_full && dt_s >= self.cfg.keyframe.min_interval_s =>
                    {
                        KeyframeDecision::Timeout
                    }
                    d => d,
                }
            }
        };
        // Inside a bridged IMU gap the state is a guess from interpolated samples: a keyframe
        // there would hang between two intervals that hardly constrain it. Inside a long gap one
        // is taken all the same when the newest keyframe's features are nearly all lost
        // (`LONG_GAP_KEYFRAME_TRACKED`): no track would span the gap, and the line alone would
        // carry the rotation across it.
        let in_gap = self
            .gap
            .is_some_and(|g| nav.t_ns > g.t0_ns && nav.t_ns < g.t1_ns);
        let lost = self.in_long_gap(nav.t_ns) && tracked_share < LONG_GAP_KEYFRAME_TRACKED;
        if !decision.is_keyframe() || (in_gap && !lost) {
            return Ok(None);
        }
        // A late frame (its IMU time already passed, e.g. a negative delay): the keyframe goes
        // at its own time and the samples after it are replayed into the next interval.
        let tail = if sample.t_ns < nav.t_ns {
            self.rewind_to(sample)
        } else {
            None
        };
        let nav = self.ins.as_ref().map_or(nav, |i| *i.state());
        let report = self.add_keyframe(t_cam_ns, nav, sample, decision, t0)?;
        for s in tail.iter().flatten() {
            self.advance(s)?;
        }
        Ok(Some(report))
    }

    /// Mean focal length, px.
    pub(super) fn focal_px(&self) -> f64 {
        0.5 * (self.cfg.camera.fx + self.cfg.camera.fy)
    }

    /// True when the images show the platform at rest since at or before the newest keyframe.
    pub(super) fn at_rest_since_last_keyframe(&self) -> bool {
        match (self.rest.verdict(), self.window.last()) {
            (RestVerdict::Rest { since_ns }, Some(last)) => since_ns <= last.t_cam_ns,
            _ => false,
        }
    }

    /// True inside (strictly) a bridged IMU gap longer than `imu_gap.bridge_max_s` (one bridged
    /// by `imu_gap.long_bridge_max_s`).
    fn in_long_gap(&self, t_ns: i64) -> bool {
        self.gap.is_some_and(|g| {
            t_ns > g.t0_ns
                && t_ns < g.t1_ns
                && g.t1_ns.saturating_sub(g.t0_ns) as f64 * 1e-9 > self.cfg.imu_gap.bridge_max_s
        })
    }

    /// Mean pixel displacement of the current frame's tracks w.r.t. the newest keyframe (with
    /// `keyframe.compensate_rotation`, after rotating the keyframe's rays by the rotation the
    /// INS predicts between them), and the share of the keyframe's features still tracked.
    fn parallax_and_tracked(&self, nav: &NavState) -> (f64, f64) {
        let (Some(pos), Some(last)) = (self.window.len().checked_sub(1), self.window.last()) else {
            return (0.0, 1.0);
        };
        // Rotation taking the keyframe camera's rays into the current camera's.
        let r_ck = self.cfg.keyframe.compensate_rotation.then(|| {
            let ck = self.ext.camera_pose(&last.state.p_wb, &last.state.q_wb);
            let cc = self.ext.camera_pose(&nav.p_wb, &nav.q_wb);
            cc.q_wc.inverse() * ck.q_wc
        });
        let pairs = self.frame_obs.iter().filter_map(|o| {
            let k = self.lms.get(o.id)?.obs.get(pos)?.as_ref()?;
            Some((k.x_n, [o.x_n[0], o.x_n[1]]))
        });
        let (parallax, n) = mean_parallax_px(pairs, r_ck.as_ref(), self.focal_px());
        // The share is only needed by the tracked-share rule (off by default) and inside a long
        // IMU gap: no pass over the landmark store per frame otherwise.
        let seen = if self.cfg.keyframe.min_tracked_ratio > 0.0 || self.in_long_gap(nav.t_ns) {
            self.lms
                .landmarks()
                .iter()
                .filter(|lm| matches!(lm.obs.get(pos), Some(Some(_))))
                .count()
        } else {
            0
        };
        let tracked = if seen == 0 {
            1.0
        } else {
            n as f64 / seen as f64
        };
        (parallax, tracked)
    }
}

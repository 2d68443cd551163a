//! One processed IMU sample (called by [`super::timing`]'s `process_imu`): before
//! initialization (frames feed the track velocities and the rest detector, the static
//! initializer may start the INS), and while running (the pending frames the sample reaches are
//! processed at their IMU time, then INS propagation and preintegration into the open keyframe
//! interval). Also the open interval's accessors, and the rewind of the INS and the open
//! interval to a late frame's time.

use super::window::Preint;
use super::{Estimator, ImuOutput, InitMode, Status, LATE_SAMPLES};
use crate::frontend::{CameraMotion, RestVerdict};
use crate::inertial::ins::Ins;
use crate::inertial::motion_init::Refusal;
use crate::inertial::{ImuSample, InsCovariance, NavState};
use crate::math::{Quat, Vec3};
use crate::Error;
use heapless::Vec as HVec;

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
    /// The open keyframe interval's preintegration, if one is open.
    pub(super) fn open(&self) -> Option<&Preint> {
        self.open_active.then_some(&self.open)
    }

    /// The open interval, mutable.
    pub(super) fn open_mut(&mut self) -> Option<&mut Preint> {
        if self.open_active {
            Some(&mut self.open)
        } else {
            None
        }
    }

    /// Time of the INS state (the newest propagated sample), ns.
    fn ins_time(&self) -> i64 {
        self.ins.as_ref().map_or(i64::MIN, |i| i.state().t_ns)
    }

    pub(super) fn current_td(&self) -> f64 {
        self.window
            .last()
            .map_or(self.reinit.map_or(self.cfg.td_s, |r| r.td_s), |k| k.td_s)
    }

    /// One sample before initialization: frames feed the track velocities, the rest
    /// detector and the in-motion initializer; the static initializer may start the INS, and
    /// (`init.mode` auto while the images do not show a rest, or motion) the in-motion one.
    pub(super) fn imu_waiting_for_init(&mut self, s: &ImuSample) -> Result<(), Error> {
        let td_ns = (self.cfg.td_s * 1e9) as i64;
        while self.next_frame() {
            self.counters.frames_before_init += 1;
            let t_cam_ns = self.frame.t_cam_ns;
            if self
                .tracks
                .process(
                    t_cam_ns,
                    &self.frame.obs,
                    &self.cfg.camera,
                    CameraMotion::ZERO,
                    &mut self.frame_obs,
                )
                .is_ok()
            {
                self.rest.push(t_cam_ns, &self.frame_obs, self.focal_px());
                if self.cfg.init.mode != InitMode::Static {
                    let obs = self.frame_obs.iter().map(|o| (o.id, o.x_n));
                    self.motion_init
                        .push_frame(t_cam_ns.saturating_add(td_ns), obs);
                }
            }
        }
        let rest_since = match self.rest.verdict() {
            RestVerdict::Rest { since_ns } => Some(since_ns.saturating_add(td_ns)),
            _ => None,
        };
        if rest_since.is_some() {
            self.last_rest_ns = Some(s.t_ns);
        }
        let state = match self.cfg.init.mode {
            InitMode::Motion => None,
            _ => match self.static_init.push_with_rest(s, rest_since) {
                Ok(st) => st,
                Err(Error::CapacityExceeded) => return Err(Error::InvalidConfig),
                Err(e) => return Err(e),
            },
        };
        let state = match state {
            Some(st) => {
                self.counters.static_inits += 1;
                Some(st)
            }
            None => {
                // Auto: after a rest the static initializer keeps the start for the span of
                // the init frames (a gentle take-off must still start static).
                let span_ns = (self.cfg.init.motion.max_span_s * 1e9) as i64;
                let rest_recent = self
                    .last_rest_ns
                    .is_some_and(|t| s.t_ns.saturating_sub(t) <= span_ns);
                self.try_motion_init(s, rest_recent)
            }
        };
        if let Some(state) = state {
            let state = self.continued(state);
            let ins = Ins::new(self.ins_config(), state)?;
            self.ins.set(ins);
            if let Some(ins) = self.ins.as_mut() {
                let st = *ins.propagate(s)?;
                self.record_ins(&st);
            }
            self.status = Status::Running;
        }
        Ok(())
    }

    /// A start after a full reset continues from where the consumer last saw the platform
    /// ([`Estimator::reset`]): the new start's leveled attitude turned about the vertical to the
    /// old yaw, its velocity turned with it, and the old position; where the frames that came
    /// during the outage show the rotation and the direction of travel
    /// ([`super::outage_heading`]), the old yaw turned by that rotation and the old position
    /// moved along that path at the old speed. What is published does not jump.
    fn continued(&mut self, mut st: NavState) -> NavState {
        let Some(old) = self.resume.take() else {
            return st;
        };
        // The yaw the platform had turned to by the start, where the images carried it across
        // the outage; else the last published one.
        let seen = self
            .outage
            .heading_change(old.t_ns, st.t_ns, &self.ext.q_bc);
        self.counters.outage_motion_from_images += u64::from(seen.is_some());
        let q_target = seen.map_or(old.q_wb, |m| old.q_wb * m.q_b0b1);
        let r = Quat::from_axis_angle(&Vec3::z_axis(), yaw(&q_target) - yaw(&st.q_wb));
        // The position: where the images carried it, the camera's path at the speed before the
        // outage plus the lever arm's turn; else the last published one.
        let moved = seen.map_or(Vec3::zeros(), |m| {
            let dp_c = old.q_wb * m.path_b0_s * old.v_wb.norm();
            dp_c + old.q_wb * self.ext.p_bc - q_target * self.ext.p_bc
        });
        st.q_wb = r * st.q_wb;
        st.v_wb = r * st.v_wb;
        st.p_wb = if moved.iter().all(|x| x.is_finite()) {
            old.p_wb + moved
        } else {
            old.p_wb
        };
        st
    }

    /// The in-motion initializer at sample `s` (not in static mode, nor in auto mode while
    /// the images show a rest): the state to start from, refusals counted by reason.
    fn try_motion_init(&mut self, s: &ImuSample, at_rest: bool) -> Option<NavState> {
        let mode = self.cfg.init.mode;
        if mode == InitMode::Static {
            return None;
        }
        self.motion_init.push_imu(s);
        if mode == InitMode::Auto && at_rest {
            return None;
        }
        // Known biases (`[init.biases]`): the solve integrates with them, holds them, and the
        // start keeps them.
        let known = self.cfg.init.biases;
        let bg = known.map_or(Vec3::zeros(), |b| Vec3::from(b.gyro_rps));
        let ba = known.map(|b| Vec3::from(b.accel_mps2));
        let c = &mut self.counters;
        match self
            .motion_init
            .try_solve(&self.ext, self.cfg.gravity_mps2, &bg, ba.as_ref())
        {
            Ok(Some((state, _))) => {
                c.motion_inits += 1;
                self.motion_started = true;
                Some(state)
            }
            Ok(None) => None,
            Err(r) => {
                match r {
                    Refusal::TooFewTracks => c.motion_init_refused_tracks += 1,
                    Refusal::LowParallax => c.motion_init_refused_parallax += 1,
                    Refusal::IllConditioned | Refusal::NonFinite => {
                        c.motion_init_refused_conditioning += 1
                    }
                    Refusal::GravityNorm => c.motion_init_refused_gravity += 1,
                    Refusal::Residual => c.motion_init_refused_residual += 1,
                }
                None
            }
        }
    }

    /// One sample while running: pending frames whose IMU time has been reached are processed
    /// at exactly that time (or at this sample when it is already past: the observations' delay
    /// correction accounts for the difference, see `add_keyframe`), then the INS propagates to
    /// the sample. Returns the INS epoch the final propagation started from when it was a plain
    /// propagation of `s` (see [`Self::fast_path_update`]).
    pub(super) fn imu_running(
        &mut self,
        s: &ImuSample,
        out: &mut ImuOutput,
    ) -> Result<Option<u32>, Error> {
        while let Some(t_f) = self
            .pending
            .front()
            .map(|p| p.t_cam_ns.saturating_add((self.current_td() * 1e9) as i64))
            .filter(|t_f| *t_f <= s.t_ns)
        {
            // The keyframe sample: the real one at t_f, or one interpolated at t_f, or (the frame
            // is late, or right after initialization) this sample itself.
            let sample_f = match self.last_imu {
                _ if t_f == s.t_ns => *s,
                Some(prev) if prev.t_ns < t_f && self.ins_time() <= t_f => {
                    interpolate(&prev, s, t_f)
                }
                // Late: the sample at t_f from the open interval (the keyframe is rewound there).
                _ => self.open_sample_at(t_f).unwrap_or(*s),
            };
            if self.ins_time() < sample_f.t_ns {
                self.advance(&sample_f)?;
            }
            if self.next_frame() {
                if let Some(r) = self.process_frame(&sample_f)? {
                    out.keyframe = Some(r);
                }
            }
        }
        if self.ins.as_ref().is_none_or(|i| i.state().t_ns >= s.t_ns) {
            return Ok(None);
        }
        let from = self.ins.epoch;
        self.advance(s)?;
        let plain = self.ins.held && self.ins.epoch == from.wrapping_add(1);
        Ok(plain.then_some(from))
    }

    /// INS propagation and preintegration of one sample (real or interpolated).
    pub(super) fn advance(&mut self, s: &ImuSample) -> Result<(), Error> {
        let Some(ins) = self.ins.as_mut() else {
            return Err(Error::NotInitialized);
        };
        match ins.propagate(s).copied() {
            Ok(st) => {
                let finite = st.p_wb.iter().chain(st.v_wb.iter()).all(|x| x.is_finite())
                    && st.q_wb.coords.iter().all(|x| x.is_finite());
                if !finite || st.v_wb.amax() > self.cfg.max_speed_mps {
                    // Diverged (or fed garbage that passed the range check): start over.
                    self.counters.divergence_resets += 1;
                    self.reset();
                    return Ok(());
                }
                self.record_ins(&st);
            }
            Err(Error::TimeGap) => {
                self.reset();
                return Ok(());
            }
            Err(e) => return Err(e),
        }
        if let Some(open) = self.open_mut() {
            match open.push(s) {
                Ok(()) => {}
                // No keyframe for as long as an interval holds (a camera dropout): the window
                // cannot take the interval, the INS can go on alone; the next frame starts a
                // new window from it (as after a breakdown), but with what the healthy window
                // knew: its newest keyframe's covariance propagated over the dropout.
                Err(Error::CapacityExceeded) => {
                    if let Some(st) = self.ins.as_ref().map(|i| *i.state()) {
                        self.counters.interval_overflows += 1;
                        let cov = self.dropout_covariance(s);
                        self.reinitialize_from(st);
                        if let Some(ins) = self.ins.as_mut() {
                            ins.set_covariance(cov);
                        }
                    }
                }
                // The interval cannot be bridged: start over rather than integrate a hole.
                Err(Error::TimeGap) => self.reset(),
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// The IMU sample at `t_ns` interpolated from the open interval's samples (strictly after its
    /// start), if it holds that time.
    fn open_sample_at(&self, t_ns: i64) -> Option<ImuSample> {
        let v = self.open()?.samples();
        let k = v.iter().position(|x| x.t_ns >= t_ns).filter(|&k| k > 0)?;
        let (a, b) = (v.get(k - 1)?, v.get(k)?);
        Some(if b.t_ns == t_ns {
            *b
        } else {
            interpolate(a, b, t_ns)
        })
    }

    /// The covariance of the INS state at `s` (the sample the full open interval refused),
    /// propagated from the newest keyframe's marginal covariance over the interval's samples
    /// and `s` (the INS's own step, as [`Self::rewind_to`] replays them); `None` when the
    /// window's covariance is unavailable.
    fn dropout_covariance(&mut self, s: &ImuSample) -> Option<InsCovariance> {
        let kf_state = self.window.last()?.state;
        let kf_cov = match self.kf_cov.get() {
            Some(c) => *c,
            None => self.window_covariance()?,
        };
        let mut ins = Ins::new(self.ins_config(), kf_state).ok()?;
        ins.set_covariance(Some(kf_cov));
        for x in self.open()?.samples().iter().chain(core::iter::once(s)) {
            ins.propagate(x).ok()?;
        }
        ins.covariance().copied()
    }

    /// Rewinds the INS and the open interval to `sample` (between the newest keyframe and the
    /// newest sample): the interval is truncated there and the INS re-propagated from the
    /// keyframe. Returns the samples after `sample`, to replay once the keyframe is in; `None`
    /// (nothing changed) when there is no keyframe yet or too many samples to replay.
    pub(super) fn rewind_to(
        &mut self,
        sample: &ImuSample,
    ) -> Option<HVec<ImuSample, LATE_SAMPLES>> {
        let kf_state = self.window.last()?.state;
        let ins_cfg = self.ins_config();
        let kf_cov = self.kf_cov.get().copied();
        let open = self.open_mut()?;
        let mut tail: HVec<ImuSample, LATE_SAMPLES> = HVec::new();
        for s in open.samples().iter().filter(|s| s.t_ns > sample.t_ns) {
            tail.push(*s).ok()?;
        }
        open.truncate_at(sample).ok()?;
        let mut ins = Ins::new(ins_cfg, kf_state).ok()?;
        ins.set_covariance(kf_cov);
        for s in open.samples() {
            ins.propagate(s).ok()?;
        }
        self.ins.set(ins);
        Some(tail)
    }
}

/// Linear interpolation of an IMU sample at `t_ns` between `a` and `b` (`a.t < t <= b.t`).
pub(super) fn interpolate(a: &ImuSample, b: &ImuSample, t_ns: i64) -> ImuSample {
    let span = b.t_ns.saturating_sub(a.t_ns) as f64;
    let w = if span > 0.0 {
        t_ns.saturating_sub(a.t_ns) as f64 / span
    } else {
        1.0
    };
    ImuSample {
        t_ns,
        gyro_rps: a.gyro_rps + (b.gyro_rps - a.gyro_rps) * w,
        accel_mps2: a.accel_mps2 + (b.accel_mps2 - a.accel_mps2) * w,
    }
}

/// Yaw of `q` (rotation about the world's vertical z of the ZYX Euler angles), rad.
fn yaw(q: &Quat) -> f64 {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    libm::atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
}

//! Sensor timing: the estimator owns it (PX4 EKF2's model). `push_*` only queue; [`update`]
//! processes in time order on a delayed horizon.
//!
//! - [`Estimator::push_imu`] validates a sample (finite, below the sensor's full scale, later
//!   than the previous one) and queues it ([`IMU_QUEUE`] samples).
//! - [`Estimator::push_frame`] queues a camera frame ([`super::PENDING_FRAMES`]); it is taken at
//!   the first processed IMU sample at or past `t_cam + td` (interpolated to that time).
//! - [`Estimator::push_lidar`] queues a whole sweep (up to `Q` points, [`PENDING_SWEEPS`]
//!   sweeps); it is de-skewed right after the first processed IMU sample at or past its last
//!   point (`max t_point + td_l`), when the INS covers every point of it.
//! - [`Estimator::update`] processes the oldest queued IMU sample once it is at least
//!   `delay_horizon_s` older than the newest one pushed (0 by default: at once), with the frames
//!   and sweeps that are due, and returns what it produced. Call it until it returns `None`.
//!   A sample that steps far from the last processed one waits for the next, which tells a
//!   spike (dropped, counted) from a real step ([`super::ImuSpikeConfig`]); a gap before the
//!   sample is a clock jump ([`super::clock_jump`]: it waits for the first frame after it to
//!   tell), or is bridged or resets the estimator ([`super::ImuGapConfig`]).
//!
//! So a caller pushes each measurement when it arrives, in any interleaving of the sensors, and
//! drains [`update`]: frames and sweeps that arrive up to the horizon after the IMU samples
//! of their time are still processed in time order (later frames are rewound to their time,
//! up to [`super::LATE_SAMPLES`] samples). The IMU-rate output is the sample's
//! [`super::ImuOutput`]; with a horizon, a [`crate::inertial::FastPath`] fed at push time gives
//! the pose without the horizon's delay.
//!
//! [`update`]: Estimator::update

use super::clock_jump::JumpCheck;
use super::imu_step::interpolate;
use super::{Estimator, ImuOutput, PendingFrame, Status, MAX_FEATURES};
use crate::camera::FeatureObs;
use crate::inertial::preintegration::UnmeasuredSpan;
use crate::inertial::{ImuSample, InsUpdate};
use crate::lidar::{LidarPoint, Queued, ThinGrid};
use crate::math::Vec3;
use crate::Error;
use heapless::Vec as HVec;

/// Interpolated samples one bridged IMU gap is integrated with, at most.
const MAX_BRIDGE_STEPS: i64 = 1024;
/// How far back the samples before a gap are read for [`line_departure`], ns.
const LINE_HISTORY_NS: i64 = 2_000_000_000;
/// Fewest windows [`line_departure`] measures the line's error on.
const LINE_WINDOWS: u32 = 3;
/// IMU samples the estimator queues (2.56 s at 200 Hz): a horizon must stay well below it.
pub const IMU_QUEUE: usize = 512;
/// LiDAR sweeps the estimator queues.
pub const PENDING_SWEEPS: usize = 4;
/// Raw LiDAR points the estimator queues by default (16 bytes each; 0 without the `lidar`
/// feature), after the crop to the camera's view: a sweep of an Ouster OS1-128 at 1024 x 10
/// (131,072 points, about 45% within a 90-degree camera's view and its margin) with room to
/// spare, or three of a Livox Avia at 10 Hz.
#[cfg(feature = "lidar")]
pub const PENDING_LIDAR_POINTS: usize = 65_536;
/// Raw LiDAR points the estimator queues by default (0: built without `lidar`).
#[cfg(not(feature = "lidar"))]
pub const PENDING_LIDAR_POINTS: usize = 0;

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
    /// Queues one IMU sample (processed by [`Self::update`]). Refused and counted, nothing
    /// changed: [`Error::NonFinite`], [`Error::OutOfRange`] (at or beyond the full scale
    /// `max_gyro_rps` / `max_accel_mps2`: clipped), [`Error::TimeNotIncreasing`], [`Error::CapacityExceeded`] (the queue
    /// is full: call [`Self::update`]). [`Error::NotInitialized`] (nothing counted) while
    /// [`Status::Unconfigured`].
    pub fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        if self.status == Status::Unconfigured {
            return Err(Error::NotInitialized);
        }
        let s = &ImuSample {
            t_ns: self.clock_map.inside(s.t_ns),
            ..*s
        };
        if !s.is_finite() {
            self.counters.imu_rejected_nonfinite += 1;
            return Err(Error::NonFinite);
        }
        // At the full scale a reading is clipped: refused like one beyond it.
        if s.gyro_rps.amax() >= self.cfg.max_gyro_rps
            || s.accel_mps2.amax() >= self.cfg.max_accel_mps2
        {
            self.counters.imu_rejected_range += 1;
            return Err(Error::OutOfRange);
        }
        let newest = self.imu_in.back().or(self.last_imu.as_ref());
        if newest.is_some_and(|last| s.t_ns <= last.t_ns) {
            self.counters.imu_rejected_time += 1;
            return Err(Error::TimeNotIncreasing);
        }
        if self.imu_in.push_back(*s).is_err() {
            self.counters.imu_dropped_queue_full += 1;
            return Err(Error::CapacityExceeded);
        }
        self.input_ended = false;
        Ok(())
    }

    /// Tells the estimator that no more input comes (the end of a recording): the samples it
    /// holds back for later input are then processed by the next [`Self::update`] calls, as if
    /// that input had said nothing: a sample that steps like a spike (no next sample to confirm
    /// it: kept), the samples inside the delay horizon (`delay_horizon_s`), and those waiting
    /// for the frame that tells a clock jump from an outage (none comes: not a jump). Drain
    /// [`Self::update`] after it. A later push ends this.
    pub fn end_input(&mut self) {
        self.input_ended = true;
    }

    /// Queues a camera frame of tracked features (raw pixels) at camera time `t_cam_ns`. It is
    /// processed by [`Self::update`] at the first IMU sample at or past `t_cam + td`
    /// ([`PENDING_FRAMES`](super::PENDING_FRAMES) are held; one more drops the oldest, counted).
    /// Refused, counted: [`Error::TimeNotIncreasing`], [`Error::OutOfRange`] (more than
    /// `max_frame_lead_s` ahead of the newest IMU sample pushed). [`Error::NotInitialized`]
    /// (nothing counted) while [`Status::Unconfigured`].
    pub fn push_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) -> Result<(), Error> {
        if self.status == Status::Unconfigured {
            return Err(Error::NotInitialized);
        }
        let t_cam_ns = self.clock_map.inside(t_cam_ns);
        self.counters.frames += 1;
        self.outage_frame(t_cam_ns, obs);
        // A frame far ahead of the IMU would block every real frame until the IMU caught up
        // (and overflow the open interval): refuse it.
        let lead_limit_ns = (self.cfg.max_frame_lead_s * 1e9) as i64;
        let newest = self.imu_in.back().or(self.last_imu.as_ref());
        if newest.is_some_and(|s| t_cam_ns.saturating_sub(s.t_ns) > lead_limit_ns) {
            self.counters.frames_rejected_time += 1;
            return Err(Error::OutOfRange);
        }
        if let Some(p) = self.pending.back() {
            if t_cam_ns <= p.t_cam_ns {
                self.counters.frames_rejected_time += 1;
                return Err(Error::TimeNotIncreasing);
            }
        }
        if self.pending.is_full() {
            let _ = self.pending.pop_front();
            self.counters.frames_dropped_no_imu += 1;
        }
        let mut pf = PendingFrame {
            t_cam_ns,
            obs: HVec::new(),
        };
        let take = obs.len().min(MAX_FEATURES);
        for o in obs.iter().take(take) {
            let _ = pf.obs.push(*o);
        }
        self.counters.features_rejected += (obs.len() - take) as u64;
        self.counters.features_received += (obs.len() - take) as u64;
        // Not full (made room above): cannot fail.
        let _ = self.pending.push_back(pf);
        Ok(())
    }

    /// Queues one LiDAR sweep (points in the LiDAR frame with their own times), de-skewed by
    /// [`Self::update`] once the IMU has passed its last point. A sweep larger than the queue's
    /// free room keeps its last points (the others counted as evicted). Refused whole and
    /// counted in `lidar_scans_refused`: LiDAR disabled ([`Error::InvalidConfig`]), its last
    /// point more than `max_frame_lead_s` ahead of the newest IMU sample ([`Error::OutOfRange`];
    /// its points counted as rejected), no room in the queue ([`Error::CapacityExceeded`]), or
    /// (when it is due) the estimator not running.
    pub fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error> {
        if self.status == Status::Unconfigured {
            return Err(Error::NotInitialized);
        }
        self.counters.lidar_scans += 1;
        self.counters.lidar_points_received += points.len() as u64;
        if !self.cfg.lidar.enabled {
            self.counters.lidar_scans_refused += 1;
            return Err(Error::InvalidConfig);
        }
        let shift_ns = self.clock_map.total_ns();
        let trigger_ns = crate::lidar::sweep_due_ns(points, self.cfg.lidar.td_l_s)
            .map_or(i64::MIN, |t| t.saturating_sub(shift_ns));
        // A sweep far ahead of the IMU would hold every later one back: refuse it.
        let lead_limit_ns = (self.cfg.max_frame_lead_s * 1e9) as i64;
        let newest = self.imu_in.back().or(self.last_imu.as_ref());
        if newest.is_some_and(|s| trigger_ns.saturating_sub(s.t_ns) > lead_limit_ns) {
            self.counters.lidar_scans_refused += 1;
            self.counters.lidar_points_rejected += points.len() as u64;
            return Err(Error::OutOfRange);
        }
        let crop = self.view_crop;
        let keep = |p: &LidarPoint| crop.as_ref().is_none_or(|c| c.keeps(p.p_l));
        match self
            .sweeps_in
            .push_kept_shifted(points, trigger_ns, shift_ns, keep)
        {
            Queued::Queued { evicted, outside } => {
                // Pushed out of the queue before the INS reached them: lost young.
                self.counters.lidar_points_evicted += u64::from(evicted);
                self.counters.lidar_points_evicted_in_span += u64::from(evicted);
                self.counters.lidar_points_outside_view += u64::from(outside);
                Ok(())
            }
            Queued::Full => {
                self.counters.lidar_scans_refused += 1;
                self.counters.lidar_scans_dropped_queue_full += 1;
                Err(Error::CapacityExceeded)
            }
        }
    }

    /// IMU samples queued and not processed yet.
    pub fn queued_imu(&self) -> usize {
        self.imu_in.len()
    }

    /// Processes the oldest queued IMU sample if it is due (see the module docs): the INS
    /// propagates to it, the frames it reaches are processed (a keyframe is solved here), the
    /// sweeps it passes are de-skewed. `Ok(None)`: nothing is due. An error ends this sample's
    /// processing (the sample is consumed).
    pub fn update(&mut self) -> Result<Option<ImuOutput>, Error> {
        let front = loop {
            let Some(front) = self.imu_in.front().copied() else {
                return Ok(None);
            };
            if self.cfg.delay_horizon_s > 0.0 && !self.input_ended {
                let newest = self.imu_in.back().map_or(front.t_ns, |b| b.t_ns);
                let horizon_ns = (self.cfg.delay_horizon_s * 1e9) as i64;
                if newest.saturating_sub(front.t_ns) < horizon_ns {
                    return Ok(None);
                }
            }
            match self.spike_check(&front) {
                Spike::No => break front,
                Spike::Wait => return Ok(None),
                Spike::Yes => {
                    let _ = self.imu_in.pop_front();
                    self.counters.imu_spikes_rejected += 1;
                }
            }
        };
        let jump_ns = match self.clock_jump_check(&front) {
            JumpCheck::Wait => return Ok(None),
            JumpCheck::Jump(jump_ns) => {
                self.jump_clock(jump_ns);
                Some(jump_ns)
            }
            JumpCheck::No => None,
        };
        // The queued samples were moved onto the estimator's clock by a jump.
        let Some(front) = self.imu_in.pop_front() else {
            return Ok(None);
        };
        let mut out = self.process_imu(&front)?;
        out.clock_jump_s = jump_ns.map(|j| j as f64 * 1e-9);
        self.outside_clock(&mut out);
        self.deskew_due_sweeps(front.t_ns);
        Ok(Some(out))
    }

    /// Whether `front` (the oldest queued sample) is a spike (see
    /// [`crate::estimator::ImuSpikeConfig`]): it steps from the last processed sample beyond
    /// the limits and the next queued sample steps as far from it; `Wait` until that next
    /// sample is pushed.
    fn spike_check(&self, front: &ImuSample) -> Spike {
        let c = &self.cfg.imu_spike;
        let Some(last) = self.last_imu.as_ref() else {
            return Spike::No;
        };
        if !c.enabled || !c.is_step(last, front) {
            return Spike::No;
        }
        match self.imu_in.iter().nth(1) {
            None if self.input_ended => Spike::No,
            None => Spike::Wait,
            Some(next) if c.is_step(front, next) => Spike::Yes,
            Some(_) => Spike::No,
        }
    }

    /// One validated sample, in time order: a gap above `max_imu_dt_s` while running is bridged
    /// up to `imu_gap.bridge_max_s` and resets the estimator beyond; then initialization or the
    /// running step.
    fn process_imu(&mut self, s: &ImuSample) -> Result<ImuOutput, Error> {
        let mut out = ImuOutput {
            nav: None,
            keyframe: None,
            ins: None,
            gap_bridged_s: None,
            clock_jump_s: None,
            nav_withheld: false,
        };
        if let Some(last) = self.last_imu {
            let gap_ns = s.t_ns.saturating_sub(last.t_ns);
            let gap_s = gap_ns as f64 * 1e-9;
            if gap_s > self.cfg.max_imu_dt_s {
                if self.status == Status::Running {
                    if gap_s <= self.cfg.imu_gap.bridge_max_s {
                        self.bridge_gap(&last, s, None, &mut out)?;
                    } else if let Some(line) = self.long_gap_line(gap_ns) {
                        self.bridge_gap(&last, s, Some(line), &mut out)?;
                    } else {
                        self.counters.imu_gap_resets += 1;
                        // The frames after the gap (queued while a clock jump was waited for)
                        // are the next start's.
                        self.reset_keeping_frames_from(s.t_ns);
                    }
                }
                // A window of the history must not span the gap.
                self.motion.clear();
            } else {
                self.imu_dt_ns = gap_ns;
            }
        }
        self.motion.push(s);
        self.counters.imu_samples += 1;
        if self.cfg.camera.readout_s > 0.0 {
            if self.gyro_recent.is_full() {
                let _ = self.gyro_recent.pop_front();
            }
            // Not full (made room above): cannot fail.
            let _ = self.gyro_recent.push_back((s.t_ns, s.gyro_rps));
        }
        let plain_from = if self.status == Status::WaitingForInit {
            self.imu_waiting_for_init(s)?;
            None
        } else {
            self.imu_running(s, &mut out)?
        };
        self.last_imu = Some(*s);
        out.nav = self.ins.as_ref().map(|i| *i.state());
        out.ins = self.fast_path_update(plain_from);
        self.withhold_after_gap(&mut out);
        Ok(out)
    }

    /// After a long bridged gap the INS has crossed it on the line between the samples around
    /// it, off by up to the gap's predicted error (2 s after a calm flight: about 0.05 rad of
    /// tilt, a metre of position). The first keyframe after the gap corrects its pose, not yet
    /// its velocity (the interval before it is the gap: real EuRoC, 1 s gap, the velocity then
    /// 0.5 m/s off); the second, whose interval was measured, corrects both. Until then the state
    /// is withheld ([`ImuOutput::nav_withheld`]; a fast path is reset, then given the corrected
    /// state), at most [`super::GAP_WITHHOLD_MAX_S`]. The keyframes are the selector's own: the
    /// estimate is the same as without the hold, only handed out later. A consumer sees the gap
    /// a few frame periods longer, not a jump (BENCHMARKS.md, "The published pose just after a
    /// long gap").
    fn withhold_after_gap(&mut self, out: &mut ImuOutput) {
        let Some(w) = self.withheld else {
            return;
        };
        // The newest keyframe's interval was measured: the one before it is after the gap.
        let measured = self
            .window
            .len()
            .checked_sub(2)
            .and_then(|p| self.window.get(p))
            .is_some_and(|k| k.state.t_ns >= w.gap_end_ns);
        // The hold starts at the sample that ends the gap: the fast path is reset there.
        let first = out.gap_bridged_s.is_some();
        if (out.keyframe.is_some() && measured) || out.nav.is_none_or(|n| n.t_ns >= w.until_ns) {
            self.withheld = None;
            if !first && out.ins.is_none() {
                out.ins = self.ins.as_ref().map(|i| InsUpdate::State(*i));
            }
            return;
        }
        out.nav = None;
        out.nav_withheld = true;
        out.ins = first.then_some(InsUpdate::Reset);
    }

    /// Bridges the gap from `last` to `s` (see [`crate::estimator::ImuGapConfig`]): declares it
    /// unmeasured to the open interval (and, through `self.gap`, to the intervals that keyframes
    /// inside it open), then runs samples interpolated between `last` and `s`, at most
    /// `max_imu_dt_s / 2` apart, through the running step: the frames inside the gap are
    /// processed at their times. A reset on the way (a diverged INS) ends the bridge.
    fn bridge_gap(
        &mut self,
        last: &ImuSample,
        s: &ImuSample,
        measured: Option<(f64, f64)>,
        out: &mut ImuOutput,
    ) -> Result<(), Error> {
        let gap_ns = s.t_ns.saturating_sub(last.t_ns);
        let gap_s = gap_ns as f64 * 1e-9;
        let g = self.cfg.imu_gap;
        // The line's error: the configured bound, or less where the motion before the gap
        // departed less from a line over the gap's length (a long gap's, measured on the block
        // history by `long_gap_line`).
        let (mut sa, mut sg) = (g.accel_sigma_mps2, g.gyro_sigma_rps);
        let history = self
            .keyframes()
            .filter_map(|k| k.preint())
            .chain(self.open())
            .flat_map(|p| p.samples().iter())
            .filter(|x| x.t_ns >= last.t_ns.saturating_sub(LINE_HISTORY_NS));
        if let Some((a, w)) = measured.or_else(|| line_departure(history, gap_ns)) {
            sa = sa.min(a);
            sg = sg.min(w);
        }
        let span = UnmeasuredSpan {
            t0_ns: last.t_ns,
            t1_ns: s.t_ns,
            accel_var_per_s: sa * sa * gap_s,
            gyro_var_per_s: sg * sg * gap_s,
        };
        if let Some(open) = self.open_mut() {
            if open.add_unmeasured(span).is_err() {
                // More gaps in one interval than it holds: start over.
                self.counters.imu_gap_resets += 1;
                self.reset();
                return Ok(());
            }
        }
        self.gap = Some(span);
        self.counters.imu_gaps_bridged += 1;
        self.counters.imu_gaps_bridged_long += u64::from(measured.is_some());
        out.gap_bridged_s = Some(gap_s);
        if measured.is_some() {
            let hold_ns = (super::GAP_WITHHOLD_MAX_S * 1e9) as i64;
            self.withheld = Some(Withheld {
                gap_end_ns: s.t_ns,
                until_ns: s.t_ns.saturating_add(hold_ns),
            });
        }
        // At most MAX_BRIDGE_STEPS steps (bounded time; a step longer than max_imu_dt_s, from
        // a tiny max_imu_dt_s, makes the INS refuse it: a reset).
        let step_ns = ((self.cfg.max_imu_dt_s * 0.5 * 1e9) as i64).max(1);
        let steps = ((gap_ns + step_ns - 1) / step_ns).min(MAX_BRIDGE_STEPS);
        for k in 1..steps {
            let t_ns = last.t_ns + (i128::from(gap_ns) * i128::from(k) / i128::from(steps)) as i64;
            let m = interpolate(last, s, t_ns);
            self.imu_running(&m, out)?;
            if self.status != Status::Running {
                break;
            }
            self.last_imu = Some(m);
        }
        Ok(())
    }

    /// A gap above `imu_gap.bridge_max_s`: the line's error measured on the block history
    /// (specific force m/s^2, angular rate rad/s) when the gap is at most
    /// `imu_gap.long_bridge_max_s` and that error, over the gap, stays within the long-gap
    /// limits; `None`: reset ([`crate::estimator::ImuGapConfig`]).
    fn long_gap_line(&self, gap_ns: i64) -> Option<(f64, f64)> {
        let g = self.cfg.imu_gap;
        let gap_s = gap_ns as f64 * 1e-9;
        if gap_s > g.long_bridge_max_s {
            return None;
        }
        let (a, w) = self.motion.line_departure(gap_ns)?;
        (w * gap_s <= g.long_max_rotation_rad && a * gap_s <= g.long_max_velocity_mps)
            .then_some((a, w))
    }

    /// The estimator's current INS as an update for a [`crate::inertial::FastPath`] (`None`
    /// while it has none: waiting for initialization, or after a reset). Hand it to a fast path
    /// that starts beside an estimator already holding a state (e.g. after
    /// [`Self::initialize`]): the fast path then publishes from the first sample instead of
    /// waiting for the first [`ImuOutput::ins`]. Changes nothing in the estimator: its next
    /// [`Self::update`] still reports the same INS, which the fast path applies again to the
    /// same result.
    pub fn fast_path_seed(&self) -> Option<InsUpdate> {
        if self.withheld.is_some() {
            return None;
        }
        self.ins
            .as_ref()
            .map(|ins| InsUpdate::State(self.ins_outside(ins)))
    }

    /// `ins` on the inputs' clock ([`super::clock_jump`]).
    fn ins_outside(&self, ins: &crate::inertial::Ins) -> crate::inertial::Ins {
        ins.time_shifted(self.clock_map.offset_at(ins.state().t_ns))
    }

    /// An output's times on the inputs' clock ([`super::clock_jump`]).
    fn outside_clock(&self, out: &mut ImuOutput) {
        let m = &self.clock_map;
        if let Some(n) = out.nav.as_mut() {
            n.t_ns = m.outside(n.t_ns);
        }
        if let Some(k) = out.keyframe.as_mut() {
            k.t_ns = m.outside(k.t_ns);
            k.t_cam_ns = m.outside(k.t_cam_ns);
        }
        if let Some(InsUpdate::State(ins)) = out.ins.as_mut() {
            *ins = self.ins_outside(ins);
        }
    }

    /// The update a fast path needs after this sample ([`ImuOutput::ins`]): none when the INS
    /// only propagated the sample (`plain_from`: the INS epoch that propagation started from)
    /// from the state the fast path already follows.
    fn fast_path_update(&mut self, plain_from: Option<u32>) -> Option<InsUpdate> {
        let synced = core::mem::replace(&mut self.ins_synced, self.ins.epoch);
        if plain_from == Some(synced) || self.ins.epoch == synced {
            return None;
        }
        Some(match self.ins.as_ref() {
            Some(ins) => InsUpdate::State(*ins),
            None => InsUpdate::Reset,
        })
    }

    /// De-skews and stores the queued sweeps whose last point the IMU has reached (`t_ns`).
    fn deskew_due_sweeps(&mut self, t_ns: i64) {
        while let Some(due_ns) = self.sweeps_in.next_trigger_ns().filter(|&t| t <= t_ns) {
            let running = self.status == Status::Running;
            let (points, ins, cfg) = (&mut self.points, &self.ins_window, &self.cfg.lidar);
            let dt_ns = self.last_sweep_due_ns.map(|t| due_ns.saturating_sub(t));
            self.last_sweep_due_ns = Some(due_ns);
            let span_ns = crate::lidar::buffer::seconds_to_ns(cfg.association.span_s);
            let hold_ns = crate::lidar::buffer::seconds_to_ns(
                cfg.association.span_s / crate::lidar::thin::THIN_PER_SPAN,
            );
            let thin = &mut self.thin;
            let done = self.sweeps_in.pop_with(|it, received, dropped| {
                running.then(|| {
                    let st = if ThinGrid::<TC>::wanted(it.len(), dt_ns, P, span_ns) {
                        points.push_points_thinned(it, ins, cfg, |p_l, r2, t| {
                            thin.keeps(p_l, libm::sqrt(r2), t, hold_ns)
                        })
                    } else {
                        points.push_points(it, ins, cfg)
                    };
                    (st, received, dropped)
                })
            });
            let c = &mut self.counters;
            match done {
                Some(Some((st, _, dropped))) => {
                    c.lidar_points_accepted += u64::from(st.accepted);
                    c.lidar_points_rejected += u64::from(st.rejected_nonfinite)
                        + u64::from(st.rejected_range)
                        + u64::from(st.rejected_time)
                        + u64::from(dropped);
                    c.lidar_points_evicted += u64::from(st.evicted);
                    c.lidar_points_evicted_in_span += u64::from(st.evicted_in_span);
                    c.lidar_points_thinned += u64::from(st.thinned);
                }
                Some(None) => c.lidar_scans_refused += 1,
                None => break,
            }
        }
    }
}

/// [`Estimator::update`]'s verdict on the oldest queued sample.
enum Spike {
    /// Not a spike: process it.
    No,
    /// It steps beyond the limits: the next sample decides.
    Wait,
    /// A spike: drop it.
    Yes,
}

/// How far the bridge's line would have missed the motion before a gap: `samples` (time order)
/// are cut into consecutive windows of `span_ns` (each from one sample to the first at least
/// `span_ns` later, as a gap runs from the sample before it to the one after), and in each the
/// mean of the samples inside is compared with the midpoint of the two end samples (what the
/// linear interpolation between them integrates to); returns the RMS per axis of those
/// differences for the specific force (m/s^2) and the angular rate (rad/s), `None` with fewer
/// than [`LINE_WINDOWS`] windows. The end samples' own noise and vibration count, as they do in
/// the bridge. A sample not later than the one before (an interval's first sample repeats the
/// previous interval's last) is skipped.
pub(super) fn line_departure<'a>(
    samples: impl Iterator<Item = &'a ImuSample>,
    span_ns: i64,
) -> Option<(f64, f64)> {
    let mut start: Option<&ImuSample> = None;
    let mut last_ns = i64::MIN;
    let (mut sum_a, mut sum_g, mut n) = (Vec3::zeros(), Vec3::zeros(), 0u32);
    let mut dep = Departure::new();
    for x in samples {
        if x.t_ns <= last_ns {
            continue;
        }
        last_ns = x.t_ns;
        let Some(a) = start else {
            start = Some(x);
            continue;
        };
        if x.t_ns < a.t_ns.saturating_add(span_ns) {
            sum_a += x.accel_mps2;
            sum_g += x.gyro_rps;
            n += 1;
            continue;
        }
        dep.add(
            (sum_a, sum_g, n),
            (&a.accel_mps2, &a.gyro_rps),
            (&x.accel_mps2, &x.gyro_rps),
        );
        start = Some(x);
        (sum_a, sum_g, n) = (Vec3::zeros(), Vec3::zeros(), 0);
    }
    dep.rms()
}

/// What [`line_departure`] and the block history's measure
/// ([`super::motion_history::MotionHistory::line_departure`]) sum over their windows.
pub(super) struct Departure {
    acc_a: f64,
    acc_g: f64,
    count: u32,
}

impl Departure {
    /// No window yet.
    pub(super) fn new() -> Self {
        Self {
            acc_a: 0.0,
            acc_g: 0.0,
            count: 0,
        }
    }

    /// One window: `inner` the sums of its inner samples' specific force and angular rate and
    /// their count (none: not counted), `start` and `end` its end samples' (specific force,
    /// angular rate).
    pub(super) fn add(
        &mut self,
        inner: (Vec3, Vec3, u32),
        start: (&Vec3, &Vec3),
        end: (&Vec3, &Vec3),
    ) {
        let (sum_a, sum_g, n) = inner;
        if n > 0 {
            let k = f64::from(n);
            self.acc_a += (sum_a / k - (start.0 + end.0) * 0.5).norm_squared();
            self.acc_g += (sum_g / k - (start.1 + end.1) * 0.5).norm_squared();
            self.count += 1;
        }
    }

    /// The RMS per axis of the windows' differences (specific force m/s^2, angular rate
    /// rad/s), `None` with fewer than [`LINE_WINDOWS`] windows.
    pub(super) fn rms(&self) -> Option<(f64, f64)> {
        (self.count >= LINE_WINDOWS).then(|| {
            let c = 3.0 * f64::from(self.count);
            (libm::sqrt(self.acc_a / c), libm::sqrt(self.acc_g / c))
        })
    }
}

/// The state withheld after a long bridged IMU gap ([`Estimator::withhold_after_gap`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Withheld {
    /// The first sample after the gap, ns.
    pub(super) gap_end_ns: i64,
    /// INS time from which the state is handed out whether or not a keyframe came, ns. (No
    /// flag here: `Estimator::empty` is all zero bits, and `None` of a struct without a niche
    /// is.)
    until_ns: i64,
}

#[cfg(test)]
mod line_tests {
    use super::line_departure;
    use crate::inertial::ImuSample;
    use crate::math::Vec3;
    use heapless::Vec as HVec;

    fn samples(f: impl Fn(f64) -> f64, n: i64) -> impl Iterator<Item = ImuSample> {
        (0..n).map(move |k| {
            let t = k as f64 * 0.005;
            ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: Vec3::new(0.0, f(t) * 0.1, 0.0),
                accel_mps2: Vec3::new(f(t), 0.0, 9.81),
            }
        })
    }

    #[test]
    fn a_line_departs_by_nothing_a_parabola_by_its_curvature() {
        // 2 s at 200 Hz; a 0.2 s span.
        let line: HVec<ImuSample, 400> = samples(|t| 3.0 * t - 1.0, 400).collect();
        let (a, g) = line_departure(line.iter(), 200_000_000).expect("enough windows");
        assert!(a < 1e-12 && g < 1e-12, "{a} {g}");
        // a = c t^2 over a window of length T from t0: the mean inside is c (t0^2 + t0 T + T^2/3)
        // (the 39 samples strictly inside at 200 Hz: 2.5% more), the ends' midpoint c (t0^2 + t0 T
        // + T^2/2), so every window misses by c T^2 / 6 on one of three axes: c T^2 / (6 sqrt(3))
        // per axis.
        let c = 2.0;
        let par: HVec<ImuSample, 400> = samples(|t| c * t * t, 400).collect();
        let (a, g) = line_departure(par.iter(), 200_000_000).expect("enough windows");
        let want = c * 0.2 * 0.2 / (6.0 * 3f64.sqrt());
        assert!((a - 1.025 * want).abs() < 0.005 * want, "{a} {want}");
        assert!((g - 0.1025 * want).abs() < 0.005 * want, "{g}");
        // A sample that alone jumps (vibration) at a window's end counts.
        let mut shaken = line.clone();
        for k in (0..400).step_by(40) {
            if let Some(s) = shaken.get_mut(k) {
                s.accel_mps2.x += 1.0;
            }
        }
        let (a, _) = line_departure(shaken.iter(), 200_000_000).expect("enough windows");
        assert!((a - 1.0 / 3f64.sqrt()).abs() < 1e-9, "{a}");
        // Too little history: unknown.
        assert!(line_departure(par[..100].iter(), 200_000_000).is_none());
        // A repeated sample (intervals share their boundary sample) counts once.
        let once = line_departure(par.iter(), 200_000_000);
        let twice = par.iter().flat_map(|s| core::iter::repeat_n(s, 2));
        assert_eq!(line_departure(twice, 200_000_000), once);
    }
}

//! Clock jumps: every stream's stamps stepping forward together (a driver's clock re-synced to
//! GPS or PTP, a recording's clock set while it runs), which no data says happened to the
//! platform. An IMU gap above `imu_gap.bridge_max_s` while running is such a jump, not an
//! outage, when the images say so:
//!
//! - the camera's stream stepped by the same amount: the first frame after the gap (the first
//!   queued frame past the gap's midpoint, waited for up to [`JUMP_WAIT_NS`] of IMU samples
//!   after the gap) comes, less the IMU's step `J` (the gap less one sample period), between 0
//!   and [`JUMP_MAX_FRAME_PERIODS`] frame periods after the frame before it; and
//! - nothing moved in between that one frame period does not explain: at least half of the
//!   previous frame's features (and [`JUMP_MIN_TRACKED`]) are seen again, and the median over
//!   them of the displacement in pixels less twice the displacement their tracked velocity
//!   predicts over that frame period is at most [`JUMP_SLACK_PX`].
//!
//! After a true outage of every sensor (a recording paused while the platform moved) the tracks
//! are lost or moved by the outage's worth of motion; at rest both readings agree, and either
//! is right. An IMU-only gap is told at once, without waiting: frames inside it are queued.
//!
//! A jump moves the estimator's clock, not the platform: the INS state, its time moved by `J`,
//! goes on from where it was; the window is dropped as after a camera dropout and the next frame
//! starts a new one from the INS state with the dropped window's covariance (`imu_step`), so
//! the published pose does not move. Counted in `counters.clock_jumps` (and, as the window
//! restarts, `counters.reinitializations`). `[imu_gap] clock_jumps = false` turns it off (the
//! gap is then bridged or resets, as any other). While the samples after a gap wait for a frame,
//! [`Estimator::update`] returns `None`: a stream that ends within [`JUMP_WAIT_NS`] of such a
//! gap leaves them unprocessed.

use super::{Estimator, PendingFrame, Status, MAX_FEATURES};
use crate::inertial::ImuSample;
use heapless::Vec as HVec;

/// How long the samples after a gap wait for the first frame after it, ns (IMU time).
pub const JUMP_WAIT_NS: i64 = 500_000_000;
/// Largest spacing, in frame periods, of the frames around a jump once `J` is taken off.
pub const JUMP_MAX_FRAME_PERIODS: f64 = 2.5;
/// Fewest features seen again across a jump.
pub const JUMP_MIN_TRACKED: usize = 10;
/// Largest median displacement across a jump beyond twice the predicted one, px.
pub const JUMP_SLACK_PX: f32 = 3.0;

/// What [`Estimator::clock_jump_check`] found for the oldest queued sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum JumpCheck {
    /// Not a jump (or not a gap): process the sample as it is.
    No,
    /// The first frame after the gap is not queued yet: wait.
    Wait,
    /// A clock jump of this many ns: move the clock, then process the sample.
    Jump(i64),
}

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
    /// Whether the gap before `front` (the oldest queued sample) is a clock jump (module docs).
    pub(super) fn clock_jump_check(&self, front: &ImuSample) -> JumpCheck {
        let (Some(last), true) = (self.last_imu, self.status == Status::Running) else {
            return JumpCheck::No;
        };
        let g = self.cfg.imu_gap;
        let gap_ns = front.t_ns.saturating_sub(last.t_ns);
        let gap_s = gap_ns as f64 * 1e-9;
        if !g.clock_jumps
            || gap_s <= self.cfg.max_imu_dt_s
            || gap_s <= g.bridge_max_s
            || self.imu_dt_ns <= 0
            || self.frame_dt_ns <= 0
            || self.frame.obs.len() < JUMP_MIN_TRACKED
        {
            return JumpCheck::No;
        }
        let jump_ns = gap_ns.saturating_sub(self.imu_dt_ns);
        let td_ns = (self.current_td() * 1e9) as i64;
        let mid_ns = last.t_ns.saturating_add(gap_ns / 2);
        let after = |p: &PendingFrame| p.t_cam_ns.saturating_add(td_ns) > mid_ns;
        // A frame inside the gap: the camera went on, only the IMU stopped.
        let inside_from = last.t_ns.saturating_add(self.frame_dt_ns);
        let inside = |p: &PendingFrame| {
            let t = p.t_cam_ns.saturating_add(td_ns);
            t > inside_from && t <= mid_ns
        };
        if self.pending.iter().any(inside) {
            return JumpCheck::No;
        }
        let Some(first) = self.pending.iter().find(|p| after(p)) else {
            let newest = self.imu_in.back().map_or(front.t_ns, |s| s.t_ns);
            let waited = newest.saturating_sub(front.t_ns);
            return if waited < JUMP_WAIT_NS && self.imu_in.len() < self.imu_in.capacity() / 2 {
                JumpCheck::Wait
            } else {
                JumpCheck::No
            };
        };
        // The frame before it: the newest queued one before the gap, or the last processed.
        let before = self
            .pending
            .iter()
            .rev()
            .find(|p| !after(p))
            .unwrap_or(&self.frame);
        let spacing_ns = first
            .t_cam_ns
            .saturating_sub(jump_ns)
            .saturating_sub(before.t_cam_ns);
        let max_spacing = JUMP_MAX_FRAME_PERIODS * self.frame_dt_ns as f64;
        if spacing_ns <= 0 || spacing_ns as f64 > max_spacing {
            return JumpCheck::No;
        }
        if self.same_view(before, first, spacing_ns as f64 * 1e-9) {
            JumpCheck::Jump(jump_ns)
        } else {
            JumpCheck::No
        }
    }

    /// Whether `next` shows what `prev` showed `dt_s` earlier (module docs): enough features
    /// seen again, moved no further than their velocities (`self.frame_obs`, the last processed
    /// frame's) allow.
    fn same_view(&self, prev: &PendingFrame, next: &PendingFrame, dt_s: f64) -> bool {
        let focal = self.focal_px();
        let mut excess: HVec<f32, MAX_FEATURES> = HVec::new();
        for o in next.obs.iter() {
            let Some(p) = prev.obs.iter().find(|p| p.id == o.id) else {
                continue;
            };
            let moved = libm::hypot(o.u_px - p.u_px, o.v_px - p.v_px);
            let predicted = self
                .frame_obs
                .iter()
                .find(|f| f.id == o.id)
                .map_or(0.0, |f| libm::hypot(f.vel[0], f.vel[1]) * focal * dt_s);
            let x = (moved - 2.0 * predicted) as f32;
            if x.is_finite() {
                // At most MAX_FEATURES observations per frame: cannot fail.
                let _ = excess.push(x);
            }
        }
        let seen = excess.len();
        if seen < JUMP_MIN_TRACKED || 2 * seen < prev.obs.len() {
            return false;
        }
        let mid = seen / 2;
        let (_, median, _) = excess.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        *median <= JUMP_SLACK_PX
    }

    /// Moves the estimator's clock forward by `jump_ns` (module docs): the INS state goes on
    /// from where it was, the window restarts from its covariance, the frames queued before the
    /// jump are dropped (counted in `frames_dropped_no_imu`).
    pub(super) fn jump_clock(&mut self, jump_ns: i64) {
        let Some(last) = self.last_imu else {
            return;
        };
        let Some(mut st) = self.ins.as_ref().map(|i| *i.state()) else {
            return;
        };
        let cov = self.dropout_covariance(None);
        let td_ns = (self.current_td() * 1e9) as i64;
        while self.pending.front().is_some_and(|p| {
            p.t_cam_ns.saturating_add(td_ns) <= last.t_ns.saturating_add(jump_ns / 2)
        }) {
            let _ = self.pending.pop_front();
            self.counters.frames_dropped_no_imu += 1;
        }
        st.t_ns = st.t_ns.saturating_add(jump_ns);
        self.reinitialize_keeping_frames(st);
        if let Some(ins) = self.ins.as_mut() {
            ins.set_covariance(cov);
        }
        self.last_imu = Some(ImuSample {
            t_ns: last.t_ns.saturating_add(jump_ns),
            ..last
        });
        self.frame.t_cam_ns = self.frame.t_cam_ns.saturating_add(jump_ns);
        for (t, _) in self.gyro_recent.iter_mut() {
            *t = t.saturating_add(jump_ns);
        }
        self.motion.clear();
        self.counters.clock_jumps += 1;
    }
}

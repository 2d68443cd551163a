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
//! A jump moves the inputs' clock, not the estimator's: from then on every input stamp is taken
//! `J` earlier (the sum of the jumps, [`ClockMap`]), so inside the estimator nothing happened
//! and the window, the INS and the tracks go on; every time handed out (the IMU-rate state, the
//! keyframe report and states, the INS for a fast path) is moved back onto the inputs' clock,
//! and a fast path is handed the INS again after the jump. Counted in `counters.clock_jumps`.
//! [`Estimator::keyframes`] and the other accessors of internal state keep the estimator's own
//! clock. `[imu_gap] clock_jumps = false` turns it off (the gap is then bridged or resets, as
//! any other). While the samples after a gap wait for a frame,
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

/// Jumps a [`ClockMap`] remembers to map the estimator's times back: older ones, whose times no
/// output carries any more (more than this many jumps within one window), take the offset of
/// the oldest one kept.
pub const CLOCK_JUMPS: usize = 4;

/// The inputs' clock against the estimator's (see the module docs): an input stamp `t` is
/// `t - total` inside; an estimator time `t` is `t + ` the offset of the newest jump at or
/// before it outside.
#[derive(Debug, Clone)]
pub struct ClockMap {
    /// The sum of the jumps, ns.
    total_ns: i64,
    /// The offset of times before every jump kept, ns.
    base_ns: i64,
    /// `(estimator time from which, offset)` of the newest jumps, oldest first.
    jumps: heapless::Deque<(i64, i64), CLOCK_JUMPS>,
}

impl ClockMap {
    /// No jump (all zero bits).
    pub const fn new() -> Self {
        ClockMap {
            total_ns: 0,
            base_ns: 0,
            jumps: heapless::Deque::new(),
        }
    }

    /// Forgets every jump.
    pub fn clear(&mut self) {
        *self = Self::new();
    }

    /// The sum of the jumps, ns.
    pub fn total_ns(&self) -> i64 {
        self.total_ns
    }

    /// An input stamp on the estimator's clock.
    pub fn inside(&self, t_ns: i64) -> i64 {
        t_ns.saturating_sub(self.total_ns)
    }

    /// What to add to an estimator time `t_ns` to put it on the inputs' clock.
    pub fn offset_at(&self, t_ns: i64) -> i64 {
        self.jumps
            .iter()
            .rev()
            .find(|(from, _)| t_ns >= *from)
            .map_or(self.base_ns, |(_, off)| *off)
    }

    /// An estimator time on the inputs' clock.
    pub fn outside(&self, t_ns: i64) -> i64 {
        t_ns.saturating_add(self.offset_at(t_ns))
    }

    /// A jump of `jump_ns` of the inputs' clock, for estimator times from `from_ns` on.
    pub fn push(&mut self, from_ns: i64, jump_ns: i64) {
        self.total_ns = self.total_ns.saturating_add(jump_ns);
        if self.jumps.is_full() {
            if let Some((_, off)) = self.jumps.pop_front() {
                self.base_ns = off;
            }
        }
        // Not full (made room above): cannot fail.
        let _ = self.jumps.push_back((from_ns, self.total_ns));
    }
}

impl Default for ClockMap {
    fn default() -> Self {
        Self::new()
    }
}

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
            return if waited < JUMP_WAIT_NS
                && self.imu_in.len() < self.imu_in.capacity() / 2
                && !self.input_ended
            {
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

    /// Takes the inputs from the gap on `jump_ns` earlier (module docs): the queued samples
    /// (every one is after the gap), the frames and sweeps queued after its middle, and every
    /// input pushed from now on; a fast path is handed the INS again.
    pub(super) fn jump_clock(&mut self, jump_ns: i64) {
        let Some(last) = self.last_imu else {
            return;
        };
        let mid_ns = last.t_ns.saturating_add(jump_ns / 2);
        for s in self.imu_in.iter_mut() {
            s.t_ns = s.t_ns.saturating_sub(jump_ns);
        }
        let td_ns = (self.current_td() * 1e9) as i64;
        for p in self.pending.iter_mut() {
            if p.t_cam_ns.saturating_add(td_ns) > mid_ns {
                p.t_cam_ns = p.t_cam_ns.saturating_sub(jump_ns);
            }
        }
        self.sweeps_in.shift_due_after(mid_ns, jump_ns);
        self.clock_map.push(last.t_ns.saturating_add(1), jump_ns);
        // The fast path saw the jump: hand it the INS (on the new clock) at the next sample.
        let _ = self.ins.as_mut();
        self.counters.clock_jumps += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_map_takes_inputs_back_and_hands_times_out_by_the_jump_they_follow() {
        let mut m = ClockMap::new();
        assert_eq!((m.inside(500), m.outside(500)), (500, 500));
        // A jump of +1000 after estimator time 100, then one of +50 after 300.
        m.push(101, 1000);
        m.push(301, 50);
        assert_eq!(m.total_ns(), 1050);
        assert_eq!(m.inside(2000), 950);
        for (t, out) in [
            (100, 100),
            (101, 1101),
            (300, 1300),
            (301, 1351),
            (950, 2000),
        ] {
            assert_eq!(m.outside(t), out, "estimator time {t}");
        }
        // An input taken in and handed back out is itself (after the last jump).
        assert_eq!(m.outside(m.inside(5000)), 5000);
    }

    #[test]
    fn more_jumps_than_it_keeps_give_old_times_the_oldest_kept_offset() {
        let mut m = ClockMap::new();
        for k in 1..=(CLOCK_JUMPS as i64 + 2) {
            m.push(k * 100, 10);
        }
        let n = CLOCK_JUMPS as i64 + 2;
        assert_eq!(m.total_ns(), 10 * n);
        assert_eq!(m.outside(n * 100), n * 100 + 10 * n);
        // The two oldest jumps are forgotten: times before the oldest kept one take its
        // predecessor's offset.
        assert_eq!(m.outside(50), 50 + 20);
        m.clear();
        assert_eq!((m.total_ns(), m.outside(50)), (0, 50));
    }
}

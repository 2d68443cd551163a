//! A bounded time-ordered window of INS states with pose interpolation, for feature prediction
//! and LiDAR de-skew.
//!
//! Between two buffered states `a`, `b` with `s = (t - t_a)/(t_b - t_a)`:
//! `p_wb(t) = (1 - s) p_a + s p_b` and `q_wb(t) = q_a Exp(s Log(q_a^-1 q_b))` (slerp on the short
//! arc). At IMU rate the interpolation error is far below sensor noise.

use super::state::NavState;
use crate::math::{log_so3, quat_exp, Quat, Vec3};
use crate::Error;
use heapless::Deque;

/// Ring buffer of the last `N` INS states, strictly increasing in time; pushing into a full
/// window evicts the oldest state. `N == 0` does not compile (heapless checks it).
#[derive(Debug, Clone)]
pub struct InsWindow<const N: usize> {
    states: Deque<NavState, N>,
}

impl<const N: usize> Default for InsWindow<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> InsWindow<N> {
    /// An empty window.
    pub const fn new() -> Self {
        InsWindow {
            states: Deque::new(),
        }
    }

    /// Number of buffered states.
    pub fn len(&self) -> usize {
        self.states.len()
    }

    /// True when no state is buffered.
    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    /// Removes every state.
    pub fn clear(&mut self) {
        self.states.clear();
    }

    /// Moves every buffered state by the rigid correction that takes `from` onto `to` (the
    /// INS restarting from an optimized state): `p' = R (p - p_from) + p_to`, `q' = q q_wb`,
    /// `v' = R v` with `q = q_to q_from^-1`. Keeps the window continuous across the restart.
    pub fn apply_correction(&mut self, from: &NavState, to: &NavState) {
        let q = super::state::renormalize(to.q_wb * from.q_wb.inverse());
        for s in self.states.iter_mut() {
            s.p_wb = q * (s.p_wb - from.p_wb) + to.p_wb;
            s.v_wb = q * s.v_wb;
            s.q_wb = super::state::renormalize(q * s.q_wb);
        }
    }

    /// Oldest buffered state.
    pub fn oldest(&self) -> Option<&NavState> {
        self.states.front()
    }

    /// Newest buffered state.
    pub fn newest(&self) -> Option<&NavState> {
        self.states.back()
    }

    /// Appends a state, evicting the oldest when full. Rejects a state that is not later than the
    /// newest ([`Error::TimeNotIncreasing`]) or not finite ([`Error::NonFinite`]).
    pub fn push(&mut self, s: NavState) -> Result<(), Error> {
        if !(finite3(&s.p_wb) && finite3(&s.v_wb) && s.q_wb.coords.iter().all(|x| x.is_finite())) {
            return Err(Error::NonFinite);
        }
        if self.states.back().is_some_and(|b| s.t_ns <= b.t_ns) {
            return Err(Error::TimeNotIncreasing);
        }
        if self.states.is_full() {
            self.states.pop_front();
        }
        self.states
            .push_back(s)
            .map_err(|_| Error::CapacityExceeded)
    }

    /// Pose of the body at `t_ns`, interpolated between the buffered states that bracket it.
    /// [`Error::OutOfRange`] outside `[oldest, newest]` (and on an empty window).
    pub fn pose_at(&self, t_ns: i64) -> Result<(Vec3, Quat), Error> {
        let n = self.len();
        let first = self.states.front().ok_or(Error::OutOfRange)?;
        let last = self.states.back().ok_or(Error::OutOfRange)?;
        if t_ns < first.t_ns || t_ns > last.t_ns {
            return Err(Error::OutOfRange);
        }
        // Binary search for the first state with time >= t_ns (exists: t_ns <= last).
        let (mut lo, mut hi) = (0usize, n - 1);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            let tm = self.states.get(mid).ok_or(Error::OutOfRange)?.t_ns;
            if tm < t_ns {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        let b = self.states.get(lo).ok_or(Error::OutOfRange)?;
        if b.t_ns == t_ns || lo == 0 {
            return Ok((b.p_wb, b.q_wb));
        }
        let a = self.states.get(lo - 1).ok_or(Error::OutOfRange)?;
        Ok(interpolate(a, b, t_ns))
    }

    /// The buffered states bracketing `t_ns`: `(i, a, b)` with `a` state `i`, `b` state `i + 1` and
    /// `a.t_ns <= t_ns <= b.t_ns` (`a` and `b` are the same state when the window holds one state
    /// and `t_ns` is its time). Interval `hint`, then its successor, are tried before a binary
    /// search, so time-sorted queries (LiDAR de-skew) cost O(1) each: pass the `i` of the
    /// previous answer. [`Error::OutOfRange`] outside `[oldest, newest]`.
    pub fn bracket(&self, t_ns: i64, hint: usize) -> Result<(usize, &NavState, &NavState), Error> {
        let n = self.len();
        let first = self.states.front().ok_or(Error::OutOfRange)?;
        let last = self.states.back().ok_or(Error::OutOfRange)?;
        if t_ns < first.t_ns || t_ns > last.t_ns {
            return Err(Error::OutOfRange);
        }
        if n == 1 {
            return Ok((0, first, first));
        }
        let fits = |i: usize| match (self.states.get(i), self.states.get(i.wrapping_add(1))) {
            (Some(a), Some(b)) if a.t_ns <= t_ns && t_ns <= b.t_ns => Some((i, a, b)),
            _ => None,
        };
        if let Some(r) = fits(hint).or_else(|| fits(hint.wrapping_add(1))) {
            return Ok(r);
        }
        // Largest i in [0, n - 2] with t_i <= t_ns (exists: t_0 <= t_ns).
        let (mut lo, mut hi) = (0usize, n - 2);
        while lo < hi {
            let mid = lo + (hi - lo).div_ceil(2);
            if self.states.get(mid).ok_or(Error::OutOfRange)?.t_ns <= t_ns {
                lo = mid;
            } else {
                hi = mid - 1;
            }
        }
        fits(lo).ok_or(Error::OutOfRange)
    }
}

fn finite3(v: &Vec3) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Interpolates the pose between two states with `a.t_ns < t_ns <= b.t_ns`.
fn interpolate(a: &NavState, b: &NavState, t_ns: i64) -> (Vec3, Quat) {
    let span = (b.t_ns as i128 - a.t_ns as i128) as f64;
    let s = (t_ns as i128 - a.t_ns as i128) as f64 / span;
    let p = a.p_wb * (1.0 - s) + b.p_wb * s;
    let dphi = log_so3(&(a.q_wb.inverse() * b.q_wb));
    let q = super::state::renormalize(a.q_wb * quat_exp(&(dphi * s)));
    (p, q)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn st(t_ns: i64, x: f64, yaw: f64) -> NavState {
        NavState {
            p_wb: Vec3::new(x, 2.0 * x, -x),
            q_wb: quat_exp(&Vec3::new(0.0, 0.0, yaw)),
            ..NavState::identity(t_ns)
        }
    }

    #[test]
    fn interpolates_and_rejects_out_of_range() {
        let mut w = InsWindow::<4>::new();
        assert_eq!(w.pose_at(0).err(), Some(Error::OutOfRange));
        for k in 0..6i64 {
            w.push(st(k * 100, k as f64, 0.1 * k as f64)).unwrap();
        }
        // Capacity 4: states 2..=5 remain.
        assert_eq!(w.len(), 4);
        assert_eq!(w.oldest().map(|s| s.t_ns), Some(200));
        assert_eq!(w.pose_at(199).err(), Some(Error::OutOfRange));
        assert_eq!(w.pose_at(501).err(), Some(Error::OutOfRange));
        let (p, q) = w.pose_at(325).unwrap();
        assert!((p - Vec3::new(3.25, 6.5, -3.25)).norm() < 1e-12);
        assert!((log_so3(&q) - Vec3::new(0.0, 0.0, 0.325)).norm() < 1e-12);
        // Exact hits at both ends and inside.
        for k in 2..6i64 {
            let (p, _) = w.pose_at(k * 100).unwrap();
            assert_eq!(p.x, k as f64);
        }
    }

    #[test]
    fn bracket_finds_the_interval_whatever_the_hint() {
        let mut w = InsWindow::<8>::new();
        assert_eq!(w.bracket(0, 0).err(), Some(Error::OutOfRange));
        w.push(st(100, 0.0, 0.0)).unwrap();
        // One state: only its own time is inside.
        assert_eq!(w.bracket(100, 5).map(|r| r.0), Ok(0));
        assert_eq!(w.bracket(101, 0).err(), Some(Error::OutOfRange));
        for k in 2..8i64 {
            w.push(st(k * 100, k as f64, 0.0)).unwrap();
        }
        // States at 100, 200, ..., 700: interval i spans [100 (i + 1), 100 (i + 2)].
        for t in [100i64, 150, 199, 200, 201, 450, 699, 700] {
            for hint in [0usize, 1, 3, 5, 6, 7, 100, usize::MAX] {
                let (i, a, b) = w.bracket(t, hint).unwrap();
                assert!(a.t_ns <= t && t <= b.t_ns, "t {t} hint {hint}");
                assert_eq!(b.t_ns - a.t_ns, 100);
                assert_eq!(a.t_ns, 100 * (i as i64 + 1));
            }
        }
        assert_eq!(w.bracket(99, 0).err(), Some(Error::OutOfRange));
        assert_eq!(w.bracket(701, 5).err(), Some(Error::OutOfRange));
    }

    #[test]
    fn slerp_takes_the_short_arc_across_pi() {
        let mut w = InsWindow::<2>::new();
        w.push(st(0, 0.0, 3.0)).unwrap();
        w.push(st(10, 0.0, -3.0)).unwrap(); // 2pi - 6 = 0.283 rad the short way
        let (_, q) = w.pose_at(5).unwrap();
        let yaw = log_so3(&q).z;
        assert!(
            (yaw.abs() - core::f64::consts::PI).abs() < 1e-9,
            "yaw {yaw}"
        );
    }

    #[test]
    fn rejects_non_increasing_and_non_finite() {
        let mut w = InsWindow::<3>::new();
        w.push(st(10, 0.0, 0.0)).unwrap();
        assert_eq!(w.push(st(10, 1.0, 0.0)), Err(Error::TimeNotIncreasing));
        assert_eq!(w.push(st(5, 1.0, 0.0)), Err(Error::TimeNotIncreasing));
        assert_eq!(w.push(st(20, f64::NAN, 0.0)), Err(Error::NonFinite));
        assert_eq!(w.len(), 1);
    }
}

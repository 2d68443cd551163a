//! The IMU-rate fast path: the estimator's INS, followed at IMU rate apart from the keyframe
//! solve.
//!
//! The estimator ([`crate::estimator::Estimator::push_imu`]) runs a keyframe solve inline with
//! the IMU sample that completes the keyframe, so its own IMU-rate state waits for that solve.
//! A [`FastPath`] owned by another thread (the IMU thread of `povins-platform`'s pipeline)
//! keeps publishing poses meanwhile:
//!
//! - [`FastPath::push_imu`] buffers the sample (a ring of the last `B`) and propagates its own
//!   copy of the INS;
//! - whenever the estimator's INS changed other than by propagating the sample it was given
//!   (initialization, a keyframe's optimized state, a frame processed at an interpolated
//!   sample, a reset), [`crate::estimator::ImuOutput::ins`] carries an [`InsUpdate`]: the whole
//!   INS as it stands after that sample;
//! - [`FastPath::apply`] takes it, possibly late, and re-propagates the buffered samples that
//!   came after it.
//!
//! Exactness: the INS is deterministic, so a fast path that has applied every update in order
//! holds *bit for bit* the estimator's state at every sample after the newest update applied
//! (`tests/fast_path.rs` checks this on real data, with updates applied at once and with them
//! delayed by up to 40 samples). Applied at once (lockstep), its output is the estimator's
//! `ImuOutput::nav` exactly. Except after a spike: the fast path publishes at push time, so it
//! cannot wait for the next sample to tell a spike from a step as the estimator does
//! (`estimator::ImuSpikeConfig`); a sample the estimator drops as a spike moves the fast path's
//! output until the next update (at the latest, the next camera frame's).
//!
//! Frames: the states are [`NavState`]s (`q_wb`, `p_wb`, `v_wb` of the IMU body in the world).

use super::covariance::InsCovariance;
use super::imu::ImuSample;
use super::ins::Ins;
use super::state::NavState;
use crate::Error;
use heapless::Deque;

/// What the estimator hands its fast path (see the module docs). `Copy` and fixed-size (about
/// 300 bytes) so it crosses a lock-free queue by value; the `Reset` variant is rare.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum InsUpdate {
    /// The estimator's INS after the sample at `state().t_ns`.
    State(Ins),
    /// The estimator has no INS (reset, or waiting for initialization): the fast path stops
    /// publishing until the next [`InsUpdate::State`].
    Reset,
}

impl InsUpdate {
    /// Time of the update's state, ns (`None` for [`InsUpdate::Reset`]).
    pub fn t_ns(&self) -> Option<i64> {
        match self {
            InsUpdate::State(ins) => Some(ins.state().t_ns),
            InsUpdate::Reset => None,
        }
    }
}

/// What a [`FastPath`] counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FastPathCounters {
    /// Samples accepted into the ring.
    pub samples: u64,
    /// Samples refused: not later than the previous one.
    pub samples_rejected_time: u64,
    /// Samples refused: non-finite or outside the limits ([`FastPath::with_limits`]).
    pub samples_rejected_value: u64,
    /// Samples the INS refused (non-finite, or a gap above the INS's `max_dt_s`): the fast path
    /// stops publishing until the next update.
    pub propagation_failures: u64,
    /// Updates applied.
    pub updates: u64,
    /// Updates refused because samples after them have already left the ring (the estimator
    /// lags by more than `B` samples); the fast path goes on from its own state.
    pub updates_too_old: u64,
    /// Buffered samples re-propagated after late updates.
    pub replayed: u64,
    /// Largest number of samples one update re-propagated (how late updates arrive).
    pub max_replay: u32,
}

/// The IMU-rate fast path, holding the last `B` IMU samples (see the module docs).
#[derive(Debug, Clone)]
pub struct FastPath<const B: usize> {
    ins: Ins,
    active: bool,
    ring: Deque<ImuSample, B>,
    /// Largest accepted |gyro| component (rad/s) and |accel| component (m/s^2).
    limits: (f64, f64),
    /// Time of the newest sample that left the ring, ns (an update older than it cannot be
    /// replayed).
    dropped_t_ns: i64,
    counters: FastPathCounters,
}

impl<const B: usize> Default for FastPath<B> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const B: usize> FastPath<B> {
    /// An empty fast path that accepts any finite sample: it publishes nothing until its first
    /// [`InsUpdate::State`].
    pub const fn new() -> Self {
        Self::with_limits(f64::INFINITY, f64::INFINITY)
    }

    /// An empty fast path that refuses samples the estimator refuses: give it the estimator's
    /// `max_gyro_rps` and `max_accel_mps2` ([`crate::estimator::EstimatorConfig`]), so that both
    /// integrate the same samples.
    pub const fn with_limits(max_gyro_rps: f64, max_accel_mps2: f64) -> Self {
        FastPath {
            ins: Ins::blank(),
            active: false,
            ring: Deque::new(),
            limits: (max_gyro_rps, max_accel_mps2),
            dropped_t_ns: i64::MIN,
            counters: FastPathCounters {
                samples: 0,
                samples_rejected_time: 0,
                samples_rejected_value: 0,
                propagation_failures: 0,
                updates: 0,
                updates_too_old: 0,
                replayed: 0,
                max_replay: 0,
            },
        }
    }

    /// The current state, once an update has been applied (and no reset or failure since).
    pub fn state(&self) -> Option<&NavState> {
        self.active.then_some(self.ins.state())
    }

    /// The covariance of [`FastPath::state`], when the estimator computes one
    /// ([`crate::estimator::EstimatorConfig::covariance`]): it arrives with each update and is
    /// propagated with the samples after it, as the state is.
    pub fn covariance(&self) -> Option<&InsCovariance> {
        if self.active {
            self.ins.covariance()
        } else {
            None
        }
    }

    /// The counters.
    pub fn counters(&self) -> FastPathCounters {
        self.counters
    }

    /// Buffers `s` and propagates to it; returns the state at `s.t_ns` (`None` before the first
    /// update, or after a reset or an INS failure). Refused, counted, nothing changed:
    /// [`Error::NonFinite`], [`Error::OutOfRange`] (the limits), [`Error::TimeNotIncreasing`]
    /// (not later than the previous sample); the estimator refuses the same samples.
    pub fn push_imu(&mut self, s: &ImuSample) -> Result<Option<NavState>, Error> {
        if !s.is_finite() {
            self.counters.samples_rejected_value += 1;
            return Err(Error::NonFinite);
        }
        // At the full scale a reading is clipped (as the estimator judges it).
        if s.gyro_rps.amax() >= self.limits.0 || s.accel_mps2.amax() >= self.limits.1 {
            self.counters.samples_rejected_value += 1;
            return Err(Error::OutOfRange);
        }
        if self.ring.back().is_some_and(|b| s.t_ns <= b.t_ns) {
            self.counters.samples_rejected_time += 1;
            return Err(Error::TimeNotIncreasing);
        }
        if self.ring.is_full() {
            if let Some(old) = self.ring.pop_front() {
                self.dropped_t_ns = old.t_ns;
            }
        }
        // Not full (made room above): cannot fail.
        let _ = self.ring.push_back(*s);
        self.counters.samples += 1;
        if self.active && s.t_ns > self.ins.state().t_ns && self.ins.propagate(s).is_err() {
            self.active = false;
            self.counters.propagation_failures += 1;
        }
        Ok(self.state().copied())
    }

    /// Applies an estimator update (see the module docs) and re-propagates the buffered samples
    /// after it; returns the state at the newest buffered sample. An update older than the
    /// ring is refused (counted in `updates_too_old`) and the fast path goes on from its own
    /// state.
    pub fn apply(&mut self, u: &InsUpdate) -> Option<NavState> {
        let ins = match u {
            InsUpdate::Reset => {
                self.active = false;
                self.counters.updates += 1;
                return None;
            }
            InsUpdate::State(ins) => ins,
        };
        let t_u = ins.state().t_ns;
        if t_u < self.dropped_t_ns {
            self.counters.updates_too_old += 1;
            return self.state().copied();
        }
        self.counters.updates += 1;
        self.ins = *ins;
        self.active = true;
        let mut replayed = 0u32;
        for s in self.ring.iter().filter(|s| s.t_ns > t_u) {
            if self.ins.propagate(s).is_err() {
                self.active = false;
                self.counters.propagation_failures += 1;
                break;
            }
            replayed += 1;
        }
        self.counters.replayed += u64::from(replayed);
        self.counters.max_replay = self.counters.max_replay.max(replayed);
        self.state().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inertial::InsConfig;
    use crate::math::{Quat, Vec3};

    fn sample(k: i64) -> ImuSample {
        let t = k as f64 * 0.005;
        ImuSample {
            t_ns: k * 5_000_000,
            gyro_rps: Vec3::new(0.3 * libm::sin(t), 0.2, -0.1 * libm::cos(2.0 * t)),
            accel_mps2: Vec3::new(0.5 * libm::cos(t), 0.1, 9.81 + 0.2 * libm::sin(3.0 * t)),
        }
    }

    fn start(k: i64) -> Ins {
        let st = NavState {
            t_ns: sample(k).t_ns,
            q_wb: Quat::identity(),
            ..NavState::ZERO
        };
        let mut ins = Ins::new(InsConfig::DEFAULT, st).expect("valid");
        ins.propagate(&sample(k)).expect("start sample");
        ins
    }

    #[test]
    fn late_update_replays_to_the_same_bits() {
        // Reference: one INS from sample 10 on.
        let mut reference = start(10);
        let mut fast: FastPath<64> = FastPath::new();
        for k in 0..=10 {
            assert_eq!(fast.push_imu(&sample(k)), Ok(None));
        }
        let update = InsUpdate::State(reference);
        for k in 11..40 {
            let r = *reference.propagate(&sample(k)).expect("propagates");
            let f = fast.push_imu(&sample(k)).expect("accepted");
            if k == 30 {
                // The update taken at sample 10 arrives at sample 30: 20 samples replayed.
                assert_eq!(fast.apply(&update), Some(r));
            }
            if k >= 30 {
                assert_eq!(fast.state(), Some(&r));
            } else {
                assert_eq!(f, None);
            }
        }
        assert_eq!(fast.counters().max_replay, 20);
    }

    #[test]
    fn update_older_than_the_ring_is_refused() {
        let mut fast: FastPath<8> = FastPath::new();
        let old = InsUpdate::State(start(0));
        for k in 0..20 {
            fast.push_imu(&sample(k)).expect("accepted");
        }
        assert_eq!(fast.apply(&old), None);
        assert_eq!(fast.counters().updates_too_old, 1);
        // An update inside the ring is taken.
        let recent = InsUpdate::State(start(15));
        assert!(fast.apply(&recent).is_some());
        assert_eq!(fast.state().map(|s| s.t_ns), Some(sample(19).t_ns));
    }

    #[test]
    fn reset_stops_output_and_bad_samples_are_refused() {
        let mut fast: FastPath<8> = FastPath::new();
        fast.push_imu(&sample(0)).expect("accepted");
        assert!(fast.apply(&InsUpdate::State(start(0))).is_some());
        assert!(fast.push_imu(&sample(1)).expect("accepted").is_some());
        assert_eq!(fast.push_imu(&sample(1)), Err(Error::TimeNotIncreasing));
        assert_eq!(fast.counters().samples_rejected_time, 1);
        let mut nan = sample(2);
        nan.gyro_rps[0] = f64::NAN;
        assert_eq!(fast.push_imu(&nan), Err(Error::NonFinite));
        let mut limited: FastPath<8> = FastPath::with_limits(1.0, 20.0);
        assert_eq!(
            limited.push_imu(&ImuSample {
                gyro_rps: Vec3::new(0.0, 2.0, 0.0),
                ..sample(0)
            }),
            Err(Error::OutOfRange)
        );
        assert_eq!(limited.counters().samples_rejected_value, 1);
        assert_eq!(fast.counters().samples_rejected_value, 1);
        assert_eq!(fast.apply(&InsUpdate::Reset), None);
        assert_eq!(fast.push_imu(&sample(2)), Ok(None));
        // A gap the INS refuses stops output until the next update.
        assert!(fast.apply(&InsUpdate::State(start(2))).is_some());
        let mut far = sample(3);
        far.t_ns += 1_000_000_000;
        assert_eq!(fast.push_imu(&far), Ok(None));
        assert_eq!(fast.counters().propagation_failures, 1);
    }
}

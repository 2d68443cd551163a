//! The fault variants of the suite (`povins regress --variants faults`, issue 32): sensor faults
//! injected at half the IMU's time span into the simulated sequences and into the real ones
//! (EuRoC, the corridor), each judged like the standard sequence (median ATE against its stored
//! figures; a reset or an output covering less than 95% of the run counts as a divergence), with
//! the coverage of the ground truth reported.
//!
//! - [`Fault::ImuGap`]: 0.2 s of IMU samples removed (bridged: no reset).
//! - [`Fault::ImuGapLong`]: 2 s of IMU samples removed, on the robot, the vehicle and the
//!   flight, whose motion a line follows over 2 s (bridged as a long gap, no reset; a reset
//!   never restarted the robot and the vehicle), and on the hand-held scenario, where it resets
//!   and the one reset is expected ([`Fault::resets_expected`]): the restart is turned and moved
//!   by the frames during the outage (`estimator::outage_heading`), judged like any run
//!   otherwise. Not run on the fast scenario (it resets too, and the frames during its outage,
//!   turning at 100-130 deg/s, show little of its path: 0.8-1.1 m, over the suite's 1 m limit)
//!   nor on EuRoC (a reset, 5 s to restart). The flight joined once the state after the gap was
//!   withheld until keyframes correct it (before, it published up to about 1 m off for a frame
//!   period after the gap, over the suite's 1 m divergence limit).
//! - [`Fault::Spikes`]: one accelerometer sample of 150 m/s^2, one gyro sample of 34 rad/s 1 s
//!   later and a 0.1 s burst of garbage 2 s later (dropped as spikes, the burst's hole bridged).
//! - [`Fault::CameraDropout`]: 3 s without camera frames (the window is dropped when the open
//!   interval is full, the INS goes on alone, the frames after the dropout start a new window
//!   from its covariance).
//! - [`Fault::ClockJump`]: every stamp from the fault on (every stream, the ground truth too)
//!   moved by +1 h (a clock jump: the inputs' clock moved, the estimate goes on;
//!   `estimator::clock_jump`).

use crate::sim::Scenario;
use povins_core::math::Vec3;
use povins_platform::dataset::Dataset;

/// A sensor fault injected into a simulated sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Fault {
    /// 0.2 s of IMU samples removed.
    ImuGap,
    /// 2 s of IMU samples removed (robot, vehicle, flight and hand-held only).
    ImuGapLong,
    /// Spikes and a burst inside the sensor's range.
    Spikes,
    /// 3 s without camera frames.
    CameraDropout,
    /// Every stamp moved by +1 h.
    ClockJump,
}

/// Length of [`Fault::ImuGap`], ns.
const GAP_NS: i64 = 200_000_000;
/// Length of [`Fault::ImuGapLong`], ns.
const LONG_GAP_NS: i64 = 2_000_000_000;
/// Length of [`Fault::CameraDropout`], ns.
const DROPOUT_NS: i64 = 3_000_000_000;
/// Size of [`Fault::ClockJump`], ns.
const CLOCK_JUMP_NS: i64 = 3_600_000_000_000;

impl Fault {
    /// Suffix of the sequence names.
    pub fn suffix(self) -> &'static str {
        match self {
            Fault::ImuGap => "-imugap0.2s",
            Fault::ImuGapLong => "-imugap2s",
            Fault::Spikes => "-spikes",
            Fault::CameraDropout => "-cameradropout3s",
            Fault::ClockJump => "-clockjump1h",
        }
    }

    /// Full resets the fault is meant to cause on `scenario`: a 2 s gap in the hand-held motion,
    /// which no line follows (the suite counts any other reset as a divergence).
    pub fn resets_expected(self, scenario: Option<Scenario>) -> u64 {
        u64::from(self == Fault::ImuGapLong && scenario == Some(Scenario::Handheld))
    }

    /// Whether the fault is run on `scenario` (`None`: the real sequences).
    pub fn applies_to(self, scenario: Option<Scenario>) -> bool {
        match self {
            Fault::ImuGapLong => matches!(
                scenario,
                Some(Scenario::Robot | Scenario::Vehicle | Scenario::Flight | Scenario::Handheld)
            ),
            Fault::ImuGap | Fault::Spikes | Fault::CameraDropout | Fault::ClockJump => true,
        }
    }

    /// Injects the fault into `ds` at half its IMU time span.
    pub fn inject(self, ds: &mut Dataset) {
        let (Some(first), Some(last)) = (ds.imu.first(), ds.imu.last()) else {
            return;
        };
        let at = first.t_ns + (last.t_ns - first.t_ns) / 2;
        match self {
            Fault::ImuGap => ds.imu.retain(|s| s.t_ns < at || s.t_ns >= at + GAP_NS),
            Fault::ImuGapLong => ds.imu.retain(|s| s.t_ns < at || s.t_ns >= at + LONG_GAP_NS),
            Fault::Spikes => {
                let burst = at + 2_000_000_000;
                let mut state = 0x9e37_79b9_7f4a_7c15_u64;
                let mut rand = move || {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
                };
                let first_at = |t: i64| ds.imu.iter().position(|s| s.t_ns >= t);
                let (a, g) = (first_at(at), first_at(at + 1_000_000_000));
                if let Some(s) = a.and_then(|k| ds.imu.get_mut(k)) {
                    s.accel_mps2.x = 150.0;
                }
                if let Some(s) = g.and_then(|k| ds.imu.get_mut(k)) {
                    s.gyro_rps.y = 34.0;
                }
                for s in ds
                    .imu
                    .iter_mut()
                    .filter(|s| s.t_ns >= burst && s.t_ns < burst + 100_000_000)
                {
                    s.gyro_rps = Vec3::new(rand(), rand(), rand()) * 30.0;
                    s.accel_mps2 = Vec3::new(rand(), rand(), rand()) * 150.0;
                }
            }
            Fault::CameraDropout => {
                let keep = |t: i64| t < at || t >= at + DROPOUT_NS;
                ds.features.retain(|f| keep(f.t_ns));
                ds.images.retain(|f| keep(f.t_ns));
            }
            Fault::ClockJump => {
                let shift = |t: &mut i64| {
                    if *t >= at {
                        *t += CLOCK_JUMP_NS;
                    }
                };
                ds.imu.iter_mut().for_each(|s| shift(&mut s.t_ns));
                ds.features.iter_mut().for_each(|f| shift(&mut f.t_ns));
                ds.images.iter_mut().for_each(|f| shift(&mut f.t_ns));
                ds.ground_truth.iter_mut().for_each(|g| shift(&mut g.t_ns));
                // A sweep moves whole, with its stamp.
                for w in ds.lidar.iter_mut().filter(|w| w.t_ns >= at) {
                    w.t_ns += CLOCK_JUMP_NS;
                    w.points.iter_mut().for_each(|p| p.t_ns += CLOCK_JUMP_NS);
                }
            }
        }
    }
}

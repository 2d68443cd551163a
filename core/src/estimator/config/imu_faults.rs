//! IMU faults: gaps (TOML table `[imu_gap]`: how a sample spacing above
//! [`super::EstimatorConfig::max_imu_dt_s`] is handled while running) and spikes
//! (`[imu_spike]`: single samples far off the signal around them).

use crate::ranges::{self, Ranges};
use crate::Error;

/// Bridging of IMU gaps. A gap up to `bridge_max_s` is bridged: the INS and the open keyframe
/// interval integrate samples interpolated linearly between the samples around it (at most
/// `max_imu_dt_s / 2` apart), and the interval's covariance takes the unmeasured motion's
/// uncertainty (a specific force and an angular rate wrong by `sigma` for the whole gap:
/// velocity and rotation standard deviations of `sigma * T_gap`, see
/// [`crate::inertial::preintegration`]). `sigma` is how far such a line would have missed the
/// motion just before: over the 2 s before the gap, cut into windows of the gap's length, the
/// mean of each window's samples against the midpoint of its two end samples (RMS per axis; the
/// end samples' vibration counts, as in the bridge), at most `accel_sigma_mps2` and
/// `gyro_sigma_rps` (those alone when the window holds fewer than three gap lengths of samples
/// before it). So the images carry the window across it. The frames inside the gap are tracked but never made keyframes: a keyframe there
/// hangs between two intervals that hardly constrain it, and on the hand-held scenario such
/// keyframes let the window's velocity drift by 0.4 m/s after a 0.2 s gap (ATE 0.03 -> 0.8 m;
/// 0.04 m without them, BENCHMARKS.md "Sensor faults").
///
/// A longer gap, up to `long_bridge_max_s`, is bridged the same way when the motion before it
/// was smooth enough for a line: over the last 9.6 s of samples (the estimator's block history,
/// `estimator::motion_history`), in windows of the gap's length, the line's error as above
/// (`sigma_a`, `sigma_g`, at least three windows) must integrate over the gap to at most
/// `long_max_rotation_rad` (`sigma_g * T_gap`) and `long_max_velocity_mps` (`sigma_a * T_gap`);
/// the bridge then takes those measured values; inside such a gap a keyframe is taken where
/// nearly all the newest keyframe's features are lost (no track would span the gap otherwise;
/// `estimator::frame_step`). A wheeled robot, a car or a calm flight passes
/// (2 s: 0.02-0.05 rad, 0.06-0.3 m/s on the simulator's scenarios), a hand-held rig or an
/// aggressive flight does not (0.9-2.2 rad), nor does a platform whose accelerometer vibrates
/// (the line runs through two raw samples). Any other gap resets the estimator, which starts
/// again (in motion when it must) and continues from the last estimate
/// ([`super::super::Estimator::reset`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ImuGapConfig {
    /// Longest gap bridged, s (0: none; at most [`ImuGapConfig::MAX_BRIDGE_S`]).
    pub bridge_max_s: f64,
    /// Largest standard deviation of the specific force during a gap about the line between the
    /// samples around it, m/s^2 (less where the motion before the gap was smoother).
    pub accel_sigma_mps2: f64,
    /// Largest standard deviation of the angular rate during a gap about that line, rad/s.
    pub gyro_sigma_rps: f64,
    /// Longest gap bridged when the motion before it was smooth enough (see above), s (at most
    /// [`ImuGapConfig::MAX_BRIDGE_S`]; not above `bridge_max_s`: off).
    pub long_bridge_max_s: f64,
    /// A longer gap's largest predicted rotation error (the line's measured angular-rate error
    /// times the gap), rad.
    pub long_max_rotation_rad: f64,
    /// A longer gap's largest predicted velocity error (the line's measured specific-force
    /// error times the gap), m/s.
    pub long_max_velocity_mps: f64,
    /// A gap above `bridge_max_s` across which the images show that only the clock moved (every
    /// stream stepped together, the tracks continue) is a clock jump: the inputs' stamps are
    /// taken that much earlier from then on and the estimate goes on
    /// ([`crate::estimator::clock_jump`]). False: such a gap is bridged or resets as any other.
    pub clock_jumps: bool,
}

impl ImuGapConfig {
    /// Longest gap that may be bridged, s: the interpolated samples of one gap are processed in
    /// one [`super::super::Estimator::update`] call.
    pub const MAX_BRIDGE_S: f64 = 3.0;

    /// The defaults (what [`Default`] gives): holes up to 0.6 s bridged (a 0.5 s hole in a
    /// 200 Hz stream is a 0.505 s spacing), with 1 m/s^2 and 0.3 rad/s of unmeasured motion
    /// about the interpolated line at most. Measured (BENCHMARKS.md, "IMU gaps"): the line's error over
    /// 0.2 s of the hand-held scenario is 0.6 m/s^2 and up to 0.35 rad/s RMS per axis; looser
    /// values (5 m/s^2, 1 rad/s) doubled the hand-held ATE after 0.5 s gaps, and bridging 1 s
    /// cost the hand-held and fast-rotation scenarios 7-300x (a reset is cheaper there).
    /// Longer gaps up to 2.5 s (a 2 s hole and margin) where the motion before predicts at most
    /// 0.1 rad and 0.6 m/s of error over the gap: 2 s gaps on the robot, vehicle and flight
    /// scenarios bridged at 0.8-1.4x the fault-free ATE (robot, flight) where a reset lost the
    /// rest of the run or cost 40-60x (BENCHMARKS.md "Long IMU gaps bridged where the motion
    /// was smooth").
    pub const DEFAULT: ImuGapConfig = ImuGapConfig {
        bridge_max_s: 0.6,
        accel_sigma_mps2: 1.0,
        gyro_sigma_rps: 0.3,
        long_bridge_max_s: 2.5,
        long_max_rotation_rad: 0.1,
        long_max_velocity_mps: 0.6,
        clock_jumps: true,
    };

    /// Checks ranges ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[imu_gap]`): `bridge_max_s` and `long_bridge_max_s` within
    /// `0..=MAX_BRIDGE_S`, positive standard deviations, non-negative long-gap limits.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        let b = self.bridge_max_s;
        r.within(
            "imu_gap.bridge_max_s",
            b,
            0.0,
            Self::MAX_BRIDGE_S,
            "0..=3 (s)",
        );
        r.positive("imu_gap.accel_sigma_mps2", self.accel_sigma_mps2);
        r.positive("imu_gap.gyro_sigma_rps", self.gyro_sigma_rps);
        r.within(
            "imu_gap.long_bridge_max_s",
            self.long_bridge_max_s,
            0.0,
            Self::MAX_BRIDGE_S,
            "0..=3 (s)",
        );
        r.non_negative("imu_gap.long_max_rotation_rad", self.long_max_rotation_rad);
        r.non_negative("imu_gap.long_max_velocity_mps", self.long_max_velocity_mps);
    }
}

impl Default for ImuGapConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Spikes: a sample whose gyro or accelerometer reading steps from the last processed sample
/// by more than `max_gyro_step_rps` / `max_accel_step_mps2` (any axis) is held until the next
/// sample arrives. When the next one steps as far from it, the held sample was a spike (or one
/// of a burst): it is dropped and counted (`counters.imu_spikes_rejected`), and the dropped
/// samples leave a gap that is bridged like any other ([`ImuGapConfig`]). When the next one
/// agrees with it, the step was real and both are processed. A sample is held for at most one
/// sample period, and only when it steps that far. The defaults are several times the largest
/// step of real IMUs at 200 Hz (EuRoC's ADIS16448 on a MAV: 10 m/s^2 and 0.3 rad/s;
/// BENCHMARKS.md, "IMU spikes"); readings at or beyond the sensor's full scale
/// (`max_gyro_rps`, `max_accel_mps2`) are clipped and refused at push time.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ImuSpikeConfig {
    /// Check for spikes at all.
    pub enabled: bool,
    /// Largest accelerometer step between consecutive samples taken without confirmation, m/s^2.
    pub max_accel_step_mps2: f64,
    /// Largest gyro step between consecutive samples taken without confirmation, rad/s.
    pub max_gyro_step_rps: f64,
}

impl ImuSpikeConfig {
    /// The defaults (what [`Default`] gives): on, 40 m/s^2 and 5 rad/s.
    pub const DEFAULT: ImuSpikeConfig = ImuSpikeConfig {
        enabled: true,
        max_accel_step_mps2: 40.0,
        max_gyro_step_rps: 5.0,
    };

    /// Checks ranges ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[imu_spike]`): positive steps.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        r.positive("imu_spike.max_accel_step_mps2", self.max_accel_step_mps2);
        r.positive("imu_spike.max_gyro_step_rps", self.max_gyro_step_rps);
    }

    /// Whether `b` steps from `a` by more than the limits.
    pub fn is_step(&self, a: &crate::inertial::ImuSample, b: &crate::inertial::ImuSample) -> bool {
        (b.accel_mps2 - a.accel_mps2).amax() > self.max_accel_step_mps2
            || (b.gyro_rps - a.gyro_rps).amax() > self.max_gyro_step_rps
    }
}

impl Default for ImuSpikeConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

//! IMU samples and the IMU noise model.

use crate::math::Vec3;
use crate::Error;

/// One IMU sample in the body (IMU) frame `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Sample time, integer nanoseconds on the sensor clock.
    pub t_ns: i64,
    /// Angular rate of `b` relative to inertial space, in `b`, rad/s.
    pub gyro_rps: Vec3,
    /// Specific force in `b`, m/s^2 (at rest: `+g` along the body's up axis).
    pub accel_mps2: Vec3,
}

impl ImuSample {
    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.gyro_rps
            .iter()
            .chain(self.accel_mps2.iter())
            .all(|x| x.is_finite())
    }
}

/// Checks a sample against the previous time: finite, strictly later, and within `max_dt_s`.
/// Returns the spacing in seconds.
pub(crate) fn check_sample(s: &ImuSample, prev_t_ns: i64, max_dt_s: f64) -> Result<f64, Error> {
    if !s.is_finite() {
        return Err(Error::NonFinite);
    }
    if s.t_ns <= prev_t_ns {
        return Err(Error::TimeNotIncreasing);
    }
    // i128 so extreme timestamps cannot overflow the subtraction.
    let dt_s = (s.t_ns as i128 - prev_t_ns as i128) as f64 * 1e-9;
    if dt_s > max_dt_s {
        return Err(Error::TimeGap);
    }
    Ok(dt_s)
}

/// Continuous-time IMU noise model (datasheet / Kalibr `sensor.yaml` units).
///
/// Biases follow a random walk, or a first-order Gauss-Markov process when
/// `bias_corr_time_s` is set (LE-VINS): `db/dt = -b/T + w`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ImuNoise {
    /// Gyro white-noise density, rad/s/sqrt(Hz).
    pub gyro_noise_density: f64,
    /// Accelerometer white-noise density, m/s^2/sqrt(Hz).
    pub accel_noise_density: f64,
    /// Gyro bias random-walk density, rad/s^2/sqrt(Hz).
    pub gyro_bias_rw: f64,
    /// Accelerometer bias random-walk density, m/s^3/sqrt(Hz).
    pub accel_bias_rw: f64,
    /// Gauss-Markov correlation time of both biases, s; `None` = pure random walk.
    #[cfg_attr(
        feature = "serde",
        serde(default, skip_serializing_if = "Option::is_none")
    )]
    pub bias_corr_time_s: Option<f64>,
}

impl ImuNoise {
    /// EuRoC ADIS16448 values from its `sensor.yaml`.
    pub const EUROC_ADIS16448: ImuNoise = ImuNoise {
        gyro_noise_density: 1.6968e-4,
        accel_noise_density: 2.0e-3,
        gyro_bias_rw: 1.9393e-5,
        accel_bias_rw: 3.0e-3,
        bias_corr_time_s: None,
    };

    /// True when every density is finite and non-negative and the correlation time (if any)
    /// positive ([`Self::check_ranges`]).
    pub fn is_valid(&self) -> bool {
        crate::ranges::first_invalid(|r| self.check_ranges(r)).is_none()
    }

    /// The range checks (`[imu_noise]`).
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        r.non_negative("imu_noise.gyro_noise_density", self.gyro_noise_density);
        r.non_negative("imu_noise.accel_noise_density", self.accel_noise_density);
        r.non_negative("imu_noise.gyro_bias_rw", self.gyro_bias_rw);
        r.non_negative("imu_noise.accel_bias_rw", self.accel_bias_rw);
        if let Some(t) = self.bias_corr_time_s {
            r.positive("imu_noise.bias_corr_time_s", t);
        }
    }
}

//! Range checks of configuration values that can say which setting is wrong: each
//! configuration group lists its checks once ([`Ranges`] visits them), and both its
//! `validate()` (ok or [`crate::Error::InvalidConfig`]) and the detailed report
//! ([`crate::estimator::EstimatorConfig::find_invalid`]: the key, the value and the allowed
//! range) are decided by that one list. No allocation, no panic.

use core::fmt;

/// A setting outside its allowed range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InvalidSetting {
    /// The setting's TOML path, e.g. `imu_noise.gyro_noise_density`.
    pub key: &'static str,
    /// Its value (integers and counts as `f64`; for a vector or quaternion, the offending
    /// component).
    pub value: f64,
    /// The allowed range, e.g. `> 0`, `0..=1`.
    pub allowed: &'static str,
}

impl fmt::Display for InvalidSetting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} = {} is out of range (allowed: {})",
            self.key, self.value, self.allowed
        )
    }
}

/// Visits range checks: each check hands its setting and whether it passed to the visitor.
pub struct Ranges<'f> {
    visit: &'f mut dyn FnMut(InvalidSetting, bool),
}

impl<'f> Ranges<'f> {
    /// Checks handed to `visit` (the setting, whether it is in range).
    pub fn new(visit: &'f mut dyn FnMut(InvalidSetting, bool)) -> Self {
        Ranges { visit }
    }

    /// One check: `ok` says whether `value` of `key` is within `allowed`.
    pub fn check(&mut self, key: &'static str, value: f64, allowed: &'static str, ok: bool) {
        (self.visit)(
            InvalidSetting {
                key,
                value,
                allowed,
            },
            ok,
        );
    }

    /// A finite number above zero.
    pub fn positive(&mut self, key: &'static str, v: f64) {
        self.check(key, v, "> 0", v.is_finite() && v > 0.0);
    }

    /// A finite number not below zero.
    pub fn non_negative(&mut self, key: &'static str, v: f64) {
        self.check(key, v, ">= 0", v.is_finite() && v >= 0.0);
    }

    /// A finite number.
    pub fn finite(&mut self, key: &'static str, v: f64) {
        self.check(key, v, "finite", v.is_finite());
    }

    /// A number in `lo..=hi` (`allowed` says so in words, e.g. `0..=1`).
    pub fn within(&mut self, key: &'static str, v: f64, lo: f64, hi: f64, allowed: &'static str) {
        self.check(key, v, allowed, (lo..=hi).contains(&v));
    }

    /// Every component of `v` finite (the first non-finite one is the value reported).
    pub fn all_finite(&mut self, key: &'static str, v: &[f64]) {
        let bad = v.iter().copied().find(|x| !x.is_finite());
        self.check(key, bad.unwrap_or(0.0), "finite", bad.is_none());
    }
}

/// The first check of `list` that fails.
pub fn first_invalid(list: impl FnOnce(&mut Ranges<'_>)) -> Option<InvalidSetting> {
    let mut bad = None;
    let mut visit = |s: InvalidSetting, ok: bool| {
        if !ok && bad.is_none() {
            bad = Some(s);
        }
    };
    list(&mut Ranges::new(&mut visit));
    bad
}

/// [`first_invalid`] as the `validate()` of a configuration group.
pub fn validate(list: impl FnOnce(&mut Ranges<'_>)) -> Result<(), crate::Error> {
    match first_invalid(list) {
        None => Ok(()),
        Some(_) => Err(crate::Error::InvalidConfig),
    }
}

#[cfg(test)]
mod tests {
    use crate::camera::{CameraExtrinsic, PinholeCamera};
    use crate::estimator::EstimatorConfig;
    use crate::inertial::ImuNoise;
    use crate::math::{Quat, Vec3};

    /// `validate` and `find_invalid` decide alike, and the first failing check is the one named.
    #[test]
    fn find_invalid_names_the_setting_validate_refuses() {
        let ext = CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: Quat::identity(),
        };
        let mut c = EstimatorConfig::new(PinholeCamera::EUROC_CAM0, ext, ImuNoise::EUROC_ADIS16448);
        assert_eq!(c.find_invalid(), None);
        assert!(c.validate().is_ok());
        c.imu_noise.gyro_noise_density = -1.0;
        let bad = c.find_invalid().expect("out of range");
        assert_eq!(
            (bad.key, bad.value, bad.allowed),
            ("imu_noise.gyro_noise_density", -1.0, ">= 0")
        );
        assert!(c.validate().is_err());
        c.imu_noise = ImuNoise::EUROC_ADIS16448;
        c.td_s = 1.5;
        assert_eq!(c.find_invalid().map(|b| b.key), Some("td_s"));
        c.td_s = -1.0;
        assert_eq!(c.find_invalid(), None);
        assert!(EstimatorConfig::PLACEHOLDER.find_invalid().is_some());
        assert!(EstimatorConfig::PLACEHOLDER.validate().is_err());
    }
}

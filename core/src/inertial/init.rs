//! INS initialization: static (zero-velocity) initialization by gravity leveling, or from a
//! given full state.
//!
//! Static detection over a sliding window of samples: the platform is static when
//! `| mean |f| - g | <= accel_norm_tol`, every axis of the specific force has a standard
//! deviation `<= accel_std_max` and every gyro axis `<= gyro_std_max`, and the window spans at
//! least `min_static_s`. The two strict limits are raised to `noise_std_factor` times what a
//! still IMU of the configured white noise shows (`density * sqrt(rate)`, the rate measured over
//! the window) when that is larger ([`StaticInitializer::reset_with_noise`]): a consumer IMU held
//! still is noisier than the absolute limits, which suit tactical and good MEMS IMUs. When the images say the platform has been at rest over the whole window
//! ([`crate::frontend::RestDetector`]), the spread may reach the vibration limits instead
//! (`vibration_accel_std_max`, `vibration_gyro_std_max`): rotors idling on the ground shake an
//! IMU far more than the strict limits allow, yet the mean is still gravity and the gyro bias.
//!
//! Leveling: at rest the mean specific force is `f = R_wb^T (0, 0, g)`. With yaw set to zero and
//! `R_wb = Ry(pitch) Rx(roll)`, `f = g (-sin pitch, sin roll cos pitch, cos roll cos pitch)`, so
//! `roll = atan2(f_y, f_z)` and `pitch = atan2(-f_x, sqrt(f_y^2 + f_z^2))`. The gyro bias is the
//! mean gyro (Earth rotation, < 7.3e-5 rad/s, is absorbed into it). The accelerometer bias is not
//! separable from the tilt at rest and is set to zero; position and velocity are zero.

use super::imu::{check_sample, ImuNoise, ImuSample};
use super::state::NavState;
use crate::math::{quat_exp, Vec3};
use crate::Error;
use heapless::Deque;

/// Thresholds of the static detector.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct StaticInitConfig {
    /// Gravity magnitude, m/s^2.
    pub gravity_mps2: f64,
    /// Largest `| mean |f| - g |`, m/s^2.
    pub accel_norm_tol_mps2: f64,
    /// Largest standard deviation of each specific-force axis, m/s^2.
    pub accel_std_max_mps2: f64,
    /// Largest standard deviation of each gyro axis, rad/s.
    pub gyro_std_max_rps: f64,
    /// Largest standard deviation of each specific-force axis when the images confirm the rest
    /// (vibration), m/s^2.
    pub vibration_accel_std_max_mps2: f64,
    /// Largest standard deviation of each gyro axis when the images confirm the rest, rad/s.
    pub vibration_gyro_std_max_rps: f64,
    /// Shortest static span, s.
    pub min_static_s: f64,
    /// The strict limits are at least this many times the white-noise standard deviation of a
    /// still IMU, `density * sqrt(rate)` of the configured `[imu_noise]` (per axis). 1 by
    /// default: the configured densities are those of the moving platform (inflated over a
    /// still IMU's), and a larger factor accepts the first second of a smoothly moving robot
    /// with a consumer IMU's densities (BENCHMARKS.md, issue 31 item 3).
    pub noise_std_factor: f64,
    /// Larger sample spacings restart the detection, s.
    pub max_dt_s: f64,
}

impl StaticInitConfig {
    /// Thresholds that fit consumer and tactical MEMS IMUs on a still platform.
    pub const DEFAULT: StaticInitConfig = StaticInitConfig {
        gravity_mps2: 9.81,
        accel_norm_tol_mps2: 0.3,
        accel_std_max_mps2: 0.05,
        gyro_std_max_rps: 0.005,
        vibration_accel_std_max_mps2: 2.5,
        vibration_gyro_std_max_rps: 0.2,
        min_static_s: 1.0,
        noise_std_factor: 1.0,
        max_dt_s: 0.05,
    };

    /// Whether every threshold is in its range ([`Self::check_ranges`]).
    pub fn is_valid(&self) -> bool {
        crate::ranges::first_invalid(|r| self.check_ranges(r)).is_none()
    }

    /// The range checks (`[static_init]`): every threshold positive.
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        r.positive("static_init.gravity_mps2", self.gravity_mps2);
        r.positive("static_init.accel_norm_tol_mps2", self.accel_norm_tol_mps2);
        r.positive("static_init.accel_std_max_mps2", self.accel_std_max_mps2);
        r.positive("static_init.gyro_std_max_rps", self.gyro_std_max_rps);
        let (va, vg) = (
            self.vibration_accel_std_max_mps2,
            self.vibration_gyro_std_max_rps,
        );
        r.positive("static_init.vibration_accel_std_max_mps2", va);
        r.positive("static_init.vibration_gyro_std_max_rps", vg);
        r.positive("static_init.min_static_s", self.min_static_s);
        r.positive("static_init.noise_std_factor", self.noise_std_factor);
        r.positive("static_init.max_dt_s", self.max_dt_s);
    }
}

/// Sliding-window static initializer holding up to `M` samples; `M` must cover `min_static_s`
/// at the IMU rate.
#[derive(Debug, Clone)]
pub struct StaticInitializer<const M: usize> {
    cfg: StaticInitConfig,
    /// White-noise densities `(gyro rad/s/sqrt(Hz), accel m/s^2/sqrt(Hz))` the strict limits
    /// scale with (0: the absolute limits only).
    densities: (f64, f64),
    window: Deque<ImuSample, M>,
    gaps: u32,
}

/// Mean and per-axis standard deviation of the window's gyro and specific force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticStats {
    /// Mean gyro, rad/s.
    pub gyro_mean: Vec3,
    /// Per-axis gyro standard deviation, rad/s.
    pub gyro_std: Vec3,
    /// Mean specific force, m/s^2.
    pub accel_mean: Vec3,
    /// Per-axis specific-force standard deviation, m/s^2.
    pub accel_std: Vec3,
    /// Mean of `|f|`, m/s^2.
    pub accel_norm_mean: f64,
}

impl<const M: usize> StaticInitializer<M> {
    /// A new initializer ([`Error::InvalidConfig`] for non-positive thresholds or `M < 2`).
    pub fn new(cfg: StaticInitConfig) -> Result<Self, Error> {
        if !cfg.is_valid() || M < 2 {
            return Err(Error::InvalidConfig);
        }
        Ok(StaticInitializer {
            cfg,
            densities: (0.0, 0.0),
            window: Deque::new(),
            gaps: 0,
        })
    }

    /// An initializer without samples and without the checks of [`StaticInitializer::new`]
    /// (`cfg` may be a placeholder: give it a valid one with
    /// [`StaticInitializer::reset_to_new`] before use); `const` so it can initialize a `static`.
    pub const fn new_unchecked(cfg: StaticInitConfig) -> Self {
        StaticInitializer {
            cfg,
            densities: (0.0, 0.0),
            window: Deque::new(),
            gaps: 0,
        }
    }

    /// Back to the state [`StaticInitializer::new`] builds with `cfg`, in place (the same
    /// errors, and then nothing changes).
    pub fn reset_to_new(&mut self, cfg: StaticInitConfig) -> Result<(), Error> {
        if !cfg.is_valid() || M < 2 {
            return Err(Error::InvalidConfig);
        }
        self.cfg = cfg;
        self.densities = (0.0, 0.0);
        self.window.clear();
        self.gaps = 0;
        Ok(())
    }

    /// [`Self::reset_to_new`], the strict limits raised to `noise_std_factor` times the white
    /// noise of `noise` when that is larger (module docs).
    pub fn reset_with_noise(
        &mut self,
        cfg: StaticInitConfig,
        noise: &ImuNoise,
    ) -> Result<(), Error> {
        self.reset_to_new(cfg)?;
        let d = (noise.gyro_noise_density, noise.accel_noise_density);
        if d.0.is_finite() && d.1.is_finite() && d.0 >= 0.0 && d.1 >= 0.0 {
            self.densities = d;
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }

    /// How many time gaps restarted the detection.
    pub fn gaps(&self) -> u32 {
        self.gaps
    }

    /// Statistics of the current window ([`Error::NotEnoughData`] below two samples).
    pub fn stats(&self) -> Result<StaticStats, Error> {
        let n = self.window.len();
        if n < 2 {
            return Err(Error::NotEnoughData);
        }
        let inv_n = 1.0 / n as f64;
        let (mut gm, mut am, mut norm_m) = (Vec3::zeros(), Vec3::zeros(), 0.0);
        for s in self.window.iter() {
            gm += s.gyro_rps;
            am += s.accel_mps2;
            norm_m += s.accel_mps2.norm();
        }
        gm *= inv_n;
        am *= inv_n;
        let (mut gv, mut av) = (Vec3::zeros(), Vec3::zeros());
        for s in self.window.iter() {
            gv += (s.gyro_rps - gm).component_mul(&(s.gyro_rps - gm));
            av += (s.accel_mps2 - am).component_mul(&(s.accel_mps2 - am));
        }
        let inv_n1 = 1.0 / (n as f64 - 1.0);
        Ok(StaticStats {
            gyro_mean: gm,
            gyro_std: (gv * inv_n1).map(libm::sqrt),
            accel_mean: am,
            accel_std: (av * inv_n1).map(libm::sqrt),
            accel_norm_mean: norm_m * inv_n,
        })
    }

    /// Feeds one sample. Returns the leveled state at this sample's time once the window is
    /// static for long enough. Non-finite and non-increasing samples are rejected (window
    /// untouched); a gap above `max_dt_s` restarts the window at this sample and is counted.
    /// [`Error::CapacityExceeded`] means the full window spans less than `min_static_s` (the
    /// sample is still taken): `M` is too small for this IMU rate.
    pub fn push(&mut self, s: &ImuSample) -> Result<Option<NavState>, Error> {
        self.push_with_rest(s, None)
    }

    /// [`Self::push`] with the images' verdict: `rest_since_ns` is the IMU time since which the
    /// images show the platform at rest (`None`: no image verdict). When it covers the whole
    /// window, the vibration limits apply instead of the strict ones.
    pub fn push_with_rest(
        &mut self,
        s: &ImuSample,
        rest_since_ns: Option<i64>,
    ) -> Result<Option<NavState>, Error> {
        if !s.is_finite() {
            return Err(Error::NonFinite);
        }
        if let Some(last) = self.window.back() {
            match check_sample(s, last.t_ns, self.cfg.max_dt_s) {
                Ok(_) => {}
                Err(Error::TimeGap) => {
                    self.window.clear();
                    self.gaps = self.gaps.saturating_add(1);
                }
                Err(e) => return Err(e),
            }
        }
        if self.window.is_full() {
            self.window.pop_front();
        }
        self.window
            .push_back(*s)
            .map_err(|_| Error::CapacityExceeded)?;
        let (Some(first), Some(last)) = (self.window.front(), self.window.back()) else {
            return Ok(None);
        };
        let span_s = (last.t_ns as i128 - first.t_ns as i128) as f64 * 1e-9;
        if span_s < self.cfg.min_static_s {
            return if self.window.is_full() {
                Err(Error::CapacityExceeded)
            } else {
                Ok(None)
            };
        }
        let st = self.stats()?;
        let c = &self.cfg;
        let images_at_rest = rest_since_ns.is_some_and(|t| t <= first.t_ns);
        let (a_max, g_max) = if images_at_rest {
            (c.vibration_accel_std_max_mps2, c.vibration_gyro_std_max_rps)
        } else {
            // A still IMU's per-axis spread: density * sqrt(rate), the rate over the window.
            let sqrt_rate = libm::sqrt((self.window.len() as f64 - 1.0) / span_s);
            let k = c.noise_std_factor * sqrt_rate;
            (
                c.accel_std_max_mps2.max(k * self.densities.1),
                c.gyro_std_max_rps.max(k * self.densities.0),
            )
        };
        let is_static = libm::fabs(st.accel_norm_mean - c.gravity_mps2) <= c.accel_norm_tol_mps2
            && st.accel_std.max() <= a_max
            && st.gyro_std.max() <= g_max;
        if !is_static {
            return Ok(None);
        }
        Ok(Some(level(&st, last.t_ns)))
    }
}

/// The leveled state from window statistics.
fn level(st: &StaticStats, t_ns: i64) -> NavState {
    let f = st.accel_mean;
    let roll = libm::atan2(f.y, f.z);
    let pitch = libm::atan2(-f.x, libm::sqrt(f.y * f.y + f.z * f.z));
    let q_wb = quat_exp(&Vec3::new(0.0, pitch, 0.0)) * quat_exp(&Vec3::new(roll, 0.0, 0.0));
    NavState {
        t_ns,
        q_wb,
        bg: st.gyro_mean,
        ..NavState::identity(t_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> StaticInitConfig {
        StaticInitConfig {
            min_static_s: 0.5,
            ..StaticInitConfig::DEFAULT
        }
    }

    #[test]
    fn levels_a_tilted_body_and_recovers_gyro_bias() {
        let q_true = quat_exp(&Vec3::new(0.0, 0.0, 1.2))
            * quat_exp(&Vec3::new(0.0, -0.3, 0.0))
            * quat_exp(&Vec3::new(0.4, 0.0, 0.0));
        let f = q_true.inverse() * Vec3::new(0.0, 0.0, 9.81);
        let bg = Vec3::new(0.001, -0.002, 0.003);
        let mut init = StaticInitializer::<200>::new(cfg()).unwrap();
        let mut out = None;
        for k in 0..200i64 {
            // Deterministic +-1 mrad/s, +-5 mm/s^2 dither so the std is not zero.
            let d = if k % 2 == 0 { 1.0 } else { -1.0 };
            let s = ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: bg + Vec3::new(1e-3, 0.0, 0.0) * d,
                accel_mps2: f + Vec3::new(0.0, 5e-3, 0.0) * d,
            };
            if let Some(st) = init.push(&s).unwrap() {
                out = Some(st);
                break;
            }
        }
        let st = out.expect("static window must initialize");
        // 0.5 s at 200 Hz: initialized at the 101st sample.
        assert_eq!(st.t_ns, 500_000_000);
        // Gravity direction in the body matches; yaw is zero.
        let up_b = st.q_wb.inverse() * Vec3::z();
        let up_true = q_true.inverse() * Vec3::z();
        assert!((up_b - up_true).norm() < 1e-3, "{up_b:?} vs {up_true:?}");
        let fwd_w = st.q_wb * Vec3::x();
        assert!(fwd_w.y.abs() < 1e-12);
        assert!((st.bg - bg).norm() < 2e-5);
        assert_eq!(st.v_wb, Vec3::zeros());
    }

    #[test]
    fn motion_prevents_initialization_and_gaps_restart() {
        let mut init = StaticInitializer::<200>::new(cfg()).unwrap();
        for k in 0..200i64 {
            let s = ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: Vec3::new(0.0, 0.0, 0.3 * libm::sin(k as f64 * 0.1)),
                accel_mps2: Vec3::new(0.0, 0.0, 9.81),
            };
            assert_eq!(init.push(&s), Ok(None));
        }
        // Gap then a static sample: window restarts.
        let s = ImuSample {
            t_ns: 10_000_000_000,
            gyro_rps: Vec3::zeros(),
            accel_mps2: Vec3::new(0.0, 0.0, 9.81),
        };
        assert_eq!(init.push(&s), Ok(None));
        assert_eq!(init.gaps(), 1);
        assert_eq!(init.stats().err(), Some(Error::NotEnoughData));
        assert_eq!(init.push(&s), Err(Error::TimeNotIncreasing));
        let nan = ImuSample {
            t_ns: 10_005_000_000,
            gyro_rps: Vec3::new(f64::NAN, 0.0, 0.0),
            ..s
        };
        assert_eq!(init.push(&nan), Err(Error::NonFinite));
    }

    /// A hand-held consumer IMU's tremor (per axis +-0.008 rad/s, +-0.09 m/s^2 at 200 Hz):
    /// above the absolute limits, within one white-noise deviation of DM-VIO's configured
    /// densities (1e-3 rad/s/sqrt(Hz), 1e-2 m/s^2/sqrt(Hz): 0.0141, 0.141); a sine of 0.3 rad/s
    /// is refused either way.
    #[test]
    fn limits_scale_with_the_configured_white_noise() {
        let noise = ImuNoise {
            gyro_noise_density: 1e-3,
            accel_noise_density: 1e-2,
            gyro_bias_rw: 1e-5,
            accel_bias_rw: 1e-3,
            bias_corr_time_s: None,
        };
        let run = |init: &mut StaticInitializer<200>, moving: bool| {
            let mut out = None;
            for k in 0..200i64 {
                let d = if k % 2 == 0 { 1.0 } else { -1.0 };
                let turn = if moving {
                    0.3 * libm::sin(k as f64 * 0.1)
                } else {
                    0.0
                };
                let s = ImuSample {
                    t_ns: k * 5_000_000,
                    gyro_rps: Vec3::new(8e-3 * d, 0.0, turn),
                    accel_mps2: Vec3::new(0.0, 0.09 * d, 9.81),
                };
                if let Some(st) = init.push(&s).unwrap() {
                    out = Some(st);
                    break;
                }
            }
            out
        };
        let mut init = StaticInitializer::<200>::new(cfg()).unwrap();
        assert_eq!(run(&mut init, false), None, "absolute limits only");
        init.reset_with_noise(cfg(), &noise).unwrap();
        assert_eq!(run(&mut init, false).map(|s| s.t_ns), Some(500_000_000));
        init.reset_with_noise(cfg(), &noise).unwrap();
        assert_eq!(run(&mut init, true), None, "motion");
        init.reset_to_new(cfg()).unwrap();
        assert_eq!(
            run(&mut init, false),
            None,
            "reset_to_new drops the densities"
        );
        let bad = ImuNoise {
            gyro_noise_density: f64::NAN,
            ..noise
        };
        assert_eq!(
            init.reset_with_noise(cfg(), &bad),
            Err(Error::InvalidConfig)
        );
    }

    #[test]
    fn too_small_window_reports_capacity() {
        let mut init = StaticInitializer::<10>::new(cfg()).unwrap();
        let mut last = Ok(None);
        for k in 0..10i64 {
            last = init.push(&ImuSample {
                t_ns: k * 5_000_000,
                gyro_rps: Vec3::zeros(),
                accel_mps2: Vec3::new(0.0, 0.0, 9.81),
            });
        }
        assert_eq!(last, Err(Error::CapacityExceeded));
        assert_eq!(
            StaticInitializer::<1>::new(cfg()).err(),
            Some(Error::InvalidConfig)
        );
    }
}

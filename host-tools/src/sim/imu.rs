//! IMU measurement model and datasheet presets.
//!
//! At sample `k` (rate `f`, `dt = 1/f`):
//!
//! ```text
//! gyro_k  = w_b(t_k) + bg_k + n_g,              n_g ~ N(0, (sigma_g sqrt(f))^2 I)
//! accel_k = R_wb^T (a_w(t_k) + g e_z) + ba_k + n_a,  n_a ~ N(0, (sigma_a sqrt(f))^2 I)
//! b_{k+1} = b_k + sigma_b sqrt(dt) n_b           (bias random walk)
//! ```
//!
//! where `sigma_*` are the continuous densities of [`ImuNoise`]. Turn-on biases are drawn per axis
//! from `N(0, turn_on^2)`. Datasheets give bias *instability* `B` (flat of the Allan deviation),
//! not a random-walk density; we model it as the random-walk density `B sqrt(2 / T)` with
//! `T = 100 s`, i.e. the drift reaches about `B sqrt(2)` after 100 s (stated per preset below).

use super::rng::Rng;
use super::trajectory::Trajectory;
use povins_core::inertial::{ImuNoise, ImuSample, NavState};

const DEG: f64 = core::f64::consts::PI / 180.0;
/// Standard gravity used for `ug`/`mg` datasheet units, m/s^2.
const G0: f64 = 9.80665;
/// Correlation time used to turn a bias instability into a random-walk density, s.
const BIAS_T_S: f64 = 100.0;

/// Random-walk density from a bias instability `b` (see module docs).
fn rw_from_instability(b: f64) -> f64 {
    b * libm::sqrt(2.0 / BIAS_T_S)
}

/// An IMU model: noise densities plus the spread of the turn-on biases.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuPreset {
    /// Part name.
    pub name: &'static str,
    /// Continuous noise model (also written to the calibration).
    pub noise: ImuNoise,
    /// 1-sigma turn-on gyro bias per axis, rad/s.
    pub gyro_turn_on_rps: f64,
    /// 1-sigma turn-on accelerometer bias per axis, m/s^2.
    pub accel_turn_on_mps2: f64,
}

impl ImuPreset {
    /// Analog Devices ADIS16465-1 (wheeled robot). Datasheet (Rev. B) features list: gyro angular
    /// random walk 0.15 deg/sqrt(h), in-run bias stability 2 deg/h; accelerometer in-run bias
    /// stability 3.6 ug. Velocity random walk 0.012 m/s/sqrt(h) and the turn-on bias spread
    /// (0.2 deg/s, 2 mg) are the specification-table values as we recall them (not re-checked).
    pub fn adis16465() -> Self {
        ImuPreset {
            name: "ADIS16465-1",
            noise: ImuNoise {
                gyro_noise_density: 0.15 * DEG / 60.0,
                accel_noise_density: 0.012 / 60.0,
                gyro_bias_rw: rw_from_instability(2.0 * DEG / 3600.0),
                accel_bias_rw: rw_from_instability(3.6e-6 * G0),
                bias_corr_time_s: None,
            },
            gyro_turn_on_rps: 0.2 * DEG,
            accel_turn_on_mps2: 2e-3 * G0,
        }
    }

    /// Bosch BMI088 (hand-held). Datasheet BST-BMI088-DS001: gyro output noise density
    /// 0.014 deg/s/sqrt(Hz), zero-rate offset +-1 deg/s; accelerometer noise density
    /// 175 ug/sqrt(Hz) (x, y), zero-g offset +-20 mg. The typical +- values are taken as 2-sigma.
    /// The datasheet gives no bias instability; we assume 5 deg/h and 40 ug (consumer MEMS class).
    pub fn bmi088() -> Self {
        ImuPreset {
            name: "BMI088",
            noise: ImuNoise {
                gyro_noise_density: 0.014 * DEG,
                accel_noise_density: 175e-6 * G0,
                gyro_bias_rw: rw_from_instability(5.0 * DEG / 3600.0),
                accel_bias_rw: rw_from_instability(40e-6 * G0),
                bias_corr_time_s: None,
            },
            gyro_turn_on_rps: 0.5 * DEG,
            accel_turn_on_mps2: 10e-3 * G0,
        }
    }

    /// Safran Sensonor STIM300 (vehicle), 10 g accelerometer variant. Datasheet (TS1524): gyro
    /// angular random walk 0.15 deg/sqrt(h), bias instability 0.5 deg/h, bias run-to-run 4 deg/h
    /// (1 sigma); accelerometer velocity random walk 0.07 m/s/sqrt(h), bias instability 0.05 mg,
    /// bias run-to-run 0.75 mg (1 sigma).
    pub fn stim300() -> Self {
        ImuPreset {
            name: "STIM300",
            noise: ImuNoise {
                gyro_noise_density: 0.15 * DEG / 60.0,
                accel_noise_density: 0.07 / 60.0,
                gyro_bias_rw: rw_from_instability(0.5 * DEG / 3600.0),
                accel_bias_rw: rw_from_instability(0.05e-3 * G0),
                bias_corr_time_s: None,
            },
            gyro_turn_on_rps: 4.0 * DEG / 3600.0,
            accel_turn_on_mps2: 0.75e-3 * G0,
        }
    }
}

impl ImuPreset {
    /// Analog Devices ADIS16448 as EuRoC's MAV carries it, with the noise densities of EuRoC's
    /// `imu0/sensor.yaml` (gyro 1.6968e-4 rad/s/sqrt(Hz), walk 1.9393e-5; accelerometer
    /// 2.0e-3 m/s^2/sqrt(Hz), walk 3.0e-3) and turn-on biases of the size EuRoC's ground truth
    /// shows (a few 0.01 rad/s, about 0.1 m/s^2).
    pub fn adis16448_euroc() -> Self {
        ImuPreset {
            name: "ADIS16448 (EuRoC)",
            noise: ImuNoise {
                gyro_noise_density: 1.6968e-4,
                accel_noise_density: 2.0e-3,
                gyro_bias_rw: 1.9393e-5,
                accel_bias_rw: 3.0e-3,
                bias_corr_time_s: None,
            },
            gyro_turn_on_rps: 0.02,
            accel_turn_on_mps2: 0.08,
        }
    }
}

/// IMU samples and the ground truth at the same instants.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuRun {
    /// Measurements.
    pub imu: Vec<ImuSample>,
    /// True state (with the true biases) at each sample time.
    pub ground_truth: Vec<NavState>,
}

/// Simulates `n` IMU samples at `rate_hz` starting at `t0_ns` (trajectory time 0).
pub fn simulate_imu(
    traj: &Trajectory,
    preset: &ImuPreset,
    rate_hz: f64,
    n: usize,
    t0_ns: i64,
    gravity_mps2: f64,
    rng: &mut Rng,
) -> ImuRun {
    let dt_ns = (1e9 / rate_hz).round() as i64;
    let dt_s = dt_ns as f64 * 1e-9;
    let sig_g = preset.noise.gyro_noise_density / libm::sqrt(dt_s);
    let sig_a = preset.noise.accel_noise_density / libm::sqrt(dt_s);
    let sig_bg = preset.noise.gyro_bias_rw * libm::sqrt(dt_s);
    let sig_ba = preset.noise.accel_bias_rw * libm::sqrt(dt_s);
    let mut bg = rng.normal3(preset.gyro_turn_on_rps);
    let mut ba = rng.normal3(preset.accel_turn_on_mps2);
    let mut imu = Vec::with_capacity(n);
    let mut ground_truth = Vec::with_capacity(n);
    for k in 0..n {
        let t_ns = t0_ns + k as i64 * dt_ns;
        let kin = traj.eval((k as i64 * dt_ns) as f64 * 1e-9);
        let gyro = kin.omega_b + bg + rng.normal3(sig_g);
        let accel = kin.specific_force_b(gravity_mps2) + ba + rng.normal3(sig_a);
        imu.push(ImuSample {
            t_ns,
            gyro_rps: gyro,
            accel_mps2: accel,
        });
        ground_truth.push(NavState {
            t_ns,
            p_wb: kin.p_wb,
            q_wb: kin.q_wb,
            v_wb: kin.v_wb,
            bg,
            ba,
        });
        bg += rng.normal3(sig_bg);
        ba += rng.normal3(sig_ba);
    }
    ImuRun { imu, ground_truth }
}

/// Discrete white-noise standard deviations `(gyro, accel)` at `rate_hz`.
pub fn discrete_noise_std(noise: &ImuNoise, rate_hz: f64) -> (f64, f64) {
    let r = libm::sqrt(rate_hz);
    (noise.gyro_noise_density * r, noise.accel_noise_density * r)
}

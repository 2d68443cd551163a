//! # povins-core
//!
//! The whole PO-VINS estimator as a `#![no_std]` library that never allocates: every buffer has a
//! capacity fixed at compile time by const generics, every dense block lives inside a struct the
//! caller owns, and bad input is returned as an [`Error`] or rejected and counted, never a panic.
//!
//! ## Conventions (used by every module)
//! - Quaternions are Hamilton, `q_ab` rotates vectors of frame `b` into frame `a`
//!   (`v_a = q_ab * v_b`); `R_ab` is its matrix and `p_ab`/`t_ab` the position of `b`'s origin in `a`.
//! - `w` is the world frame (z up, gravity along -z), `b` the body (= IMU) frame, `c` the camera,
//!   `l` the LiDAR.
//! - Times are integer nanoseconds (`_ns`, `i64`) at interfaces; durations inside the math are
//!   seconds (`_s`, `f64`). All arithmetic is `f64`; transcendental functions go through `libm` so
//!   x86-64 and aarch64 give bit-identical results.
//! - Rotation perturbations are right-multiplicative: `R <- R * Exp(dtheta)`.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

// The logging shim comes first so every module below can use its macros.
#[macro_use]
pub mod log;

pub mod camera;
pub mod error;
pub mod estimator;
pub mod factors;
pub mod frontend;
pub mod inertial;
pub mod landmarks;
pub mod lidar;
pub mod math;
pub mod odometry;
pub mod ranges;
pub mod solver;
pub mod vio;

pub use error::Error;

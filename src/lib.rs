//! `povins`: facade over the PO-VINS crates.
//!
//! - [`core`]: the `no_std`, heap-free estimator (INS, preintegration, pose-only factors, solver).
//! - [`platform`]: Linux I/O, threads, queues, timing and outputs.
//! - [`host_tools`]: dataset replay, simulation, evaluation and plots (the `povins` binary).

pub use povins_core as core;
pub use povins_host_tools as host_tools;
pub use povins_platform as platform;

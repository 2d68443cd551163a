//! # povins-host-tools
//!
//! Library behind the `povins` command: inertial reports, and (as the issues land) dataset
//! replay, simulation, evaluation and plots.

//! # povins-host-tools
//!
//! Library behind the `povins` command: dataset replay, simulation, evaluation, plots and the
//! LiDAR ablation. Each subcommand lives in [`cmd`]; the reusable pieces (evaluation math,
//! simulator, plotting, ablation) in their own modules so tests and benches can call them
//! directly.

pub mod ablation;
pub mod cmd;
pub mod config;
pub mod eval;
pub mod frontend_stats;
pub mod images;
pub mod plot;
pub mod plot_estimate;
pub mod progress;
pub mod realtime;
pub mod regress;
pub mod regress_paired;
pub mod report;
pub mod runner;
pub mod setup;
pub mod sim;
pub mod track;
pub mod track_pictures;

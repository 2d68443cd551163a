//! One module per `povins` subcommand: its clap `Args` and its `run`.

pub mod ablation;
pub mod demo;
pub mod eval;
pub mod plot;
pub mod run;
pub mod simulate;
pub mod track;

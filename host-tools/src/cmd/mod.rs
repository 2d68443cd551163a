//! One module per `povins` subcommand: its clap `Args` and its `run`.

pub mod ablation;
pub mod compare_tracks;
pub mod convert;
pub mod demo;
pub mod eval;
pub mod info;
pub mod plot;
pub mod record;
pub mod regress;
pub mod replay;
pub mod run;
pub mod score_tracks;
pub mod simulate;
pub mod timing;
pub mod track;

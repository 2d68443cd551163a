//! The `povins` command.

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "povins",
    version,
    about = "PO-VINS: pose-only visual-inertial state estimator"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Placeholder until the first command lands.
    Version,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Version => println!("povins {}", env!("CARGO_PKG_VERSION")),
    }
    Ok(())
}

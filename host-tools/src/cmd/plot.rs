//! `povins plot` (STUB: implemented by the data-plane work).

/// Arguments of `povins plot`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("povins plot is not implemented yet")
}

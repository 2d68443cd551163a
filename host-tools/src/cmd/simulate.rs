//! `povins simulate` (STUB: implemented by the data-plane work).

/// Arguments of `povins simulate`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("povins simulate is not implemented yet")
}

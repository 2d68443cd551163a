//! `povins eval` (STUB: implemented by the data-plane work).

/// Arguments of `povins eval`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("povins eval is not implemented yet")
}

//! `dpr-gpu eval` (placeholder until the eval work lands).

/// Arguments of `dpr-gpu eval`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs `dpr-gpu eval`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("eval is not implemented yet")
}

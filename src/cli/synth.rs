//! `dpr-gpu synth` (placeholder until the synth work lands).

/// Arguments of `dpr-gpu synth`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs `dpr-gpu synth`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("synth is not implemented yet")
}

//! `colslam bench features` (being built).

use anyhow::{bail, Result};

/// Arguments of `bench features`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Runs `bench features`.
pub fn run(_args: &Args, _quiet: bool) -> Result<()> {
    bail!("`colslam bench features` is not built yet")
}

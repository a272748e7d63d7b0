//! `colslam bench ba` (being built).

use anyhow::{bail, Result};

/// Arguments of `bench ba`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Runs `bench ba`.
pub fn run(_args: &Args, _quiet: bool) -> Result<()> {
    bail!("`colslam bench ba` is not built yet")
}

//! `colslam bench estimators` (being built).

use anyhow::{bail, Result};

/// Arguments of `bench estimators`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Runs `bench estimators`.
pub fn run(_args: &Args, _quiet: bool) -> Result<()> {
    bail!("`colslam bench estimators` is not built yet")
}

//! `colslam bench [--suite quick|full]` (being built).

use anyhow::{bail, Result};

/// Arguments of the sequence suite.
#[derive(Debug, clap::Args)]
pub struct SuiteArgs {
    /// Which suite.
    #[arg(long, default_value = "quick")]
    pub suite: String,
}

/// Runs the suite.
pub fn run(_args: &SuiteArgs, _quiet: bool) -> Result<()> {
    bail!("`colslam bench --suite` is not built yet")
}

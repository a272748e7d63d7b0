//! `colslam bench`: benchmarks. With no kind, the sequence suite (the paper's
//! tables, side by side with peers); `features`, `estimators` and `ba` time
//! one layer against its peer (OpenCV, pycolmap, Ceres through pycolmap).

pub mod ba;
pub mod estimators;
pub mod features;
pub mod suite;

use anyhow::Result;

/// Arguments of `bench`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct BenchArgs {
    /// A single layer to benchmark; without one, the sequence suite runs.
    #[command(subcommand)]
    pub kind: Option<BenchKind>,
    #[command(flatten)]
    pub suite: suite::SuiteArgs,
}

/// Layer benchmarks.
#[derive(Debug, clap::Subcommand)]
pub enum BenchKind {
    /// ORB extraction and Hamming matching against OpenCV.
    Features(features::Args),
    /// RANSAC estimators against pycolmap.
    Estimators(estimators::Args),
    /// Bundle adjustment against Ceres (pycolmap).
    Ba(ba::Args),
}

/// Runs `bench`.
pub fn run(args: &BenchArgs, quiet: bool) -> Result<()> {
    match &args.kind {
        Some(BenchKind::Features(a)) => features::run(a, quiet),
        Some(BenchKind::Estimators(a)) => estimators::run(a, quiet),
        Some(BenchKind::Ba(a)) => ba::run(a, quiet),
        None => suite::run(&args.suite, quiet),
    }
}

//! `colslam bench`: benchmarks. With no kind, the sequence suite (the paper's
//! tables, side by side with peers); `features`, `estimators` and `ba` time
//! one layer against its peer (OpenCV, pycolmap, Ceres through pycolmap);
//! `precision` reports keypoint localisation, reprojection error, track
//! lengths and ATE per sequence (issue 14).
//! `scale` measures time and memory against the length of a video.
//!
//! This is an application crate of the colslam binary, so it uses anyhow like
//! the binary: it is the binary's benchmark lab (reached as `colslam bench`,
//! whose clap arguments are [`BenchArgs`]), not a library for users. The
//! datasets and the Python peers are found through `colslam-testutil`'s
//! lookups ([`colslam_testutil::find_data_dir`],
//! [`colslam_testutil::find_peer_python`]).

pub mod ba;
pub mod estimators;
pub mod features;
pub mod precision;
pub mod scale;
pub mod stdout;
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
    /// Precision report: keypoint localisation error (synthetic ground
    /// truth), reprojection error, track lengths and ATE per sequence.
    Precision(precision::Args),
    /// Long videos: time and memory against the number of frames
    /// (synthetic exploring and looping paths, a real sequence played
    /// forward and back).
    Scale(scale::Args),
}

/// Runs `bench`; `threads` is the binary's global `--threads` (`None`: all
/// cores), given to every run of the suite and to both sides of `bench ba`.
pub fn run(args: &BenchArgs, quiet: bool, threads: Option<usize>) -> Result<()> {
    match &args.kind {
        Some(BenchKind::Features(a)) => features::run(a, quiet),
        Some(BenchKind::Estimators(a)) => estimators::run(a, quiet),
        Some(BenchKind::Ba(a)) => ba::run(a, quiet, threads),
        Some(BenchKind::Precision(a)) => precision::run(a, quiet, threads),
        Some(BenchKind::Scale(a)) => scale::run(a, quiet, threads),
        None => suite::run(&args.suite, quiet, threads),
    }
}

/// Median of the finite values of a sample (NaN when there are none).
pub(crate) fn median(v: &[f64]) -> f64 {
    colslam_geometry::stats::median_finite(v).unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians() {
        assert_eq!(median(&[3.0, f64::NAN, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0]), 2.5);
        assert!(median(&[f64::INFINITY]).is_nan());
    }
}

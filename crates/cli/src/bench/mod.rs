//! `colslam bench`: benchmarks. With no kind, the sequence suite (the paper's
//! tables, side by side with peers); `features`, `estimators` and `ba` time
//! one layer against its peer (OpenCV, pycolmap, Ceres through pycolmap).

pub mod ba;
pub mod estimators;
pub mod features;
pub mod suite;

use anyhow::{Result, anyhow, bail};
use std::path::{Path, PathBuf};

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

/// The workspace root as compiled in (fallback for relative paths).
pub(crate) fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The datasets folder: `COLSLAM_DATA`, else the first folder of
/// `./datasets`, `../shared/datasets` (relative to the current directory) and
/// `../shared/datasets` beside the workspace that exists.
pub(crate) fn data_dir() -> Result<PathBuf> {
    if let Some(d) = std::env::var_os("COLSLAM_DATA") {
        let d = PathBuf::from(d);
        if d.is_dir() {
            return Ok(d);
        }
        bail!("COLSLAM_DATA={} is not a folder", d.display());
    }
    let candidates =
        [PathBuf::from("datasets"), PathBuf::from("../shared/datasets"), workspace_root().join("../shared/datasets")];
    candidates.iter().find(|d| d.is_dir()).cloned().ok_or_else(|| {
        let looked: Vec<String> = candidates.iter().map(|c| c.display().to_string()).collect();
        anyhow!("dataset folder not found (looked in {}); set COLSLAM_DATA", looked.join(", "))
    })
}

/// Median of the finite values of a sample (NaN when there are none).
pub(crate) fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    // n >= 1 here, so n / 2 and (n - 1) / 2 are valid indices.
    0.5 * (s[(n - 1) / 2] + s[n / 2])
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

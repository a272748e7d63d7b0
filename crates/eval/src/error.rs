//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong while reading, evaluating or plotting
/// trajectories. Messages name the file (or the trajectory label) and the
/// problem, so a user can fix the input without reading code.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A file could not be read or written.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A line of a TUM trajectory file is malformed.
    #[error("{path}:{line}: {problem}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        problem: String,
    },
    /// A trajectory holds no poses.
    #[error("{name}: trajectory holds no poses")]
    Empty {
        /// File or label of the trajectory.
        name: String,
    },
    /// A trajectory's `stamps` and `poses` differ in length, or a value is not finite.
    #[error("{name}: invalid trajectory: {problem}")]
    InvalidTrajectory {
        /// File or label of the trajectory.
        name: String,
        /// What is wrong.
        problem: String,
    },
    /// Association found no pair of timestamps.
    #[error(
        "found no matching timestamps between {reference} and {estimate} with max. time diff {max_diff} s and time offset {offset} s"
    )]
    NoMatches {
        /// Reference file or label.
        reference: String,
        /// Estimate file or label.
        estimate: String,
        /// `EvalOptions::max_diff`.
        max_diff: f64,
        /// `EvalOptions::offset`.
        offset: f64,
    },
    /// Too few associated poses for the requested computation.
    #[error("{reference} vs {estimate}: only {matched} matched poses, {needed} needed for {purpose}")]
    TooFewMatches {
        /// Reference file or label.
        reference: String,
        /// Estimate file or label.
        estimate: String,
        /// Number of matched poses.
        matched: usize,
        /// Number needed.
        needed: usize,
        /// What they are needed for.
        purpose: &'static str,
    },
    /// The alignment is not defined (e.g. all positions collinear or equal).
    #[error("{reference} vs {estimate}: degenerate geometry, {reason}")]
    Degenerate {
        /// Reference file or label.
        reference: String,
        /// Estimate file or label.
        estimate: String,
        /// Why.
        reason: String,
    },
    /// An options struct holds an invalid value.
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// The plot could not be written.
    #[error(transparent)]
    Image(#[from] colslam_image::ImageError),
    /// The report holds nothing that can be plotted.
    #[error("cannot plot: {0}")]
    Plot(String),
}

//! Errors of the XFeat crate.

use std::path::PathBuf;

/// Everything that can go wrong loading XFeat weights or running the network.
#[derive(Debug, thiserror::Error)]
pub enum XFeatError {
    /// The weights file could not be read.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file is not a readable PyTorch zip checkpoint.
    #[error("{path}: not a PyTorch zip checkpoint: {reason}")]
    BadArchive {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The pickled state dict uses something this minimal reader does not handle.
    #[error("{path}: cannot read the pickled state dict: {reason}")]
    BadPickle {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A tensor the network needs is missing or has the wrong shape or type.
    #[error("{path}: weight '{name}': {reason}")]
    BadWeight {
        /// The file.
        path: PathBuf,
        /// The state-dict key.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// No weights file could be found.
    #[error("XFeat weights not found: {0}")]
    WeightsNotFound(String),
    /// An options struct failed its `validate()`.
    #[error("invalid {what} options: {reason}")]
    InvalidOptions {
        /// Which options.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The input image has no pixels.
    #[error("empty image ({width}x{height}): there is nothing to extract features from")]
    EmptyImage {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
}

impl From<XFeatError> for colslam_features::FeatureError {
    fn from(e: XFeatError) -> Self {
        match e {
            XFeatError::EmptyImage { width, height } => colslam_features::FeatureError::EmptyImage { width, height },
            XFeatError::InvalidOptions { what, reason } => {
                colslam_features::FeatureError::InvalidOptions { what, reason }
            }
            other => colslam_features::FeatureError::InvalidOptions { what: "XFeat", reason: other.to_string() },
        }
    }
}

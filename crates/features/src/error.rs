//! Errors of the feature crate.

/// Everything that can go wrong when extracting, matching or scoring features.
#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    /// The input image has no pixels.
    #[error("empty image ({width}x{height}): there is nothing to extract features from")]
    EmptyImage {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
    },
    /// An options struct failed its `validate()`.
    #[error("invalid {what} options: {reason}")]
    InvalidOptions {
        /// Which options (e.g. "ORB").
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The number of keypoints and descriptors of a feature set differ.
    #[error("inconsistent features: {keypoints} keypoints but {descriptors} descriptors")]
    InconsistentFeatures {
        /// Keypoint count.
        keypoints: usize,
        /// Descriptor count.
        descriptors: usize,
    },
    /// Two descriptor sets cannot be compared (binary vs float, or different
    /// float dimensions), or a float buffer is not a whole number of rows.
    #[error("descriptor mismatch: {0}")]
    DescriptorMismatch(String),
    /// A match refers to a keypoint that does not exist.
    #[error("match {index} refers to {side} keypoint {keypoint}, but that set has only {len} keypoints")]
    MatchOutOfRange {
        /// Index of the match in the list.
        index: usize,
        /// "query" or "train".
        side: &'static str,
        /// The keypoint index the match names.
        keypoint: u32,
        /// Number of keypoints on that side.
        len: usize,
    },
    /// A guided search got a prediction list of the wrong length.
    #[error("guided matching got {predictions} predictions for {queries} query keypoints")]
    PredictionCount {
        /// Number of predictions given.
        predictions: usize,
        /// Number of query keypoints.
        queries: usize,
    },
    /// Focal lengths must be finite and positive.
    #[error("invalid focal length fx={fx}, fy={fy}: both must be finite and positive")]
    BadFocalLength {
        /// fx.
        fx: f64,
        /// fy.
        fy: f64,
    },
    /// No extractor / matcher of that name exists.
    #[error("unknown {kind} '{name}' (known: {known})")]
    UnknownName {
        /// "extractor" or "matcher".
        kind: &'static str,
        /// The name asked for.
        name: String,
        /// The known names, comma separated.
        known: String,
    },
}

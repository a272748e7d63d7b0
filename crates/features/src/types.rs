//! The interface types shared by every extractor and matcher.

use crate::FeatureError;
use colslam_image::Image;

/// One detected keypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column in pixels of the full-resolution image (pyramid level 0), OpenCV
    /// convention: the centre of the left-most pixel column is `x = 0`.
    pub x: f32,
    /// Row in pixels of the full-resolution image, centre of the top row at
    /// `y = 0` (OpenCV convention; COLMAP's is `y + 0.5`).
    pub y: f32,
    /// Pyramid level the keypoint was detected at (0 = full resolution).
    pub octave: u8,
    /// Orientation in degrees, `[0, 360)`, measured from the +x axis towards
    /// +y (clockwise on screen, as OpenCV).
    pub angle: f32,
    /// Detector response (larger is stronger); its scale depends on the
    /// extractor and its score type.
    pub response: f32,
    /// Diameter of the described patch in level-0 pixels.
    pub size: f32,
}

/// Descriptors of a feature set, one row per keypoint.
#[derive(Debug, Clone, PartialEq)]
pub enum Descriptors {
    /// 256-bit binary descriptors (ORB). Bit `i` of the descriptor is bit
    /// `i % 64` of word `i / 64`; this is the same bit order as OpenCV's byte
    /// layout read as little-endian 64-bit words.
    Binary(Vec<[u64; 4]>),
    /// Float descriptors of `dim` values each, row-major (learned features).
    Float {
        /// Values per descriptor.
        dim: usize,
        /// `len * dim` values.
        data: Vec<f32>,
    },
}

impl Descriptors {
    /// Number of descriptors (0 for a float set with `dim == 0`).
    pub fn len(&self) -> usize {
        match self {
            Descriptors::Binary(v) => v.len(),
            Descriptors::Float { dim, data } => data.len().checked_div(*dim).unwrap_or(0),
        }
    }

    /// True if there are no descriptors.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Keypoints with one descriptor each.
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// The keypoints.
    pub keypoints: Vec<Keypoint>,
    /// Their descriptors, in the same order.
    pub descriptors: Descriptors,
}

impl Features {
    /// An empty binary feature set.
    pub fn empty_binary() -> Self {
        Self { keypoints: Vec::new(), descriptors: Descriptors::Binary(Vec::new()) }
    }

    /// Number of features.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// True if there are no features.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// Checks that there is one descriptor per keypoint and that a float
    /// buffer holds whole rows.
    pub fn validate(&self) -> Result<(), FeatureError> {
        if let Descriptors::Float { dim, data } = &self.descriptors {
            if *dim == 0 && !data.is_empty() {
                return Err(FeatureError::DescriptorMismatch("float descriptors with dim 0".into()));
            }
            if *dim != 0 && data.len() % dim != 0 {
                return Err(FeatureError::DescriptorMismatch(format!(
                    "{} float values is not a whole number of {dim}-dimensional descriptors",
                    data.len()
                )));
            }
        }
        if self.descriptors.len() != self.keypoints.len() {
            return Err(FeatureError::InconsistentFeatures {
                keypoints: self.keypoints.len(),
                descriptors: self.descriptors.len(),
            });
        }
        Ok(())
    }
}

/// Detects keypoints and computes their descriptors.
pub trait FeatureExtractor: Send + Sync {
    /// Short name, as accepted by [`crate::extractor_by_name`].
    fn name(&self) -> &str;
    /// Extracts features from an 8-bit image. Gray images are used as they
    /// are; RGB ones are converted to gray (BT.601) first.
    fn extract(&self, gray: &Image) -> Result<Features, FeatureError>;
}

/// One correspondence between a query and a train feature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// Index into the query (first) feature set.
    pub query: u32,
    /// Index into the train (second) feature set.
    pub train: u32,
    /// Descriptor distance (Hamming bits for binary descriptors, Euclidean
    /// for float ones).
    pub distance: f32,
}

/// Matches two feature sets.
pub trait Matcher: Send + Sync {
    /// Short name, as accepted by [`crate::matcher_by_name`].
    fn name(&self) -> &str;
    /// Matches `a` (query) against `b` (train). The result is sorted by query
    /// index, and each query appears at most once.
    fn match_features(&self, a: &Features, b: &Features) -> Result<Vec<Match>, FeatureError>;
    /// The matches of `a` against `b` and of `b` against `a`, as two calls
    /// of [`Matcher::match_features`] give them; a matcher that finds both in
    /// one pass overrides it.
    fn match_features_both(&self, a: &Features, b: &Features) -> Result<(Vec<Match>, Vec<Match>), FeatureError> {
        Ok((self.match_features(a, b)?, self.match_features(b, a)?))
    }
}

//! The colslam feature front end.
//!
//! * [`OrbExtractor`]: ORB features following the ORB-SLAM recipe (Mur-Artal
//!   et al., ORB-SLAM / ORB-SLAM2 `ORBextractor`; Rublee et al., ICCV 2011):
//!   an 8-level pyramid, FAST-9 with a fallback threshold, the strongest
//!   Harris corners of each level (as OpenCV's ORB; ORB-SLAM's quadtree that
//!   spreads the keypoints over the image is an option), intensity-centroid
//!   orientation and steered rBRIEF descriptors.
//! * [`NnMatcher`]: nearest-neighbour matching (Hamming for binary
//!   descriptors, Euclidean for float ones) with mutual (cross-check), ratio
//!   and distance filters, plus a guided variant that only searches near a
//!   predicted position.
//! * [`Vocabulary`], [`PlaceIndex`]: a bag of binary words trained on the
//!   run's own descriptors and an inverted index, for loop detection.
//! * [`flow_score`]: the optical-flow score the paper (section 3.2) uses for
//!   keyframe selection.
//!
//! Extractors and matchers are used through the [`FeatureExtractor`] and
//! [`Matcher`] traits and can be made by name ([`extractor_by_name`],
//! [`matcher_by_name`]) so that learned front ends (XFeat, ...) plug in
//! beside ORB.
//!
//! # Example
//! ```
//! use colslam_features::{extractor_by_name, flow_score, matcher_by_name};
//! use colslam_image::Image;
//!
//! // A synthetic textured frame and the same frame shifted 8 px right.
//! let texture = |x: usize, y: usize| (((x / 9) * 37 + (y / 7) * 91 + (x * y) % 13) % 251) as u8;
//! let a = Image::from_vec(320, 240, 1, (0..320 * 240usize).map(|i| texture(i % 320, i / 320)).collect())?;
//! let b = Image::from_vec(320, 240, 1, (0..320 * 240usize).map(|i| texture((i % 320).saturating_sub(8), i / 320)).collect())?;
//!
//! let orb = extractor_by_name("orb", &Default::default())?;
//! let nn = matcher_by_name("nn", &Default::default())?;
//! let (fa, fb) = (orb.extract(&a)?, orb.extract(&b)?);
//! let matches = nn.match_features(&fa, &fb)?;
//! let flow = flow_score(&fa.keypoints, &fb.keypoints, &matches, 500.0, 500.0)?;
//! assert!(flow.num_matches > 50);
//! assert!((flow.median_x - 8.0 / 500.0).abs() < 1.0 / 500.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # Coordinate convention
//! Keypoint coordinates follow OpenCV: the centre of the top-left pixel is
//! `(0, 0)`, x to the right, y down, in pixels of the full-resolution input
//! image (pyramid level 0). COLMAP puts that centre at `(0.5, 0.5)`; the
//! pipeline adds 0.5 when it hands keypoints to the reconstruction.

mod error;
mod fast;
pub mod flow;
pub mod matcher;
pub mod orb;
mod orb_pattern;
mod pyramid;
mod registry;
mod simd;
mod subpixel;
mod types;
pub mod vocabulary;

pub use error::FeatureError;
pub use flow::{FlowScore, flow_score};
pub use matcher::{NnMatcher, NnMatcherOptions, hamming_distance};
pub use orb::{FallbackMode, OrbExtractor, OrbLevelReport, OrbOptions, OrbReport, ScoreType, Selection};
pub use registry::{
    EXTRACTOR_NAMES, ExtractorOptions, MATCHER_NAMES, MatcherOptions, extractor_by_name, matcher_by_name,
};
pub use types::{Descriptors, FeatureExtractor, Features, Keypoint, Match, Matcher};
pub use vocabulary::{BowVector, PlaceIndex, Vocabulary, VocabularyOptions, bow_score};

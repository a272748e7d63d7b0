//! Frame identity and the per-frame records of a run: one [`FrameId`]
//! (index, timestamp, name) reused by the frontend's [`FrameData`], the
//! records of non-keyframes and the poses of localised frames.

use colslam_camera::Camera;
use colslam_features::{Features, Match};
use colslam_geometry::{Rigid3, Vec2};
use colslam_scene::ImageId;
use serde::Serialize;

/// Which frame of the input: its index (after skip), timestamp and name.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameId {
    /// Frame index (after skip).
    pub index: usize,
    /// Timestamp, seconds.
    pub timestamp: f64,
    /// Name (the image name in the model).
    pub name: String,
}

impl FrameId {
    /// The identity of a decoded frame.
    pub fn of(frame: &colslam_io::Frame) -> Self {
        Self { index: frame.index, timestamp: frame.timestamp, name: frame.name.clone() }
    }
}

/// A frame's features, ready for mapping.
#[derive(Debug, Clone)]
pub struct FrameData {
    /// Which frame.
    pub id: FrameId,
    /// Keypoints and descriptors (keypoints that cannot be undistorted are
    /// dropped, so every index below is valid).
    pub features: Features,
    /// Keypoint positions in COLMAP's pixel convention (centre of the
    /// top-left pixel at (0.5, 0.5)).
    pub pixels: Vec<Vec2>,
    /// Undistorted normalised image-plane coordinates.
    pub normalized: Vec<Vec2>,
    /// RGB colour at each keypoint.
    pub colors: Vec<[u8; 3]>,
}

impl FrameData {
    /// Recomputes the normalised coordinates from the pixels with `camera`
    /// (COLMAP pixel convention), as the map's camera changes when its
    /// intrinsics are refined; a keypoint the camera cannot undistort keeps
    /// its value.
    pub fn normalize_with(&mut self, camera: &Camera) {
        for (n, px) in self.normalized.iter_mut().zip(&self.pixels) {
            if let Some(v) = undistort(camera, px) {
                *n = v;
            }
        }
    }

    /// Frame index (after skip).
    pub fn index(&self) -> usize {
        self.id.index
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    /// True without keypoints.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }
}

/// One 2D observation of a non-keyframe, linked to a keyframe keypoint.
///
/// Compact (20 bytes), since every non-keyframe's record is kept until the
/// final localisation (in memory or spilled to disk, `crate::records`): the position is kept as the extractor's `f32`
/// keypoint and the normalised coordinates are derived again from it with
/// the map's camera when they are used ([`FrameRecord::normalized`]), so
/// they always follow the final camera and are not stored twice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordObs {
    /// Keypoint index in the frame.
    pub frame_kp: u32,
    /// Keypoint position in OpenCV's pixel convention, as extracted.
    keypoint: [f32; 2],
    /// The keyframe it matched.
    pub keyframe: ImageId,
    /// The keyframe keypoint it matched.
    pub keyframe_kp: u32,
}

impl RecordObs {
    /// An observation at `pixel` (COLMAP convention). The frontend's pixels
    /// are an `f32` keypoint plus 0.5 computed in `f64`
    /// ([`crate::frontend`]), so subtracting 0.5 and narrowing to `f32` gives
    /// the keypoint back exactly and [`Self::pixel`] the same pixel.
    pub fn new(frame_kp: u32, pixel: Vec2, keyframe: ImageId, keyframe_kp: u32) -> Self {
        Self { frame_kp, keypoint: [(pixel.x - 0.5) as f32, (pixel.y - 0.5) as f32], keyframe, keyframe_kp }
    }

    /// An observation at the extractor's keypoint `keypoint` (OpenCV
    /// convention), as [`Self::keypoint`] gives it back.
    pub(crate) fn from_keypoint(frame_kp: u32, keypoint: [f32; 2], keyframe: ImageId, keyframe_kp: u32) -> Self {
        Self { frame_kp, keypoint, keyframe, keyframe_kp }
    }

    /// The extractor's keypoint, OpenCV's pixel convention.
    pub(crate) fn keypoint(&self) -> [f32; 2] {
        self.keypoint
    }

    /// The same observation linked to keypoint `keyframe_kp` of `keyframe`
    /// instead (the keyframe it matched was culled).
    pub fn relinked(&self, keyframe: ImageId, keyframe_kp: u32) -> Self {
        Self { keyframe, keyframe_kp, ..*self }
    }

    /// Its position, pixels (COLMAP convention).
    pub fn pixel(&self) -> Vec2 {
        Vec2::new(f64::from(self.keypoint[0]) + 0.5, f64::from(self.keypoint[1]) + 0.5)
    }
}

/// A non-keyframe to localise against the final map.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    /// Which frame.
    pub frame: FrameId,
    /// Matches to keyframes.
    pub obs: Vec<RecordObs>,
    /// Rolling-shutter compensated normalised coordinates, one per
    /// observation, once compensation ran (`Mapper::compensate_rolling_shutter`);
    /// empty before, when they are derived from the pixels.
    pub compensated: Vec<Vec2>,
    /// Became a keyframe later (not localised from this record).
    pub promoted: bool,
}

impl FrameRecord {
    /// A record with no observations yet.
    pub fn new(data: &FrameData) -> Self {
        Self { frame: data.id.clone(), obs: Vec::new(), compensated: Vec::new(), promoted: false }
    }

    /// Adds the matches of `data` (query) to keyframe `kf` (train).
    pub fn add_matches(&mut self, data: &FrameData, kf: ImageId, matches: &[Match]) {
        for m in matches {
            if let Some(px) = data.pixels.get(m.query as usize) {
                self.obs.push(RecordObs::new(m.query, *px, kf, m.train));
            }
        }
    }

    /// The normalised coordinates of observation `k` as localisation uses
    /// them: compensated for rolling shutter once that ran, else measured
    /// (undistorted from its pixel with `camera`); `None` when the camera
    /// cannot undistort it.
    pub fn normalized(&self, k: usize, camera: &Camera) -> Option<Vec2> {
        match self.compensated.get(k) {
            Some(n) => n.iter().all(|v| v.is_finite()).then_some(*n),
            None => undistort(camera, &self.obs.get(k)?.pixel()),
        }
    }

    /// Appends the observations of another record of the same frame.
    pub fn extend(&mut self, other: &FrameRecord) {
        // Compensation runs on whole maps after merging: both records are
        // compensated or neither is; a mix falls back to the pixels.
        if self.compensated.len() == self.obs.len() && other.compensated.len() == other.obs.len() {
            self.compensated.extend_from_slice(&other.compensated);
        } else {
            self.compensated.clear();
        }
        self.obs.extend_from_slice(&other.obs);
        self.promoted |= other.promoted;
    }
}

/// The normalised coordinates of a pixel, when finite.
pub(crate) fn undistort(camera: &Camera, px: &Vec2) -> Option<Vec2> {
    camera.cam_from_img(px).filter(|n| n.iter().all(|v| v.is_finite()))
}

/// A localised frame.
#[derive(Debug, Clone)]
pub struct FramePose {
    /// Which frame.
    pub frame: FrameId,
    /// Pose.
    pub cam_from_world: Rigid3,
    /// Whether it is a keyframe of the map.
    pub keyframe: bool,
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use colslam_features::{Descriptors, Keypoint};

    pub(crate) fn frame_data(index: usize, normalized: Vec<Vec2>) -> FrameData {
        let n = normalized.len();
        let keypoints =
            (0..n).map(|_| Keypoint { x: 0.0, y: 0.0, octave: 0, angle: 0.0, response: 0.0, size: 31.0 }).collect();
        FrameData {
            id: FrameId { index, timestamp: index as f64 / 30.0, name: format!("{index:06}.png") },
            features: Features { keypoints, descriptors: Descriptors::Binary(vec![[0; 4]; n]) },
            pixels: normalized.clone(),
            normalized,
            colors: vec![[0; 3]; n],
        }
    }

    #[test]
    fn records_keep_only_matches_of_existing_keypoints() {
        let data = frame_data(3, vec![Vec2::new(0.1, 0.2), Vec2::new(-0.3, 0.4)]);
        let mut r = FrameRecord::new(&data);
        assert_eq!(r.frame.index, 3);
        let matches = [Match { query: 1, train: 7, distance: 0.0 }, Match { query: 5, train: 8, distance: 0.0 }];
        r.add_matches(&data, ImageId(2), &matches);
        assert_eq!(r.obs.len(), 1, "the match of a missing keypoint is dropped");
        let o = r.obs[0];
        assert_eq!((o.frame_kp, o.keyframe, o.keyframe_kp), (1, ImageId(2), 7));
        assert_eq!(o.pixel(), Vec2::new(f64::from(-0.8f32) + 0.5, f64::from(-0.1f32) + 0.5));
        assert!(!r.promoted);
    }

    #[test]
    fn record_pixels_round_trip_exactly_and_are_compact() {
        // The frontend's pixels: an f32 keypoint + 0.5 in f64.
        for (x, y) in [(0.0f32, 0.0f32), (17.123_457, 639.999), (1234.567, 0.001), (3.0e-3, 8191.75)] {
            let px = Vec2::new(f64::from(x) + 0.5, f64::from(y) + 0.5);
            assert_eq!(RecordObs::new(0, px, ImageId(1), 0).pixel(), px);
        }
        assert_eq!(std::mem::size_of::<RecordObs>(), 20);
    }

    #[test]
    fn record_normalised_coordinates_follow_the_camera_until_compensated() {
        let cam = |f: f64| Camera::pinhole(640, 480, f, f, 320.0, 240.0);
        let mut data = frame_data(0, vec![Vec2::new(420.5, 240.5)]);
        data.pixels = vec![Vec2::new(420.5, 240.5)];
        let mut r = FrameRecord::new(&data);
        r.add_matches(&data, ImageId(1), &[Match { query: 0, train: 0, distance: 0.0 }]);
        assert!((r.normalized(0, &cam(500.0)).unwrap().x - 0.201).abs() < 1e-12);
        assert!((r.normalized(0, &cam(1000.0)).unwrap().x - 0.1005).abs() < 1e-12);
        r.compensated = vec![Vec2::new(0.3, 0.0)];
        assert_eq!(r.normalized(0, &cam(500.0)), Some(Vec2::new(0.3, 0.0)));
        assert_eq!(r.normalized(1, &cam(500.0)), None);
    }
}

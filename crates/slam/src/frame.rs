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
#[derive(Debug, Clone, Copy)]
pub struct RecordObs {
    /// Keypoint index in the frame.
    pub frame_kp: u32,
    /// Its position, pixels (COLMAP convention).
    pub pixel: Vec2,
    /// Its normalised coordinates (rolling-shutter compensated when that is
    /// on).
    pub normalized: Vec2,
    /// Its normalised coordinates as measured.
    pub measured: Vec2,
    /// The keyframe it matched.
    pub keyframe: ImageId,
    /// The keyframe keypoint it matched.
    pub keyframe_kp: u32,
}

/// A non-keyframe to localise against the final map.
#[derive(Debug, Clone)]
pub struct FrameRecord {
    /// Which frame.
    pub frame: FrameId,
    /// Matches to keyframes.
    pub obs: Vec<RecordObs>,
    /// Became a keyframe later (not localised from this record).
    pub promoted: bool,
}

impl FrameRecord {
    /// A record with no observations yet.
    pub fn new(data: &FrameData) -> Self {
        Self { frame: data.id.clone(), obs: Vec::new(), promoted: false }
    }

    /// Adds the matches of `data` (query) to keyframe `kf` (train).
    pub fn add_matches(&mut self, data: &FrameData, kf: ImageId, matches: &[Match]) {
        for m in matches {
            if let (Some(n), Some(px)) = (data.normalized.get(m.query as usize), data.pixels.get(m.query as usize)) {
                self.obs.push(RecordObs {
                    frame_kp: m.query,
                    pixel: *px,
                    normalized: *n,
                    measured: *n,
                    keyframe: kf,
                    keyframe_kp: m.train,
                });
            }
        }
    }
}

impl FrameRecord {
    /// Recomputes the observations' normalised coordinates (as measured)
    /// from their pixels with `camera` ([`FrameData::normalize_with`]).
    pub fn normalize_with(&mut self, camera: &Camera) {
        for o in &mut self.obs {
            if let Some(v) = undistort(camera, &o.pixel) {
                o.normalized = v;
                o.measured = v;
            }
        }
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
        assert_eq!(o.normalized, o.measured);
        assert_eq!(o.normalized, Vec2::new(-0.3, 0.4));
        assert!(!r.promoted);
    }
}

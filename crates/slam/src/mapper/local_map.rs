//! Tracking a new keyframe against the local map (ORB-SLAM's `TrackLocalMap`
//! with `ORBmatcher::SearchByProjection`, Mur-Artal and Tardós 2017): after
//! the pose from the matches to the recent keyframes, the 3D points of the
//! keyframes that share points with the new one (and of their covisible
//! neighbours) are projected into it and matched by descriptor in a small
//! window around the projection. The pose is then estimated again from all
//! 2D-3D correspondences, and their tracks continue into the new keyframe.
//!
//! Why: matching a keyframe only to the last few keyframes by descriptor
//! links the chain of keyframes by short tracks (most points are seen by two
//! or three keyframes), so each keyframe's scale is tied to its neighbours'
//! alone and forward motion drifts in scale. A point re-found over many
//! keyframes ties all their scales together.

use super::register::Correspondences;
use super::state::{Mapper, ORB_LEVEL_SCALE, level_scale};
use crate::frame::FrameData;
use crate::options::{
    LOCAL_MAP_MAX_HAMMING, LOCAL_MAP_MIN_VIEW_COS, LOCAL_MAP_RADIUS_PX, LOCAL_MAP_RATIO, SlamOptions,
};
use colslam_camera::Camera;
use colslam_estimators::{AbsolutePoseReport, estimate_absolute_pose};
use colslam_features::{Descriptors, Keypoint, hamming_distance};
use colslam_geometry::{Rigid3, Vec3};
use colslam_scene::{ImageId, Point3DId};
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

/// A local-map point projected into the new keyframe.
#[derive(Debug, Clone, Copy)]
struct Projected {
    id: Point3DId,
    /// Predicted keypoint position, OpenCV pixel convention (as keypoints).
    x: f32,
    y: f32,
    /// Predicted pyramid level.
    level: u8,
    /// Search radius, pixels.
    radius: f32,
    /// The point's representative descriptor.
    descriptor: [u64; 4],
}

/// The new keyframe's keypoints binned in square cells, for the window
/// searches.
struct KeypointGrid {
    cell: f32,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl KeypointGrid {
    fn new(keypoints: &[Keypoint], width: f32, height: f32, cell: f32) -> Self {
        let cols = ((width / cell).ceil() as usize).max(1);
        let rows = ((height / cell).ceil() as usize).max(1);
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, k) in keypoints.iter().enumerate() {
            let (c, r) = ((k.x / cell).floor(), (k.y / cell).floor());
            if c >= 0.0 && r >= 0.0 && (c as usize) < cols && (r as usize) < rows {
                cells[r as usize * cols + c as usize].push(i as u32);
            }
        }
        Self { cell, cols, rows, cells }
    }

    /// Calls `f` with every keypoint index in the cells the window touches.
    fn for_each_near(&self, x: f32, y: f32, radius: f32, mut f: impl FnMut(u32)) {
        let lo = |v: f32| ((v - radius) / self.cell).floor().max(0.0) as usize;
        let hi = |v: f32, n: usize| (((v + radius) / self.cell).floor().max(0.0) as usize).min(n - 1);
        for r in lo(y)..=hi(y, self.rows) {
            for c in lo(x)..=hi(x, self.cols) {
                self.cells[r * self.cols + c].iter().for_each(|&i| f(i));
            }
        }
    }
}

impl Mapper {
    /// Tracks the new keyframe `data` against the local map from the pose of
    /// its matches to recent keyframes. Returns the correspondences (the
    /// first pose's inliers and the points found by projection) and the pose
    /// estimated from all of them; the first ones unchanged when the second
    /// estimate fails or keeps fewer inliers.
    pub(super) fn track_local_map(
        &self,
        data: &FrameData,
        corr: Correspondences,
        pose: AbsolutePoseReport,
        focal: f64,
        seed: u64,
        opts: &SlamOptions,
    ) -> (Correspondences, AbsolutePoseReport) {
        let Descriptors::Binary(desc) = &data.features.descriptors else { return (corr, pose) };
        let Ok(camera) = self.camera() else { return (corr, pose) };
        let mut tracked = Correspondences::default();
        let kept = corr.points2d.iter().zip(&corr.points3d).zip(&corr.ids).zip(&pose.inlier_mask);
        for (((p2, p3), id), _) in kept.filter(|(_, inlier)| **inlier) {
            tracked.points2d.push(*p2);
            tracked.points3d.push(*p3);
            tracked.ids.push(*id);
        }
        let seeds: Vec<Point3DId> = tracked.ids.iter().map(|(_, p)| *p).collect();
        let keyframes = self.local_keyframes(&seeds, opts.mapper.local_map_keyframes);
        let used_points: HashSet<Point3DId> = seeds.iter().copied().collect();
        let used_kps: HashSet<u32> = tracked.ids.iter().map(|(q, _)| *q).collect();
        let projected = self.project_local_map(&keyframes, &used_points, &pose.cam_from_world, camera, data);
        let found = search_by_projection(&projected, data, desc, &used_kps, camera);
        let matched = found.len();
        for (q, pid) in found {
            let (Some(n), Some(p)) = (data.normalized.get(q as usize), self.rec.point3d(pid)) else { continue };
            tracked.points2d.push(*n);
            tracked.points3d.push(p.xyz);
            tracked.ids.push((q, pid));
        }
        let pose_opts = opts.mapper.absolute_pose(focal, seed);
        let again = estimate_absolute_pose(&tracked.points2d, &tracked.points3d, &pose_opts)
            .ok()
            .filter(|again| again.num_inliers >= pose.num_inliers);
        tracing::debug!(
            "frame {}: local map of {} keyframes, {} points projected, {matched} matched, PnP inliers {} -> {}",
            data.index(),
            keyframes.len(),
            projected.len(),
            pose.num_inliers,
            again.as_ref().map_or(pose.num_inliers, |a| a.num_inliers)
        );
        match again {
            Some(again) => (tracked, again),
            None => (corr, pose),
        }
    }

    /// The local keyframes (ORB-SLAM's K1 and K2): the images observing the
    /// `seeds` points, most shared points first, then the images sharing
    /// points with those, up to `max` in all.
    fn local_keyframes(&self, seeds: &[Point3DId], max: usize) -> Vec<ImageId> {
        let first = self.observers(seeds.iter().copied(), &HashSet::new());
        let mut out: Vec<ImageId> = first.iter().map(|(id, _)| *id).take(max).collect();
        if out.len() < max {
            let ring_points = out
                .iter()
                .filter_map(|id| self.rec.image(*id))
                .flat_map(|img| img.points2d.iter().filter_map(|p| p.point3d_id));
            let known: HashSet<ImageId> = out.iter().copied().collect();
            let second = self.observers(ring_points, &known);
            out.extend(second.iter().map(|(id, _)| *id).take(max - out.len()));
        }
        out
    }

    /// The registered images observing `points` outside `exclude`, with how
    /// many of the points each observes, most first (ties: lower id).
    fn observers(&self, points: impl Iterator<Item = Point3DId>, exclude: &HashSet<ImageId>) -> Vec<(ImageId, usize)> {
        let mut count: BTreeMap<ImageId, usize> = BTreeMap::new();
        for pid in points {
            let Some(p) = self.rec.point3d(pid) else { continue };
            for e in &p.track {
                if !exclude.contains(&e.image_id) {
                    *count.entry(e.image_id).or_default() += 1;
                }
            }
        }
        let mut v: Vec<(ImageId, usize)> =
            count.into_iter().filter(|(id, _)| self.rec.image(*id).is_some_and(|i| i.registered)).collect();
        v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        v
    }

    /// The points of `keyframes` outside `exclude` that project into the
    /// new keyframe at `pose` inside the image, seen from a direction within
    /// [`LOCAL_MAP_MIN_VIEW_COS`] of their mean viewing direction and at a
    /// distance their descriptor's scale covers.
    fn project_local_map(
        &self,
        keyframes: &[ImageId],
        exclude: &HashSet<Point3DId>,
        pose: &Rigid3,
        camera: &Camera,
        data: &FrameData,
    ) -> Vec<Projected> {
        let by_image: HashMap<ImageId, usize> =
            self.keyframes.iter().enumerate().map(|(k, kf)| (kf.image_id, k)).collect();
        let mut points: BTreeSet<Point3DId> = BTreeSet::new();
        for img in keyframes.iter().filter_map(|id| self.rec.image(*id)) {
            points.extend(img.points2d.iter().filter_map(|p| p.point3d_id).filter(|p| !exclude.contains(p)));
        }
        let levels = data.features.keypoints.iter().map(|k| k.octave).max().unwrap_or(0);
        points.into_iter().filter_map(|pid| self.project_point(pid, &by_image, pose, camera, levels)).collect()
    }

    /// One point's projection and search window, or `None` when the new
    /// keyframe cannot see it (ORB-SLAM's `isInFrustum`).
    fn project_point(
        &self,
        pid: Point3DId,
        by_image: &HashMap<ImageId, usize>,
        pose: &Rigid3,
        camera: &Camera,
        max_level: u8,
    ) -> Option<Projected> {
        let p = self.rec.point3d(pid)?;
        let in_cam = pose.transform_point(&p.xyz);
        let px = camera.img_from_cam(&in_cam)?;
        // COLMAP pixels to the keypoints' OpenCV convention.
        let (x, y) = ((px.x - 0.5) as f32, (px.y - 0.5) as f32);
        if !(x >= 0.0 && y >= 0.0 && x < camera.width as f32 && y < camera.height as f32) {
            return None;
        }
        let ray = p.xyz - pose.center();
        let dist = ray.norm();
        // The representative observation (ORB-SLAM's distinctive
        // descriptor: least median distance to the others) and the mean
        // viewing direction.
        let mut obs: Vec<([u64; 4], u8, f64)> = Vec::with_capacity(p.track.len());
        let mut mean_dir = Vec3::zeros();
        for e in &p.track {
            let (Some(&k), Some(img)) = (by_image.get(&e.image_id), self.rec.image(e.image_id)) else { continue };
            let data = &self.keyframes[k].data;
            let (Descriptors::Binary(d), Some(kp)) =
                (&data.features.descriptors, data.features.keypoints.get(e.point2d_idx as usize))
            else {
                continue;
            };
            let Some(desc) = d.get(e.point2d_idx as usize) else { continue };
            let v = p.xyz - img.cam_from_world.center();
            mean_dir += v.normalize();
            obs.push((*desc, kp.octave, v.norm()));
        }
        let view_cos = mean_dir.normalize().dot(&ray) / dist;
        if obs.is_empty() || view_cos.is_nan() || view_cos < LOCAL_MAP_MIN_VIEW_COS {
            return None;
        }
        let (descriptor, ref_level, ref_dist) = obs[medoid(&obs)];
        let level = predicted_level(ref_level, ref_dist, dist, max_level)?;
        // A point seen head-on is predicted better than one seen askew.
        let base = if view_cos > 0.998 { 0.625 * LOCAL_MAP_RADIUS_PX } else { LOCAL_MAP_RADIUS_PX };
        let radius = (base * level_scale(level)) as f32;
        Some(Projected { id: pid, x, y, level, radius, descriptor })
    }
}

/// Index of the observation whose descriptor has the least median Hamming
/// distance to the others' (ties: the first).
fn medoid(obs: &[([u64; 4], u8, f64)]) -> usize {
    let mut best = (u32::MAX, 0);
    for (i, a) in obs.iter().enumerate() {
        let mut d: Vec<u32> = obs.iter().map(|b| hamming_distance(&a.0, &b.0)).collect();
        d.sort_unstable();
        let median = d[(d.len() - 1) / 2];
        if median < best.0 {
            best = (median, i);
        }
    }
    best.1
}

/// The pyramid level a point seen at `ref_level` from `ref_dist` should be
/// detected at from `dist` (ORB-SLAM's `PredictScale`), or `None` when the
/// distance leaves the range the pyramid covers.
fn predicted_level(ref_level: u8, ref_dist: f64, dist: f64, max_level: u8) -> Option<u8> {
    let s = f64::from(ORB_LEVEL_SCALE);
    let max_dist = ref_dist * level_scale(ref_level);
    let min_dist = max_dist / level_scale(max_level);
    if !(dist >= 0.8 * min_dist && dist <= 1.2 * max_dist) {
        return None;
    }
    let level = ((max_dist / dist).ln() / s.ln()).ceil();
    Some(level.clamp(0.0, f64::from(max_level)) as u8)
}

/// Matches the projected points to the new keyframe's free keypoints in
/// their windows (ORB-SLAM's `SearchByProjection`: keypoints at the predicted
/// level or one below, Hamming distance at most [`LOCAL_MAP_MAX_HAMMING`],
/// ratio [`LOCAL_MAP_RATIO`] to the second best when both are at one level),
/// one point per keypoint (the closest; ties: the first point). Returns
/// (keypoint, point) pairs in point order.
fn search_by_projection(
    projected: &[Projected],
    data: &FrameData,
    desc: &[[u64; 4]],
    used_kps: &HashSet<u32>,
    camera: &Camera,
) -> Vec<(u32, Point3DId)> {
    let kps = &data.features.keypoints;
    let max_radius = projected.iter().map(|p| p.radius).fold(1.0, f32::max);
    let grid = KeypointGrid::new(kps, camera.width as f32, camera.height as f32, max_radius.max(8.0));
    let mut owner: HashMap<u32, (u32, usize)> = HashMap::new();
    for (n, p) in projected.iter().enumerate() {
        let mut best = (u32::MAX, u32::MAX, 0u8);
        let mut second = (u32::MAX, 0u8);
        grid.for_each_near(p.x, p.y, p.radius, |i| {
            let (Some(k), Some(d)) = (kps.get(i as usize), desc.get(i as usize)) else { return };
            let (dx, dy) = (k.x - p.x, k.y - p.y);
            let level_ok = k.octave + 1 >= p.level && k.octave <= p.level;
            if used_kps.contains(&i) || !level_ok || dx * dx + dy * dy > p.radius * p.radius {
                return;
            }
            let h = hamming_distance(&p.descriptor, d);
            if h < best.0 {
                second = (best.0, best.2);
                best = (h, i, k.octave);
            } else if h < second.0 {
                second = (h, k.octave);
            }
        });
        let (h, i, level) = best;
        if h > LOCAL_MAP_MAX_HAMMING
            || (second.1 == level && second.0 != u32::MAX && h as f32 > LOCAL_MAP_RATIO * second.0 as f32)
        {
            continue;
        }
        let entry = owner.entry(i).or_insert((h, n));
        if h < entry.0 {
            *entry = (h, n);
        }
    }
    let mut out: Vec<(usize, u32)> = owner.into_iter().map(|(i, (_, n))| (n, i)).collect();
    out.sort_unstable();
    out.into_iter().map(|(n, i)| (i, projected[n].id)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_level_follows_the_distance_within_the_pyramid() {
        // Seen at level 2 from 10: level 0 covers up to 10 * 1.2^2 = 14.4.
        assert_eq!(predicted_level(2, 10.0, 10.0, 7), Some(2));
        assert_eq!(predicted_level(2, 10.0, 14.0, 7), Some(1), "farther: finer level");
        assert_eq!(predicted_level(2, 10.0, 6.0, 7), Some(5), "nearer: coarser level");
        assert_eq!(predicted_level(2, 10.0, 18.0, 7), None, "beyond level 0's range");
        assert_eq!(predicted_level(0, 10.0, 1.0, 7), None, "nearer than the top level covers");
        assert_eq!(predicted_level(0, 10.0, 9.0, 0), Some(0), "one level: 0.8 to 1.2 times the distance");
        assert_eq!(predicted_level(0, 10.0, 7.9, 0), None);
    }

    #[test]
    fn the_representative_descriptor_is_the_medoid() {
        let d = |w: u64| ([w, 0, 0, 0], 0u8, 1.0);
        // Median distances to the set: 5, 2, 1, 2, 5.
        assert_eq!(medoid(&[d(0b1111_0000), d(0b0001), d(0b0011), d(0b0111), d(0b1111_1111)]), 2);
        // Ties go to the first.
        assert_eq!(medoid(&[d(0b0), d(0b1), d(0b11), d(0b1111_1111)]), 0);
        assert_eq!(medoid(&[d(5)]), 0);
    }
}

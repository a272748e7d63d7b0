//! The incremental triangulator: creates new 3D points from the
//! correspondences of a newly registered image, continues existing tracks,
//! merges tracks that meet, completes tracks with further observations and
//! retriangulates under-reconstructed image pairs.
//!
//! After COLMAP's `src/colmap/sfm/incremental_triangulator.{h,cc}` (Schönberger
//! & Frahm, "Structure-from-Motion Revisited", CVPR 2016, section 4.5); the
//! thresholds and their defaults follow COLMAP's. Free functions over a
//! `Reconstruction` and a `CorrespondenceGraph`, so the caller owns both.

use crate::{Correspondence, CorrespondenceGraph, SfmError};
use colslam_estimators::triangulation::{TriangulationOptions, triangulate_multiview};
use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_scene::{ImageId, Point3DId, Reconstruction, TrackElement};
use std::collections::{BTreeSet, HashSet};
use std::hash::{BuildHasherDefault, Hasher};

/// A multiply-rotate hasher (the Fx hash of rustc) for the integer-id sets
/// on the track-merging path, where SipHash's DoS resistance buys nothing
/// and costs most of the lookup.
#[derive(Default, Clone, Copy)]
struct FxHasher(u64);

impl Hasher for FxHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.write_u64(u64::from(v));
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

type FastHash = BuildHasherDefault<FxHasher>;

/// Colour given to new points; the pipeline recolours points from the
/// keyframes' pixels.
pub const DEFAULT_POINT_COLOR: [u8; 3] = [128, 128, 128];

/// Views considered when searching for the best pair to start a new track:
/// bounds the quadratic pair search for long correspondence chains.
const MAX_CREATE_VIEWS: usize = 12;

/// Options of the triangulator (COLMAP's `IncrementalTriangulator::Options`).
#[derive(Debug, Clone, PartialEq)]
pub struct TriangulatorOptions {
    /// Hops through the correspondence graph when looking for correspondences
    /// of a keypoint (default 1).
    pub max_transitivity: usize,
    /// Maximum angular error (degrees) between a viewing ray and a new point
    /// for the view to join it (default 2).
    pub create_max_angle_error_deg: f64,
    /// Maximum angular error (degrees) to continue an existing track (default 2).
    pub continue_max_angle_error_deg: f64,
    /// Maximum reprojection error (px) of every observation of two merged
    /// tracks (default 4).
    pub merge_max_reproj_error_px: f64,
    /// Maximum reprojection error (px) to add an observation when completing
    /// a track (default 4).
    pub complete_max_reproj_error_px: f64,
    /// Hops through the correspondence graph when completing tracks (default 5).
    pub complete_max_transitivity: usize,
    /// Maximum angular error (degrees) when retriangulating (default 5).
    pub re_max_angle_error_deg: f64,
    /// Image pairs whose share of triangulated correspondences is below this
    /// are retriangulated (default 0.2).
    pub re_min_ratio: f64,
    /// Retriangulation attempts per image pair (default 1).
    pub re_max_trials: usize,
    /// Minimum triangulation angle (degrees) of a new point (default 1.5).
    pub min_angle_deg: f64,
    /// Skip keypoints seen in exactly two images of the graph (COLMAP's
    /// default is true for unordered photo collections; a sequential pipeline
    /// matches each keyframe to a few previous ones only, so many valid
    /// points are two-view when first seen: default false).
    pub ignore_two_view_tracks: bool,
}

impl Default for TriangulatorOptions {
    fn default() -> Self {
        Self {
            max_transitivity: 1,
            create_max_angle_error_deg: 2.0,
            continue_max_angle_error_deg: 2.0,
            merge_max_reproj_error_px: 4.0,
            complete_max_reproj_error_px: 4.0,
            complete_max_transitivity: 5,
            re_max_angle_error_deg: 5.0,
            re_min_ratio: 0.2,
            re_max_trials: 1,
            min_angle_deg: 1.5,
            ignore_two_view_tracks: false,
        }
    }
}

impl TriangulatorOptions {
    /// Checks every option's range.
    pub fn validate(&self) -> Result<(), SfmError> {
        let positive = [
            ("create_max_angle_error_deg", self.create_max_angle_error_deg),
            ("continue_max_angle_error_deg", self.continue_max_angle_error_deg),
            ("merge_max_reproj_error_px", self.merge_max_reproj_error_px),
            ("complete_max_reproj_error_px", self.complete_max_reproj_error_px),
            ("re_max_angle_error_deg", self.re_max_angle_error_deg),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return Err(SfmError::InvalidOption { name, value: v.to_string(), reason: "must be positive" });
            }
        }
        if !(0.0..=1.0).contains(&self.re_min_ratio) {
            return Err(SfmError::InvalidOption {
                name: "re_min_ratio",
                value: self.re_min_ratio.to_string(),
                reason: "must lie in [0, 1]",
            });
        }
        if !(self.min_angle_deg >= 0.0 && self.min_angle_deg < 180.0) {
            return Err(SfmError::InvalidOption {
                name: "min_angle_deg",
                value: self.min_angle_deg.to_string(),
                reason: "must lie in [0, 180)",
            });
        }
        Ok(())
    }
}

/// What a triangulation step changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TriangulationReport {
    /// New 3D points.
    pub created: usize,
    /// Observations added to existing tracks (continue and complete).
    pub continued: usize,
    /// Track merges.
    pub merged: usize,
}

impl TriangulationReport {
    /// Observations added or points created, in total.
    pub fn total(&self) -> usize {
        self.created + self.continued + self.merged
    }
}

impl std::ops::AddAssign for TriangulationReport {
    fn add_assign(&mut self, o: Self) {
        self.created += o.created;
        self.continued += o.continued;
        self.merged += o.merged;
    }
}

/// A keypoint of a registered image, with what triangulation needs.
#[derive(Debug, Clone, Copy)]
struct View {
    el: TrackElement,
    pose: Rigid3,
    /// Normalised image-plane coordinates (undistorted).
    normalized: Vec2,
    /// Unit viewing ray in the camera frame.
    ray: Vec3,
    point3d: Option<Point3DId>,
}

fn view_of(rec: &Reconstruction, el: TrackElement) -> Option<View> {
    let img = rec.image(el.image_id)?;
    if !img.registered {
        return None;
    }
    let cam = rec.camera(img.camera_id)?;
    let kp = img.points2d.get(el.point2d_idx as usize)?;
    let normalized = cam.camera.cam_from_img(&kp.xy)?;
    let ray = Vec3::new(normalized.x, normalized.y, 1.0).normalize();
    Some(View { el, pose: img.cam_from_world, normalized, ray, point3d: kp.point3d_id })
}

/// Angle (radians) between a view's ray and the direction to a world point;
/// pi for a point behind the camera.
fn angular_error(view: &View, xyz: &Vec3) -> f64 {
    let p = view.pose.transform_point(xyz);
    let n = p.norm();
    if p.z <= 0.0 || n == 0.0 {
        return std::f64::consts::PI;
    }
    (view.ray.dot(&p) / n).clamp(-1.0, 1.0).acos()
}

fn reprojection_error_px(rec: &Reconstruction, el: TrackElement, xyz: &Vec3) -> f64 {
    let Some(img) = rec.image(el.image_id) else { return f64::INFINITY };
    let Some(cam) = rec.camera(img.camera_id) else { return f64::INFINITY };
    let Some(kp) = img.points2d.get(el.point2d_idx as usize) else { return f64::INFINITY };
    cam.camera.img_from_cam(&img.cam_from_world.transform_point(xyz)).map_or(f64::INFINITY, |px| (px - kp.xy).norm())
}

/// Registered-image correspondences of a keypoint (up to `transitivity` hops).
fn find_views(
    rec: &Reconstruction,
    graph: &CorrespondenceGraph,
    image_id: ImageId,
    point2d_idx: u32,
    transitivity: usize,
) -> Vec<View> {
    graph
        .transitive_correspondences(image_id, point2d_idx, transitivity)
        .into_iter()
        .filter_map(|c: Correspondence| view_of(rec, TrackElement::new(c.image_id, c.point2d_idx)))
        .collect()
}

/// Triangulates the keypoints of a newly registered image: continues tracks
/// of its correspondences and creates new points from those without one
/// (COLMAP's `TriangulateImage`).
pub fn triangulate_image(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    image_id: ImageId,
    opts: &TriangulatorOptions,
) -> Result<TriangulationReport, SfmError> {
    opts.validate()?;
    let img = rec.image(image_id).ok_or(SfmError::UnknownImage(image_id))?;
    if !img.registered {
        return Ok(TriangulationReport::default());
    }
    let n = img.points2d.len() as u32;
    let mut report = TriangulationReport::default();
    for idx in 0..n {
        let views = find_views(rec, graph, image_id, idx, opts.max_transitivity);
        if views.is_empty() {
            continue;
        }
        let Some(reference) = view_of(rec, TrackElement::new(image_id, idx)) else { continue };
        if reference.point3d.is_none() && views.iter().any(|v| v.point3d.is_some()) {
            report.continued += continue_track(rec, &reference, &views, opts)?;
        }
        // The reference may observe a point now; re-read it.
        let reference = match view_of(rec, TrackElement::new(image_id, idx)) {
            Some(r) => r,
            None => continue,
        };
        let mut candidates = views;
        candidates.push(reference);
        report.created += create(rec, graph, candidates, opts.create_max_angle_error_deg, opts)?;
    }
    Ok(report)
}

/// Adds the reference keypoint to the existing track it fits best, if the
/// angular error is within `continue_max_angle_error_deg`.
fn continue_track(
    rec: &mut Reconstruction,
    reference: &View,
    views: &[View],
    opts: &TriangulatorOptions,
) -> Result<usize, SfmError> {
    let max_err = opts.continue_max_angle_error_deg.to_radians();
    let mut best: Option<(f64, Point3DId)> = None;
    let mut seen = BTreeSet::new();
    for v in views {
        let Some(pid) = v.point3d else { continue };
        if !seen.insert(pid) {
            continue;
        }
        let Some(p) = rec.point3d(pid) else { continue };
        // A track may hold one keypoint per image only.
        if p.track.iter().any(|e| e.image_id == reference.el.image_id) {
            continue;
        }
        let err = angular_error(reference, &p.xyz);
        if err <= max_err && best.is_none_or(|(e, _)| err < e) {
            best = Some((err, pid));
        }
    }
    match best {
        Some((_, pid)) => {
            rec.add_observation(pid, reference.el)?;
            Ok(1)
        }
        None => Ok(0),
    }
}

/// Creates new points from the views that observe none yet: RANSAC over view
/// pairs for the best-supported, well-conditioned pair, then a multi-view
/// refinement on its inliers (COLMAP's `Create` with its triangulation
/// RANSAC). Returns the number of points created.
fn create(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    views: Vec<View>,
    max_angle_error_deg: f64,
    opts: &TriangulatorOptions,
) -> Result<usize, SfmError> {
    // One keypoint per image, none already triangulated.
    let mut per_image = HashSet::new();
    let mut free: Vec<View> =
        views.into_iter().filter(|v| v.point3d.is_none() && per_image.insert(v.el.image_id)).collect();
    if free.len() < 2 {
        return Ok(0);
    }
    if opts.ignore_two_view_tracks
        && free.len() == 2
        && graph.correspondences(free[0].el.image_id, free[0].el.point2d_idx).len() == 1
    {
        return Ok(0);
    }
    // Bound the pair search, but keep the last view: the callers put the
    // keypoint being triangulated there, and a point created without it
    // would leave that keypoint untriangulated.
    if free.len() > MAX_CREATE_VIEWS {
        let last = free.len() - 1;
        free.swap(MAX_CREATE_VIEWS - 1, last);
        free.truncate(MAX_CREATE_VIEWS);
    }
    let max_err = max_angle_error_deg.to_radians();
    let tri_opts = TriangulationOptions {
        min_tri_angle_deg: opts.min_angle_deg,
        // Acceptance is by angular error below; the normalised-unit check
        // here only rejects wild solutions.
        max_reproj_error: f64::MAX,
        ..TriangulationOptions::default()
    };
    let mut created = 0;
    let mut remaining = free;
    // A second round on the outliers of the first, as COLMAP recurses.
    for _round in 0..2 {
        if remaining.len() < 2 {
            break;
        }
        let mut best: Option<(usize, f64, Vec<usize>)> = None;
        for i in 0..remaining.len() {
            for j in i + 1..remaining.len() {
                let (a, b) = (&remaining[i], &remaining[j]);
                let Ok(tp) = triangulate_multiview(&[a.pose, b.pose], &[a.normalized, b.normalized], &tri_opts) else {
                    continue;
                };
                if angular_error(a, &tp.point) > max_err || angular_error(b, &tp.point) > max_err {
                    continue;
                }
                let inliers: Vec<usize> =
                    (0..remaining.len()).filter(|&k| angular_error(&remaining[k], &tp.point) <= max_err).collect();
                let better = match &best {
                    None => true,
                    Some((n, angle, _)) => inliers.len() > *n || (inliers.len() == *n && tp.tri_angle_deg > *angle),
                };
                if better {
                    best = Some((inliers.len(), tp.tri_angle_deg, inliers));
                }
            }
        }
        let Some((_, _, inliers)) = best else { break };
        let poses: Vec<Rigid3> = inliers.iter().map(|&k| remaining[k].pose).collect();
        let obs: Vec<Vec2> = inliers.iter().map(|&k| remaining[k].normalized).collect();
        let Ok(tp) = triangulate_multiview(&poses, &obs, &tri_opts) else { break };
        let track: Vec<TrackElement> = inliers.iter().map(|&k| remaining[k].el).collect();
        if inliers.iter().any(|&k| angular_error(&remaining[k], &tp.point) > max_err) {
            break;
        }
        rec.add_point3d(tp.point, DEFAULT_POINT_COLOR, track)?;
        created += 1;
        let inlier_set: HashSet<usize> = inliers.into_iter().collect();
        remaining =
            remaining.into_iter().enumerate().filter(|(k, _)| !inlier_set.contains(k)).map(|(_, v)| v).collect();
    }
    Ok(created)
}

/// Adds observations of registered images to the given points' tracks where
/// a correspondence of a track element (up to `complete_max_transitivity`
/// hops) reprojects within `complete_max_reproj_error_px` (COLMAP's
/// `CompleteTracks`).
pub fn complete_tracks(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    points: &[Point3DId],
    opts: &TriangulatorOptions,
) -> Result<usize, SfmError> {
    opts.validate()?;
    let mut added = 0;
    for &pid in points {
        let Some(p) = rec.point3d(pid) else { continue };
        let xyz = p.xyz;
        // Breadth-first from the track, as COLMAP's CompleteTrack: only
        // observations that were added are expanded further, up to
        // `complete_max_transitivity` hops from the original track.
        // Tracks hold tens of elements: a vector beats hashing here.
        let mut in_track: Vec<ImageId> = p.track.iter().map(|e| e.image_id).collect();
        let mut frontier: Vec<TrackElement> = p.track.clone();
        for _hop in 0..opts.complete_max_transitivity {
            let mut next = Vec::new();
            for el in &frontier {
                for &n in graph.correspondences(el.image_id, el.point2d_idx) {
                    if in_track.contains(&n.image_id) {
                        continue;
                    }
                    // Cheap tests first: a registered image whose keypoint
                    // has no point yet (no undistortion needed for that).
                    let Some(img) = rec.image(n.image_id) else { continue };
                    if !img.registered
                        || img.points2d.get(n.point2d_idx as usize).is_none_or(|k| k.point3d_id.is_some())
                    {
                        continue;
                    }
                    let cand = TrackElement::new(n.image_id, n.point2d_idx);
                    if reprojection_error_px(rec, cand, &xyz) <= opts.complete_max_reproj_error_px {
                        rec.add_observation(pid, cand)?;
                        in_track.push(n.image_id);
                        next.push(cand);
                        added += 1;
                    }
                }
            }
            if next.is_empty() {
                break;
            }
            frontier = next;
        }
    }
    Ok(added)
}

/// Merges the tracks of the given points with tracks they meet through the
/// correspondence graph, when every observation of the merged track
/// reprojects within `merge_max_reproj_error_px` (COLMAP's `MergeTracks`).
/// Returns the number of merges.
pub fn merge_tracks(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    points: &[Point3DId],
    opts: &TriangulatorOptions,
) -> Result<usize, SfmError> {
    opts.validate()?;
    let mut merges = 0;
    let mut tried: HashSet<(Point3DId, Point3DId), FastHash> = HashSet::default();
    let mut queue: Vec<Point3DId> = points.to_vec();
    while let Some(pid) = queue.pop() {
        let Some(a) = rec.point3d(pid) else { continue };
        // Images of this track: a merged track may hold one keypoint per
        // image only. Built once per point (the track only changes by a
        // merge, after which the merged point is queued afresh).
        let images_a: Vec<ImageId> = a.track.iter().map(|e| e.image_id).collect();
        let mut partner = None;
        'elements: for el in &a.track {
            for c in graph.correspondences(el.image_id, el.point2d_idx) {
                if images_a.contains(&c.image_id) {
                    // The same image as an element of this track: its
                    // point (if any) cannot merge, or is this point.
                    continue;
                }
                let Some(img) = rec.image(c.image_id) else { continue };
                if !img.registered {
                    continue;
                }
                let Some(other) = img.points2d.get(c.point2d_idx as usize).and_then(|k| k.point3d_id) else {
                    continue;
                };
                // `other` is not `pid`: every keypoint of `pid` lies on an
                // image of `images_a`, skipped above.
                if !tried.insert((pid.min(other), pid.max(other))) {
                    continue;
                }
                let Some(b) = rec.point3d(other) else { continue };
                if b.track.iter().any(|e| images_a.contains(&e.image_id)) {
                    continue;
                }
                let (wa, wb) = (a.track.len() as f64, b.track.len() as f64);
                let merged = (a.xyz * wa + b.xyz * wb) / (wa + wb);
                let ok = a
                    .track
                    .iter()
                    .chain(&b.track)
                    .all(|e| reprojection_error_px(rec, *e, &merged) <= opts.merge_max_reproj_error_px);
                if ok {
                    partner = Some(other);
                    break 'elements;
                }
            }
        }
        if let Some(other) = partner {
            let new_id = rec.merge_points3d(pid, other)?;
            merges += 1;
            queue.push(new_id);
        }
    }
    Ok(merges)
}

/// Completes and merges the tracks of every point observed by `image_id`
/// (COLMAP's `CompleteImage` followed by merging).
pub fn complete_and_merge_image(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    image_id: ImageId,
    opts: &TriangulatorOptions,
) -> Result<TriangulationReport, SfmError> {
    let img = rec.image(image_id).ok_or(SfmError::UnknownImage(image_id))?;
    let points: Vec<Point3DId> = img.points2d.iter().filter_map(|p| p.point3d_id).collect();
    let continued = complete_tracks(rec, graph, &points, opts)?;
    let img = rec.image(image_id).ok_or(SfmError::UnknownImage(image_id))?;
    let points: Vec<Point3DId> = img.points2d.iter().filter_map(|p| p.point3d_id).collect();
    let merged = merge_tracks(rec, graph, &points, opts)?;
    Ok(TriangulationReport { created: 0, continued, merged })
}

/// Completes and merges every track of the model.
pub fn complete_and_merge_all(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    opts: &TriangulatorOptions,
) -> Result<TriangulationReport, SfmError> {
    let points = rec.point3d_ids();
    let continued = complete_tracks(rec, graph, &points, opts)?;
    let points = rec.point3d_ids();
    let merged = merge_tracks(rec, graph, &points, opts)?;
    Ok(TriangulationReport { created: 0, continued, merged })
}

/// Retriangulates registered image pairs whose share of triangulated
/// correspondences is below `re_min_ratio`, with the relaxed angular
/// threshold `re_max_angle_error_deg` (COLMAP's `Retriangulate`). `images`
/// limits the pairs to those involving these images (`None`: all pairs).
pub fn retriangulate(
    rec: &mut Reconstruction,
    graph: &CorrespondenceGraph,
    images: Option<&[ImageId]>,
    opts: &TriangulatorOptions,
) -> Result<TriangulationReport, SfmError> {
    opts.validate()?;
    let focus: Option<HashSet<ImageId>> = images.map(|s| s.iter().copied().collect());
    let pairs: Vec<(ImageId, ImageId, usize)> =
        graph.image_pairs().filter(|(a, b, _)| focus.as_ref().is_none_or(|f| f.contains(a) || f.contains(b))).collect();
    let re_opts = TriangulatorOptions { continue_max_angle_error_deg: opts.re_max_angle_error_deg, ..opts.clone() };
    let mut report = TriangulationReport::default();
    for (a, b, num_corrs) in pairs {
        let registered = |id| rec.image(id).is_some_and(|i| i.registered);
        if num_corrs == 0 || !registered(a) || !registered(b) {
            continue;
        }
        for _trial in 0..opts.re_max_trials.max(1) {
            let matches = graph.matches_between(a, b);
            let triangulated = matches
                .iter()
                .filter(|(i, j)| {
                    let pa = rec.image(a).and_then(|im| im.points2d.get(*i as usize)).and_then(|p| p.point3d_id);
                    let pb = rec.image(b).and_then(|im| im.points2d.get(*j as usize)).and_then(|p| p.point3d_id);
                    pa.is_some() && pa == pb
                })
                .count();
            if triangulated as f64 / num_corrs as f64 >= opts.re_min_ratio {
                break;
            }
            let mut created = 0;
            for (i, j) in &matches {
                let mut views = find_views(rec, graph, a, *i, opts.max_transitivity);
                let Some(reference) = view_of(rec, TrackElement::new(a, *i)) else { continue };
                if reference.point3d.is_none() {
                    report.continued += continue_track(rec, &reference, &views, &re_opts)?;
                }
                // The other end too: COLMAP continues whichever keypoint of
                // the match lacks a point (for the newest image, usually `b`).
                if let Some(other) = view_of(rec, TrackElement::new(b, *j))
                    && other.point3d.is_none()
                {
                    let other_views = find_views(rec, graph, b, *j, opts.max_transitivity);
                    let added = continue_track(rec, &other, &other_views, &re_opts)?;
                    if added > 0 {
                        report.continued += added;
                        // `views` still lists that keypoint as free.
                        views = find_views(rec, graph, a, *i, opts.max_transitivity);
                    }
                }
                let Some(reference) = view_of(rec, TrackElement::new(a, *i)) else { continue };
                let mut candidates = views;
                candidates.push(reference);
                created += create(rec, graph, candidates, opts.re_max_angle_error_deg, opts)?;
            }
            report.created += created;
            if created == 0 {
                break;
            }
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_camera::Camera;
    use colslam_geometry::{Quat, SplitMix64};
    use colslam_scene::Image;

    /// A small scene: `n_img` cameras on a line looking at `n_pts` points;
    /// every image sees every point; all consecutive pairs matched.
    fn scene(n_img: u32, n_pts: usize) -> (Reconstruction, CorrespondenceGraph, Vec<Vec3>) {
        let mut rng = SplitMix64::new(5);
        let cam = Camera::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0);
        let mut rec = Reconstruction::new();
        let cam_id = rec.add_camera(cam.clone());
        let pts: Vec<Vec3> = (0..n_pts)
            .map(|_| Vec3::new(rng.uniform(-2.0, 2.0), rng.uniform(-1.5, 1.5), rng.uniform(4.0, 8.0)))
            .collect();
        let mut graph = CorrespondenceGraph::new();
        for i in 1..=n_img {
            let pose =
                Rigid3::new(Quat::from_euler_angles(0.0, 0.02 * i as f64, 0.0), Vec3::new(-0.3 * i as f64, 0.0, 0.0));
            let kps: Vec<Vec2> = pts.iter().map(|p| cam.img_from_cam(&pose.transform_point(p)).unwrap()).collect();
            let mut img = Image::new(ImageId(i), format!("{i}.png"), cam_id, kps);
            img.cam_from_world = pose;
            rec.add_image(img).unwrap();
            rec.register_image(ImageId(i)).unwrap();
            graph.add_image(ImageId(i), n_pts).unwrap();
        }
        for i in 1..n_img {
            let m: Vec<(u32, u32)> = (0..n_pts as u32).map(|k| (k, k)).collect();
            graph.add_correspondences(ImageId(i), ImageId(i + 1), &m).unwrap();
        }
        (rec, graph, pts)
    }

    #[test]
    fn triangulate_continue_and_complete() {
        let (mut rec, graph, pts) = scene(4, 30);
        let opts = TriangulatorOptions::default();
        let r = triangulate_image(&mut rec, &graph, ImageId(1), &opts).unwrap();
        assert_eq!(r.created, 30);
        for (_, p) in rec.points3d() {
            let truth = pts.iter().map(|t| (t - p.xyz).norm()).fold(f64::INFINITY, f64::min);
            assert!(truth < 1e-8, "point off by {truth}");
            assert_eq!(p.track.len(), 2);
        }
        // Image 3 continues the tracks through image 2.
        let r = triangulate_image(&mut rec, &graph, ImageId(3), &opts).unwrap();
        assert_eq!((r.created, r.continued), (0, 30));
        // Image 4 is reached only transitively (4-3-2-1 chain is complete already via 3).
        let r = triangulate_image(&mut rec, &graph, ImageId(4), &opts).unwrap();
        assert_eq!(r.continued, 30);
        assert_eq!(rec.num_points3d(), 30);
        assert_eq!(rec.num_observations(), 120);
        rec.check_consistency().unwrap();
    }

    #[test]
    fn merge_and_complete() {
        let (mut rec, graph, _) = scene(4, 10);
        // Two separate tracks for the same physical points: (1,2) and (3,4).
        for k in 0..10u32 {
            for (a, b) in [(1, 2), (3, 4)] {
                let xyz = {
                    let va = view_of(&rec, TrackElement::new(ImageId(a), k)).unwrap();
                    let vb = view_of(&rec, TrackElement::new(ImageId(b), k)).unwrap();
                    triangulate_multiview(
                        &[va.pose, vb.pose],
                        &[va.normalized, vb.normalized],
                        &TriangulationOptions::default(),
                    )
                    .unwrap()
                    .point
                };
                rec.add_point3d(
                    xyz,
                    DEFAULT_POINT_COLOR,
                    vec![TrackElement::new(ImageId(a), k), TrackElement::new(ImageId(b), k)],
                )
                .unwrap();
            }
        }
        assert_eq!(rec.num_points3d(), 20);
        let r = complete_and_merge_all(&mut rec, &graph, &TriangulatorOptions::default()).unwrap();
        assert_eq!(r.merged, 10);
        assert_eq!(rec.num_points3d(), 10);
        assert!(rec.points3d().all(|(_, p)| p.track.len() == 4));
        rec.check_consistency().unwrap();
    }

    #[test]
    fn outlier_match_is_not_triangulated() {
        let (mut rec, mut graph, _) = scene(2, 10);
        // Break keypoint 0 of image 2: move it 40 px.
        let mut bad = rec.image(ImageId(2)).unwrap().clone();
        bad.points2d[0].xy.x += 40.0;
        let mut rec2 = Reconstruction::new();
        let cam_id = rec2.add_camera(rec.camera(bad.camera_id).unwrap().camera.clone());
        for id in [ImageId(1), ImageId(2)] {
            let mut img = if id == ImageId(2) { bad.clone() } else { rec.image(id).unwrap().clone() };
            img.camera_id = cam_id;
            rec2.add_image(img).unwrap();
            rec2.register_image(id).unwrap();
        }
        rec = rec2;
        let r = triangulate_image(&mut rec, &graph, ImageId(1), &TriangulatorOptions::default()).unwrap();
        assert_eq!(r.created, 9);
        // Invalid options are refused.
        let bad_opts = TriangulatorOptions { re_min_ratio: 2.0, ..TriangulatorOptions::default() };
        assert!(triangulate_image(&mut rec, &graph, ImageId(1), &bad_opts).is_err());
        assert!(matches!(
            triangulate_image(&mut rec, &graph, ImageId(9), &TriangulatorOptions::default()),
            Err(SfmError::UnknownImage(_))
        ));
        let _ = &mut graph;
    }

    #[test]
    fn angular_error_is_zero_on_the_ray_and_pi_behind_the_camera() {
        let (rec, _, pts) = scene(2, 3);
        let v = view_of(&rec, TrackElement::new(ImageId(1), 0)).unwrap();
        // acos near 1 resolves angles to about 1e-8 rad only.
        assert!(angular_error(&v, &pts[0]) < 1e-7);
        // Any point on the ray, near or far, has no error.
        let centre = rec.image(ImageId(1)).unwrap().projection_center();
        assert!(angular_error(&v, &(centre + (pts[0] - centre) * 3.0)) < 1e-7);
        // The mirrored point behind the camera is as wrong as can be.
        assert_eq!(angular_error(&v, &(centre - (pts[0] - centre))), std::f64::consts::PI);
        // A point 0.1 rad off the ray, seen from the centre.
        let to_p = pts[0] - centre;
        let side = to_p.cross(&Vec3::new(0.0, 1.0, 0.0)).normalize() * to_p.norm() * 0.1f64.tan();
        assert!((angular_error(&v, &(pts[0] + side)) - 0.1).abs() < 1e-9);
        // Unknown images and keypoints have no view.
        assert!(view_of(&rec, TrackElement::new(ImageId(1), 3)).is_none());
        assert!(view_of(&rec, TrackElement::new(ImageId(7), 0)).is_none());
    }

    #[test]
    fn reprojection_error_is_infinite_where_nothing_projects() {
        let (rec, _, pts) = scene(2, 3);
        let el = TrackElement::new(ImageId(2), 1);
        assert!(reprojection_error_px(&rec, el, &pts[1]) < 1e-9);
        let centre = rec.image(ImageId(2)).unwrap().projection_center();
        // Behind the camera: no pixel, even though the mirrored ray hits the keypoint.
        assert_eq!(reprojection_error_px(&rec, el, &(centre - (pts[1] - centre))), f64::INFINITY);
        assert_eq!(reprojection_error_px(&rec, TrackElement::new(ImageId(2), 9), &pts[1]), f64::INFINITY);
        assert_eq!(reprojection_error_px(&rec, TrackElement::new(ImageId(9), 1), &pts[1]), f64::INFINITY);
    }
}

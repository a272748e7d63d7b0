//! Offline recovery after lost tracking: merging maps and relocalising
//! frames that no map explained.
//!
//! A sequential pipeline that loses tracking starts a new map; being
//! offline, we can afterwards look for overlap between the maps (keyframes
//! close in time are matched, 3D-3D correspondences through their points
//! give a similarity by RANSAC + Umeyama, accepted on reprojection), bring
//! the smaller map into the larger one's frame, join reconstructions and
//! correspondence graphs, and bundle adjust the union. Frames that were
//! never tracked are then matched to the keyframes nearest in time and
//! localised like every other frame.

use super::state::{Keyframe, Mapper};
use crate::error::SlamError;
use crate::frame::{FrameData, FrameRecord};
use crate::frontend::Frontend;
use crate::options::{GlobalBaTolerance, SlamOptions};
use crate::timing::{Stage, StageTimings};
use colslam_geometry::{Sim3, SplitMix64, Vec2, Vec3, umeyama};
use colslam_scene::{Image, ImageId, Point3DId, Reconstruction, TrackElement};
use std::collections::{BTreeMap, HashMap, HashSet};

/// Keyframes of the smaller map tried at each end (first and last).
const MERGE_KEYFRAMES_PER_END: usize = 5;
/// Keyframes of the other map, nearest in time, each is matched against.
const MERGE_NEIGHBOURS: usize = 5;
/// RANSAC iterations of the similarity search.
const MERGE_RANSAC_ITERATIONS: usize = 400;
/// Reprojection threshold (px) of a merged 3D-3D correspondence.
const MERGE_MAX_REPROJ_PX: f64 = 8.0;
/// Inlier correspondences needed to merge two maps.
const MERGE_MIN_INLIERS: usize = 30;
/// Mixed into the run's seed for the similarity RANSAC ("merge" in ASCII).
const MERGE_SEED: u64 = 0x6d_6572_6765;
/// Keypoint matches between a keyframe of the source map and one of the
/// target map: (source image, target image, (source kp, target kp) pairs).
type CrossMatches = (ImageId, ImageId, Vec<(u32, u32)>);
/// Keyframes nearest in time an orphan frame is matched against.
const RELOCALIZE_NEIGHBOURS: usize = 5;

/// A 3D-3D correspondence between two maps, with the observation in the
/// target map used to verify it by reprojection.
#[derive(Clone)]
pub(super) struct Pair {
    pub(super) source_point: Point3DId,
    pub(super) target_point: Point3DId,
    pub(super) source_xyz: Vec3,
    pub(super) target_xyz: Vec3,
    pub(super) target_image: ImageId,
    pub(super) target_pixel: Vec2,
}

/// Keyframes of `map` nearest in frame index to `frame`, nearest first.
fn nearest_keyframes(map: &Mapper, frame: usize, k: usize) -> Vec<&Keyframe> {
    let mut kfs: Vec<&Keyframe> =
        map.keyframes.iter().filter(|kf| map.rec.image(kf.image_id).is_some_and(|i| i.registered)).collect();
    kfs.sort_by_key(|kf| (kf.data.index().abs_diff(frame), kf.data.index()));
    kfs.truncate(k);
    kfs
}

fn point_of(map: &Mapper, image: ImageId, kp: u32) -> Option<(Point3DId, Vec3)> {
    let pid = map.rec.image(image)?.points2d.get(kp as usize)?.point3d_id?;
    Some((pid, map.rec.point3d(pid)?.xyz))
}

/// 3D-3D correspondences and keypoint matches between the keyframes at
/// both ends of `source` and their nearest keyframes in time of `target`.
fn cross_matches(
    target: &Mapper,
    source: &Mapper,
    frontend: &Frontend,
    timings: &mut StageTimings,
) -> Result<(Vec<Pair>, Vec<CrossMatches>), SlamError> {
    let n = source.keyframes.len();
    let mut ends: Vec<&Keyframe> = source.keyframes.iter().take(MERGE_KEYFRAMES_PER_END).collect();
    ends.extend(source.keyframes.iter().skip(n.saturating_sub(MERGE_KEYFRAMES_PER_END).max(MERGE_KEYFRAMES_PER_END)));
    let mut pairs = Vec::new();
    let mut cross: Vec<CrossMatches> = Vec::new();
    for kb in ends {
        for ka in nearest_keyframes(target, kb.data.index(), MERGE_NEIGHBOURS) {
            let matches = timings.time(Stage::Matching, || frontend.match_frames(&kb.data, &ka.data))?;
            let mut edge = Vec::new();
            for m in &matches {
                edge.push((m.query, m.train));
                let (Some((sp, sx)), Some((tp, tx))) =
                    (point_of(source, kb.image_id, m.query), point_of(target, ka.image_id, m.train))
                else {
                    continue;
                };
                let Some(px) = target.rec.image(ka.image_id).and_then(|i| i.points2d.get(m.train as usize)) else {
                    continue;
                };
                pairs.push(Pair {
                    source_point: sp,
                    target_point: tp,
                    source_xyz: sx,
                    target_xyz: tx,
                    target_image: ka.image_id,
                    target_pixel: px.xy,
                });
            }
            cross.push((kb.image_id, ka.image_id, edge));
        }
    }
    Ok((pairs, cross))
}

/// True when `p`'s source point, moved by `s`, reprojects into its target
/// observation within [`MERGE_MAX_REPROJ_PX`].
pub(super) fn is_inlier(target: &Mapper, s: &Sim3, p: &Pair) -> bool {
    reprojects_within(target, p.target_image, &s.transform_point(&p.source_xyz), &p.target_pixel, MERGE_MAX_REPROJ_PX)
}

/// True when `xyz` projects (in front of the camera) into image `image`
/// of `map` within `max_px` of `pixel`.
pub(super) fn reprojects_within(map: &Mapper, image: ImageId, xyz: &Vec3, pixel: &Vec2, max_px: f64) -> bool {
    let Some(img) = map.rec.image(image) else { return false };
    let Some(cam) = map.rec.camera(img.camera_id) else { return false };
    let x = img.cam_from_world.transform_point(xyz);
    cam.camera.img_from_cam(&x).is_some_and(|px| (px - pixel).norm() <= max_px)
}

/// The similarity `target_from_source` with the most reprojection inliers
/// over [`MERGE_RANSAC_ITERATIONS`] minimal samples, refitted on its
/// inliers; `None` below [`MERGE_MIN_INLIERS`].
pub(super) fn similarity(target: &Mapper, pairs: &[Pair], seed: u64) -> Option<Sim3> {
    let mut rng = SplitMix64::new(seed ^ MERGE_SEED);
    let mut best: Option<(usize, Sim3)> = None;
    for _ in 0..MERGE_RANSAC_ITERATIONS {
        let idx = [rng.below(pairs.len()), rng.below(pairs.len()), rng.below(pairs.len())];
        if idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] {
            continue;
        }
        let src: Vec<Vec3> = idx.iter().map(|&i| pairs[i].source_xyz).collect();
        let dst: Vec<Vec3> = idx.iter().map(|&i| pairs[i].target_xyz).collect();
        let Ok(s) = umeyama(&src, &dst, true) else { continue };
        if !(s.scale.is_finite() && s.scale > 0.0) {
            continue;
        }
        let count = pairs.iter().filter(|p| is_inlier(target, &s, p)).count();
        if best.as_ref().is_none_or(|(c, _)| count > *c) {
            best = Some((count, s));
        }
    }
    let (count, s0) = best?;
    if count < MERGE_MIN_INLIERS {
        tracing::debug!("only {count} consistent 3D-3D matches");
        return None;
    }
    // Refit on all inliers.
    let inliers: Vec<&Pair> = pairs.iter().filter(|p| is_inlier(target, &s0, p)).collect();
    let src: Vec<Vec3> = inliers.iter().map(|p| p.source_xyz).collect();
    let dst: Vec<Vec3> = inliers.iter().map(|p| p.target_xyz).collect();
    let refit = umeyama(&src, &dst, true).ok();
    Some(refit.filter(|s| inliers.iter().filter(|p| is_inlier(target, s, p)).count() >= count).unwrap_or(s0))
}

/// Merges each pair of points whose tracks see disjoint images (a track
/// sees an image once); returns how many were merged.
pub(super) fn merge_point_pairs(
    rec: &mut Reconstruction,
    pairs: &[(Point3DId, Point3DId)],
) -> Result<usize, colslam_scene::SceneError> {
    let mut merged = 0;
    for &(a, b) in pairs {
        // Both may have been merged away already by an earlier pair.
        let images = |id: Point3DId| rec.point3d(id).map(|p| p.track.iter().map(|e| e.image_id).collect::<Vec<_>>());
        let disjoint = matches!((images(a), images(b)), (Some(x), Some(y)) if x.iter().all(|i| !y.contains(i)));
        if disjoint {
            rec.merge_points3d(a, b)?;
            merged += 1;
        }
    }
    Ok(merged)
}

impl Mapper {
    /// Tries to bring `source` into this map's frame and join them (then
    /// globally refined). Returns the similarity `self_from_source` when
    /// they were merged.
    pub fn merge(
        &mut self,
        source: &Mapper,
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Option<Sim3>, SlamError> {
        let (pairs, cross) = cross_matches(self, source, frontend, timings)?;
        if pairs.len() < MERGE_MIN_INLIERS {
            return Ok(None);
        }
        let Some(sim) = similarity(self, &pairs, opts.seed) else {
            tracing::debug!("maps {} and {} not merged", self.index, source.index);
            return Ok(None);
        };
        let merged_pairs: Vec<(Point3DId, Point3DId)> =
            pairs.iter().filter(|p| is_inlier(self, &sim, p)).map(|p| (p.target_point, p.source_point)).collect();
        self.join(source, &sim, &cross, &merged_pairs)?;
        tracing::info!(
            "map {} merged into map {} ({} consistent 3D-3D matches, scale {:.4})",
            source.index,
            self.index,
            merged_pairs.len(),
            sim.scale
        );
        self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        Ok(Some(sim))
    }

    /// Copies `source` (transformed by `sim`) into this map: images, points,
    /// graph, keyframes and records; links the matched points and the
    /// cross-map matches.
    fn join(
        &mut self,
        source: &Mapper,
        sim: &Sim3,
        cross: &[CrossMatches],
        merged_pairs: &[(Point3DId, Point3DId)],
    ) -> Result<(), SlamError> {
        let mut src = source.rec.clone();
        src.transform(sim);
        let (image_map, shared) = self.join_images(&src)?;
        let point_map = self.join_points(&src, &image_map)?;
        self.join_graph(source, &image_map, cross)?;
        self.link_merged_points(merged_pairs, &point_map)?;
        for kf in source.keyframes.iter().filter(|k| !shared.contains(&k.image_id)) {
            if let Some(&id) = image_map.get(&kf.image_id) {
                // Normalised with the source's camera: stale here once either
                // camera was refined.
                let version = if source.intrinsics_version == 0 && self.intrinsics_version == 0 { 0 } else { u64::MAX };
                self.keyframes.push(Keyframe { image_id: id, data: kf.data.clone(), version });
            }
        }
        for (old_id, sig) in source.sigmas.iter().filter(|(id, _)| !shared.contains(id)) {
            if let Some(&id) = image_map.get(old_id) {
                std::sync::Arc::make_mut(&mut self.sigmas).insert(id, sig.clone());
            }
        }
        self.order_keyframes_by_time();
        self.culled += source.culled;
        for r in source.records.all()? {
            let mut r = r;
            // Maps are joined before rolling-shutter compensation, which
            // runs on the joined map: nothing compensated to carry.
            r.compensated.clear();
            r.obs.retain_mut(|o| match image_map.get(&o.keyframe) {
                Some(&id) => {
                    o.keyframe = id;
                    true
                }
                None => false,
            });
            self.records.push(r)?;
        }
        Ok(())
    }

    /// Adds the registered images of `src` (already transformed); returns
    /// the map from their ids to ours and the ids that were shared. A frame
    /// that is a keyframe of both maps (one map tracked backwards over
    /// frames the other had tracked) stays one image: the source's
    /// observations of it go to our image of the same frame, whose keypoints
    /// are the same.
    fn join_images(
        &mut self,
        src: &Reconstruction,
    ) -> Result<(HashMap<ImageId, ImageId>, HashSet<ImageId>), SlamError> {
        let mut image_map: HashMap<ImageId, ImageId> = HashMap::new();
        let existing: HashMap<String, ImageId> = self
            .keyframes
            .iter()
            .filter(|k| self.rec.image(k.image_id).is_some_and(|i| i.registered))
            .map(|k| (k.data.id.name.clone(), k.image_id))
            .collect();
        let mut shared: HashSet<ImageId> = HashSet::new();
        for id in src.registered_image_ids().to_vec() {
            let Some(img) = src.image(id) else { continue };
            if let Some(&same) = existing.get(&img.name) {
                image_map.insert(id, same);
                shared.insert(id);
                continue;
            }
            let new_id = self.rec.next_image_id();
            let mut copy =
                Image::new(new_id, img.name.clone(), self.camera_id, img.points2d.iter().map(|p| p.xy).collect());
            copy.cam_from_world = img.cam_from_world;
            self.rec.add_image(copy)?;
            self.rec.register_image(new_id)?;
            self.graph.add_image(new_id, img.points2d.len())?;
            image_map.insert(id, new_id);
        }
        Ok((image_map, shared))
    }

    /// Adds the points of `src` whose tracks keep two observations on our
    /// images; returns the map from their ids to ours.
    fn join_points(
        &mut self,
        src: &Reconstruction,
        image_map: &HashMap<ImageId, ImageId>,
    ) -> Result<BTreeMap<Point3DId, Point3DId>, SlamError> {
        let mut point_map: BTreeMap<Point3DId, Point3DId> = BTreeMap::new();
        for (pid, p) in src.points3d() {
            let mut seen = HashSet::new();
            let track: Vec<TrackElement> = p
                .track
                .iter()
                .filter_map(|e| image_map.get(&e.image_id).map(|&i| TrackElement::new(i, e.point2d_idx)))
                // On a shared image the keypoint may already observe one of
                // our points, and a track sees an image once.
                .filter(|e| {
                    let free = self
                        .rec
                        .image(e.image_id)
                        .and_then(|img| img.points2d.get(e.point2d_idx as usize))
                        .is_some_and(|p| p.point3d_id.is_none());
                    free && seen.insert(e.image_id)
                })
                .collect();
            if track.len() < 2 {
                continue;
            }
            let new_id = self.rec.add_point3d(p.xyz, p.color, track)?;
            point_map.insert(pid, new_id);
        }
        Ok(point_map)
    }

    /// Adds `source`'s correspondence graph and the cross-map matches.
    fn join_graph(
        &mut self,
        source: &Mapper,
        image_map: &HashMap<ImageId, ImageId>,
        cross: &[CrossMatches],
    ) -> Result<(), SlamError> {
        for (a, b, _) in source.graph.image_pairs() {
            if let (Some(&na), Some(&nb)) = (image_map.get(&a), image_map.get(&b))
                && na != nb
            {
                self.graph.add_correspondences(na, nb, &source.graph.matches_between(a, b))?;
            }
        }
        for (kb, ka, edge) in cross {
            if let Some(&nb) = image_map.get(kb)
                && nb != *ka
            {
                self.graph.add_correspondences(nb, *ka, edge)?;
            }
        }
        Ok(())
    }

    /// Merges each matched pair (ours, source's as copied) whose tracks see
    /// disjoint images.
    fn link_merged_points(
        &mut self,
        merged_pairs: &[(Point3DId, Point3DId)],
        point_map: &BTreeMap<Point3DId, Point3DId>,
    ) -> Result<(), SlamError> {
        let pairs: Vec<(Point3DId, Point3DId)> =
            merged_pairs.iter().filter_map(|(tp, sp)| point_map.get(sp).map(|&np| (*tp, np))).collect();
        merge_point_pairs(&mut self.rec, &pairs)?;
        Ok(())
    }

    /// Records for frames no map tracked: matched to the keyframes nearest
    /// in time, to be localised with the map's other records.
    pub fn relocalization_records(
        &self,
        orphans: &[FrameData],
        frontend: &Frontend,
        timings: &mut StageTimings,
    ) -> Result<Vec<FrameRecord>, SlamError> {
        let mut out = Vec::new();
        for f in orphans {
            let mut rec = FrameRecord::new(f);
            for kf in nearest_keyframes(self, f.index(), RELOCALIZE_NEIGHBOURS) {
                let m = timings.time(Stage::Matching, || frontend.match_frames(f, &kf.data))?;
                rec.add_matches(f, kf.image_id, &m);
            }
            out.push(rec);
        }
        Ok(out)
    }
}

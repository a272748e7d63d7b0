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

use crate::frontend::{FrameData, Frontend};
use crate::map::{FrameRecord, Keyframe, MapState};
use crate::timing::{Stage, StageTimings};
use crate::{SlamError, SlamOptions};
use colslam_geometry::{Sim3, SplitMix64, Vec2, Vec3, umeyama};
use colslam_scene::{Image, ImageId, Point3DId, TrackElement};
use std::collections::{BTreeMap, HashMap};

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
struct Pair {
    source_point: Point3DId,
    target_point: Point3DId,
    source_xyz: Vec3,
    target_xyz: Vec3,
    target_image: ImageId,
    target_pixel: Vec2,
}

/// Keyframes of `map` nearest in frame index to `frame`, nearest first.
fn nearest_keyframes(map: &MapState, frame: usize, k: usize) -> Vec<&Keyframe> {
    let mut kfs: Vec<&Keyframe> =
        map.keyframes.iter().filter(|kf| map.rec.image(kf.image_id).is_some_and(|i| i.registered)).collect();
    kfs.sort_by_key(|kf| (kf.data.index.abs_diff(frame), kf.data.index));
    kfs.truncate(k);
    kfs
}

fn point_of(map: &MapState, image: ImageId, kp: u32) -> Option<(Point3DId, Vec3)> {
    let pid = map.rec.image(image)?.points2d.get(kp as usize)?.point3d_id?;
    Some((pid, map.rec.point3d(pid)?.xyz))
}

/// Tries to bring `source` into `target`'s frame and join them. Returns the
/// similarity `target_from_source` when they were merged (then `source` has
/// been consumed into `target`).
pub fn try_merge(
    target: &mut MapState,
    source: &MapState,
    frontend: &Frontend,
    opts: &SlamOptions,
    timings: &mut StageTimings,
) -> Result<Option<Sim3>, SlamError> {
    let n = source.keyframes.len();
    let mut ends: Vec<&Keyframe> = source.keyframes.iter().take(MERGE_KEYFRAMES_PER_END).collect();
    ends.extend(source.keyframes.iter().skip(n.saturating_sub(MERGE_KEYFRAMES_PER_END).max(MERGE_KEYFRAMES_PER_END)));
    let mut pairs = Vec::new();
    let mut cross: Vec<CrossMatches> = Vec::new();
    for kb in ends {
        for ka in nearest_keyframes(target, kb.data.index, MERGE_NEIGHBOURS) {
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
    if pairs.len() < MERGE_MIN_INLIERS {
        return Ok(None);
    }
    let is_inlier = |s: &Sim3, p: &Pair| -> bool {
        let Some(img) = target.rec.image(p.target_image) else { return false };
        let Some(cam) = target.rec.camera(img.camera_id) else { return false };
        let x = img.cam_from_world.transform_point(&s.transform_point(&p.source_xyz));
        cam.camera.img_from_cam(&x).is_some_and(|px| (px - p.target_pixel).norm() <= MERGE_MAX_REPROJ_PX)
    };
    let mut rng = SplitMix64::new(opts.seed ^ MERGE_SEED);
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
        let count = pairs.iter().filter(|p| is_inlier(&s, p)).count();
        if best.as_ref().is_none_or(|(c, _)| count > *c) {
            best = Some((count, s));
        }
    }
    let Some((count, s0)) = best else { return Ok(None) };
    if count < MERGE_MIN_INLIERS {
        tracing::debug!("maps {} and {}: only {count} consistent 3D-3D matches", target.index, source.index);
        return Ok(None);
    }
    // Refit on all inliers.
    let inliers: Vec<&Pair> = pairs.iter().filter(|p| is_inlier(&s0, p)).collect();
    let src: Vec<Vec3> = inliers.iter().map(|p| p.source_xyz).collect();
    let dst: Vec<Vec3> = inliers.iter().map(|p| p.target_xyz).collect();
    let sim = umeyama(&src, &dst, true)
        .ok()
        .filter(|s| inliers.iter().filter(|p| is_inlier(s, p)).count() >= count)
        .unwrap_or(s0);
    let merged_pairs: Vec<(Point3DId, Point3DId)> =
        pairs.iter().filter(|p| is_inlier(&sim, p)).map(|p| (p.target_point, p.source_point)).collect();
    join(target, source, &sim, &cross, &merged_pairs)?;
    tracing::info!(
        "map {} merged into map {} ({} consistent 3D-3D matches, scale {:.4})",
        source.index,
        target.index,
        merged_pairs.len(),
        sim.scale
    );
    target.global_ba(opts, timings)?;
    Ok(Some(sim))
}

/// Copies `source` (transformed by `sim`) into `target`: images, points,
/// graph, keyframes and records; links the matched points and the cross-map
/// matches.
fn join(
    target: &mut MapState,
    source: &MapState,
    sim: &Sim3,
    cross: &[CrossMatches],
    merged_pairs: &[(Point3DId, Point3DId)],
) -> Result<(), SlamError> {
    let mut src = source.rec.clone();
    src.transform(sim);
    let mut image_map: HashMap<ImageId, ImageId> = HashMap::new();
    // A frame that is a keyframe of both maps (one map tracked backwards
    // over frames the other had tracked) stays one image: the source's
    // observations of it go to the target's image of the same frame, whose
    // keypoints are the same.
    let existing: HashMap<String, ImageId> = target
        .keyframes
        .iter()
        .filter(|k| target.rec.image(k.image_id).is_some_and(|i| i.registered))
        .map(|k| (k.data.name.clone(), k.image_id))
        .collect();
    let mut shared: std::collections::HashSet<ImageId> = std::collections::HashSet::new();
    for id in src.registered_image_ids().to_vec() {
        let Some(img) = src.image(id) else { continue };
        if let Some(&same) = existing.get(&img.name) {
            image_map.insert(id, same);
            shared.insert(id);
            continue;
        }
        let new_id = target.rec.next_image_id();
        let mut copy =
            Image::new(new_id, img.name.clone(), target.camera_id, img.points2d.iter().map(|p| p.xy).collect());
        copy.cam_from_world = img.cam_from_world;
        target.rec.add_image(copy)?;
        target.rec.register_image(new_id)?;
        target.graph.add_image(new_id, img.points2d.len())?;
        image_map.insert(id, new_id);
    }
    let mut point_map: BTreeMap<Point3DId, Point3DId> = BTreeMap::new();
    for (pid, p) in src.points3d() {
        let mut seen = std::collections::HashSet::new();
        let track: Vec<TrackElement> = p
            .track
            .iter()
            .filter_map(|e| image_map.get(&e.image_id).map(|&i| TrackElement::new(i, e.point2d_idx)))
            // On a shared image the keypoint may already observe a target
            // point, and a track sees an image once.
            .filter(|e| {
                let free = target
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
        let new_id = target.rec.add_point3d(p.xyz, p.color, track)?;
        point_map.insert(pid, new_id);
    }
    for (a, b, _) in source.graph.image_pairs() {
        if let (Some(&na), Some(&nb)) = (image_map.get(&a), image_map.get(&b))
            && na != nb
        {
            target.graph.add_correspondences(na, nb, &source.graph.matches_between(a, b))?;
        }
    }
    for (kb, ka, edge) in cross {
        if let Some(&nb) = image_map.get(kb)
            && nb != *ka
        {
            target.graph.add_correspondences(nb, *ka, edge)?;
        }
    }
    for (tp, sp) in merged_pairs {
        let Some(&np) = point_map.get(sp) else { continue };
        // Both may have been merged away already by an earlier pair.
        if target.rec.point3d(*tp).is_some() && target.rec.point3d(np).is_some() {
            let a = target.rec.point3d(*tp).map(|p| p.track.iter().map(|e| e.image_id).collect::<Vec<_>>());
            let b = target.rec.point3d(np).map(|p| p.track.iter().map(|e| e.image_id).collect::<Vec<_>>());
            let disjoint = matches!((a, b), (Some(a), Some(b)) if a.iter().all(|i| !b.contains(i)));
            if disjoint {
                let _ = target.rec.merge_points3d(*tp, np)?;
            }
        }
    }
    for kf in &source.keyframes {
        if shared.contains(&kf.image_id) {
            continue;
        }
        if let Some(&id) = image_map.get(&kf.image_id) {
            target.keyframes.push(Keyframe { image_id: id, data: kf.data.clone() });
        }
    }
    for (old_id, sig) in source.sigmas.iter() {
        if shared.contains(old_id) {
            continue;
        }
        if let Some(&id) = image_map.get(old_id) {
            std::sync::Arc::make_mut(&mut target.sigmas).insert(id, sig.clone());
        }
    }
    target.keyframes.sort_by_key(|k| k.data.index);
    for r in &source.records {
        let mut r = r.clone();
        r.obs.retain_mut(|o| match image_map.get(&o.keyframe) {
            Some(&id) => {
                o.keyframe = id;
                true
            }
            None => false,
        });
        target.records.push(r);
    }
    Ok(())
}

/// Records for frames no map tracked: matched to the keyframes nearest in
/// time, to be localised with the map's other records.
pub fn relocalization_records(
    map: &MapState,
    orphans: &[FrameData],
    frontend: &Frontend,
    timings: &mut StageTimings,
) -> Result<Vec<FrameRecord>, SlamError> {
    let mut out = Vec::new();
    for f in orphans {
        let mut rec = FrameRecord::new(f);
        for kf in nearest_keyframes(map, f.index, RELOCALIZE_NEIGHBOURS) {
            let m = timings.time(Stage::Matching, || frontend.match_frames(f, &kf.data))?;
            rec.add_matches(f, kf.image_id, &m);
        }
        out.push(rec);
    }
    Ok(out)
}

//! Loop closure by appearance (`--loop-closure`), after ORB-SLAM's loop
//! closing (Mur-Artal and Tardós, ORB-SLAM2, T-RO 2017: place recognition
//! with a bag of binary words, Sim(3) verification, correction of the poses
//! between the two ends, loop fusion, then global BA) on COLMAP's parts:
//! the fused tracks and the loop's matches go into the correspondence
//! graph, and COLMAP's track completion/merging and global BA finish the
//! closure.
//!
//! Revisit matching (`Mapper::revisited_keyframes`) only finds old keyframes
//! near the drifted pose; once drift exceeds its bounds a loop is never
//! closed. Here every new keyframe is described by a tf-idf word vector
//! (vocabulary trained on the map's own keyframes, retrained whenever the
//! keyframes doubled) and looked up in an inverted index:
//! 1. candidates: keyframes sharing no point with the new one that score at
//!    least its covisible neighbours' lowest score (ORB-SLAM's rule), found
//!    for [`LOOP_CONSISTENCY`] consecutive keyframes (their covisibility
//!    groups overlapping);
//! 2. verification: the new keyframe is matched to the candidate and its
//!    covisible keyframes, their 3D-3D correspondences give a similarity by
//!    the map merge's RANSAC (`merge.rs`, checked by reprojection), with at
//!    least [`LOOP_MIN_INLIERS`] inliers;
//! 3. correction: the keyframes after the candidate move by the similarity
//!    interpolated along the keyframe order (none at the candidate, all of
//!    it at the new keyframe: the drift is spread over the loop, as a pose
//!    graph over the loop's chain would do), each point with its observers;
//!    the inlier point pairs are merged, the verified matches added to the
//!    graph, tracks completed and merged, and a converged global BA run.

use super::merge::{Pair, is_inlier, merge_point_pairs, reprojects_within, similarity};
use super::state::Mapper;
use crate::error::SlamError;
use crate::frontend::Frontend;
use crate::options::{GlobalBaTolerance, SlamOptions, VERIFY_MAX_ERROR_PX};
use crate::timing::{Stage, StageTimings};
use colslam_features::{BowVector, Descriptors, PlaceIndex, Vocabulary, VocabularyOptions, bow_score};
use colslam_geometry::{Quat, Sim3, Vec2, Vec3};
use colslam_scene::reconstruction::transform_cam_from_world;
use colslam_scene::{ImageId, Point3DId};
use colslam_sfm::bundle::covisible_images;
use colslam_sfm::triangulator::complete_and_merge_all;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet, HashMap};

/// Keyframes the map needs before the vocabulary is first trained (and
/// loops are looked for): fewer give too few documents for the idf.
pub const LOOP_MIN_KEYFRAMES: usize = 12;
/// Consecutive keyframes a candidate (or its covisible group) must be found
/// for (ORB-SLAM: 3).
pub const LOOP_CONSISTENCY: usize = 3;
/// Candidates verified per keyframe, best score first.
const LOOP_MAX_CANDIDATES: usize = 3;
/// Covisible neighbours whose scores set the candidates' minimum score, and
/// keyframes in a candidate's group.
const LOOP_NEIGHBOURS: usize = 10;
/// Shared points that make a keyframe a neighbour for the minimum score
/// (ORB-SLAM's covisibility-graph edge weight).
const LOOP_NEIGHBOUR_MIN_SHARED: usize = 15;
/// Covisible keyframes of the candidate matched besides it.
const LOOP_MATCH_GROUP: usize = 4;
/// Sim(3) inliers a loop needs (ORB-SLAM: 40 after guided matching).
pub const LOOP_MIN_INLIERS: usize = 40;
/// Reprojection threshold (px) of the check in the new keyframe (ORB-SLAM:
/// chi-square 9.21 at unit sigma, about 3 px at the finest level).
const LOOP_MAX_REPROJ_PX: f64 = 4.0;
/// New keyframes after a closure before the next loop is looked for.
const LOOP_GAP_KEYFRAMES: usize = 10;

/// A keyframe's binary descriptors (`None` for float ones: no loops with
/// learned features).
fn binary(k: &super::state::Keyframe) -> Option<&[[u64; 4]]> {
    match &k.data.features.descriptors {
        Descriptors::Binary(d) => Some(d.as_slice()),
        Descriptors::Float { .. } => None,
    }
}

/// One loop closed, as `report.json` lists it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopClosure {
    /// The frame of the keyframe that closed the loop.
    pub frame: usize,
    /// The frame of the old keyframe it was recognised as.
    pub loop_frame: usize,
    /// Its bag-of-words score against that keyframe.
    pub score: f32,
    /// Sim(3) inliers (3D-3D correspondences consistent by reprojection).
    pub inliers: usize,
    /// Point pairs merged across the loop.
    pub merged_points: usize,
    /// Keyframes whose poses were corrected.
    pub keyframes_corrected: usize,
    /// The correction at the closing keyframe: scale, rotation (degrees) and
    /// how far its centre moved (map units, before the global BA).
    pub scale: f64,
    /// Rotation of the correction, degrees.
    pub rotation_deg: f64,
    /// Displacement of the closing keyframe's centre.
    pub translation: f64,
}

/// The place-recognition state of a map.
#[derive(Debug, Clone, Default)]
pub struct LoopState {
    vocab: Option<Vocabulary>,
    /// Keyframes the vocabulary was trained on.
    trained_on: usize,
    bows: BTreeMap<ImageId, BowVector>,
    index: PlaceIndex,
    /// The previous keyframe's candidate groups and how many consecutive
    /// keyframes found each.
    groups: Vec<(BTreeSet<ImageId>, usize)>,
    /// Keyframes registered since the last closure (or the start).
    since_last: usize,
    /// Loops closed.
    pub(super) closed: Vec<LoopClosure>,
}

/// A verified loop: the candidate, its score, the similarity
/// `candidate_side_from_new_side` and its inlier pairs.
struct VerifiedLoop {
    candidate: ImageId,
    score: f32,
    sim: Sim3,
    inliers: Vec<Pair>,
    matches: Vec<(usize, Vec<colslam_features::Match>)>,
}

impl Mapper {
    /// Loops closed so far in this map.
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops.closed
    }

    /// Looks for a loop at the keyframe just registered as `image_id` and
    /// closes it; returns the closure.
    pub fn close_loop(
        &mut self,
        image_id: ImageId,
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Option<LoopClosure>, SlamError> {
        let started = std::time::Instant::now();
        self.loops.since_last += 1;
        if !self.index_keyframe(image_id) {
            return Ok(None);
        }
        let candidates = self.loop_candidates(image_id);
        timings.add(Stage::LoopClosure, started.elapsed());
        if self.loops.since_last <= LOOP_GAP_KEYFRAMES {
            return Ok(None);
        }
        for (candidate, score) in candidates {
            let Some(found) = self.verify_loop(image_id, candidate, score, frontend, opts, timings)? else { continue };
            let closure = self.apply_loop(image_id, &found, frontend, opts, timings)?;
            tracing::info!(
                "map {}: loop closed, frame {} to frame {} ({} inliers, scale {:.3}, {:.1} deg, {} keyframes corrected)",
                self.index,
                closure.frame,
                closure.loop_frame,
                closure.inliers,
                closure.scale,
                closure.rotation_deg,
                closure.keyframes_corrected
            );
            self.loops.closed.push(closure.clone());
            self.loops.since_last = 0;
            self.loops.groups.clear();
            return Ok(Some(closure));
        }
        Ok(None)
    }

    /// Adds the keyframe to the place index, training (or retraining, once
    /// the keyframes doubled) the vocabulary first. False while the map is
    /// too young or its descriptors are not binary.
    fn index_keyframe(&mut self, image_id: ImageId) -> bool {
        let n = self.keyframes.len();
        if n < LOOP_MIN_KEYFRAMES {
            return false;
        }
        if self.loops.vocab.is_none() || n >= 2 * self.loops.trained_on {
            let docs: Option<Vec<&[[u64; 4]]>> = self.keyframes.iter().map(binary).collect();
            let Some(docs) = docs else { return false };
            let vocab = Vocabulary::train(&docs, &VocabularyOptions::default());
            let mut index = PlaceIndex::default();
            let mut bows = BTreeMap::new();
            for (k, d) in self.keyframes.iter().zip(&docs) {
                let bow = vocab.transform(d);
                index.add(k.image_id.0, &bow);
                bows.insert(k.image_id, bow);
            }
            tracing::debug!("map {}: vocabulary of {} words on {n} keyframes", self.index, vocab.num_words());
            (self.loops.vocab, self.loops.index, self.loops.bows, self.loops.trained_on) =
                (Some(vocab), index, bows, n);
            return true;
        }
        let Some(kf) = self.keyframes.iter().find(|k| k.image_id == image_id) else { return false };
        let (Some(vocab), Some(d)) = (&self.loops.vocab, binary(kf)) else { return false };
        let bow = vocab.transform(d);
        self.loops.index.add(image_id.0, &bow);
        self.loops.bows.insert(image_id, bow);
        true
    }

    /// The loop candidates of `image_id` that were consistent over
    /// [`LOOP_CONSISTENCY`] consecutive keyframes, best score first; updates
    /// the consistency groups.
    fn loop_candidates(&mut self, image_id: ImageId) -> Vec<(ImageId, f32)> {
        let Some(bow) = self.loops.bows.get(&image_id) else { return Vec::new() };
        let connected: BTreeSet<ImageId> = covisible_images(&self.rec, image_id, 1, usize::MAX).into_iter().collect();
        let neighbours = covisible_images(&self.rec, image_id, LOOP_NEIGHBOUR_MIN_SHARED, LOOP_NEIGHBOURS);
        let min_score = neighbours
            .iter()
            .filter_map(|n| self.loops.bows.get(n))
            .map(|b| bow_score(bow, b))
            .fold(f32::INFINITY, f32::min);
        if !min_score.is_finite() {
            return Vec::new();
        }
        let registered = |id: ImageId| self.rec.image(id).is_some_and(|i| i.registered);
        let hits: Vec<(ImageId, f32)> = self
            .loops
            .index
            .query(bow)
            .into_iter()
            .map(|(doc, s)| (ImageId(doc), s))
            .filter(|(id, s)| *id != image_id && !connected.contains(id) && *s >= min_score && registered(*id))
            .filter(|(id, _)| self.loops.bows.contains_key(id))
            .take(LOOP_MAX_CANDIDATES)
            .collect();
        let mut groups = Vec::new();
        let mut out = Vec::new();
        for (id, score) in hits {
            let mut group: BTreeSet<ImageId> =
                covisible_images(&self.rec, id, 1, LOOP_NEIGHBOURS).into_iter().collect();
            group.insert(id);
            let previous =
                self.loops.groups.iter().filter(|(g, _)| !g.is_disjoint(&group)).map(|(_, c)| *c).max().unwrap_or(0);
            if previous + 1 >= LOOP_CONSISTENCY {
                out.push((id, score));
            }
            groups.push((group, previous + 1));
        }
        self.loops.groups = groups;
        out
    }

    /// Matches the keyframe to the candidate and its covisible keyframes
    /// and fits the similarity of their 3D-3D correspondences.
    fn verify_loop(
        &self,
        image_id: ImageId,
        candidate: ImageId,
        score: f32,
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Option<VerifiedLoop>, SlamError> {
        let Some(current) = self.keyframe_position(image_id) else { return Ok(None) };
        let mut group = vec![candidate];
        group.extend(covisible_images(&self.rec, candidate, 1, LOOP_MATCH_GROUP));
        let data = &self.keyframes[current].data;
        let mut pairs = Vec::new();
        let mut matches = Vec::new();
        for id in group {
            let Some(k) = self.keyframe_position(id) else { continue };
            let m = timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[k].data))?;
            pairs.extend(self.point_pairs(image_id, id, &m));
            matches.push((k, m));
        }
        if pairs.len() < LOOP_MIN_INLIERS {
            return Ok(None);
        }
        let one_way: Vec<Pair> = pairs.iter().map(|(p, _)| p.clone()).collect();
        let Some(sim) = similarity(self, &one_way, opts.seed ^ u64::from(image_id.0)) else { return Ok(None) };
        // Both ways, as ORB-SLAM's Sim(3) check: the old point must also
        // reproject into the new keyframe where its match was seen.
        let back = sim.inverse();
        let inliers: Vec<Pair> = pairs
            .into_iter()
            .filter(|(p, px)| {
                is_inlier(self, &sim, p) && self.reprojects(image_id, &back.transform_point(&p.target_xyz), px)
            })
            .map(|(p, _)| p)
            .collect();
        tracing::debug!("map {}: loop candidate {candidate:?}: {} Sim(3) inliers", self.index, inliers.len());
        if inliers.len() < LOOP_MIN_INLIERS {
            return Ok(None);
        }
        Ok(Some(VerifiedLoop { candidate, score, sim, inliers, matches }))
    }

    /// The 3D-3D correspondences of matches (query: keyframe `source`,
    /// train: keyframe `target`) between distinct points.
    fn point_pairs(&self, source: ImageId, target: ImageId, matches: &[colslam_features::Match]) -> Vec<(Pair, Vec2)> {
        let (Some(si), Some(ti)) = (self.rec.image(source), self.rec.image(target)) else { return Vec::new() };
        let point = |img: &colslam_scene::Image, kp: u32| {
            let p2 = img.points2d.get(kp as usize)?;
            let pid = p2.point3d_id?;
            Some((pid, self.rec.point3d(pid)?.xyz, p2.xy))
        };
        matches
            .iter()
            .filter_map(|m| {
                let (sp, sx, spx) = point(si, m.query)?;
                let (tp, tx, px) = point(ti, m.train)?;
                let pair = Pair {
                    source_point: sp,
                    target_point: tp,
                    source_xyz: sx,
                    target_xyz: tx,
                    target_image: target,
                    target_pixel: px,
                };
                (sp != tp).then_some((pair, spx))
            })
            .collect()
    }

    /// True when `xyz` projects into image `image` within
    /// [`LOOP_MAX_REPROJ_PX`] of `pixel`.
    fn reprojects(&self, image: ImageId, xyz: &Vec3, pixel: &Vec2) -> bool {
        reprojects_within(self, image, xyz, pixel, LOOP_MAX_REPROJ_PX)
    }

    /// Corrects the poses and points, fuses the loop's points and matches,
    /// and refines the map globally.
    fn apply_loop(
        &mut self,
        image_id: ImageId,
        found: &VerifiedLoop,
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<LoopClosure, SlamError> {
        let started = std::time::Instant::now();
        let frame_of = |m: &Mapper, id: ImageId| m.keyframe_position(id).map_or(0, |k| m.keyframes[k].data.index());
        let before = self.rec.image(image_id).map(|i| i.cam_from_world.center()).unwrap_or_else(Vec3::zeros);
        let pivot = found.inliers.iter().map(|p| p.source_xyz).sum::<Vec3>() / found.inliers.len().max(1) as f64;
        let corrected = self.correct_loop_poses(image_id, found.candidate, &found.sim, &pivot);
        let after = self.rec.image(image_id).map(|i| i.cam_from_world.center()).unwrap_or_else(Vec3::zeros);
        let pairs: Vec<(Point3DId, Point3DId)> =
            found.inliers.iter().map(|p| (p.target_point, p.source_point)).collect();
        let mut merged = merge_point_pairs(&mut self.rec, &pairs)?;
        // Fusion's matching, track work and the global BA count in their
        // own stages.
        timings.add(Stage::LoopClosure, started.elapsed());
        merged += self.fuse_loop(image_id, found, frontend, timings)?;
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || complete_and_merge_all(&mut self.rec, &self.graph, &tri))?;
        self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        Ok(LoopClosure {
            frame: frame_of(self, image_id),
            loop_frame: frame_of(self, found.candidate),
            score: found.score,
            inliers: found.inliers.len(),
            merged_points: merged,
            keyframes_corrected: corrected,
            scale: found.sim.scale,
            rotation_deg: found.sim.rotation.angle().to_degrees(),
            translation: (after - before).norm(),
        })
    }

    /// Loop fusion on the corrected map: the closing keyframe and its
    /// covisible keyframes are matched to the candidate's group (the closing
    /// keyframe's matches are the verification's); matches that agree with
    /// the corrected poses go into the correspondence graph, and matched
    /// points that now coincide (reprojection, as the verification) are
    /// merged. Returns the points merged.
    fn fuse_loop(
        &mut self,
        image_id: ImageId,
        found: &VerifiedLoop,
        frontend: &Frontend,
        timings: &mut StageTimings,
    ) -> Result<usize, SlamError> {
        let focal = self.focal()?;
        let mut sources = vec![image_id];
        sources.extend(covisible_images(&self.rec, image_id, 1, LOOP_MATCH_GROUP));
        let targets: Vec<usize> = found.matches.iter().map(|(k, _)| *k).collect();
        let mut merged = 0;
        let target_ids: Vec<ImageId> = targets.iter().map(|&t| self.keyframes[t].image_id).collect();
        // A neighbour of the closing keyframe may already be in the
        // candidate's group (it saw both sides): nothing to fuse there.
        sources.retain(|s| !target_ids.contains(s));
        for source in sources {
            let (Some(s), Some(pose)) =
                (self.keyframe_position(source), self.rec.image(source).map(|i| i.cam_from_world))
            else {
                continue;
            };
            let data = &self.keyframes[s].data;
            let fresh;
            let matches = if source == image_id {
                &found.matches
            } else {
                let mut out = Vec::with_capacity(targets.len());
                for &t in &targets {
                    let m = timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[t].data))?;
                    out.push((t, m));
                }
                fresh = out;
                &fresh
            };
            let verified = self.verified_matches(data, &pose, matches, focal, VERIFY_MAX_ERROR_PX);
            self.add_correspondences(source, &verified)?;
            let identity = Sim3::identity();
            let pairs: Vec<(Point3DId, Point3DId)> = matches
                .iter()
                .flat_map(|(t, m)| self.point_pairs(source, self.keyframes[*t].image_id, m))
                .filter(|(p, px)| is_inlier(self, &identity, p) && self.reprojects(source, &p.target_xyz, px))
                .map(|(p, _)| (p.target_point, p.source_point))
                .collect();
            merged += merge_point_pairs(&mut self.rec, &pairs)?;
        }
        Ok(merged)
    }

    /// Moves the keyframes registered after `candidate` (up to `image_id`)
    /// by `sim` interpolated along the keyframe order, and each point by
    /// its observers' mean share; returns the keyframes moved.
    fn correct_loop_poses(&mut self, image_id: ImageId, candidate: ImageId, sim: &Sim3, pivot: &Vec3) -> usize {
        let (Some(c), Some(n)) = (self.keyframe_position(candidate), self.keyframe_position(image_id)) else {
            return 0;
        };
        if n <= c {
            return 0;
        }
        let share: HashMap<ImageId, f64> = self
            .keyframes
            .iter()
            .enumerate()
            .map(|(i, k)| (k.image_id, if i <= c { 0.0 } else { ((i - c) as f64 / (n - c) as f64).min(1.0) }))
            .collect();
        let mut moved = 0;
        for (&id, &t) in &share {
            let Some(pose) = self.rec.cam_from_world_mut(id) else { continue };
            if t > 0.0 {
                *pose = transform_cam_from_world(&interpolate(sim, pivot, t), pose);
                moved += 1;
            }
        }
        for pid in self.rec.point3d_ids() {
            let Some(p) = self.rec.point3d(pid) else { continue };
            let shares: Vec<f64> = p.track.iter().filter_map(|e| share.get(&e.image_id).copied()).collect();
            let t = shares.iter().sum::<f64>() / shares.len().max(1) as f64;
            if t > 0.0
                && let Some(x) = self.rec.point3d_xyz_mut(pid)
            {
                *x = interpolate(sim, pivot, t).transform_point(x);
            }
        }
        moved
    }
}

/// The share `t` in [0, 1] of `sim`, about `pivot`: scale `s^t`, rotation
/// `R^t` about the pivot and `t` of the pivot's displacement (identity at 0,
/// `sim` at 1), so the drift is spread without swinging far points about
/// the world origin.
fn interpolate(sim: &Sim3, pivot: &Vec3, t: f64) -> Sim3 {
    let scale = sim.scale.powf(t);
    let rotation: Quat = sim.rotation.powf(t);
    let target = pivot + t * (sim.transform_point(pivot) - pivot);
    Sim3 { scale, rotation, translation: target - scale * (rotation * pivot) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_goes_from_identity_to_the_similarity() {
        let sim = Sim3 {
            scale: 1.3,
            rotation: Quat::from_euler_angles(0.1, -0.2, 0.4),
            translation: Vec3::new(0.5, -1.0, 2.0),
        };
        let (pivot, x) = (Vec3::new(1.0, 2.0, 3.0), Vec3::new(-2.0, 0.5, 4.0));
        assert!((interpolate(&sim, &pivot, 0.0).transform_point(&x) - x).norm() < 1e-12);
        assert!((interpolate(&sim, &pivot, 1.0).transform_point(&x) - sim.transform_point(&x)).norm() < 1e-12);
        let half = interpolate(&sim, &pivot, 0.5);
        assert!((half.scale - 1.3f64.sqrt()).abs() < 1e-12);
        let mid = half.transform_point(&pivot);
        assert!((mid - (pivot + sim.transform_point(&pivot)) / 2.0).norm() < 1e-12);
    }
}

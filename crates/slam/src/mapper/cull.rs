//! Keyframe culling (`--cull-keyframes`): ORB-SLAM's `KeyFrameCulling`
//! (Mur-Artal et al., ORB-SLAM 2015, section VI.E; ORB-SLAM3's
//! `LocalMapping::KeyFrameCulling`). A keyframe whose 3D points are almost
//! all seen by at least three other keyframes at the same or a finer scale
//! adds nothing the map needs: revisiting mapped space otherwise adds
//! keyframes (and their features, graph and observations) as new space does.
//!
//! A culled keyframe leaves the reconstruction and the correspondence graph
//! as COLMAP's `Reconstruction::DeRegisterImage` / `DeleteObservation` leave
//! a model (its observations leave their tracks, points left with fewer than
//! two are deleted), and then the image itself. Its frame stays in the
//! trajectory: it becomes a compact record like any non-keyframe, its
//! keypoints linked to other keyframes' observations of the same 3D points,
//! and is localised at the end. Records that referred to its keypoints are
//! relinked the same way.

use super::state::Mapper;
use crate::error::SlamError;
use crate::frame::{FrameRecord, RecordObs};
use crate::options::{CULL_MIN_OBSERVERS, CULL_RECORD_LINKS, CULL_REDUNDANT_SHARE, SlamOptions};
use colslam_scene::{ImageId, TrackElement};
use std::collections::HashMap;

/// For each keypoint of a culled keyframe, the keypoints of other keyframes
/// it stays linked to (at most [`CULL_RECORD_LINKS`]).
type Links = Vec<Vec<TrackElement>>;

impl Mapper {
    /// Culls the redundant keyframes of the local bundle of `image_id` (the
    /// newest keyframe, which stays, as do the initial pair's); returns how
    /// many were culled. Candidates are checked in the bundle's order, each
    /// against the map as the previous culls left it.
    pub(super) fn cull_keyframes(&mut self, image_id: ImageId, opts: &SlamOptions) -> Result<usize, SlamError> {
        let bundle: Vec<ImageId> = self.local_bundle(image_id, opts).into_iter().filter(|&id| id != image_id).collect();
        self.cull_among(bundle)
    }

    /// Culls the redundant keyframes of the whole map, oldest first, once
    /// tracking ended: culling after each registration only sees the local
    /// bundle of the newest keyframe, so the last keyframes of a revisit
    /// (no newer keyframe's bundle holds them) and old keyframes outside
    /// every later bundle are never checked otherwise. Returns how many were
    /// culled.
    pub fn cull_all_keyframes(&mut self) -> Result<usize, SlamError> {
        let all: Vec<ImageId> = self.keyframes.iter().map(|k| k.image_id).collect();
        self.cull_among(all)
    }

    /// Culls the redundant keyframes among `ids` (never the initial pair's),
    /// each checked against the map as the previous culls left it.
    fn cull_among(&mut self, ids: Vec<ImageId>) -> Result<usize, SlamError> {
        let (first, second) = self.initial_frames;
        let candidates: Vec<ImageId> = ids
            .into_iter()
            .filter(|&id| {
                self.keyframe_position(id).is_some_and(|k| ![first, second].contains(&self.keyframes[k].data.index()))
            })
            .collect();
        let mut culled = 0;
        for id in candidates {
            if self.is_redundant(id) {
                self.cull(id)?;
                culled += 1;
            }
        }
        self.culled += culled;
        Ok(culled)
    }

    /// The pyramid level of keypoint `idx` of the keyframe of image `id`.
    fn keypoint_level(&self, positions: &HashMap<ImageId, usize>, id: ImageId, idx: u32) -> Option<i32> {
        let kf = &self.keyframes[*positions.get(&id)?];
        kf.data.features.keypoints.get(idx as usize).map(|k| i32::from(k.octave))
    }

    /// True when more than [`CULL_REDUNDANT_SHARE`] of the keyframe's 3D
    /// points are seen by [`CULL_MIN_OBSERVERS`] other keyframes at its
    /// keypoint's pyramid level or finer, one level of slack as ORB-SLAM
    /// allows (a coarser observation locates the point less well).
    pub(super) fn is_redundant(&self, id: ImageId) -> bool {
        let Some(img) = self.rec.image(id).filter(|i| i.registered) else { return false };
        let positions: HashMap<ImageId, usize> =
            self.keyframes.iter().enumerate().map(|(k, kf)| (kf.image_id, k)).collect();
        let (mut points, mut redundant) = (0usize, 0usize);
        for (idx, p2) in img.points2d.iter().enumerate() {
            let Some(point) = p2.point3d_id.and_then(|pid| self.rec.point3d(pid)) else { continue };
            points += 1;
            if point.track.len() <= CULL_MIN_OBSERVERS {
                continue;
            }
            let Some(level) = self.keypoint_level(&positions, id, idx as u32) else { continue };
            let observers = point
                .track
                .iter()
                .filter(|e| e.image_id != id)
                .filter(|e| self.keypoint_level(&positions, e.image_id, e.point2d_idx).is_some_and(|l| l <= level + 1))
                .count();
            redundant += usize::from(observers >= CULL_MIN_OBSERVERS);
        }
        points > 0 && redundant as f64 > CULL_REDUNDANT_SHARE * points as f64
    }

    /// Removes the keyframe of image `id` from the map, turning its frame
    /// into a record and relinking the records that referred to it.
    fn cull(&mut self, id: ImageId) -> Result<(), SlamError> {
        let Some(k) = self.keyframe_position(id) else { return Ok(()) };
        let links = self.links_of(id);
        let kf = self.keyframes.remove(k);
        let mut record = FrameRecord::new(&kf.data);
        for (kp, to) in links.iter().enumerate() {
            let Some(px) = kf.data.pixels.get(kp) else { continue };
            for el in to {
                record.obs.push(RecordObs::new(kp as u32, *px, el.image_id, el.point2d_idx));
            }
        }
        // Records that matched it follow its keypoints' first links.
        let first = links.iter().map(|l| l.first().copied()).collect();
        self.records.cull(id, kf.data.index(), first);
        self.records.push(record)?;
        let report = self.rec.delete_image(id)?;
        self.graph.delete_image(id)?;
        if self.sigmas.contains_key(&id) {
            std::sync::Arc::make_mut(&mut self.sigmas).remove(&id);
        }
        tracing::debug!(
            "map {}: culled the keyframe of frame {} ({} observations, {} points deleted), {} keyframes left",
            self.index,
            kf.data.index(),
            report.observations_removed,
            report.points_deleted.len(),
            self.keyframes.len()
        );
        Ok(())
    }

    /// Each keypoint's links to other keyframes: the other observations of
    /// its 3D point, else its correspondences in the graph (a point may
    /// still be triangulated there).
    fn links_of(&self, id: ImageId) -> Links {
        let Some(img) = self.rec.image(id) else { return Vec::new() };
        img.points2d
            .iter()
            .enumerate()
            .map(|(idx, p2)| {
                let track = p2.point3d_id.and_then(|pid| self.rec.point3d(pid)).map(|p| &p.track);
                let from_track = track.into_iter().flatten().filter(|e| e.image_id != id).copied();
                let mut to: Vec<TrackElement> = from_track.take(CULL_RECORD_LINKS).collect();
                if to.is_empty() {
                    let corrs = self.graph.correspondences(id, idx as u32);
                    to.extend(
                        corrs.iter().take(CULL_RECORD_LINKS).map(|c| TrackElement::new(c.image_id, c.point2d_idx)),
                    );
                }
                to
            })
            .collect()
    }
}

//! Localisation of every frame against a finished map (beyond the paper,
//! which keeps only keyframes), and the optional refinement with all of them
//! (COLMAP registers every image).

use super::state::Mapper;
use crate::error::SlamError;
use crate::frame::{FrameId, FramePose, FrameRecord};
use crate::options::{GlobalBaTolerance, SlamOptions};
use crate::timing::{Stage, StageTimings};
use colslam_camera::Camera;
use colslam_estimators::{estimate_absolute_pose, estimate_absolute_pose_guided};
use colslam_geometry::{Vec2, Vec3};
use colslam_scene::{Image, ImageId, Point3DId, TrackElement};
use colslam_sfm::SfmError;
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap, HashSet};

/// A localised frame's PnP inliers: (normalised keypoint, 3D point).
pub type FrameInliers = Vec<(Vec2, Point3DId)>;

/// What [`Mapper::localize_all`] returns.
#[derive(Debug, Clone, Default)]
pub struct Localization {
    /// Poses of keyframes and localised frames, one per frame, in frame order.
    pub poses: Vec<FramePose>,
    /// Records that could not be localised, in frame order.
    pub failed: Vec<crate::frame::FrameId>,
    /// Each localised frame's inliers, by frame index.
    pub inliers: HashMap<usize, FrameInliers>,
}

/// Keyframes whose correspondences a weakly localised frame's PnP samples
/// from, one group at a time ([`Mapper::localize`]), the largest first.
const GUIDED_POOLS: usize = 8;

/// The inlier ratio the samples from one keyframe's correspondences are
/// sized for: a keyframe that shares the frame's view holds a quarter or so
/// of inliers among its matches (herzjesu's frame 13: 26 %), and the trial
/// cap (about 3,400 trials at 0.9999 confidence) keeps a keyframe that does
/// not from costing a full RANSAC.
const GUIDED_MIN_POOL_RATIO: f64 = 0.2;

/// Frames localised per batch: the spilled records of one batch are read
/// back into memory together, so the batch bounds that memory while leaving
/// the threads enough frames to share.
const LOCALIZE_BATCH: usize = 256;

impl Mapper {
    /// Poses of the registered keyframes, in keyframe order.
    fn keyframe_poses(&self) -> Vec<FramePose> {
        self.keyframes
            .iter()
            .filter_map(|k| {
                let img = self.rec.image(k.image_id)?;
                img.registered.then(|| FramePose {
                    frame: k.data.id.clone(),
                    cam_from_world: img.cam_from_world,
                    keyframe: true,
                })
            })
            .collect()
    }

    /// Poses of every keyframe and every localised non-keyframe, in frame
    /// order, and the records that could not be localised.
    pub fn localize_all(&self, opts: &SlamOptions, timings: &mut StageTimings) -> Result<Localization, SlamError> {
        let focal = self.focal()?;
        let camera = self.camera()?;
        let mut poses = self.keyframe_poses();
        let keyframe_frames: HashSet<usize> = poses.iter().map(|p| p.frame.index).collect();
        let started = std::time::Instant::now();
        // One record per frame: a frame can hold several (tracked by two
        // maps that were merged, tracked backwards and relocalised), whose
        // observations are pooled; a frame promoted anywhere is a keyframe.
        let mut results: Vec<(FrameId, Option<(FramePose, FrameInliers)>)> = Vec::new();
        for batch in self.records.groups().chunks(LOCALIZE_BATCH) {
            let pooled = batch.iter().map(|g| self.records.pooled(g)).collect::<Result<Vec<_>, _>>()?;
            let done: Vec<(FrameId, Option<(FramePose, FrameInliers)>)> = pooled
                .par_iter()
                .flatten()
                .filter(|r| !r.promoted && !keyframe_frames.contains(&r.frame.index) && opts.refine.localize_all_frames)
                .map(|r| (r.frame.clone(), self.localize(r, camera, focal, opts)))
                .collect();
            results.extend(done);
        }
        timings.add(Stage::Localization, started.elapsed());
        let mut out = Localization::default();
        for (frame, res) in results {
            match res {
                Some((p, inl)) => {
                    out.inliers.insert(p.frame.index, inl);
                    poses.push(p);
                }
                None => out.failed.push(frame),
            }
        }
        // One pose per frame (a keyframe first: the sort is stable and
        // keyframes were pushed first).
        poses.sort_by_key(|p| p.frame.index);
        poses.dedup_by_key(|p| p.frame.index);
        out.failed.sort_by_key(|f| f.index);
        out.poses = poses;
        Ok(out)
    }

    /// The pose of one record by PnP against the map's points, with its
    /// inliers; `None` when too few correspondences or PnP fails.
    pub(crate) fn localize(
        &self,
        record: &FrameRecord,
        camera: &Camera,
        focal: f64,
        opts: &SlamOptions,
    ) -> Option<(FramePose, FrameInliers)> {
        let mut used_kp = HashSet::new();
        let mut used_pt = HashSet::new();
        let (mut p2, mut p3): (Vec<Vec2>, Vec<Vec3>) = (Vec::new(), Vec::new());
        let mut pids = Vec::new();
        // Each correspondence's place, by the keyframe whose match gave it.
        let mut by_keyframe: BTreeMap<ImageId, Vec<usize>> = BTreeMap::new();
        for (k, o) in record.obs.iter().enumerate() {
            let Some(img) = self.rec.image(o.keyframe) else { continue };
            if !img.registered {
                continue;
            }
            let Some(pid) = img.points2d.get(o.keyframe_kp as usize).and_then(|p| p.point3d_id) else { continue };
            let Some(p) = self.rec.point3d(pid) else { continue };
            if used_kp.contains(&o.frame_kp) || used_pt.contains(&pid) {
                continue;
            }
            let Some(n) = record.normalized(k, camera) else { continue };
            used_kp.insert(o.frame_kp);
            used_pt.insert(pid);
            p2.push(n);
            p3.push(p.xyz);
            pids.push(pid);
            by_keyframe.entry(o.keyframe).or_default().push(p2.len() - 1);
        }
        if p2.len() < opts.mapper.abs_pose_min_inliers {
            tracing::trace!("frame {}: not localised: {} 2D-3D correspondences", record.frame.index, p2.len());
            return None;
        }
        let pose_opts = opts.mapper.absolute_pose(focal, opts.seed ^ record.frame.index as u64);
        let plain = estimate_absolute_pose(&p2, &p3, &pose_opts);
        // Below the inlier ratio RANSAC's trial cap is sized for, whether a
        // sample of inliers was drawn at all is chance: a frame of a photo
        // set matched to many keyframes, few of which see what it sees
        // (herzjesu's frame 13: 68 inliers among 1,353 correspondences, 64
        // of them among the 246 of one keyframe's matches). Then samples
        // are drawn from one keyframe's correspondences at a time (the
        // largest groups first), support counted over all of them, and the
        // pose with the most inliers is kept.
        let weak = plain.as_ref().map_or(true, |p| p.inlier_ratio < pose_opts.ransac.min_inlier_ratio);
        let reason = plain.as_ref().err().map(ToString::to_string);
        let mut best = plain.ok();
        if weak {
            let mut pools: Vec<Vec<usize>> = by_keyframe
                .into_values()
                .filter(|g| g.len() >= opts.mapper.abs_pose_min_inliers && g.len() < p2.len())
                .collect();
            pools.sort_by_key(|g| std::cmp::Reverse(g.len()));
            pools.truncate(GUIDED_POOLS);
            let mut guided_opts = pose_opts.clone();
            guided_opts.ransac.min_inlier_ratio = GUIDED_MIN_POOL_RATIO;
            for pool in &pools {
                let Ok(g) = estimate_absolute_pose_guided(&p2, &p3, pool, &guided_opts) else { continue };
                tracing::trace!(
                    "frame {}: samples from one keyframe's {} of {} correspondences: {} inliers",
                    record.frame.index,
                    pool.len(),
                    p2.len(),
                    g.num_inliers
                );
                if best.as_ref().is_none_or(|b| g.num_inliers > b.num_inliers) {
                    best = Some(g);
                }
            }
        }
        let Some(pose) = best else {
            tracing::trace!(
                "frame {}: not localised from {} 2D-3D correspondences: {}",
                record.frame.index,
                p2.len(),
                reason.unwrap_or_default()
            );
            return None;
        };
        let inliers: FrameInliers =
            p2.iter().zip(&pids).zip(&pose.inlier_mask).filter(|(_, m)| **m).map(|((n, pid), _)| (*n, *pid)).collect();
        tracing::trace!(
            "frame {}: localised, {} of {} 2D-3D correspondences",
            record.frame.index,
            inliers.len(),
            p2.len()
        );
        let fp = FramePose { frame: record.frame.clone(), cam_from_world: pose.cam_from_world, keyframe: false };
        Some((fp, inliers))
    }

    /// Adds every localised non-keyframe to the model with its PnP inlier
    /// observations and bundle adjusts everything together (as COLMAP
    /// registers every image); the frames' poses are then read back from the
    /// model. Frames are added under their own names, so the written model
    /// holds every localised frame.
    pub fn refine_with_all_frames(
        &mut self,
        poses: &mut [FramePose],
        inliers: &HashMap<usize, FrameInliers>,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(), SfmError> {
        let camera = self.camera()?.clone();
        let mut added: HashMap<usize, ImageId> = HashMap::new();
        for p in poses.iter().filter(|p| !p.keyframe) {
            let Some(obs) = inliers.get(&p.frame.index) else { continue };
            let live: Vec<&(Vec2, Point3DId)> =
                obs.iter().filter(|(_, pid)| self.rec.point3d(*pid).is_some()).collect();
            if live.len() < opts.mapper.abs_pose_min_inliers {
                continue;
            }
            let id = self.rec.next_image_id();
            let pixels: Vec<Vec2> = live.iter().map(|(n, _)| camera.img_from_normalized(n)).collect();
            let mut img = Image::new(id, p.frame.name.clone(), self.camera_id, pixels);
            img.cam_from_world = p.cam_from_world;
            self.rec.add_image(img)?;
            self.rec.register_image(id)?;
            for (k, (_, pid)) in live.iter().enumerate() {
                let taken = self.rec.point3d(*pid).is_none_or(|pt| pt.track.iter().any(|e| e.image_id == id));
                if !taken {
                    self.rec.add_observation(*pid, TrackElement::new(id, k as u32))?;
                }
            }
            added.insert(p.frame.index, id);
        }
        if added.is_empty() {
            return Ok(());
        }
        self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        let kf_ids: HashMap<usize, ImageId> = self.keyframes.iter().map(|k| (k.data.index(), k.image_id)).collect();
        for p in poses.iter_mut() {
            let id = if p.keyframe { kf_ids.get(&p.frame.index) } else { added.get(&p.frame.index) };
            if let Some(img) = id.and_then(|id| self.rec.image(*id)).filter(|i| i.registered) {
                p.cam_from_world = img.cam_from_world;
            }
        }
        Ok(())
    }
}

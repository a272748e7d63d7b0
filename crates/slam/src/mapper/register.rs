//! Keyframe registration (paper 3.5, 3.6), as the steps of COLMAP's
//! `IncrementalMapper::RegisterNextImage` and the local refinement that
//! follows it: 2D-3D correspondences through the matches to recent
//! keyframes, PnP + LO-RANSAC, verified matches into the correspondence
//! graph, track continuation, triangulation, local bundle adjustment, local
//! filtering, and deregistration of a keyframe that keeps too few points.

use super::state::{Keyframe, Mapper, keypoint_sigmas};
use crate::error::SlamError;
use crate::frame::FrameData;
use crate::frontend::Frontend;
use crate::options::{
    LOCAL_BA_MAX_COVISIBLE, REVISIT_MAX_ANGLE_DEG, REVISIT_MAX_SPACINGS, SlamOptions, VERIFY_MAX_ERROR_PX,
};
use crate::timing::{Stage, StageTimings};
use colslam_estimators::{
    AbsolutePoseReport, EstimatorError, essential_from_pose, estimate_absolute_pose, sampson_error_sq,
};
use colslam_features::Match;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_scene::{Image, ImageId, Point3DId, TrackElement};
use colslam_sfm::SfmError;
use colslam_sfm::bundle::{adjust_local_bundle, covisible_images, most_connected_images};
use colslam_sfm::triangulator::{complete_and_merge_image, retriangulate, triangulate_image};
use std::collections::{BTreeSet, HashSet};

/// Why a keyframe candidate was not registered.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegisterFailure {
    /// Too few 2D-3D correspondences.
    #[error("only {0} 2D-3D correspondences")]
    TooFewCorrespondences(usize),
    /// Absolute pose estimation failed.
    #[error("absolute pose failed: {0}")]
    PoseFailed(EstimatorError),
    /// The keyframe kept too few points after triangulation and filtering.
    #[error("kept only {0} 3D points, deregistered")]
    TooFewPoints(usize),
}

/// The outcome of [`Mapper::register_keyframe`].
#[derive(Debug, Clone, PartialEq)]
pub enum Registration {
    /// Registered under this image id.
    Registered(ImageId),
    /// Not registered; the map is as before.
    Rejected(RegisterFailure),
}

/// Matches of a candidate to keyframes, by keyframe position.
type KeyframeMatches = Vec<(usize, Vec<Match>)>;

/// 2D-3D correspondences: normalised keypoints, 3D points, and for each the
/// keypoint index and point id. One per keypoint and one per 3D point.
#[derive(Debug, Default)]
pub(crate) struct Correspondences {
    pub(crate) points2d: Vec<Vec2>,
    pub(crate) points3d: Vec<Vec3>,
    pub(crate) ids: Vec<(u32, Point3DId)>,
}

impl Mapper {
    /// Registers a keyframe candidate (paper 3.5) and refines the map around
    /// it. `matches_to_last` are its matches (query = candidate) to the
    /// last keyframe, its reference.
    pub fn register_keyframe(
        &mut self,
        data: &FrameData,
        matches_to_last: &[Match],
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Registration, SlamError> {
        let last = self.keyframes.len().saturating_sub(1);
        self.register_keyframe_from(data, last, matches_to_last, frontend, opts, timings)
    }

    /// [`Self::register_keyframe`] for a candidate whose reference is the
    /// keyframe at position `reference` (map reuse: the keyframe that covers
    /// its view best), `matches_to_last` its matches to it.
    pub fn register_keyframe_from(
        &mut self,
        data: &FrameData,
        reference: usize,
        matches_to_last: &[Match],
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Registration, SlamError> {
        let focal = self.focal()?;
        // `data` was normalised with the camera as it is now (the caller's
        // duty); local refinement below may refine it.
        let version = self.intrinsics_version;
        let recent = self.registration_keyframes(reference, opts.mapper.match_keyframes);
        let mut kf_matches = self.match_recent(data, &recent, matches_to_last, frontend, timings)?;
        let started = std::time::Instant::now();
        let corr = self.correspondences(data, &kf_matches);
        tracing::trace!(
            "frame {}: {} matches to the last keyframe, {} keyframe points with 3D, {} 2D-3D",
            data.index(),
            matches_to_last.len(),
            self.keyframes.last().and_then(|k| self.rec.image(k.image_id)).map_or(0, Image::num_points3d),
            corr.points2d.len()
        );
        let seed = opts.seed ^ data.index() as u64;
        let pose = match self.estimate_pose(&corr, focal, seed, opts) {
            Ok(p) => p,
            Err(failure) => {
                timings.add(Stage::Registration, started.elapsed());
                return Ok(Registration::Rejected(failure));
            }
        };
        let (corr, pose) = if opts.mapper.local_map_keyframes > 0 {
            self.track_local_map(data, corr, pose, focal, seed, opts)
        } else {
            (corr, pose)
        };
        // Older keyframes that look the same way (the camera came back to a
        // view it mapped before): matching them too ties the new keyframe's
        // tracks to the old points, which holds the map's scale and shape
        // together where short-baseline keyframes alone drift (a pose-guided
        // form of ORB-SLAM's covisibility matching and loop closing).
        for k in self.revisited_keyframes(&pose.cam_from_world, &recent, opts.mapper.match_revisited) {
            let m = timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[k].data))?;
            kf_matches.push((k, m));
        }
        let image_id = self.add_keyframe_image(data, pose.cam_from_world, opts)?;
        self.refresh_keyframes(kf_matches.iter().map(|(k, _)| *k))?;
        self.add_verified_matches(data, image_id, &pose.cam_from_world, &kf_matches, focal, VERIFY_MAX_ERROR_PX)?;
        self.continue_tracks(image_id, &corr, &pose.inlier_mask)?;
        timings.add(Stage::Registration, started.elapsed());
        let registered = self.probe_registered(image_id, data.index());
        self.triangulate(image_id, opts, timings)?;
        let triangulated = registered.map(|points| self.probe_triangulated(image_id, data.index(), &points));
        self.local_refine(image_id, data.index(), opts, timings)?;
        if let Some(points) = triangulated {
            self.probe_refined(image_id, data.index(), points);
        }
        let kept = self.rec.image(image_id).map_or(0, Image::num_points3d);
        if kept < opts.mapper.min_keyframe_points {
            self.deregister(image_id)?;
            return Ok(Registration::Rejected(RegisterFailure::TooFewPoints(kept)));
        }
        self.keyframes.push(Keyframe { image_id, data: data.clone(), version });
        if opts.mapper.cull_keyframes {
            self.cull_keyframes(image_id, opts)?;
        }
        Ok(Registration::Registered(image_id))
    }

    /// Positions of the keyframes a candidate with reference `reference` is
    /// matched against, the reference first: the last `n` keyframes when the
    /// reference is the last (paper 3.5); otherwise (map reuse chose an older
    /// keyframe) the reference, the keyframes sharing most points with it (a
    /// revisit: the recent keyframes may look elsewhere) and the last
    /// keyframe, the candidate's neighbour in time (without it a photo set,
    /// whose every image is a candidate, registers images away from their
    /// predecessor: strecha_castle_P19 lost 0.2-0.7 cm on most seeds).
    fn registration_keyframes(&self, reference: usize, n: usize) -> Vec<usize> {
        let len = self.keyframes.len();
        if reference + 1 >= len {
            return (0..len).rev().take(n).collect();
        }
        let mut out = vec![reference];
        out.extend(self.covisible_keyframes(reference, n.saturating_sub(1)));
        if !out.contains(&(len - 1)) {
            out.push(len - 1);
        }
        out
    }

    /// Position of the keyframe registered as `image_id`, if it is one.
    pub fn keyframe_position(&self, image_id: ImageId) -> Option<usize> {
        self.keyframes.iter().position(|k| k.image_id == image_id)
    }

    /// Positions of the up-to-`n` keyframes sharing the most 3D points with
    /// the keyframe at position `k`, most shared first.
    pub fn covisible_keyframes(&self, k: usize, n: usize) -> Vec<usize> {
        let Some(kf) = self.keyframes.get(k) else { return Vec::new() };
        if n == 0 {
            return Vec::new();
        }
        // Images that are no keyframe (none today) are skipped, hence the margin.
        covisible_images(&self.rec, kf.image_id, 1, 2 * n)
            .into_iter()
            .filter_map(|id| self.keyframe_position(id))
            .take(n)
            .collect()
    }

    /// Matches of `data` to the keyframes at positions `recent` (newest
    /// first); the first is the reference, whose matches are given.
    fn match_recent(
        &self,
        data: &FrameData,
        recent: &[usize],
        matches_to_last: &[Match],
        frontend: &Frontend,
        timings: &mut StageTimings,
    ) -> Result<KeyframeMatches, SlamError> {
        let mut out = Vec::with_capacity(recent.len());
        for (rank, &k) in recent.iter().enumerate() {
            let m = if rank == 0 {
                matches_to_last.to_vec()
            } else {
                timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[k].data))?
            };
            out.push((k, m));
        }
        Ok(out)
    }

    /// 2D-3D correspondences through the matches to keyframes: the first
    /// match of a keypoint and the first of a 3D point win.
    pub(crate) fn correspondences(&self, data: &FrameData, kf_matches: &KeyframeMatches) -> Correspondences {
        let mut used_kp = HashSet::new();
        let mut used_pt = HashSet::new();
        let mut c = Correspondences::default();
        for (k, matches) in kf_matches {
            let Some(img) = self.rec.image(self.keyframes[*k].image_id) else { continue };
            for m in matches {
                let Some(pid) = img.points2d.get(m.train as usize).and_then(|p| p.point3d_id) else { continue };
                let Some(p) = self.rec.point3d(pid) else { continue };
                let Some(n) = data.normalized.get(m.query as usize) else { continue };
                if used_kp.contains(&m.query) || used_pt.contains(&pid) {
                    continue;
                }
                used_kp.insert(m.query);
                used_pt.insert(pid);
                c.points2d.push(*n);
                c.points3d.push(p.xyz);
                c.ids.push((m.query, pid));
            }
        }
        c
    }

    /// Absolute pose from the correspondences, or why not.
    fn estimate_pose(
        &self,
        corr: &Correspondences,
        focal: f64,
        seed: u64,
        opts: &SlamOptions,
    ) -> Result<AbsolutePoseReport, RegisterFailure> {
        if corr.points2d.len() < opts.mapper.abs_pose_min_inliers {
            return Err(RegisterFailure::TooFewCorrespondences(corr.points2d.len()));
        }
        let pose_opts = opts.mapper.absolute_pose(focal, seed);
        estimate_absolute_pose(&corr.points2d, &corr.points3d, &pose_opts).map_err(RegisterFailure::PoseFailed)
    }

    /// Adds and registers a keyframe's image at `pose` (with its keypoint
    /// sigmas when BA weights by pyramid level).
    pub(super) fn add_keyframe_image(
        &mut self,
        data: &FrameData,
        pose: Rigid3,
        opts: &SlamOptions,
    ) -> Result<ImageId, SfmError> {
        let image_id = self.rec.next_image_id();
        let mut img = Image::new(image_id, data.id.name.clone(), self.camera_id, data.pixels.clone());
        img.cam_from_world = pose;
        self.rec.add_image(img)?;
        self.rec.register_image(image_id)?;
        self.graph.add_image(image_id, data.len())?;
        if opts.mapper.weight_by_level {
            std::sync::Arc::make_mut(&mut self.sigmas).insert(image_id, keypoint_sigmas(data));
        }
        Ok(image_id)
    }

    /// Adds the matches to keyframes that agree with the known poses
    /// (Sampson error within `max_error_px`; [`VERIFY_MAX_ERROR_PX`] at
    /// registration) to the correspondence graph.
    pub(super) fn add_verified_matches(
        &mut self,
        data: &FrameData,
        image_id: ImageId,
        pose: &Rigid3,
        kf_matches: &KeyframeMatches,
        focal: f64,
        max_error_px: f64,
    ) -> Result<(), SfmError> {
        let verified = self.verified_matches(data, pose, kf_matches, focal, max_error_px);
        self.add_correspondences(image_id, &verified)
    }

    /// For each keyframe of `kf_matches`, the matches (keyframe keypoint,
    /// frame keypoint) that agree with the known poses: Sampson error within
    /// `max_error_px`. Reads the map only, so `data` may be a keyframe's own.
    pub(super) fn verified_matches(
        &self,
        data: &FrameData,
        pose: &Rigid3,
        kf_matches: &KeyframeMatches,
        focal: f64,
        max_error_px: f64,
    ) -> Vec<(ImageId, Vec<(u32, u32)>)> {
        let max_sampson = (max_error_px / focal).powi(2);
        let mut out = Vec::with_capacity(kf_matches.len());
        for (k, matches) in kf_matches {
            let kf = &self.keyframes[*k];
            let Some(kf_img) = self.rec.image(kf.image_id) else { continue };
            let e = essential_from_pose(&(*pose * kf_img.cam_from_world.inverse()));
            let pairs: Vec<(u32, u32)> = matches
                .iter()
                .filter(|m| {
                    let (Some(xk), Some(xn)) =
                        (kf.data.normalized.get(m.train as usize), data.normalized.get(m.query as usize))
                    else {
                        return false;
                    };
                    sampson_error_sq(&e, xk, xn) <= max_sampson
                })
                .map(|m| (m.train, m.query))
                .collect();
            out.push((kf.image_id, pairs));
        }
        out
    }

    /// Adds [`Self::verified_matches`] of image `image_id` to the
    /// correspondence graph.
    pub(super) fn add_correspondences(
        &mut self,
        image_id: ImageId,
        verified: &[(ImageId, Vec<(u32, u32)>)],
    ) -> Result<(), SfmError> {
        for (kf_id, pairs) in verified {
            self.graph.add_correspondences(*kf_id, image_id, pairs)?;
        }
        Ok(())
    }

    /// Continues the tracks of the PnP inliers into the new image.
    fn continue_tracks(&mut self, image_id: ImageId, corr: &Correspondences, inliers: &[bool]) -> Result<(), SfmError> {
        for ((q, pid), inlier) in corr.ids.iter().zip(inliers) {
            if !inlier {
                continue;
            }
            let Some(p) = self.rec.point3d(*pid) else { continue };
            if p.track.iter().any(|e| e.image_id == image_id) {
                continue;
            }
            self.rec.add_observation(*pid, TrackElement::new(image_id, *q))?;
        }
        Ok(())
    }

    /// Triangulates the new image's correspondences and retriangulates its
    /// under-reconstructed pairs. Tracks are completed and merged after local
    /// BA, as COLMAP's iterative local refinement does.
    fn triangulate(
        &mut self,
        image_id: ImageId,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(), SfmError> {
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || -> Result<(), SfmError> {
            triangulate_image(&mut self.rec, &self.graph, image_id, &tri)?;
            retriangulate(&mut self.rec, &self.graph, Some(&[image_id]), &tri)?;
            Ok(())
        })
    }

    /// The local bundle of a new image: it and its most connected images,
    /// or its covisible ones with `--local-ba-covisible`.
    pub(crate) fn local_bundle(&self, image_id: ImageId, opts: &SlamOptions) -> Vec<ImageId> {
        let mut bundle = vec![image_id];
        let (m, n) = (&opts.mapper, LOCAL_BA_MAX_COVISIBLE - 1);
        match m.local_ba_covisible {
            0 => bundle.extend(most_connected_images(&self.rec, image_id, m.local_ba_images - 1)),
            min => bundle.extend(covisible_images(&self.rec, image_id, min, n)),
        }
        // A young map's new keyframe may share fewer points than that with
        // every other: then its most connected one joins it.
        if bundle.len() < 2 {
            bundle.extend(most_connected_images(&self.rec, image_id, 1));
        }
        bundle
    }

    /// Local refinement (paper 3.6): local bundle adjustment around the new
    /// image, then completion/merging of its tracks and filtering of the
    /// points of the local bundle.
    fn local_refine(
        &mut self,
        image_id: ImageId,
        frame: usize,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(), SfmError> {
        let ba_opts = opts.mapper.local_ba(self.sigmas.clone());
        // Intrinsics stay fixed here: a local bundle of a few keyframes
        // does not constrain them, and the camera every later frame is
        // normalised with would follow its noise; global refinement refines
        // them.
        let bundle = self.local_bundle(image_id, opts);
        self.log_local_ba_probe("before", frame, &bundle);
        let ba = timings.time(Stage::LocalBa, || adjust_local_bundle(&mut self.rec, &bundle, false, &ba_opts))?;
        self.log_local_ba_probe("after", frame, &bundle);
        tracing::debug!(
            "frame {frame}: local BA cost {:.4e} -> {:.4e} in {} iterations ({:?}), {} variable poses",
            ba.initial_cost,
            ba.final_cost,
            ba.iterations,
            ba.termination,
            ba.num_variable_poses
        );
        let mut local_points: BTreeSet<Point3DId> = BTreeSet::new();
        for id in bundle {
            if let Some(img) = self.rec.image(id) {
                local_points.extend(img.points2d.iter().filter_map(|p| p.point3d_id));
            }
        }
        let local_points: Vec<Point3DId> = local_points.into_iter().collect();
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || -> Result<(), SfmError> {
            complete_and_merge_image(&mut self.rec, &self.graph, image_id, &tri)?;
            self.filter(Some(&local_points), opts)?;
            Ok(())
        })
    }

    /// Deregisters an image (its observations leave their tracks; points
    /// left with fewer than two observations are deleted).
    pub fn deregister(&mut self, image_id: ImageId) -> Result<(), SfmError> {
        self.rec.deregister_image(image_id)?;
        Ok(())
    }

    /// Up to `max` registered keyframes outside `exclude` whose optical axis
    /// is within [`REVISIT_MAX_ANGLE_DEG`] of the pose's and whose centre
    /// lies within the map's median keyframe spacing times
    /// [`REVISIT_MAX_SPACINGS`], nearest in direction first.
    pub(crate) fn revisited_keyframes(&self, cam_from_world: &Rigid3, exclude: &[usize], max: usize) -> Vec<usize> {
        if max == 0 || self.keyframes.len() < 3 {
            return Vec::new();
        }
        let axis = |p: &Rigid3| p.rotation.inverse() * Vec3::z();
        let (dir, centre) = (axis(cam_from_world), cam_from_world.center());
        let poses: Vec<Option<Rigid3>> = self
            .keyframes
            .iter()
            .map(|k| self.rec.image(k.image_id).filter(|i| i.registered).map(|i| i.cam_from_world))
            .collect();
        let Some(spacing) = median_spacing(&poses) else { return Vec::new() };
        let max_dist = REVISIT_MAX_SPACINGS * spacing;
        let cos_max = REVISIT_MAX_ANGLE_DEG.to_radians().cos();
        let mut found: Vec<(f64, usize)> = poses
            .iter()
            .enumerate()
            .filter(|(k, _)| !exclude.contains(k))
            .filter_map(|(k, p)| {
                let p = (*p)?;
                let cos = axis(&p).dot(&dir);
                (cos >= cos_max && (p.center() - centre).norm() <= max_dist).then_some((cos, k))
            })
            .collect();
        found.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        found.into_iter().take(max).map(|(_, k)| k).collect()
    }
}

/// The median distance between consecutive poses (in the given order), or
/// `None` without two consecutive poses.
fn median_spacing(poses: &[Option<Rigid3>]) -> Option<f64> {
    let mut steps: Vec<f64> = poses
        .windows(2)
        .filter_map(|w| Some((w[0]?.center() - w[1]?.center()).norm()))
        .filter(|d| d.is_finite())
        .collect();
    if steps.is_empty() {
        return None;
    }
    steps.sort_by(f64::total_cmp);
    Some(steps[steps.len() / 2])
}

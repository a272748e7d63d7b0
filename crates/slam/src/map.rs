//! One map of a run: a COLMAP reconstruction and correspondence graph grown
//! keyframe by keyframe (paper 3.3-3.6), and the records of the non-keyframes
//! that are localised against it at the end.

use crate::SlamOptions;
use crate::frontend::FrameData;
use crate::timing::{Stage, StageTimings};
use colslam_estimators::{
    AbsolutePoseOptions, RansacOptions, TwoViewConfig, TwoViewGeometryOptions, essential_from_pose,
    estimate_absolute_pose, estimate_two_view_geometry, sampson_error_sq,
};
use colslam_features::Match;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_scene::{CameraId, Image, ImageId, Point3DId, Reconstruction, TrackElement};
use colslam_sfm::bundle::{BundleOptions, KeypointSigmas, adjust_global, adjust_local};
use colslam_sfm::triangulator::{complete_and_merge_all, complete_and_merge_image, retriangulate, triangulate_image};
use colslam_sfm::{CorrespondenceGraph, SfmError, TriangulatorOptions};
use rayon::prelude::*;
use std::collections::{BTreeSet, HashMap, HashSet};

/// Pixel threshold of geometric verification of keyframe matches (COLMAP's
/// two-view `max_error`, 4 px).
pub const VERIFY_MAX_ERROR_PX: f64 = 4.0;

/// A registered keyframe and its features.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Its image id in the map.
    pub image_id: ImageId,
    /// Its features.
    pub data: FrameData,
}

/// One 2D observation of a non-keyframe, linked to a keyframe keypoint.
#[derive(Debug, Clone, Copy)]
pub struct RecordObs {
    /// Keypoint index in the frame.
    pub frame_kp: u32,
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
    /// Frame index.
    pub index: usize,
    /// Timestamp.
    pub timestamp: f64,
    /// Name.
    pub name: String,
    /// Matches to keyframes.
    pub obs: Vec<RecordObs>,
    /// Became a keyframe later (not localised from this record).
    pub promoted: bool,
}

impl FrameRecord {
    /// A record with no observations yet.
    pub fn new(data: &FrameData) -> Self {
        Self { index: data.index, timestamp: data.timestamp, name: data.name.clone(), obs: Vec::new(), promoted: false }
    }

    /// Adds the matches of `data` (query) to keyframe `kf` (train).
    pub fn add_matches(&mut self, data: &FrameData, kf: ImageId, matches: &[Match]) {
        for m in matches {
            if let Some(n) = data.normalized.get(m.query as usize) {
                self.obs.push(RecordObs {
                    frame_kp: m.query,
                    normalized: *n,
                    measured: *n,
                    keyframe: kf,
                    keyframe_kp: m.train,
                });
            }
        }
    }
}

/// A localised frame.
#[derive(Debug, Clone)]
pub struct FramePose {
    /// Frame index.
    pub index: usize,
    /// Timestamp.
    pub timestamp: f64,
    /// Name.
    pub name: String,
    /// Pose.
    pub cam_from_world: Rigid3,
    /// Whether it is a keyframe of the map.
    pub keyframe: bool,
}

/// One map.
#[derive(Debug, Clone)]
pub struct MapState {
    /// Index among the run's maps.
    pub index: usize,
    /// The reconstruction.
    pub rec: Reconstruction,
    /// The correspondence graph between keyframes.
    pub graph: CorrespondenceGraph,
    /// The camera's id in `rec`.
    pub camera_id: CameraId,
    /// Registered keyframes in order.
    pub keyframes: Vec<Keyframe>,
    /// Non-keyframes to localise.
    pub records: Vec<FrameRecord>,
    /// Frame indices of the initial pair.
    pub initial_frames: (usize, usize),
    /// Registered images at the last global BA.
    last_global_images: usize,
    /// Points at the last global BA.
    last_global_points: usize,
    /// Point ids sent to event consumers (only maintained when asked).
    pub sent_points: HashSet<Point3DId>,
    /// Keypoint standard deviations (px) of the keyframes, for weighting
    /// bundle adjustment by pyramid level.
    pub sigmas: KeypointSigmas,
}

/// A localised frame's PnP inliers: (normalised keypoint, 3D point).
pub type FrameInliers = Vec<(Vec2, Point3DId)>;

/// What [`MapState::localize_all`] returns: poses of keyframes and
/// localised frames, the frames that failed (index, timestamp, name), and
/// each localised frame's inliers by frame index.
pub type Localization = (Vec<FramePose>, Vec<(usize, f64, String)>, HashMap<usize, FrameInliers>);

/// Largest angle (degrees) between the optical axes of a new keyframe and
/// an older one it is matched against as a revisit.
pub const REVISIT_MAX_ANGLE_DEG: f64 = 30.0;
/// Largest distance between their centres, in median keyframe spacings.
pub const REVISIT_MAX_SPACINGS: f64 = 10.0;

/// Local BA stops once an iteration lowers the cost by less than this share
/// of it (Ceres' function tolerance; COLMAP runs its local BA for up to 25
/// iterations at 1e-6). The map around a new keyframe is already adjusted
/// from the previous keyframes, so the later iterations move it by
/// hundredths of a pixel: on TUM fr1_rpy 1e-3 cut local BA from 9.2 s to
/// 3.8 s with ATE 2.34 -> 2.32 cm (docs/benchmarks.md).
pub const LOCAL_BA_FUNCTION_TOLERANCE: f64 = 1e-3;

/// The same for the global BAs run while the map grows; the final global BA
/// converges fully (1e-6). On TUM fr1_rpy: 5.6 s -> 2.0 s, ATE unchanged.
pub const PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE: f64 = 1e-3;

/// Rolling-shutter compensation takes a frame's angular velocity from its
/// neighbours only when they are at most this far apart in time (seconds).
pub const ROLLING_SHUTTER_MAX_GAP_S: f64 = 1.0;

/// Function tolerance of the global BA that ends the compensation (it starts
/// from observations moved by pixels, so at Ceres' 1e-6 it ran 34
/// iterations): 1e-4 gave the same ATE (1.09 against 1.07 cm) 0.85 s sooner.
pub const ROLLING_SHUTTER_FINAL_TOLERANCE: f64 = 1e-4;

/// Scale between ORB pyramid levels: a keypoint found at octave `o` is
/// located to about `ORB_LEVEL_SCALE^o` pixels (ORB-SLAM's level sigma).
pub const ORB_LEVEL_SCALE: f32 = 1.2;

/// The standard deviation of each keypoint of a frame (by pyramid level).
pub fn keypoint_sigmas(data: &FrameData) -> Vec<f32> {
    data.features.keypoints.iter().map(|k| ORB_LEVEL_SCALE.powi(i32::from(k.octave))).collect()
}

/// Why a keyframe candidate was not registered.
#[derive(Debug, Clone, PartialEq)]
pub enum RegisterFailure {
    /// Too few 2D-3D correspondences.
    TooFewCorrespondences(usize),
    /// Absolute pose estimation failed.
    PoseFailed(String),
    /// The keyframe kept too few points after triangulation and filtering.
    TooFewPoints(usize),
}

impl std::fmt::Display for RegisterFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewCorrespondences(n) => write!(f, "only {n} 2D-3D correspondences"),
            Self::PoseFailed(e) => write!(f, "absolute pose failed: {e}"),
            Self::TooFewPoints(n) => write!(f, "kept only {n} 3D points, deregistered"),
        }
    }
}

pub(crate) fn triangulator_options(opts: &SlamOptions) -> TriangulatorOptions {
    TriangulatorOptions {
        min_angle_deg: opts.min_tri_angle_deg,
        merge_max_reproj_error_px: opts.max_reproj_error_px,
        complete_max_reproj_error_px: opts.max_reproj_error_px,
        ..TriangulatorOptions::default()
    }
}

fn ransac_options(max_error: f64, seed: u64) -> RansacOptions {
    RansacOptions { max_error, seed, ..RansacOptions::default() }
}

/// RANSAC trials of the two-view test of keyframe candidates (a coarse
/// classification: rotation or not).
pub const KEYFRAME_TWO_VIEW_TRIALS: usize = 500;
/// RANSAC trials of the two-view geometry of initial pair candidates.
pub const INIT_TWO_VIEW_TRIALS: usize = 2000;

/// Two-view geometry between two frames' matched keypoints (`query` side
/// first), with at most `max_trials` RANSAC trials per model.
pub fn two_view(
    a: &FrameData,
    b: &FrameData,
    matches: &[Match],
    focal: f64,
    seed: u64,
    max_trials: usize,
) -> Option<colslam_estimators::TwoViewGeometry> {
    let x1: Vec<Vec2> = matches.iter().filter_map(|m| a.normalized.get(m.query as usize).copied()).collect();
    let x2: Vec<Vec2> = matches.iter().filter_map(|m| b.normalized.get(m.train as usize).copied()).collect();
    if x1.len() != matches.len() || x2.len() != matches.len() {
        return None;
    }
    let opts = TwoViewGeometryOptions {
        ransac: RansacOptions { confidence: 0.999, max_trials, ..ransac_options(VERIFY_MAX_ERROR_PX / focal, seed) },
        ..TwoViewGeometryOptions::default()
    };
    estimate_two_view_geometry(&x1, &x2, &opts).ok()
}

impl MapState {
    /// Tries to start a map from the initialisation window (paper 3.3): the
    /// first image has the most correspondences to the others, the second
    /// has many correspondences to it and enough motion (two-view geometry
    /// neither planar-only nor pure rotation, median triangulation angle at
    /// least `init_min_tri_angle_deg`); triangulate, global BA, filter; if
    /// too few points survive, the next candidate pair is tried. Returns the
    /// map and the window indices of the two images (earlier first).
    pub fn initialize(
        index: usize,
        window: &[FrameData],
        pair_matches: &HashMap<(usize, usize), Vec<Match>>,
        camera: &colslam_camera::Camera,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Option<(MapState, usize, usize)>, SfmError> {
        let n = window.len();
        let count = |i: usize, j: usize| -> usize {
            let key = if i < j { (i, j) } else { (j, i) };
            pair_matches.get(&key).map_or(0, Vec::len)
        };
        let mut firsts: Vec<(usize, usize)> =
            (0..n).map(|i| (i, (0..n).filter(|&j| j != i).map(|j| count(i, j)).sum())).collect();
        firsts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let focal = 0.5 * (camera.focal_x() + camera.focal_y());
        // COLMAP tries several first images; two are enough to leave a
        // clearly bad window quickly.
        for &(first, _) in firsts.iter().take(2) {
            let mut seconds: Vec<usize> =
                (0..n).filter(|&j| j != first && count(first, j) >= opts.init_min_inliers).collect();
            // Video: the frames with the most matches are the nearest, with
            // the least parallax; among those matched well enough, try the
            // farthest in time first, and every one of them: in a photo
            // sequence with wide baselines (Strecha castle-P19) the far
            // frames share no view, and raw match counts (which the ratio
            // test leaves high among thousands of keypoints) do not tell.
            seconds.sort_by(|&a, &b| b.abs_diff(first).cmp(&a.abs_diff(first)).then(a.cmp(&b)));
            for second in seconds {
                let (i, j) = if first < second { (first, second) } else { (second, first) };
                let Some(matches) = pair_matches.get(&(i, j)) else { continue };
                let Some(tvg) = two_view(&window[i], &window[j], matches, focal, opts.seed, INIT_TWO_VIEW_TRIALS)
                else {
                    continue;
                };
                tracing::trace!(
                    "init candidate {} / {}: {:?}, {} inliers of {}, median angle {:?}",
                    window[i].index,
                    window[j].index,
                    tvg.config,
                    tvg.num_inliers,
                    matches.len(),
                    tvg.median_tri_angle_deg
                );
                let motion_ok = matches!(tvg.config, TwoViewConfig::Calibrated | TwoViewConfig::Planar);
                let angle_ok = tvg.median_tri_angle_deg.is_some_and(|a| a >= opts.init_min_tri_angle_deg);
                let Some(rel) = tvg.cam2_from_cam1 else { continue };
                if !motion_ok || !angle_ok || tvg.num_inliers < opts.init_min_inliers {
                    continue;
                }
                let inliers: Vec<Match> =
                    matches.iter().zip(&tvg.inlier_mask).filter(|(_, k)| **k).map(|(m, _)| *m).collect();
                let map = Self::from_pair(index, &window[i], &window[j], &inliers, rel, camera, opts, timings)?;
                if map.rec.num_points3d() >= opts.init_min_points {
                    tracing::info!(
                        "map {index} initialised from frames {} and {}: {} points, median angle {:.2} deg",
                        window[i].index,
                        window[j].index,
                        map.rec.num_points3d(),
                        tvg.median_tri_angle_deg.unwrap_or(0.0)
                    );
                    return Ok(Some((map, i, j)));
                }
                tracing::debug!(
                    "initial pair {} / {} kept only {} points",
                    window[i].index,
                    window[j].index,
                    map.rec.num_points3d()
                );
            }
        }
        Ok(None)
    }

    #[allow(clippy::too_many_arguments)]
    fn from_pair(
        index: usize,
        a: &FrameData,
        b: &FrameData,
        inliers: &[Match],
        b_from_a: Rigid3,
        camera: &colslam_camera::Camera,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<MapState, SfmError> {
        let mut rec = Reconstruction::new();
        let camera_id = rec.add_camera(camera.clone());
        let mut graph = CorrespondenceGraph::new();
        let mut ids = Vec::new();
        for (data, pose) in [(a, Rigid3::identity()), (b, b_from_a)] {
            let id = rec.next_image_id();
            let mut img = Image::new(id, data.name.clone(), camera_id, data.pixels.clone());
            img.cam_from_world = pose;
            rec.add_image(img)?;
            rec.register_image(id)?;
            graph.add_image(id, data.len())?;
            ids.push(id);
        }
        let pairs: Vec<(u32, u32)> = inliers.iter().map(|m| (m.query, m.train)).collect();
        graph.add_correspondences(ids[0], ids[1], &pairs)?;
        let tri = triangulator_options(opts);
        timings.time(Stage::Triangulation, || triangulate_image(&mut rec, &graph, ids[0], &tri))?;
        let mut map = MapState {
            index,
            rec,
            graph,
            camera_id,
            keyframes: vec![
                Keyframe { image_id: ids[0], data: a.clone() },
                Keyframe { image_id: ids[1], data: b.clone() },
            ],
            records: Vec::new(),
            initial_frames: (a.index, b.index),
            last_global_images: 0,
            last_global_points: 0,
            sent_points: HashSet::new(),
            sigmas: KeypointSigmas::default(),
        };
        if opts.weight_by_level {
            let m = std::sync::Arc::make_mut(&mut map.sigmas);
            m.insert(ids[0], keypoint_sigmas(a));
            m.insert(ids[1], keypoint_sigmas(b));
        }
        map.global_ba(opts, timings)?;
        Ok(map)
    }

    /// The last registered keyframe.
    pub fn last_keyframe(&self) -> Option<&Keyframe> {
        self.keyframes.last()
    }

    /// Filters the given points (all when `None`) by reprojection error and
    /// triangulation angle (COLMAP's `FilterPoints`).
    pub(crate) fn filter(&mut self, points: Option<&[Point3DId]>, opts: &SlamOptions) -> Result<usize, SfmError> {
        // Bundle adjustment gives points behind a camera zero cost (as
        // COLMAP's cost functions do), so those observations go first.
        let d = self.rec.filter_negative_depth(points)?;
        let a = self.rec.filter_by_reprojection_error(opts.max_reproj_error_px, points)?;
        let b = self.rec.filter_by_triangulation_angle(opts.min_tri_angle_deg, points)?;
        tracing::trace!(
            "filter: depth removed {} observations, reprojection {} observations / {} points, angle {} points",
            d.observations_removed,
            a.observations_removed,
            a.points_deleted,
            b.points_deleted
        );
        Ok(d.points_deleted + a.points_deleted + b.points_deleted)
    }

    /// Global bundle adjustment, then normalisation, merge/complete of all
    /// tracks and filtering (paper 3.6).
    pub fn global_ba(
        &mut self,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<colslam_optim::BaReport, SfmError> {
        self.global_ba_with(opts, timings, &BundleOptions::global())
    }

    /// The global BA run while the map grows ([`Self::needs_global_ba`]):
    /// as [`Self::global_ba`] but stopped once an iteration lowers the cost
    /// by less than [`PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE`]; the final
    /// global BA ([`Self::finalize`]) converges fully.
    pub fn periodic_global_ba(
        &mut self,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<colslam_optim::BaReport, SfmError> {
        self.global_ba_with_tolerance(opts, timings, PERIODIC_GLOBAL_BA_FUNCTION_TOLERANCE)
    }

    /// [`Self::global_ba`] stopped once an iteration lowers the cost by less
    /// than `function_tolerance` of it.
    pub fn global_ba_with_tolerance(
        &mut self,
        opts: &SlamOptions,
        timings: &mut StageTimings,
        function_tolerance: f64,
    ) -> Result<colslam_optim::BaReport, SfmError> {
        let mut ba = BundleOptions::global();
        ba.ba.function_tolerance = function_tolerance;
        self.global_ba_with(opts, timings, &ba)
    }

    fn global_ba_with(
        &mut self,
        opts: &SlamOptions,
        timings: &mut StageTimings,
        ba: &BundleOptions,
    ) -> Result<colslam_optim::BaReport, SfmError> {
        let report = timings.time(Stage::GlobalBa, || adjust_global(&mut self.rec, opts.refine_intrinsics, ba))?;
        tracing::debug!(
            "map {}: global BA over {} images / {} points: cost {:.4e} -> {:.4e} in {} iterations ({:?})",
            self.index,
            self.rec.num_registered_images(),
            self.rec.num_points3d(),
            report.initial_cost,
            report.final_cost,
            report.iterations,
            report.termination
        );
        self.rec.normalize(&colslam_scene::NormalizeOptions::default())?;
        let tri = triangulator_options(opts);
        timings.time(Stage::Triangulation, || complete_and_merge_all(&mut self.rec, &self.graph, &tri))?;
        let removed = self.filter(None, opts)?;
        tracing::debug!("map {}: global filter removed {removed} points, {} left", self.index, self.rec.num_points3d());
        self.last_global_images = self.rec.num_registered_images();
        self.last_global_points = self.rec.num_points3d();
        Ok(report)
    }

    /// True when the map grew enough since the last global BA.
    pub fn needs_global_ba(&self, opts: &SlamOptions) -> bool {
        let imgs = self.rec.num_registered_images() as f64;
        let pts = self.rec.num_points3d() as f64;
        imgs >= opts.global_ba_growth * self.last_global_images as f64
            || pts >= opts.global_ba_growth * self.last_global_points as f64
    }

    /// Registers a keyframe candidate (paper 3.5): 2D-3D correspondences
    /// through its matches to recent keyframes, PnP + LO-RANSAC +
    /// refinement, verified matches into the correspondence graph,
    /// triangulation, local BA, filtering and the point-count check with
    /// deregistration. `matches_to_last` are its matches (query = candidate)
    /// to the last keyframe. Returns the new image id, or why it failed.
    pub fn register_keyframe(
        &mut self,
        data: &FrameData,
        matches_to_last: &[Match],
        frontend: &crate::frontend::Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Result<ImageId, RegisterFailure>, crate::SlamError> {
        let camera = frontend.camera();
        let focal = 0.5 * (camera.focal_x() + camera.focal_y());
        // Matches to the most recent keyframes, newest first.
        let recent: Vec<usize> = (0..self.keyframes.len()).rev().take(opts.match_keyframes).collect();
        let mut kf_matches: Vec<(usize, Vec<Match>)> = Vec::with_capacity(recent.len());
        for (rank, &k) in recent.iter().enumerate() {
            let m = if rank == 0 {
                matches_to_last.to_vec()
            } else {
                timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[k].data))?
            };
            kf_matches.push((k, m));
        }
        let started = std::time::Instant::now();
        // 2D-3D correspondences: one per keypoint and one per 3D point.
        let mut used_kp = HashSet::new();
        let mut used_pt = HashSet::new();
        let (mut p2, mut p3, mut corr_ids) = (Vec::new(), Vec::new(), Vec::new());
        for (k, matches) in &kf_matches {
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
                p2.push(*n);
                p3.push(p.xyz);
                corr_ids.push((m.query, pid));
            }
        }
        tracing::trace!(
            "frame {}: {} matches to the last keyframe, {} keyframe points with 3D, {} 2D-3D",
            data.index,
            matches_to_last.len(),
            self.keyframes.last().and_then(|k| self.rec.image(k.image_id)).map_or(0, Image::num_points3d),
            p2.len()
        );
        if p2.len() < opts.abs_pose_min_inliers {
            timings.add(Stage::Registration, started.elapsed());
            return Ok(Err(RegisterFailure::TooFewCorrespondences(p2.len())));
        }
        let pose_opts = AbsolutePoseOptions {
            ransac: RansacOptions {
                confidence: 0.9999,
                ..ransac_options(opts.abs_pose_max_error_px / focal, opts.seed ^ data.index as u64)
            },
            min_num_inliers: opts.abs_pose_min_inliers,
            ..AbsolutePoseOptions::default()
        };
        let pose = match estimate_absolute_pose(&p2, &p3, &pose_opts) {
            Ok(p) => p,
            Err(e) => {
                timings.add(Stage::Registration, started.elapsed());
                return Ok(Err(RegisterFailure::PoseFailed(e.to_string())));
            }
        };
        // Older keyframes that look the same way (the camera came back to a
        // view it mapped before): matching them too ties the new keyframe's
        // tracks to the old points, which holds the map's scale and shape
        // together where short-baseline keyframes alone drift (a pose-guided
        // form of ORB-SLAM's covisibility matching and loop closing).
        let revisits = self.revisited_keyframes(&pose.cam_from_world, &recent, opts.match_revisited);
        for k in revisits {
            let m = timings.time(Stage::Matching, || frontend.match_frames(data, &self.keyframes[k].data))?;
            kf_matches.push((k, m));
        }
        let image_id = self.rec.next_image_id();
        let mut img = Image::new(image_id, data.name.clone(), self.camera_id, data.pixels.clone());
        img.cam_from_world = pose.cam_from_world;
        self.rec.add_image(img)?;
        self.rec.register_image(image_id)?;
        self.graph.add_image(image_id, data.len())?;
        if opts.weight_by_level {
            std::sync::Arc::make_mut(&mut self.sigmas).insert(image_id, keypoint_sigmas(data));
        }
        // Geometric verification of the matches with the known poses.
        let max_sampson = (VERIFY_MAX_ERROR_PX / focal).powi(2);
        for (k, matches) in &kf_matches {
            let kf = &self.keyframes[*k];
            let Some(kf_img) = self.rec.image(kf.image_id) else { continue };
            let new_from_kf = pose.cam_from_world * kf_img.cam_from_world.inverse();
            let e = essential_from_pose(&new_from_kf);
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
            self.graph.add_correspondences(kf.image_id, image_id, &pairs)?;
        }
        // Continue the tracks of the PnP inliers.
        for ((q, pid), inlier) in corr_ids.iter().zip(&pose.inlier_mask) {
            if !inlier {
                continue;
            }
            let Some(p) = self.rec.point3d(*pid) else { continue };
            if p.track.iter().any(|e| e.image_id == image_id) {
                continue;
            }
            self.rec.add_observation(*pid, TrackElement::new(image_id, *q))?;
        }
        timings.add(Stage::Registration, started.elapsed());

        let tri = triangulator_options(opts);
        timings.time(Stage::Triangulation, || -> Result<(), SfmError> {
            // Tracks are completed and merged after local BA, as COLMAP's
            // iterative local refinement does.
            triangulate_image(&mut self.rec, &self.graph, image_id, &tri)?;
            retriangulate(&mut self.rec, &self.graph, Some(&[image_id]), &tri)?;
            Ok(())
        })?;
        let ba = timings.time(Stage::LocalBa, || {
            let mut ba_opts = BundleOptions { keypoint_sigmas: Some(self.sigmas.clone()), ..BundleOptions::local() };
            ba_opts.ba.function_tolerance = LOCAL_BA_FUNCTION_TOLERANCE;
            adjust_local(&mut self.rec, image_id, opts.local_ba_images, opts.refine_intrinsics, &ba_opts)
        })?;
        tracing::debug!(
            "frame {}: local BA cost {:.4e} -> {:.4e} in {} iterations ({:?}), {} variable poses",
            data.index,
            ba.initial_cost,
            ba.final_cost,
            ba.iterations,
            ba.termination,
            ba.num_variable_poses
        );
        // Filter the points of the local bundle.
        let mut local_points: BTreeSet<Point3DId> = BTreeSet::new();
        let mut bundle = vec![image_id];
        bundle.extend(colslam_sfm::bundle::most_connected_images(&self.rec, image_id, opts.local_ba_images - 1));
        for id in &bundle {
            if let Some(img) = self.rec.image(*id) {
                local_points.extend(img.points2d.iter().filter_map(|p| p.point3d_id));
            }
        }
        let local_points: Vec<Point3DId> = local_points.into_iter().collect();
        timings.time(Stage::Triangulation, || -> Result<(), SfmError> {
            complete_and_merge_image(&mut self.rec, &self.graph, image_id, &tri)?;
            self.filter(Some(&local_points), opts)?;
            Ok(())
        })?;
        let kept = self.rec.image(image_id).map_or(0, Image::num_points3d);
        if kept < opts.min_keyframe_points {
            self.rec.deregister_image(image_id)?;
            return Ok(Err(RegisterFailure::TooFewPoints(kept)));
        }
        self.keyframes.push(Keyframe { image_id, data: data.clone() });
        Ok(Ok(image_id))
    }

    /// Up to `max` registered keyframes outside `exclude` whose optical axis
    /// is within [`REVISIT_MAX_ANGLE_DEG`] of the pose's and whose centre
    /// lies within the map's median keyframe spacing times
    /// [`REVISIT_MAX_SPACINGS`], nearest in direction first.
    fn revisited_keyframes(&self, cam_from_world: &Rigid3, exclude: &[usize], max: usize) -> Vec<usize> {
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
        let mut steps: Vec<f64> = poses
            .windows(2)
            .filter_map(|w| Some((w[0]?.center() - w[1]?.center()).norm()))
            .filter(|d| d.is_finite())
            .collect();
        if steps.is_empty() {
            return Vec::new();
        }
        steps.sort_by(f64::total_cmp);
        let max_dist = REVISIT_MAX_SPACINGS * steps[steps.len() / 2];
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

    /// Rolling-shutter compensation ([`crate::rolling_shutter`]) with the
    /// frames' angular velocities (by frame index, from a localisation):
    /// every keyframe observation and every non-keyframe record is moved,
    /// from its measured position, to its frame's middle-row time, then the
    /// map is bundle adjusted globally to the periodic tolerance, with track
    /// completion, merging and filtering. The caller localises the frames
    /// again and ends with a converged global BA. Returns the number of
    /// keyframe observations moved.
    pub fn compensate_rolling_shutter(
        &mut self,
        velocities: &HashMap<usize, Vec3>,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<usize, SfmError> {
        let readout = opts.rolling_shutter_readout;
        if readout == 0.0 || self.rec.num_registered_images() < 2 {
            return Ok(0);
        }
        let camera = self.rec.camera(self.camera_id).ok_or(colslam_scene::SceneError::UnknownCamera(self.camera_id))?;
        let camera = camera.camera.clone();
        let mut moved = 0;
        for kf in &self.keyframes {
            let Some(w) = velocities.get(&kf.data.index) else { continue };
            if !self.rec.image(kf.image_id).is_some_and(|i| i.registered) {
                continue;
            }
            // From the keyframe's own measurements, so a second call does
            // not compound corrections.
            for (k, px) in kf.data.pixels.iter().enumerate() {
                if let Some((fixed, _)) = crate::rolling_shutter::compensate(&camera, px, w, readout) {
                    self.rec.set_point2d_xy(kf.image_id, k as u32, fixed)?;
                    moved += 1;
                }
            }
        }
        for r in &mut self.records {
            let Some(w) = velocities.get(&r.index) else { continue };
            for o in &mut r.obs {
                let px = camera.img_from_normalized(&o.measured);
                if let Some((_, n)) = crate::rolling_shutter::compensate(&camera, &px, w, readout) {
                    o.normalized = n;
                }
            }
        }
        tracing::debug!(
            "map {}: rolling shutter ({:.1} ms readout): {moved} keyframe observations moved, {} frames with a velocity",
            self.index,
            1e3 * readout,
            velocities.len()
        );
        // Track completion, merging and filtering matter here: corrected
        // observations join tracks they did not fit before (BA alone after
        // compensating: 1.36 cm instead of 0.98 cm on TUM fr1/rpy).
        self.periodic_global_ba(opts, timings)?;
        Ok(moved)
    }

    /// Final global BA and filtering at the end of the run.
    pub fn finalize(&mut self, opts: &SlamOptions, timings: &mut StageTimings) -> Result<(), SfmError> {
        if self.rec.num_registered_images() >= 2 {
            if opts.rolling_shutter_readout > 0.0 {
                // Rolling-shutter compensation follows and ends with the
                // converged global BA.
                self.periodic_global_ba(opts, timings)?;
            } else {
                self.global_ba(opts, timings)?;
            }
        }
        self.rec.update_point_errors()?;
        Ok(())
    }

    /// Colours each point with the mean keypoint colour over its track.
    pub fn color_points(&mut self) {
        let colors: HashMap<ImageId, &Vec<[u8; 3]>> =
            self.keyframes.iter().map(|k| (k.image_id, &k.data.colors)).collect();
        let mut updates = Vec::new();
        for (pid, p) in self.rec.points3d() {
            let mut sum = [0u32; 3];
            let mut n = 0u32;
            for el in &p.track {
                if let Some(c) = colors.get(&el.image_id).and_then(|c| c.get(el.point2d_idx as usize)) {
                    for k in 0..3 {
                        sum[k] += u32::from(c[k]);
                    }
                    n += 1;
                }
            }
            // The mean of u8 values fits in u8.
            if let (Some(r), Some(g), Some(b)) = (sum[0].checked_div(n), sum[1].checked_div(n), sum[2].checked_div(n)) {
                updates.push((pid, [r as u8, g as u8, b as u8]));
            }
        }
        for (pid, c) in updates {
            let _ = self.rec.set_point3d_color(pid, c);
        }
    }

    /// Poses of every keyframe and every localised non-keyframe, in frame
    /// order, and the records that could not be localised.
    pub fn localize_all(&self, camera_focal: f64, opts: &SlamOptions, timings: &mut StageTimings) -> Localization {
        let mut poses: Vec<FramePose> = self
            .keyframes
            .iter()
            .filter_map(|k| {
                let img = self.rec.image(k.image_id)?;
                img.registered.then(|| FramePose {
                    index: k.data.index,
                    timestamp: k.data.timestamp,
                    name: k.data.name.clone(),
                    cam_from_world: img.cam_from_world,
                    keyframe: true,
                })
            })
            .collect();
        let keyframe_frames: HashSet<usize> = poses.iter().map(|p| p.index).collect();
        let started = std::time::Instant::now();
        // One record per frame: a frame can hold several (tracked by two
        // maps that were merged, tracked backwards and relocalised), whose
        // observations are pooled; a frame promoted anywhere is a keyframe.
        let mut merged: Vec<FrameRecord> = Vec::new();
        let mut slot: HashMap<usize, usize> = HashMap::new();
        for r in &self.records {
            match slot.get(&r.index) {
                Some(&k) => {
                    merged[k].obs.extend_from_slice(&r.obs);
                    merged[k].promoted |= r.promoted;
                }
                None => {
                    slot.insert(r.index, merged.len());
                    merged.push(r.clone());
                }
            }
        }
        let results: Vec<(usize, Option<(FramePose, FrameInliers)>)> = merged
            .par_iter()
            .enumerate()
            .filter(|(_, r)| !r.promoted && !keyframe_frames.contains(&r.index) && opts.localize_all_frames)
            .map(|(i, r)| (i, self.localize(r, camera_focal, opts)))
            .collect();
        timings.add(Stage::Localization, started.elapsed());
        let mut failed = Vec::new();
        let mut inliers = HashMap::new();
        for (i, res) in results {
            match res {
                Some((p, inl)) => {
                    inliers.insert(p.index, inl);
                    poses.push(p);
                }
                None => {
                    let r = &merged[i];
                    failed.push((r.index, r.timestamp, r.name.clone()));
                }
            }
        }
        // One pose per frame (a keyframe first: the sort is stable and
        // keyframes were pushed first).
        poses.sort_by_key(|p| p.index);
        poses.dedup_by_key(|p| p.index);
        failed.sort_by_key(|f| f.0);
        (poses, failed, inliers)
    }

    fn localize(
        &self,
        record: &FrameRecord,
        focal: f64,
        opts: &SlamOptions,
    ) -> Option<(FramePose, Vec<(Vec2, Point3DId)>)> {
        let mut used_kp = HashSet::new();
        let mut used_pt = HashSet::new();
        let (mut p2, mut p3): (Vec<Vec2>, Vec<Vec3>) = (Vec::new(), Vec::new());
        let mut pids = Vec::new();
        for o in &record.obs {
            let Some(img) = self.rec.image(o.keyframe) else { continue };
            if !img.registered {
                continue;
            }
            let Some(pid) = img.points2d.get(o.keyframe_kp as usize).and_then(|p| p.point3d_id) else { continue };
            let Some(p) = self.rec.point3d(pid) else { continue };
            if used_kp.contains(&o.frame_kp) || used_pt.contains(&pid) {
                continue;
            }
            used_kp.insert(o.frame_kp);
            used_pt.insert(pid);
            p2.push(o.normalized);
            p3.push(p.xyz);
            pids.push(pid);
        }
        if p2.len() < opts.abs_pose_min_inliers {
            return None;
        }
        let pose_opts = AbsolutePoseOptions {
            ransac: RansacOptions {
                confidence: 0.9999,
                ..ransac_options(opts.abs_pose_max_error_px / focal, opts.seed ^ record.index as u64)
            },
            min_num_inliers: opts.abs_pose_min_inliers,
            ..AbsolutePoseOptions::default()
        };
        let pose = estimate_absolute_pose(&p2, &p3, &pose_opts).ok()?;
        let inliers =
            p2.iter().zip(&pids).zip(&pose.inlier_mask).filter(|(_, m)| **m).map(|((n, pid), _)| (*n, *pid)).collect();
        let fp = FramePose {
            index: record.index,
            timestamp: record.timestamp,
            name: record.name.clone(),
            cam_from_world: pose.cam_from_world,
            keyframe: false,
        };
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
        let Some(camera) = self.rec.camera(self.camera_id).map(|c| c.camera.clone()) else { return Ok(()) };
        let mut added: Vec<(usize, ImageId)> = Vec::new();
        for p in poses.iter().filter(|p| !p.keyframe) {
            let Some(obs) = inliers.get(&p.index) else { continue };
            let live: Vec<&(Vec2, Point3DId)> =
                obs.iter().filter(|(_, pid)| self.rec.point3d(*pid).is_some()).collect();
            if live.len() < opts.abs_pose_min_inliers {
                continue;
            }
            let id = self.rec.next_image_id();
            let pixels: Vec<Vec2> = live.iter().map(|(n, _)| camera.img_from_normalized(n)).collect();
            let mut img = Image::new(id, p.name.clone(), self.camera_id, pixels);
            img.cam_from_world = p.cam_from_world;
            self.rec.add_image(img)?;
            self.rec.register_image(id)?;
            for (k, (_, pid)) in live.iter().enumerate() {
                let taken = self.rec.point3d(*pid).is_none_or(|pt| pt.track.iter().any(|e| e.image_id == id));
                if !taken {
                    self.rec.add_observation(*pid, TrackElement::new(id, k as u32))?;
                }
            }
            added.push((p.index, id));
        }
        if added.is_empty() {
            return Ok(());
        }
        self.global_ba(opts, timings)?;
        let by_index: HashMap<usize, ImageId> = added.into_iter().collect();
        let kf_ids: HashMap<usize, ImageId> = self.keyframes.iter().map(|k| (k.data.index, k.image_id)).collect();
        for p in poses.iter_mut() {
            let id = if p.keyframe { kf_ids.get(&p.index) } else { by_index.get(&p.index) };
            if let Some(img) = id.and_then(|id| self.rec.image(*id)).filter(|i| i.registered) {
                p.cam_from_world = img.cam_from_world;
            }
        }
        Ok(())
    }
}

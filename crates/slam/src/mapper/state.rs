//! The mapper's state and the steps that only read or reset it: accessors,
//! filtering, the global refinement schedule, colouring.

use crate::calibrate;
use crate::error::SlamError;
use crate::frame::{FrameData, FrameRecord};
use crate::options::{GlobalBaTolerance, SlamOptions};
use crate::records::{RecordStore, SpillConfig};
use crate::timing::{Stage, StageTimings};
use colslam_camera::{Camera, CameraModelId};
use colslam_scene::{CameraId, ImageId, Point3DId, Reconstruction, SceneError};
use colslam_sfm::bundle::{BundleOptions, KeypointSigmas, RefinedIntrinsics, adjust_global_long_tracks};
use colslam_sfm::triangulator::complete_and_merge_all;
use colslam_sfm::{CorrespondenceGraph, SfmError};
use std::collections::HashMap;

/// A registered keyframe and its features.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Its image id in the map.
    pub image_id: ImageId,
    /// Its features; their normalised coordinates are those of the map's
    /// camera at intrinsics version `version` ([`Mapper::refresh_keyframes`]).
    pub data: FrameData,
    /// The map's intrinsics version its normalised coordinates were made at.
    pub version: u64,
}

/// One map.
#[derive(Debug, Clone)]
pub struct Mapper {
    /// Index among the run's maps.
    pub(super) index: usize,
    /// The reconstruction.
    pub(super) rec: Reconstruction,
    /// The correspondence graph between keyframes.
    pub(super) graph: CorrespondenceGraph,
    /// The camera's id in `rec`: the one camera of the run, refined there by
    /// bundle adjustment when intrinsics are refined.
    pub(super) camera_id: CameraId,
    /// Registered keyframes. Their order defines the reference keyframe (the
    /// last) and the recent ones a new keyframe is matched against: frame
    /// order, except while tracking backwards ([`Self::order_keyframes_by_distance_to`]).
    pub(super) keyframes: Vec<Keyframe>,
    /// Non-keyframes to localise, in memory or spilled to disk
    /// (`crate::records`).
    pub(super) records: RecordStore,
    /// Frame indices of the initial pair.
    pub(super) initial_frames: (usize, usize),
    /// The initial pair's pose came from its homography (a planar scene or
    /// little baseline), which leaves the focal length free.
    pub(super) planar_start: bool,
    /// Registered images of the map the starting camera's focal length was
    /// settled in (0: a guess or a calibration): the global BAs hold the
    /// refined intrinsics while this map has fewer ([`Self::constrains_focal`]).
    pub(super) camera_support: usize,
    /// Registered images and points at the last global BA.
    pub(super) last_global: (usize, usize),
    /// Relative change of the focal length in the last global BA (infinite
    /// before the first): `--robust-intrinsics` waits for it to settle.
    pub(super) focal_step: f64,
    /// Registered images and focal length after each global BA that
    /// refined the intrinsics: [`Self::focal_drift_since`] reads how far the
    /// focal length moved while the map grew.
    pub(super) focal_trace: Vec<(usize, f64)>,
    /// Keypoint standard deviations (px) of the keyframes, for weighting
    /// bundle adjustment by pyramid level.
    pub(super) sigmas: KeypointSigmas,
    /// Counts the bundle adjustments that refined the camera's intrinsics:
    /// the reconstruction owns the run's camera, and normalised coordinates
    /// made before the last refinement are stale.
    pub(super) intrinsics_version: u64,
    /// Keyframes culled as redundant (`--cull-keyframes`, `cull.rs`).
    pub(super) culled: usize,
    /// Place recognition and the loops closed (`--loop-closure`,
    /// `loop_closure.rs`).
    pub(super) loops: super::loop_closure::LoopState,
    /// Set once mapping ended ([`Self::finalize`]): the global BAs from
    /// then on are the final ones (`--robust-final-ba`).
    pub(super) mapping_ended: bool,
    /// The radial term was tried on this map's final camera
    /// ([`Self::try_radial_distortion`]), kept or not.
    radial_tried: bool,
}

/// Relative change of the focal length in a global BA under which it has
/// settled: from then on `--robust-intrinsics` makes the BAs robust. Before,
/// the residuals a focal length far off causes at the image borders would
/// be taken for outliers and hold it there.
const FOCAL_SETTLED: f64 = 0.01;

/// Relative standard deviation of the focal length
/// ([`crate::calibrate::FocalProfile::spread`]) under which the two views
/// of an initial pair fix it: they know it better than the guess from the
/// image area does (5-9 % off on the suite's cameras). The Strecha sets'
/// pairs measure 0.8-6.4 %, the synthetic room's 13 %, KITTI's and the
/// clip's have no curvature at all.
const MAX_FOCAL_SIGMA: f64 = 0.1;

/// Chi-square by which a focal length 10 % away must fit two views better
/// ([`crate::calibrate::FocalProfile::drop`]) for them to refute the one
/// they were posed with, however loosely they fix it: the 90 % point of
/// one degree of freedom. The KITTI drive's initial pairs drop 0.2 (their
/// BAs, refining, ran out of iterations taking the guess of 683 px to
/// 504-750 px, and the maps broke), the clip's 0.01, the entry set's 17.6
/// (docs/benchmarks.md).
const MIN_FOCAL_DROP: f64 = 2.71;

/// Observations of tracks of `--final-ba-min-track` views or more below
/// which an image keeps its shorter tracks in the final BAs' pose estimate:
/// a pose resting on a handful of points is worse off without the rest.
const MIN_LONG_TRACK_OBSERVATIONS: usize = 30;

/// Scale of the Cauchy loss of the final bundle adjustments
/// (`--robust-final-ba`), in units of the map's median point reprojection
/// error: at the error level itself most observations keep nearly their
/// full weight and the few off by several times it count little. Measured:
/// 1x against 2x and a fixed 1 px (docs/benchmarks.md, "Observation
/// refinement"); TUM's rolling-shutter residuals (median 1.2 px) lost
/// accuracy at the fixed pixel.
pub const FINAL_BA_LOSS_SCALE: f64 = 1.0;

/// Iterations of a final bundle adjustment with `--robust-final-ba`. A
/// Cauchy loss is applied as iteratively reweighted least squares (Ceres'
/// corrector, no curvature term where the loss bends down), which converges
/// linearly: such a BA ran into the 50 of a squared one (which stops near
/// 12) while its cost fell by a few 1e-6 per iteration. At 20 the suite's
/// figures are level over seeds and TUM's final BAs take half the time
/// (docs/benchmarks.md).
const ROBUST_FINAL_BA_MAX_ITERATIONS: usize = 20;

/// The loss of a final bundle adjustment with `--robust-final-ba`: a
/// Cauchy loss of `scale` replaces the squared one, and where the refined
/// intrinsics already carry a Cauchy loss (`--robust-intrinsics`, 1 px) the
/// smaller scale holds. A fixed pixel is less robust than the map's own
/// error level once that is under it: with `--refine-distortion` the
/// refined Strecha maps lost half their accuracy to the 1 px loss
/// (docs/benchmarks.md).
pub(super) fn final_ba_loss(loss: colslam_optim::LossFunction, scale: f64) -> colslam_optim::LossFunction {
    use colslam_optim::LossFunction;
    match loss {
        LossFunction::Trivial => LossFunction::Cauchy(scale),
        LossFunction::Cauchy(a) => LossFunction::Cauchy(a.min(scale)),
        other => other,
    }
}

/// Keyframes a map needs before a radial distortion term is tried on its
/// camera ([`Mapper::try_radial_distortion`]): fewer keep too few
/// observations near the image borders, where distortion shows.
pub const RADIAL_MIN_KEYFRAMES: usize = 5;

/// Cost gain (in residual variances, chi-square with one degree of
/// freedom) above which the radial term is kept: 0.1 % of false positives on
/// an undistorted camera (the gains measured: docs/benchmarks.md).
pub const RADIAL_GAIN_CHI2: f64 = 10.83;

/// The least a radial term tried at the end must move image points (for
/// one term: the farthest corner) to be kept, pixels
/// ([`calibrate::distortion_shift`]). Over 10^5 residuals
/// the chi-square gain finds a fraction of a pixel significant: Strecha
/// herzjesu's undistorted photos ask for k -0.0023 (0.96 px at the corners)
/// at a gain of 108, and the term then costs its trajectory 7 %, where the
/// lenses that need one move their corners 4.8 px (TUM fr1), 9 px (KITTI's
/// rectified images) and 13-22 px (the synthetic lenses; docs/benchmarks.md).
pub const MIN_RADIAL_SHIFT_PX: f64 = 2.0;

/// Least fraction of the trial BA's cost a second radial term must remove
/// to be kept (with [`RADIAL_GAIN_CHI2`] and [`MIN_RADIAL_SHIFT_PX`] for its
/// own move of the image). An effect size, not only a significance: the
/// residuals of 10^5 observations are not independent (a track, a frame,
/// the lens model share their errors), so the chi-square gain finds any
/// systematic trade significant. A lens whose profile one term does not
/// describe (the synthetic pincushion, k1 0.1 and k2 -0.1: 0.87 %; TUM
/// fr1's k1 0.26, k2 -0.95, k3 1.16: 1.1-1.4 %) gains far more than a
/// forward-moving drive, where the radial terms trade with depth (Wu,
/// "Critical configurations for radial distortion self-calibration", CVPR
/// 2014) and KITTI's rectified images gain 0.19 % for a term that costs the
/// trajectory 37 % (docs/benchmarks.md, session 28).
pub const SECOND_RADIAL_MIN_GAIN: f64 = 0.005;

/// Function tolerance of the BA that tries the second radial term from the
/// converged map with one: it decides, the refinement after it converges.
/// Stopped there it finds nearly all of the gain (TUM fr1 1.20 % of the
/// cost in 8 iterations against 1.27 % in 23 fully converged; the synthetic
/// pincushion 0.91 against 0.92 %), and stopping early only lowers the
/// gain, never lets a term in. Not for the first term: along KITTI's
/// focal length / distortion ridge its first step lowers the cost by under
/// 1e-4 and the term was lost (docs/benchmarks.md, session 28).
const SECOND_RADIAL_TRIAL_TOLERANCE: f64 = 1e-4;

/// `BaOptions::focal_step_tolerance` of the converged BAs that refine the
/// focal length (a camera estimated from the video): a step that moves it
/// by under 1e-4 of itself (0.05 px at 500 px) and lowers the cost by under
/// 1e-5 of it ends the BA (docs/benchmarks.md, session 27).
const SELF_CALIBRATION_FOCAL_STEP: f64 = 1e-4;

/// Global refinements (BA, track completion, filtering) of a map whose
/// camera was given a radial term. One: each is a converged BA of the
/// intrinsics, which creeps along the focal length's valley to its 50
/// iterations, and leaving out the second changed the ATE by -4 to +5 %
/// over TUM, KITTI odometry and the synthetic lenses and saved a second of
/// TUM's 13 (docs/benchmarks.md, session 27).
const RADIAL_REFINEMENTS: usize = 1;

/// COLMAP's `Camera::HasBogusParams` with its mapper's defaults: a focal
/// length 0.1 to 10 times the larger image side and extra parameters of at
/// most 1 in magnitude.
pub(crate) fn plausible_camera(camera: &Camera) -> bool {
    let side = camera.width.max(camera.height) as f64;
    let focal_ok = [camera.focal_x(), camera.focal_y()].iter().all(|f| (0.1 * side..=10.0 * side).contains(f));
    let extras = camera.model.extra_params_idxs();
    let c = camera.principal_point();
    let centre_ok = (0.0..=camera.width as f64).contains(&c.x) && (0.0..=camera.height as f64).contains(&c.y);
    focal_ok
        && centre_ok
        && extras.iter().all(|&i| camera.params.get(i).is_some_and(|v| v.is_finite() && v.abs() <= 1.0))
}

/// The cost gain of a trial BA with one more camera parameter (`with`)
/// over the same map without it (`without`), in units of the residual
/// variance of the fit without: chi-square with one degree of freedom when
/// the parameter is truly 0.
fn chi_square_gain(without: &colslam_optim::BaReport, with: &colslam_optim::BaReport) -> f64 {
    let variance = 2.0 * without.final_cost / without.num_residuals.max(1) as f64;
    2.0 * (without.final_cost - with.final_cost) / variance.max(f64::MIN_POSITIVE)
}

/// A trial bundle adjustment of a copy of the map (`rec`): the global BA
/// of the long tracks with the intrinsics refined, as the final ones.
fn trial_ba(
    rec: &mut Reconstruction,
    ba: &BundleOptions,
    min_track: usize,
    timings: &mut StageTimings,
) -> Result<colslam_optim::BaReport, SfmError> {
    timings.time(Stage::GlobalBa, || adjust_global_long_tracks(rec, true, ba, min_track, MIN_LONG_TRACK_OBSERVATIONS))
}

/// Scale between ORB pyramid levels: a keypoint found at octave `o` is
/// located to about `ORB_LEVEL_SCALE^o` pixels (ORB-SLAM's level sigma).
pub const ORB_LEVEL_SCALE: f32 = 1.2;

/// [`ORB_LEVEL_SCALE`] to the power `octave`: the size in full-resolution
/// pixels of a pixel of that pyramid level.
pub fn level_scale(octave: u8) -> f64 {
    f64::from(ORB_LEVEL_SCALE).powi(i32::from(octave))
}

/// The standard deviation of each keypoint of a frame (by pyramid level).
pub fn keypoint_sigmas(data: &FrameData) -> Vec<f32> {
    data.features.keypoints.iter().map(|k| ORB_LEVEL_SCALE.powi(i32::from(k.octave))).collect()
}

impl Mapper {
    /// An empty map for `camera` (COLMAP pixel convention).
    pub(super) fn empty(index: usize, camera: &Camera) -> Self {
        let mut rec = Reconstruction::new();
        let camera_id = rec.add_camera(camera.clone());
        Self {
            index,
            rec,
            graph: CorrespondenceGraph::new(),
            camera_id,
            keyframes: Vec::new(),
            records: RecordStore::default(),
            initial_frames: (0, 0),
            planar_start: false,
            camera_support: 0,
            last_global: (0, 0),
            focal_step: f64::INFINITY,
            focal_trace: Vec::new(),
            sigmas: KeypointSigmas::default(),
            intrinsics_version: 0,
            culled: 0,
            loops: Default::default(),
            mapping_ended: false,
            radial_tried: false,
        }
    }

    /// Index among the run's maps (order of creation).
    pub fn index(&self) -> usize {
        self.index
    }

    /// The reconstruction.
    pub fn reconstruction(&self) -> &Reconstruction {
        &self.rec
    }

    /// The correspondence graph between keyframes.
    pub fn graph(&self) -> &CorrespondenceGraph {
        &self.graph
    }

    /// The run's camera as the map holds it (refined when intrinsics are).
    pub fn camera(&self) -> Result<&Camera, SceneError> {
        self.camera_in(&self.rec)
    }

    /// This map's camera as `rec` (the map or a trial copy of it) has it.
    fn camera_in<'a>(&self, rec: &'a Reconstruction) -> Result<&'a Camera, SceneError> {
        rec.camera(self.camera_id).map(|c| &c.camera).ok_or(SceneError::UnknownCamera(self.camera_id))
    }

    /// Mean focal length of the map's camera, pixels.
    pub(crate) fn focal(&self) -> Result<f64, SceneError> {
        Ok(self.camera()?.mean_focal())
    }

    /// The camera when its refined focal length has settled (the last
    /// global BA moved it by less than [`FOCAL_SETTLED`]) and is plausible;
    /// `None` before the first global BA, while it still moves, or when it
    /// ran away.
    pub(crate) fn settled_camera(&self) -> Option<&Camera> {
        let camera = self.camera().ok()?;
        (self.focal_step < FOCAL_SETTLED && plausible_camera(camera)).then_some(camera)
    }

    /// The largest relative distance between the focal length now and the
    /// one each global BA left since the map had `1 / growth` of the
    /// registered images it has now (the last BA at or below that size
    /// included); `None` when no BA refined it that early. A focal length
    /// one BA barely moves can still be on its way: under forward motion
    /// KITTI's paused at 784 px over 16-20 keyframes and then went to 708
    /// (true ~719, docs/benchmarks.md). One that stayed put while the map
    /// grew by half is what the views say.
    pub(crate) fn focal_drift_since(&self, growth: f64) -> Option<f64> {
        let &(now_images, now) = self.focal_trace.last()?;
        let since = now_images as f64 / growth;
        let start = self.focal_trace.iter().rposition(|&(n, _)| n as f64 <= since)?;
        let drift = self.focal_trace[start..].iter().map(|&(_, f)| (f / now - 1.0).abs());
        Some(drift.fold(0.0, f64::max))
    }

    /// Whether the map's views can fix the focal length: not while it is
    /// the two images of an initial pair posed by their homography. Two
    /// views of a plane leave it free (a homography fits any focal length
    /// with another pose), and so do two views whose optical axes meet
    /// (Sturm 2001), which a car's level camera gives: the KITTI runs'
    /// consecutive initial frames ran the guess of 1489 px to 4070 px
    /// (kitti_odom00_first300) and 4391 px (the clip) in their two-view BA.
    /// A pair posed by its essential matrix refines it where its views say
    /// something about it ([`Self::views_fix_focal`]): the Strecha sets'
    /// two-view BAs move the guess most of the way to the truth, where a
    /// car's forward pair would let it run.
    ///
    /// Nor while the map has fewer registered images than the one the
    /// starting camera was settled in ([`Self::camera_support`]): a map of
    /// fewer views knows less about the focal length than that one did.
    /// KITTI's frames mapped again at the 699 px its first long map settled
    /// at (19 images, sharpness 0.14) had it taken to 526 px by their
    /// initial pair's two-view BA, broke twice and climbed back over 25
    /// keyframes (docs/benchmarks.md).
    pub(super) fn constrains_focal(&self) -> bool {
        let images = self.rec.num_registered_images();
        !(self.planar_start && images < 3) && images >= self.camera_support
    }

    /// Whether the map's views tell anything about the focal length:
    /// measured for the two views of an initial pair
    /// ([`crate::calibrate::focal_profile`]: they fix it within
    /// [`MAX_FOCAL_SIGMA`] or refute the guess by [`MIN_FOCAL_DROP`]), taken
    /// for granted from the third view on. Two views whose optical axes meet
    /// (Sturm 2001), as a car's forward drive gives, leave it free however
    /// their pose was found (the KITTI drive's initial pairs are posed by
    /// their essential matrix). Larger maps are refined as before: the
    /// measurement would cost three BAs each time, and the BAs of a growing
    /// map stop short of convergence, which made its profile noise (TUM's
    /// maps of three to five images measured concave ones and were held
    /// into losing frames; docs/benchmarks.md).
    pub(super) fn views_fix_focal(&self) -> Result<bool, SfmError> {
        let images = self.rec.num_registered_images();
        if images >= 3 {
            return Ok(true);
        }
        let profile = crate::calibrate::focal_profile(&self.rec, self.focal()?)?;
        tracing::debug!(
            "map {}: two views fix the focal length to {:.2} % and refute it by chi-square {:.2}",
            self.index,
            100.0 * profile.spread,
            profile.drop
        );
        Ok(profile.spread <= MAX_FOCAL_SIGMA || profile.drop >= MIN_FOCAL_DROP)
    }

    /// Notes that a bundle adjustment may have refined the intrinsics.
    pub(super) fn intrinsics_refined(&mut self, opts: &SlamOptions) {
        if opts.refine.refine_intrinsics {
            self.intrinsics_version += 1;
        }
    }

    /// Brings the normalised coordinates of the keyframes at positions `ks`
    /// to the map's current camera (nothing to do unless intrinsics were
    /// refined since they were made).
    pub fn refresh_keyframes(&mut self, ks: impl IntoIterator<Item = usize>) -> Result<(), SceneError> {
        let version = self.intrinsics_version;
        let camera = self.camera()?.clone();
        for k in ks {
            if let Some(kf) = self.keyframes.get_mut(k).filter(|kf| kf.version != version) {
                kf.data.normalize_with(&camera);
                kf.version = version;
            }
        }
        Ok(())
    }

    /// Brings every keyframe's normalised coordinates to the map's current
    /// camera (after intrinsics were refined); records derive theirs from
    /// their pixels when used ([`FrameRecord::normalized`]).
    pub fn refresh_all(&mut self) -> Result<(), SceneError> {
        self.refresh_keyframes(0..self.keyframes.len())
    }

    /// Registered keyframes, in the current order (frame order outside a
    /// backward pass).
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// The reference keyframe new frames are matched to: the last in order.
    pub fn last_keyframe(&self) -> Option<&Keyframe> {
        self.keyframes.last()
    }

    /// Keyframes culled as redundant so far (`--cull-keyframes`); their
    /// frames are among the records.
    pub fn culled_keyframes(&self) -> usize {
        self.culled
    }

    /// Records of the non-keyframes, pooled by frame, read into memory
    /// (tests and diagnostics; localisation reads them a batch at a time).
    pub fn records(&self) -> Result<Vec<FrameRecord>, SlamError> {
        self.records.pooled_all()
    }

    /// The store of the records.
    pub fn record_store(&self) -> &RecordStore {
        &self.records
    }

    /// Where and when the records spill to disk from now on (`None`: they
    /// stay in memory).
    pub fn set_record_spill(&mut self, config: Option<SpillConfig>) {
        self.records.set_config(config);
    }

    /// Drops the records and their temporary file, once every frame is
    /// localised.
    pub fn release_records(&mut self) {
        self.records.clear();
    }

    /// Frame indices of the initial pair.
    pub fn initial_frames(&self) -> (usize, usize) {
        self.initial_frames
    }

    /// Adds the record of a non-keyframe; returns its index.
    pub fn add_record(&mut self, record: FrameRecord) -> Result<usize, SlamError> {
        self.records.push(record)
    }

    /// Appends the matches of `data` to keyframe `kf` to record `index`
    /// (from [`Self::add_record`]).
    pub fn add_record_matches(
        &mut self,
        index: usize,
        data: &FrameData,
        kf: ImageId,
        matches: &[colslam_features::Match],
    ) {
        self.records.add_matches(index, data, kf, matches);
    }

    /// Marks record `index` as promoted: its frame became a keyframe.
    pub fn promote_record(&mut self, index: usize) {
        self.records.promote(index);
    }

    /// Adds records of frames to localise; those of a frame that already
    /// has one are pooled with it when localised ([`RecordStore::groups`]).
    pub fn add_records(&mut self, extra: Vec<FrameRecord>) -> Result<(), SlamError> {
        for r in extra {
            self.records.push(r)?;
        }
        Ok(())
    }

    /// Orders the keyframes by distance in time to frame `index`, nearest
    /// last, so that it becomes the reference and the nearest ones are those
    /// registration matches against (tracking backwards).
    pub fn order_keyframes_by_distance_to(&mut self, index: usize) {
        self.keyframes.sort_by(|a, b| {
            b.data
                .index()
                .abs_diff(index)
                .cmp(&a.data.index().abs_diff(index))
                .then(a.data.index().cmp(&b.data.index()))
        });
    }

    /// Restores frame order of the keyframes.
    pub fn order_keyframes_by_time(&mut self) {
        self.keyframes.sort_by_key(|k| k.data.index());
    }

    /// Filters the given points (all when `None`) by depth, reprojection
    /// error and triangulation angle (COLMAP's `FilterPoints`); returns the
    /// number of points deleted.
    pub fn filter(&mut self, points: Option<&[Point3DId]>, opts: &SlamOptions) -> Result<usize, SfmError> {
        // Bundle adjustment gives points behind a camera zero cost (as
        // COLMAP's cost functions do), so those observations go first.
        let d = self.rec.filter_negative_depth(points)?;
        let a = self.rec.filter_by_reprojection_error(opts.mapper.max_reproj_error, points)?;
        let b = self.rec.filter_by_triangulation_angle(opts.mapper.min_tri_angle, points)?;
        tracing::trace!(
            "filter: depth removed {} observations, reprojection {} observations / {} points, angle {} points",
            d.observations_removed,
            a.observations_removed,
            a.points_deleted,
            b.points_deleted
        );
        Ok(d.points_deleted + a.points_deleted + b.points_deleted)
    }

    /// Frees the principal point in `ba`, a final BA (the map then carries
    /// it), with `--refine-principal-point` when the intrinsics are refined:
    /// a camera without distortion terms once no radial term is still to be
    /// tried (`--estimate-distortion`), and the radial term the trial kept
    /// together with it. Not before the trial: the freed principal point
    /// absorbs part of a lens's distortion (28 px off on the synthetic room
    /// with a barrel lens) and the term is then tried from there (that room
    /// ended at 1.66 mm against 0.29 mm). A given calibration's distortion
    /// terms keep it held. True when freed.
    fn free_principal_point(&self, ba: &mut BundleOptions, opts: &SlamOptions) -> Result<bool, SceneError> {
        let settled =
            self.radial_tried || (self.camera()?.model.extra_params_idxs().is_empty() && !self.radial_pending(opts)?);
        let free = opts.refine.refine_intrinsics
            && opts.refine.refine_principal_point
            && ba.intrinsics == RefinedIntrinsics::Calibration
            && settled;
        if free {
            ba.intrinsics = RefinedIntrinsics::WithPrincipalPoint;
        }
        Ok(free)
    }

    /// True while a radial term is still to be tried on this map's camera at
    /// the end (`--estimate-distortion`): a refined one-focal pinhole camera
    /// of a map with at least [`RADIAL_MIN_KEYFRAMES`] keyframes.
    fn radial_pending(&self, opts: &SlamOptions) -> Result<bool, SceneError> {
        Ok(opts.refine.refine_intrinsics
            && opts.refine.estimate_distortion
            && !self.radial_tried
            && self.camera()?.model == CameraModelId::SimplePinhole
            && self.keyframes.len() >= RADIAL_MIN_KEYFRAMES)
    }

    /// Global refinement (paper 3.6): global bundle adjustment to
    /// `tolerance`, then normalisation, merge/complete of all tracks and
    /// filtering. Resets the growth counters of [`Self::needs_global_refine`].
    pub fn global_refine(
        &mut self,
        tolerance: GlobalBaTolerance,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<colslam_optim::BaReport, SfmError> {
        let mut ba = opts.global_ba(tolerance, self.focal_step < FOCAL_SETTLED);
        // The converged BAs once mapping ended settle the final map.
        let final_ba = self.mapping_ended && tolerance == GlobalBaTolerance::Converged;
        if opts.refine.robust_final_ba
            && final_ba
            && let Some(scale) = self.median_point_error()?
        {
            ba.ba.loss = final_ba_loss(ba.ba.loss, FINAL_BA_LOSS_SCALE * scale);
            ba.ba.max_iterations = ROBUST_FINAL_BA_MAX_ITERATIONS;
        }
        // Held: refined intrinsics the map's views cannot fix yet; the
        // focal length's own test only where the focal length is refined
        // (a calibration's residual radial term is not).
        let refines_focal = ba.intrinsics != RefinedIntrinsics::FirstRadial;
        let held = opts.refine.refine_intrinsics
            && !(self.constrains_focal() && (!refines_focal || self.views_fix_focal()?));
        let refine = opts.refine.refine_intrinsics && !held;
        if refine && refines_focal && tolerance == GlobalBaTolerance::Converged {
            ba.ba.focal_step_tolerance = SELF_CALIBRATION_FOCAL_STEP;
        }
        let frees_centre = final_ba && self.free_principal_point(&mut ba, opts)?;
        self.log_global_probe("before");
        let before = self.focal()?;
        // A residual distortion term that runs away (mismatches of a young
        // map under forward motion pull it along the depth it trades with)
        // is refused: the map goes back and is adjusted with it held.
        let kept = (opts.refine.refine_distortion || frees_centre).then(|| self.rec.clone());
        // Once mapping ended, the short tracks leave the pose estimate
        // (`--final-ba-min-track`); while it grows, the newest keyframe's
        // points are all two-view tracks and it needs them.
        let min_track = self.min_track(opts);
        let adjust = |rec: &mut Reconstruction, refine: bool| {
            adjust_global_long_tracks(rec, refine, &ba, min_track, MIN_LONG_TRACK_OBSERVATIONS)
        };
        let mut report = timings.time(Stage::GlobalBa, || adjust(&mut self.rec, refine))?;
        if let Some(kept) = kept
            && !plausible_camera(self.camera()?)
        {
            tracing::debug!("map {}: the refined distortion term ran away; held for this BA", self.index);
            self.rec = kept;
            report = timings.time(Stage::GlobalBa, || adjust(&mut self.rec, false))?;
        }
        self.focal_step = if held { f64::INFINITY } else { (self.focal()? / before - 1.0).abs() };
        if refine {
            self.focal_trace.push((self.rec.num_registered_images(), self.focal()?));
        }
        self.intrinsics_refined(opts);
        tracing::debug!(
            "map {}: global BA over {} images / {} points: cost {:.4e} -> {:.4e} in {} iterations ({:?}, {:.2} s), focal {:.1} px{}",
            self.index,
            self.rec.num_registered_images(),
            self.rec.num_points3d(),
            report.initial_cost,
            report.final_cost,
            report.iterations,
            report.termination,
            report.time.as_secs_f64(),
            self.focal()?,
            if held { " (held: the views do not constrain it yet)" } else { "" }
        );
        self.rec.normalize(&colslam_scene::NormalizeOptions::default())?;
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || complete_and_merge_all(&mut self.rec, &self.graph, &tri))?;
        let removed = self.filter(None, opts)?;
        tracing::debug!("map {}: global filter removed {removed} points, {} left", self.index, self.rec.num_points3d());
        self.last_global = (self.rec.num_registered_images(), self.rec.num_points3d());
        self.log_global_probe("after");
        Ok(report)
    }

    /// The median over the points of their mean reprojection error, pixels
    /// (`None` without points): the map's own error level, which scales the
    /// final bundle adjustments' robust loss.
    fn median_point_error(&mut self) -> Result<Option<f64>, SceneError> {
        self.rec.update_point_errors()?;
        let mut errors: Vec<f64> = self.rec.points3d().map(|(_, p)| p.error).filter(|e| *e > 0.0).collect();
        Ok(colslam_geometry::stats::median_in_place(&mut errors))
    }

    /// True when registered keyframes or points grew by
    /// `global_ba_growth` since the last global refinement (COLMAP's
    /// schedule).
    pub fn needs_global_refine(&self, opts: &SlamOptions) -> bool {
        let imgs = self.rec.num_registered_images() as f64;
        let pts = self.rec.num_points3d() as f64;
        let growth = opts.mapper.global_ba_growth;
        imgs >= growth * self.last_global.0 as f64 || pts >= growth * self.last_global.1 as f64
    }

    /// Final global refinement and point errors at the end of the run; with
    /// rolling-shutter compensation to follow, only to the periodic
    /// tolerance (the compensation ends with its own converged BA).
    pub fn finalize(&mut self, opts: &SlamOptions, timings: &mut StageTimings) -> Result<(), SfmError> {
        self.mapping_ended = true;
        if self.rec.num_registered_images() >= 2 {
            self.global_refine(opts.final_ba_tolerance(), opts, timings)?;
            self.try_radial_distortion(opts, timings)?;
        }
        self.rec.update_point_errors()?;
        Ok(())
    }

    /// The shortest track that enters a global BA: `--final-ba-min-track`
    /// once mapping ended, every track before.
    fn min_track(&self, opts: &SlamOptions) -> usize {
        if self.mapping_ended { opts.refine.final_ba_min_track } else { 0 }
    }

    /// Once the map is final, gives a refined one-focal pinhole camera (a
    /// guess or an estimate) a radial distortion term when the data ask for
    /// it: a converged global BA of the map with SIMPLE_PINHOLE, then one
    /// with SIMPLE_RADIAL (k from 0) from its optimum, both with the
    /// principal point held at the centre (COLMAP's setting), and the radial
    /// camera kept when its cost gain is significant ([`RADIAL_GAIN_CHI2`]),
    /// it moves the image's corners by at least [`MIN_RADIAL_SHIFT_PX`] and
    /// its parameters are plausible (COLMAP's bogus-camera check); a kept
    /// term may gain a second ([`Self::try_second_radial_term`]). Then the
    /// final refinements free the principal point, with the terms if kept,
    /// and drop a lens that moves the image by under [`MIN_RADIAL_SHIFT_PX`]
    /// there. Only now: the map made with the focal length alone carries k,
    /// while k freed from the first keyframes trades against the focal
    /// length (docs/history.md).
    fn try_radial_distortion(&mut self, opts: &SlamOptions, timings: &mut StageTimings) -> Result<(), SfmError> {
        if !self.radial_pending(opts)? {
            return Ok(());
        }
        let mut ba = opts.global_ba(GlobalBaTolerance::Converged, true);
        ba.ba.focal_step_tolerance = SELF_CALIBRATION_FOCAL_STEP;
        let min_track = self.min_track(opts);
        let mut pinhole = self.rec.clone();
        let p = trial_ba(&mut pinhole, &ba, min_track, timings)?;
        // The term is tried from the pinhole's optimum: its BA starts where
        // the pinhole's ended, so whatever it lowers the cost by is the
        // term's, and it converges in fewer iterations than from the map
        // before (TUM fr1 18 against 31).
        let mut radial = pinhole.clone();
        if let Some(c) = radial.camera_mut(self.camera_id) {
            *c = c.with_radial_term();
        }
        let r = trial_ba(&mut radial, &ba, min_track, timings)?;
        tracing::debug!(
            "map {}: radial trial: pinhole {:.5e} -> {:.5e} in {} iterations ({:.2} s), radial {:.5e} -> {:.5e} in {} iterations ({:.2} s)",
            self.index,
            p.initial_cost,
            p.final_cost,
            p.iterations,
            p.time.as_secs_f64(),
            r.initial_cost,
            r.final_cost,
            r.iterations,
            r.time.as_secs_f64()
        );
        let gain = chi_square_gain(&p, &r);
        let refined = self.camera_in(&radial)?.clone();
        let shift = calibrate::distortion_shift(&refined);
        let plausible = plausible_camera(&refined);
        let keep =
            plausible && r.num_residuals == p.num_residuals && gain > RADIAL_GAIN_CHI2 && shift >= MIN_RADIAL_SHIFT_PX;
        tracing::info!(
            "map {}: radial distortion {}: k {:.4}, focal {:.1} px (pinhole {:.1}), cost gain {gain:.1} (threshold {RADIAL_GAIN_CHI2}), moves the image {shift:.2} px (at least {MIN_RADIAL_SHIFT_PX}){}",
            self.index,
            if keep { "estimated" } else { "left out" },
            refined.params.get(3).copied().unwrap_or(0.0),
            refined.focal_x(),
            pinhole.camera(self.camera_id).map_or(f64::NAN, |c| c.camera.focal_x()),
            if plausible { "" } else { ", implausible parameters" }
        );
        self.radial_tried = true;
        if !keep {
            // The pinhole map once more, with its principal point freed.
            self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
            return Ok(());
        }
        let radial = self.try_second_radial_term(radial, &r, &ba, min_track, timings)?;
        let unrefined = std::mem::replace(&mut self.rec, radial);
        self.intrinsics_refined(opts);
        // The tracks the pinhole map filtered near the borders come back,
        // and the radial camera is refined with them.
        for _ in 0..RADIAL_REFINEMENTS {
            self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        }
        // With the principal point free a term that stood in for its offset
        // from the centre shrinks (Strecha castle's photos: k -0.009 at the
        // trial, -0.001 after); then the pinhole map goes on without it.
        let refined_shift = calibrate::distortion_shift(self.camera()?);
        if refined_shift < MIN_RADIAL_SHIFT_PX {
            tracing::info!(
                "map {}: radial distortion dropped: with the principal point refined it moves the image {refined_shift:.2} px",
                self.index
            );
            self.rec = unrefined;
            self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        }
        Ok(())
    }

    /// Once the trial kept a radial term, tries a second (SIMPLE_RADIAL to
    /// RADIAL, k2 from 0) on the trial's converged map `one` (its BA's
    /// report `one_report`): a global BA with both terms from the same
    /// state to [`SECOND_RADIAL_TRIAL_TOLERANCE`] (the principal point held
    /// at the centre, as in the trial), the second kept when its gain is
    /// significant ([`RADIAL_GAIN_CHI2`]), removes at least
    /// [`SECOND_RADIAL_MIN_GAIN`] of the cost, moves the image by at least
    /// [`MIN_RADIAL_SHIFT_PX`] on its own and the camera is plausible.
    /// Returns the map to refine on: with both terms or `one` as it was. A
    /// lens that one term does not describe otherwise pulls the focal length
    /// along with the term (the synthetic pincushion lens ended 0.8 % long
    /// and its trajectory 2.5x the calibrated run's).
    fn try_second_radial_term(
        &self,
        one: Reconstruction,
        one_report: &colslam_optim::BaReport,
        ba: &BundleOptions,
        min_track: usize,
        timings: &mut StageTimings,
    ) -> Result<Reconstruction, SfmError> {
        let camera = self.camera_in(&one)?.clone();
        if camera.model != CameraModelId::SimpleRadial {
            return Ok(one);
        }
        let mut two = one.clone();
        if let Some(c) = two.camera_mut(self.camera_id) {
            *c = camera.with_second_radial_term();
        }
        let mut ba = BundleOptions { intrinsics: RefinedIntrinsics::EveryTerm, ..ba.clone() };
        ba.ba.function_tolerance = SECOND_RADIAL_TRIAL_TOLERANCE;
        let r = trial_ba(&mut two, &ba, min_track, timings)?;
        let p = one_report;
        let gain = chi_square_gain(p, &r);
        let share = (p.final_cost - r.final_cost) / p.final_cost.max(f64::MIN_POSITIVE);
        let refined = self.camera_in(&two)?.clone();
        let shift = calibrate::term_shift(&refined, refined.model.extra_params_idxs().get(1..).unwrap_or_default());
        let plausible = plausible_camera(&refined);
        let keep = plausible
            && r.num_residuals == p.num_residuals
            && gain > RADIAL_GAIN_CHI2
            && share >= SECOND_RADIAL_MIN_GAIN
            && shift >= MIN_RADIAL_SHIFT_PX;
        tracing::debug!(
            "map {}: second radial trial: {:.5e} -> {:.5e} in {} iterations ({:.2} s; one term: {:.5e})",
            self.index,
            r.initial_cost,
            r.final_cost,
            r.iterations,
            r.time.as_secs_f64(),
            p.final_cost
        );
        tracing::info!(
            "map {}: second radial term {}: k1 {:.4}, k2 {:.4}, focal {:.1} px (one term {:.1}), cost gain {gain:.1} (threshold {RADIAL_GAIN_CHI2}), {:.2} % of the cost (at least {:.1} %), it moves the image {shift:.2} px (at least {MIN_RADIAL_SHIFT_PX}){}",
            self.index,
            if keep { "estimated" } else { "left out" },
            refined.params.get(3).copied().unwrap_or(0.0),
            refined.params.get(4).copied().unwrap_or(0.0),
            refined.focal_x(),
            camera.focal_x(),
            100.0 * share,
            100.0 * SECOND_RADIAL_MIN_GAIN,
            if plausible { "" } else { ", implausible parameters" }
        );
        Ok(if keep { two } else { one })
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
            // Every id comes from the loop above over existing points.
            let _ = self.rec.set_point3d_color(pid, c);
        }
    }
}

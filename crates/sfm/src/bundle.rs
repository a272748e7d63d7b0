//! Bundle adjustment of a `Reconstruction`: builds a `colslam_optim::Problem`
//! from a chosen set of variable images and points, solves it and writes the
//! refined poses, points and intrinsics back (after COLMAP's
//! `BundleAdjustmentConfig` and `IncrementalMapper::AdjustLocalBundle` /
//! `AdjustGlobalBundle`).

use crate::SfmError;
use colslam_optim::{BaOptions, BaPose, BaReport, BundleAdjuster, IntrinsicsRefinement, LossFunction, Problem};
use colslam_scene::{CameraId, ImageId, Point3DId, Reconstruction};
use std::collections::{BTreeMap, BTreeSet};

/// Which parts of the model a bundle adjustment refines.
#[derive(Debug, Clone, Default)]
pub struct BundleConfig {
    /// Images whose poses vary (must be registered).
    pub variable_images: BTreeSet<ImageId>,
    /// Images whose poses are held constant. Other registered images that
    /// observe a variable point are added as constant too.
    pub constant_images: BTreeSet<ImageId>,
    /// Images whose pose is constant except for one translation coordinate
    /// (gauge fixing through a second pose); chosen automatically when
    /// `None` and the bundle has no constant image.
    pub gauge: Option<(ImageId, ImageId)>,
    /// Points that vary: `None` means every point observed by a variable image.
    pub variable_points: Option<BTreeSet<Point3DId>>,
    /// Refine the intrinsics of cameras used by variable images.
    pub refine_intrinsics: bool,
}

/// Per-keypoint measurement standard deviations in pixels, by image (a
/// keypoint detected at a coarser pyramid level is less precise).
pub type KeypointSigmas = std::sync::Arc<std::collections::HashMap<ImageId, Vec<f32>>>;

/// Options of [`adjust_bundle`] beyond the configuration.
#[derive(Debug, Clone, Default)]
pub struct BundleOptions {
    /// Solver options (loss, tolerances, iterations, which intrinsics).
    pub ba: BaOptions,
    /// Standard deviation of each keypoint's position (px); observations are
    /// weighted by its inverse (ORB-SLAM's per-level information). Missing
    /// entries weigh 1.
    pub keypoint_sigmas: Option<KeypointSigmas>,
    /// Which intrinsics a bundle that refines them frees.
    pub intrinsics: RefinedIntrinsics,
}

/// Which intrinsics a bundle adjustment refining them frees.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RefinedIntrinsics {
    /// The focal length(s) and the distortion terms the calibration uses
    /// ([`refined_intrinsics`]).
    #[default]
    Calibration,
    /// The first radial distortion term alone (focal length and principal
    /// point held): a given calibration's residual radial distortion.
    FirstRadial,
    /// [`Self::Calibration`]'s parameters and the principal point: a
    /// self-calibration's final BA, once the map carries it.
    WithPrincipalPoint,
    /// The focal length(s) and every distortion term of the model, zero or
    /// not: an estimated camera's term just added at 0, which
    /// [`Self::Calibration`] would hold beside the non-zero ones.
    EveryTerm,
}

impl BundleOptions {
    /// COLMAP's local-BA settings: soft-L1 loss of scale 1 px, at most 25
    /// iterations.
    pub fn local() -> Self {
        Self {
            ba: BaOptions { loss: LossFunction::SoftL1(1.0), max_iterations: 25, ..BaOptions::default() },
            ..Self::default()
        }
    }

    /// COLMAP's global-BA settings: trivial loss, at most 50 iterations.
    pub fn global() -> Self {
        Self { ba: BaOptions { max_iterations: 50, ..BaOptions::default() }, ..Self::default() }
    }
}

/// The up-to-`max_images` registered images sharing the most 3D points with
/// `image_id` (COLMAP's `FindLocalBundle`), most shared first.
pub fn most_connected_images(rec: &Reconstruction, image_id: ImageId, max_images: usize) -> Vec<ImageId> {
    covisible_images(rec, image_id, 1, max_images)
}

/// The up-to-`max_images` images sharing at least `min_shared` 3D points
/// with `image_id` (ORB-SLAM's covisible keyframes, whose graph links
/// keyframes sharing 15 points), most shared first; ties: lower id.
pub fn covisible_images(rec: &Reconstruction, image_id: ImageId, min_shared: usize, max_images: usize) -> Vec<ImageId> {
    let Some(img) = rec.image(image_id) else { return Vec::new() };
    let mut shared: BTreeMap<ImageId, usize> = BTreeMap::new();
    for p2 in &img.points2d {
        let Some(p) = p2.point3d_id.and_then(|pid| rec.point3d(pid)) else { continue };
        for el in &p.track {
            if el.image_id != image_id {
                *shared.entry(el.image_id).or_insert(0) += 1;
            }
        }
    }
    let mut v: Vec<(ImageId, usize)> = shared.into_iter().filter(|(_, n)| *n >= min_shared).collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v.into_iter().take(max_images).map(|(id, _)| id).collect()
}

/// The intrinsics refined when `refine_intrinsics` is set: the focal
/// length(s) and the distortion terms the calibration uses. A coefficient
/// that is exactly zero beside non-zero ones is a term the calibration left
/// out (a 5-coefficient OpenCV calibration stored as FULL_OPENCV has k4 = k5
/// = k6 = 0); freeing it lets BA trade it against the others, which on TUM
/// fr1 drove k1 to 26. A camera without any distortion value (a guess)
/// refines every term of its model. The principal point stays fixed, as in
/// COLMAP, unless [`RefinedIntrinsics::WithPrincipalPoint`] frees it. With [`RefinedIntrinsics::FirstRadial`], the model's first
/// radial term alone (none for a model without distortion); with
/// [`RefinedIntrinsics::EveryTerm`], every term of the model.
pub fn refined_intrinsics(camera: &colslam_camera::Camera, which: RefinedIntrinsics) -> IntrinsicsRefinement {
    let model = camera.model;
    if which == RefinedIntrinsics::FirstRadial {
        return match model.extra_params_idxs().first() {
            Some(k1) => IntrinsicsRefinement::Params(vec![*k1]),
            None => IntrinsicsRefinement::Fixed,
        };
    }
    let mut idx: Vec<usize> = model.focal_length_idxs().to_vec();
    let extras = model.extra_params_idxs();
    if which == RefinedIntrinsics::EveryTerm {
        idx.extend_from_slice(extras);
        return IntrinsicsRefinement::Params(idx);
    }
    let used: Vec<usize> =
        extras.iter().copied().filter(|&i| camera.params.get(i).is_some_and(|v| *v != 0.0)).collect();
    idx.extend(if used.is_empty() { extras.to_vec() } else { used });
    if which == RefinedIntrinsics::WithPrincipalPoint {
        idx.extend_from_slice(model.principal_point_idxs());
        idx.sort_unstable();
    }
    IntrinsicsRefinement::Params(idx)
}

/// Index of each camera and pose of the bundle in the problem.
struct ProblemIndex {
    cameras: BTreeMap<CameraId, usize>,
    poses: BTreeMap<ImageId, usize>,
    points: Vec<Point3DId>,
}

/// The points `config` optimises: those given, or every point of the
/// variable images.
fn variable_points(rec: &Reconstruction, config: &BundleConfig) -> Result<BTreeSet<Point3DId>, SfmError> {
    if let Some(p) = &config.variable_points {
        return Ok(p.iter().copied().filter(|id| rec.point3d(*id).is_some()).collect());
    }
    let mut s = BTreeSet::new();
    for id in &config.variable_images {
        let img = rec.image(*id).ok_or(SfmError::UnknownImage(*id))?;
        s.extend(img.points2d.iter().filter_map(|p| p.point3d_id));
    }
    Ok(s)
}

/// Adds the cameras and poses of `images` (registered ones) to `problem`.
/// Cameras used by a constant image only stay fixed even when refining.
fn add_images(
    problem: &mut Problem,
    rec: &Reconstruction,
    config: &BundleConfig,
    images: &BTreeSet<ImageId>,
    which: RefinedIntrinsics,
) -> Result<ProblemIndex, SfmError> {
    let mut index = ProblemIndex { cameras: BTreeMap::new(), poses: BTreeMap::new(), points: Vec::new() };
    for id in images {
        let img = rec.image(*id).ok_or(SfmError::UnknownImage(*id))?;
        if !img.registered {
            continue;
        }
        let variable = config.variable_images.contains(id) && !config.constant_images.contains(id);
        if let std::collections::btree_map::Entry::Vacant(e) = index.cameras.entry(img.camera_id) {
            let cam = rec.camera(img.camera_id).ok_or(colslam_scene::SceneError::UnknownCamera(img.camera_id))?;
            let refine = if config.refine_intrinsics {
                refined_intrinsics(&cam.camera, which)
            } else {
                IntrinsicsRefinement::Fixed
            };
            e.insert(problem.add_camera(cam.camera.clone(), refine));
        }
        let pose = if variable { BaPose::variable(img.cam_from_world) } else { BaPose::fixed(img.cam_from_world) };
        index.poses.insert(*id, problem.add_pose(pose));
    }
    if config.refine_intrinsics {
        for (cid, &ci) in &index.cameras {
            let used_by_variable =
                config.variable_images.iter().filter_map(|id| rec.image(*id)).any(|img| img.camera_id == *cid);
            if !used_by_variable {
                problem.cameras[ci].refine = IntrinsicsRefinement::Fixed;
            }
        }
    }
    Ok(index)
}

/// Adds the points and their observations in the problem's images, each
/// weighted by its keypoint's standard deviation when given.
fn add_points(
    problem: &mut Problem,
    index: &mut ProblemIndex,
    rec: &Reconstruction,
    opts: &BundleOptions,
    points: &BTreeSet<Point3DId>,
) {
    index.points.reserve(points.len());
    for pid in points {
        let Some(p) = rec.point3d(*pid) else { continue };
        let pi = problem.add_point(p.xyz, false);
        index.points.push(*pid);
        for el in &p.track {
            let (Some(&pose), Some(img)) = (index.poses.get(&el.image_id), rec.image(el.image_id)) else { continue };
            let Some(&cam) = index.cameras.get(&img.camera_id) else { continue };
            let Some(kp) = img.points2d.get(el.point2d_idx as usize) else { continue };
            let sigma = opts
                .keypoint_sigmas
                .as_ref()
                .and_then(|m| m.get(&el.image_id))
                .and_then(|v| v.get(el.point2d_idx as usize))
                .copied()
                .filter(|s| s.is_finite() && *s > 0.0)
                .unwrap_or(1.0);
            problem.add_weighted_observation(pose, cam, pi, kp.xy, 1.0 / f64::from(sigma));
        }
    }
}

/// Gauge: with no constant pose, fix one pose and one translation
/// coordinate of another, as COLMAP does.
fn fix_gauge(problem: &mut Problem, index: &ProblemIndex, config: &BundleConfig) {
    let any_constant = problem.poses.iter().any(|p| p.fixed);
    let gauge = config.gauge.or_else(|| {
        if any_constant {
            return None;
        }
        let mut it = config.variable_images.iter();
        match (it.next(), it.next()) {
            (Some(a), Some(b)) => Some((*a, *b)),
            _ => None,
        }
    });
    if let Some((a, b)) = gauge
        && let (Some(&ia), Some(&ib)) = (index.poses.get(&a), index.poses.get(&b))
    {
        problem.fix_gauge(ia, ib);
    }
}

/// Writes the solved poses, points and (when refined) intrinsics back.
fn write_back(
    rec: &mut Reconstruction,
    problem: &Problem,
    index: &ProblemIndex,
    config: &BundleConfig,
) -> Result<(), SfmError> {
    for (id, &pi) in &index.poses {
        if let Some(pose) = problem.poses.get(pi)
            && (!pose.fixed || pose.fixed_translation.iter().any(|f| *f))
        {
            rec.set_cam_from_world(*id, pose.cam_from_world)?;
        }
    }
    for (pid, bp) in index.points.iter().zip(&problem.points) {
        if let Some(xyz) = rec.point3d_xyz_mut(*pid) {
            *xyz = bp.xyz;
        }
    }
    if config.refine_intrinsics {
        for (cid, &ci) in &index.cameras {
            if let (Some(dst), Some(src)) = (rec.camera_mut(*cid), problem.cameras.get(ci)) {
                dst.params.clone_from(&src.camera.params);
            }
        }
    }
    Ok(())
}

/// Runs bundle adjustment on the part of `rec` named by `config` and writes
/// the result back.
pub fn adjust_bundle(
    rec: &mut Reconstruction,
    config: &BundleConfig,
    opts: &BundleOptions,
) -> Result<BaReport, SfmError> {
    let variable_points = variable_points(rec, config)?;
    // Every registered image observing a variable point takes part.
    let mut images: BTreeSet<ImageId> = config.variable_images.clone();
    for pid in &variable_points {
        if let Some(p) = rec.point3d(*pid) {
            images.extend(p.track.iter().map(|e| e.image_id));
        }
    }
    images.extend(config.constant_images.iter().copied());
    let mut problem = Problem::default();
    let mut index = add_images(&mut problem, rec, config, &images, opts.intrinsics)?;
    add_points(&mut problem, &mut index, rec, opts, &variable_points);
    fix_gauge(&mut problem, &index, config);
    let report = BundleAdjuster::solve(&mut problem, &opts.ba)?;
    write_back(rec, &problem, &index, config)?;
    Ok(report)
}

/// Global bundle adjustment: every registered image and every point vary,
/// the gauge is fixed through the first two registered images.
pub fn adjust_global(
    rec: &mut Reconstruction,
    refine_intrinsics: bool,
    opts: &BundleOptions,
) -> Result<BaReport, SfmError> {
    let points = rec.point3d_ids().into_iter().collect();
    adjust_bundle(rec, &global_config(rec, points, refine_intrinsics), opts)
}

/// Every registered image varies, with `points`; the gauge is fixed
/// through the first two registered images.
fn global_config(rec: &Reconstruction, points: BTreeSet<Point3DId>, refine_intrinsics: bool) -> BundleConfig {
    let reg = rec.registered_image_ids();
    let gauge = match (reg.first(), reg.get(1)) {
        (Some(a), Some(b)) => Some((*a, *b)),
        _ => None,
    };
    BundleConfig {
        variable_images: reg.iter().copied().collect(),
        constant_images: BTreeSet::new(),
        gauge,
        variable_points: Some(points),
        refine_intrinsics,
    }
}

/// Global bundle adjustment in which only the points seen by at least
/// `min_track` registered images move the poses and intrinsics; the
/// shorter tracks are adjusted afterwards with every pose and camera held.
/// An image with fewer than `min_image_observations` observations of such
/// points keeps its short tracks in the first adjustment, so that no pose
/// is left without observations. `min_track` of 2 or less is
/// [`adjust_global`].
///
/// Why: a track of two views checks its observations only along their
/// epipolar line, so an observation a pixel or two off (a mismatch, a
/// coarse pyramid level) bends the two poses to fit it, and no reprojection
/// test catches it afterwards. From three views on the views check each
/// other. GLOMAP's track establishment (colmap/src/glomap,
/// `min_num_views_per_track = 3`) keeps tracks of three views and more for
/// its global positioning and bundle adjustment.
pub fn adjust_global_long_tracks(
    rec: &mut Reconstruction,
    refine_intrinsics: bool,
    opts: &BundleOptions,
    min_track: usize,
    min_image_observations: usize,
) -> Result<BaReport, SfmError> {
    if min_track <= 2 {
        return adjust_global(rec, refine_intrinsics, opts);
    }
    let (long, short) = split_by_track_length(rec, min_track, min_image_observations);
    let report = adjust_bundle(rec, &global_config(rec, long, refine_intrinsics), opts)?;
    if short.is_empty() {
        return Ok(report);
    }
    let structure = BundleConfig {
        variable_images: BTreeSet::new(),
        constant_images: rec.registered_image_ids().iter().copied().collect(),
        gauge: None,
        variable_points: Some(short),
        refine_intrinsics: false,
    };
    adjust_bundle(rec, &structure, opts)?;
    Ok(report)
}

/// The points of `rec` seen by at least `min_track` registered images, and
/// the others; the short tracks of an image with fewer than
/// `min_image_observations` observations of long ones count as long.
fn split_by_track_length(
    rec: &Reconstruction,
    min_track: usize,
    min_image_observations: usize,
) -> (BTreeSet<Point3DId>, BTreeSet<Point3DId>) {
    let registered = |id: ImageId| rec.image(id).is_some_and(|img| img.registered);
    let views =
        |pid: Point3DId| rec.point3d(pid).map_or(0, |p| p.track.iter().filter(|e| registered(e.image_id)).count());
    let (mut long, mut short): (BTreeSet<Point3DId>, BTreeSet<Point3DId>) =
        rec.point3d_ids().into_iter().partition(|pid| views(*pid) >= min_track);
    if short.is_empty() {
        return (long, short);
    }
    for id in rec.registered_image_ids() {
        let Some(img) = rec.image(*id) else { continue };
        let observed = img.points2d.iter().filter_map(|p| p.point3d_id);
        if observed.clone().filter(|pid| long.contains(pid)).count() < min_image_observations {
            for pid in observed {
                if short.remove(&pid) {
                    long.insert(pid);
                }
            }
        }
    }
    (long, short)
}

/// Local bundle adjustment around `image_id`: it and its up to
/// `num_images - 1` most connected images vary ([`adjust_local_bundle`]).
pub fn adjust_local(
    rec: &mut Reconstruction,
    image_id: ImageId,
    num_images: usize,
    refine_intrinsics: bool,
    opts: &BundleOptions,
) -> Result<BaReport, SfmError> {
    let mut local = vec![image_id];
    local.extend(most_connected_images(rec, image_id, num_images.saturating_sub(1)));
    adjust_local_bundle(rec, &local, refine_intrinsics, opts)
}

/// Local bundle adjustment of the images `local` (the new one first, then
/// its neighbours, most connected first): they vary, with every point they
/// observe; other images observing those points are constant. When the
/// bundle touches no constant image (a young map), its two last members fix
/// the gauge (COLMAP's `AdjustLocalBundle`).
pub fn adjust_local_bundle(
    rec: &mut Reconstruction,
    local: &[ImageId],
    refine_intrinsics: bool,
    opts: &BundleOptions,
) -> Result<BaReport, SfmError> {
    let variable: BTreeSet<ImageId> = local.iter().copied().collect();
    let mut points = BTreeSet::new();
    for id in local {
        if let Some(img) = rec.image(*id) {
            points.extend(img.points2d.iter().filter_map(|p| p.point3d_id));
        }
    }
    let mut observers = BTreeSet::new();
    for pid in &points {
        if let Some(p) = rec.point3d(*pid) {
            observers.extend(p.track.iter().map(|e| e.image_id));
        }
    }
    let has_constant = observers.iter().any(|id| !variable.contains(id));
    let gauge =
        if has_constant || local.len() < 2 { None } else { Some((local[local.len() - 1], local[local.len() - 2])) };
    let config = BundleConfig {
        variable_images: variable,
        constant_images: BTreeSet::new(),
        gauge,
        variable_points: Some(points),
        refine_intrinsics,
    };
    adjust_bundle(rec, &config, opts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_camera::{Camera, CameraModelId};

    #[test]
    fn refinement_keeps_unused_distortion_terms_fixed() {
        // TUM fr1 (plumb_bob) stored as FULL_OPENCV: k4..k6 are not part of it.
        let tum = Camera {
            model: CameraModelId::FullOpenCv,
            width: 640,
            height: 480,
            params: vec![517.3, 516.5, 318.6, 255.3, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633, 0.0, 0.0, 0.0],
        };
        assert_eq!(
            refined_intrinsics(&tum, RefinedIntrinsics::Calibration),
            IntrinsicsRefinement::Params(vec![0, 1, 4, 5, 6, 7, 8])
        );
        // A guessed camera has no distortion value yet: every term is free.
        let guess = Camera::simple_pinhole(640, 480, 600.0, 320.0, 240.0);
        assert_eq!(refined_intrinsics(&guess, RefinedIntrinsics::Calibration), IntrinsicsRefinement::Params(vec![0]));
        let radial = Camera {
            model: CameraModelId::SimpleRadial,
            width: 640,
            height: 480,
            params: vec![600.0, 320.0, 240.0, 0.0],
        };
        assert_eq!(
            refined_intrinsics(&radial, RefinedIntrinsics::Calibration),
            IntrinsicsRefinement::Params(vec![0, 3])
        );
        // The principal point joins them, in parameter order.
        assert_eq!(
            refined_intrinsics(&radial, RefinedIntrinsics::WithPrincipalPoint),
            IntrinsicsRefinement::Params(vec![0, 1, 2, 3])
        );
        assert_eq!(
            refined_intrinsics(&tum, RefinedIntrinsics::WithPrincipalPoint),
            IntrinsicsRefinement::Params(vec![0, 1, 2, 3, 4, 5, 6, 7, 8])
        );
        // A term just added at 0 is refined with the others.
        let two = radial.with_second_radial_term();
        assert_eq!(
            refined_intrinsics(&two, RefinedIntrinsics::Calibration),
            IntrinsicsRefinement::Params(vec![0, 3, 4])
        );
        let two = Camera { params: vec![600.0, 320.0, 240.0, 0.05, 0.0], ..two };
        assert_eq!(refined_intrinsics(&two, RefinedIntrinsics::Calibration), IntrinsicsRefinement::Params(vec![0, 3]));
        assert_eq!(refined_intrinsics(&two, RefinedIntrinsics::EveryTerm), IntrinsicsRefinement::Params(vec![0, 3, 4]));
    }
}

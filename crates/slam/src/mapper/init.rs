//! The initial pair (paper 3.3): COLMAP's `FindInitialImagePair` and
//! `RegisterInitialImagePair`, adapted to a window of video frames.

use super::state::{Keyframe, Mapper};
use crate::frame::FrameData;
use crate::options::{GlobalBaTolerance, INIT_TWO_VIEW_TRIALS, SlamOptions, VERIFY_MAX_ERROR_PX, ransac_options};
use crate::timing::{Stage, StageTimings};
use colslam_camera::Camera;
use colslam_estimators::{
    RansacOptions, RecoveredPose, TwoViewConfig, TwoViewGeometry, TwoViewGeometryOptions, essential_from_pose,
    estimate_two_view_geometry, homography_poses, median_tri_angle_deg, sampson_error_sq,
};
use colslam_features::Match;
use colslam_geometry::{Rigid3, Vec2};
use colslam_sfm::SfmError;
use colslam_sfm::triangulator::triangulate_image;
use std::collections::HashMap;

/// Matches between frames of the initialisation window, by window indices
/// `(i, j)` with `i < j` (query = `i`).
pub type PairMatches = HashMap<(usize, usize), Vec<Match>>;

/// A new map and the window indices of its initial pair (earlier first).
pub type Initialized = (Mapper, usize, usize);

/// The matched keypoints' normalised coordinates in `a` and `b`, pair by
/// pair; `None` when a match names a keypoint the frames lack.
fn matched_normalized(a: &FrameData, b: &FrameData, matches: &[Match]) -> Option<(Vec<Vec2>, Vec<Vec2>)> {
    matches
        .iter()
        .map(|m| Some((*a.normalized.get(m.query as usize)?, *b.normalized.get(m.train as usize)?)))
        .collect::<Option<Vec<(Vec2, Vec2)>>>()
        .map(|pairs| pairs.into_iter().unzip())
}

/// Two-view geometry between two frames' matched keypoints (`query` side
/// first), with at most `max_trials` RANSAC trials per model.
pub fn two_view(
    a: &FrameData,
    b: &FrameData,
    matches: &[Match],
    focal: f64,
    seed: u64,
    max_trials: usize,
) -> Option<TwoViewGeometry> {
    let (x1, x2) = matched_normalized(a, b, matches)?;
    let opts = TwoViewGeometryOptions {
        ransac: RansacOptions { confidence: 0.999, max_trials, ..ransac_options(VERIFY_MAX_ERROR_PX / focal, seed) },
        ..TwoViewGeometryOptions::default()
    };
    estimate_two_view_geometry(&x1, &x2, &opts).ok()
}

/// A rival decomposition of a planar pair's homography is plausible when it
/// keeps at least this share of the best one's points in front of both
/// cameras (ORB-SLAM's `ReconstructH` asks the second best for less than
/// 0.75 of the best).
const PLANAR_AMBIGUITY_RATIO: f64 = 0.75;

/// Decompositions whose translations differ by less than this (degrees) are
/// the same solution, not rivals.
const PLANAR_RIVAL_MIN_ANGLE_DEG: f64 = 10.0;

/// How a planar pair's pose stands against its homography's other
/// decompositions.
#[derive(Debug, Clone, PartialEq)]
enum PlanarPose {
    /// No plausible rival, or the best supported by the matches off the plane.
    Clear,
    /// The rival, which the matches off the plane support better, with its
    /// median triangulation angle (degrees).
    Rival(Rigid3, f64),
    /// The two explain the matches equally well.
    Ambiguous,
}

/// Which decomposition of a planar pair's homography to trust. Moving
/// towards a plane (forward motion over a floor, along a wall) makes the
/// swapped decomposition (translation along the plane's normal) keep as
/// many points in front of both cameras as the true one, often more, with
/// a much larger, wrong triangulation angle. Only the matches off the plane
/// tell them apart: they satisfy the true pose's epipolar geometry, not the
/// swapped one's; so the rival is taken when more of all the pair's matches
/// lie within the verification threshold of its epipolar geometry, and the
/// pair is ambiguous on a tie.
fn planar_pose(tvg: &TwoViewGeometry, a: &FrameData, b: &FrameData, matches: &[Match], focal: f64) -> PlanarPose {
    let Some(h) = tvg.homography else { return PlanarPose::Clear };
    let Some((n1, n2)) = matched_normalized(a, b, matches) else { return PlanarPose::Clear };
    let all: Vec<(Vec2, Vec2)> = n1.into_iter().zip(n2).collect();
    let (x1, x2): (Vec<Vec2>, Vec<Vec2>) =
        all.iter().zip(&tvg.inlier_mask).filter(|(_, k)| **k).map(|(x, _)| *x).unzip();
    let Ok(mut poses) = homography_poses(&h, &x1, &x2) else { return PlanarPose::Clear };
    poses.sort_by_key(|p| std::cmp::Reverse(p.num_valid));
    let Some((best, rest)) = poses.split_first() else { return PlanarPose::Clear };
    let t0 = best.cam2_from_cam1.translation;
    let Some(rival) = rest.iter().find(|p| {
        let t = p.cam2_from_cam1.translation;
        let cos = (t.dot(&t0) / (t.norm() * t0.norm())).clamp(-1.0, 1.0);
        let distinct = !cos.is_finite() || cos.acos().to_degrees() >= PLANAR_RIVAL_MIN_ANGLE_DEG;
        distinct && p.num_valid as f64 >= PLANAR_AMBIGUITY_RATIO * best.num_valid as f64
    }) else {
        return PlanarPose::Clear;
    };
    let max = (VERIFY_MAX_ERROR_PX / focal).powi(2);
    let support = |p: &RecoveredPose| {
        let e = essential_from_pose(&p.cam2_from_cam1);
        all.iter().filter(|(x1, x2)| sampson_error_sq(&e, x1, x2) <= max).count()
    };
    let (sb, sr) = (support(best), support(rival));
    tracing::debug!(
        "planar pair {} / {}: best in front {} epipolar {}, rival in front {} epipolar {} (of {} matches)",
        a.index(),
        b.index(),
        best.num_valid,
        sb,
        rival.num_valid,
        sr,
        all.len()
    );
    match sr.cmp(&sb) {
        std::cmp::Ordering::Less => PlanarPose::Clear,
        std::cmp::Ordering::Equal => PlanarPose::Ambiguous,
        std::cmp::Ordering::Greater => match median_tri_angle_deg(rival) {
            Some(angle) => PlanarPose::Rival(rival.cam2_from_cam1, angle),
            None => PlanarPose::Ambiguous,
        },
    }
}

/// Matches of the pair `(i, j)` in either order.
fn count(pair_matches: &PairMatches, i: usize, j: usize) -> usize {
    let key = if i < j { (i, j) } else { (j, i) };
    pair_matches.get(&key).map_or(0, Vec::len)
}

/// First-image candidates: window indices by total matches to the others,
/// most first (ties: earlier first).
pub(crate) fn first_candidates(n: usize, pair_matches: &PairMatches) -> Vec<usize> {
    let mut firsts: Vec<(usize, usize)> =
        (0..n).map(|i| (i, (0..n).filter(|&j| j != i).map(|j| count(pair_matches, i, j)).sum())).collect();
    firsts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    firsts.into_iter().map(|(i, _)| i).collect()
}

/// Second-image candidates for `first`: the frames matched at least
/// `min_inliers` times, farthest in time first (ties: earlier first).
///
/// Video: the frames with the most matches are the nearest, with the least
/// parallax; among those matched well enough every one is tried, farthest
/// first: in a photo sequence with wide baselines the far frames share no
/// view, and raw match counts (which the ratio test leaves high among
/// thousands of keypoints) do not tell.
pub(crate) fn second_candidates(n: usize, first: usize, pair_matches: &PairMatches, min_inliers: usize) -> Vec<usize> {
    let mut seconds: Vec<usize> =
        (0..n).filter(|&j| j != first && count(pair_matches, first, j) >= min_inliers).collect();
    seconds.sort_by(|&a, &b| b.abs_diff(first).cmp(&a.abs_diff(first)).then(a.cmp(&b)));
    seconds
}

/// The verified relative pose and inlier matches of a candidate pair, when
/// its geometry allows an initialisation: enough inliers, motion that is
/// neither planar-only nor pure rotation, and a median triangulation angle
/// of at least `init_min_tri_angle`. With `init_resolve_planar` a planar
/// pair takes the decomposition its matches off the plane support
/// ([`planar_pose`]) and is refused when they cannot tell.
fn verified_pair(
    a: &FrameData,
    b: &FrameData,
    matches: &[Match],
    focal: f64,
    opts: &SlamOptions,
) -> Option<(Rigid3, Vec<Match>, f64, bool)> {
    let tvg = two_view(a, b, matches, focal, opts.seed, INIT_TWO_VIEW_TRIALS)?;
    tracing::trace!(
        "init candidate {} / {}: {:?}, {} inliers of {}, median angle {:?}",
        a.index(),
        b.index(),
        tvg.config,
        tvg.num_inliers,
        matches.len(),
        tvg.median_tri_angle_deg
    );
    let motion_ok = matches!(tvg.config, TwoViewConfig::Calibrated | TwoViewConfig::Planar);
    if !motion_ok || tvg.num_inliers < opts.init.init_min_inliers {
        return None;
    }
    let (mut rel, mut angle) = (tvg.cam2_from_cam1?, tvg.median_tri_angle_deg?);
    if opts.init.init_resolve_planar && tvg.config == TwoViewConfig::Planar {
        match planar_pose(&tvg, a, b, matches, focal) {
            PlanarPose::Clear => {}
            PlanarPose::Rival(r, a) => (rel, angle) = (r, a),
            PlanarPose::Ambiguous => return None,
        }
    }
    // A pair seen from directions far apart shares few reliable matches
    // (binary descriptors are not invariant to strong perspective change):
    // its few points would carry the whole map's start
    // (`--init-max-tri-angle`).
    if angle < opts.init.init_min_tri_angle || angle > opts.init.init_max_tri_angle {
        return None;
    }
    let inliers = matches.iter().zip(&tvg.inlier_mask).filter(|(_, k)| **k).map(|(m, _)| *m).collect();
    Some((rel, inliers, angle, tvg.config == TwoViewConfig::Planar))
}

impl Mapper {
    /// Tries to start a map from the initialisation window (paper 3.3): the
    /// first image has the most correspondences to the others, the second
    /// has many correspondences to it and enough motion; triangulate, global
    /// refinement; if too few points survive, the next candidate pair is
    /// tried. Returns the map and the window indices of its two images.
    /// `support`: registered images of the map `camera`'s focal length was
    /// settled in (0 for a guess or a calibration; [`Mapper::constrains_focal`]).
    pub fn initialize(
        index: usize,
        window: &[FrameData],
        pair_matches: &PairMatches,
        (camera, support): (&Camera, usize),
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Option<Initialized>, SfmError> {
        let n = window.len();
        let focal = camera.mean_focal();
        // COLMAP tries several first images; two are enough to leave a
        // clearly bad window quickly.
        for first in first_candidates(n, pair_matches).into_iter().take(2) {
            for second in second_candidates(n, first, pair_matches, opts.init.init_min_inliers) {
                let (i, j) = if first < second { (first, second) } else { (second, first) };
                let Some(matches) = pair_matches.get(&(i, j)) else { continue };
                let Some((rel, inliers, angle, planar)) = verified_pair(&window[i], &window[j], matches, focal, opts)
                else {
                    continue;
                };
                let pair = (&window[i], &window[j]);
                let map = Self::from_pair(index, pair, &inliers, (rel, planar), (camera, support), opts, timings)?;
                let points = map.rec.num_points3d();
                let (a, b) = (window[i].index(), window[j].index());
                if points >= opts.init.init_min_points {
                    tracing::info!(
                        "map {index} initialised from frames {a} and {b}: {points} points, median angle {angle:.2} deg"
                    );
                    return Ok(Some((map, i, j)));
                }
                tracing::debug!("initial pair {a} / {b} kept only {points} points");
            }
        }
        Ok(None)
    }

    /// A map of two keyframes: `pair.0` at the origin, `pair.1` at
    /// `b_from_a`, their inlier matches triangulated and refined globally;
    /// `planar`: the pose came from the pair's homography.
    fn from_pair(
        index: usize,
        pair: (&FrameData, &FrameData),
        inliers: &[Match],
        (b_from_a, planar): (Rigid3, bool),
        (camera, support): (&Camera, usize),
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Mapper, SfmError> {
        let mut map = Mapper::empty(index, camera);
        let ids = [
            map.add_keyframe_image(pair.0, Rigid3::identity(), opts)?,
            map.add_keyframe_image(pair.1, b_from_a, opts)?,
        ];
        let pairs: Vec<(u32, u32)> = inliers.iter().map(|m| (m.query, m.train)).collect();
        map.graph.add_correspondences(ids[0], ids[1], &pairs)?;
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || triangulate_image(&mut map.rec, &map.graph, ids[0], &tri))?;
        map.keyframes = vec![
            Keyframe { image_id: ids[0], data: pair.0.clone(), version: 0 },
            Keyframe { image_id: ids[1], data: pair.1.clone(), version: 0 },
        ];
        map.initial_frames = (pair.0.index(), pair.1.index());
        map.planar_start = planar;
        map.camera_support = support;
        map.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        Ok(map)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::tests::frame_data;
    use crate::options::InitOptions;
    use colslam_geometry::{SplitMix64, Vec3};

    /// Two frames seeing `points` (camera-1 coordinates) from camera 1 and
    /// from `cam2_from_cam1`, with `noise_px` pixels of noise at a focal
    /// length of 300, and their identity matches.
    fn pair(points: &[Vec3], cam2_from_cam1: &Rigid3, noise_px: f64, seed: u64) -> (FrameData, FrameData, Vec<Match>) {
        let mut rng = SplitMix64::new(seed);
        let mut noisy =
            |p: Vec3| Vec2::new(p.x / p.z, p.y / p.z) + Vec2::new(rng.normal(), rng.normal()) * (noise_px / 300.0);
        let x1 = points.iter().map(|p| noisy(*p)).collect();
        let x2 = points.iter().map(|p| noisy(cam2_from_cam1.transform_point(p))).collect();
        (frame_data(0, x1), frame_data(3, x2), matches(points.len()))
    }

    /// Points on a plane in front of camera 1: `height` below it (a floor,
    /// y down) when `wall` is false, else a wall `height` ahead.
    fn plane(n: usize, height: f64, wall: bool, seed: u64) -> Vec<Vec3> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|_| {
                let (a, b) = (rng.uniform(-4.0, 4.0), rng.uniform(4.0, 14.0));
                if wall { Vec3::new(a, b - 9.0, height) } else { Vec3::new(a, height, b) }
            })
            .collect()
    }

    /// Degrees between camera 2's centre (in camera 1) and the optical axis.
    fn off_axis_deg(cam2_from_cam1: &Rigid3) -> f64 {
        let c = cam2_from_cam1.inverse().translation;
        (c.z / c.norm()).clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// Forward motion (0.6 m ahead) over a floor 1.5 m below the camera.
    fn forward() -> Rigid3 {
        Rigid3::from_wxyz([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -0.6])
    }

    #[test]
    fn the_matches_off_the_floor_pick_the_forward_decomposition() {
        // A drive: mostly floor, some points above it (walls, boxes). The
        // homography's best-supported decomposition moves the camera down
        // onto the floor; the matches off the floor agree only with forward.
        let mut points = plane(150, 1.5, false, 1);
        let mut rng = SplitMix64::new(5);
        points
            .extend((0..25).map(|_| Vec3::new(rng.uniform(-4.0, 4.0), rng.uniform(-1.5, 1.0), rng.uniform(5.0, 14.0))));
        let (a, b, m) = pair(&points, &forward(), 0.3, 2);
        let tvg = two_view(&a, &b, &m, 300.0, 7, INIT_TWO_VIEW_TRIALS).unwrap();
        assert_eq!(tvg.config, TwoViewConfig::Planar);
        let mut opts = SlamOptions::default();
        opts.init.init_min_tri_angle = 0.5;
        let (off, _, off_angle, _) = verified_pair(&a, &b, &m, 300.0, &opts).expect("off: the homography's pose");
        assert!(off_axis_deg(&off) > 45.0, "off by default: the swapped pose, {} deg", off_axis_deg(&off));
        opts.init.init_resolve_planar = true;
        let (on, _, on_angle, _) = verified_pair(&a, &b, &m, 300.0, &opts).expect("resolved");
        assert!(off_axis_deg(&on) < 3.0, "{} deg off the axis", off_axis_deg(&on));
        assert!(on_angle < off_angle, "the true pose's angle {on_angle} is the smaller (swapped: {off_angle})");
    }

    #[test]
    fn a_flat_floor_alone_cannot_tell_and_is_not_an_initial_pair() {
        let (a, b, m) = pair(&plane(150, 1.5, false, 1), &forward(), 0.0, 2);
        let tvg = two_view(&a, &b, &m, 300.0, 7, INIT_TWO_VIEW_TRIALS).unwrap();
        assert_eq!(tvg.config, TwoViewConfig::Planar);
        assert_eq!(planar_pose(&tvg, &a, &b, &m, 300.0), PlanarPose::Ambiguous);
        let mut opts = SlamOptions {
            init: InitOptions { init_min_tri_angle: 0.5, ..InitOptions::default() },
            ..SlamOptions::default()
        };
        assert!(verified_pair(&a, &b, &m, 300.0, &opts).is_some(), "off by default");
        opts.init.init_resolve_planar = true;
        assert!(verified_pair(&a, &b, &m, 300.0, &opts).is_none());
    }

    #[test]
    fn a_pair_moving_along_a_wall_is_clear() {
        // Sideways motion in front of a wall: the swapped decomposition puts
        // most points behind a camera, so the pose is clear and the pair
        // still starts a map.
        let sideways = Rigid3::from_wxyz([1.0, 0.0, 0.0, 0.0], [-0.8, 0.0, 0.0]);
        let (a, b, m) = pair(&plane(150, 6.0, true, 3), &sideways, 0.3, 4);
        let tvg = two_view(&a, &b, &m, 300.0, 7, INIT_TWO_VIEW_TRIALS).unwrap();
        assert_eq!(tvg.config, TwoViewConfig::Planar);
        assert_eq!(planar_pose(&tvg, &a, &b, &m, 300.0), PlanarPose::Clear);
        let mut opts = SlamOptions::default();
        opts.init.init_resolve_planar = true;
        assert!(verified_pair(&a, &b, &m, 300.0, &opts).is_some());
    }

    fn matches(n: usize) -> Vec<Match> {
        (0..n as u32).map(|k| Match { query: k, train: k, distance: 0.0 }).collect()
    }

    #[test]
    fn first_image_has_the_most_matches_and_ties_go_to_the_earlier() {
        let mut pm = PairMatches::new();
        pm.insert((0, 1), matches(10));
        pm.insert((1, 2), matches(30));
        pm.insert((0, 2), matches(5));
        // Totals: 0 -> 15, 1 -> 40, 2 -> 35.
        assert_eq!(first_candidates(3, &pm), vec![1, 2, 0]);
        let mut tie = PairMatches::new();
        tie.insert((0, 1), matches(10));
        assert_eq!(first_candidates(3, &tie), vec![0, 1, 2]);
    }

    #[test]
    fn second_images_are_the_well_matched_ones_farthest_first() {
        let mut pm = PairMatches::new();
        for j in 1..6 {
            pm.insert((0, j), matches(if j == 3 { 50 } else { 120 }));
        }
        pm.insert((2, 4), matches(500));
        // Frame 3 has too few matches to frame 0; the others come farthest first.
        assert_eq!(second_candidates(6, 0, &pm, 100), vec![5, 4, 2, 1]);
        // Around a middle frame, equal distances go to the earlier.
        let mut mid = PairMatches::new();
        for j in [0, 1, 3, 4] {
            let key = if j < 2 { (j, 2) } else { (2, j) };
            mid.insert(key, matches(100));
        }
        assert_eq!(second_candidates(5, 2, &mid, 100), vec![0, 4, 1, 3]);
    }
}

//! The bundle-adjustment wrappers: the local-bundle choice, what local and
//! global adjustment may move, and convergence back to an exact map.

mod common;

use colslam_geometry::{Rigid3, Vec3};
use colslam_optim::Termination;
use colslam_scene::{CameraId, ImageId, Point3DId, Reconstruction};
use colslam_sfm::SfmError;
use colslam_sfm::bundle::{
    BundleConfig, BundleOptions, adjust_bundle, adjust_global, adjust_global_long_tracks, adjust_local,
    most_connected_images,
};
use common::{Scene, img, look_at, perturb_pose, point_offset};
use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;

fn ids(v: &[u32]) -> Vec<ImageId> {
    v.iter().map(|&i| img(i)).collect()
}

fn pose(s: &Scene, i: u32) -> Rigid3 {
    s.rec.image(img(i)).unwrap().cam_from_world
}

/// Distance between the centres of image `i`'s current and true poses.
fn centre_error(s: &Scene, i: u32) -> f64 {
    (pose(s, i).center() - s.poses[i as usize - 1].center()).norm()
}

/// Moves image `i` by a small rigid motion.
fn perturb_image(s: &mut Scene, i: u32, angle_deg: f64, shift: f64) {
    let p = perturb_pose(&pose(s, i), angle_deg, shift);
    s.rec.set_cam_from_world(img(i), p).unwrap();
}

/// Moves every listed point by about `scale`.
fn perturb_points(s: &mut Scene, points: &[Point3DId], scale: f64) {
    for (k, pid) in points.iter().enumerate() {
        *s.rec.point3d_xyz_mut(*pid).unwrap() += point_offset(k, scale);
    }
}

/// A scene whose every point is observed by every image.
fn full_tracks(s: &mut Scene) -> Vec<Point3DId> {
    let all: Vec<u32> = (1..=s.poses.len() as u32).collect();
    (0..s.n()).map(|k| s.add_true_point(k, &all)).collect()
}

/// `n_images` on a line, each seeing all `n_points`, with the images `moved`
/// perturbed by `angle_deg` and `shift`; returns the points too.
fn perturbed_line(
    n_images: usize,
    n_points: usize,
    moved: &[u32],
    angle_deg: f64,
    shift: f64,
) -> (Scene, Vec<Point3DId>) {
    let mut s = Scene::line(n_images, n_points);
    let points = full_tracks(&mut s);
    for &i in moved {
        perturb_image(&mut s, i, angle_deg, shift);
    }
    (s, points)
}

// ----- local bundle choice ---------------------------------------------------

/// Image 1 shares 5 points with image 2, 3 with images 3 and 4, 1 with
/// image 5; points 9 and 10 do not involve image 1.
fn shared_points() -> Scene {
    let mut s = Scene::line(6, 11);
    let tracks: [&[u32]; 11] =
        [&[1, 2], &[1, 2], &[1, 2], &[1, 2], &[1, 2], &[1, 3, 4], &[1, 3, 4], &[1, 4, 3], &[1, 5], &[2, 3], &[5, 6]];
    for (k, t) in tracks.iter().enumerate() {
        s.add_true_point(k as u32, t);
    }
    s
}

#[test]
fn most_connected_images_rank_by_shared_points() {
    let s = shared_points();
    assert_eq!(most_connected_images(&s.rec, img(1), 10), ids(&[2, 3, 4, 5]));
    assert_eq!(most_connected_images(&s.rec, img(3), 10), ids(&[1, 4, 2]));
    assert_eq!(most_connected_images(&s.rec, img(5), 10), ids(&[1, 6]));
    // The image itself never appears; an image without points has no bundle.
    assert!(!most_connected_images(&s.rec, img(2), 10).contains(&img(2)));
    let mut lonely = Scene::line(2, 3);
    lonely.add_true_point(0, &[1, 2]);
    assert_eq!(most_connected_images(&lonely.rec, img(2), 10), ids(&[1]));
    assert!(most_connected_images(&s.rec, img(42), 10).is_empty());
}

#[test]
fn most_connected_images_respect_the_count() {
    let s = shared_points();
    assert!(most_connected_images(&s.rec, img(1), 0).is_empty());
    assert_eq!(most_connected_images(&s.rec, img(1), 1), ids(&[2]));
    // Images 3 and 4 tie: the smaller id comes first.
    assert_eq!(most_connected_images(&s.rec, img(1), 2), ids(&[2, 3]));
    assert_eq!(most_connected_images(&s.rec, img(1), 3), ids(&[2, 3, 4]));
}

#[test]
fn most_connected_images_break_ties_by_id() {
    let mut s = Scene::line(5, 6);
    full_tracks(&mut s);
    assert_eq!(most_connected_images(&s.rec, img(3), 2), ids(&[1, 2]));
    assert_eq!(most_connected_images(&s.rec, img(1), 4), ids(&[2, 3, 4, 5]));
    // The ranking does not depend on the order tracks were built in.
    let mut t = Scene::line(5, 6);
    for k in 0..6 {
        t.add_true_point(k, &[5, 4, 3, 2, 1]);
    }
    for i in 1..=5 {
        assert_eq!(most_connected_images(&t.rec, img(i), 4), most_connected_images(&s.rec, img(i), 4));
    }
}

// ----- local adjustment --------------------------------------------------------

#[test]
fn adjust_local_moves_only_the_neighbourhood() {
    // Points 0-9 seen by images 1-3, points 10-19 by images 2-6, points
    // 20-29 by images 4-6. Around image 6 the two most connected images are
    // 4 and 5 (20 shared points each); images 2 and 3 observe bundle points
    // and are held constant; image 1 and points 0-9 are outside.
    let mut s = Scene::line(6, 30);
    let mut points = Vec::new();
    for k in 0..30 {
        let track: &[u32] = match k {
            0..10 => &[1, 2, 3],
            10..20 => &[2, 3, 4, 5, 6],
            _ => &[4, 5, 6],
        };
        points.push(s.add_true_point(k, track));
    }
    assert_eq!(most_connected_images(&s.rec, img(6), 2), ids(&[4, 5]));
    for i in 4..=6 {
        perturb_image(&mut s, i, 0.3, 0.02);
    }
    perturb_points(&mut s, &points[10..], 0.02);
    let before = s.rec.clone();
    let report = adjust_local(&mut s.rec, img(6), 3, false, &BundleOptions::local()).unwrap();
    assert_eq!(report.num_variable_poses, 3);
    assert_eq!(report.num_variable_points, 20);
    for i in 1..=3 {
        assert_eq!(pose(&s, i), before.image(img(i)).unwrap().cam_from_world, "image {i} moved");
    }
    for pid in &points[..10] {
        assert_eq!(s.rec.point3d(*pid).unwrap().xyz, before.point3d(*pid).unwrap().xyz);
    }
    assert_eq!(s.rec.camera(CameraId(1)), before.camera(CameraId(1)));
    // Images 2 and 3 fix the gauge: the neighbourhood returns to the truth.
    for i in 4..=6 {
        assert!(centre_error(&s, i) < 1e-6, "image {i} off by {}", centre_error(&s, i));
    }
    for pid in &points[10..] {
        assert!(s.truth_error(*pid) < 1e-6);
    }
    assert!(s.max_reprojection_error() < 1e-4);
}

#[test]
fn adjust_local_on_a_young_map_fixes_the_gauge_with_its_least_connected_image() {
    // Three images seeing every point: the bundle around image 3 is all of
    // them, no image outside it is constant, so the last of the ranking
    // (image 2) is held fixed and image 1 loses one translation coordinate.
    let (mut s, _) = perturbed_line(3, 12, &[3], 0.5, 0.03);
    let fixed = pose(&s, 2);
    let report = adjust_local(&mut s.rec, img(3), 3, false, &BundleOptions::local()).unwrap();
    assert!(report.final_cost < 1e-6 * report.initial_cost);
    assert_eq!(pose(&s, 2), fixed);
    assert!(centre_error(&s, 3) < 1e-6);
    assert!(s.max_reprojection_error() < 1e-4);
}

// ----- global adjustment -------------------------------------------------------

#[test]
fn adjust_global_returns_a_perturbed_map_to_the_exact_one() {
    let (mut s, points) = perturbed_line(5, 25, &[3, 4, 5], 0.4, 0.03);
    perturb_points(&mut s, &points, 0.03);
    assert!(s.max_reprojection_error() > 1.0);
    let first = pose(&s, 1);
    let report = adjust_global(&mut s.rec, false, &BundleOptions::global()).unwrap();
    assert!(report.final_cost < 1e-10 * report.initial_cost, "{report:?}");
    assert_eq!(report.num_variable_points, 25);
    // Image 1 fixes the gauge; one coordinate of image 2 fixes the scale.
    assert_eq!(pose(&s, 1), first);
    for i in 2..=5 {
        assert!(centre_error(&s, i) < 1e-6, "image {i} off by {}", centre_error(&s, i));
    }
    for pid in &points {
        assert!(s.truth_error(*pid) < 1e-6);
    }
    assert!(s.max_reprojection_error() < 1e-6);
}

/// Five cameras around the box at different heights and distances (varied
/// rotations make the focal length observable), every point seen by all.
fn orbit_scene() -> Scene {
    let target = Vec3::new(0.5, 0.0, 6.0);
    let centres = [
        Vec3::new(-2.0, -0.5, 1.0),
        Vec3::new(0.0, 0.5, 0.0),
        Vec3::new(2.0, -0.3, 1.0),
        Vec3::new(3.0, 0.8, 3.0),
        Vec3::new(-1.5, 1.0, 3.0),
    ];
    let mut s = Scene::new(centres.iter().map(|c| look_at(*c, target)).collect(), common::box_points(30, 17));
    full_tracks(&mut s);
    s
}

#[test]
fn adjust_global_keeps_intrinsics_fixed_unless_refinement_is_asked() {
    let mut s = orbit_scene();
    s.rec.camera_mut(CameraId(1)).unwrap().params[..2].copy_from_slice(&[510.0, 510.0]);
    let start = s.rec.clone();
    adjust_global(&mut s.rec, false, &BundleOptions::global()).unwrap();
    assert_eq!(s.rec.camera(CameraId(1)).unwrap().camera.params, [510.0, 510.0, 320.0, 240.0]);
    // A wrong focal length cannot be absorbed by poses and points.
    assert!(s.max_reprojection_error() > 1e-3);

    s.rec = start;
    adjust_global(&mut s.rec, true, &BundleOptions::global()).unwrap();
    let params = &s.rec.camera(CameraId(1)).unwrap().camera.params;
    assert!((params[0] - 500.0).abs() < 1e-4 && (params[1] - 500.0).abs() < 1e-4, "{params:?}");
    // The principal point stays fixed, as in COLMAP.
    assert_eq!(params[2..], [320.0, 240.0]);
    assert!(s.max_reprojection_error() < 1e-4);
}

#[test]
fn constant_images_override_variable_ones() {
    let (mut s, _) = perturbed_line(4, 12, &[2, 3], 0.3, 0.02);
    let before = s.rec.clone();
    let config = BundleConfig {
        variable_images: [img(2), img(3)].into_iter().collect(),
        constant_images: [img(3)].into_iter().collect(),
        ..BundleConfig::default()
    };
    let report = adjust_bundle(&mut s.rec, &config, &BundleOptions::global()).unwrap();
    assert_eq!(report.num_variable_poses, 1);
    for i in [1, 3, 4] {
        assert_eq!(pose(&s, i), before.image(img(i)).unwrap().cam_from_world, "image {i} moved");
    }
    assert_ne!(pose(&s, 2), before.image(img(2)).unwrap().cam_from_world);
    // An unknown image is a typed error.
    let bad = BundleConfig { variable_images: BTreeSet::from([img(99)]), ..BundleConfig::default() };
    assert!(matches!(
        adjust_bundle(&mut s.rec, &bad, &BundleOptions::global()),
        Err(SfmError::UnknownImage(ImageId(99)))
    ));
}

#[test]
fn keypoint_sigmas_weigh_down_an_imprecise_observation() {
    // Keypoint 0 of image 4 is 20 px off. Unweighted, global BA spreads its
    // error over the map; with a huge sigma on it the others stay exact.
    let mut s = Scene::line(4, 20);
    full_tracks(&mut s);
    s.shift_keypoint(4, 0, 20.0, 0.0);
    let start = s.rec.clone();
    let others_error = |rec: &Reconstruction| {
        let mut worst: f64 = 0.0;
        for (_, p) in rec.points3d() {
            for el in p.track.iter().filter(|e| (e.image_id, e.point2d_idx) != (img(4), 0)) {
                let image = rec.image(el.image_id).unwrap();
                let px = common::pixel(&image.cam_from_world, &p.xyz);
                worst = worst.max((px - image.points2d[el.point2d_idx as usize].xy).norm());
            }
        }
        worst
    };
    adjust_global(&mut s.rec, false, &BundleOptions::global()).unwrap();
    assert!(others_error(&s.rec) > 1e-2);
    // Only keypoint 0 of image 4 has a sigma; missing entries weigh 1.
    let sigmas = Arc::new(HashMap::from([(img(4), vec![1e5_f32])]));
    let weighted = BundleOptions { keypoint_sigmas: Some(sigmas), ..BundleOptions::global() };
    s.rec = start;
    adjust_global(&mut s.rec, false, &weighted).unwrap();
    assert!(others_error(&s.rec) < 1e-3, "{}", others_error(&s.rec));
}

/// Four images on a line: points 0-39 seen by all, points 40-99 by pairs
/// of consecutive images with the second image's keypoint 1.5 px off (a
/// two-view track checks it only along the epipolar line); image 5 sees
/// only two-view points shared with image 4. Images 3-5 start perturbed.
fn biased_two_view_scene() -> Scene {
    let mut s = Scene::line(5, 100);
    for k in 0..40 {
        s.add_true_point(k, &[1, 2, 3, 4]);
    }
    for k in 40..100 {
        let a = 1 + (k - 40) % 4;
        s.add_true_point(k, &[a, a + 1]);
        s.shift_keypoint(a + 1, k, 1.5, 1.0);
    }
    for i in 3..=5 {
        perturb_image(&mut s, i, 0.3, 0.02);
    }
    s
}

#[test]
fn two_view_tracks_stay_out_of_the_pose_estimate_of_long_tracks() {
    let mut s = biased_two_view_scene();
    let start = s.rec.clone();
    adjust_global(&mut s.rec, false, &BundleOptions::global()).unwrap();
    // Every track moves the poses: the biased two-view ones bend them.
    let bent: f64 = (2..=4).map(|i| centre_error(&s, i)).fold(0.0, f64::max);
    assert!(bent > 1e-3, "{bent}");

    s.rec = start.clone();
    let report = adjust_global_long_tracks(&mut s.rec, false, &BundleOptions::global(), 3, 30).unwrap();
    // Only the 40 long tracks and image 5's 15 two-view points (it has no
    // long track, so it keeps its short ones) move the poses.
    assert_eq!(report.num_variable_points, 55);
    for i in 2..=4 {
        assert!(centre_error(&s, i) < 1e-6, "image {i} off by {}", centre_error(&s, i));
    }
    assert!(centre_error(&s, 5) < 0.05, "image 5 off by {}", centre_error(&s, 5));
    assert!(centre_error(&s, 5) < start_error(&start, &s, 5), "image 5 was not adjusted");
    // The short tracks were adjusted to the final poses: each lands between
    // its two keypoints, about half the 1.8 px offset from each.
    for k in 40..100 {
        let pid = s.point_of(1 + (k - 40) % 4, k).unwrap();
        let xyz = s.rec.point3d(pid).unwrap().xyz;
        for el in &s.rec.point3d(pid).unwrap().track {
            let image = s.rec.image(el.image_id).unwrap();
            let off = (common::pixel(&image.cam_from_world, &xyz) - image.points2d[k as usize].xy).norm();
            assert!(off < 1.5, "point {k} in image {}: {off} px", el.image_id.0);
        }
    }

    // min_track 2 keeps every track: the plain global adjustment.
    let mut plain = start.clone();
    adjust_global(&mut plain, false, &BundleOptions::global()).unwrap();
    s.rec = start;
    adjust_global_long_tracks(&mut s.rec, false, &BundleOptions::global(), 2, 30).unwrap();
    assert_eq!(s.rec, plain);
}

/// Centre error of image `i` in `start`, against the truth of `s`.
fn start_error(start: &Reconstruction, s: &Scene, i: u32) -> f64 {
    (start.image(img(i)).unwrap().cam_from_world.center() - s.poses[i as usize - 1].center()).norm()
}

#[test]
fn adjust_global_without_points_changes_nothing() {
    let mut empty = Reconstruction::new();
    let report = adjust_global(&mut empty, false, &BundleOptions::global()).unwrap();
    assert_eq!(report.termination, Termination::NothingToOptimize);
    let mut s = Scene::line(3, 4);
    let before = s.rec.clone();
    let report = adjust_global(&mut s.rec, true, &BundleOptions::global()).unwrap();
    assert_eq!(report.termination, Termination::NothingToOptimize);
    assert_eq!(s.rec, before);
}

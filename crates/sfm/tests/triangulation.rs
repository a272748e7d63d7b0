//! The incremental triangulator on exact synthetic scenes (after COLMAP's
//! `incremental_triangulator_test.cc`): create, continue, merge, complete,
//! retriangulate, and the thresholds that refuse bad geometry.

mod common;

use colslam_geometry::Vec3;
use colslam_scene::Point3DId;
use colslam_sfm::triangulator::{
    complete_and_merge_all, complete_and_merge_image, complete_tracks, merge_tracks, retriangulate, triangulate_image,
};
use colslam_sfm::{SfmError, TriangulationReport, TriangulatorOptions};
use common::{Scene, box_points, img, look_at};

fn opts() -> TriangulatorOptions {
    TriangulatorOptions::default()
}

fn report(created: usize, continued: usize, merged: usize) -> TriangulationReport {
    TriangulationReport { created, continued, merged }
}

/// Scene with images 1..=`n_images` on a line; images 1 and 2 triangulated
/// (two-view tracks of every keypoint), the others registered but without
/// observations; consecutive images matched.
fn two_view_map(n_images: usize, n_points: usize) -> Scene {
    let mut s = Scene::line(n_images, n_points);
    s.match_chain();
    for i in 3..=n_images as u32 {
        s.unregister(i);
    }
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap().created, n_points);
    for i in 3..=n_images as u32 {
        s.rec.register_image(img(i)).unwrap();
    }
    s
}

// ----- create --------------------------------------------------------------

#[test]
fn create_from_a_registered_pair_is_exact() {
    let mut s = Scene::line(2, 12);
    s.match_pair(1, 2);
    let r = triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(r, report(12, 0, 0));
    assert_eq!(r.total(), 12);
    assert_eq!(s.rec.num_points3d(), 12);
    for k in 0..12 {
        let pid = s.point_of(1, k).expect("keypoint triangulated");
        assert_eq!(s.point_of(2, k), Some(pid));
        assert_eq!(s.track_images(pid), [1, 2]);
        let err = s.truth_error(pid);
        assert!(err < 1e-9, "point {k} off by {err}");
    }
    s.rec.check_consistency().unwrap();
    // Every keypoint of image 2 observes a point now: nothing left to do.
    let before = s.rec.clone();
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(2), &opts()).unwrap(), TriangulationReport::default());
    assert_eq!(s.rec, before);
}

#[test]
fn unregistered_images_take_no_part() {
    let mut s = Scene::line(3, 8);
    s.match_all();
    s.unregister(2);
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(2), &opts()).unwrap(), TriangulationReport::default());
    assert_eq!(s.rec.num_points3d(), 0);
    let r = triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(r, report(8, 0, 0));
    for k in 0..8 {
        assert_eq!(s.track_images(s.point_of(1, k).unwrap()), [1, 3]);
        assert_eq!(s.point_of(2, k), None);
    }
    assert!(matches!(triangulate_image(&mut s.rec, &s.graph, img(9), &opts()), Err(SfmError::UnknownImage(_))));
}

#[test]
fn create_refuses_a_pair_seen_from_nearly_the_same_centre() {
    // A 1 cm baseline at 5-7 m: triangulation angles of about 0.1 degrees.
    let target = Vec3::new(1.0, 0.0, 6.0);
    let poses = vec![look_at(Vec3::zeros(), target), look_at(Vec3::new(0.01, 0.0, 0.0), target)];
    let mut s = Scene::new(poses, box_points(6, 3));
    s.match_pair(1, 2);
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap(), TriangulationReport::default());
    assert_eq!(s.rec.num_points3d(), 0);
    // The same pair passes a minimum angle below its own.
    let low = TriangulatorOptions { min_angle_deg: 0.05, ..opts() };
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &low).unwrap().created, 6);
    for (pid, _) in s.rec.points3d() {
        assert!(s.truth_error(pid) < 1e-6);
    }
}

#[test]
fn create_refuses_a_point_behind_a_camera() {
    // Image 2 looks back across the scene; the last keypoint pair is
    // consistent only with a point in front of image 1 and behind image 2
    // (its image-2 keypoint is the mirrored projection).
    let target = Vec3::new(1.0, 0.0, 6.0);
    let poses = vec![look_at(Vec3::zeros(), target), look_at(Vec3::new(3.0, 0.0, 9.0), target)];
    let mut truth = box_points(6, 11);
    let behind = Vec3::new(2.5, 0.3, 11.0);
    assert!(poses[0].transform_point(&behind).z > 0.0 && poses[1].transform_point(&behind).z < 0.0);
    truth.push(behind);
    let mut s = Scene::new(poses, truth);
    s.match_pair(1, 2);
    let r = triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(r.created, 6);
    for k in 0..6 {
        assert!(s.truth_error(s.point_of(1, k).unwrap()) < 1e-9);
    }
    assert_eq!(s.point_of(1, 6), None);
    assert_eq!(s.point_of(2, 6), None);
    for (_, p) in s.rec.points3d() {
        assert!(
            s.rec.registered_image_ids().iter().all(|id| s
                .rec
                .image(*id)
                .unwrap()
                .cam_from_world
                .transform_point(&p.xyz)
                .z
                > 0.0)
        );
    }
}

#[test]
fn create_leaves_an_outlier_view_out_of_the_track() {
    // Keypoint 0 of image 3 is 60 px off (across the epipolar lines): the
    // point comes from images 1 and 2 only, still exact.
    let mut s = Scene::line(3, 8);
    s.match_all();
    s.shift_keypoint(3, 0, 0.0, 60.0);
    let r = triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(r, report(8, 0, 0));
    let p0 = s.point_of(1, 0).unwrap();
    assert_eq!(s.track_images(p0), [1, 2]);
    assert!(s.truth_error(p0) < 1e-9);
    assert_eq!(s.point_of(3, 0), None);
    for k in 1..8 {
        let pid = s.point_of(1, k).unwrap();
        assert_eq!(s.track_images(pid), [1, 2, 3]);
        assert!(s.truth_error(pid) < 1e-9);
    }
    s.rec.check_consistency().unwrap();
}

#[test]
fn create_max_angle_error_decides_whether_a_view_joins() {
    // A 10 px error is about 1 degree: within the default 2, beyond 0.25.
    let build = || {
        let mut s = Scene::line(3, 4);
        s.match_all();
        s.shift_keypoint(3, 0, 0.0, 10.0);
        s
    };
    let mut s = build();
    triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(s.track_images(s.point_of(1, 0).unwrap()), [1, 2, 3]);
    let mut s = build();
    let strict = TriangulatorOptions { create_max_angle_error_deg: 0.25, ..opts() };
    triangulate_image(&mut s.rec, &s.graph, img(1), &strict).unwrap();
    let p0 = s.point_of(1, 0).unwrap();
    assert_eq!(s.track_images(p0), [1, 2]);
    assert!(s.truth_error(p0) < 1e-9);
    // The exact keypoints still form three-view tracks.
    assert_eq!(s.track_images(s.point_of(1, 1).unwrap()), [1, 2, 3]);
}

#[test]
fn two_view_tracks_are_skipped_only_when_asked() {
    let skip = TriangulatorOptions { ignore_two_view_tracks: true, ..opts() };
    let mut s = Scene::line(3, 5);
    s.match_pair(1, 2);
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &skip).unwrap().created, 0);
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap().created, 5);
    // Once image 2's keypoints are also matched to image 3 they are not
    // two-view observations any more.
    let mut s = Scene::line(3, 5);
    s.match_chain();
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(1), &skip).unwrap().created, 5);
}

#[test]
fn a_keypoint_with_many_free_views_keeps_its_own_observation() {
    // Image 14 matched to 13 registered images whose keypoints observe no
    // point yet: the point created for each of its keypoints must include it.
    let n_images = 14;
    let mut s = Scene::new(common::line_poses(n_images, 0.25), box_points(4, 5));
    for i in 1..n_images as u32 {
        s.match_pair(i, n_images as u32);
    }
    let r = triangulate_image(&mut s.rec, &s.graph, img(14), &opts()).unwrap();
    assert_eq!(r.created, 4);
    for k in 0..4 {
        let pid = s.point_of(14, k).expect("the new image observes the point it created");
        assert!(s.track_images(pid).len() >= 2);
        assert!(s.truth_error(pid) < 1e-9);
    }
    s.rec.check_consistency().unwrap();
}

// ----- continue ------------------------------------------------------------

#[test]
fn continue_extends_tracks_into_a_newly_registered_image() {
    let mut s = two_view_map(3, 10);
    let before: Vec<(Point3DId, Vec3)> = s.rec.points3d().map(|(id, p)| (id, p.xyz)).collect();
    let r = triangulate_image(&mut s.rec, &s.graph, img(3), &opts()).unwrap();
    assert_eq!(r, report(0, 10, 0));
    assert_eq!(s.rec.num_points3d(), 10);
    for (pid, xyz) in before {
        assert_eq!(s.track_images(pid), [1, 2, 3]);
        // Continuing adds an observation; it does not move the point.
        assert_eq!(s.rec.point3d(pid).unwrap().xyz, xyz);
    }
    assert_eq!(s.rec.num_observations(), 30);
    s.rec.check_consistency().unwrap();
}

#[test]
fn continue_refuses_keypoints_beyond_the_angular_threshold() {
    // 30 px is about 3 degrees, 10 px about 1 degree.
    let build = || {
        let mut s = two_view_map(3, 6);
        s.shift_keypoint(3, 0, 30.0, 0.0);
        s.shift_keypoint(3, 1, 0.0, 10.0);
        s
    };
    let mut s = build();
    let r = triangulate_image(&mut s.rec, &s.graph, img(3), &opts()).unwrap();
    assert_eq!(r, report(0, 5, 0));
    assert_eq!(s.point_of(3, 0), None);
    assert_eq!(s.point_of(3, 1), s.point_of(2, 1));
    let mut s = build();
    let strict = TriangulatorOptions { continue_max_angle_error_deg: 0.5, ..opts() };
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(3), &strict).unwrap(), report(0, 4, 0));
    assert_eq!(s.point_of(3, 0), None);
    assert_eq!(s.point_of(3, 1), None);
    assert!(s.point_of(3, 2).is_some());
}

// ----- merge -----------------------------------------------------------------

/// Four images, all matched; every keypoint observed by two points: one
/// with track {1, 2}, one with track {3, 4} (both at the true position
/// unless `offset` moves the second).
fn split_tracks(n_points: u32, offset: Vec3) -> (Scene, Vec<Point3DId>, Vec<Point3DId>) {
    let mut s = Scene::line(4, n_points as usize);
    s.match_all();
    let mut a = Vec::new();
    let mut b = Vec::new();
    for k in 0..n_points {
        a.push(s.add_true_point(k, &[1, 2]));
        b.push(s.add_point_at(s.truth[k as usize] + offset, k, &[3, 4]));
    }
    (s, a, b)
}

#[test]
fn merge_joins_two_tracks_of_the_same_point() {
    let (mut s, a, b) = split_tracks(5, Vec3::zeros());
    assert_eq!(merge_tracks(&mut s.rec, &s.graph, &[a[0]], &opts()).unwrap(), 1);
    assert_eq!(s.rec.num_points3d(), 9);
    assert!(s.rec.point3d(a[0]).is_none() && s.rec.point3d(b[0]).is_none());
    let merged = s.point_of(1, 0).unwrap();
    assert_eq!(s.track_images(merged), [1, 2, 3, 4]);
    assert!(s.truth_error(merged) < 1e-12);
    // Merging everything joins the other four pairs.
    let all = s.rec.point3d_ids();
    assert_eq!(merge_tracks(&mut s.rec, &s.graph, &all, &opts()).unwrap(), 4);
    assert_eq!(s.rec.num_points3d(), 5);
    assert!(s.rec.points3d().all(|(_, p)| p.track.len() == 4));
    s.rec.check_consistency().unwrap();
}

#[test]
fn merge_refuses_tracks_whose_merged_point_reprojects_badly() {
    // The second track's point is 0.3 m off: the mean is off by 0.15 m,
    // 10-15 px in every image.
    let offset = Vec3::new(0.0, 0.3, 0.0);
    let (mut s, a, b) = split_tracks(3, offset);
    let before = s.rec.clone();
    let all = s.rec.point3d_ids();
    assert_eq!(merge_tracks(&mut s.rec, &s.graph, &all, &opts()).unwrap(), 0);
    assert_eq!(s.rec, before);
    let loose = TriangulatorOptions { merge_max_reproj_error_px: 40.0, ..opts() };
    assert_eq!(merge_tracks(&mut s.rec, &s.graph, &[a[1]], &loose).unwrap(), 1);
    let merged = s.point_of(3, 1).unwrap();
    assert!(s.rec.point3d(b[1]).is_none());
    assert!((s.rec.point3d(merged).unwrap().xyz - (s.truth[1] + offset / 2.0)).norm() < 1e-12);
}

// ----- complete --------------------------------------------------------------

/// A chain 1-2-3-4 with every point observed by images 1 and 2 only.
fn incomplete_chain(n_points: u32) -> (Scene, Vec<Point3DId>) {
    let mut s = Scene::line(4, n_points as usize);
    s.match_chain();
    let ids = (0..n_points).map(|k| s.add_true_point(k, &[1, 2])).collect();
    (s, ids)
}

#[test]
fn complete_adds_observations_through_the_graph_up_to_the_transitivity() {
    let (mut s, ids) = incomplete_chain(6);
    // Image 3 is one hop from the track, image 4 two.
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids, &opts()).unwrap(), 12);
    for &pid in &ids {
        assert_eq!(s.track_images(pid), [1, 2, 3, 4]);
    }
    let (mut s, ids) = incomplete_chain(6);
    let one_hop = TriangulatorOptions { complete_max_transitivity: 1, ..opts() };
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids, &one_hop).unwrap(), 6);
    for &pid in &ids {
        assert_eq!(s.track_images(pid), [1, 2, 3]);
    }
    // Only the listed points are completed.
    let (mut s, ids) = incomplete_chain(6);
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids[..2], &opts()).unwrap(), 4);
    assert_eq!(s.rec.num_observations(), 16);
    s.rec.check_consistency().unwrap();
}

#[test]
fn complete_refuses_observations_beyond_the_reprojection_threshold() {
    let build = || {
        let (mut s, ids) = incomplete_chain(4);
        s.shift_keypoint(3, 0, 5.0, 0.0);
        s.shift_keypoint(3, 1, 0.0, 3.0);
        s.shift_keypoint(4, 2, 3.0, -3.0);
        (s, ids)
    };
    let (mut s, ids) = build();
    // Point 0 cannot reach image 3 (5 px) nor, through it, image 4; point 2
    // reaches image 3 but not image 4 (4.24 px).
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids, &opts()).unwrap(), 5);
    assert_eq!(s.track_images(ids[0]), [1, 2]);
    assert_eq!(s.track_images(ids[1]), [1, 2, 3, 4]);
    assert_eq!(s.track_images(ids[2]), [1, 2, 3]);
    assert_eq!(s.track_images(ids[3]), [1, 2, 3, 4]);
    let (mut s, ids) = build();
    let loose = TriangulatorOptions { complete_max_reproj_error_px: 5.5, ..opts() };
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids, &loose).unwrap(), 8);
}

#[test]
fn complete_skips_unregistered_and_already_triangulated_keypoints() {
    let mut s = Scene::line(6, 4);
    s.match_all();
    s.unregister(3);
    let ids: Vec<Point3DId> = (0..4).map(|k| s.add_true_point(k, &[1, 2])).collect();
    // Keypoint 0 of images 4 and 5 already observes another point.
    let other = s.add_true_point(0, &[4, 5]);
    assert_eq!(complete_tracks(&mut s.rec, &s.graph, &ids, &opts()).unwrap(), 1 + 3 * 3);
    assert_eq!(s.track_images(ids[0]), [1, 2, 6]);
    assert_eq!(s.track_images(ids[1]), [1, 2, 4, 5, 6]);
    assert_eq!(s.track_images(other), [4, 5]);
    assert!(s.rec.image(img(3)).unwrap().points2d.iter().all(|p| p.point3d_id.is_none()));
    s.rec.check_consistency().unwrap();
}

/// Gives each keypoint of `keys` two true points: one observed by the
/// images `first`, one by the images `second`.
fn add_split(s: &mut Scene, keys: std::ops::Range<u32>, first: &[u32], second: &[u32]) {
    for k in keys {
        s.add_true_point(k, first);
        s.add_true_point(k, second);
    }
}

#[test]
fn complete_and_merge_all_reports_both_steps() {
    // Tracks {1, 2} and {3, 4} of each point, image 5 unobserved.
    let mut s = Scene::line(5, 6);
    s.match_all();
    add_split(&mut s, 0..6, &[1, 2], &[3, 4]);
    let r = complete_and_merge_all(&mut s.rec, &s.graph, &opts()).unwrap();
    assert_eq!(r, report(0, 6, 6));
    assert_eq!(s.rec.num_points3d(), 6);
    for k in 0..6 {
        let pid = s.point_of(1, k).unwrap();
        assert_eq!(s.track_images(pid), [1, 2, 3, 4, 5]);
        assert!(s.truth_error(pid) < 1e-12);
    }
    s.rec.check_consistency().unwrap();
    assert_eq!(complete_and_merge_all(&mut s.rec, &s.graph, &opts()).unwrap(), TriangulationReport::default());
}

#[test]
fn complete_and_merge_image_touches_only_that_images_points() {
    let mut s = Scene::line(5, 6);
    s.match_all();
    add_split(&mut s, 0..3, &[1, 2], &[3, 4]);
    // Mergeable split tracks that image 1 does not observe.
    add_split(&mut s, 3..6, &[2, 3], &[4, 5]);
    let r = complete_and_merge_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    assert_eq!(r, report(0, 3, 3));
    assert_eq!(s.rec.num_points3d(), 3 + 6);
    for k in 0..3 {
        assert_eq!(s.track_images(s.point_of(1, k).unwrap()), [1, 2, 3, 4, 5]);
    }
    for k in 3..6 {
        assert_eq!(s.track_images(s.point_of(2, k).unwrap()), [2, 3]);
    }
    assert!(matches!(complete_and_merge_image(&mut s.rec, &s.graph, img(42), &opts()), Err(SfmError::UnknownImage(_))));
}

// ----- retriangulate ---------------------------------------------------------

#[test]
fn retriangulate_rebuilds_a_model_without_points() {
    let mut s = Scene::line(4, 10);
    s.match_all();
    let r = retriangulate(&mut s.rec, &s.graph, None, &opts()).unwrap();
    assert_eq!(r, report(10, 0, 0));
    for k in 0..10 {
        let pid = s.point_of(1, k).unwrap();
        assert_eq!(s.track_images(pid), [1, 2, 3, 4]);
        assert!(s.truth_error(pid) < 1e-9);
    }
    s.rec.check_consistency().unwrap();
}

#[test]
fn retriangulate_leaves_well_triangulated_pairs_alone() {
    let mut s = Scene::line(4, 10);
    s.match_all();
    triangulate_image(&mut s.rec, &s.graph, img(1), &opts()).unwrap();
    let before = s.rec.clone();
    assert_eq!(retriangulate(&mut s.rec, &s.graph, None, &opts()).unwrap(), TriangulationReport::default());
    assert_eq!(s.rec, before);
}

#[test]
fn retriangulate_only_pairs_below_the_minimum_ratio() {
    // Pair 1-2 has 3 of 10 correspondences triangulated (ratio 0.3).
    let build = || {
        let mut s = Scene::line(3, 10);
        s.match_chain();
        for k in 0..3 {
            s.add_true_point(k, &[1, 2]);
        }
        s
    };
    let mut s = build();
    assert_eq!(retriangulate(&mut s.rec, &s.graph, Some(&[img(1)]), &opts()).unwrap(), TriangulationReport::default());
    assert_eq!(s.rec.num_points3d(), 3);
    let eager = TriangulatorOptions { re_min_ratio: 0.5, ..opts() };
    assert_eq!(retriangulate(&mut s.rec, &s.graph, Some(&[img(1)]), &eager).unwrap(), report(7, 0, 0));
    for k in 3..10 {
        // Only pairs with image 1 were considered; pair 2-3 was not.
        assert_eq!(s.track_images(s.point_of(1, k).unwrap()), [1, 2]);
        assert_eq!(s.point_of(3, k), None);
    }
    // Without a focus, pair 2-3 (ratio 0) is retriangulated too.
    let mut s = build();
    let r = retriangulate(&mut s.rec, &s.graph, None, &opts()).unwrap();
    assert_eq!(r.created, 7);
    assert_eq!(s.rec.num_points3d(), 10);
}

/// Images 1-2-3 in a chain; the points are triangulated in the two images
/// other than `shifted`, whose keypoints are all 26 px off (2.4-3 degrees:
/// beyond the continue threshold, within the retriangulation one).
fn shifted_image(shifted: u32) -> Scene {
    let mut s = Scene::line(3, 8);
    s.match_chain();
    let others: Vec<u32> = (1..=3).filter(|&i| i != shifted).collect();
    for k in 0..8 {
        s.add_true_point(k, &others);
        s.shift_keypoint(shifted, k, 0.0, 26.0);
    }
    s
}

/// Triangulating image `shifted` continues none of its keypoints (beyond 2
/// degrees); retriangulating its pairs continues all of them (within 5).
fn assert_retriangulation_continues(shifted: u32) {
    let mut s = shifted_image(shifted);
    let r = triangulate_image(&mut s.rec, &s.graph, img(shifted), &opts()).unwrap();
    assert_eq!(r, TriangulationReport::default());
    let r = retriangulate(&mut s.rec, &s.graph, Some(&[img(shifted)]), &opts()).unwrap();
    assert_eq!(r, report(0, 8, 0));
    for k in 0..8 {
        assert_eq!(s.point_of(shifted, k), s.point_of(2, k));
    }
    s.rec.check_consistency().unwrap();
}

#[test]
fn retriangulate_continues_tracks_into_the_newer_image_with_the_relaxed_threshold() {
    // Pair 2-3: the keypoint lacking a point is in the second image of the pair.
    assert_retriangulation_continues(3);
}

#[test]
fn retriangulate_continues_tracks_into_the_older_image_with_the_relaxed_threshold() {
    // Pair 1-2: the keypoint lacking a point is in the first image of the pair.
    assert_retriangulation_continues(1);
    // Beyond the relaxed threshold nothing is continued.
    let mut s = shifted_image(1);
    let strict = TriangulatorOptions { re_max_angle_error_deg: 2.0, ..opts() };
    assert_eq!(retriangulate(&mut s.rec, &s.graph, Some(&[img(1)]), &strict).unwrap(), TriangulationReport::default());
}

// ----- options ---------------------------------------------------------------

#[test]
fn invalid_options_are_refused_by_every_step() {
    let cases: Vec<(&str, TriangulatorOptions)> = vec![
        ("create_max_angle_error_deg", TriangulatorOptions { create_max_angle_error_deg: 0.0, ..opts() }),
        ("continue_max_angle_error_deg", TriangulatorOptions { continue_max_angle_error_deg: -1.0, ..opts() }),
        ("merge_max_reproj_error_px", TriangulatorOptions { merge_max_reproj_error_px: f64::NAN, ..opts() }),
        ("complete_max_reproj_error_px", TriangulatorOptions { complete_max_reproj_error_px: f64::INFINITY, ..opts() }),
        ("re_max_angle_error_deg", TriangulatorOptions { re_max_angle_error_deg: 0.0, ..opts() }),
        ("re_min_ratio", TriangulatorOptions { re_min_ratio: 1.5, ..opts() }),
        ("min_angle_deg", TriangulatorOptions { min_angle_deg: 180.0, ..opts() }),
        ("min_angle_deg", TriangulatorOptions { min_angle_deg: -0.1, ..opts() }),
    ];
    let mut s = Scene::line(3, 4);
    s.match_all();
    let pid = s.add_true_point(0, &[1, 2]);
    let before = s.rec.clone();
    for (name, o) in &cases {
        let is_named = |e: SfmError| matches!(e, SfmError::InvalidOption { name: n, .. } if n == *name);
        assert!(is_named(o.validate().unwrap_err()), "{name}");
        assert!(is_named(triangulate_image(&mut s.rec, &s.graph, img(1), o).unwrap_err()));
        assert!(is_named(complete_tracks(&mut s.rec, &s.graph, &[pid], o).unwrap_err()));
        assert!(is_named(merge_tracks(&mut s.rec, &s.graph, &[pid], o).unwrap_err()));
        assert!(is_named(retriangulate(&mut s.rec, &s.graph, None, o).unwrap_err()));
        assert!(is_named(complete_and_merge_all(&mut s.rec, &s.graph, o).unwrap_err()));
    }
    assert_eq!(s.rec, before);
    // Boundary values are valid.
    let edge = TriangulatorOptions { min_angle_deg: 0.0, re_min_ratio: 1.0, ..opts() };
    edge.validate().unwrap();
    opts().validate().unwrap();
}

#[test]
fn reports_add_up() {
    let mut total = TriangulationReport::default();
    total += report(3, 2, 1);
    total += report(1, 0, 4);
    assert_eq!(total, report(4, 2, 5));
    assert_eq!(total.total(), 11);
}

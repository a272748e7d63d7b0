//! The observation filters of colslam-scene's `Reconstruction` on maps built
//! by the triangulator and on maps with planted outliers, run as the mapper
//! runs them after triangulation and bundle adjustment (after COLMAP's
//! `observation_manager_test.cc`): exact counts of what each removes.

mod common;

use colslam_geometry::Vec3;
use colslam_scene::{FilterReport, Point3DId, Reconstruction};
use colslam_sfm::TriangulatorOptions;
use colslam_sfm::triangulator::triangulate_image;
use common::{Scene, img, look_at};

fn filtered(observations_removed: usize, points_deleted: usize) -> FilterReport {
    FilterReport { observations_removed, points_deleted }
}

/// The mapper's filter sequence (negative depth, reprojection error,
/// triangulation angle) with COLMAP's default thresholds.
fn filter_all(rec: &mut Reconstruction, points: Option<&[Point3DId]>) -> [FilterReport; 3] {
    [
        rec.filter_negative_depth(points).unwrap(),
        rec.filter_by_reprojection_error(4.0, points).unwrap(),
        rec.filter_by_triangulation_angle(1.5, points).unwrap(),
    ]
}

#[test]
fn an_exactly_triangulated_map_passes_every_filter() {
    let mut s = Scene::line(4, 12);
    s.match_all();
    triangulate_image(&mut s.rec, &s.graph, img(1), &TriangulatorOptions::default()).unwrap();
    assert_eq!(s.rec.num_observations(), 48);
    let before = s.rec.num_observations();
    assert_eq!(filter_all(&mut s.rec, None), [FilterReport::default(); 3]);
    assert_eq!(s.rec.num_observations(), before);
    // The reprojection filter stores the (zero) mean errors of the survivors.
    assert!(s.rec.points3d().all(|(_, p)| p.has_error() && p.error < 1e-9));
}

/// Eight points of four-image tracks (except where noted) with planted
/// keypoint errors: point 0 one 10 px outlier, point 1 (two-image track) one
/// outlier, point 2 (three images) two outliers, point 3 a 3 px error.
fn planted_reprojection_outliers() -> (Scene, Vec<Point3DId>) {
    let mut s = Scene::line(4, 8);
    let tracks: [&[u32]; 8] =
        [&[1, 2, 3, 4], &[1, 2], &[1, 2, 3], &[1, 2, 3, 4], &[1, 2, 3, 4], &[1, 2, 3, 4], &[1, 2, 3, 4], &[2, 3, 4]];
    let ids = tracks.iter().enumerate().map(|(k, t)| s.add_true_point(k as u32, t)).collect();
    s.shift_keypoint(4, 0, 10.0, 0.0);
    s.shift_keypoint(2, 1, 0.0, -10.0);
    s.shift_keypoint(2, 2, 6.0, 8.0);
    s.shift_keypoint(3, 2, -7.0, 0.0);
    s.shift_keypoint(1, 3, 0.0, 3.0);
    (s, ids)
}

#[test]
fn reprojection_filter_removes_exactly_the_planted_outliers() {
    let (mut s, ids) = planted_reprojection_outliers();
    assert_eq!(s.rec.num_observations(), 28);
    // Point 0 loses one observation; points 1 and 2 keep fewer than two and
    // go with all their observations (2 + 3).
    assert_eq!(s.rec.filter_by_reprojection_error(4.0, None).unwrap(), filtered(1 + 2 + 3, 2));
    assert_eq!(s.rec.num_points3d(), 6);
    assert_eq!(s.rec.num_observations(), 22);
    assert_eq!(s.track_images(ids[0]), [1, 2, 3]);
    assert!(s.rec.point3d(ids[1]).is_none() && s.rec.point3d(ids[2]).is_none());
    assert_eq!(s.point_of(1, 1), None);
    // Survivors carry their mean error over the kept observations.
    assert!(s.rec.point3d(ids[0]).unwrap().error < 1e-9);
    assert!((s.rec.point3d(ids[3]).unwrap().error - 0.75).abs() < 1e-9);
    s.rec.check_consistency().unwrap();
    // A second pass has nothing left to remove.
    assert_eq!(s.rec.filter_by_reprojection_error(4.0, None).unwrap(), FilterReport::default());
    // A threshold below the 3 px error takes that observation too.
    assert_eq!(s.rec.filter_by_reprojection_error(2.9, None).unwrap(), filtered(1, 0));
    assert_eq!(s.track_images(ids[3]), [2, 3, 4]);
}

#[test]
fn reprojection_filter_only_touches_the_listed_points() {
    let (mut s, ids) = planted_reprojection_outliers();
    assert_eq!(s.rec.filter_by_reprojection_error(4.0, Some(&[ids[1], ids[4]])).unwrap(), filtered(2, 1));
    assert_eq!(s.track_images(ids[0]), [1, 2, 3, 4]);
    assert_eq!(s.track_images(ids[2]), [1, 2, 3]);
    // Ids of deleted or unknown points are ignored.
    assert_eq!(
        s.rec.filter_by_reprojection_error(4.0, Some(&[ids[1], Point3DId(999)])).unwrap(),
        FilterReport::default()
    );
    assert_eq!(s.rec.filter_by_reprojection_error(4.0, Some(&[ids[0]])).unwrap(), filtered(1, 0));
}

#[test]
fn angle_filter_deletes_points_seen_from_nearly_one_centre() {
    // Images 1 and 2 are 1 cm apart (about 0.1 degrees at 6 m), image 3 1 m away.
    let target = Vec3::new(1.0, 0.0, 6.0);
    let poses =
        [Vec3::zeros(), Vec3::new(0.01, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0)].map(|c| look_at(c, target)).to_vec();
    let mut s = Scene::new(poses, common::box_points(5, 21));
    let tracks: [&[u32]; 5] = [&[1, 2], &[1, 2, 3], &[1, 3], &[2, 1], &[2, 3]];
    let ids: Vec<Point3DId> = tracks.iter().enumerate().map(|(k, t)| s.add_true_point(k as u32, t)).collect();
    // Every point passes a minimum below 0.05 degrees.
    assert_eq!(s.rec.filter_by_triangulation_angle(0.05, None).unwrap(), FilterReport::default());
    assert_eq!(s.rec.filter_by_triangulation_angle(1.5, Some(&ids[1..])).unwrap(), filtered(2, 1));
    assert!(s.rec.point3d(ids[3]).is_none());
    assert!(s.rec.point3d(ids[0]).is_some());
    assert_eq!(s.rec.filter_by_triangulation_angle(1.5, None).unwrap(), filtered(2, 1));
    assert_eq!(s.rec.num_points3d(), 3);
    assert_eq!(s.rec.num_observations(), 7);
    s.rec.check_consistency().unwrap();
}

#[test]
fn negative_depth_filter_removes_observations_behind_their_camera() {
    // Images 1 and 2 look into the box, image 3 looks back at it from behind.
    let target = Vec3::new(1.0, 0.0, 6.0);
    let poses =
        [Vec3::zeros(), Vec3::new(0.5, 0.0, 0.0), Vec3::new(3.0, 0.0, 9.0)].map(|c| look_at(c, target)).to_vec();
    let mut s = Scene::new(poses.clone(), common::box_points(4, 13));
    let ids: Vec<Point3DId> = [[1u32, 2, 3].as_slice(), &[1, 3], &[1, 2, 3], &[2, 3]]
        .iter()
        .enumerate()
        .map(|(k, t)| s.add_true_point(k as u32, t))
        .collect();
    assert_eq!(s.rec.filter_negative_depth(None).unwrap(), FilterReport::default());
    // Move points 0 and 1 in front of images 1 and 2 but behind image 3.
    let behind = Vec3::new(2.5, 0.3, 11.0);
    assert!(poses.iter().map(|p| p.transform_point(&behind).z > 0.0).eq([true, true, false]));
    for &pid in &ids[..2] {
        *s.rec.point3d_xyz_mut(pid).unwrap() = behind;
    }
    assert_eq!(s.rec.filter_negative_depth(None).unwrap(), filtered(1 + 2, 1));
    assert_eq!(s.track_images(ids[0]), [1, 2]);
    assert!(s.rec.point3d(ids[1]).is_none());
    assert_eq!(s.track_images(ids[2]), [1, 2, 3]);
    assert_eq!(s.rec.num_observations(), 2 + 3 + 2);
    s.rec.check_consistency().unwrap();
}

#[test]
fn a_continued_wrong_match_is_removed_by_the_mapper_filters() {
    // Images 1-2 triangulated; image 3's keypoint 0 is 10 px off, within the
    // 2 degree continue threshold, so triangulation adds it to the track
    // without moving the point; the 4 px reprojection filter removes it.
    let mut s = Scene::line(3, 6);
    s.match_chain();
    s.unregister(3);
    let opts = TriangulatorOptions::default();
    triangulate_image(&mut s.rec, &s.graph, img(1), &opts).unwrap();
    s.rec.register_image(img(3)).unwrap();
    s.shift_keypoint(3, 0, 0.0, 10.0);
    assert_eq!(triangulate_image(&mut s.rec, &s.graph, img(3), &opts).unwrap().continued, 6);
    let local: Vec<Point3DId> = s.rec.image(img(3)).unwrap().points2d.iter().filter_map(|p| p.point3d_id).collect();
    let [depth, reproj, angle] = filter_all(&mut s.rec, Some(&local));
    assert_eq!((depth, reproj, angle), (FilterReport::default(), filtered(1, 0), FilterReport::default()));
    assert_eq!(s.point_of(3, 0), None);
    assert_eq!(s.track_images(s.point_of(1, 0).unwrap()), [1, 2]);
    assert!(s.max_reprojection_error() < 1e-6);
}

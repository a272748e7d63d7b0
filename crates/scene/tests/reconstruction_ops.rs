//! Mapper operations keep the 2D<->3D links consistent; statistics,
//! normalisation, transforms, filters and PLY output.

mod common;

use colslam_geometry::{Quat, Sim3, Vec2, Vec3};
use colslam_scene::{
    ImageId, NormalizeOptions, PlyFormat, Point3DId, Reconstruction, SceneError, TrackElement, ply::encode_ply,
};
use common::synthetic_model;

fn errors(rec: &Reconstruction) -> Vec<f64> {
    rec.point3d_ids().into_iter().map(|id| rec.compute_point_error(id).unwrap()).collect()
}

#[test]
fn statistics_match_tracks() {
    let rec = synthetic_model(1);
    let total: usize = rec.points3d().map(|(_, p)| p.track.len()).sum();
    assert_eq!(rec.num_observations(), total);
    assert_eq!(rec.num_points3d(), 60);
    assert!((rec.mean_track_length() - total as f64 / 60.0).abs() < 1e-12);
    assert!((rec.mean_observations_per_registered_image() - total as f64 / 6.0).abs() < 1e-12);
    // Keypoints carry up to 0.5 px of noise per axis.
    let mean = rec.mean_reprojection_error();
    assert!(mean > 0.05 && mean < 0.71, "{mean}");
    assert!(Reconstruction::new().mean_track_length() == 0.0);
}

#[test]
fn observations_add_delete_and_merge_keep_links() {
    let mut rec = synthetic_model(2);
    let (pid, p) = rec.points3d().find(|(_, p)| p.track.len() == 4).map(|(i, p)| (i, p.clone())).unwrap();
    // Removing from a 4-track keeps the point.
    let el = p.track[0];
    let r = rec.delete_observation(el.image_id, el.point2d_idx).unwrap();
    assert!(!r.point_deleted);
    assert_eq!(rec.point3d(pid).unwrap().track.len(), 3);
    assert_eq!(rec.image(el.image_id).unwrap().points2d[el.point2d_idx as usize].point3d_id, None);
    rec.check_consistency().unwrap();
    // Adding it back.
    rec.add_observation(pid, el).unwrap();
    assert_eq!(rec.point3d(pid).unwrap().track.len(), 4);
    // Linking an already linked keypoint fails.
    let other = rec.points3d().find(|(i, _)| *i != pid).map(|(i, _)| i).unwrap();
    let err = rec.add_observation(other, el).unwrap_err();
    assert!(matches!(err, SceneError::BadObservation { .. }), "{err}");
    // Removing from a 2-track deletes the point and both links.
    let (pid2, p2) = rec.points3d().find(|(_, p)| p.track.len() == 2).map(|(i, p)| (i, p.clone())).unwrap();
    let r = rec.delete_observation(p2.track[0].image_id, p2.track[0].point2d_idx).unwrap();
    assert!(r.point_deleted);
    assert!(rec.point3d(pid2).is_none());
    for e in &p2.track {
        assert_eq!(rec.image(e.image_id).unwrap().points2d[e.point2d_idx as usize].point3d_id, None);
    }
    rec.check_consistency().unwrap();
    // Merge two points: union of tracks, weighted position, new id.
    let ids = rec.point3d_ids();
    let (a, b) = (ids[0], ids[1]);
    let (pa, pb) = (rec.point3d(a).unwrap().clone(), rec.point3d(b).unwrap().clone());
    let m = rec.merge_points3d(a, b).unwrap();
    assert!(m.0 > ids.iter().map(|i| i.0).max().unwrap());
    let pm = rec.point3d(m).unwrap();
    assert_eq!(pm.track.len(), pa.track.len() + pb.track.len());
    let (wa, wb) = (pa.track.len() as f64, pb.track.len() as f64);
    assert!((pm.xyz - (pa.xyz * wa + pb.xyz * wb) / (wa + wb)).norm() < 1e-12);
    for e in &pm.track {
        assert_eq!(rec.image(e.image_id).unwrap().points2d[e.point2d_idx as usize].point3d_id, Some(m));
    }
    assert!(rec.point3d(a).is_none() && rec.point3d(b).is_none());
    rec.check_consistency().unwrap();
    assert!(rec.merge_points3d(m, m).is_err());
    // Deleting a point clears its links.
    let gone = rec.delete_point3d(m).unwrap();
    for e in &gone.track {
        assert_eq!(rec.image(e.image_id).unwrap().points2d[e.point2d_idx as usize].point3d_id, None);
    }
    assert!(matches!(rec.delete_point3d(m), Err(SceneError::UnknownPoint3D(_))));
    rec.check_consistency().unwrap();
}

#[test]
fn new_points_need_registered_free_keypoints() {
    let mut rec = synthetic_model(3);
    let unreg = rec.images().find(|i| !i.registered).unwrap().id;
    let reg = rec.registered_image_ids()[0];
    let free = rec.image(reg).unwrap().points2d.iter().position(|p| p.point3d_id.is_none()).unwrap() as u32;
    let err = rec
        .add_point3d(Vec3::zeros(), [0; 3], vec![TrackElement::new(reg, free), TrackElement::new(unreg, 0)])
        .unwrap_err();
    assert!(err.to_string().contains("not registered"), "{err}");
    let err = rec
        .add_point3d(Vec3::zeros(), [0; 3], vec![TrackElement::new(reg, free), TrackElement::new(reg, free)])
        .unwrap_err();
    assert!(err.to_string().contains("twice"), "{err}");
    let err = rec.add_point3d(Vec3::zeros(), [0; 3], vec![TrackElement::new(reg, 10_000)]).unwrap_err();
    assert!(err.to_string().contains("out of range"), "{err}");
    // Failed additions leave nothing behind.
    rec.check_consistency().unwrap();
    let before = rec.num_points3d();
    let id = rec.add_point3d(Vec3::zeros(), [1, 2, 3], vec![TrackElement::new(reg, free)]).unwrap();
    assert_eq!(rec.num_points3d(), before + 1);
    assert_eq!(rec.point3d(id).unwrap().error, -1.0);
    rec.check_consistency().unwrap();
}

#[test]
fn deregistering_removes_observations_and_short_tracks() {
    let mut rec = synthetic_model(4);
    let victim = rec.registered_image_ids()[2];
    let observed: Vec<(Point3DId, usize)> = rec
        .points3d()
        .filter(|(_, p)| p.track.iter().any(|e| e.image_id == victim))
        .map(|(i, p)| (i, p.track.len()))
        .collect();
    let n_obs = rec.num_observations();
    let report = rec.deregister_image(victim).unwrap();
    assert_eq!(report.observations_removed, observed.len());
    let expected_deleted: Vec<Point3DId> = observed.iter().filter(|(_, l)| *l <= 2).map(|(i, _)| *i).collect();
    let mut got = report.points_deleted.clone();
    got.sort();
    assert_eq!(got, expected_deleted);
    assert!(!rec.image(victim).unwrap().registered);
    assert!(!rec.registered_image_ids().contains(&victim));
    let lost: usize = observed.iter().map(|(_, l)| if *l <= 2 { *l } else { 1 }).sum();
    assert_eq!(rec.num_observations(), n_obs - lost);
    rec.check_consistency().unwrap();
    // Registering again appends it to the order.
    rec.register_image(victim).unwrap();
    assert_eq!(rec.registered_image_ids().last(), Some(&victim));
    rec.check_consistency().unwrap();
    assert!(matches!(rec.register_image(ImageId(999)), Err(SceneError::UnknownImage(_))));
}

#[test]
fn deleting_an_image_removes_it_and_its_observations() {
    let mut rec = synthetic_model(4);
    let victim = rec.registered_image_ids()[1];
    let (images, registered) = (rec.num_images(), rec.num_registered_images());
    let observed = rec.points3d().filter(|(_, p)| p.track.iter().any(|e| e.image_id == victim)).count();
    assert!(observed > 0);
    let report = rec.delete_image(victim).unwrap();
    assert_eq!(report.observations_removed, observed);
    assert!(rec.image(victim).is_none());
    assert_eq!((rec.num_images(), rec.num_registered_images()), (images - 1, registered - 1));
    assert!(rec.points3d().all(|(_, p)| p.track.len() >= 2 && p.track.iter().all(|e| e.image_id != victim)));
    rec.check_consistency().unwrap();
    assert!(matches!(rec.delete_image(victim), Err(SceneError::UnknownImage(_))));
}

#[test]
fn transform_and_normalize_keep_projections() {
    let mut rec = synthetic_model(5);
    let before = errors(&rec);
    let s =
        Sim3 { scale: 3.5, rotation: Quat::from_euler_angles(0.3, -0.5, 1.2), translation: Vec3::new(4.0, -2.0, 7.0) };
    rec.transform(&s);
    for (a, b) in errors(&rec).iter().zip(&before) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
    let centers: Vec<Vec3> =
        rec.registered_image_ids().iter().map(|i| rec.image(*i).unwrap().projection_center()).collect();
    let opts = NormalizeOptions::default();
    let applied = rec.normalize(&opts).unwrap();
    for (c, id) in centers.iter().zip(rec.registered_image_ids()) {
        let now = rec.image(*id).unwrap().projection_center();
        assert!((applied.transform_point(c) - now).norm() < 1e-9);
    }
    for (a, b) in errors(&rec).iter().zip(&before) {
        assert!((a - b).abs() < 1e-9);
    }
    // With percentiles 0..1 the box of the centres gets exactly the extent.
    let full = NormalizeOptions { min_percentile: 0.0, max_percentile: 1.0, ..opts };
    rec.normalize(&full).unwrap();
    let c: Vec<Vec3> = rec.registered_image_ids().iter().map(|i| rec.image(*i).unwrap().projection_center()).collect();
    let lo = c.iter().fold(Vec3::repeat(f64::INFINITY), |m, v| m.inf(v));
    let hi = c.iter().fold(Vec3::repeat(f64::NEG_INFINITY), |m, v| m.sup(v));
    assert!(((hi - lo).norm() - 10.0).abs() < 1e-9, "{}", (hi - lo).norm());
    let mean = c.iter().sum::<Vec3>() / c.len() as f64;
    assert!(mean.norm() < 1e-9, "{mean}");
    assert!(rec.normalize(&NormalizeOptions { extent: 0.0, ..opts }).is_err());
    assert!(rec.normalize(&NormalizeOptions { min_percentile: 0.9, max_percentile: 0.1, ..opts }).is_err());
}

#[test]
fn filters_remove_what_they_should() {
    let mut rec = synthetic_model(6);
    assert_eq!(rec.filter_by_reprojection_error(4.0, None).unwrap(), Default::default());
    // Move one keypoint of a 4-track 50 px away: one observation goes.
    let (pid, p) = rec.points3d().find(|(_, p)| p.track.len() == 4).map(|(i, p)| (i, p.clone())).unwrap();
    let el = p.track[1];
    // Replace the observation by a keypoint 50 px off.
    rec.delete_observation(el.image_id, el.point2d_idx).unwrap();
    let xy = rec.image(el.image_id).unwrap().points2d[el.point2d_idx as usize].xy + Vec2::new(50.0, 0.0);
    let idx = rec.push_point2d(el.image_id, xy).unwrap();
    rec.add_observation(pid, TrackElement::new(el.image_id, idx)).unwrap();
    let r = rec.filter_by_reprojection_error(4.0, None).unwrap();
    assert_eq!((r.observations_removed, r.points_deleted), (1, 0));
    assert_eq!(rec.point3d(pid).unwrap().track.len(), 3);
    assert!(rec.point3d(pid).unwrap().error < 1.0);
    rec.check_consistency().unwrap();

    // A point very far away has a tiny triangulation angle.
    let far = rec.point3d_ids()[0];
    *rec.point3d_xyz_mut(far).unwrap() *= 1e6;
    let r = rec.filter_by_triangulation_angle(1.5, Some(&[far])).unwrap();
    assert_eq!(r.points_deleted, 1);
    assert!(rec.point3d(far).is_none());
    let r = rec.filter_by_triangulation_angle(0.0, None).unwrap();
    assert_eq!(r.points_deleted, 0);

    // A point behind every camera loses all its observations.
    let behind = rec.point3d_ids()[0];
    let len = rec.point3d(behind).unwrap().track.len();
    *rec.point3d_xyz_mut(behind).unwrap() = Vec3::new(0.0, 0.0, -20.0);
    let r = rec.filter_negative_depth(None).unwrap();
    assert_eq!((r.points_deleted, r.observations_removed), (1, len));
    rec.check_consistency().unwrap();
}

#[test]
fn ply_header_and_size() {
    let rec = synthetic_model(7);
    let bin = encode_ply(&rec, PlyFormat::BinaryLittleEndian);
    let header = "ply\nformat binary_little_endian 1.0\nelement vertex 60\nproperty float x\nproperty float y\n\
                  property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
    assert!(bin.starts_with(header.as_bytes()));
    assert_eq!(bin.len(), header.len() + 60 * 15);
    let (_, first) = rec.points3d().next().unwrap();
    let x = f32::from_le_bytes(bin[header.len()..header.len() + 4].try_into().unwrap());
    assert_eq!(x, first.xyz.x as f32);
    assert_eq!(&bin[header.len() + 12..header.len() + 15], &first.color);
    let ascii = String::from_utf8(encode_ply(&rec, PlyFormat::Ascii)).unwrap();
    assert!(ascii.starts_with("ply\nformat ascii 1.0\nelement vertex 60\n"));
    assert_eq!(ascii.lines().count(), 10 + 60);
    let dir = tempfile::tempdir().unwrap();
    colslam_scene::write_ply(&rec, &dir.path().join("p.ply")).unwrap();
    assert_eq!(std::fs::read(dir.path().join("p.ply")).unwrap(), bin);
}

//! Cross-check against pycolmap 4.2 (COLMAP's estimators) on the same
//! synthetic correspondences: our relative and absolute poses must be about
//! as accurate as COLMAP's, and the two-view classification must agree.
//! Skips outside CI when the peer venv is missing (scripts/setup-peers.sh).

use colslam_estimators::synthetic::{
    absolute_scene, planar_scene, random_rotation, relative_scene_wide, relative_scene_with_pose, rotation_error_deg,
    translation_dir_error_deg,
};
use colslam_estimators::{
    AbsolutePoseOptions, RansacOptions, RelativePoseOptions, TwoViewConfig, TwoViewGeometryOptions, Vec2, Vec3,
    estimate_absolute_pose, estimate_relative_pose, estimate_two_view_geometry,
};
use colslam_geometry::{Rigid3, SplitMix64};
use std::fmt::Write as _;

const FOCAL: f64 = 500.0;
const ONE_PIXEL: f64 = 1.0 / FOCAL;

fn pts2(p: &[Vec2]) -> String {
    let items: Vec<String> = p.iter().map(|v| format!("[{:.17e},{:.17e}]", v.x, v.y)).collect();
    format!("[{}]", items.join(","))
}

fn pts3(p: &[Vec3]) -> String {
    let items: Vec<String> = p.iter().map(|v| format!("[{:.17e},{:.17e},{:.17e}]", v.x, v.y, v.z)).collect();
    format!("[{}]", items.join(","))
}

fn pose_of(v: &serde_json::Value) -> Option<Rigid3> {
    let rows = v.as_array()?;
    let m = |r: usize, c: usize| rows.get(r)?.as_array()?.get(c)?.as_f64();
    let rot = colslam_geometry::Mat3::from_fn(|r, c| m(r, c).unwrap_or(f64::NAN));
    let t = Vec3::new(m(0, 3)?, m(1, 3)?, m(2, 3)?);
    Some(Rigid3::from_rotation_matrix(&rot, t))
}

#[test]
fn matches_pycolmap() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "numpy"]) else {
        return;
    };
    let rel: Vec<_> = (0..5).map(|s| relative_scene_wide(100 + s, 500, ONE_PIXEL, 0.3)).collect();
    let abs: Vec<_> = (0..5).map(|s| absolute_scene(200 + s, 500, ONE_PIXEL, 0.3)).collect();
    let mut rng = SplitMix64::new(5);
    let rot_only = Rigid3::new(random_rotation(&mut rng, 0.2), Vec3::zeros());
    let two_view = [
        (relative_scene_wide(300, 400, ONE_PIXEL, 0.2), TwoViewConfig::Calibrated, "CALIBRATED"),
        (planar_scene(301, 400, ONE_PIXEL, 0.2), TwoViewConfig::Planar, "PLANAR"),
        // COLMAP calls a noisy pure rotation PLANAR: it reports PANORAMIC
        // only when the homography decomposition has exactly zero
        // translation. We also look at the triangulation angles.
        (
            relative_scene_with_pose(&mut rng, rot_only, 400, ONE_PIXEL, 0.2, (2.0, 8.0)),
            TwoViewConfig::Panoramic,
            "PLANAR",
        ),
    ];

    let mut cases = Vec::new();
    for (i, s) in rel.iter().enumerate() {
        cases.push(format!(r#"{{"kind":"relative","seed":{i},"x1":{},"x2":{}}}"#, pts2(&s.x1), pts2(&s.x2)));
    }
    for (i, s) in abs.iter().enumerate() {
        cases.push(format!(
            r#"{{"kind":"absolute","seed":{i},"x1":{},"p3":{}}}"#,
            pts2(&s.points2d),
            pts3(&s.points3d)
        ));
    }
    for (i, (s, _, _)) in two_view.iter().enumerate() {
        cases.push(format!(r#"{{"kind":"twoview","seed":{i},"x1":{},"x2":{}}}"#, pts2(&s.x1), pts2(&s.x2)));
    }
    let mut input = String::new();
    write!(input, r#"{{"focal":{FOCAL},"cases":[{}]}}"#, cases.join(",")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("input.json");
    std::fs::write(&path, input).unwrap();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/pycolmap_peer.py");
    let out = colslam_testutil::run_python(&py, &[script, path.to_str().unwrap()]);
    let res: Vec<serde_json::Value> = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(res.len(), cases.len());

    // Relative pose: our error at most 1.5x COLMAP's plus a small margin.
    for (i, s) in rel.iter().enumerate() {
        let theirs = pose_of(&res[i]["pose"]).expect("pycolmap found no essential matrix");
        let opts = RelativePoseOptions {
            ransac: RansacOptions { seed: i as u64, ..RelativePoseOptions::default().ransac },
            ..Default::default()
        };
        let ours = estimate_relative_pose(&s.x1, &s.x2, &opts).unwrap().cam2_from_cam1;
        let (er_o, er_t) =
            (rotation_error_deg(&ours, &s.cam2_from_cam1), rotation_error_deg(&theirs, &s.cam2_from_cam1));
        let et_o = translation_dir_error_deg(&ours.translation, &s.cam2_from_cam1.translation);
        let et_t = translation_dir_error_deg(&theirs.translation, &s.cam2_from_cam1.translation);
        eprintln!(
            "relative {i}: rotation ours {er_o:.4} colmap {er_t:.4} deg; translation ours {et_o:.4} colmap {et_t:.4} deg"
        );
        assert!(er_o <= 1.5 * er_t + 0.02, "relative {i}: rotation {er_o} vs COLMAP {er_t}");
        assert!(et_o <= 1.5 * et_t + 0.2, "relative {i}: translation {et_o} vs COLMAP {et_t}");
    }
    // Absolute pose.
    for (i, s) in abs.iter().enumerate() {
        let theirs = pose_of(&res[rel.len() + i]["pose"]).expect("pycolmap found no absolute pose");
        let opts = AbsolutePoseOptions {
            ransac: RansacOptions { seed: i as u64, ..AbsolutePoseOptions::default().ransac },
            ..Default::default()
        };
        let ours = estimate_absolute_pose(&s.points2d, &s.points3d, &opts).unwrap().cam_from_world;
        let (er_o, er_t) =
            (rotation_error_deg(&ours, &s.cam_from_world), rotation_error_deg(&theirs, &s.cam_from_world));
        let ep_o = (ours.center() - s.cam_from_world.center()).norm();
        let ep_t = (theirs.center() - s.cam_from_world.center()).norm();
        eprintln!(
            "absolute {i}: rotation ours {er_o:.4} colmap {er_t:.4} deg; position ours {ep_o:.5} colmap {ep_t:.5}"
        );
        assert!(er_o <= 1.5 * er_t + 0.01, "absolute {i}: rotation {er_o} vs COLMAP {er_t}");
        assert!(ep_o <= 1.5 * ep_t + 1e-3, "absolute {i}: position {ep_o} vs COLMAP {ep_t}");
    }
    // Two-view classification.
    for (i, (s, expected, colmap_name)) in two_view.iter().enumerate() {
        let r = &res[rel.len() + abs.len() + i];
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        eprintln!(
            "two-view {i}: ours {:?} ({} inliers), colmap {} ({} inliers)",
            g.config, g.num_inliers, r["config"], r["num_inliers"]
        );
        assert_eq!(g.config, *expected);
        assert_eq!(r["config"].as_str(), Some(*colmap_name), "COLMAP classified case {i} differently");
    }
}

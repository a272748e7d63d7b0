//! Server tests of the frame panel: where a model's images are found, the
//! per-camera keypoints by state, the pictures (and the requests refused),
//! and the ground-truth layer in the state.

use super::tests::{get, get_json, post, raw, start};
use super::*;
use colslam_scene::{ImageId, Reconstruction};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A demo model with one observation moved 10 px off its projection (an
/// outlier) and one keypoint without a 3D point added to image 2.
fn model_with_outlier() -> (Reconstruction, usize, usize, usize) {
    let mut rec = demo_reconstruction(4, 80, 3).expect("demo");
    let img = rec.image(ImageId(2)).expect("image 2").clone();
    let (slot, kp) = img.points2d.iter().enumerate().find(|(_, p)| p.point3d_id.is_some()).expect("an observation");
    let moved = kp.xy + colslam_geometry::Vec2::new(10.0, 0.0);
    rec.set_point2d_xy(ImageId(2), slot as u32, moved).expect("move");
    rec.push_point2d(ImageId(2), colslam_geometry::Vec2::new(5.0, 5.0)).expect("push");
    let img = rec.image(ImageId(2)).expect("image 2");
    let observed = img.points2d.iter().filter(|p| p.point3d_id.is_some()).count();
    (rec.clone(), observed - 1, 1, img.points2d.len() - observed)
}

/// A small RGB picture for image `i`.
fn write_picture(path: &Path, i: usize) {
    let mut img = colslam_image::Image::new(64, 48, 3);
    for y in 0..48 {
        for x in 0..64 {
            img.set(x, y, 0, (x * 4) as u8);
            img.set(x, y, 1, (y * 5) as u8);
            img.set(x, y, 2, (40 * i) as u8);
        }
    }
    img.write_png(path).expect("write png");
}

fn write_pictures(rec: &Reconstruction, dir: &Path) {
    std::fs::create_dir_all(dir).expect("mkdir");
    for (i, id) in rec.registered_image_ids().iter().enumerate() {
        write_picture(&dir.join(&rec.image(*id).expect("image").name), i);
    }
}

#[test]
fn camera_detail_counts_keypoints_by_state() {
    let (rec, tri, out, un) = model_with_outlier();
    let v = start();
    v.set_reconstruction(&rec);
    let (code, d) = get_json(&v, "/api/camera?id=2");
    assert_eq!(code, 200, "{d}");
    assert_eq!(d["counts"]["triangulated"], tri);
    assert_eq!(d["counts"]["outlier"], out);
    assert_eq!(d["counts"]["unmatched"], un);
    assert_eq!(d["observations"], tri + out);
    let states = d["keypoints"]["state"].as_array().expect("states");
    assert_eq!(states.len(), tri + out + un);
    assert_eq!(d["keypoints"]["xy"].as_array().map(Vec::len), Some(2 * states.len()));
    // One observation is 10 px off, the others exact: the mean is 10 / n.
    let mean = d["mean_reproj_error"].as_f64().expect("mean error");
    assert!((mean - 10.0 / (tri + out) as f64).abs() < 1e-3, "{mean}");
    assert_eq!(d["name"], "frame_000001.png");
    assert_eq!(d["timestamp"], Value::Null, "frame_000001 carries no time");
    assert_eq!(get_json(&v, "/api/camera?id=99").0, 404);
    assert_eq!(get_json(&v, "/api/camera?id=x").0, 400);
    assert_eq!(get_json(&v, "/api/camera").0, 400);
}

#[test]
fn pictures_of_a_loaded_model_are_found_and_served() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = demo_reconstruction(3, 30, 1).expect("demo");
    let model = dir.path().join("run/sparse");
    colslam_scene::write_model(&rec, &model, colslam_scene::ModelFormat::Binary).expect("write model");
    // Nothing on disk yet: the reason names the option.
    let missing = ImageSource::discover(&model, &rec);
    assert!(!missing.available() && missing.describe().contains("--images"), "{}", missing.describe());
    // Images in the folder above the model's `images/` are found by loading.
    write_pictures(&rec, &dir.path().join("run/images"));
    assert_eq!(ImageSource::discover(&model, &rec), ImageSource::Folder(dir.path().join("run/images")));
    let v = start();
    let (code, j) = post(&v, "/api/load", &serde_json::json!({ "path": model }).to_string());
    assert_eq!(code, 200, "{j}");
    let snap = get_json(&v, "/api/state").1;
    assert_eq!(snap["images"]["available"], true, "{}", snap["images"]);
    let req = |id: &str| {
        let body = format!("{{\"id\": {id}}}");
        let head = format!(
            "POST /api/image HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        raw(&v, head.as_bytes())
    };
    let (code, png) = req("2");
    assert_eq!(code, 200);
    let img = colslam_image::Image::decode(&png, Path::new("served.png")).expect("a PNG");
    assert_eq!((img.width(), img.height(), img.get(10, 20, 0), img.get(0, 0, 2)), (64, 48, 40, 40));
    assert_eq!(req("7").0, 404, "an id the model does not have");
    assert_eq!(req("\"x\"").0, 400);
    assert_eq!(get(&v, "/api/image?id=2").0, 405, "pictures are read by POST only");
}

#[test]
fn image_requests_outside_the_images_folder_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let images = dir.path().join("images");
    std::fs::create_dir_all(&images).expect("mkdir");
    write_picture(&dir.path().join("secret.png"), 0);
    write_picture(&images.join("ok.png"), 1);
    let mut rec = Reconstruction::new();
    let cam = rec.add_camera(colslam_camera::Camera::pinhole(64, 48, 50.0, 50.0, 32.0, 24.0));
    let names = ["ok.png", "../secret.png", "/etc/passwd", "link.png", ""];
    for (i, name) in names.iter().enumerate() {
        let mut img = colslam_scene::Image::new(ImageId(i as u32 + 1), *name, cam, vec![]);
        img.registered = true;
        rec.add_image(img).expect("add image");
    }
    #[cfg(unix)]
    std::os::unix::fs::symlink(dir.path().join("secret.png"), images.join("link.png")).expect("symlink");
    let src = ImageSource::Folder(images);
    assert!(load_picture(&rec, &src, 1, 640).is_ok());
    for id in [2, 3, 5] {
        let e = load_picture(&rec, &src, id, 640).expect_err("refused");
        assert_eq!(e.status(), 403, "image {id}: {e}");
    }
    #[cfg(unix)]
    assert_eq!(load_picture(&rec, &src, 4, 640).map(|_| ()).map_err(|e| e.status()), Err(403), "a link out");
    assert_eq!(load_picture(&rec, &src, 9, 640).map(|_| ()).map_err(|e| e.status()), Err(404));
    // Through the server: the same refusal, and nothing without images.
    let v = start();
    v.set_reconstruction(&rec);
    assert_eq!(post(&v, "/api/image", r#"{"id": 1}"#).0, 404, "no images set yet");
    v.set_images(src);
    assert_eq!(post(&v, "/api/image", r#"{"id": 2}"#).0, 403);
}

/// A run folder `dir/out` whose `report.json` names its input `dir/seq`,
/// which holds the pictures of a small demo model.
fn run_folder(dir: &Path) -> (Reconstruction, PathBuf, PathBuf) {
    let input = dir.join("seq");
    let rec = demo_reconstruction(3, 30, 1).expect("demo");
    write_pictures(&rec, &input);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).expect("mkdir");
    std::fs::write(out.join("report.json"), serde_json::json!({ "input": input }).to_string()).expect("report");
    (rec, input, out)
}

#[test]
fn a_run_report_names_the_input_and_its_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (rec, input, out) = run_folder(dir.path());
    match ImageSource::discover(&out, &rec) {
        ImageSource::Sequence { files, .. } => {
            assert_eq!(files.get("frame_000001.png"), Some(&input.join("frame_000001.png")));
            assert_eq!(files.len(), 3);
        }
        other => panic!("expected the run's input, got {other:?}"),
    }
    // From a map below the run folder too.
    let map = out.join("maps/1");
    std::fs::create_dir_all(&map).expect("mkdir");
    assert!(matches!(ImageSource::discover(&map, &rec), ImageSource::Sequence { .. }));
    let given = ImageSource::given(&dir.path().join("nope")).expect_err("missing folder");
    assert!(given.to_string().contains("nope"), "{given}");
}

#[test]
fn a_run_report_gives_the_frames_times_to_the_ground_truth_layer() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (rec, input, out) = run_folder(dir.path());
    // A TUM list: the frames' times are in rgb.txt, not in their names.
    let mut names: Vec<String> =
        rec.registered_image_ids().iter().filter_map(|id| rec.image(*id)).map(|i| i.name.clone()).collect();
    names.sort();
    let list: String = names.iter().enumerate().map(|(k, n)| format!("{} {n}\n", 100.5 + 0.1 * k as f64)).collect();
    std::fs::write(input.join("rgb.txt"), list).expect("rgb.txt");
    let source = ImageSource::discover(&out, &rec);
    assert_eq!(source.timestamp(&names[1]), Some(100.6), "{source:?}");
    // A ground truth in the list's times: the cameras' own poses.
    let stamp_of = |n: &str| source.timestamp(n);
    let (est, _) = export::model_trajectory_timed(&rec, &stamp_of);
    assert_eq!(est.stamps.first().copied(), Some(100.5));
    let layer = GroundTruthLayer::compute_timed(&rec, &est, "gt.tum", &stamp_of).expect("layer");
    assert_eq!(layer.matched, 3);
    assert!(layer.ate_rmse < 1e-9, "{}", layer.ate_rmse);
    // The names alone hold no such times: nothing would be compared.
    assert!(GroundTruthLayer::compute(&rec, &est, "gt.tum").is_err());
    // The page's camera info gives the listed time too.
    let id = rec.registered_image_ids().iter().find(|i| rec.image(**i).is_some_and(|im| im.name == names[1]));
    let id = id.expect("the second frame's image").0;
    let v = start();
    v.set_reconstruction(&rec);
    v.set_images(source);
    assert_eq!(get_json(&v, &format!("/api/camera?id={id}")).1["timestamp"], 100.6);
}

#[test]
fn the_ground_truth_layer_reaches_the_page() {
    let rec = demo_reconstruction(6, 40, 2).expect("demo");
    // Ground truth: the camera centres scaled by 2 and shifted, one moved.
    let (est, _) = export::model_trajectory_timed(&rec, &|_| None);
    let mut gt = est.clone();
    for (i, p) in gt.poses.iter_mut().enumerate() {
        p.translation = p.translation * 2.0 + colslam_geometry::Vec3::new(1.0, 2.0, 3.0);
        if i == 3 {
            p.translation.y += 0.1;
        }
    }
    let layer = GroundTruthLayer::compute(&rec, &gt, "gt.tum").expect("layer");
    // The numbers of `colslam eval` on the model's TUM export.
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("est.tum"), tum_trajectory(&rec)).expect("est");
    gt.write_tum(&dir.path().join("gt.tum")).expect("gt");
    let report = colslam_eval::evaluate_files(
        &dir.path().join("gt.tum"),
        &dir.path().join("est.tum"),
        &colslam_eval::EvalOptions::default(),
    )
    .expect("eval");
    assert!((layer.ate_rmse - report.ate_rmse).abs() <= 1e-12 * report.ate_rmse.max(1.0), "{layer:?}");
    assert!(layer.ate_rmse > 0.0);
    assert_eq!((layer.matched, layer.errors.len(), layer.path.len()), (6, 6, 6));
    assert!((layer.scale - 2.0).abs() < 0.05, "{}", layer.scale);
    // Worst camera: the one moved.
    let worst = layer.errors.iter().max_by(|a, b| a.1.total_cmp(&b.1)).expect("errors");
    assert_eq!(worst.0, 4);
    let v = start();
    v.set_reconstruction(&rec);
    v.set_ground_truth(Some(layer.clone()));
    let snap = get_json(&v, "/api/state").1;
    assert_eq!(snap["gt"]["ate_rmse"], layer.ate_rmse);
    assert_eq!(snap["gt"]["path"].as_array().map(Vec::len), Some(18));
    v.set_reconstruction(&rec);
    assert_eq!(get_json(&v, "/api/state").1["gt"], Value::Null, "a new model drops the old ground truth");
}

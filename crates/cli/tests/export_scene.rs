//! `colslam export -f 3dgs|nerfstudio` end to end (issue 18): runs on the
//! synthetic sequence and on tum_fr1_rpy_sub (FULL_OPENCV, k1 0.26, k3 1.16),
//! exports them and checks the outputs independently in the peer venv
//! (`tests/peer/check_export.py`: pycolmap, numpy, OpenCV): the model reads,
//! names and files agree, the nerfstudio convention projects the points
//! where pycolmap projects them with the run's camera (and so onto the
//! keypoints up to the run's own residual), the undistorted images match
//! OpenCV's undistortion; `--frames keyframes` gives exactly the keyframes;
//! bad inputs give errors naming the file.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{fails, ok};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn check(py: &Path, kind: &str, out: &Path, run: &Path) -> Value {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/peer/check_export.py");
    let text = colslam_testutil::run_python(py, &[script, kind, s(out), s(run)]);
    eprintln!("{kind} {}: {text}", out.display());
    serde_json::from_str(text.trim()).expect("one JSON object")
}

fn report(run: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("report.json")).expect("report")).expect("json")
}

/// Lines of a run's trajectory.tum: its localised frames.
fn localized(run: &Path) -> u64 {
    let text = std::fs::read_to_string(run.join("trajectory.tum")).expect("trajectory");
    text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()).count() as u64
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// What both datasets must show: counts, names, sizes, the nerfstudio
/// convention. Returns the 3dgs and nerfstudio checks.
fn check_both(py: &Path, run: &Path, root: &Path, frames: &str) -> (Value, Value) {
    let rep = report(run);
    let keyframes = rep["keyframes"].as_u64().expect("keyframes");
    let expected = if frames == "all" { localized(run) } else { keyframes };
    let gs = root.join(format!("gs-{frames}"));
    let ns = root.join(format!("ns-{frames}"));
    ok(&["-q", "export", s(run), "-f", "3dgs", "-o", s(&gs), "--frames", frames]);
    ok(&["-q", "export", s(run), "-f", "nerfstudio", "-o", s(&ns), "--frames", frames]);

    let g = check(py, "3dgs", &gs, run);
    assert_eq!(g["camera_model"], "PINHOLE");
    assert_eq!(g["cameras"], 1);
    assert_eq!(g["images"].as_u64(), Some(expected), "{g}");
    assert_eq!(g["images_with_observations"].as_u64(), Some(keyframes), "{g}");
    assert_eq!(g["names_equal_files"], true, "images/ must hold exactly the model's images: {g}");
    assert_eq!(g["bad_size"], serde_json::json!([]), "{g}");
    assert!(g["points"].as_u64().unwrap_or(0) > 100, "{g}");
    // Keypoints undistorted with the camera: the points reproject as in the run.
    assert!(f(&g["reprojection"]["mean"]) < 2.0, "{g}");

    let n = check(py, "nerfstudio", &ns, run);
    assert_eq!(n["missing_keys"], serde_json::json!([]), "{n}");
    assert_eq!(n["missing_files"], serde_json::json!([]), "{n}");
    assert_eq!(n["bad_size"], serde_json::json!([]), "{n}");
    assert_eq!(n["frames"].as_u64(), Some(expected), "{n}");
    assert_eq!(n["behind_camera"], 0, "{n}");
    assert_eq!(n["ply_points"].as_u64(), Some(rep["points"].as_u64().expect("points")), "{n}");
    // float32 PLY coordinates of the rotated points.
    assert!(f(&n["ply_max_diff"]) < 1e-4, "sparse_pc.ply is not in the transforms' world: {n}");
    assert_eq!(n["to_keypoints"]["n"].as_u64(), Some(rep["observations"].as_u64().expect("observations")));
    // The convention: nerfstudio's projection equals pycolmap's with the
    // run's camera, so it lands on the keypoints up to the run's residual.
    assert!(f(&n["to_pycolmap"]["max"]) < 1e-4, "{n}");
    assert!(f(&n["to_keypoints"]["mean"]) < 2.0, "{n}");
    (g, n)
}

#[test]
fn synthetic_run_exports_for_splatting_and_nerfstudio() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "cv2", "numpy"]) else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let (seq, run) = (dir.path().join("seq"), dir.path().join("run"));
    ok(&["-q", "demo", "--generate-only", "-o", s(&seq), "--frames", "40", "--width", "320", "--height", "240"]);
    ok(&["-q", "run", s(&seq), "-o", s(&run)]);
    let (g, n) = check_both(&py, &run, dir.path(), "all");
    assert_eq!(n["camera_model"], "OPENCV");
    // A synthetic run: the SLAM residual itself is sub-pixel, and the typical
    // observation lies within the 0.5 px of its exported projection
    // (the mean carries the map's own residual, up to its 4 px filter).
    assert!(f(&n["to_keypoints"]["mean"]) < 1.0, "{n}");
    assert!(f(&n["to_keypoints"]["median"]) < 0.5, "{n}");
    assert!(f(&g["reprojection"]["mean"]) < 1.0, "{g}");
    check_both(&py, &run, dir.path(), "keyframes");

    // Deterministic: the same export twice gives the same files.
    let again = dir.path().join("ns-again");
    ok(&["-q", "export", s(&run), "-f", "nerfstudio", "-o", s(&again)]);
    for file in ["transforms.json", "sparse_pc.ply"] {
        let a = std::fs::read(dir.path().join("ns-all").join(file)).expect("first");
        assert!(a == std::fs::read(again.join(file)).expect("second"), "{file} differs");
    }
    // The other format into the same folder replaces it as a whole.
    ok(&["-q", "export", s(&run), "-f", "3dgs", "-o", s(&again)]);
    let mut names: Vec<String> = std::fs::read_dir(&again)
        .expect("ls")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["images", "sparse"]);

    // The input moved: --images names its new place.
    let moved = dir.path().join("moved");
    std::fs::rename(&seq, &moved).expect("move the input");
    let err = fails(&["export", s(&run), "-f", "3dgs", "-o", s(&dir.path().join("x"))]);
    assert!(err.contains(s(&seq)) && err.contains("--images"), "{err}");
    let out = ok(&["export", s(&run), "-f", "3dgs", "-o", s(&dir.path().join("x")), "--images", s(&moved)]);
    assert!(out.contains(&format!("{} frames", localized(&run))), "{out}");
}

#[test]
fn tum_run_exports_undistorted_and_opencv() {
    let Some(data) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "cv2", "numpy"]) else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("run");
    // The first 60 frames: the other 140 of the input have no pose and are left out.
    ok(&["-q", "run", s(&data), "-o", s(&run), "--max-frames", "60"]);
    let (g, n) = check_both(&py, &run, dir.path(), "all");
    assert_eq!(g["run_camera_model"], "FULL_OPENCV");
    // COLMAP's choice of the undistorted camera keeps only valid pixels.
    let (w, h) = (g["width"].as_u64().expect("w"), g["height"].as_u64().expect("h"));
    assert!(w < 640 && h < 480 && w > 500 && h > 380, "{g}");
    assert!(f(&g["opencv_valid_fraction"]) > 0.99, "{g}");
    assert!(g["opencv_undistort_mean_abs"]["n"].as_u64().unwrap_or(0) >= 10, "{g}");
    assert!(f(&g["opencv_undistort_mean_abs"]["max"]) < 1.0, "undistortion differs from OpenCV's: {g}");
    // FULL_OPENCV without rational terms is OPENCV with k3 for nerfstudio,
    // and the images keep their distortion.
    assert_eq!(n["camera_model"], "OPENCV");
    let meta: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("ns-all").join("transforms.json")).expect("transforms"),
    )
    .expect("json");
    assert!((f(&meta["k3"]) - 1.1633).abs() < 1e-12 && (f(&meta["k1"]) - 0.2624).abs() < 1e-12, "{meta}");
    assert_eq!((meta["w"].as_u64(), meta["h"].as_u64()), (Some(640), Some(480)));
    let first = meta["frames"][0]["file_path"].as_str().expect("file_path");
    let name = first.strip_prefix("images/").expect("images/");
    let source = data.join("rgb").join(name);
    assert!(
        std::fs::read(source).expect("source image")
            == std::fs::read(dir.path().join("ns-all").join(first)).expect("exported"),
        "{first}: nerfstudio images are the source files"
    );
}

#[test]
fn video_frames_are_extracted_as_png() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "cv2", "numpy"]) else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let (seq, run) = (dir.path().join("seq"), dir.path().join("run"));
    ok(&["-q", "demo", "--generate-only", "-o", s(&seq), "--frames", "40", "--width", "320", "--height", "240"]);
    // A lossless video of the sequence, with its camera file beside it.
    let video = dir.path().join("video").join("seq.mkv");
    std::fs::create_dir_all(video.parent().expect("parent")).expect("mkdir");
    std::fs::copy(seq.join("camera.yaml"), dir.path().join("video").join("camera.yaml")).expect("camera");
    let pattern = seq.join("rgb").join("%06d.png");
    let ff = Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-nostdin", "-framerate", "30", "-i", s(&pattern), "-c:v", "ffv1", s(&video)])
        .output()
        .expect("run ffmpeg");
    assert!(ff.status.success(), "{}", String::from_utf8_lossy(&ff.stderr));
    // The pinhole kept as given (no radial term estimated), so the exported
    // frames are the decoded ones, not undistorted (that is the TUM test's).
    ok(&["-q", "run", s(&video), "-o", s(&run), "--refine-distortion", "false"]);
    let (g, _) = check_both(&py, &run, dir.path(), "all");
    assert!(g["images"].as_u64().unwrap_or(0) >= 30, "{g}");
    let names: Vec<String> = std::fs::read_dir(dir.path().join("gs-all").join("images"))
        .expect("ls")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| n.starts_with("frame_") && n.ends_with(".png") && n.len() == 16), "{names:?}");
    // Lossless: an extracted frame is the source frame.
    let a =
        colslam_image::Image::read(&dir.path().join("gs-all").join("images").join("frame_000020.png")).expect("png");
    let b = colslam_image::Image::read(&seq.join("rgb").join("000020.png")).expect("source");
    assert!(a.to_rgb().data() == b.to_rgb().data(), "frame_000020.png differs from the source frame");
}

/// A run folder whose report names `input`.
fn run_with_input(from: &Path, to: &Path, input: &Path) -> PathBuf {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("ls").flatten() {
        std::fs::copy(e.path(), to.join(e.file_name())).expect("copy");
    }
    let mut rep = report(from);
    rep["input"] = Value::String(s(input).to_string());
    std::fs::write(to.join("report.json"), rep.to_string()).expect("write report");
    to.to_path_buf()
}

#[test]
fn bad_inputs_name_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (seq, run) = (dir.path().join("seq"), dir.path().join("run"));
    ok(&["-q", "demo", "--generate-only", "-o", s(&seq), "--frames", "30", "--width", "160", "--height", "120"]);
    ok(&["-q", "run", s(&seq), "-o", s(&run)]);
    let out = dir.path().join("out");

    // Not a run: the missing file is named.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).expect("mkdir");
    let err = fails(&["export", s(&empty), "-f", "3dgs", "-o", s(&out)]);
    assert!(err.contains("not a colslam run folder") && err.contains("report.json"), "{err}");
    let err = fails(&["export", s(&seq), "-f", "nerfstudio", "-o", s(&out)]);
    assert!(err.contains("not a colslam run folder"), "{err}");

    // An output that is a file.
    let file = dir.path().join("file");
    std::fs::write(&file, "x").expect("write");
    let err = fails(&["export", s(&run), "-f", "3dgs", "-o", s(&file)]);
    assert!(err.contains("not a folder"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).expect("file"), "x");

    // A missing input.
    let gone = run_with_input(&run, &dir.path().join("run-gone"), &dir.path().join("gone"));
    let err = fails(&["export", s(&gone), "-f", "nerfstudio", "-o", s(&out)]);
    assert!(err.contains("gone") && err.contains("no such file"), "{err}");

    // Another input: the keyframes are not among its frames.
    let other = dir.path().join("other");
    ok(&["-q", "demo", "--generate-only", "-o", s(&other), "--frames", "5", "--width", "160", "--height", "120"]);
    let wrong = run_with_input(&run, &dir.path().join("run-wrong"), &other);
    let err = fails(&["export", s(&wrong), "-f", "3dgs", "-o", s(&out)]);
    assert!(err.contains("is not the run's input") && err.contains("keyframes"), "{err}");

    // An unreadable frame: its name and the input in the message, no output.
    // (A frame in the middle of the sequence, which the run localised.)
    let name = "000015.png";
    std::fs::write(seq.join("rgb").join(name), b"not a png").expect("corrupt");
    let err = fails(&["export", s(&run), "-f", "3dgs", "-o", s(&out)]);
    assert!(err.contains(name) && err.contains(s(&seq)), "{err}");
    assert!(!out.exists(), "a failed export leaves no output");

    // --frames/--images belong to the scene formats.
    let err = fails(&["export", s(&run), "-f", "bin", "-o", s(&out), "--frames", "keyframes"]);
    assert!(err.contains("--frames"), "{err}");
}

/// A run that ended with two maps: `--map 1` exports `maps/1/` (here the
/// same model with only its keyframes in the trajectory, so the two exports
/// differ), map 0 stays the default, a map the run lacks is named.
#[test]
fn a_second_map_is_exported_with_map() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (seq, run) = (dir.path().join("seq"), dir.path().join("run"));
    ok(&["-q", "demo", "--generate-only", "-o", s(&seq), "--frames", "30", "--width", "160", "--height", "120"]);
    ok(&["-q", "run", s(&seq), "-o", s(&run)]);
    let second = run.join("maps").join("1");
    std::fs::create_dir_all(&second).expect("mkdir");
    for name in ["cameras.bin", "images.bin", "points3D.bin"] {
        std::fs::copy(run.join(name), second.join(name)).expect("copy");
    }
    std::fs::copy(run.join("keyframes.tum"), second.join("trajectory.tum")).expect("copy");
    let keyframes = localized(&second) as usize;

    let frames = |out: &str| std::fs::read_dir(dir.path().join(out).join("images")).expect("images").count();
    ok(&["-q", "export", s(&run), "-f", "3dgs", "-o", s(&dir.path().join("m0"))]);
    ok(&["-q", "export", s(&run), "-f", "3dgs", "-o", s(&dir.path().join("m1")), "--map", "1"]);
    assert_eq!(frames("m0"), localized(&run) as usize, "map 0 exports every localised frame");
    assert_eq!(frames("m1"), keyframes, "--map 1 exports maps/1, whose trajectory holds the keyframes only");

    let err = fails(&["export", s(&run), "-f", "3dgs", "-o", s(&dir.path().join("m2")), "--map", "2"]);
    assert!(err.contains("no map 2") && err.contains("2 map(s)"), "{err}");
    let err = fails(&["export", s(&run), "-f", "bin", "-o", s(&dir.path().join("m3")), "--map", "1"]);
    assert!(err.contains("--map"), "{err}");
}

//! Camera files: dataset files, every syntax, round trips and every error case.

mod common;

use std::path::{Path, PathBuf};

use colslam_camera::file::{CameraFileFormat, read_camera_file, read_camera_file_report, write_camera_file};
use colslam_camera::{Camera, CameraModelId};

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn all_dataset_camera_files_parse() {
    let Some(data) = colslam_testutil::data_dir() else { return };
    let mut n = 0;
    for entry in std::fs::read_dir(&data).unwrap() {
        let path = entry.unwrap().path().join("camera.yaml");
        if !path.exists() {
            continue;
        }
        let rep = read_camera_file_report(&path).unwrap_or_else(|e| panic!("{e}"));
        rep.camera.validate().unwrap();
        eprintln!("{}: {:?} {:?}", path.display(), rep.camera, rep.unknown_keys);
        n += 1;
        let dir = path.parent().and_then(|p| p.file_name()).and_then(|s| s.to_str()).unwrap_or("");
        if dir == "tum_fr1_rpy_sub" {
            assert_eq!(rep.camera, common::tum_fr1());
            assert_eq!(rep.fps, Some(30.0));
            assert!(rep.unknown_keys.is_empty(), "{:?}", rep.unknown_keys);
        } else if dir.starts_with("strecha") {
            assert_eq!(rep.camera.model, CameraModelId::Pinhole);
            assert_eq!((rep.camera.width, rep.camera.height), (1536, 1024));
        }
    }
    assert!(n >= 5, "only {n} camera.yaml files found under {}", data.display());
}

#[test]
fn write_read_round_trip_every_model() {
    let dir = tempfile::tempdir().unwrap();
    for (name, cam) in common::cameras() {
        let p = dir.path().join(format!("{name}.yaml"));
        write_camera_file(&cam, &p).unwrap();
        let back = read_camera_file(&p).unwrap();
        assert_eq!(back, cam, "{name}");
    }
    // Writing an invalid camera fails and names the key.
    let bad = Camera::pinhole(640, 480, -1.0, 500.0, 320.0, 240.0);
    let p = dir.path().join("bad.yaml");
    let e = write_camera_file(&bad, &p).unwrap_err().to_string();
    assert!(e.contains("bad.yaml") && e.contains("fx"), "{e}");
    assert!(!p.exists());
}

#[test]
fn accepted_syntaxes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // COLMAP name with a params list.
    let p = write(d, "a.yaml", "model: SIMPLE_RADIAL\nwidth: 100\nheight: 80\nparams: [90, 50, 40, -0.1]\n");
    let c = read_camera_file(&p).unwrap();
    assert_eq!(c, Camera::new(CameraModelId::SimpleRadial, 100, 80, vec![90.0, 50.0, 40.0, -0.1]).unwrap());
    // COLMAP numeric id and named keys, TOML-style with quotes and a table header.
    let p = write(
        d,
        "b.toml",
        "# camera\n[camera]\nmodel = \"OPENCV\"\nwidth = 752\nheight = 480\nfx = 458.654\nfy = 457.296\ncx = 367.215\n\
         cy = 248.375\nk1 = -0.28\nk2 = 0.07\np1 = 0.0002\np2 = 1.7e-5\nrate_hz = 20\n",
    );
    let rep = read_camera_file_report(&p).unwrap();
    assert_eq!(rep.format, CameraFileFormat::Toml);
    assert_eq!(rep.camera.model, CameraModelId::OpenCv);
    assert_eq!(rep.camera.params[7], 1.7e-5);
    assert_eq!(rep.unknown_keys, vec!["rate_hz".to_string()]);
    let p = write(d, "c.yaml", "model: 5\nwidth: 64\nheight: 64\nparams: 30 32 32 30 0.01 0 0 0\n");
    assert_eq!(read_camera_file(&p).unwrap().model, CameraModelId::OpenCvFisheye);
    // PINHOLE_RADTAN with k3 == 0 is OPENCV; with k3 it is FULL_OPENCV.
    let radtan = "model: PINHOLE_RADTAN\nwidth: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\nk1: 0.1\nk2: -0.2\np1: 0.001\np2: 0.002\n";
    let p = write(d, "d.yaml", &format!("{radtan}k3: 0.0\n"));
    assert_eq!(read_camera_file(&p).unwrap().model, CameraModelId::OpenCv);
    let p = write(d, "e.yaml", &format!("{radtan}k3: 0.5\n"));
    let c = read_camera_file(&p).unwrap();
    assert_eq!(c.model, CameraModelId::FullOpenCv);
    assert_eq!(&c.params[4..], &[0.1, -0.2, 0.001, 0.002, 0.5, 0.0, 0.0, 0.0]);
    // PINHOLE with non-zero distortion keys keeps the distortion.
    let p = write(d, "f.yaml", &radtan.replace("PINHOLE_RADTAN", "PINHOLE"));
    assert_eq!(read_camera_file(&p).unwrap().model, CameraModelId::OpenCv);
    // PINHOLE with zero distortion keys stays PINHOLE.
    let p = write(d, "g.yaml", "model: PINHOLE\nwidth: 10\nheight: 10\nfx: 9\nfy: 9\ncx: 5\ncy: 5\nk1: 0\nk2: 0\n");
    let rep = read_camera_file_report(&p).unwrap();
    assert_eq!(rep.camera.model, CameraModelId::Pinhole);
    assert!(rep.unknown_keys.is_empty());
}

#[test]
fn orb_slam_settings_files() {
    let dir = tempfile::tempdir().unwrap();
    // ORB-SLAM2 TUM1.yaml style (plus a size, which ORB-SLAM2 lacks).
    let orb2 = "%YAML:1.0\n\n# Camera Parameters\nCamera.fx: 517.306408\nCamera.fy: 516.469215\nCamera.cx: 318.643040\n\
                Camera.cy: 255.313989\n\nCamera.k1: 0.262383\nCamera.k2: -0.953104\nCamera.p1: -0.005358\nCamera.p2: 0.002628\n\
                Camera.k3: 1.163314\n\nCamera.width: 640\nCamera.height: 480\nCamera.fps: 30.0\nCamera.RGB: 1\n\n\
                ORBextractor.nFeatures: 1000\nViewer.KeyFrameSize: 0.05\n";
    let p = write(dir.path(), "TUM1.yaml", orb2);
    let rep = read_camera_file_report(&p).unwrap();
    assert_eq!(rep.format, CameraFileFormat::OrbSlam);
    assert_eq!(rep.camera.model, CameraModelId::FullOpenCv);
    assert_eq!(rep.camera.params[8], 1.163314);
    assert_eq!(rep.fps, Some(30.0));
    assert!(rep.unknown_keys.contains(&"ORBextractor.nFeatures".to_string()));
    // ORB-SLAM3 style: Camera1.*, Camera.type, KannalaBrandt8, matrices.
    let orb3 = "%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"KannalaBrandt8\"\nCamera1.fx: 190.97\nCamera1.fy: 190.97\n\
                Camera1.cx: 254.93\nCamera1.cy: 256.90\nCamera1.k1: 0.0034\nCamera1.k2: 0.0007\nCamera1.k3: -0.0020\n\
                Camera1.k4: 0.0002\nCamera2.fx: 191.0\nCamera.width: 512\nCamera.height: 512\n\
                Stereo.T_c1_c2: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: f\n  data: [1.0, 0.0, 0.0, 0.1,\n         0.0, 1.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n         0, 0, 0, 1.0]\n";
    let p = write(dir.path(), "TUM_VI.yaml", orb3);
    let c = read_camera_file(&p).unwrap();
    assert_eq!(c.model, CameraModelId::OpenCvFisheye);
    assert_eq!(c.params, vec![190.97, 190.97, 254.93, 256.90, 0.0034, 0.0007, -0.0020, 0.0002]);
    // ORB-SLAM PinHole without distortion keys.
    let p = write(
        dir.path(),
        "pin.yaml",
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.width: 640\nCamera.height: 480\n",
    );
    assert_eq!(read_camera_file(&p).unwrap().model, CameraModelId::Pinhole);
}

/// Reads `text` from a file and checks the error names the file, the key
/// and contains `what`.
fn check_error(text: &str, key: &str, what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "cam_under_test.yaml", text);
    let e = read_camera_file(&p).expect_err(text).to_string();
    assert!(e.contains("cam_under_test.yaml"), "error does not name the file: {e}");
    assert!(e.contains(&format!("`{key}`")), "error does not name key `{key}`: {e}");
    assert!(e.contains(what), "error lacks {what:?}: {e}");
}

const GOOD: &str = "model: PINHOLE\nwidth: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n";

#[test]
fn error_missing_parameter() {
    check_error(&GOOD.replace("fy: 500\n", ""), "fy", "missing parameter");
    check_error(
        "model: PINHOLE_RADTAN\nwidth: 640\nheight: 480\nfx: 5\nfy: 5\ncx: 3\ncy: 3\nk1: 0\nk2: 0\np1: 0\n",
        "p2",
        "missing",
    );
    check_error(
        "%YAML:1.0\nCamera.fx: 5\nCamera.fy: 5\nCamera.cx: 3\nCamera.cy: 3\nCamera.height: 480\n",
        "Camera.width",
        "missing",
    );
    check_error(&GOOD.replace("width: 640\n", ""), "width", "missing");
    check_error(&GOOD.replace("model: PINHOLE\n", ""), "model", "missing");
}

#[test]
fn error_non_positive_focal() {
    check_error(&GOOD.replace("fx: 500", "fx: -500"), "fx", "focal length must be positive");
    check_error(&GOOD.replace("fy: 500", "fy: 0"), "fy", "focal length must be positive");
    check_error(
        "%YAML:1.0\nCamera.fx: 0\nCamera.fy: 5\nCamera.cx: 3\nCamera.cy: 3\nCamera.width: 6\nCamera.height: 6\n",
        "Camera.fx",
        "positive",
    );
}

#[test]
fn error_bad_size() {
    check_error(&GOOD.replace("width: 640", "width: 0"), "width", "positive integer");
    check_error(&GOOD.replace("height: 480", "height: -480"), "height", "positive integer");
    check_error(&GOOD.replace("height: 480", "height: 480.5"), "height", "positive integer");
    check_error(&GOOD.replace("height: 480", "height: big"), "height", "positive integer");
}

#[test]
fn error_non_finite() {
    check_error(&GOOD.replace("fx: 500", "fx: nan"), "fx", "not finite");
    check_error(&GOOD.replace("cy: 240", "cy: inf"), "cy", "not finite");
    check_error("model: SIMPLE_PINHOLE\nwidth: 6\nheight: 6\nparams: [5, NaN, 3]\n", "params", "not finite");
}

#[test]
fn error_principal_point_far_outside() {
    check_error(&GOOD.replace("cx: 320", "cx: 5000"), "cx", "far outside");
    check_error(&GOOD.replace("cy: 240", "cy: -2000"), "cy", "far outside");
}

#[test]
fn error_unknown_model() {
    check_error(&GOOD.replace("PINHOLE", "THIN_PRISM_FISHEYE"), "model", "unknown camera model");
    check_error(&GOOD.replace("PINHOLE", "42"), "model", "unknown camera model");
}

#[test]
fn error_non_numeric_value() {
    check_error(&GOOD.replace("cx: 320", "cx: 320px"), "cx", "expected a number");
    check_error("model: SIMPLE_PINHOLE\nwidth: 6\nheight: 6\nparams: [5, x, 3]\n", "params", "expected a number");
    check_error(
        "model = PINHOLE\nwidth = 640\nheight = 480\nfx = 5\nfy = \"five\"\ncx = 3\ncy = 3\n",
        "fy",
        "expected a number",
    );
}

#[test]
fn error_wrong_param_count_duplicate_and_syntax() {
    check_error("model: RADIAL\nwidth: 6\nheight: 6\nparams: [5, 3, 3]\n", "params", "takes 5 parameters");
    check_error(&format!("{GOOD}fx: 400\n"), "fx", "more than once");
    check_error(&format!("{GOOD}this line has no separator\n"), "(line 8)", "expected `key: value`");
}

#[test]
fn error_unreadable_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("does_not_exist.yaml");
    let e = read_camera_file(&p).unwrap_err().to_string();
    assert!(e.contains("does_not_exist.yaml") && e.contains("cannot read"), "{e}");
    // A directory is unreadable as a file too.
    let e = read_camera_file(dir.path()).unwrap_err().to_string();
    assert!(e.contains("cannot read"), "{e}");
    // Binary garbage.
    let p = dir.path().join("binary.yaml");
    std::fs::write(&p, [0xff, 0xfe, 0x00, 0x80]).unwrap();
    let e = read_camera_file(&p).unwrap_err().to_string();
    assert!(e.contains("binary.yaml") && e.contains("UTF-8"), "{e}");
}

#[test]
fn euroc_kalibr_sensor_yaml() {
    let dir = tempfile::tempdir().unwrap();
    let text = "%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\n\n\
                # Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,\n\
                \x20        0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,\n         0.0, 0.0, 0.0, 1.0]\n\n\
                # Camera specific definitions.\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n\
                intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\ndistortion_model: radial-tangential\n\
                distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n";
    // EuRoC files start with `%YAML:1.0`; also try without the header.
    for (name, t) in [("sensor.yaml", text.to_string()), ("plain.yaml", text.replace("%YAML:1.0\n", ""))] {
        let p = write(dir.path(), name, &t);
        let c = read_camera_file(&p).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(c.model, CameraModelId::OpenCv, "{name}");
        assert_eq!((c.width, c.height), (752, 480));
        assert_eq!(
            c.params,
            vec![458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
        );
    }
    // Equidistant (TUM-VI Kalibr) and a bad list.
    let equi = "camera_model: pinhole\nresolution: [512, 512]\nintrinsics: [190.97, 190.97, 254.93, 256.90]\n\
                distortion_model: equidistant\ndistortion_coefficients: [0.0034, 0.0007, -0.0020, 0.0002]\n";
    let p = write(dir.path(), "equi.yaml", equi);
    assert_eq!(read_camera_file(&p).unwrap().model, CameraModelId::OpenCvFisheye);
    check_error(
        &equi.replace("[190.97, 190.97, 254.93, 256.90]", "[190.97, 190.97, 254.93]"),
        "intrinsics",
        "expected 4 values",
    );
    check_error(&equi.replace("equidistant", "omni"), "distortion_model", "unknown distortion model");
}

#[test]
fn refined_over_round_trip_and_range() {
    let dir = tempfile::tempdir().unwrap();
    let cam = Camera::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0);
    // A run that refined the intrinsics says over how many images.
    let text = colslam_camera::file::to_run_yaml_string(&cam, 0.0, Some(79));
    let rep = read_camera_file_report(&write(dir.path(), "r.yaml", &text)).unwrap();
    assert_eq!((rep.camera, rep.refined_over, rep.readout_s), (cam.clone(), Some(79), None));
    assert!(rep.unknown_keys.is_empty(), "{:?}", rep.unknown_keys);
    let text = colslam_camera::file::to_run_yaml_string(&cam, 0.0, None);
    assert!(!text.contains("refined_over"), "{text}");
    assert_eq!(read_camera_file_report(&write(dir.path(), "c.yaml", &text)).unwrap().refined_over, None);
    check_error(&format!("{GOOD}refined_over: 0\n"), "refined_over", "positive integer");
    check_error(&format!("{GOOD}refined_over: 2.5\n"), "refined_over", "positive integer");
}

#[test]
fn readout_time_round_trip_and_range() {
    let dir = tempfile::tempdir().unwrap();
    let cam = Camera::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0);
    // A run that compensated a readout writes it; the file gives it back.
    let text = colslam_camera::file::to_run_yaml_string(&cam, 0.0333, None);
    let rep = read_camera_file_report(&write(dir.path(), "rs.yaml", &text)).unwrap();
    assert_eq!((rep.camera, rep.readout_s), (cam.clone(), Some(0.0333)));
    assert!(rep.unknown_keys.is_empty(), "{:?}", rep.unknown_keys);
    // A global-shutter run writes no readout.
    let text = colslam_camera::file::to_run_yaml_string(&cam, 0.0, None);
    assert!(!text.contains("readout"), "{text}");
    let rep = read_camera_file_report(&write(dir.path(), "gs.yaml", &text)).unwrap();
    assert_eq!(rep.readout_s, None);
    check_error(&format!("{GOOD}readout_s: 1.5\n"), "readout_s", "[0, 1)");
    check_error(&format!("{GOOD}readout_s: -0.01\n"), "readout_s", "[0, 1)");
}

//! Fuzzing of the camera-file parser and the preset lookup: mutated camera
//! files give a validated camera or an error, never a panic, a hang or a
//! huge allocation; an accepted camera survives its own writer. See
//! `colslam_testutil::fuzz`; the long run is in docs/benchmarks.md
//! ("Fuzzing").

use std::path::Path;

use colslam_camera::file::{parse_camera, to_yaml_string};
use colslam_camera::presets::{preset, preset_names};
use colslam_camera::{Camera, CameraModelId};
use colslam_testutil::fuzz::{Corpus, fuzz};

colslam_testutil::fuzz_allocator!();

/// Inputs per parser in the default test run.
const CI_ITERS: u64 = 6_000;

/// A camera of `model` with plausible parameters (focal 500, centre of a
/// 640x480 image, small distortion).
fn plausible(model: CameraModelId) -> Camera {
    let params = model
        .param_name_list()
        .map(|n| match n {
            "f" | "fx" | "fy" => 500.0,
            "cx" => 320.0,
            "cy" => 240.0,
            _ => 0.01,
        })
        .collect();
    Camera::new(model, 640, 480, params).unwrap()
}

/// Files in every accepted syntax: our writer's output for each model and
/// preset, COLMAP params lists, TOML-style, ORB-SLAM 2 and 3 settings,
/// Kalibr `sensor.yaml`.
fn corpus() -> Corpus {
    let mut corpus = Corpus::single("camera.yaml");
    let written = CameraModelId::ALL
        .iter()
        .map(|m| plausible(*m))
        .chain(preset_names().iter().filter_map(|n| preset(n)))
        .map(|c| to_yaml_string(&c));
    for text in written {
        corpus = corpus.sample(text);
    }
    corpus
        .sample("model: SIMPLE_RADIAL\nwidth: 100\nheight: 80\nparams: [90, 50, 40, -0.1]\n")
        .sample("model: 5\nwidth: 64\nheight: 64\nparams: 30 32 32 30 0.01 0 0 0\n")
        .sample(
            "# camera\n[camera]\nmodel = \"OPENCV\"\nwidth = 752\nheight = 480\nfx = 458.654\nfy = 457.296\n\
             cx = 367.215\ncy = 248.375\nk1 = -0.28\nk2 = 0.07\np1 = 0.0002\np2 = 1.7e-5\nrate_hz = 20\n",
        )
        .sample(
            "model: PINHOLE_RADTAN\nwidth: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\nk1: 0.1\n\
             k2: -0.2\np1: 0.001\np2: 0.002\nk3: 0.5\nfps: 30\n",
        )
        .sample(
            "%YAML:1.0\n\n# Camera Parameters\nCamera.fx: 517.306408\nCamera.fy: 516.469215\nCamera.cx: 318.643040\n\
             Camera.cy: 255.313989\n\nCamera.k1: 0.262383\nCamera.k2: -0.953104\nCamera.p1: -0.005358\n\
             Camera.p2: 0.002628\nCamera.k3: 1.163314\n\nCamera.width: 640\nCamera.height: 480\nCamera.fps: 30.0\n\
             Camera.RGB: 1\n\nORBextractor.nFeatures: 1000\n",
        )
        .sample(
            "%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"KannalaBrandt8\"\nCamera1.fx: 190.97\n\
             Camera1.fy: 190.97\nCamera1.cx: 254.93\nCamera1.cy: 256.90\nCamera1.k1: 0.0034\nCamera1.k2: 0.0007\n\
             Camera1.k3: -0.0020\nCamera1.k4: 0.0002\nCamera2.fx: 191.0\nCamera.width: 512\nCamera.height: 512\n\
             Stereo.T_c1_c2: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: f\n  data: [1.0, 0.0, 0.0, 0.1,\n\
             \x20        0.0, 1.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n         0, 0, 0, 1.0]\n",
        )
        .sample(
            "%YAML:1.0\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\nT_BS:\n  cols: 4\n  rows: 4\n\
             \x20 data: [0.0148, -0.9998, 0.0041, -0.0216,\n         0.9995, 0.0149, 0.0257, -0.0646,\n\
             \x20        0.0, 0.0, 0.0, 1.0]\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n\
             intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\n\
             distortion_model: radial-tangential\n\
             distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n",
        )
        .sample(
            "camera_model: pinhole\nresolution: [512, 512]\nintrinsics: [190.97, 190.97, 254.93, 256.90]\n\
             distortion_model: equidistant\ndistortion_coefficients: [0.0034, 0.0007, -0.0020, 0.0002]\n",
        )
        .words(CameraModelId::ALL.map(CameraModelId::name))
        .words([
            "PINHOLE_RADTAN",
            "KannalaBrandt8",
            "PinHole",
            "EQUIDISTANT",
            "model",
            "width",
            "height",
            "params",
            "fx",
            "fy",
            "cx",
            "cy",
            "f",
            "k1",
            "k4",
            "k6",
            "p1",
            "Camera.",
            "Camera1.",
            "Camera2.",
            "Camera.type",
            "%YAML:1.0",
            "fps",
            "intrinsics",
            "resolution",
            "distortion_coefficients",
            "camera_model",
            "none",
            "image_width",
            "[camera]",
            "!!opencv-matrix",
        ])
}

#[test]
fn fuzz_camera_file() {
    let origin = Path::new("fuzz/camera.yaml");
    let report = fuzz("camera-file", &corpus(), CI_ITERS, |parts| {
        // As read_camera_file_report: the bytes must be UTF-8 text.
        let text = std::str::from_utf8(&parts[0]).map_err(|e| e.to_string())?;
        let file = parse_camera(text, origin).map_err(|e| e.to_string())?;
        file.camera.validate().unwrap_or_else(|e| panic!("accepted an invalid camera: {e}"));
        let again = parse_camera(&to_yaml_string(&file.camera), origin)
            .unwrap_or_else(|e| panic!("the written accepted camera does not parse: {e}"));
        assert_eq!(again.camera, file.camera, "the camera changed through its own writer");
        Ok::<_, String>(())
    });
    assert!(report.accepted > report.inputs / 20, "too few accepted inputs to reach deep: {report}");
}

#[test]
fn fuzz_camera_preset() {
    let mut corpus = Corpus::single("preset.txt");
    for name in preset_names() {
        corpus = corpus.sample(name.as_bytes().to_vec());
    }
    let corpus = corpus.sample("TUM_FR1").sample(" kitti-984 ");
    fuzz("camera-preset", &corpus, CI_ITERS, |parts| {
        let cam = preset(&String::from_utf8_lossy(&parts[0])).ok_or("unknown preset")?;
        cam.validate().unwrap_or_else(|e| panic!("preset is invalid: {e}"));
        Ok::<_, &str>(())
    });
}

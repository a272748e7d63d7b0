//! Realistic cameras for every model, shared by the integration tests.
#![allow(dead_code)]

use colslam_camera::{Camera, CameraModelId};

/// TUM fr1 colour camera (Kinect v1), published calibration: strong k3.
pub fn tum_fr1() -> Camera {
    Camera::new(
        CameraModelId::FullOpenCv,
        640,
        480,
        vec![517.3, 516.5, 318.6, 255.3, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633, 0.0, 0.0, 0.0],
    )
    .unwrap()
}

/// One realistic camera (or more) per model, with a label.
pub fn cameras() -> Vec<(&'static str, Camera)> {
    use CameraModelId::*;
    let c = |m, w, h, p: &[f64]| Camera::new(m, w, h, p.to_vec()).unwrap();
    vec![
        ("simple_pinhole", c(SimplePinhole, 640, 480, &[525.0, 319.5, 239.5])),
        ("pinhole", c(Pinhole, 1536, 1024, &[1379.74, 1382.08, 760.095, 503.155])),
        ("simple_radial", c(SimpleRadial, 1024, 768, &[800.0, 512.0, 384.0, -0.08])),
        ("radial", c(Radial, 1242, 375, &[984.0, 621.0, 187.5, -0.12, 0.03])),
        // EuRoC MAV cam0 (radial-tangential).
        (
            "opencv_euroc",
            c(
                OpenCv,
                752,
                480,
                &[458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
            ),
        ),
        ("full_opencv_tum_fr1", tum_fr1()),
        // Rational model (OpenCV CALIB_RATIONAL_MODEL style wide-angle lens).
        (
            "full_opencv_rational",
            c(FullOpenCv, 1280, 720, &[640.0, 641.0, 639.5, 359.5, 2.0, 0.5, 0.0008, -0.0006, 0.01, 2.3, 0.9, 0.05]),
        ),
        // Strong fisheye: ~170° diagonal field of view (corner rays ~86° off axis).
        ("fisheye_strong", c(OpenCvFisheye, 640, 480, &[260.0, 259.0, 320.5, 240.5, -0.01, 0.02, -0.006, 0.0008])),
        // Mild fisheye, TUM-VI-like coefficients on a narrower image.
        (
            "fisheye_tumvi",
            c(
                OpenCvFisheye,
                512,
                512,
                &[300.0, 300.0, 254.93, 256.90, 0.0034823894, 0.0007150348, -0.0020532361, 0.0002029367],
            ),
        ),
    ]
}

/// Dense pixel grid: every 4th pixel, every border pixel (centres in both
/// pixel conventions), and the image corners/edges in both conventions.
pub fn dense_grid(w: u64, h: u64) -> Vec<(f64, f64)> {
    let (wf, hf) = (w as f64, h as f64);
    let axis = |n: u64, nf: f64| {
        let mut v: Vec<f64> = (0..=n).step_by(4).map(|i| i as f64).collect();
        v.extend([-0.5, 0.5, nf - 1.0, nf - 0.5, nf]);
        v
    };
    let (xs, ys) = (axis(w, wf), axis(h, hf));
    let mut out = Vec::new();
    for &y in &ys {
        for &x in &xs {
            out.push((x, y));
        }
    }
    // Every border pixel in both conventions.
    let xb = [-0.5, 0.0, 0.5, wf - 1.0, wf - 0.5, wf];
    let yb = [-0.5, 0.0, 0.5, hf - 1.0, hf - 0.5, hf];
    for i in 0..=w {
        for &y in &yb {
            out.push((i as f64, y));
            out.push((i as f64 + 0.5, y));
        }
    }
    for j in 0..=h {
        for &x in &xb {
            out.push((x, j as f64));
            out.push((x, j as f64 + 0.5));
        }
    }
    out
}

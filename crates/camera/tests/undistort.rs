//! Undistortion: output camera choice, remapping of a synthetic line pattern,
//! point undistortion.

mod common;

use colslam_camera::undistort::{
    UndistortMap, UndistortOptions, UndistortOutput, undistort_points, undistorted_camera,
};
use colslam_camera::{Camera, PixelConvention, Vec2};
use colslam_image::Image;

/// Stripe period in pixels at the image centre.
const PERIOD_PX: f64 = 40.0;

/// Stripe pattern in normalised coordinates: straight lines in the scene
/// (smooth, so bilinear resampling error stays small); `period` in
/// normalised units.
fn pattern(uv: Vec2, period: f64, rgb_channel: usize) -> f64 {
    let tau = std::f64::consts::TAU;
    let a = (tau * uv.x / period).cos();
    let b = (tau * uv.y / (1.5 * period)).cos();
    match rgb_channel {
        0 => 127.5 + 60.0 * a + 60.0 * b,
        1 => 127.5 + 120.0 * a,
        _ => 127.5 + 120.0 * b,
    }
}

/// Renders the pattern (period `period` in normalised units) as seen by
/// `cam` (pixel (i, j) at its COLMAP centre).
fn render(cam: &Camera, period: f64, channels: usize) -> Image {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut img = Image::new(w, h, channels);
    for j in 0..h {
        for i in 0..w {
            let px = Vec2::new(i as f64 + 0.5, j as f64 + 0.5);
            let uv = cam.cam_from_img(&px).unwrap();
            for c in 0..channels {
                img.set(
                    i,
                    j,
                    c,
                    pattern(uv, period, if channels == 1 { 0 } else { c }).round().clamp(0.0, 255.0) as u8,
                );
            }
        }
    }
    img
}

/// Mean absolute difference over pixels the map fills.
fn mean_abs_diff(map: &UndistortMap, a: &Image, b: &Image) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for j in 0..a.height() {
        for i in 0..a.width() {
            if map.source_of(i, j).is_none() {
                continue;
            }
            for c in 0..a.channels() {
                sum += (a.get(i, j, c) as f64 - b.get(i, j, c) as f64).abs();
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

#[test]
fn remapped_lines_come_out_straight() {
    for (name, cam) in common::cameras() {
        if !cam.has_distortion() {
            continue;
        }
        let period = PERIOD_PX / cam.mean_focal();
        for channels in [1, 3] {
            let distorted = render(&cam, period, channels);
            let map = UndistortMap::new(&cam, &UndistortOptions::default()).unwrap();
            let out = map.remap(&distorted).unwrap();
            // What an ideal pinhole camera sees: straight stripes.
            let ideal = render(map.undistorted_camera(), period, channels);
            let err = mean_abs_diff(&map, &out, &ideal);
            assert!(err < 2.0, "{name} ({channels} ch): remapped vs ideal pinhole differ by {err:.2} gray levels");
            // Control: without undistortion (same K, distorted image) the
            // stripes are curved and the difference is large.
            let keep = UndistortMap::new(
                &cam,
                &UndistortOptions { output: UndistortOutput::KeepCalibration, ..Default::default() },
            )
            .unwrap();
            let ideal_keep = render(keep.undistorted_camera(), period, channels);
            let control = mean_abs_diff(&keep, &distorted, &ideal_keep);
            let err_keep = mean_abs_diff(&keep, &keep.remap(&distorted).unwrap(), &ideal_keep);
            assert!(err_keep < 2.0, "{name}: keep-calibration remap error {err_keep:.2}");
            assert!(control > 10.0 * err_keep.max(0.5), "{name}: control difference only {control:.2}");
        }
    }
}

#[test]
fn fit_without_blank_pixels_fills_every_output_pixel() {
    for (name, cam) in common::cameras() {
        let map = UndistortMap::new(&cam, &UndistortOptions::default()).unwrap();
        let frac = map.valid_fraction();
        assert_eq!(frac, 1.0, "{name}: {frac} of output pixels valid with blank_pixels = 0");
        let out = map.undistorted_camera();
        assert_eq!(out.model, colslam_camera::CameraModelId::Pinhole);
        assert_eq!((out.focal_x(), out.focal_y()), (cam.focal_x(), cam.focal_y()), "{name}");
    }
}

#[test]
fn fit_with_all_pixels_keeps_every_source_pixel() {
    let opts = UndistortOptions { blank_pixels: 1.0, ..Default::default() };
    for (name, cam) in common::cameras() {
        if cam.model == colslam_camera::CameraModelId::OpenCvFisheye {
            // A pinhole image cannot hold rays near 90° off axis: the scale
            // clamps at max_scale, so blank_pixels = 1 keeps only part.
            continue;
        }
        let out = undistorted_camera(&cam, &opts).unwrap();
        let (w, h) = (out.width as f64, out.height as f64);
        // Every border pixel centre of the source lands inside the output
        // (up to the rounding of the output size to whole pixels).
        let mut border = Vec::new();
        for i in 0..cam.width {
            border.push(Vec2::new(i as f64 + 0.5, 0.5));
            border.push(Vec2::new(i as f64 + 0.5, cam.height as f64 - 0.5));
        }
        for j in 0..cam.height {
            border.push(Vec2::new(0.5, j as f64 + 0.5));
            border.push(Vec2::new(cam.width as f64 - 0.5, j as f64 + 0.5));
        }
        for p in undistort_points(&cam, &out, &border).into_iter().flatten() {
            assert!(p.x > -1.0 && p.x < w + 1.0 && p.y > -1.0 && p.y < h + 1.0, "{name}: {p:?} outside {w}x{h}");
        }
        // Distorted cameras with barrel distortion need blank pixels then.
        if cam.has_distortion() {
            let map = UndistortMap::with_target(&cam, &out, PixelConvention::Colmap, 0).unwrap();
            assert!(map.valid_fraction() < 1.0, "{name}");
        }
    }
}

#[test]
fn tum_fr1_output_camera() {
    let cam = common::tum_fr1();
    let out = undistorted_camera(&cam, &UndistortOptions::default()).unwrap();
    eprintln!("tum fr1 undistorted (blank 0): {:?} {}x{}", out.params, out.width, out.height);
    assert!(out.width <= 640 && out.width >= 560 && out.height <= 480 && out.height >= 420, "{out:?}");
    let max = UndistortOptions { max_image_size: 320, ..Default::default() };
    let small = undistorted_camera(&cam, &max).unwrap();
    assert!(small.width.max(small.height) == 320, "{small:?}");
    let bad = UndistortOptions { blank_pixels: 1.5, ..Default::default() };
    assert!(undistorted_camera(&cam, &bad).is_err());
    assert!(UndistortOptions { min_scale: 0.0, ..Default::default() }.validate().is_err());
    // Wrong image size is an error, not a panic.
    let map = UndistortMap::new(&cam, &UndistortOptions::default()).unwrap();
    assert!(map.remap(&Image::new(320, 240, 1)).unwrap_err().to_string().contains("320x240"));
}

#[test]
fn map_and_point_undistortion_agree() {
    let cam = common::tum_fr1();
    let map = UndistortMap::new(&cam, &UndistortOptions::default()).unwrap();
    let out = map.undistorted_camera().clone();
    for j in (0..out.height as usize).step_by(37) {
        for i in (0..out.width as usize).step_by(41) {
            let src = map.source_of(i, j).unwrap();
            // Index space -> COLMAP pixel coordinates.
            let src_px = src + Vec2::new(0.5, 0.5);
            let back = map.undistort_points(&[src_px])[0].unwrap();
            let want = Vec2::new(i as f64 + 0.5, j as f64 + 0.5);
            assert!((back - want).norm() < 1e-3, "({i}, {j}): {back:?} vs {want:?}");
            let there = map.distort_points(&[want])[0].unwrap();
            assert!((there - src_px).norm() < 1e-3);
        }
    }
}

//! Acceptance tests of projection, unprojection and Jacobians for every model.

mod common;

use colslam_camera::{Camera, CameraModelId, MAX_PARAMS, Vec2, Vec3};
use colslam_geometry::SplitMix64;

/// Round-trip tolerance in pixels.
const ROUND_TRIP_PX: f64 = 1e-10;
/// Relative tolerance of analytic vs central finite-difference Jacobians.
const JAC_REL: f64 = 1e-6;
/// Columns smaller than this (pixels per unit) are compared absolutely.
const JAC_FLOOR: f64 = 1e-2;

#[test]
fn every_model_is_covered() {
    let cams = common::cameras();
    for m in CameraModelId::ALL {
        assert!(cams.iter().any(|(_, c)| c.model == m), "no test camera for {m}");
    }
    for (name, c) in &cams {
        c.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

#[test]
fn unproject_project_round_trip_dense_grid() {
    for (name, cam) in common::cameras() {
        let f = cam.mean_focal();
        let mut worst = 0.0f64;
        let mut n = 0usize;
        for (x, y) in common::dense_grid(cam.width, cam.height) {
            let px = Vec2::new(x, y);
            let uv = cam.cam_from_img(&px).unwrap_or_else(|| panic!("{name}: no unprojection at ({x}, {y})"));
            let back = cam.img_from_normalized(&uv);
            worst = worst.max((back - px).norm());
            // Same through a 3D point at depth 3.
            let p = Vec3::new(uv.x * 3.0, uv.y * 3.0, 3.0);
            let back3 = cam.img_from_cam(&p).unwrap();
            assert!((back3 - px).norm() < ROUND_TRIP_PX * 10.0, "{name}: 3D round trip at ({x}, {y})");
            n += 1;
        }
        assert!(worst < ROUND_TRIP_PX, "{name}: worst unproject->project error {worst:e} px over {n} pixels");
        eprintln!("{name}: worst unproject->project {worst:.2e} px (f {f}) over {n} pixels");
    }
}

#[test]
fn project_unproject_round_trip() {
    let mut rng = SplitMix64::new(7);
    for (name, cam) in common::cameras() {
        // Bounding box of the image in normalised coordinates.
        let (w, h) = (cam.width as f64, cam.height as f64);
        let corners =
            [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h), (w / 2.0, 0.0), (w / 2.0, h), (0.0, h / 2.0), (w, h / 2.0)];
        let (mut lo, mut hi) = (Vec2::repeat(f64::MAX), Vec2::repeat(f64::MIN));
        for (x, y) in corners {
            let uv = cam.cam_from_img(&Vec2::new(x, y)).unwrap();
            lo = lo.inf(&uv);
            hi = hi.sup(&uv);
        }
        let mut tested = 0;
        while tested < 20_000 {
            let uv = Vec2::new(rng.uniform(lo.x, hi.x), rng.uniform(lo.y, hi.y));
            let px = cam.img_from_normalized(&uv);
            if !(px.x >= 0.0 && px.x <= w && px.y >= 0.0 && px.y <= h) {
                continue;
            }
            let back = cam.cam_from_img(&px).unwrap_or_else(|| panic!("{name}: no unprojection of {px:?}"));
            // Error measured in pixel units through the local scale f.
            let err = (back - uv).norm() * cam.mean_focal();
            assert!(err < ROUND_TRIP_PX, "{name}: project->unproject error {err:e} px at uv {uv:?}");
            tested += 1;
        }
    }
}

#[test]
fn unprojection_of_principal_point_and_behind_camera() {
    for (name, cam) in common::cameras() {
        let c = cam.principal_point();
        let uv = cam.cam_from_img(&c).unwrap();
        assert!(uv.norm() < 1e-15, "{name}");
        assert!(cam.img_from_cam(&Vec3::new(0.1, 0.2, 0.0)).is_none(), "{name}");
        assert!(cam.img_from_cam(&Vec3::new(0.1, 0.2, -1.0)).is_none(), "{name}");
        assert!(cam.img_from_cam_with_jacobians(&Vec3::new(0.1, 0.2, -1.0)).is_none(), "{name}");
        let b = cam.bearing_from_img(&Vec2::new(10.0, 20.0)).unwrap();
        assert!((b.norm() - 1.0).abs() < 1e-12 && b.z > 0.0);
    }
}

#[test]
fn fisheye_pixels_beyond_ninety_degrees_are_rejected() {
    // TUM-VI calibration on its 512x512 image: the corners are > 90° off axis.
    let cam = Camera::new(
        CameraModelId::OpenCvFisheye,
        512,
        512,
        vec![190.97, 190.97, 254.93, 256.90, 0.0034823894, 0.0007150348, -0.0020532361, 0.0002029367],
    )
    .unwrap();
    assert!(cam.cam_from_img(&Vec2::new(0.0, 0.0)).is_none());
    assert!(cam.cam_from_img(&Vec2::new(254.93, 10.0)).is_some());
    // Image-plane centre row still round-trips.
    let px = Vec2::new(254.93 + 200.0, 256.90);
    let uv = cam.cam_from_img(&px).unwrap();
    assert!((cam.img_from_normalized(&uv) - px).norm() < ROUND_TRIP_PX);
}

#[test]
fn tum_fr1_unprojection_converges_on_whole_image() {
    // Every pixel centre (OpenCV convention) of the full 640x480 image.
    let cam = common::tum_fr1();
    let mut worst = 0.0f64;
    for y in 0..480 {
        for x in 0..640 {
            let px = Vec2::new(x as f64, y as f64);
            let uv = cam.cam_from_img(&px).unwrap_or_else(|| panic!("no convergence at ({x}, {y})"));
            worst = worst.max((cam.img_from_normalized(&uv) - px).norm());
        }
    }
    assert!(worst < ROUND_TRIP_PX, "worst {worst:e}");
}

/// A random camera-frame point whose projection lies in the image.
fn random_point(cam: &Camera, rng: &mut SplitMix64) -> Vec3 {
    loop {
        let px = Vec2::new(rng.uniform(0.0, cam.width as f64), rng.uniform(0.0, cam.height as f64));
        if let Some(uv) = cam.cam_from_img(&px) {
            let z = rng.uniform(0.3, 20.0);
            return Vec3::new(uv.x * z, uv.y * z, z);
        }
    }
}

fn check_column(name: &str, what: &str, ana: Vec2, fd: Vec2) {
    let err = (ana - fd).norm();
    let tol = JAC_REL * fd.norm().max(JAC_FLOOR);
    assert!(
        err <= tol,
        "{name}: d pixel/d {what}: analytic {ana:?} vs finite difference {fd:?} (err {err:e}, tol {tol:e})"
    );
}

#[test]
fn jacobians_match_central_differences() {
    let mut rng = SplitMix64::new(42);
    for (name, cam) in common::cameras() {
        let names: Vec<&str> = cam.model.param_name_list().collect();
        for _ in 0..300 {
            let p = random_point(&cam, &mut rng);
            let proj = cam.img_from_cam_with_jacobians(&p).unwrap();
            assert_eq!(Some(proj.pixel), cam.img_from_cam(&p), "{name}");
            // Point.
            let h = 1e-6 * p.norm().max(1.0);
            for k in 0..3 {
                let mut a = p;
                let mut b = p;
                a[k] += h;
                b[k] -= h;
                let fd = (cam.img_from_cam(&a).unwrap() - cam.img_from_cam(&b).unwrap()) / (2.0 * h);
                check_column(name, ["x", "y", "z"][k], proj.d_point.column(k).into(), fd);
            }
            // Parameters.
            for (k, pname) in names.iter().enumerate() {
                // Pixels are linear in every parameter except k4..k6 of
                // FULL_OPENCV, so a large step costs no truncation error and
                // keeps rounding noise (~eps * cx / h) small.
                let h = 1e-4 * cam.params[k].abs().max(1.0);
                let mut a = cam.clone();
                let mut b = cam.clone();
                a.params[k] += h;
                b.params[k] -= h;
                let fd = (a.img_from_cam(&p).unwrap() - b.img_from_cam(&p).unwrap()) / (2.0 * h);
                check_column(name, pname, proj.d_params.column(k).into(), fd);
            }
            for k in names.len()..MAX_PARAMS {
                assert_eq!(proj.d_params.column(k).norm(), 0.0, "{name}: column {k} must be zero");
            }
        }
    }
}

#[test]
fn jacobians_near_the_optical_axis() {
    // The fisheye factor switches to its Taylor form near r = 0; check both sides.
    for (name, cam) in common::cameras() {
        for r in [0.0, 1e-12, 1e-9, 1e-7, 1e-5] {
            let p = Vec3::new(r, -0.5 * r, 1.0);
            let proj = cam.img_from_cam_with_jacobians(&p).unwrap();
            // Larger step: the pixel is dominated by cx, so rounding noise
            // is ~eps * cx / h.
            let h = 1e-4;
            for k in 0..3 {
                let mut a = p;
                let mut b = p;
                a[k] += h;
                b[k] -= h;
                let fd = (cam.img_from_cam(&a).unwrap() - cam.img_from_cam(&b).unwrap()) / (2.0 * h);
                check_column(name, "point near axis", proj.d_point.column(k).into(), fd);
            }
            let uv = cam.cam_from_img(&proj.pixel).unwrap();
            assert!((uv - Vec2::new(r, -0.5 * r)).norm() < 1e-15, "{name}: r {r}");
        }
    }
}

#[test]
#[ignore = "timing only; run with --release -- --ignored --nocapture"]
fn timing_projection_and_unprojection() {
    let cam = common::tum_fr1();
    let mut rng = SplitMix64::new(1);
    let pts: Vec<Vec3> = (0..100_000).map(|_| random_point(&cam, &mut rng)).collect();
    let t = std::time::Instant::now();
    let mut acc = 0.0;
    for p in &pts {
        acc += cam.img_from_cam(p).map_or(0.0, |v| v.x);
    }
    let proj = t.elapsed().as_nanos() as f64 / pts.len() as f64;
    let t = std::time::Instant::now();
    for p in &pts {
        acc += cam.img_from_cam_with_jacobians(p).map_or(0.0, |v| v.d_params[(0, 4)]);
    }
    let jac = t.elapsed().as_nanos() as f64 / pts.len() as f64;
    let pixels: Vec<Vec2> = pts.iter().filter_map(|p| cam.img_from_cam(p)).collect();
    let t = std::time::Instant::now();
    for px in &pixels {
        acc += cam.cam_from_img(px).map_or(0.0, |v| v.x);
    }
    let unproj = t.elapsed().as_nanos() as f64 / pixels.len() as f64;
    eprintln!("TUM fr1: img_from_cam {proj:.0} ns, with Jacobians {jac:.0} ns, cam_from_img {unproj:.0} ns ({acc:.1})");
}

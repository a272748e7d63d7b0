//! Cross-check against pycolmap (COLMAP 3.x/4.x C++ camera models):
//! projection, unprojection and the undistorted camera agree.

mod common;

use std::io::Write;
use std::process::{Command, Stdio};

use colslam_camera::undistort::{UndistortOptions, undistorted_camera};
use colslam_camera::{Camera, Vec2, Vec3};
use colslam_geometry::SplitMix64;

/// Reads `CAM`/`P3`/`PX`/`UND` lines on stdin, answers one line each.
const SCRIPT: &str = r#"
import sys, numpy as np, pycolmap
cam = None
out = []
for line in sys.stdin:
    t = line.split()
    if not t:
        continue
    if t[0] == "CAM":
        cam = pycolmap.Camera(model=t[1], width=int(t[2]), height=int(t[3]), params=[float(v) for v in t[4:]])
        out.append("OK")
    elif t[0] == "P3":
        r = cam.img_from_cam(np.array([[float(v) for v in t[1:4]]]))
        out.append("R %.17g %.17g" % (r[0][0], r[0][1]))
    elif t[0] == "PX":
        r = cam.cam_from_img(np.array([[float(v) for v in t[1:3]]]))
        out.append("R %.17g %.17g" % (r[0][0], r[0][1]))
    elif t[0] == "UND":
        o = pycolmap.UndistortCameraOptions()
        o.blank_pixels = float(t[1])
        u = pycolmap.undistort_camera(o, cam)
        out.append("U %d %d %s" % (u.width, u.height, " ".join("%.17g" % p for p in u.params)))
print("\n".join(out))
"#;

fn run_peer(py: &std::path::Path, input: &str) -> Vec<Vec<f64>> {
    let mut child = Command::new(py)
        .args(["-c", SCRIPT])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start peer python");
    child.stdin.take().unwrap().write_all(input.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "peer failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .filter(|l| *l != "OK")
        .map(|l| l.split_whitespace().skip(1).map(|v| v.parse::<f64>().unwrap_or(f64::NAN)).collect())
        .collect()
}

fn cam_line(c: &Camera) -> String {
    let p: Vec<String> = c.params.iter().map(|v| format!("{v:?}")).collect();
    format!("CAM {} {} {} {}\n", c.model.name(), c.width, c.height, p.join(" "))
}

#[test]
fn projection_and_unprojection_match_pycolmap() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "numpy"]) else { return };
    let mut rng = SplitMix64::new(3);
    for (name, cam) in common::cameras() {
        let mut input = cam_line(&cam);
        let mut points = Vec::new();
        let mut pixels = Vec::new();
        for _ in 0..200 {
            let px = Vec2::new(rng.uniform(0.0, cam.width as f64), rng.uniform(0.0, cam.height as f64));
            let uv = cam.cam_from_img(&px).unwrap();
            let z = rng.uniform(0.5, 10.0);
            let p = Vec3::new(uv.x * z, uv.y * z, z);
            input.push_str(&format!("P3 {:?} {:?} {:?}\n", p.x, p.y, p.z));
            input.push_str(&format!("PX {:?} {:?}\n", px.x, px.y));
            points.push(p);
            pixels.push(px);
        }
        let res = run_peer(&py, &input);
        assert_eq!(res.len(), 2 * points.len(), "{name}");
        let (mut worst_proj, mut worst_unproj) = (0.0f64, 0.0f64);
        for (k, (p, px)) in points.iter().zip(&pixels).enumerate() {
            let theirs = Vec2::new(res[2 * k][0], res[2 * k][1]);
            let ours = cam.img_from_cam(p).unwrap();
            worst_proj = worst_proj.max((theirs - ours).norm());
            let theirs_uv = Vec2::new(res[2 * k + 1][0], res[2 * k + 1][1]);
            let ours_uv = cam.cam_from_img(px).unwrap();
            worst_unproj = worst_unproj.max((theirs_uv - ours_uv).norm() * cam.mean_focal());
        }
        eprintln!("{name}: |ours - pycolmap| projection {worst_proj:.1e} px, unprojection {worst_unproj:.1e} px");
        assert!(worst_proj < 1e-9, "{name}: projection differs from pycolmap by {worst_proj:e} px");
        // COLMAP's unprojection stops early, so allow its residual.
        assert!(worst_unproj < 1e-4, "{name}: unprojection differs from pycolmap by {worst_unproj:e} px");
    }
}

#[test]
fn undistorted_camera_matches_pycolmap() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap", "numpy"]) else { return };
    for (name, cam) in common::cameras() {
        if !cam.has_distortion() || cam.model == colslam_camera::CameraModelId::OpenCvFisheye {
            continue;
        }
        for blank in [0.0, 1.0] {
            let input = format!("{}UND {blank}\n", cam_line(&cam));
            let theirs = &run_peer(&py, &input)[0];
            let ours =
                undistorted_camera(&cam, &UndistortOptions { blank_pixels: blank, ..Default::default() }).unwrap();
            eprintln!(
                "{name} blank {blank}: ours {}x{} {:?}, pycolmap {:?}",
                ours.width, ours.height, ours.params, theirs
            );
            // COLMAP measures the right/bottom margin from `size - 0.5`;
            // we use the image edge, so sizes may differ by a pixel or two.
            let (tw, th) = (theirs[0], theirs[1]);
            assert!((ours.width as f64 - tw).abs() <= 2.0 && (ours.height as f64 - th).abs() <= 2.0, "{name}");
            assert_eq!((ours.params[0], ours.params[1]), (theirs[2], theirs[3]), "{name}: focal");
            assert!((ours.params[2] - theirs[4]).abs() < 1.5 && (ours.params[3] - theirs[5]).abs() < 1.5, "{name}");
        }
    }
}

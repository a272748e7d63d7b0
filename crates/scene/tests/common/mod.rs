//! Shared helpers of the integration tests: a synthetic model, the JSON
//! layout of `tests/py/dump_model.py`, byte comparison of model folders.
#![allow(dead_code)]

use colslam_camera::CameraModelId;
use colslam_geometry::{Quat, Rigid3, SplitMix64, Vec2, Vec3};
use colslam_scene::{CameraId, Image, ImageId, ModelFormat, Reconstruction, TrackElement, projection};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Model file base names, in COLMAP's write order.
pub const FILES: [&str; 5] = ["rigs", "cameras", "frames", "images", "points3D"];

/// Path of a helper script in tests/py.
pub fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py").join(name)
}

/// A synthetic model: five camera models, eight images (six registered,
/// registered out of id order; two unregistered), 60 points observed by 2-4
/// images each with projected, slightly noisy keypoints plus unmatched
/// keypoints, errors computed.
pub fn synthetic_model(seed: u64) -> Reconstruction {
    let mut rng = SplitMix64::new(seed);
    let mut rec = Reconstruction::new();
    let cams = [
        (CameraModelId::SimpleRadial, vec![520.3, 320.1, 239.7, -0.0123]),
        (CameraModelId::OpenCv, vec![610.5, 611.25, 401.1, 299.3, 0.021, -0.0042, 0.0011, -0.0007]),
        (CameraModelId::Pinhole, vec![700.0, 702.5, 512.0, 384.0]),
        (
            CameraModelId::FullOpenCv,
            vec![500.0, 501.0, 320.0, 240.0, 0.01, -0.002, 0.0005, 0.0004, 0.0001, 0.001, -0.0002, 0.00003],
        ),
        (CameraModelId::OpenCvFisheye, vec![300.0, 300.5, 320.0, 240.0, 0.01, -0.003, 0.0004, -0.00005]),
        (CameraModelId::SimplePinhole, vec![450.0, 320.0, 240.0]),
        (CameraModelId::Radial, vec![480.0, 320.0, 240.0, 0.01, -0.001]),
    ];
    let mut cam_ids = Vec::new();
    for (k, (model, params)) in cams.into_iter().enumerate() {
        let cam = colslam_camera::Camera::new(model, 640 + k as u64, 480, params).unwrap();
        // Ids with gaps: 1, 3, 5, ...
        let id = CameraId(1 + 2 * k as u32);
        rec.add_camera_with_id(id, cam).unwrap();
        cam_ids.push(id);
    }
    let order = [5u32, 2, 11, 3, 8, 6, 9, 14];
    let registered = [true, true, true, true, true, false, true, false];
    for (k, (&iid, &reg)) in order.iter().zip(&registered).enumerate() {
        let camera_id = cam_ids[k % cam_ids.len()];
        let rotation = Quat::from_euler_angles(rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.2, 0.2));
        let pose =
            Rigid3::new(rotation, Vec3::new(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.2, 0.2)));
        let mut img = Image::new(ImageId(iid), format!("seq/img_{iid:04}.png"), camera_id, Vec::new());
        img.cam_from_world = pose;
        for _ in 0..(5 + k) {
            img.points2d.push(colslam_scene::Point2D::new(rng.uniform(0.0, 640.0), rng.uniform(0.0, 480.0)));
        }
        img.registered = reg;
        rec.add_image(img).unwrap();
    }
    let reg_ids: Vec<ImageId> = rec.registered_image_ids().to_vec();
    for n in 0..60 {
        let xyz = Vec3::new(rng.uniform(-1.5, 1.5), rng.uniform(-1.0, 1.0), rng.uniform(4.0, 7.0));
        let len = 2 + n % 3;
        let start = rng.below(reg_ids.len());
        let mut track = Vec::new();
        for j in 0..len {
            let iid = reg_ids[(start + j) % reg_ids.len()];
            let img = rec.image(iid).unwrap();
            let cam = &rec.camera(img.camera_id).unwrap().camera;
            let px = projection::project(cam, &img.cam_from_world, &xyz).unwrap();
            let noisy = px + Vec2::new(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5));
            let idx = rec.push_point2d(iid, noisy).unwrap();
            track.push(TrackElement::new(iid, idx));
        }
        let color = [rng.below(256) as u8, rng.below(256) as u8, rng.below(256) as u8];
        rec.add_point3d(xyz, color, track).unwrap();
    }
    rec.update_point_errors().unwrap();
    rec.check_consistency().unwrap();
    rec
}

fn bits(x: f64) -> Value {
    json!(x.to_bits())
}

/// The JSON layout of tests/py/dump_model.py for our model (images as a
/// reader sees them: `registered_only` keeps only registered images).
pub fn to_json(rec: &Reconstruction, registered_only: bool) -> Value {
    let cameras: Vec<Value> = rec
        .cameras()
        .map(|c| {
            json!([
                c.id.0,
                c.camera.model.name(),
                c.camera.width,
                c.camera.height,
                c.camera.params.iter().map(|p| bits(*p)).collect::<Vec<_>>()
            ])
        })
        .collect();
    let images: Vec<Value> = rec
        .images()
        .filter(|i| i.registered || !registered_only)
        .map(|i| {
            let pose: Vec<Value> = if i.registered {
                i.cam_from_world
                    .quat_wxyz()
                    .iter()
                    .chain(i.cam_from_world.translation.iter())
                    .map(|v| bits(*v))
                    .collect()
            } else {
                Vec::new()
            };
            let pts: Vec<Value> = i
                .points2d
                .iter()
                .map(|p| json!([p.xy.x.to_bits(), p.xy.y.to_bits(), p.point3d_id.map_or(-1i128, |q| q.0 as i128)]))
                .collect();
            json!([i.id.0, i.name, i.camera_id.0, i.registered, pose, pts])
        })
        .collect();
    let points: Vec<Value> = rec
        .points3d()
        .map(|(id, p)| {
            json!([
                id.0,
                p.xyz.iter().map(|v| bits(*v)).collect::<Vec<_>>(),
                p.color,
                p.error.to_bits(),
                p.track.iter().map(|e| json!([e.image_id.0, e.point2d_idx])).collect::<Vec<_>>()
            ])
        })
        .collect();
    let mut reg: Vec<u32> = rec.registered_image_ids().iter().map(|i| i.0).collect();
    reg.sort_unstable();
    json!({"cameras": cameras, "images": images, "points": points, "reg_images": reg})
}

/// Asserts two dumps are equal, reporting the first differing record.
pub fn assert_json_eq(ours: &Value, theirs: &Value, context: &str) {
    for key in ["cameras", "images", "points", "reg_images"] {
        let (a, b) = (&ours[key], &theirs[key]);
        let (Some(a), Some(b)) = (a.as_array(), b.as_array()) else {
            panic!("{context}: {key} missing");
        };
        assert_eq!(a.len(), b.len(), "{context}: number of {key}");
        for (x, y) in a.iter().zip(b) {
            assert_eq!(x, y, "{context}: first differing {key} record (ours left)");
        }
    }
}

/// Runs tests/py/dump_model.py on a folder.
pub fn pycolmap_dump(py: &Path, dir: &Path, mode: &str) -> Value {
    let out =
        colslam_testutil::run_python(py, &[script("dump_model.py").to_str().unwrap(), dir.to_str().unwrap(), mode]);
    serde_json::from_str(&out).expect("dump_model.py prints JSON")
}

/// Model file path.
pub fn model_file(dir: &Path, base: &str, format: ModelFormat) -> PathBuf {
    dir.join(format!("{base}.{}", format.extension()))
}

/// Asserts the five files of two folders are byte-identical.
pub fn assert_same_files(a: &Path, b: &Path, format: ModelFormat) {
    for base in FILES {
        let (pa, pb) = (model_file(a, base, format), model_file(b, base, format));
        let ba = std::fs::read(&pa).unwrap_or_else(|e| panic!("{}: {e}", pa.display()));
        let bb = std::fs::read(&pb).unwrap_or_else(|e| panic!("{}: {e}", pb.display()));
        if ba != bb {
            let first = ba.iter().zip(&bb).position(|(x, y)| x != y).unwrap_or(ba.len().min(bb.len()));
            panic!(
                "{} and {} differ (sizes {} vs {}, first difference at byte {first}: {:?} vs {:?})",
                pa.display(),
                pb.display(),
                ba.len(),
                bb.len(),
                String::from_utf8_lossy(&ba[first.saturating_sub(40)..(first + 40).min(ba.len())]),
                String::from_utf8_lossy(&bb[first.saturating_sub(40)..(first + 40).min(bb.len())]),
            );
        }
    }
}

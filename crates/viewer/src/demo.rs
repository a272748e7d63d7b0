//! A synthetic scene for demos and tests of the viewer: cameras on an arc
//! looking at a coloured, box-shaped cloud of points, with real tracks.

use colslam_geometry::{Quat, Rigid3, SplitMix64, Vec2, Vec3};
use colslam_scene::{CameraId, Image, ImageId, Reconstruction, SceneError, TrackElement};

/// Image size of the synthetic camera.
const DEMO_WIDTH: u64 = 640;
/// Image height of the synthetic camera.
const DEMO_HEIGHT: u64 = 480;
/// Focal length of the synthetic camera in pixels.
const DEMO_FOCAL: f64 = 500.0;
/// Observations per point (consecutive cameras), at most the camera count.
const DEMO_TRACK_LENGTH: usize = 3;

/// A reconstruction with `num_cameras` registered images (one PINHOLE
/// camera, names `frame_000000.png`, ...) moving along a wavy line and
/// `num_points` points in front of them, each observed by up to 3
/// consecutive images starting at a random one. Deterministic in `seed`.
pub fn demo_reconstruction(num_cameras: usize, num_points: usize, seed: u64) -> Result<Reconstruction, SceneError> {
    let mut rng = SplitMix64::new(seed);
    let mut rec = Reconstruction::new();
    let cam = rec.add_camera(colslam_camera::Camera::pinhole(
        DEMO_WIDTH,
        DEMO_HEIGHT,
        DEMO_FOCAL,
        DEMO_FOCAL,
        0.5 * DEMO_WIDTH as f64,
        0.5 * DEMO_HEIGHT as f64,
    ));
    let track_len = DEMO_TRACK_LENGTH.min(num_cameras);
    // Each image gets one keypoint slot per point; slot j observes point j
    // (moved onto the point's projection below), the other slots are
    // unmatched keypoints spread over the image.
    let keypoints: Vec<Vec2> = (0..num_points)
        .map(|j| {
            Vec2::new(((j * 37) % DEMO_WIDTH as usize) as f64 + 0.5, ((j * 53) % DEMO_HEIGHT as usize) as f64 + 0.5)
        })
        .collect();
    for i in 0..num_cameras {
        let id = ImageId(u32::try_from(i + 1).unwrap_or(u32::MAX));
        let mut img = Image::new(id, format!("frame_{i:06}.png"), CameraId(cam.0), keypoints.clone());
        // Camera centre moves along +x with a slight turn; it looks along +z.
        let yaw = 0.02 * i as f64;
        let rot = Quat::from_euler_angles(0.0, yaw, 0.0);
        // A slight wave keeps the path from being a line (an alignment of
        // the cameras with a ground truth needs that).
        let center = Vec3::new(0.25 * i as f64, 0.1 * (0.7 * i as f64).sin(), 0.0);
        let world_from_cam = Rigid3::new(rot, center);
        img.cam_from_world = world_from_cam.inverse();
        img.registered = true;
        rec.add_image(img)?;
    }
    let span = 0.25 * num_cameras.max(1) as f64;
    for j in 0..num_points {
        let xyz = Vec3::new(rng.uniform(-1.0, span + 1.0), rng.uniform(-1.5, 1.5), rng.uniform(4.0, 7.0));
        let color = [
            (xyz.x / (span + 2.0) * 255.0).clamp(0.0, 255.0) as u8,
            ((xyz.y + 1.5) / 3.0 * 255.0).clamp(0.0, 255.0) as u8,
            ((xyz.z - 4.0) / 3.0 * 255.0).clamp(0.0, 255.0) as u8,
        ];
        if track_len == 0 {
            continue;
        }
        let first = rng.below(num_cameras - track_len + 1);
        let slot = u32::try_from(j).unwrap_or(u32::MAX);
        let track = (first..first + track_len)
            .map(|i| TrackElement::new(ImageId(u32::try_from(i + 1).unwrap_or(u32::MAX)), slot))
            .collect();
        let id = rec.add_point3d(xyz, color, track)?;
        // Observations sit where the point projects, so reprojection errors
        // are zero (points behind a camera keep their spread position).
        for i in first..first + track_len {
            let image_id = ImageId(u32::try_from(i + 1).unwrap_or(u32::MAX));
            let camera = rec.camera(cam).map(|c| c.camera.clone());
            let pose = rec.image(image_id).map(|img| img.cam_from_world);
            if let (Some(camera), Some(pose), Some(p)) = (camera, pose, rec.point3d(id))
                && let Some(xy) = colslam_scene::projection::project(&camera, &pose, &p.xyz)
            {
                rec.set_point2d_xy(image_id, slot, xy)?;
            }
        }
    }
    rec.update_point_errors()?;
    Ok(rec)
}

//! World-to-pixel projection for reprojection errors: the pose moves the
//! point into the camera frame, `colslam_camera::Camera::img_from_cam` applies
//! the model (COLMAP's `src/colmap/sensor/models.h` semantics).

use colslam_camera::Camera;
use colslam_geometry::{Rigid3, Vec2, Vec3};

/// Points closer to the image plane than this (in camera z) do not project
/// (COLMAP uses `std::numeric_limits<double>::epsilon()` the same way).
pub const MIN_DEPTH: f64 = f64::EPSILON;

/// Depth of a world point in an image (camera z).
pub fn depth(cam_from_world: &Rigid3, xyz: &Vec3) -> f64 {
    cam_from_world.transform_point(xyz).z
}

/// Projects a world point to pixels; `None` behind or on the camera plane,
/// or when the model gives no finite pixel.
pub fn project(camera: &Camera, cam_from_world: &Rigid3, xyz: &Vec3) -> Option<Vec2> {
    let p = cam_from_world.transform_point(xyz);
    if p.z < MIN_DEPTH {
        return None;
    }
    camera.img_from_cam(&p)
}

/// Reprojection error in pixels of `xyz` against the keypoint `xy`; `None`
/// when the point does not project.
pub fn reprojection_error(camera: &Camera, cam_from_world: &Rigid3, xyz: &Vec3, xy: &Vec2) -> Option<f64> {
    project(camera, cam_from_world, xyz).map(|p| (p - xy).norm())
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_camera::CameraModelId;

    #[test]
    fn pinhole_and_radial_projection() {
        let cam = Camera::new(CameraModelId::Pinhole, 640, 480, vec![500.0, 400.0, 320.0, 240.0]).unwrap();
        let id = Rigid3::identity();
        let p = project(&cam, &id, &Vec3::new(0.2, -0.1, 2.0)).unwrap();
        assert!((p - Vec2::new(370.0, 220.0)).norm() < 1e-12);
        assert!(project(&cam, &id, &Vec3::new(0.0, 0.0, -1.0)).is_none());
        let rad = Camera::new(CameraModelId::SimpleRadial, 640, 480, vec![500.0, 320.0, 240.0, 0.1]).unwrap();
        let q = project(&rad, &id, &Vec3::new(0.2, 0.0, 1.0)).unwrap();
        // u = 0.2, r2 = 0.04, u_d = 0.2 * 1.004
        assert!((q.x - (500.0 * 0.2 * 1.004 + 320.0)).abs() < 1e-9);
        // FULL_OPENCV with only k1 equals RADIAL with k2 = 0.
        let full = Camera::new(
            CameraModelId::FullOpenCv,
            640,
            480,
            vec![500.0, 500.0, 320.0, 240.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
        .unwrap();
        let f = project(&full, &id, &Vec3::new(0.2, 0.0, 1.0)).unwrap();
        assert!((f - q).norm() < 1e-9);
    }

    #[test]
    fn fisheye_centre_and_off_axis() {
        let cam =
            Camera::new(CameraModelId::OpenCvFisheye, 640, 480, vec![300.0, 300.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0])
                .unwrap();
        let id = Rigid3::identity();
        let c = project(&cam, &id, &Vec3::new(0.0, 0.0, 1.0)).unwrap();
        assert!((c - Vec2::new(320.0, 240.0)).norm() < 1e-12);
        // Equidistant: pixel radius = f * theta.
        let p = project(&cam, &id, &Vec3::new(1.0, 0.0, 1.0)).unwrap();
        assert!((p.x - 320.0 - 300.0 * std::f64::consts::FRAC_PI_4).abs() < 1e-9);
    }
}

//! The reprojection residual and its analytic Jacobians.
//!
//! Pose parameterisation (both here and in the solver): a `cam_from_world`
//! pose `(R, t)` is updated by a left-multiplicative rotation increment and an
//! additive translation increment,
//! `R <- exp([w]x) R`, `t <- t + dt`, with the tangent ordered `(w, dt)`.
//! For a world point `X`, `p = R X + t`, so
//! `dp/dw = -[R X]x`, `dp/dt = I`, `dp/dX = R`,
//! and the residual `r = project(p) - observed` chains these through the
//! camera model's Jacobians (`colslam_camera`).

use colslam_camera::Camera;
use colslam_geometry::{Quat, Rigid3, Vec2, Vec3};
use nalgebra::{Matrix2x3, SMatrix};

/// Columns of the intrinsics Jacobian (the camera crate's `MAX_PARAMS`).
pub const MAX_CAMERA_PARAMS: usize = colslam_camera::MAX_PARAMS;

/// Dimension of the pose tangent space.
pub const POSE_DIM: usize = 6;

/// A projection with its Jacobians: the contract of
/// `colslam_camera::Camera::img_from_cam_with_jacobians`.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraProjection {
    /// Projected pixel.
    pub pixel: Vec2,
    /// d pixel / d camera-frame point.
    pub d_point: Matrix2x3<f64>,
    /// d pixel / d parameters; columns `>= num_params` are zero.
    pub d_params: SMatrix<f64, 2, MAX_CAMERA_PARAMS>,
}

/// Projects a camera-frame point with Jacobians; `None` when the point cannot
/// be projected (behind the camera, or outside the model's valid domain).
pub(crate) fn project_with_jacobians(camera: &Camera, p_cam: &Vec3) -> Option<CameraProjection> {
    bridge::project_with_jacobians(camera, p_cam)
}

/// Residual and Jacobians of one observation.
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualJacobians {
    /// `project(R X + t) - observed`, in pixels.
    pub residual: Vec2,
    /// d residual / d pose tangent `(w, dt)` (left rotation increment).
    pub d_pose: SMatrix<f64, 2, POSE_DIM>,
    /// d residual / d world point.
    pub d_point: Matrix2x3<f64>,
    /// d residual / d camera parameters (COLMAP order; unused columns zero).
    pub d_params: SMatrix<f64, 2, MAX_CAMERA_PARAMS>,
}

/// The reprojection residual of `point` seen at `observed` by `camera` at
/// `cam_from_world`, with Jacobians; `None` when the point does not project.
pub fn reprojection_jacobians(
    camera: &Camera,
    cam_from_world: &Rigid3,
    point: &Vec3,
    observed: &Vec2,
) -> Option<ResidualJacobians> {
    reprojection_jacobians_with(camera, cam_from_world, point, observed, true)
}

/// [`reprojection_jacobians`]; without `with_params` the intrinsics
/// Jacobian is left zero and not computed (a constant camera: most of the
/// cost of a distorted model's projection is in its parameter derivatives).
pub fn reprojection_jacobians_with(
    camera: &Camera,
    cam_from_world: &Rigid3,
    point: &Vec3,
    observed: &Vec2,
    with_params: bool,
) -> Option<ResidualJacobians> {
    let r = cam_from_world.rotation.to_rotation_matrix().into_inner();
    let rx = r * point;
    let p_cam = rx + cam_from_world.translation;
    let (pixel, d_proj, d_params) = if with_params {
        let proj = project_with_jacobians(camera, &p_cam)?;
        (proj.pixel, proj.d_point, proj.d_params)
    } else {
        let (pixel, d_proj) = camera.img_from_cam_with_point_jacobian(&p_cam)?;
        (pixel, d_proj, SMatrix::zeros())
    };
    let residual = pixel - observed;
    let mut d_pose = SMatrix::<f64, 2, POSE_DIM>::zeros();
    // -[Rx]x: d(exp([w]x) R X)/dw at w = 0.
    let neg_skew = nalgebra::Matrix3::new(0.0, rx.z, -rx.y, -rx.z, 0.0, rx.x, rx.y, -rx.x, 0.0);
    d_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&(d_proj * neg_skew));
    d_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&d_proj);
    let d_point = d_proj * r;
    Some(ResidualJacobians { residual, d_pose, d_point, d_params })
}

/// The reprojection residual only; `None` when the point does not project.
pub fn reprojection_residual(camera: &Camera, cam_from_world: &Rigid3, point: &Vec3, observed: &Vec2) -> Option<Vec2> {
    let p_cam = cam_from_world.transform_point(point);
    bridge::project(camera, &p_cam).map(|px| px - observed)
}

/// Applies a tangent increment `(w, dt)` to a `cam_from_world` pose
/// (left-multiplicative rotation, additive translation).
pub fn pose_plus(pose: &Rigid3, delta: &[f64; POSE_DIM]) -> Rigid3 {
    let w = Vec3::new(delta[0], delta[1], delta[2]);
    let rotation = Quat::from_scaled_axis(w) * pose.rotation;
    let translation = pose.translation + Vec3::new(delta[3], delta[4], delta[5]);
    Rigid3 { rotation, translation }
}

/// Projection through the camera crate (the single source of truth for the
/// camera models).
mod bridge {
    use super::*;

    pub(super) fn project_with_jacobians(camera: &Camera, p_cam: &Vec3) -> Option<CameraProjection> {
        let p = camera.img_from_cam_with_jacobians(p_cam)?;
        Some(CameraProjection { pixel: p.pixel, d_point: p.d_point, d_params: p.d_params })
    }

    pub(super) fn project(camera: &Camera, p_cam: &Vec3) -> Option<Vec2> {
        camera.img_from_cam(p_cam)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use colslam_camera::CameraModelId;

    /// A plausible camera of each model (640x480, mild distortion).
    pub(crate) fn sample_camera(model: CameraModelId) -> Camera {
        let params: Vec<f64> = match model {
            CameraModelId::SimplePinhole => vec![500.0, 320.0, 240.0],
            CameraModelId::Pinhole => vec![510.0, 490.0, 321.0, 239.0],
            CameraModelId::SimpleRadial => vec![500.0, 320.0, 240.0, -0.05],
            CameraModelId::Radial => vec![500.0, 320.0, 240.0, -0.05, 0.01],
            CameraModelId::OpenCv => vec![510.0, 490.0, 321.0, 239.0, -0.05, 0.01, 0.001, -0.002],
            CameraModelId::OpenCvFisheye => vec![510.0, 490.0, 321.0, 239.0, 0.01, -0.01, 0.002, -0.001],
            CameraModelId::FullOpenCv => {
                vec![510.0, 490.0, 321.0, 239.0, 0.26, -0.95, -0.005, 0.0026, 1.16, 0.01, -0.01, 0.02]
            }
        };
        // The parameter counts above are the model table's.
        Camera { model, width: 640, height: 480, params }
    }

    #[test]
    fn jacobians_match_central_differences_for_every_model() {
        let pose = Rigid3::new(Quat::from_euler_angles(0.1, -0.2, 0.3), Vec3::new(0.2, -0.1, 0.5));
        let points = [Vec3::new(0.3, -0.2, 4.0), Vec3::new(-1.0, 0.7, 3.0), Vec3::new(0.05, 0.02, 2.5)];
        for model in CameraModelId::ALL {
            let cam = sample_camera(model);
            for x in &points {
                let obs = Vec2::new(300.0, 200.0);
                let jac = reprojection_jacobians(&cam, &pose, x, &obs).expect("projects");
                let res = |c: &Camera, p: &Rigid3, x: &Vec3| reprojection_residual(c, p, x, &obs).expect("projects");
                assert!((jac.residual - res(&cam, &pose, x)).norm() < 1e-12);
                let h = 1e-6;
                for k in 0..POSE_DIM {
                    let mut d = [0.0; POSE_DIM];
                    d[k] = h;
                    let plus = res(&cam, &pose_plus(&pose, &d), x);
                    d[k] = -h;
                    let minus = res(&cam, &pose_plus(&pose, &d), x);
                    let fd = (plus - minus) / (2.0 * h);
                    let an = jac.d_pose.column(k);
                    assert!((fd - an).norm() < 1e-5 * (1.0 + an.norm()), "{model} pose {k}: {fd} vs {an}");
                }
                for k in 0..3 {
                    let mut xp = *x;
                    xp[k] += h;
                    let mut xm = *x;
                    xm[k] -= h;
                    let fd = (res(&cam, &pose, &xp) - res(&cam, &pose, &xm)) / (2.0 * h);
                    let an = jac.d_point.column(k);
                    assert!((fd - an).norm() < 1e-5 * (1.0 + an.norm()), "{model} point {k}: {fd} vs {an}");
                }
                for k in 0..MAX_CAMERA_PARAMS {
                    if k >= cam.params.len() {
                        assert_eq!(jac.d_params.column(k).norm(), 0.0, "{model} unused column {k}");
                        continue;
                    }
                    let hk = h * cam.params[k].abs().max(1e-2);
                    let mut cp = cam.clone();
                    cp.params[k] += hk;
                    let mut cm = cam.clone();
                    cm.params[k] -= hk;
                    let fd = (res(&cp, &pose, x) - res(&cm, &pose, x)) / (2.0 * hk);
                    let an = jac.d_params.column(k);
                    assert!((fd - an).norm() < 1e-5 * (1.0 + an.norm()), "{model} param {k}: {fd} vs {an}");
                }
            }
        }
    }

    #[test]
    fn constant_camera_path_gives_the_same_pose_and_point_jacobians() {
        let pose = Rigid3::new(Quat::from_euler_angles(-0.2, 0.1, 0.4), Vec3::new(-0.3, 0.2, 0.1));
        let obs = Vec2::new(310.0, 250.0);
        for model in CameraModelId::ALL {
            let cam = sample_camera(model);
            for x in [Vec3::new(0.4, 0.3, 3.0), Vec3::new(-0.8, -0.5, 2.0)] {
                let full = reprojection_jacobians_with(&cam, &pose, &x, &obs, true).expect("projects");
                let fixed = reprojection_jacobians_with(&cam, &pose, &x, &obs, false).expect("projects");
                assert!((full.residual - fixed.residual).norm() < 1e-12, "{model}");
                assert!((full.d_pose - fixed.d_pose).norm() < 1e-9 * (1.0 + full.d_pose.norm()), "{model}");
                assert!((full.d_point - fixed.d_point).norm() < 1e-9 * (1.0 + full.d_point.norm()), "{model}");
                assert_eq!(fixed.d_params.norm(), 0.0, "{model}: no intrinsics Jacobian on the constant path");
            }
        }
        let cam = sample_camera(CameraModelId::FullOpenCv);
        assert!(reprojection_jacobians_with(&cam, &pose, &Vec3::new(0.0, 0.0, -1.0), &obs, false).is_none());
    }

    #[test]
    fn points_behind_do_not_project() {
        let cam = sample_camera(CameraModelId::SimplePinhole);
        let pose = Rigid3::identity();
        assert!(reprojection_jacobians(&cam, &pose, &Vec3::new(0.0, 0.0, -1.0), &Vec2::zeros()).is_none());
        assert!(reprojection_residual(&cam, &pose, &Vec3::new(f64::NAN, 0.0, 1.0), &Vec2::zeros()).is_none());
    }
}

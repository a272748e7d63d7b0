//! Deterministic synthetic scenes for tests and benchmarks: random poses,
//! points in front of the cameras, optional Gaussian noise and outliers, all
//! in normalised image coordinates.

use crate::{Vec2, Vec3};
use colslam_geometry::{Quat, Rigid3, SplitMix64};

/// Half-width of the synthetic field of view in normalised units (about
/// 2 x 31 degrees).
pub const HALF_FOV: f64 = 0.6;

/// A two-view scene.
#[derive(Debug, Clone)]
pub struct RelativeScene {
    /// Ground-truth pose of camera 2 relative to camera 1.
    pub cam2_from_cam1: Rigid3,
    /// Points in camera-1 coordinates (for outliers: the uncorrupted point).
    pub points: Vec<Vec3>,
    /// Observations in camera 1.
    pub x1: Vec<Vec2>,
    /// Observations in camera 2.
    pub x2: Vec<Vec2>,
    /// False for correspondences replaced by outliers.
    pub is_inlier: Vec<bool>,
}

/// A scene for absolute pose.
#[derive(Debug, Clone)]
pub struct AbsoluteScene {
    /// Ground-truth camera pose.
    pub cam_from_world: Rigid3,
    /// World points.
    pub points3d: Vec<Vec3>,
    /// Observations (normalised).
    pub points2d: Vec<Vec2>,
    /// False for correspondences replaced by outliers.
    pub is_inlier: Vec<bool>,
}

/// A random rotation of angle up to `max_angle` radians about a random axis.
pub fn random_rotation(rng: &mut SplitMix64, max_angle: f64) -> Quat {
    let axis = random_unit(rng);
    let angle = rng.uniform(-max_angle, max_angle);
    Quat::from_scaled_axis(axis * angle)
}

/// A uniformly distributed unit vector.
pub fn random_unit(rng: &mut SplitMix64) -> Vec3 {
    loop {
        let v = Vec3::new(rng.normal(), rng.normal(), rng.normal());
        let n = v.norm();
        if n > 1e-6 {
            return v / n;
        }
    }
}

fn project(p: &Vec3) -> Vec2 {
    Vec2::new(p.x / p.z, p.y / p.z)
}

/// Half-width of the wide field of view of [`relative_scene_wide`]
/// (2 x 45 degrees).
pub const WIDE_HALF_FOV: f64 = 1.0;

fn random_point_in_view(rng: &mut SplitMix64, min_depth: f64, max_depth: f64) -> Vec3 {
    random_point_in_fov(rng, min_depth, max_depth, HALF_FOV)
}

fn random_point_in_fov(rng: &mut SplitMix64, min_depth: f64, max_depth: f64, half_fov: f64) -> Vec3 {
    let d = rng.uniform(min_depth, max_depth);
    Vec3::new(rng.uniform(-half_fov, half_fov) * d, rng.uniform(-half_fov, half_fov) * d, d)
}

fn outlier_point(rng: &mut SplitMix64) -> Vec2 {
    Vec2::new(rng.uniform(-HALF_FOV, HALF_FOV), rng.uniform(-HALF_FOV, HALF_FOV))
}

/// Two views with a baseline of length ~1 and a rotation up to ~17 degrees;
/// points at depth 2-8 in camera 1, visible in both. `noise` is the standard
/// deviation of the image noise (normalised units); a fraction
/// `outlier_ratio` of the correspondences gets a random second observation.
pub fn relative_scene(seed: u64, n: usize, noise: f64, outlier_ratio: f64) -> RelativeScene {
    let mut rng = SplitMix64::new(seed);
    let rot = random_rotation(&mut rng, 0.3);
    let t = random_unit(&mut rng) * rng.uniform(0.5, 1.0);
    let pose = Rigid3::new(rot, t);
    relative_scene_with_pose(&mut rng, pose, n, noise, outlier_ratio, (2.0, 8.0))
}

/// Like [`relative_scene`] with a 90-degree field of view
/// ([`WIDE_HALF_FOV`]): the rotation/translation ambiguity of narrow fields
/// of view is weaker, so the pose is better conditioned.
pub fn relative_scene_wide(seed: u64, n: usize, noise: f64, outlier_ratio: f64) -> RelativeScene {
    let mut rng = SplitMix64::new(seed);
    let rot = random_rotation(&mut rng, 0.3);
    let t = random_unit(&mut rng) * rng.uniform(0.5, 1.0);
    let pose = Rigid3::new(rot, t);
    scene_impl(&mut rng, pose, n, noise, outlier_ratio, (2.0, 8.0), WIDE_HALF_FOV)
}

/// Like [`relative_scene`] but with the given pose and depth range.
pub fn relative_scene_with_pose(
    rng: &mut SplitMix64,
    cam2_from_cam1: Rigid3,
    n: usize,
    noise: f64,
    outlier_ratio: f64,
    depth: (f64, f64),
) -> RelativeScene {
    scene_impl(rng, cam2_from_cam1, n, noise, outlier_ratio, depth, HALF_FOV)
}

fn scene_impl(
    rng: &mut SplitMix64,
    cam2_from_cam1: Rigid3,
    n: usize,
    noise: f64,
    outlier_ratio: f64,
    depth: (f64, f64),
    half_fov: f64,
) -> RelativeScene {
    let n_out = (n as f64 * outlier_ratio).round() as usize;
    let mut s = RelativeScene { cam2_from_cam1, points: vec![], x1: vec![], x2: vec![], is_inlier: vec![] };
    while s.points.len() < n {
        let p = random_point_in_fov(rng, depth.0, depth.1, half_fov);
        let q = cam2_from_cam1.transform_point(&p);
        if q.z < 0.1 * depth.0 {
            continue;
        }
        let inlier = s.points.len() >= n_out;
        let noise1 = Vec2::new(rng.normal(), rng.normal()) * noise;
        let noise2 = Vec2::new(rng.normal(), rng.normal()) * noise;
        s.x1.push(project(&p) + noise1);
        let outlier = Vec2::new(rng.uniform(-half_fov, half_fov), rng.uniform(-half_fov, half_fov));
        s.x2.push(if inlier { project(&q) + noise2 } else { outlier });
        s.points.push(p);
        s.is_inlier.push(inlier);
    }
    s
}

/// Two views of points on one plane (`z = 4 + 0.3 x - 0.2 y` in camera 1).
pub fn planar_scene(seed: u64, n: usize, noise: f64, outlier_ratio: f64) -> RelativeScene {
    let mut rng = SplitMix64::new(seed);
    let rot = random_rotation(&mut rng, 0.3);
    let t = random_unit(&mut rng) * rng.uniform(0.5, 1.0);
    let pose = Rigid3::new(rot, t);
    let n_out = (n as f64 * outlier_ratio).round() as usize;
    let mut s = RelativeScene { cam2_from_cam1: pose, points: vec![], x1: vec![], x2: vec![], is_inlier: vec![] };
    while s.points.len() < n {
        let (u, v) = (rng.uniform(-HALF_FOV, HALF_FOV), rng.uniform(-HALF_FOV, HALF_FOV));
        // Ray (u, v, 1) meets the plane z = 4 + 0.3 x - 0.2 y at this depth.
        let d = 4.0 / (1.0 - 0.3 * u + 0.2 * v);
        let p = Vec3::new(u * d, v * d, d);
        let q = pose.transform_point(&p);
        if q.z < 0.5 {
            continue;
        }
        let inlier = s.points.len() >= n_out;
        s.x1.push(project(&p) + Vec2::new(rng.normal(), rng.normal()) * noise);
        s.x2.push(if inlier {
            project(&q) + Vec2::new(rng.normal(), rng.normal()) * noise
        } else {
            outlier_point(&mut rng)
        });
        s.points.push(p);
        s.is_inlier.push(inlier);
    }
    s
}

/// A camera looking at points at depth 2-8 (in camera coordinates) with a
/// random pose; outliers get a random observation.
pub fn absolute_scene(seed: u64, n: usize, noise: f64, outlier_ratio: f64) -> AbsoluteScene {
    let mut rng = SplitMix64::new(seed);
    let rot = random_rotation(&mut rng, std::f64::consts::PI);
    let t = Vec3::new(rng.normal(), rng.normal(), rng.normal());
    let pose = Rigid3::new(rot, t);
    let world_from_cam = pose.inverse();
    let n_out = (n as f64 * outlier_ratio).round() as usize;
    let mut s = AbsoluteScene { cam_from_world: pose, points3d: vec![], points2d: vec![], is_inlier: vec![] };
    for i in 0..n {
        let pc = random_point_in_view(&mut rng, 2.0, 8.0);
        let inlier = i >= n_out;
        s.points3d.push(world_from_cam.transform_point(&pc));
        s.points2d.push(if inlier {
            project(&pc) + Vec2::new(rng.normal(), rng.normal()) * noise
        } else {
            outlier_point(&mut rng)
        });
        s.is_inlier.push(inlier);
    }
    s
}

/// Angle between two rotations, in degrees.
pub fn rotation_error_deg(a: &Rigid3, b: &Rigid3) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

/// Angle between two translation directions, in degrees (0 when either is 0).
pub fn translation_dir_error_deg(a: &Vec3, b: &Vec3) -> f64 {
    let (na, nb) = (a.norm(), b.norm());
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    (a.dot(b) / (na * nb)).clamp(-1.0, 1.0).acos().to_degrees()
}

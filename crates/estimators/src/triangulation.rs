//! Triangulation of a point from two or more calibrated views: linear DLT
//! (Hartley & Zisserman, §12.2) followed by Gauss-Newton refinement of the
//! reprojection error, then COLMAP's acceptance checks (positive depth,
//! minimum triangulation angle, maximum reprojection error), reporting why a
//! point was rejected.

use crate::error::EstimatorError;
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use nalgebra::{DMatrix, SMatrix};

/// Options of [`triangulate_multiview`].
#[derive(Debug, Clone, PartialEq)]
pub struct TriangulationOptions {
    /// Minimum triangulation angle in degrees (largest angle between two
    /// viewing rays). Default 1.5 (COLMAP's `filter_min_tri_angle`).
    pub min_tri_angle_deg: f64,
    /// Maximum reprojection error in any view, normalised units. Default
    /// 8e-3 (4 px at a 500 px focal length, COLMAP's `filter_max_reproj_error`).
    pub max_reproj_error: f64,
    /// Gauss-Newton iterations after the DLT (0 disables). Default 10.
    pub refine_iterations: usize,
}

impl Default for TriangulationOptions {
    fn default() -> Self {
        Self { min_tri_angle_deg: 1.5, max_reproj_error: 8e-3, refine_iterations: 10 }
    }
}

impl TriangulationOptions {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), EstimatorError> {
        if !(self.min_tri_angle_deg >= 0.0 && self.min_tri_angle_deg < 180.0) {
            return Err(EstimatorError::InvalidOptions(format!(
                "min_tri_angle_deg must lie in [0, 180), got {}",
                self.min_tri_angle_deg
            )));
        }
        if !(self.max_reproj_error > 0.0) {
            return Err(EstimatorError::InvalidOptions(format!(
                "max_reproj_error must be positive, got {}",
                self.max_reproj_error
            )));
        }
        Ok(())
    }
}

/// An accepted point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangulatedPoint {
    /// The point in world coordinates.
    pub point: Vec3,
    /// Largest angle between two viewing rays, degrees.
    pub tri_angle_deg: f64,
    /// Largest reprojection error over the views (normalised units).
    pub max_reproj_error: f64,
    /// Mean reprojection error over the views.
    pub mean_reproj_error: f64,
}

/// Why a point was not triangulated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TriangulationRejection {
    /// Invalid options.
    #[error(transparent)]
    InvalidOptions(#[from] EstimatorError),
    /// Fewer than two views.
    #[error("need at least two views, got {0}")]
    TooFewViews(usize),
    /// Poses and observations differ in number.
    #[error("{poses} poses but {observations} observations")]
    LengthMismatch {
        /// Number of poses.
        poses: usize,
        /// Number of observations.
        observations: usize,
    },
    /// A pose or observation is not finite (or beyond [`crate::error::MAX_COORD`]).
    #[error("observation or pose {0} is not finite or out of range")]
    NonFinite(usize),
    /// The linear system has no finite solution (parallel rays, point at infinity).
    #[error("degenerate configuration (parallel rays or point at infinity)")]
    Degenerate,
    /// The point is behind (or on the plane of) a camera.
    #[error("point has non-positive depth {depth} in view {view}")]
    NegativeDepth {
        /// The view.
        view: usize,
        /// The depth.
        depth: f64,
    },
    /// The triangulation angle is too small.
    #[error("triangulation angle {angle_deg} deg below the minimum")]
    SmallAngle {
        /// The largest angle between two rays, degrees.
        angle_deg: f64,
    },
    /// A view's reprojection error is too large.
    #[error("reprojection error {error} in view {view} exceeds the maximum")]
    LargeReprojError {
        /// The view.
        view: usize,
        /// Its reprojection error (normalised units).
        error: f64,
    },
}

/// Angle (radians) at `point` between the rays to the two camera centres.
pub fn triangulation_angle(center1: &Vec3, center2: &Vec3, point: &Vec3) -> f64 {
    let a = center1 - point;
    let b = center2 - point;
    let (na, nb) = (a.norm(), b.norm());
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    (a.dot(&b) / (na * nb)).clamp(-1.0, 1.0).acos()
}

fn reproj(pose: &Rigid3, x: &Vec3, obs: &Vec2) -> Option<f64> {
    let c = pose.transform_point(x);
    (c.z > 0.0).then(|| (Vec2::new(c.x / c.z, c.y / c.z) - obs).norm())
}

/// Linear (DLT) triangulation; `None` for a point at infinity.
fn dlt(poses: &[Rigid3], obs: &[Vec2]) -> Option<Vec3> {
    let n = poses.len();
    let mut a = DMatrix::<f64>::zeros((2 * n).max(4), 4);
    for (i, (p, u)) in poses.iter().zip(obs).enumerate() {
        let m = p.matrix3x4();
        for c in 0..4 {
            a[(2 * i, c)] = u.x * m[(2, c)] - m[(0, c)];
            a[(2 * i + 1, c)] = u.y * m[(2, c)] - m[(1, c)];
        }
    }
    if !crate::error::all_finite(a.iter()) {
        return None;
    }
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    // Singular values are sorted descending: the last row is the solution.
    let x = vt.row(3);
    let w = x[3];
    let xyz = Vec3::new(x[0], x[1], x[2]);
    if w.abs() <= 1e-12 * xyz.norm() || !w.is_finite() {
        return None;
    }
    let p = xyz / w;
    p.iter().all(|v| v.is_finite()).then_some(p)
}

/// Gauss-Newton on the reprojection error; keeps only improving steps.
fn refine(poses: &[Rigid3], obs: &[Vec2], mut x: Vec3, iterations: usize) -> Vec3 {
    let cost = |x: &Vec3| -> f64 {
        poses.iter().zip(obs).map(|(p, u)| reproj(p, x, u).map_or(f64::INFINITY, |e| e * e)).sum()
    };
    let mut c = cost(&x);
    for _ in 0..iterations {
        let mut jtj = Mat3::zeros();
        let mut jtr = Vec3::zeros();
        for (p, u) in poses.iter().zip(obs) {
            let pc = p.transform_point(&x);
            if pc.z <= 0.0 {
                return x;
            }
            let iz = 1.0 / pc.z;
            let r = Vec2::new(pc.x * iz - u.x, pc.y * iz - u.y);
            let dp = SMatrix::<f64, 2, 3>::new(iz, 0.0, -pc.x * iz * iz, 0.0, iz, -pc.y * iz * iz);
            let j = dp * p.rotation_matrix();
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
        }
        let Some(step) = jtj.cholesky().map(|ch| ch.solve(&jtr)) else {
            return x;
        };
        let nx = x - step;
        let nc = cost(&nx);
        if !(nc < c) {
            return x;
        }
        x = nx;
        c = nc;
    }
    x
}

/// Triangulates one point seen in `cams_from_world.len() >= 2` views at the
/// normalised image points `points`, then checks it.
pub fn triangulate_multiview(
    cams_from_world: &[Rigid3],
    points: &[Vec2],
    opts: &TriangulationOptions,
) -> Result<TriangulatedPoint, TriangulationRejection> {
    opts.validate()?;
    if cams_from_world.len() != points.len() {
        return Err(TriangulationRejection::LengthMismatch {
            poses: cams_from_world.len(),
            observations: points.len(),
        });
    }
    if points.len() < 2 {
        return Err(TriangulationRejection::TooFewViews(points.len()));
    }
    for (i, (p, u)) in cams_from_world.iter().zip(points).enumerate() {
        let values = || u.iter().chain(p.translation.iter()).chain(p.rotation.coords.iter());
        let finite = crate::error::all_finite(values()) && crate::error::all_in_range(values());
        if !finite {
            return Err(TriangulationRejection::NonFinite(i));
        }
    }
    let x0 = dlt(cams_from_world, points).ok_or(TriangulationRejection::Degenerate)?;
    for (view, p) in cams_from_world.iter().enumerate() {
        let depth = p.transform_point(&x0).z;
        if !(depth > 0.0) {
            return Err(TriangulationRejection::NegativeDepth { view, depth });
        }
    }
    let x = refine(cams_from_world, points, x0, opts.refine_iterations);
    let centers: Vec<Vec3> = cams_from_world.iter().map(|p| p.center()).collect();
    let mut angle: f64 = 0.0;
    for i in 0..centers.len() {
        for j in i + 1..centers.len() {
            angle = angle.max(triangulation_angle(&centers[i], &centers[j], &x));
        }
    }
    let angle_deg = angle.to_degrees();
    let (mut max_err, mut sum_err) = (0.0f64, 0.0);
    for (view, (p, u)) in cams_from_world.iter().zip(points).enumerate() {
        let depth = p.transform_point(&x).z;
        if !(depth > 0.0) {
            return Err(TriangulationRejection::NegativeDepth { view, depth });
        }
        let e = reproj(p, &x, u).unwrap_or(f64::INFINITY);
        if e > opts.max_reproj_error {
            return Err(TriangulationRejection::LargeReprojError { view, error: e });
        }
        max_err = max_err.max(e);
        sum_err += e;
    }
    if angle_deg < opts.min_tri_angle_deg {
        return Err(TriangulationRejection::SmallAngle { angle_deg });
    }
    Ok(TriangulatedPoint {
        point: x,
        tri_angle_deg: angle_deg,
        max_reproj_error: max_err,
        mean_reproj_error: sum_err / points.len() as f64,
    })
}

/// Two-view convenience wrapper of [`triangulate_multiview`].
pub fn triangulate_two_view(
    cam1_from_world: &Rigid3,
    cam2_from_world: &Rigid3,
    x1: &Vec2,
    x2: &Vec2,
    opts: &TriangulationOptions,
) -> Result<TriangulatedPoint, TriangulationRejection> {
    triangulate_multiview(&[*cam1_from_world, *cam2_from_world], &[*x1, *x2], opts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{random_rotation, random_unit};
    use colslam_geometry::SplitMix64;

    fn views(seed: u64, n: usize) -> (Vec<Rigid3>, Vec3) {
        let mut rng = SplitMix64::new(seed);
        let x = Vec3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        let poses = (0..n)
            .map(|_| {
                // Camera about 5 units away, looking roughly at the point.
                let r = random_rotation(&mut rng, 0.2);
                let c = x - r.inverse() * Vec3::new(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 5.0)
                    + random_unit(&mut rng) * 0.01;
                Rigid3::new(r, -(r * c))
            })
            .collect();
        (poses, x)
    }

    fn project(p: &Rigid3, x: &Vec3) -> Vec2 {
        let c = p.transform_point(x);
        Vec2::new(c.x / c.z, c.y / c.z)
    }

    #[test]
    fn exact_on_noise_free_data() {
        let opts = TriangulationOptions { min_tri_angle_deg: 0.0, ..Default::default() };
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let (poses, x) = views(seed, 2 + seed as usize % 5);
            let obs: Vec<Vec2> = poses.iter().map(|p| project(p, &x)).collect();
            let t = triangulate_multiview(&poses, &obs, &opts).unwrap();
            worst = worst.max((t.point - x).norm());
            assert!(t.max_reproj_error < 1e-10);
        }
        assert!(worst < 1e-8, "worst triangulation error {worst}");
    }

    #[test]
    fn refinement_beats_dlt_under_noise() {
        let mut rng = SplitMix64::new(9);
        let (mut e_dlt, mut e_ref) = (0.0, 0.0);
        for seed in 0..50 {
            let (poses, x) = views(seed, 4);
            let obs: Vec<Vec2> =
                poses.iter().map(|p| project(p, &x) + Vec2::new(rng.normal(), rng.normal()) * 2e-3).collect();
            let d = dlt(&poses, &obs).unwrap();
            let r = refine(&poses, &obs, d, 10);
            let c = |y: &Vec3| poses.iter().zip(&obs).map(|(p, u)| (project(p, y) - u).norm_squared()).sum::<f64>();
            e_dlt += c(&d);
            e_ref += c(&r);
        }
        assert!(e_ref <= e_dlt);
    }

    #[test]
    fn rejections() {
        let o = TriangulationOptions::default();
        let (poses, x) = views(1, 2);
        let obs: Vec<Vec2> = poses.iter().map(|p| project(p, &x)).collect();
        assert_eq!(triangulate_multiview(&poses[..1], &obs[..1], &o), Err(TriangulationRejection::TooFewViews(1)));
        assert!(matches!(
            triangulate_multiview(&poses, &obs[..1], &o),
            Err(TriangulationRejection::LengthMismatch { .. })
        ));
        let mut bad = obs.clone();
        bad[1].x = f64::NAN;
        assert_eq!(triangulate_multiview(&poses, &bad, &o), Err(TriangulationRejection::NonFinite(1)));
        // Identical cameras: parallel rays.
        let same = [poses[0], poses[0]];
        let o_same = [obs[0], obs[0]];
        assert!(triangulate_multiview(&same, &o_same, &o).is_err());
        // Small baseline (cameras 1 cm apart at 5 m): small angle.
        let near = Rigid3::new(poses[0].rotation, poses[0].translation + Vec3::new(0.01, 0.0, 0.0));
        let obs2 = [obs[0], project(&near, &x)];
        assert!(matches!(
            triangulate_multiview(&[poses[0], near], &obs2, &o),
            Err(TriangulationRejection::SmallAngle { .. })
        ));
        // Point behind the cameras.
        let behind = Vec3::new(0.0, 0.0, -5.0);
        let p0 = Rigid3::identity();
        let p1 = Rigid3::new(colslam_geometry::Quat::identity(), Vec3::new(-1.0, 0.0, 0.0));
        let ob = [project(&p0, &behind), project(&p1, &behind)];
        assert!(matches!(triangulate_multiview(&[p0, p1], &ob, &o), Err(TriangulationRejection::NegativeDepth { .. })));
        // Inconsistent observations: large reprojection error.
        let (p3, x3) = views(2, 3);
        let mut wrong: Vec<Vec2> = p3.iter().map(|p| project(p, &x3)).collect();
        wrong[2] += Vec2::new(0.05, -0.05);
        let r = triangulate_multiview(&p3, &wrong, &o);
        assert!(matches!(r, Err(TriangulationRejection::LargeReprojError { .. })), "{r:?}");
        let two = triangulate_two_view(&poses[0], &poses[1], &obs[0], &obs[1], &o).unwrap();
        assert!((two.point - x).norm() < 1e-8);
    }
}

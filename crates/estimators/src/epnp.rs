//! EPnP: camera pose from `n >= 4` 2D-3D correspondences in O(n).
//!
//! Lepetit, Moreno-Noguer & Fua, "EPnP: An Accurate O(n) Solution to the PnP
//! Problem", IJCV 81(2), 2009. World points are written as barycentric
//! combinations of four control points (centroid + principal axes); the
//! camera-frame control points lie in the null space of a 2n x 12 system,
//! spanned by the four eigenvectors of `MᵀM` with the smallest eigenvalues.
//! Their weights `β` come from the paper's three linearisations, each refined
//! by Gauss-Newton on the control-point distance constraints; the candidate
//! with the smallest reprojection error wins.
//!
//! Planar point sets (a vanishing third principal axis) are reported as
//! degenerate: use P3P plus refinement for those.

use crate::error::{EstimatorError, all_finite, check_pairs, rigid_align};
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use nalgebra::{DMatrix, SMatrix, SVector};

const PROBLEM: &str = "EPnP";
/// Minimal number of correspondences.
pub const MIN_POINTS: usize = 4;
/// Smallest-to-largest principal variance ratio below which the points are
/// treated as planar (or collinear) and rejected.
const MIN_SPREAD_RATIO: f64 = 1e-10;
/// Gauss-Newton iterations on the betas (the paper uses 5).
const GN_ITERATIONS: usize = 5;

/// The six control-point pairs, in the paper's order.
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
/// The ten products β_k β_l (k <= l) in the paper's order.
const PRODUCTS: [(usize, usize); 10] = [(0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2), (0, 3), (1, 3), (2, 3), (3, 3)];

/// Camera pose (`cam_from_world`) from `n >= 4` correspondences between
/// normalised image points and non-planar world points.
pub fn estimate_epnp(points2d: &[Vec2], points3d: &[Vec3]) -> Result<Rigid3, EstimatorError> {
    check_pairs(PROBLEM, points2d, points3d, MIN_POINTS)?;
    solve(points2d, points3d)
        .ok_or(EstimatorError::Degenerate { problem: PROBLEM, reason: "planar, collinear or coincident world points" })
}

fn reprojection_sq_sum(pose: &Rigid3, p2: &[Vec2], p3: &[Vec3]) -> f64 {
    p2.iter()
        .zip(p3)
        .map(|(u, x)| {
            let c = pose.transform_point(x);
            if c.z <= 0.0 { f64::INFINITY } else { (Vec2::new(c.x / c.z, c.y / c.z) - u).norm_squared() }
        })
        .sum()
}

pub(crate) fn solve(p2: &[Vec2], p3: &[Vec3]) -> Option<Rigid3> {
    let n = p2.len();
    // Control points: centroid + principal axes scaled by their deviation.
    let c0 = p3.iter().sum::<Vec3>() / n as f64;
    let mut cov = Mat3::zeros();
    for x in p3 {
        let d = x - c0;
        cov += d * d.transpose();
    }
    cov /= n as f64;
    if !all_finite(cov.iter()) {
        return None;
    }
    let eig = cov.symmetric_eigen();
    let max_ev = eig.eigenvalues.max();
    if !(max_ev > 0.0) || eig.eigenvalues.min() <= MIN_SPREAD_RATIO * max_ev {
        return None;
    }
    let mut ctrl = [c0; 4];
    for j in 0..3 {
        ctrl[j + 1] = c0 + eig.eigenvectors.column(j) * eig.eigenvalues[j].sqrt();
    }
    let basis = Mat3::from_columns(&[ctrl[1] - c0, ctrl[2] - c0, ctrl[3] - c0]);
    let basis_inv = basis.try_inverse()?;
    let alphas: Vec<[f64; 4]> = p3
        .iter()
        .map(|x| {
            let a = basis_inv * (x - c0);
            [1.0 - a.x - a.y - a.z, a.x, a.y, a.z]
        })
        .collect();
    // MᵀM accumulated row by row (12 x 12).
    let mut mtm = SMatrix::<f64, 12, 12>::zeros();
    for (a, u) in alphas.iter().zip(p2) {
        let mut r1 = SVector::<f64, 12>::zeros();
        let mut r2 = SVector::<f64, 12>::zeros();
        for j in 0..4 {
            r1[3 * j] = a[j];
            r1[3 * j + 2] = -u.x * a[j];
            r2[3 * j + 1] = a[j];
            r2[3 * j + 2] = -u.y * a[j];
        }
        mtm += r1 * r1.transpose() + r2 * r2.transpose();
    }
    if !all_finite(mtm.iter()) {
        return None;
    }
    let eig = mtm.symmetric_eigen();
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let v: Vec<SVector<f64, 12>> = order[..4].iter().map(|&k| eig.eigenvectors.column(k).into()).collect();
    // L (6 x 10) and rho (6).
    let mut l = SMatrix::<f64, 6, 10>::zeros();
    let mut rho = SVector::<f64, 6>::zeros();
    for (p, &(a, b)) in PAIRS.iter().enumerate() {
        let dv: Vec<Vec3> = v
            .iter()
            .map(|vk| Vec3::new(vk[3 * a] - vk[3 * b], vk[3 * a + 1] - vk[3 * b + 1], vk[3 * a + 2] - vk[3 * b + 2]))
            .collect();
        for (m, &(k, kk)) in PRODUCTS.iter().enumerate() {
            let f = if k == kk { 1.0 } else { 2.0 };
            l[(p, m)] = f * dv[k].dot(&dv[kk]);
        }
        rho[p] = (ctrl[a] - ctrl[b]).norm_squared();
    }
    let lsq = |cols: &[usize]| -> Option<Vec<f64>> {
        let sub = DMatrix::from_fn(6, cols.len(), |r, c| l[(r, cols[c])]);
        if !all_finite(sub.iter().chain(rho.iter())) {
            return None;
        }
        let rhs = DMatrix::from_fn(6, 1, |r, _| rho[r]);
        let sol = sub.svd(true, true).solve(&rhs, 1e-14).ok()?;
        Some(sol.iter().copied().collect())
    };
    let mut inits: Vec<[f64; 4]> = Vec::new();
    if let Some(b) = lsq(&[0, 1, 3, 6]) {
        let (s, b0) = if b[0] < 0.0 { (-1.0, -b[0]) } else { (1.0, b[0]) };
        let b1 = b0.sqrt();
        if b1 > 0.0 {
            inits.push([b1, s * b[1] / b1, s * b[2] / b1, s * b[3] / b1]);
        }
    }
    if let Some(mut b) = lsq(&[0, 1, 2]) {
        if b[0] < 0.0 {
            b.iter_mut().for_each(|x| *x = -*x);
        }
        let b1 = b[0].max(0.0).sqrt();
        let b2 = b[2].max(0.0).sqrt() * b[1].signum();
        inits.push([b1, b2, 0.0, 0.0]);
    }
    if let Some(mut b) = lsq(&[0, 1, 2, 3, 4]) {
        if b[0] < 0.0 {
            b.iter_mut().for_each(|x| *x = -*x);
        }
        let b1 = b[0].max(0.0).sqrt();
        let b2 = b[2].max(0.0).sqrt() * b[1].signum();
        let b3 = if b1 > 0.0 { b[3] / b1 } else { 0.0 };
        inits.push([b1, b2, b3, 0.0]);
    }
    let mut best: Option<(f64, Rigid3)> = None;
    for init in inits {
        let beta = gauss_newton(&l, &rho, init);
        let Some(pose) = pose_from_betas(&beta, &v, &alphas, p3) else {
            continue;
        };
        let err = reprojection_sq_sum(&pose, p2, p3);
        if err.is_finite() && best.as_ref().is_none_or(|(e, _)| err < *e) {
            best = Some((err, pose));
        }
    }
    best.map(|(_, p)| p)
}

fn gauss_newton(l: &SMatrix<f64, 6, 10>, rho: &SVector<f64, 6>, mut beta: [f64; 4]) -> [f64; 4] {
    for _ in 0..GN_ITERATIONS {
        let mut j = SMatrix::<f64, 6, 4>::zeros();
        let mut r = SVector::<f64, 6>::zeros();
        for p in 0..6 {
            let mut val = 0.0;
            for (m, &(k, kk)) in PRODUCTS.iter().enumerate() {
                val += l[(p, m)] * beta[k] * beta[kk];
                j[(p, k)] += l[(p, m)] * beta[kk];
                j[(p, kk)] += l[(p, m)] * beta[k];
            }
            r[p] = val - rho[p];
        }
        if !all_finite(j.iter().chain(r.iter())) {
            break;
        }
        let Some(step) = j.svd(true, true).solve(&r, 1e-14).ok() else {
            break;
        };
        for k in 0..4 {
            beta[k] -= step[k];
        }
    }
    beta
}

fn pose_from_betas(beta: &[f64; 4], v: &[SVector<f64, 12>], alphas: &[[f64; 4]], p3: &[Vec3]) -> Option<Rigid3> {
    let mut c = SVector::<f64, 12>::zeros();
    for (b, vk) in beta.iter().zip(v) {
        c += vk * *b;
    }
    let ctrl: Vec<Vec3> = (0..4).map(|j| Vec3::new(c[3 * j], c[3 * j + 1], c[3 * j + 2])).collect();
    let mut cam: Vec<Vec3> =
        alphas.iter().map(|a| ctrl[0] * a[0] + ctrl[1] * a[1] + ctrl[2] * a[2] + ctrl[3] * a[3]).collect();
    // The null space fixes the control points up to sign: pick the sign
    // that puts the points in front of the camera.
    let front = cam.iter().filter(|p| p.z > 0.0).count();
    if 2 * front < cam.len() {
        cam.iter_mut().for_each(|p| *p = -*p);
    }
    rigid_align(p3, &cam)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::absolute_scene;

    #[test]
    fn exact_on_noise_free_data() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = absolute_scene(seed, 6 + seed as usize % 50, 0.0, 0.0);
            let p = estimate_epnp(&s.points2d, &s.points3d).unwrap();
            let err =
                p.rotation.angle_to(&s.cam_from_world.rotation) + (p.translation - s.cam_from_world.translation).norm();
            worst = worst.max(err);
        }
        assert!(worst < 1e-8, "worst EPnP error {worst}");
    }

    #[test]
    fn degenerate_inputs() {
        let p2 = vec![Vec2::new(0.1, 0.2); 6];
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 6];
        assert!(estimate_epnp(&p2, &same).is_err());
        let planar: Vec<Vec3> = (0..6).map(|i| Vec3::new(i as f64, (i * i) as f64, 5.0)).collect();
        assert!(estimate_epnp(&p2, &planar).is_err());
        assert!(matches!(estimate_epnp(&p2[..3], &same[..3]), Err(EstimatorError::TooFewPoints { .. })));
    }
}

//! Perspective-three-point: up to four camera poses from three 2D-3D
//! correspondences.
//!
//! The main solver (behind [`estimate_p3p`]) follows the idea of
//! Lambda Twist (Persson & Nordberg, ECCV 2018): intersect two conics of the
//! depth constraints through a degenerate member of their pencil (a pair of
//! planes), then polish the depths by Newton's method.
//!
//! Grunert's classical formulation (J. A. Grunert 1841, reviewed by Haralick,
//! Lee, Ottenberg & Nölle, IJCV 1994) is kept as an independent cross-check:
//! with the depths written `s2 = u s1`, `s3 = v s1`, the laws of cosines
//! reduce to one quartic in `v` after eliminating `u`. Both build their
//! polynomials with polynomial arithmetic rather than closed-form
//! coefficients. Each solution's camera-frame points are aligned to the world
//! points by the closed-form absolute orientation (Umeyama 1991).

use crate::error::{EstimatorError, all_finite, check_pairs, rigid_align};
use crate::poly;
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;

/// Minimal number of correspondences.
pub const SAMPLE_SIZE: usize = 3;
/// `|D(v)|` (the divisor that yields `u`) below this relative size is
/// treated as zero: `u` is then taken from the third law of cosines.
const SMALL_DIVISOR: f64 = 1e-10;

/// Camera poses (`cam_from_world`) consistent with three correspondences
/// between normalised image points and world points. Extra points beyond
/// the third are ignored. Empty when the configuration is degenerate
/// (collinear or coincident world points, parallel rays).
pub fn estimate_p3p(points2d: &[Vec2], points3d: &[Vec3]) -> Result<Vec<Rigid3>, EstimatorError> {
    check_pairs("P3P", points2d, points3d, SAMPLE_SIZE)?;
    let mut out = Vec::new();
    let b = |i: usize| Vec3::new(points2d[i].x, points2d[i].y, 1.0).normalize();
    solve([b(0), b(1), b(2)], [points3d[0], points3d[1], points3d[2]], &mut out);
    Ok(out)
}

/// Like [`estimate_p3p`] but with Grunert's quartic (an independent
/// formulation, useful as a cross-check).
pub fn estimate_p3p_grunert(points2d: &[Vec2], points3d: &[Vec3]) -> Result<Vec<Rigid3>, EstimatorError> {
    check_pairs("P3P (Grunert)", points2d, points3d, SAMPLE_SIZE)?;
    let mut out = Vec::new();
    let b = |i: usize| Vec3::new(points2d[i].x, points2d[i].y, 1.0).normalize();
    solve_grunert([b(0), b(1), b(2)], [points3d[0], points3d[1], points3d[2]], &mut out);
    Ok(out)
}

/// Grunert's formulation on unit bearing vectors `f` and world points `x`
/// (kept as an independent cross-check of [`solve`]).
fn solve_grunert(f: [Vec3; 3], x: [Vec3; 3], out: &mut Vec<Rigid3>) {
    let a2 = (x[1] - x[2]).norm_squared();
    let b2 = (x[0] - x[2]).norm_squared();
    let c2 = (x[0] - x[1]).norm_squared();
    let scale = a2.max(b2).max(c2);
    // Collinear or coincident world points have no unique solution.
    let area2 = (x[1] - x[0]).cross(&(x[2] - x[0])).norm_squared();
    if !(scale > 0.0) || area2 <= 1e-20 * scale * scale {
        return;
    }
    let (ca, cb, cg) = (f[1].dot(&f[2]), f[0].dot(&f[2]), f[0].dot(&f[1]));
    let q = [1.0, -2.0 * cb, 1.0];
    let n = poly::sub(&q.iter().map(|c| c * (a2 - c2)).collect::<Vec<_>>(), &[b2, 0.0, -b2]);
    let d = [-2.0 * b2 * ca, 2.0 * b2 * cg];
    let d2 = poly::mul(&d, &d);
    let nn = poly::mul(&n, &n);
    let nd = poly::mul(&n, &d);
    let lhs = poly::sub(&poly::add(&d2, &nn), &nd.iter().map(|c| 2.0 * cg * c).collect::<Vec<_>>());
    let lhs: Vec<f64> = lhs.iter().map(|c| b2 * c).collect();
    let rhs: Vec<f64> = poly::mul(&q, &d2).iter().map(|c| c2 * c).collect();
    let quartic = poly::sub(&lhs, &rhs);
    for v in poly::real_roots(&quartic) {
        if !(v > 0.0) {
            continue;
        }
        let qv = 1.0 + v * v - 2.0 * v * cb;
        if !(qv > 0.0) {
            continue;
        }
        let dv = poly::eval_with_derivative(&d, v).0;
        let nv = poly::eval_with_derivative(&n, v).0;
        let mut us = Vec::with_capacity(2);
        if dv.abs() > SMALL_DIVISOR * b2 {
            us.push(nv / dv);
        } else {
            // b²(1 + u² - 2u cγ) = c² Q(v): quadratic in u.
            let (qa, qb, qc) = (b2, -2.0 * b2 * cg, b2 - c2 * qv);
            let disc = qb * qb - 4.0 * qa * qc;
            if disc >= 0.0 {
                us.push((-qb + disc.sqrt()) / (2.0 * qa));
                us.push((-qb - disc.sqrt()) / (2.0 * qa));
            }
        }
        for u in us {
            if !(u > 0.0) {
                continue;
            }
            let s1 = (b2 / qv).sqrt();
            let depths = polish_depths([s1, u * s1, v * s1], [cg, cb, ca], [c2, b2, a2]);
            let cam = [f[0] * depths[0], f[1] * depths[1], f[2] * depths[2]];
            if let Some(pose) = rigid_align(&x, &cam) {
                out.push(pose);
            }
        }
    }
}

/// Solver on unit bearing vectors `f` and world points `x`: the
/// degenerate-conic construction of Lambda Twist (Persson & Nordberg,
/// "Lambda Twist: An Accurate Fast Robust Perspective Three Point (P3P)
/// Solver", ECCV 2018), derived here as follows. With depths `Λ`, the three
/// constraints are quadratic forms `Λᵀ M_ij Λ = a_ij`. Eliminating the
/// right-hand sides gives two homogeneous conics `D1 = a23 M12 - a12 M23`,
/// `D2 = a23 M13 - a13 M23`; a member `D0 = D1 + γ D2` of their pencil with
/// `det D0 = 0` (a cubic in γ) is a pair of planes through the origin, found
/// from its eigen-decomposition. On each plane `Λ` has one free ratio `τ`,
/// fixed by a quadratic from `D1` (or `D2`), and the scale comes from
/// `Λᵀ M12 Λ = a12`. The depths are then polished by Newton's method and the
/// pose follows from absolute orientation.
pub(crate) fn solve(f: [Vec3; 3], x: [Vec3; 3], out: &mut Vec<Rigid3>) {
    let a12 = (x[0] - x[1]).norm_squared();
    let a13 = (x[0] - x[2]).norm_squared();
    let a23 = (x[1] - x[2]).norm_squared();
    let scale = a12.max(a13).max(a23);
    let area2 = (x[1] - x[0]).cross(&(x[2] - x[0])).norm_squared();
    if !(scale > 0.0) || area2 <= 1e-20 * scale * scale {
        return;
    }
    let (b12, b13, b23) = (f[0].dot(&f[1]), f[0].dot(&f[2]), f[1].dot(&f[2]));
    let m12 = Mat3::new(1.0, -b12, 0.0, -b12, 1.0, 0.0, 0.0, 0.0, 0.0);
    let m13 = Mat3::new(1.0, 0.0, -b13, 0.0, 0.0, 0.0, -b13, 0.0, 1.0);
    let m23 = Mat3::new(0.0, 0.0, 0.0, 0.0, 1.0, -b23, 0.0, -b23, 1.0);
    let d1 = m12 * a23 - m23 * a12;
    let d2 = m13 * a23 - m23 * a13;
    // det(D1 + γ D2) as a cubic in γ; entries are [slope, offset].
    let m = |i: usize, j: usize| vec![d2[(i, j)], d1[(i, j)]];
    let cof = |r1: usize, r2: usize, c1: usize, c2: usize| {
        poly::sub(&poly::mul(&m(r1, c1), &m(r2, c2)), &poly::mul(&m(r1, c2), &m(r2, c1)))
    };
    let det = poly::add(
        &poly::sub(&poly::mul(&m(0, 0), &cof(1, 2, 1, 2)), &poly::mul(&m(0, 1), &cof(1, 2, 0, 2))),
        &poly::mul(&m(0, 2), &cof(1, 2, 0, 1)),
    );
    // Every real root gives the same intersection; take the best-conditioned
    // pair of planes (largest smaller non-zero eigenvalue relative to ‖D0‖).
    let mut best: Option<(f64, nalgebra::SymmetricEigen<f64, nalgebra::U3>)> = None;
    for g in poly::real_roots(&det) {
        let d0 = d1 + d2 * g;
        if !all_finite(d0.iter()) {
            continue;
        }
        let eig = d0.symmetric_eigen();
        let mut ev: Vec<f64> = eig.eigenvalues.iter().map(|v| v.abs()).collect();
        ev.sort_by(f64::total_cmp);
        let quality = ev[1] / ev[2].max(f64::MIN_POSITIVE);
        if best.as_ref().is_none_or(|(q, _)| quality > *q) {
            best = Some((quality, eig));
        }
    }
    let Some((_, eig)) = best else {
        return;
    };
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    // Eigenvalues sorted descending: σa > 0 ≈ σ0 > σb for an indefinite pair.
    let (sa, sb) = (eig.eigenvalues[idx[0]], eig.eigenvalues[idx[2]]);
    if !(sa > 0.0 && sb < 0.0) {
        return; // semidefinite: the conic is a single line or point
    }
    let ea: Vec3 = eig.eigenvectors.column(idx[0]).into();
    let eb: Vec3 = eig.eigenvectors.column(idx[2]).into();
    let s = (-sb / sa).sqrt();
    let cg = [b12, b13, b23];
    let d2s = [a12, a13, a23];
    for n in [ea - eb * s, ea + eb * s] {
        // On the plane nᵀΛ = 0 solve for the component with the largest
        // coefficient: Λ = λj (τ A + B).
        let k = n.iamax();
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        let mut a = Vec3::zeros();
        let mut b = Vec3::zeros();
        a[i] = 1.0;
        a[k] = -n[i] / n[k];
        b[j] = 1.0;
        b[k] = -n[j] / n[k];
        let quad = |d: &Mat3| [a.dot(&(d * a)), 2.0 * a.dot(&(d * b)), b.dot(&(d * b))];
        let (q1, q2) = (quad(&d1), quad(&d2));
        let norm = |q: &[f64; 3]| q.iter().map(|v| v * v).sum::<f64>();
        let q = if norm(&q1) >= norm(&q2) { q1 } else { q2 };
        for tau in poly::real_roots(&q) {
            let w = a * tau + b;
            let den = w.dot(&(m12 * w));
            if !(den > 0.0) {
                continue;
            }
            let lj = (a12 / den).sqrt();
            let lam = w * lj;
            // Depths of one sign: flip an all-negative solution (the
            // quadratic forms are even in Λ).
            let lam = if lam.iter().all(|v| *v < 0.0) { -lam } else { lam };
            if !lam.iter().all(|v| *v > 0.0) {
                continue;
            }
            let depths = polish_depths([lam[0], lam[1], lam[2]], cg, d2s);
            let cam = [f[0] * depths[0], f[1] * depths[1], f[2] * depths[2]];
            if let Some(pose) = rigid_align(&x, &cam) {
                out.push(pose);
            }
        }
    }
}

/// Newton steps refining the three depths on the laws of cosines.
const DEPTH_NEWTON_STEPS: usize = 3;

/// Refines depths `s` so that `s_i² + s_j² - 2 s_i s_j c_ij = d_ij²` for the
/// pairs (0,1), (0,2), (1,2) (cosines `c` and squared distances `d2` in that
/// order), as Lambda Twist does after its closed form. Keeps the input when a
/// step does not reduce the residual.
fn polish_depths(mut s: [f64; 3], c: [f64; 3], d2: [f64; 3]) -> [f64; 3] {
    const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];
    let residual = |s: &[f64; 3]| -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::from_fn(|k, _| {
            let (i, j) = PAIRS[k];
            s[i] * s[i] + s[j] * s[j] - 2.0 * s[i] * s[j] * c[k] - d2[k]
        })
    };
    let mut r = residual(&s);
    for _ in 0..DEPTH_NEWTON_STEPS {
        let mut jac = nalgebra::Matrix3::<f64>::zeros();
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            jac[(k, i)] = 2.0 * s[i] - 2.0 * s[j] * c[k];
            jac[(k, j)] = 2.0 * s[j] - 2.0 * s[i] * c[k];
        }
        let Some(step) = jac.lu().solve(&r) else {
            break;
        };
        let cand = [s[0] - step[0], s[1] - step[1], s[2] - step[2]];
        let rc = residual(&cand);
        if !(rc.norm() < r.norm()) {
            break;
        }
        s = cand;
        r = rc;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::absolute_scene;

    #[test]
    fn exact_on_noise_free_data() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = absolute_scene(seed, 3, 0.0, 0.0);
            let poses = estimate_p3p(&s.points2d, &s.points3d).unwrap();
            let err = poses
                .iter()
                .map(|p| {
                    p.rotation.angle_to(&s.cam_from_world.rotation)
                        + (p.translation - s.cam_from_world.translation).norm()
                })
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(err);
        }
        assert!(worst < 1e-8, "worst P3P error {worst}");
    }

    /// Far, narrow configurations (points ~50 units away spread over ~2
    /// units: a 2-degree field of view) stay accurate.
    #[test]
    fn narrow_field_of_view() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let mut rng = colslam_geometry::SplitMix64::new(seed);
            let pose = Rigid3::new(
                crate::synthetic::random_rotation(&mut rng, 3.0),
                Vec3::new(rng.normal(), rng.normal(), rng.normal()),
            );
            let inv = pose.inverse();
            let cam: Vec<Vec3> = (0..3)
                .map(|_| Vec3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(48.0, 52.0)))
                .collect();
            let p3: Vec<Vec3> = cam.iter().map(|c| inv.transform_point(c)).collect();
            let p2: Vec<Vec2> = cam.iter().map(|c| Vec2::new(c.x / c.z, c.y / c.z)).collect();
            let poses = estimate_p3p(&p2, &p3).unwrap();
            let err = poses
                .iter()
                .map(|p| p.rotation.angle_to(&pose.rotation) + (p.translation - pose.translation).norm() / 50.0)
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(err);
        }
        assert!(worst < 1e-7, "worst narrow-FOV P3P error {worst}");
    }

    /// Lambda Twist and Grunert find the same solution sets.
    #[test]
    fn agrees_with_grunert() {
        for seed in 0..100 {
            let s = absolute_scene(seed, 3, 0.0, 0.0);
            let f: Vec<Vec3> = s.points2d.iter().map(|p| Vec3::new(p.x, p.y, 1.0).normalize()).collect();
            let x = [s.points3d[0], s.points3d[1], s.points3d[2]];
            let (mut a, mut b) = (Vec::new(), Vec::new());
            solve([f[0], f[1], f[2]], x, &mut a);
            solve_grunert([f[0], f[1], f[2]], x, &mut b);
            for p in &b {
                let d = a
                    .iter()
                    .map(|q| q.rotation.angle_to(&p.rotation) + (q.translation - p.translation).norm())
                    .fold(f64::INFINITY, f64::min);
                assert!(d < 1e-7, "seed {seed}: Grunert solution missing from Lambda Twist ({d})");
            }
        }
    }

    #[test]
    fn degenerate_inputs() {
        let p2 = vec![Vec2::new(0.0, 0.0), Vec2::new(0.1, 0.0), Vec2::new(0.2, 0.0)];
        let collinear = vec![Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.5, 0.0, 5.0), Vec3::new(1.0, 0.0, 5.0)];
        assert!(estimate_p3p(&p2, &collinear).unwrap().is_empty());
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 3];
        assert!(estimate_p3p(&p2, &same).unwrap().is_empty());
        assert!(matches!(estimate_p3p(&p2[..2], &same[..2]), Err(EstimatorError::TooFewPoints { .. })));
        let mut bad = same.clone();
        bad[1].z = f64::NAN;
        assert!(matches!(estimate_p3p(&p2, &bad), Err(EstimatorError::NonFinite { index: 1, .. })));
    }
}

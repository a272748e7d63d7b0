//! Fundamental matrix: the 7-point and the normalised 8-point algorithms
//! (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., §11.1-11.2;
//! Hartley, "In defense of the eight-point algorithm", TPAMI 1997).
//!
//! Both return `F` with `x2ᵀ F x1 = 0`, scaled to unit Frobenius norm. The
//! residual to use with them is [`crate::sampson_error_sq`].

use crate::error::{EstimatorError, all_finite, check_pairs};
use crate::poly;
use crate::{Mat3, Vec2, Vec3};
use nalgebra::{DMatrix, SMatrix, SVector};

/// Minimal sample of the 7-point algorithm.
pub const SAMPLE_SIZE_7PT: usize = 7;
/// Minimal sample of the 8-point algorithm.
pub const SAMPLE_SIZE_8PT: usize = 8;

/// Relative singular value below which a constraint counts as dependent.
const RANK_TOL: f64 = 1e-10;

/// Hartley normalisation: translate the centroid to the origin and scale the
/// mean distance to sqrt(2). Returns the 3x3 transform, or `None` when all
/// points coincide.
pub(crate) fn normalizing_transform(pts: &[Vec2]) -> Option<Mat3> {
    let n = pts.len() as f64;
    let c = pts.iter().sum::<Vec2>() / n;
    let mean_dist = pts.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    if !(mean_dist.is_finite() && mean_dist > 1e-12 * (1.0 + c.norm())) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    Some(Mat3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0))
}

pub(crate) fn apply(t: &Mat3, p: &Vec2) -> Vec3 {
    t * Vec3::new(p.x, p.y, 1.0)
}

/// Right singular vectors of the epipolar design matrix, sorted by
/// decreasing singular value (rows of the returned 9x9 `Vᵀ`).
///
/// `None` when fewer than `min_rank` constraints are independent (e.g.
/// collinear or coincident points), which would leave a larger null space.
fn epipolar_null_basis(a: &[Vec3], b: &[Vec3], min_rank: usize) -> Option<SMatrix<f64, 9, 9>> {
    let n = a.len();
    let rank_ok = |s: &SVector<f64, 9>| s[min_rank - 1] > RANK_TOL * s[0];
    let row = |i: usize| SVector::<f64, 9>::from_fn(|k, _| b[i][k / 3] * a[i][k % 3]).transpose();
    if n < 9 {
        let mut m = SMatrix::<f64, 9, 9>::zeros();
        for i in 0..n {
            m.set_row(i, &row(i));
        }
        if !all_finite(m.iter()) {
            return None;
        }
        let svd = m.svd(false, true);
        if !rank_ok(&svd.singular_values) {
            return None;
        }
        svd.v_t
    } else {
        let mut m = DMatrix::<f64>::zeros(n, 9);
        for i in 0..n {
            m.set_row(i, &row(i));
        }
        if !all_finite(m.iter()) {
            return None;
        }
        let svd = m.svd(false, true);
        let sv = SVector::<f64, 9>::from_fn(|k, _| svd.singular_values[k]);
        if !rank_ok(&sv) {
            return None;
        }
        let vt = svd.v_t?;
        Some(SMatrix::<f64, 9, 9>::from_fn(|r, c| vt[(r, c)]))
    }
}

fn finish(f: Mat3) -> Option<Mat3> {
    let n = f.norm();
    (n.is_finite() && n > 0.0).then(|| f / n)
}

/// The 7-point algorithm: up to three fundamental matrices from exactly 7
/// correspondences (extra points are ignored). Empty when degenerate.
pub fn estimate_fundamental_7pt(x1: &[Vec2], x2: &[Vec2]) -> Result<Vec<Mat3>, EstimatorError> {
    check_pairs("fundamental 7-point", x1, x2, SAMPLE_SIZE_7PT)?;
    let mut out = Vec::new();
    solve_7pt(&x1[..SAMPLE_SIZE_7PT], &x2[..SAMPLE_SIZE_7PT], &mut out);
    Ok(out)
}

pub(crate) fn solve_7pt(x1: &[Vec2], x2: &[Vec2], out: &mut Vec<Mat3>) {
    let (Some(t1), Some(t2)) = (normalizing_transform(x1), normalizing_transform(x2)) else {
        return;
    };
    let a: Vec<Vec3> = x1.iter().map(|p| apply(&t1, p)).collect();
    let b: Vec<Vec3> = x2.iter().map(|p| apply(&t2, p)).collect();
    let Some(vt) = epipolar_null_basis(&a, &b, SAMPLE_SIZE_7PT) else {
        return;
    };
    let f1 = Mat3::from_fn(|i, j| vt[(7, 3 * i + j)]);
    let f2 = Mat3::from_fn(|i, j| vt[(8, 3 * i + j)]);
    // det(f2 + s (f1 - f2)) is a cubic in s; entries are polynomials [slope, offset].
    let d = f1 - f2;
    let m = |i: usize, j: usize| vec![d[(i, j)], f2[(i, j)]];
    let cof = |r1: usize, r2: usize, c1: usize, c2: usize| {
        poly::sub(&poly::mul(&m(r1, c1), &m(r2, c2)), &poly::mul(&m(r1, c2), &m(r2, c1)))
    };
    let det = poly::add(
        &poly::sub(&poly::mul(&m(0, 0), &cof(1, 2, 1, 2)), &poly::mul(&m(0, 1), &cof(1, 2, 0, 2))),
        &poly::mul(&m(0, 2), &cof(1, 2, 0, 1)),
    );
    for s in poly::real_roots(&det) {
        let fnorm = f2 + d * s;
        if let Some(f) = finish(t2.transpose() * fnorm * t1) {
            out.push(f);
        }
    }
}

/// The normalised 8-point algorithm (least squares for more than 8 points),
/// with the rank-2 constraint enforced by zeroing the smallest singular value.
pub fn estimate_fundamental_8pt(x1: &[Vec2], x2: &[Vec2]) -> Result<Mat3, EstimatorError> {
    check_pairs("fundamental 8-point", x1, x2, SAMPLE_SIZE_8PT)?;
    solve_8pt(x1, x2).ok_or(EstimatorError::Degenerate {
        problem: "fundamental 8-point",
        reason: "coincident points or singular system",
    })
}

pub(crate) fn solve_8pt(x1: &[Vec2], x2: &[Vec2]) -> Option<Mat3> {
    let t1 = normalizing_transform(x1)?;
    let t2 = normalizing_transform(x2)?;
    let a: Vec<Vec3> = x1.iter().map(|p| apply(&t1, p)).collect();
    let b: Vec<Vec3> = x2.iter().map(|p| apply(&t2, p)).collect();
    let vt = epipolar_null_basis(&a, &b, SAMPLE_SIZE_8PT)?;
    let f = Mat3::from_fn(|i, j| vt[(8, 3 * i + j)]);
    if !all_finite(f.iter()) {
        return None;
    }
    let svd = f.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut s = svd.singular_values;
    s[2] = 0.0;
    let f = u * Mat3::from_diagonal(&s) * v_t;
    finish(t2.transpose() * f * t1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::essential_5pt::{essential_from_pose, sampson_error_sq};
    use crate::synthetic::relative_scene;

    fn fundamental_error(f: &Mat3, truth: &Mat3) -> f64 {
        let t = truth / truth.norm();
        (f - t).norm().min((f + t).norm())
    }

    #[test]
    fn seven_point_exact() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = relative_scene(seed, 7, 0.0, 0.0);
            // A fundamental matrix of an uncalibrated pair: K2^-T E K1^-1.
            let fs = estimate_fundamental_7pt(&s.x1, &s.x2).unwrap();
            let truth = essential_from_pose(&s.cam2_from_cam1);
            let err = fs.iter().map(|f| fundamental_error(f, &truth)).fold(f64::INFINITY, f64::min);
            worst = worst.max(err);
        }
        assert!(worst < 1e-8, "worst 7-point error {worst}");
    }

    #[test]
    fn eight_point_exact() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = relative_scene(seed, 8 + (seed as usize % 20), 0.0, 0.0);
            let f = estimate_fundamental_8pt(&s.x1, &s.x2).unwrap();
            let truth = essential_from_pose(&s.cam2_from_cam1);
            worst = worst.max(fundamental_error(&f, &truth));
            for (p, q) in s.x1.iter().zip(&s.x2) {
                assert!(sampson_error_sq(&f, p, q) < 1e-18);
            }
        }
        assert!(worst < 1e-8, "worst 8-point error {worst}");
    }

    #[test]
    fn degenerate_inputs() {
        let p = vec![Vec2::new(0.3, -0.1); 8];
        assert!(estimate_fundamental_7pt(&p, &p).unwrap().is_empty());
        assert!(estimate_fundamental_8pt(&p, &p).is_err());
        assert!(matches!(estimate_fundamental_8pt(&p[..7], &p[..7]), Err(EstimatorError::TooFewPoints { .. })));
        let line: Vec<Vec2> = (0..10).map(|i| Vec2::new(0.1 * i as f64, 0.05 * i as f64)).collect();
        assert!(estimate_fundamental_7pt(&line, &line).unwrap().is_empty());
        assert!(estimate_fundamental_8pt(&line, &line).is_err());
        let mut q = p.clone();
        q[0].y = f64::INFINITY;
        assert!(matches!(estimate_fundamental_7pt(&q, &p), Err(EstimatorError::NonFinite { .. })));
    }
}

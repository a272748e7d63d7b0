//! Essential matrix from five (or more) calibrated correspondences.
//!
//! Nistér, "An efficient solution to the five-point relative pose problem",
//! IEEE TPAMI 26(6), 2004. The four-dimensional null space of the epipolar
//! constraints is parameterised as `E = x X + y Y + z Z + W`; the cubic
//! constraints `det(E) = 0` and `2 E Eᵀ E - tr(E Eᵀ) E = 0` give a 10 x 20
//! linear system in the monomials of (x, y, z), reduced by Gauss-Jordan
//! elimination; three pairs of its rows combine into a 3 x 3 matrix of
//! polynomials in `z` whose determinant is the degree-10 polynomial of the
//! paper. Its real roots give up to ten essential matrices.
//!
//! With more than five points the null space is the least-squares one (the
//! four smallest right singular vectors), as COLMAP's
//! `EssentialMatrixFivePointEstimator` does for its local optimisation.

use crate::error::{EstimatorError, all_finite, check_pairs};
use crate::poly;
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use nalgebra::{SMatrix, SVector};

const PROBLEM: &str = "essential 5-point";
/// Minimal number of correspondences.
pub const SAMPLE_SIZE: usize = 5;
/// Relative pivot size below which the elimination is declared singular.
const PIVOT_TOL: f64 = 1e-12;
/// Relative size of the fifth singular value of the constraint matrix below
/// which the correspondences are degenerate (fewer than five independent).
const RANK_TOL: f64 = 1e-10;
/// A triangulated point farther than this many baselines counts as being at
/// infinity and fails the cheirality test (COLMAP's `kMaxDepth` rule).
pub const MAX_DEPTH_BASELINES: f64 = 1000.0;

/// The 20 monomials x^a y^b z^c (a, b, c) of degree <= 3, in the order of
/// Nistér's paper: the first ten are eliminated, the last ten are
/// x·{z², z, 1}, y·{z², z, 1}, {z³, z², z, 1}.
const MONOMIALS: [(usize, usize, usize); 20] = [
    (3, 0, 0),
    (0, 3, 0),
    (2, 1, 0),
    (1, 2, 0),
    (2, 0, 1),
    (2, 0, 0),
    (0, 2, 1),
    (0, 2, 0),
    (1, 1, 1),
    (1, 1, 0),
    (1, 0, 2),
    (1, 0, 1),
    (1, 0, 0),
    (0, 1, 2),
    (0, 1, 1),
    (0, 1, 0),
    (0, 0, 3),
    (0, 0, 2),
    (0, 0, 1),
    (0, 0, 0),
];

/// Index of the monomial x^i y^j z^k in [`MONOMIALS`], or 20 when absent
/// (degree above 3).
const fn monomial_index(i: usize, j: usize, k: usize) -> usize {
    let mut m = 0;
    while m < 20 {
        let e = MONOMIALS[m];
        if e.0 == i && e.1 == j && e.2 == k {
            return m;
        }
        m += 1;
    }
    20
}

/// `PRODUCT[a][b]`: index of the product of monomials `a` and `b`, or 20
/// when its degree exceeds 3.
const PRODUCT: [[usize; 20]; 20] = {
    let mut t = [[20usize; 20]; 20];
    let mut a = 0;
    while a < 20 {
        let mut b = 0;
        while b < 20 {
            let (ea, eb) = (MONOMIALS[a], MONOMIALS[b]);
            t[a][b] = monomial_index(ea.0 + eb.0, ea.1 + eb.1, ea.2 + eb.2);
            b += 1;
        }
        a += 1;
    }
    t
};

/// A polynomial of total degree <= 3 in (x, y, z): coefficients of the
/// monomials in [`MONOMIALS`] order.
#[derive(Clone, Copy)]
struct P3([f64; 20]);

impl P3 {
    fn zero() -> Self {
        P3([0.0; 20])
    }
    /// `a x + b y + c z + d`.
    fn linear(a: f64, b: f64, c: f64, d: f64) -> Self {
        let mut p = Self::zero();
        p.0[monomial_index(1, 0, 0)] = a;
        p.0[monomial_index(0, 1, 0)] = b;
        p.0[monomial_index(0, 0, 1)] = c;
        p.0[monomial_index(0, 0, 0)] = d;
        p
    }
    /// Indices of the non-zero coefficients.
    fn support(&self) -> ([usize; 20], usize) {
        let mut out = [0usize; 20];
        let mut n = 0;
        for (m, c) in self.0.iter().enumerate() {
            if *c != 0.0 {
                out[n] = m;
                n += 1;
            }
        }
        (out, n)
    }
    fn mul(&self, o: &P3) -> P3 {
        let mut r = P3::zero();
        let (sa, na) = self.support();
        let (sb, nb) = o.support();
        for &a in &sa[..na] {
            for &b in &sb[..nb] {
                // Callers multiply at most three linear factors, so the
                // product never exceeds degree 3 (index 20 never occurs);
                // `get_mut` keeps it safe regardless.
                if let Some(c) = r.0.get_mut(PRODUCT[a][b]) {
                    *c += self.0[a] * o.0[b];
                }
            }
        }
        r
    }
    fn add(&self, o: &P3) -> P3 {
        let mut r = *self;
        r.axpy(1.0, o);
        r
    }
    fn axpy(&mut self, s: f64, o: &P3) {
        for (a, b) in self.0.iter_mut().zip(&o.0) {
            *a += s * b;
        }
    }
    /// Value and gradient at (x, y, z).
    fn eval_grad(&self, v: &Vec3) -> (f64, Vec3) {
        let pw = |b: f64| [1.0, b, b * b, b * b * b];
        let (px, py, pz) = (pw(v.x), pw(v.y), pw(v.z));
        let mut val = 0.0;
        let mut g = Vec3::zeros();
        for (&(i, j, k), &c) in MONOMIALS.iter().zip(&self.0) {
            if c == 0.0 {
                continue;
            }
            val += c * px[i] * py[j] * pz[k];
            if i > 0 {
                g.x += c * i as f64 * px[i - 1] * py[j] * pz[k];
            }
            if j > 0 {
                g.y += c * j as f64 * px[i] * py[j - 1] * pz[k];
            }
            if k > 0 {
                g.z += c * k as f64 * px[i] * py[j] * pz[k - 1];
            }
        }
        (val, g)
    }
}

/// Gauss-Newton steps polishing a root (x, y, z) of the ten cubic
/// constraints; the companion-matrix roots are only accurate to ~1e-9.
const POLISH_STEPS: usize = 3;

fn polish(rows: &[P3], mut v: Vec3) -> Vec3 {
    let cost = |v: &Vec3| rows.iter().map(|p| p.eval_grad(v).0.powi(2)).sum::<f64>();
    let mut c = cost(&v);
    for _ in 0..POLISH_STEPS {
        let mut jtj = Mat3::zeros();
        let mut jtr = Vec3::zeros();
        for p in rows {
            let (r, g) = p.eval_grad(&v);
            jtj += g * g.transpose();
            jtr += g * r;
        }
        let Some(step) = jtj.lu().solve(&jtr) else {
            break;
        };
        let nv = v - step;
        let nc = cost(&nv);
        if !(nc < c) {
            break;
        }
        v = nv;
        c = nc;
    }
    v
}

/// The four null-space basis matrices X, Y, Z, W of the epipolar
/// constraints (each row-major 3x3), or `None` when the SVD fails.
fn null_space(x1: &[Vec2], x2: &[Vec2]) -> Option<[Mat3; 4]> {
    let n = x1.len();
    let row = |i: usize| -> SVector<f64, 9> {
        let a = Vec3::new(x1[i].x, x1[i].y, 1.0);
        let b = Vec3::new(x2[i].x, x2[i].y, 1.0);
        // Coefficient of E_rc is b_r a_c (E row-major).
        SVector::<f64, 9>::from_fn(|k, _| b[k / 3] * a[k % 3])
    };
    let v_t = if n < 9 {
        // Pad to 9 x 9 so that the SVD returns the full right basis.
        let mut a = SMatrix::<f64, 9, 9>::zeros();
        for i in 0..n {
            a.set_row(i, &row(i).transpose());
        }
        if !all_finite(a.iter()) {
            return None;
        }
        let svd = a.svd(false, true);
        if !(svd.singular_values[4] > RANK_TOL * svd.singular_values[0]) {
            return None; // fewer than five independent constraints
        }
        svd.v_t?
    } else {
        let mut a = nalgebra::DMatrix::<f64>::zeros(n, 9);
        for i in 0..n {
            a.set_row(i, &row(i).transpose());
        }
        if !all_finite(a.iter()) {
            return None;
        }
        let svd = a.svd(false, true);
        if !(svd.singular_values[4] > RANK_TOL * svd.singular_values[0]) {
            return None;
        }
        let vt = svd.v_t?;
        SMatrix::<f64, 9, 9>::from_fn(|r, c| vt[(r, c)])
    };
    // Singular values are sorted descending: rows 5..9 span the null space.
    let m = |r: usize| Mat3::from_fn(|i, j| v_t[(r, 3 * i + j)]);
    Some([m(5), m(6), m(7), m(8)])
}

/// Essential matrices from `n >= 5` calibrated correspondences in normalised
/// image coordinates (`x2ᵀ E x1 = 0`). Returns up to 10 candidates (each
/// scaled to unit Frobenius norm); an empty list when the points are
/// degenerate.
pub fn estimate_essential_5pt(x1: &[Vec2], x2: &[Vec2]) -> Result<Vec<Mat3>, EstimatorError> {
    check_pairs(PROBLEM, x1, x2, SAMPLE_SIZE)?;
    let mut out = Vec::new();
    solve(x1, x2, &mut out);
    Ok(out)
}

/// Unchecked solver used by RANSAC (inputs already validated).
// Index loops mirror the matrix formulas (E Eᵀ E) they implement.
#[allow(clippy::needless_range_loop)]
pub(crate) fn solve(x1: &[Vec2], x2: &[Vec2], out: &mut Vec<Mat3>) {
    let Some([bx, by, bz, bw]) = null_space(x1, x2) else {
        return;
    };
    // E as a matrix of linear polynomials.
    let e: [[P3; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| P3::linear(bx[(i, j)], by[(i, j)], bz[(i, j)], bw[(i, j)])));
    // E Eᵀ (quadratic entries) and its trace.
    let mut eet = [[P3::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                eet[i][j] = eet[i][j].add(&e[i][k].mul(&e[j][k]));
            }
        }
    }
    let trace = eet[0][0].add(&eet[1][1]).add(&eet[2][2]);
    // Ten cubic constraints: 9 trace constraints + det(E).
    let mut rows: Vec<P3> = Vec::with_capacity(10);
    for i in 0..3 {
        for j in 0..3 {
            let mut c = P3::zero();
            for k in 0..3 {
                c.axpy(2.0, &eet[i][k].mul(&e[k][j]));
            }
            c.axpy(-1.0, &trace.mul(&e[i][j]));
            rows.push(c);
        }
    }
    let det = e[0][1]
        .mul(&e[1][2])
        .mul(&e[2][0])
        .add(&e[0][2].mul(&e[1][0]).mul(&e[2][1]))
        .add(&e[0][0].mul(&e[1][1]).mul(&e[2][2]));
    let mut det_neg = e[0][2].mul(&e[1][1]).mul(&e[2][0]);
    det_neg.axpy(1.0, &e[0][0].mul(&e[1][2]).mul(&e[2][1]));
    det_neg.axpy(1.0, &e[0][1].mul(&e[1][0]).mul(&e[2][2]));
    let mut det = det;
    det.axpy(-1.0, &det_neg);
    rows.push(det);

    let mut a = SMatrix::<f64, 10, 20>::zeros();
    for (r, p) in rows.iter().enumerate() {
        for (c, v) in p.0.iter().enumerate() {
            a[(r, c)] = *v;
        }
    }
    // Gauss-Jordan with partial pivoting on the first ten columns.
    let scale = a.amax();
    if !(scale.is_finite() && scale > 0.0) {
        return;
    }
    for col in 0..10 {
        let mut piv = col;
        for r in col + 1..10 {
            if a[(r, col)].abs() > a[(piv, col)].abs() {
                piv = r;
            }
        }
        if a[(piv, col)].abs() <= PIVOT_TOL * scale {
            return;
        }
        a.swap_rows(col, piv);
        let p = a[(col, col)];
        let pivot_row = a.row(col) / p;
        a.set_row(col, &pivot_row);
        for r in 0..10 {
            if r != col {
                let f = a[(r, col)];
                if f != 0.0 {
                    let new_row = a.row(r) - pivot_row * f;
                    a.set_row(r, &new_row);
                }
            }
        }
    }
    // Row r now reads mono_r + sum_c B[r][c] mono_{10+c} = 0. Combine rows
    // (4,5), (6,7), (8,9) as <row_a> - z <row_b> into polynomials in z
    // multiplying (x, y, 1).
    let b = |r: usize, c: usize| a[(r, 10 + c)];
    let poly_rows: Vec<[Vec<f64>; 3]> = [(4, 5), (6, 7), (8, 9)]
        .iter()
        .map(|&(ra, rb)| {
            let px = vec![-b(rb, 0), b(ra, 0) - b(rb, 1), b(ra, 1) - b(rb, 2), b(ra, 2)];
            let py = vec![-b(rb, 3), b(ra, 3) - b(rb, 4), b(ra, 4) - b(rb, 5), b(ra, 5)];
            let p1 = vec![-b(rb, 6), b(ra, 6) - b(rb, 7), b(ra, 7) - b(rb, 8), b(ra, 8) - b(rb, 9), b(ra, 9)];
            [px, py, p1]
        })
        .collect();
    let m = |r: usize, c: usize| &poly_rows[r][c];
    let cof = |r1: usize, r2: usize, c1: usize, c2: usize| {
        poly::sub(&poly::mul(m(r1, c1), m(r2, c2)), &poly::mul(m(r1, c2), m(r2, c1)))
    };
    let det_z = poly::add(
        &poly::sub(&poly::mul(m(0, 0), &cof(1, 2, 1, 2)), &poly::mul(m(0, 1), &cof(1, 2, 0, 2))),
        &poly::mul(m(0, 2), &cof(1, 2, 0, 1)),
    );
    for z in poly::real_roots(&det_z) {
        let eval = |p: &Vec<f64>| poly::eval_with_derivative(p, z).0;
        let rz: Vec<Vec3> = (0..3).map(|r| Vec3::new(eval(m(r, 0)), eval(m(r, 1)), eval(m(r, 2)))).collect();
        // (x, y, 1) spans the null space of the 3x3 matrix: take the largest
        // cross product of two of its rows.
        let cands = [rz[0].cross(&rz[1]), rz[0].cross(&rz[2]), rz[1].cross(&rz[2])];
        let Some(v) = cands.iter().max_by(|p, q| p.norm_squared().total_cmp(&q.norm_squared())) else {
            continue;
        };
        if v.z.abs() <= f64::EPSILON * v.norm() {
            continue;
        }
        let sol = polish(&rows, Vec3::new(v.x / v.z, v.y / v.z, z));
        let em = bx * sol.x + by * sol.y + bz * sol.z + bw;
        let nrm = em.norm();
        if nrm.is_finite() && nrm > 0.0 {
            out.push(em / nrm);
        }
    }
}

/// Squared Sampson distance of a correspondence to the epipolar geometry
/// `x2ᵀ F x1 = 0` (first-order geometric error, in image units squared).
pub fn sampson_error_sq(f: &Mat3, x1: &Vec2, x2: &Vec2) -> f64 {
    let a = Vec3::new(x1.x, x1.y, 1.0);
    let b = Vec3::new(x2.x, x2.y, 1.0);
    let fa = f * a;
    let ftb = f.transpose() * b;
    let num = b.dot(&fa);
    let den = fa.x * fa.x + fa.y * fa.y + ftb.x * ftb.x + ftb.y * ftb.y;
    if den > 0.0 { num * num / den } else { f64::INFINITY }
}

/// `E = [t]× R` for `cam2_from_cam1 = (R, t)`.
pub fn essential_from_pose(cam2_from_cam1: &Rigid3) -> Mat3 {
    cam2_from_cam1.translation.cross_matrix() * cam2_from_cam1.rotation_matrix()
}

/// The four `(R, t)` decompositions of an essential matrix (`t` of unit
/// norm): (R1, t), (R2, t), (R1, -t), (R2, -t). Errors when the SVD fails or
/// the input is not finite.
pub fn decompose_essential(e: &Mat3) -> Result<[(Mat3, Vec3); 4], EstimatorError> {
    if !crate::error::all_finite(e.iter()) || !crate::error::all_in_range(e.iter()) || e.norm() == 0.0 {
        return Err(EstimatorError::Degenerate { problem: "decompose essential", reason: "zero or non-finite matrix" });
    }
    let svd = e.svd(true, true);
    let (Some(mut u), Some(mut v_t)) = (svd.u, svd.v_t) else {
        return Err(EstimatorError::Degenerate { problem: "decompose essential", reason: "SVD failed" });
    };
    // Make U and V proper rotations; flipping a column's sign only flips the
    // sign of E, which is irrelevant up to scale.
    if u.determinant() < 0.0 {
        u = -u;
    }
    if v_t.determinant() < 0.0 {
        v_t = -v_t;
    }
    let w = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let r1 = u * w * v_t;
    let r2 = u * w.transpose() * v_t;
    let t: Vec3 = u.column(2).into();
    let t = t / t.norm();
    Ok([(r1, t), (r2, t), (r1, -t), (r2, -t)])
}

/// Midpoint triangulation of one correspondence under `cam2_from_cam1 =
/// (r, t)`. Returns the point in camera-1 coordinates and the two depths.
pub(crate) fn triangulate_midpoint(r: &Mat3, t: &Vec3, x1: &Vec2, x2: &Vec2) -> Option<(Vec3, f64, f64)> {
    let a = r * Vec3::new(x1.x, x1.y, 1.0);
    let b = Vec3::new(x2.x, x2.y, 1.0);
    // Minimise |d1 a + t - d2 b|² over the depths (d1, d2).
    let (aa, bb, ab, at, bt) = (a.dot(&a), b.dot(&b), a.dot(&b), a.dot(t), b.dot(t));
    let det = aa * bb - ab * ab;
    if det <= 1e-15 * aa * bb {
        return None; // parallel rays
    }
    let d1 = (-at * bb + ab * bt) / det;
    let d2 = (aa * bt - ab * at) / det;
    let mid2 = 0.5 * (a * d1 + t + b * d2);
    let p1 = r.transpose() * (mid2 - t);
    Some((p1, d1, d2))
}

/// A relative pose recovered from an essential matrix.
#[derive(Debug, Clone)]
pub struct RecoveredPose {
    /// Pose of camera 2 relative to camera 1, unit translation.
    pub cam2_from_cam1: Rigid3,
    /// `valid[i]`: correspondence `i` triangulates in front of both cameras
    /// (and closer than [`MAX_DEPTH_BASELINES`] baselines).
    pub valid: Vec<bool>,
    /// Number of `true` entries in `valid`.
    pub num_valid: usize,
    /// Triangulated points in camera-1 coordinates (meaningful where valid).
    pub points3d: Vec<Vec3>,
}

/// Checks one candidate; returns the validity mask and points.
pub(crate) fn cheirality(r: &Mat3, t: &Vec3, x1: &[Vec2], x2: &[Vec2]) -> (Vec<bool>, Vec<Vec3>, usize) {
    let max_depth = MAX_DEPTH_BASELINES * t.norm();
    let mut valid = Vec::with_capacity(x1.len());
    let mut pts = Vec::with_capacity(x1.len());
    let mut count = 0;
    for (p, q) in x1.iter().zip(x2) {
        match triangulate_midpoint(r, t, p, q) {
            Some((x, d1, d2)) => {
                let ok = d1 > f64::EPSILON && d2 > f64::EPSILON && d1 < max_depth && d2 < max_depth;
                count += ok as usize;
                valid.push(ok);
                pts.push(x);
            }
            None => {
                valid.push(false);
                pts.push(Vec3::repeat(f64::NAN));
            }
        }
    }
    (valid, pts, count)
}

/// Recovers `cam2_from_cam1` from an essential matrix: of the four
/// decompositions, the one with the most correspondences in front of both
/// cameras (COLMAP's `PoseFromEssentialMatrix`).
pub fn pose_from_essential(e: &Mat3, x1: &[Vec2], x2: &[Vec2]) -> Result<RecoveredPose, EstimatorError> {
    check_pairs("pose from essential", x1, x2, 1)?;
    let cands = decompose_essential(e)?;
    let mut best: Option<RecoveredPose> = None;
    for (r, t) in cands.iter() {
        let (valid, points3d, num_valid) = cheirality(r, t, x1, x2);
        if best.as_ref().is_none_or(|b| num_valid > b.num_valid) {
            best =
                Some(RecoveredPose { cam2_from_cam1: Rigid3::from_rotation_matrix(r, *t), valid, num_valid, points3d });
        }
    }
    match best {
        Some(b) if b.num_valid > 0 => Ok(b),
        _ => Err(EstimatorError::Degenerate {
            problem: "pose from essential",
            reason: "no point in front of both cameras",
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{relative_scene, rotation_error_deg};

    #[test]
    fn exact_on_noise_free_data() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = relative_scene(seed, 5, 0.0, 0.0);
            let es = estimate_essential_5pt(&s.x1, &s.x2).unwrap();
            let truth = essential_from_pose(&s.cam2_from_cam1);
            let truth = truth / truth.norm();
            let err = es.iter().map(|e| (e - truth).norm().min((e + truth).norm())).fold(f64::INFINITY, f64::min);
            if err > 1e-9 {
                eprintln!("seed {seed} err {err:e} n {}", es.len());
            }
            worst = worst.max(err);
        }
        assert!(worst < 1e-8, "worst essential error {worst}");
    }

    #[test]
    fn pose_recovery_and_overdetermined() {
        for seed in 0..20 {
            let s = relative_scene(seed, 50, 0.0, 0.0);
            let es = estimate_essential_5pt(&s.x1, &s.x2).unwrap();
            assert!(!es.is_empty());
            let cost = |e: &Mat3| s.x1.iter().zip(&s.x2).map(|(p, q)| sampson_error_sq(e, p, q)).sum::<f64>();
            let e = *es.iter().min_by(|a, b| cost(a).total_cmp(&cost(b))).unwrap();
            for (p, q) in s.x1.iter().zip(&s.x2) {
                assert!(sampson_error_sq(&e, p, q) < 1e-20);
            }
            let pose = pose_from_essential(&e, &s.x1, &s.x2).unwrap();
            assert_eq!(pose.num_valid, 50);
            assert!(rotation_error_deg(&pose.cam2_from_cam1, &s.cam2_from_cam1) < 1e-6);
            let tdir = s.cam2_from_cam1.translation.normalize();
            assert!((pose.cam2_from_cam1.translation - tdir).norm() < 1e-8);
        }
    }

    #[test]
    fn degenerate_inputs() {
        let p = vec![Vec2::new(0.1, 0.2); 5];
        assert!(estimate_essential_5pt(&p, &p).unwrap().is_empty());
        assert!(matches!(estimate_essential_5pt(&p[..4], &p[..4]), Err(EstimatorError::TooFewPoints { .. })));
        let mut q = p.clone();
        q[2].x = f64::NAN;
        assert!(matches!(estimate_essential_5pt(&q, &p), Err(EstimatorError::NonFinite { index: 2, .. })));
        assert!(decompose_essential(&Mat3::zeros()).is_err());
    }
}

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
use crate::ransac::{Support, SupportAccumulator, SupportMeasure};
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use nalgebra::SMatrix;

const PROBLEM: &str = "essential 5-point";
/// Minimal number of correspondences.
pub const SAMPLE_SIZE: usize = 5;
/// Relative pivot size below which the elimination is declared singular.
const PIVOT_TOL: f64 = 1e-12;
/// Relative size of the smallest diagonal entry of the QR factor of the five
/// constraints below which they are degenerate (fewer than five independent).
const RANK_TOL: f64 = 1e-10;
/// Relative size of the fifth singular value of an overdetermined constraint
/// matrix below which the correspondences are degenerate. Larger than
/// [`RANK_TOL`] because it is read from the eigenvalues of `AᵀA`, whose
/// rounding floor is `eps * sigma_1²`.
const RANK_TOL_LSQ: f64 = 1e-7;
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

/// The monomials of degree <= 2: xx, xy, xz, yy, yz, zz, x, y, z, 1.
const QUADS: [(usize, usize, usize); 10] =
    [(2, 0, 0), (1, 1, 0), (1, 0, 1), (0, 2, 0), (0, 1, 1), (0, 0, 2), (1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)];

/// The variables of a linear polynomial: x, y, z, 1.
const LINEAR: [(usize, usize, usize); 4] = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)];

/// Index of the exponent triple `e` in `list`, or `list.len()` when absent.
const fn index_in(list: &[(usize, usize, usize)], e: (usize, usize, usize)) -> usize {
    let mut m = 0;
    while m < list.len() {
        if list[m].0 == e.0 && list[m].1 == e.1 && list[m].2 == e.2 {
            return m;
        }
        m += 1;
    }
    list.len()
}

/// `QUAD_OF[a][b]`: index in [`QUADS`] of `LINEAR[a] * LINEAR[b]`.
const QUAD_OF: [[usize; 4]; 4] = {
    let mut t = [[0usize; 4]; 4];
    let mut a = 0;
    while a < 4 {
        let mut b = 0;
        while b < 4 {
            let (ea, eb) = (LINEAR[a], LINEAR[b]);
            t[a][b] = index_in(&QUADS, (ea.0 + eb.0, ea.1 + eb.1, ea.2 + eb.2));
            b += 1;
        }
        a += 1;
    }
    t
};

/// `CUBE_OF[m][b]`: index in [`MONOMIALS`] of `QUADS[m] * LINEAR[b]`.
const CUBE_OF: [[usize; 4]; 10] = {
    let mut t = [[0usize; 4]; 10];
    let mut m = 0;
    while m < 10 {
        let mut b = 0;
        while b < 4 {
            let (em, eb) = (QUADS[m], LINEAR[b]);
            t[m][b] = index_in(&MONOMIALS, (em.0 + eb.0, em.1 + eb.1, em.2 + eb.2));
            b += 1;
        }
        m += 1;
    }
    t
};

/// Linear polynomial in (x, y, z): coefficients of x, y, z, 1.
type Lin = [f64; 4];
/// Quadratic polynomial: coefficients of [`QUADS`].
type Quad = [f64; 10];
/// Cubic polynomial: coefficients of [`MONOMIALS`].
type Cubic = [f64; 20];

/// `out += s * p * q` for linear `p`, `q`.
fn mul_lin_acc(p: &Lin, q: &Lin, s: f64, out: &mut Quad) {
    for (a, pa) in p.iter().enumerate() {
        for (b, qb) in q.iter().enumerate() {
            out[QUAD_OF[a][b]] += s * pa * qb;
        }
    }
}

/// `out += s * p * q` for quadratic `p` and linear `q`.
fn mul_quad_acc(p: &Quad, q: &Lin, s: f64, out: &mut Cubic) {
    for (m, pm) in p.iter().enumerate() {
        for (b, qb) in q.iter().enumerate() {
            out[CUBE_OF[m][b]] += s * pm * qb;
        }
    }
}

/// Orthonormal basis of the null space of the five epipolar constraints,
/// as four 3x3 matrices, by a Householder QR of the 9 x 5 transposed
/// constraint matrix (its last four Q columns span the null space; PoseLib's
/// `relpose_5pt` does the same). `None` when the five constraints are not
/// independent.
fn null_space_minimal(x1: &[Vec2], x2: &[Vec2]) -> Option<[Mat3; 4]> {
    // cols[j]: constraint j (coefficients of E row-major), i.e. a column of
    // the 9 x 5 matrix Aᵀ.
    let mut cols = [[0.0f64; 9]; 5];
    for (j, col) in cols.iter_mut().enumerate() {
        let a = [x1[j].x, x1[j].y, 1.0];
        let b = [x2[j].x, x2[j].y, 1.0];
        for k in 0..9 {
            col[k] = b[k / 3] * a[k % 3];
        }
    }
    let mut vs = [[0.0f64; 9]; 5];
    let mut diag = [0.0f64; 5];
    for j in 0..5 {
        // Householder vector zeroing cols[j][j+1..].
        let norm = cols[j][j..].iter().map(|v| v * v).sum::<f64>().sqrt();
        if !norm.is_finite() {
            return None;
        }
        let alpha = if cols[j][j] > 0.0 { -norm } else { norm };
        diag[j] = alpha;
        let mut v = [0.0f64; 9];
        v[j..].copy_from_slice(&cols[j][j..]);
        v[j] -= alpha;
        let vn2 = v.iter().map(|x| x * x).sum::<f64>();
        if vn2 > 0.0 {
            let inv = 1.0 / vn2.sqrt();
            v.iter_mut().for_each(|x| *x *= inv);
        }
        for col in cols.iter_mut().skip(j + 1) {
            let d = 2.0 * v.iter().zip(col.iter()).map(|(p, q)| p * q).sum::<f64>();
            col.iter_mut().zip(&v).for_each(|(c, p)| *c -= d * p);
        }
        vs[j] = v;
    }
    let dmax = diag.iter().fold(0.0f64, |m, d| m.max(d.abs()));
    let dmin = diag.iter().fold(f64::INFINITY, |m, d| m.min(d.abs()));
    if !(dmin > RANK_TOL * dmax) {
        return None; // fewer than five independent constraints
    }
    // Q = H0 H1 H2 H3 H4; null-space vector k = Q e_k, k = 5..8.
    let basis = |k: usize| {
        let mut e = [0.0f64; 9];
        e[k] = 1.0;
        for v in vs.iter().rev() {
            let d = 2.0 * v.iter().zip(&e).map(|(p, q)| p * q).sum::<f64>();
            e.iter_mut().zip(v).for_each(|(c, p)| *c -= d * p);
        }
        Mat3::from_fn(|i, j| e[3 * i + j])
    };
    Some([basis(5), basis(6), basis(7), basis(8)])
}

/// Least-squares null space of `n > 5` epipolar constraints: the four
/// eigenvectors of `AᵀA` with the smallest eigenvalues (the four smallest
/// right singular vectors of A). `None` when fewer than five constraints are
/// independent.
fn null_space_lsq(x1: &[Vec2], x2: &[Vec2]) -> Option<[Mat3; 4]> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (p, q) in x1.iter().zip(x2) {
        let a = [p.x, p.y, 1.0];
        let b = [q.x, q.y, 1.0];
        let row: [f64; 9] = std::array::from_fn(|k| b[k / 3] * a[k % 3]);
        for r in 0..9 {
            for c in r..9 {
                ata[(r, c)] += row[r] * row[c];
            }
        }
    }
    for r in 0..9 {
        for c in 0..r {
            ata[(r, c)] = ata[(c, r)];
        }
    }
    if !all_finite(ata.iter()) {
        return None;
    }
    let eig = ata.symmetric_eigen();
    let mut order: [usize; 9] = std::array::from_fn(|i| i);
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let largest = eig.eigenvalues[order[8]];
    // Singular value ratio sigma_5 / sigma_1 > RANK_TOL_LSQ, in eigenvalues.
    if !(eig.eigenvalues[order[4]] > RANK_TOL_LSQ * RANK_TOL_LSQ * largest) {
        return None;
    }
    let m = |k: usize| Mat3::from_fn(|i, j| eig.eigenvectors[(3 * i + j, order[k])]);
    // The smallest goes last, into W (the constant term): with exact data it
    // is the essential matrix itself, so the solution sits at x = y = z = 0.
    Some([m(3), m(2), m(1), m(0)])
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
pub(crate) fn solve(x1: &[Vec2], x2: &[Vec2], out: &mut Vec<Mat3>) {
    let basis = if x1.len() == SAMPLE_SIZE { null_space_minimal(x1, x2) } else { null_space_lsq(x1, x2) };
    let Some(basis) = basis else {
        return;
    };
    solve_from_basis(&basis, out);
}

/// Nistér's elimination on the null-space basis `E = x X + y Y + z Z + W`.
// Index loops mirror the matrix formulas (E Eᵀ E, cofactors) they implement.
#[allow(clippy::needless_range_loop)]
fn solve_from_basis(basis: &[Mat3; 4], out: &mut Vec<Mat3>) {
    let [bx, by, bz, bw] = basis;
    // E as a matrix of linear polynomials.
    let e: [[Lin; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| [bx[(i, j)], by[(i, j)], bz[(i, j)], bw[(i, j)]]));
    // E Eᵀ (quadratic entries, symmetric) and its trace.
    let mut eet = [[[0.0f64; 10]; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let mut q = [0.0; 10];
            for k in 0..3 {
                mul_lin_acc(&e[i][k], &e[j][k], 1.0, &mut q);
            }
            eet[i][j] = q;
            eet[j][i] = q;
        }
    }
    let trace: Quad = std::array::from_fn(|m| eet[0][0][m] + eet[1][1][m] + eet[2][2][m]);
    // Ten cubic constraints: the nine entries of 2 E Eᵀ E - tr(E Eᵀ) E, and
    // det(E).
    let mut a = [[0.0f64; 20]; 10];
    for i in 0..3 {
        for j in 0..3 {
            let row = &mut a[3 * i + j];
            for k in 0..3 {
                mul_quad_acc(&eet[i][k], &e[k][j], 2.0, row);
            }
            mul_quad_acc(&trace, &e[i][j], -1.0, row);
        }
    }
    for j in 0..3 {
        // Cofactor of e[0][j]: e[1][j+1] e[2][j+2] - e[1][j+2] e[2][j+1].
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        let mut cof = [0.0; 10];
        mul_lin_acc(&e[1][j1], &e[2][j2], 1.0, &mut cof);
        mul_lin_acc(&e[1][j2], &e[2][j1], -1.0, &mut cof);
        mul_quad_acc(&cof, &e[0][j], 1.0, &mut a[9]);
    }
    let cubics = a;
    // Gauss-Jordan with partial pivoting on the first ten columns.
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale.is_finite() && scale > 0.0) {
        return;
    }
    for col in 0..10 {
        let mut piv = col;
        for r in col + 1..10 {
            if a[r][col].abs() > a[piv][col].abs() {
                piv = r;
            }
        }
        if a[piv][col].abs() <= PIVOT_TOL * scale {
            return;
        }
        a.swap(col, piv);
        let inv = 1.0 / a[col][col];
        let pivot_row: [f64; 20] = std::array::from_fn(|c| a[col][c] * inv);
        a[col] = pivot_row;
        for (r, row) in a.iter_mut().enumerate() {
            if r != col {
                let f = row[col];
                if f != 0.0 {
                    for c in col..20 {
                        row[c] -= f * pivot_row[c];
                    }
                }
            }
        }
    }
    // Row r now reads mono_r + sum_c B[r][c] mono_{10+c} = 0. Combine rows
    // (4,5), (6,7), (8,9) as <row_a> - z <row_b> into polynomials in z
    // (lowest degree first here) multiplying (x, y, 1).
    let b = |r: usize, c: usize| a[r][10 + c];
    let mut m = [[[0.0f64; 11]; 3]; 3];
    for (k, &(ra, rb)) in [(4, 5), (6, 7), (8, 9)].iter().enumerate() {
        m[k][0][..4].copy_from_slice(&[b(ra, 2), b(ra, 1) - b(rb, 2), b(ra, 0) - b(rb, 1), -b(rb, 0)]);
        m[k][1][..4].copy_from_slice(&[b(ra, 5), b(ra, 4) - b(rb, 5), b(ra, 3) - b(rb, 4), -b(rb, 3)]);
        m[k][2][..5].copy_from_slice(&[
            b(ra, 9),
            b(ra, 8) - b(rb, 9),
            b(ra, 7) - b(rb, 8),
            b(ra, 6) - b(rb, 7),
            -b(rb, 6),
        ]);
    }
    // det of the 3x3 polynomial matrix: degree 10.
    let cof = |c1: usize, c2: usize| {
        let mut r = [0.0f64; 11];
        lpoly_mul_acc(&m[1][c1], &m[2][c2], 1.0, &mut r);
        lpoly_mul_acc(&m[1][c2], &m[2][c1], -1.0, &mut r);
        r
    };
    let mut det = [0.0f64; 11];
    lpoly_mul_acc(&m[0][0], &cof(1, 2), 1.0, &mut det);
    lpoly_mul_acc(&m[0][1], &cof(0, 2), -1.0, &mut det);
    lpoly_mul_acc(&m[0][2], &cof(0, 1), 1.0, &mut det);
    let mut det_high = det;
    det_high.reverse();
    let mut roots = [0.0f64; 10];
    let num_roots = poly::real_roots_sturm(&det_high, &mut roots);
    for &z in &roots[..num_roots] {
        let eval = |p: &[f64; 11]| p.iter().rev().fold(0.0, |acc, c| acc * z + c);
        let rz: [Vec3; 3] = std::array::from_fn(|r| Vec3::new(eval(&m[r][0]), eval(&m[r][1]), eval(&m[r][2])));
        // (x, y, 1) spans the null space of the 3x3 matrix: take the largest
        // cross product of two of its rows.
        let cands = [rz[0].cross(&rz[1]), rz[0].cross(&rz[2]), rz[1].cross(&rz[2])];
        let Some(v) = cands.iter().max_by(|p, q| p.norm_squared().total_cmp(&q.norm_squared())) else {
            continue;
        };
        if !(v.z.abs() > f64::EPSILON * v.norm()) {
            continue;
        }
        let sol = polish(&cubics, Vec3::new(v.x / v.z, v.y / v.z, z));
        let em = bx * sol.x + by * sol.y + bz * sol.z + bw;
        let nrm = em.norm();
        if nrm.is_finite() && nrm > 0.0 {
            out.push(em / nrm);
        }
    }
}

/// Gauss-Newton steps polishing a root (x, y, z) of the ten cubic
/// constraints (the root of the degree-10 polynomial is exact to rounding,
/// but recovering x and y from it loses a few digits near double roots).
const POLISH_STEPS: usize = 2;

/// Values of the 20 [`MONOMIALS`] at `v` and their gradients.
fn monomials_with_gradient(v: &Vec3) -> ([f64; 20], [Vec3; 20]) {
    let pw = |b: f64| [1.0, b, b * b, b * b * b];
    let (px, py, pz) = (pw(v.x), pw(v.y), pw(v.z));
    let mut val = [0.0; 20];
    let mut grad = [Vec3::zeros(); 20];
    for (m, &(i, j, k)) in MONOMIALS.iter().enumerate() {
        val[m] = px[i] * py[j] * pz[k];
        let d = |e: usize, p: &[f64; 4]| if e > 0 { e as f64 * p[e - 1] } else { 0.0 };
        grad[m] = Vec3::new(d(i, &px) * py[j] * pz[k], px[i] * d(j, &py) * pz[k], px[i] * py[j] * d(k, &pz));
    }
    (val, grad)
}

/// Sum of squares of the cubic constraints at `v`.
fn cubic_cost(rows: &[Cubic; 10], v: &Vec3) -> f64 {
    let (val, _) = monomials_with_gradient(v);
    rows.iter().map(|r| r.iter().zip(&val).map(|(c, m)| c * m).sum::<f64>().powi(2)).sum()
}

/// Gauss-Newton on the ten cubic constraints from `v`; steps that do not
/// lower the residual are refused.
fn polish(rows: &[Cubic; 10], mut v: Vec3) -> Vec3 {
    let mut cost = cubic_cost(rows, &v);
    for _ in 0..POLISH_STEPS {
        let (val, grad) = monomials_with_gradient(&v);
        let mut jtj = Mat3::zeros();
        let mut jtr = Vec3::zeros();
        for row in rows {
            let mut r = 0.0;
            let mut g = Vec3::zeros();
            for ((c, m), dm) in row.iter().zip(&val).zip(&grad) {
                r += c * m;
                g += dm * *c;
            }
            jtj += g * g.transpose();
            jtr += g * r;
        }
        let Some(step) = jtj.lu().solve(&jtr) else {
            break;
        };
        let nv = v - step;
        let nc = cubic_cost(rows, &nv);
        if !(nc < cost) {
            break;
        }
        v = nv;
        cost = nc;
    }
    v
}

/// `out += s * p * q` for polynomials stored lowest degree first, truncated
/// to degree 10 (the callers' products never exceed it).
fn lpoly_mul_acc(p: &[f64; 11], q: &[f64; 11], s: f64, out: &mut [f64; 11]) {
    for (i, pi) in p.iter().enumerate() {
        if *pi == 0.0 {
            continue;
        }
        for (j, qj) in q.iter().enumerate().take(11 - i) {
            out[i + j] += s * pi * qj;
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

/// Points per block of [`sampson_score`]: the early-exit test runs once per
/// block, and the block's residuals are computed in a loop the compiler can
/// vectorise.
const SCORE_BLOCK: usize = 64;

/// Squared Sampson distances of `x1[i] <-> x2[i]` to `f`, into `out`
/// (the same formula as [`sampson_error_sq`], written on scalars so that the
/// loop vectorises; a zero gradient gives NaN or infinity, an outlier).
#[inline]
pub(crate) fn sampson_sq_into(f: &Mat3, x1: &[Vec2], x2: &[Vec2], out: &mut [f64]) {
    let (f00, f01, f02) = (f[(0, 0)], f[(0, 1)], f[(0, 2)]);
    let (f10, f11, f12) = (f[(1, 0)], f[(1, 1)], f[(1, 2)]);
    let (f20, f21, f22) = (f[(2, 0)], f[(2, 1)], f[(2, 2)]);
    for ((o, p), q) in out.iter_mut().zip(x1).zip(x2) {
        let fa0 = f00 * p.x + f01 * p.y + f02;
        let fa1 = f10 * p.x + f11 * p.y + f12;
        let fa2 = f20 * p.x + f21 * p.y + f22;
        let fb0 = f00 * q.x + f10 * q.y + f20;
        let fb1 = f01 * q.x + f11 * q.y + f21;
        let num = q.x * fa0 + q.y * fa1 + fa2;
        let den = fa0 * fa0 + fa1 * fa1 + fb0 * fb0 + fb1 * fb1;
        *o = num * num / den;
    }
}

/// MSAC / inlier-count support of the epipolar model `f` (Sampson
/// residuals), with the early exit of [`crate::Estimator::score`].
pub(crate) fn sampson_score(
    f: &Mat3,
    x1: &[Vec2],
    x2: &[Vec2],
    max_sq: f64,
    measure: SupportMeasure,
    bound: Option<&Support>,
) -> Option<Support> {
    let n = x1.len().min(x2.len());
    let mut acc = SupportAccumulator::default();
    let mut r = [0.0f64; SCORE_BLOCK];
    let mut start = 0;
    while start < n {
        let end = (start + SCORE_BLOCK).min(n);
        let r = &mut r[..end - start];
        sampson_sq_into(f, &x1[start..end], &x2[start..end], r);
        acc.add_all(r, max_sq);
        if let Some(b) = bound
            && acc.cannot_beat(b, measure, max_sq, n - end)
        {
            return None;
        }
        start = end;
    }
    Some(acc.finish(max_sq))
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

//! Small dense kernels on row-major slices, used per block (sizes up to
//! 6 + 12). Callers guarantee slice lengths (`rows * cols`); each function
//! documents what it reads.

/// `out (m x n) += a^T b`, where `a` is `2 x m` and `b` is `2 x n`, both
/// stored column-major (two entries per column, as the Jacobians are).
#[inline]
pub(crate) fn add_jt_j(out: &mut [f64], a: &[f64], m: usize, b: &[f64], n: usize) {
    for i in 0..m {
        let (a0, a1) = (a[2 * i], a[2 * i + 1]);
        let row = &mut out[i * n..(i + 1) * n];
        for (k, o) in row.iter_mut().enumerate() {
            *o += a0 * b[2 * k] + a1 * b[2 * k + 1];
        }
    }
}

/// [`add_jt_j`] for compile-time sizes (unrolled by the compiler).
#[inline]
pub(crate) fn add_jt_j_fixed<const M: usize, const N: usize>(out: &mut [f64], a: &[f64], b: &[f64]) {
    let (out, a, b) = (&mut out[..M * N], &a[..2 * M], &b[..2 * N]);
    for i in 0..M {
        let (a0, a1) = (a[2 * i], a[2 * i + 1]);
        for k in 0..N {
            out[i * N + k] += a0 * b[2 * k] + a1 * b[2 * k + 1];
        }
    }
}

/// `out (m) += a^T r`, `a` is `2 x m` column-major.
#[inline]
pub(crate) fn add_jt_r(out: &mut [f64], a: &[f64], m: usize, r: &[f64; 2]) {
    for (i, o) in out.iter_mut().enumerate().take(m) {
        *o += a[2 * i] * r[0] + a[2 * i + 1] * r[1];
    }
}

/// `u (2) += a x`, `a` is `2 x m` column-major.
#[inline]
pub(crate) fn add_j_x(u: &mut [f64; 2], a: &[f64], m: usize, x: &[f64]) {
    for i in 0..m {
        u[0] += a[2 * i] * x[i];
        u[1] += a[2 * i + 1] * x[i];
    }
}

/// In-place Cholesky `A = L L^T` of an `n x n` row-major symmetric matrix
/// (only the lower triangle is read; `L` overwrites it). False when `A` is
/// not numerically positive definite.
pub(crate) fn cholesky_in_place(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    true
}

/// Solves `L L^T x = b` in place, with `l` from [`cholesky_in_place`].
pub(crate) fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
}

/// (Reference for tests.) The inverse of an `n x n` symmetric positive-definite matrix (row-major,
/// lower triangle read), or `None` when it is not positive definite.
#[cfg(test)]
pub(crate) fn spd_inverse(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = a.to_vec();
    if !cholesky_in_place(&mut l, n) {
        return None;
    }
    let mut inv = vec![0.0; n * n];
    let mut col = vec![0.0; n];
    for j in 0..n {
        col.iter_mut().for_each(|c| *c = 0.0);
        col[j] = 1.0;
        cholesky_solve(&l, n, &mut col);
        for i in 0..n {
            inv[i * n + j] = col[i];
        }
    }
    Some(inv)
}

/// The inverse of a 3x3 symmetric positive-definite matrix (row-major), or
/// `None` when it is not positive definite. Allocation-free.
pub(crate) fn spd_inverse3(a: &[f64; 9]) -> Option<[f64; 9]> {
    let m = nalgebra::Matrix3::from_row_slice(a);
    let inv = m.cholesky()?.inverse();
    let mut out = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            out[3 * i + j] = inv[(i, j)];
        }
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_inverse_round_trip() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let inv = spd_inverse(&a, 3).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let v: f64 = (0..3).map(|k| a[i * 3 + k] * inv[k * 3 + j]).sum();
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(spd_inverse(&[1.0, 2.0, 2.0, 1.0], 2).is_none());
        let inv3 = spd_inverse3(&a).unwrap();
        for (x, y) in inv3.iter().zip(&inv) {
            assert!((x - y).abs() < 1e-12);
        }
        assert!(spd_inverse3(&[1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]).is_none());
    }

    #[test]
    fn jacobian_products() {
        // a = [[1, 2], [3, 4]] (2 x 2, columns (1,3) and (2,4)).
        let a = [1.0, 3.0, 2.0, 4.0];
        let mut out = [0.0; 4];
        add_jt_j(&mut out, &a, 2, &a, 2);
        assert_eq!(out, [10.0, 14.0, 14.0, 20.0]);
        let mut fixed = [0.0; 4];
        add_jt_j_fixed::<2, 2>(&mut fixed, &a, &a);
        assert_eq!(fixed, out);
        let mut g = [0.0; 2];
        add_jt_r(&mut g, &a, 2, &[1.0, 1.0]);
        assert_eq!(g, [4.0, 6.0]);
        let mut u = [0.0; 2];
        add_j_x(&mut u, &a, 2, &[1.0, 1.0]);
        assert_eq!(u, [3.0, 7.0]);
    }
}

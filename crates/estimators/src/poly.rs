//! Univariate polynomial helpers. Coefficients are stored highest degree
//! first: `c[0] x^n + c[1] x^(n-1) + ... + c[n]`.

use nalgebra::DMatrix;

/// Newton polishing steps applied to every root from the companion matrix.
const NEWTON_STEPS: usize = 4;
/// A root is kept as real when |imag| <= this * (1 + |real|). Generous on
/// purpose: a spurious root only adds a candidate model that scoring rejects,
/// while a missed root near a double root loses the true model.
const IMAG_TOL: f64 = 1e-6;

/// Evaluates the polynomial and its derivative at `x` (Horner).
pub fn eval_with_derivative(c: &[f64], x: f64) -> (f64, f64) {
    let mut p = 0.0;
    let mut dp = 0.0;
    for &a in c {
        dp = dp * x + p;
        p = p * x + a;
    }
    (p, dp)
}

/// Product of two polynomials.
pub fn mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Sum of two polynomials (aligned at the constant term).
pub fn add(a: &[f64], b: &[f64]) -> Vec<f64> {
    let n = a.len().max(b.len());
    let mut out = vec![0.0; n];
    for (k, x) in a.iter().rev().enumerate() {
        out[n - 1 - k] += x;
    }
    for (k, x) in b.iter().rev().enumerate() {
        out[n - 1 - k] += x;
    }
    out
}

/// `a - b`.
pub fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    let nb: Vec<f64> = b.iter().map(|x| -x).collect();
    add(a, &nb)
}

/// Real roots of a polynomial (leading zeros are stripped), via the
/// eigenvalues of the companion matrix followed by Newton polishing.
pub fn real_roots(c: &[f64]) -> Vec<f64> {
    let scale = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if !(scale.is_finite() && scale > 0.0) {
        return Vec::new();
    }
    // Strip negligible leading coefficients (degree drop).
    let first = c.iter().position(|x| x.abs() > scale * 1e-14).unwrap_or(c.len());
    let c = &c[first..];
    let n = c.len().saturating_sub(1);
    if n == 0 {
        return Vec::new();
    }
    let lead = c[0];
    let mut comp = DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        comp[(0, j)] = -c[j + 1] / lead;
    }
    for i in 1..n {
        comp[(i, i - 1)] = 1.0;
    }
    if !comp.iter().all(|v| v.is_finite()) {
        return Vec::new();
    }
    let eig = comp.complex_eigenvalues();
    let mut roots = Vec::with_capacity(n);
    for z in eig.iter() {
        if !(z.re.is_finite() && z.im.is_finite()) || z.im.abs() > IMAG_TOL * (1.0 + z.re.abs()) {
            continue;
        }
        let mut x = z.re;
        for _ in 0..NEWTON_STEPS {
            let (p, dp) = eval_with_derivative(c, x);
            if dp == 0.0 || !dp.is_finite() {
                break;
            }
            let step = p / dp;
            let nx = x - step;
            // Only accept a step that does not increase |p| (guards against
            // Newton jumping between close roots).
            if eval_with_derivative(c, nx).0.abs() > p.abs() {
                break;
            }
            x = nx;
        }
        roots.push(x);
    }
    roots
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_of_known_polynomial() {
        // (x - 1)(x + 2)(x - 3.5)(x^2 + 1)
        let p = mul(&mul(&mul(&[1.0, -1.0], &[1.0, 2.0]), &[1.0, -3.5]), &[1.0, 0.0, 1.0]);
        let mut r = real_roots(&p);
        r.sort_by(f64::total_cmp);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([-2.0, 1.0, 3.5]) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        assert!(real_roots(&[0.0, 0.0]).is_empty());
        assert!(real_roots(&[f64::NAN, 1.0]).is_empty());
        assert_eq!(sub(&[1.0, 2.0, 3.0], &[1.0, 1.0]), vec![1.0, 1.0, 2.0]);
    }
}

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

/// Highest degree handled by [`real_roots_sturm`].
pub const STURM_MAX_DEGREE: usize = 10;
/// A Sturm remainder whose coefficients all fall below this fraction of its
/// dividend's largest one is taken as zero (the sequence ends: the
/// polynomial has a multiple root).
const STURM_ZERO_TOL: f64 = 1e-13;
/// Bisection depth limit of the root isolation.
const STURM_MAX_DEPTH: usize = 96;
/// Newton iterations per isolated root.
const STURM_NEWTON_STEPS: usize = 60;

/// A Sturm sequence: `seq[k]` (highest degree first) of degree `deg[k]`.
struct Sturm {
    seq: [[f64; STURM_MAX_DEGREE + 1]; STURM_MAX_DEGREE + 1],
    deg: [usize; STURM_MAX_DEGREE + 1],
    len: usize,
}

impl Sturm {
    /// Sign changes of the sequence at `x` (zeros skipped).
    fn sign_changes(&self, x: f64) -> usize {
        let mut changes = 0;
        let mut last = 0.0f64;
        for (s, &d) in self.seq.iter().zip(&self.deg).take(self.len) {
            let v = s[..=d].iter().fold(0.0, |acc, c| acc * x + c);
            if v != 0.0 {
                if last != 0.0 && (v > 0.0) != (last > 0.0) {
                    changes += 1;
                }
                last = v;
            }
        }
        changes
    }
}

/// Real roots of a polynomial of degree at most [`STURM_MAX_DEGREE`]
/// (highest degree first; negligible leading coefficients are stripped) by
/// Sturm sequences: bisection on the sign-change count until each interval
/// holds one root, then bracketed Newton iteration (the approach of
/// Nistér's paper, also PoseLib's `sturm.h`). Multiple roots are reported
/// once. Writes the roots to `out` (which must hold the degree) and returns
/// their number; higher degrees fall back to [`real_roots`].
pub fn real_roots_sturm(c: &[f64], out: &mut [f64]) -> usize {
    let scale = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if !(scale.is_finite() && scale > 0.0) {
        return 0;
    }
    let first = c.iter().position(|x| x.abs() > scale * 1e-14).unwrap_or(c.len());
    let c = &c[first..];
    let n = c.len().saturating_sub(1);
    if n == 0 {
        return 0;
    }
    if n > STURM_MAX_DEGREE {
        let r = real_roots(c);
        let k = r.len().min(out.len());
        out[..k].copy_from_slice(&r[..k]);
        return k;
    }
    let mut st = Sturm { seq: [[0.0; STURM_MAX_DEGREE + 1]; STURM_MAX_DEGREE + 1], deg: [0; 11], len: 2 };
    // Monic polynomial and its derivative.
    for i in 0..=n {
        st.seq[0][i] = c[i] / c[0];
    }
    st.deg[0] = n;
    for i in 0..n {
        st.seq[1][i] = st.seq[0][i] * (n - i) as f64 / n as f64;
    }
    st.deg[1] = n - 1;
    // s_{k+1} = -rem(s_{k-1}, s_k), each scaled to a unit largest coefficient.
    while st.len <= STURM_MAX_DEGREE && st.deg[st.len - 1] > 0 {
        let (a, da) = (st.seq[st.len - 2], st.deg[st.len - 2]);
        let (b, db) = (st.seq[st.len - 1], st.deg[st.len - 1]);
        let mut r = a;
        for i in 0..=(da - db) {
            let q = r[i] / b[0];
            for j in 0..=db {
                r[i + j] -= q * b[j];
            }
        }
        let rem = &r[da - db + 1..=da];
        let amax = a[..=da].iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let Some(lead) = rem.iter().position(|x| x.abs() > STURM_ZERO_TOL * amax) else {
            break;
        };
        let rem = &rem[lead..];
        let rmax = rem.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        if !rmax.is_finite() {
            return 0;
        }
        let k = st.len;
        for (dst, v) in st.seq[k].iter_mut().zip(rem) {
            *dst = -v / rmax;
        }
        st.deg[k] = rem.len() - 1;
        st.len += 1;
    }
    // Fujiwara's bound on the root moduli of the monic polynomial.
    let p = &st.seq[0];
    let mut bound = 0.0f64;
    for (k, c) in p.iter().enumerate().take(n + 1).skip(1) {
        let a = if k == n { c.abs() / 2.0 } else { c.abs() };
        bound = bound.max(a.powf(1.0 / k as f64));
    }
    // At least 1, so that the end points do not underflow for roots at 0.
    let bound = (2.0 * bound * (1.0 + 1e-9)).max(1.0);
    if !bound.is_finite() {
        return 0;
    }
    let mut count = 0;
    let (ca, cb) = (st.sign_changes(-bound), st.sign_changes(bound));
    isolate(&st, -bound, bound, ca, cb, 0, out, &mut count);
    count
}

/// Pushes the roots in `(a, b]` (`ca`, `cb`: sign changes at `a`, `b`).
#[allow(clippy::too_many_arguments)]
fn isolate(st: &Sturm, a: f64, b: f64, ca: usize, cb: usize, depth: usize, out: &mut [f64], count: &mut usize) {
    if ca <= cb || *count >= out.len() {
        return;
    }
    let mid = 0.5 * (a + b);
    if ca - cb == 1 {
        out[*count] = refine_root(&st.seq[0][..=st.deg[0]], a, b);
        *count += 1;
        return;
    }
    if depth >= STURM_MAX_DEPTH || b - a <= 4.0 * f64::EPSILON * (1.0 + mid.abs()) {
        // A multiple root (or a cluster closer than rounding): report once.
        out[*count] = mid;
        *count += 1;
        return;
    }
    let cm = st.sign_changes(mid);
    isolate(st, a, mid, ca, cm, depth + 1, out, count);
    isolate(st, mid, b, cm, cb, depth + 1, out, count);
}

/// The single root of `p` in `(a, b]`: Newton iteration kept inside the
/// bracket, falling back to bisection.
fn refine_root(p: &[f64], mut a: f64, mut b: f64) -> f64 {
    let fa = eval_with_derivative(p, a).0;
    let fb = eval_with_derivative(p, b).0;
    if fb == 0.0 {
        return b;
    }
    let bracketed = (fa > 0.0) != (fb > 0.0);
    let neg_at_a = fa < 0.0;
    let mut x = 0.5 * (a + b);
    for _ in 0..STURM_NEWTON_STEPS {
        let (f, df) = eval_with_derivative(p, x);
        if f == 0.0 {
            return x;
        }
        if bracketed {
            if (f < 0.0) == neg_at_a {
                a = x;
            } else {
                b = x;
            }
        }
        let mut nx = x - f / df;
        if !(nx > a && nx < b) {
            if !bracketed {
                break;
            }
            nx = 0.5 * (a + b);
        }
        let done = (nx - x).abs() <= 2.0 * f64::EPSILON * (1.0 + x.abs());
        x = nx;
        if done || (bracketed && b - a <= 2.0 * f64::EPSILON * (1.0 + x.abs())) {
            break;
        }
    }
    x
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

    #[test]
    fn sturm_roots() {
        let mut out = [0.0; 10];
        // (x - 1)(x + 2)(x - 3.5)(x^2 + 1)
        let p = mul(&mul(&mul(&[1.0, -1.0], &[1.0, 2.0]), &[1.0, -3.5]), &[1.0, 0.0, 1.0]);
        let k = real_roots_sturm(&p, &mut out);
        let mut r = out[..k].to_vec();
        r.sort_by(f64::total_cmp);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([-2.0, 1.0, 3.5]) {
            assert!((a - b).abs() < 1e-13, "{a} vs {b}");
        }
        // Ten real roots, some close together, spread over four decades.
        let truth = [-250.0, -3.0, -1.0, -0.999, 0.001, 0.002, 0.5, 2.0, 7.0, 40.0];
        let p = truth.iter().fold(vec![1.0], |acc, r| mul(&acc, &[1.0, -r]));
        let k = real_roots_sturm(&p, &mut out);
        let mut r = out[..k].to_vec();
        r.sort_by(f64::total_cmp);
        assert_eq!(r.len(), 10, "{r:?}");
        for (a, b) in r.iter().zip(truth) {
            assert!((a - b).abs() < 1e-9 * (1.0 + b.abs()), "{a} vs {b}");
        }
        // A double root is reported once; no real roots; degenerate input.
        let p = mul(&mul(&[1.0, -2.0], &[1.0, -2.0]), &[1.0, 0.0, 4.0]);
        let k = real_roots_sturm(&p, &mut out);
        assert_eq!(k, 1);
        assert!((out[0] - 2.0).abs() < 1e-6, "{}", out[0]);
        assert_eq!(real_roots_sturm(&[1.0, 0.0, 1.0], &mut out), 0);
        assert_eq!(real_roots_sturm(&[0.0, 0.0], &mut out), 0);
        assert_eq!(real_roots_sturm(&[f64::NAN, 1.0], &mut out), 0);
        assert_eq!(real_roots_sturm(&[1.0, 0.0, 0.0], &mut out), 1);
        assert_eq!(out[0], 0.0);
    }
}

//! Robust loss functions with Ceres Solver's semantics.
//!
//! A loss maps the squared residual norm `s = |r|^2` to `rho(s)`; the cost of
//! a problem is `0.5 * sum rho(s_i)`. With scale `a` (in pixels) and `b = a^2`:
//!
//! | loss | rho(s) |
//! |---|---|
//! | trivial | `s` |
//! | Huber | `s` for `s <= b`, else `2 a sqrt(s) - b` |
//! | soft-L1 | `2 b (sqrt(1 + s / b) - 1)` |
//! | Cauchy | `b ln(1 + s / b)` |
//!
//! The robustified residual and Jacobian follow the "corrector" of Ceres
//! (after Triggs et al., "Bundle Adjustment - A Modern Synthesis", 2000,
//! section 4.3): the Gauss-Newton model of `0.5 rho(|r|^2)` is matched by
//! `r~ = sqrt(rho') / (1 - alpha) r` and
//! `J~ = sqrt(rho') (I - alpha r r^T / |r|^2) J`, where `alpha` solves
//! `0.5 alpha^2 - alpha - rho'' / rho' |r|^2 = 0`. When `rho'' <= 0` (every
//! loss above, outside the quadratic region) Ceres uses `alpha = 0`, which is
//! iteratively re-weighted least squares; so do we.

/// A robust loss on the squared residual norm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum LossFunction {
    /// Plain least squares, `rho(s) = s`.
    #[default]
    Trivial,
    /// Huber loss with the given scale (pixels): quadratic below `scale`,
    /// linear above.
    Huber(f64),
    /// Soft-L1 (pseudo-Huber) loss with the given scale (pixels).
    SoftL1(f64),
    /// Cauchy loss with the given scale (pixels); COLMAP's robust choice.
    Cauchy(f64),
}

/// `rho(s)`, `rho'(s)` and `rho''(s)` at one squared residual norm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossValue {
    /// `rho(s)`.
    pub rho: f64,
    /// First derivative `rho'(s)`.
    pub d1: f64,
    /// Second derivative `rho''(s)`.
    pub d2: f64,
}

impl LossFunction {
    /// The scale parameter, if the loss has one.
    pub fn scale(&self) -> Option<f64> {
        match *self {
            Self::Trivial => None,
            Self::Huber(a) | Self::SoftL1(a) | Self::Cauchy(a) => Some(a),
        }
    }

    /// Checks that the scale is finite and positive.
    pub fn validate(&self) -> Result<(), String> {
        match self.scale() {
            Some(a) if !(a.is_finite() && a > 0.0) => {
                Err(format!("loss scale must be finite and > 0, got {a} in {self:?}"))
            }
            _ => Ok(()),
        }
    }

    /// Evaluates `rho`, `rho'`, `rho''` at the squared norm `s >= 0`.
    pub fn evaluate(&self, s: f64) -> LossValue {
        match *self {
            Self::Trivial => LossValue { rho: s, d1: 1.0, d2: 0.0 },
            Self::Huber(a) => {
                let b = a * a;
                if s > b {
                    let r = s.sqrt();
                    let d1 = a / r;
                    LossValue { rho: 2.0 * a * r - b, d1, d2: -0.5 * d1 / s }
                } else {
                    LossValue { rho: s, d1: 1.0, d2: 0.0 }
                }
            }
            Self::SoftL1(a) => {
                let b = a * a;
                let c = 1.0 + s / b;
                let sqrt_c = c.sqrt();
                let d1 = 1.0 / sqrt_c;
                // 2 b (sqrt(c) - 1) written without cancellation for small s.
                LossValue { rho: 2.0 * s / (sqrt_c + 1.0), d1, d2: -0.5 * d1 / (c * b) }
            }
            Self::Cauchy(a) => {
                let b = a * a;
                let c = 1.0 + s / b;
                let d1 = 1.0 / c;
                LossValue { rho: b * (s / b).ln_1p(), d1, d2: -d1 * d1 / b }
            }
        }
    }
}

/// The corrector for one residual block: scales for the residual and the
/// Jacobian that make the Gauss-Newton model match the robust cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Corrector {
    /// Multiplies the residual.
    pub residual_scale: f64,
    /// `sqrt(rho')`: multiplies the Jacobian.
    pub sqrt_rho1: f64,
    /// `alpha / |r|^2`: the Jacobian becomes
    /// `sqrt_rho1 * (J - alpha_sq_norm * r (r^T J))`.
    pub alpha_sq_norm: f64,
}

impl Corrector {
    /// The corrector for squared norm `s` and loss derivatives `v`.
    pub fn new(s: f64, v: &LossValue) -> Self {
        // rho' > 0 for every loss above at finite s; guard anyway so that a
        // vanishing weight gives a zero (not NaN) contribution.
        let sqrt_rho1 = v.d1.max(0.0).sqrt();
        if s == 0.0 || v.d2 <= 0.0 || v.d1 <= 0.0 {
            return Self { residual_scale: sqrt_rho1, sqrt_rho1, alpha_sq_norm: 0.0 };
        }
        // rho'' > 0: D > 1, so alpha < 0 and 1 - alpha > 1 (no division by 0).
        let d = 1.0 + 2.0 * s * v.d2 / v.d1;
        let alpha = 1.0 - d.sqrt();
        Self { residual_scale: sqrt_rho1 / (1.0 - alpha), sqrt_rho1, alpha_sq_norm: alpha / s }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [LossFunction; 4] =
        [LossFunction::Trivial, LossFunction::Huber(1.5), LossFunction::SoftL1(0.7), LossFunction::Cauchy(2.0)];

    #[test]
    fn derivatives_match_finite_differences() {
        for loss in ALL {
            for s in [0.01f64, 0.5, 1.0, 2.0, 9.0, 100.0] {
                let h = 1e-6 * s.max(1.0);
                let v = loss.evaluate(s);
                let p = loss.evaluate(s + h);
                let m = loss.evaluate(s - h);
                let d1 = (p.rho - m.rho) / (2.0 * h);
                let d2 = (p.d1 - m.d1) / (2.0 * h);
                assert!((d1 - v.d1).abs() < 1e-6 * v.d1.abs().max(1.0), "{loss:?} s={s}: {d1} vs {}", v.d1);
                assert!((d2 - v.d2).abs() < 1e-5 * v.d2.abs().max(1e-3), "{loss:?} s={s}: {d2} vs {}", v.d2);
            }
            // Every loss is the identity near zero.
            let v = loss.evaluate(1e-12);
            assert!((v.rho - 1e-12).abs() < 1e-20 && (v.d1 - 1.0).abs() < 1e-9, "{loss:?}");
        }
    }

    #[test]
    fn robust_losses_grow_slower() {
        for loss in &ALL[1..] {
            assert!(loss.evaluate(1e4).rho < 1e3, "{loss:?}");
            assert!(loss.evaluate(1e4).d1 < 0.1, "{loss:?}");
        }
        assert!(LossFunction::Cauchy(0.0).validate().is_err());
        assert!(LossFunction::Huber(f64::NAN).validate().is_err());
        assert!(LossFunction::SoftL1(1.0).validate().is_ok());
    }

    #[test]
    fn corrector_is_irls_for_concave_losses() {
        let v = LossFunction::Cauchy(1.0).evaluate(4.0);
        let c = Corrector::new(4.0, &v);
        assert_eq!(c.alpha_sq_norm, 0.0);
        assert!((c.residual_scale - (0.2f64).sqrt()).abs() < 1e-15);
        // A convex rho'' > 0 case exercises the Triggs branch: the corrected
        // model's gradient must equal rho' J^T r.
        let v = LossValue { rho: 0.0, d1: 1.0, d2: 0.1 };
        let c = Corrector::new(2.0, &v);
        assert!(c.alpha_sq_norm < 0.0);
        // 1-D: r = sqrt(2), J = 1: J~ r~ must equal rho' J r.
        let r = 2.0f64.sqrt();
        let jt = c.sqrt_rho1 * (1.0 - c.alpha_sq_norm * r * r);
        assert!((jt * c.residual_scale * r - r).abs() < 1e-12);
    }
}

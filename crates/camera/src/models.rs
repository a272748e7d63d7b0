//! Projection, unprojection and analytic Jacobians of the COLMAP camera models.
//!
//! Semantics follow COLMAP's `src/colmap/sensor/models.h` (Schönberger &
//! Frahm, "Structure-from-Motion Revisited", CVPR 2016): a camera-frame point
//! `(x, y, z)` is normalised to `(u, v) = (x/z, y/z)`, distorted by the model's
//! distortion function to `(u_d, v_d)`, and mapped to pixels by
//! `px = fx * u_d + cx`, `py = fy * v_d + cy`. The code here is an independent
//! implementation of those formulas.
//!
//! * Perspective models (SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV) share one
//!   Brown–Conrady form: `u_d = u R(r²) + 2 p1 u v + p2 (r² + 2u²)`,
//!   `v_d = v R(r²) + 2 p2 u v + p1 (r² + 2v²)`, with the rational radial
//!   factor `R = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`;
//!   each model switches on a subset of the coefficients.
//! * OPENCV_FISHEYE (Kannala–Brandt as in OpenCV's fisheye module):
//!   `θ = atan(r)`, `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`,
//!   `(u_d, v_d) = (u, v) θ_d / r`.
//!
//! Unprojection inverts the distortion by Newton's method on the 2x2 analytic
//! Jacobian with backtracking (perspective models), or on the scalar
//! `θ ↦ θ_d` (fisheye), to a relative tolerance of [`UNDISTORT_TOLERANCE`].
//! COLMAP's own fixed-step scheme (`IterativeUndistortion`) uses a numeric
//! Jacobian and stops once the squared step falls below 1e-10; it leaves up
//! to 1e-7 px round-trip error on TUM fr1 (measured with pycolmap 4.2.1), so it
//! does not reach a 1e-10 px round trip everywhere.

use nalgebra::{Matrix2, Matrix2x3, SMatrix};

use crate::{CameraModelId, Vec2, Vec3};

/// Largest parameter count of any model (FULL_OPENCV has 12).
pub const MAX_PARAMS: usize = 12;

/// Largest number of extra (distortion) parameters of any model.
const MAX_EXTRA: usize = 8;

/// Relative tolerance on the Newton step of the iterative undistortion.
pub const UNDISTORT_TOLERANCE: f64 = 1e-14;

/// Iteration cap of the iterative undistortion; Newton converges
/// quadratically, so realistic calibrations need fewer than 10.
const UNDISTORT_MAX_ITERATIONS: usize = 100;

/// Backtracking halvings allowed per Newton step before giving up.
const MAX_BACKTRACKS: usize = 30;

/// A residual this small (relative to the target) is accepted after the
/// iteration cap even if the step never dropped below the tolerance (it can
/// dither at the last bit).
const ACCEPT_RESIDUAL: f64 = 1e-13;

/// Below this squared radius the fisheye factor θ_d / r uses its Taylor
/// expansion (the exact quotient loses precision as r → 0).
const FISHEYE_SMALL_R2: f64 = 1e-16;

/// Margin below π/2 for fisheye angles: rays at or beyond 90° from the axis
/// have no normalised coordinates (z <= 0).
const FISHEYE_MAX_THETA: f64 = std::f64::consts::FRAC_PI_2 - 1e-9;

/// Projection of a point with its Jacobians (for bundle adjustment).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// The pixel.
    pub pixel: Vec2,
    /// d pixel / d (x, y, z) of the camera-frame point.
    pub d_point: Matrix2x3<f64>,
    /// d pixel / d params, in COLMAP parameter order; columns `>= num_params`
    /// are zero.
    pub d_params: SMatrix<f64, 2, MAX_PARAMS>,
}

/// Which coefficient of the generic Brown–Conrady form an extra parameter is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Coef {
    K1,
    K2,
    K3,
    K4,
    K5,
    K6,
    P1,
    P2,
}

/// Layout of a perspective model's extra parameters (COLMAP order).
fn brown_layout(model: CameraModelId) -> &'static [Coef] {
    use Coef::*;
    match model {
        CameraModelId::SimplePinhole | CameraModelId::Pinhole | CameraModelId::OpenCvFisheye => &[],
        CameraModelId::SimpleRadial => &[K1],
        CameraModelId::Radial => &[K1, K2],
        CameraModelId::OpenCv => &[K1, K2, P1, P2],
        CameraModelId::FullOpenCv => &[K1, K2, P1, P2, K3, K4, K5, K6],
    }
}

/// Coefficients of the generic Brown–Conrady form (absent ones are zero).
#[derive(Debug, Clone, Copy, Default)]
struct Brown {
    k: [f64; 6],
    p1: f64,
    p2: f64,
}

impl Brown {
    fn from_extra(model: CameraModelId, extra: &[f64; MAX_EXTRA]) -> Self {
        let mut b = Brown::default();
        for (c, &val) in brown_layout(model).iter().zip(extra.iter()) {
            match c {
                Coef::K1 => b.k[0] = val,
                Coef::K2 => b.k[1] = val,
                Coef::K3 => b.k[2] = val,
                Coef::K4 => b.k[3] = val,
                Coef::K5 => b.k[4] = val,
                Coef::K6 => b.k[5] = val,
                Coef::P1 => b.p1 = val,
                Coef::P2 => b.p2 = val,
            }
        }
        b
    }

    /// Radial factor R(r²), its derivative dR/d(r²), numerator N and
    /// denominator D.
    #[inline]
    fn radial(&self, r2: f64) -> (f64, f64, f64, f64) {
        let [k1, k2, k3, k4, k5, k6] = self.k;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let n = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
        let d = 1.0 + k4 * r2 + k5 * r4 + k6 * r6;
        let dn = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
        let dd = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4;
        (n / d, (dn * d - n * dd) / (d * d), n, d)
    }

    #[inline]
    fn distort(&self, u: f64, v: f64) -> Vec2 {
        let r2 = u * u + v * v;
        let (r, ..) = self.radial(r2);
        Vec2::new(
            u * r + 2.0 * self.p1 * u * v + self.p2 * (r2 + 2.0 * u * u),
            v * r + 2.0 * self.p2 * u * v + self.p1 * (r2 + 2.0 * v * v),
        )
    }

    /// Distorted point and d(u_d, v_d)/d(u, v).
    #[inline]
    fn distort_jac(&self, u: f64, v: f64) -> (Vec2, Matrix2<f64>) {
        let r2 = u * u + v * v;
        let (r, dr, ..) = self.radial(r2);
        let (p1, p2) = (self.p1, self.p2);
        let d = Vec2::new(
            u * r + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u),
            v * r + 2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v),
        );
        let cross = 2.0 * u * v * dr + 2.0 * p1 * u + 2.0 * p2 * v;
        let j = Matrix2::new(
            r + 2.0 * u * u * dr + 2.0 * p1 * v + 6.0 * p2 * u,
            cross,
            cross,
            r + 2.0 * v * v * dr + 2.0 * p2 * u + 6.0 * p1 * v,
        );
        (d, j)
    }

    /// d(u_d, v_d)/d coefficient, for every coefficient in `layout`,
    /// written to `out` (one entry per coefficient).
    #[inline]
    fn d_coefs(&self, layout: &[Coef], u: f64, v: f64, out: &mut [Vec2; MAX_EXTRA]) {
        let r2 = u * u + v * v;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let (_, _, n, d) = self.radial(r2);
        let (id, nd2) = (1.0 / d, -n / (d * d));
        for (slot, c) in out.iter_mut().zip(layout) {
            let d_r = match c {
                Coef::K1 => r2 * id,
                Coef::K2 => r4 * id,
                Coef::K3 => r6 * id,
                Coef::K4 => r2 * nd2,
                Coef::K5 => r4 * nd2,
                Coef::K6 => r6 * nd2,
                Coef::P1 => {
                    *slot = Vec2::new(2.0 * u * v, r2 + 2.0 * v * v);
                    continue;
                }
                Coef::P2 => {
                    *slot = Vec2::new(r2 + 2.0 * u * u, 2.0 * u * v);
                    continue;
                }
            };
            *slot = Vec2::new(u * d_r, v * d_r);
        }
    }
}

/// Kannala–Brandt polynomial θ_d(θ) and its derivative.
#[inline]
fn fisheye_theta_d(k: &[f64; 4], theta: f64) -> (f64, f64) {
    let t2 = theta * theta;
    let t4 = t2 * t2;
    let t6 = t4 * t2;
    let t8 = t4 * t4;
    let poly = 1.0 + k[0] * t2 + k[1] * t4 + k[2] * t6 + k[3] * t8;
    let dpoly = 1.0 + 3.0 * k[0] * t2 + 5.0 * k[1] * t4 + 7.0 * k[2] * t6 + 9.0 * k[3] * t8;
    (theta * poly, dpoly)
}

/// Fisheye scale s(r) = θ_d / r and g(r) = s'(r) / r, so that
/// d(u_d, v_d)/d(u, v) = s I + g (u, v)(u, v)ᵀ.
#[inline]
fn fisheye_scale(k: &[f64; 4], r2: f64) -> (f64, f64) {
    if r2 < FISHEYE_SMALL_R2 {
        // θ/r = 1 - r²/3 + O(r⁴), poly = 1 + k1 r² + O(r⁴):
        // s = 1 + (k1 - 1/3) r², s'(r)/r = 2 (k1 - 1/3).
        let a = k[0] - 1.0 / 3.0;
        return (1.0 + a * r2, 2.0 * a);
    }
    let r = r2.sqrt();
    let theta = r.atan();
    let (td, dtd) = fisheye_theta_d(k, theta);
    let s = td / r;
    // s'(r) = (θ_d'(θ) θ'(r) r - θ_d) / r², θ'(r) = 1 / (1 + r²).
    let ds = (dtd / (1.0 + r2) * r - td) / r2;
    (s, ds / r)
}

/// A camera's parameters unpacked into fixed-size storage (no allocation).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Intrinsics {
    pub(crate) model: CameraModelId,
    pub(crate) fx: f64,
    pub(crate) fy: f64,
    pub(crate) cx: f64,
    pub(crate) cy: f64,
    extra: [f64; MAX_EXTRA],
}

impl Intrinsics {
    /// Unpacks `params`; missing entries (a malformed parameter vector) read
    /// as NaN, so every result is non-finite and rejected downstream.
    pub(crate) fn new(model: CameraModelId, params: &[f64]) -> Self {
        let get = |i: usize| params.get(i).copied().unwrap_or(f64::NAN);
        let fi = model.focal_length_idxs();
        let pi = model.principal_point_idxs();
        let fx = get(fi.first().copied().unwrap_or(usize::MAX));
        let fy = get(fi.last().copied().unwrap_or(usize::MAX));
        let cx = get(pi.first().copied().unwrap_or(usize::MAX));
        let cy = get(pi.last().copied().unwrap_or(usize::MAX));
        let mut extra = [0.0; MAX_EXTRA];
        for (slot, &i) in extra.iter_mut().zip(model.extra_params_idxs()) {
            *slot = get(i);
        }
        Self { model, fx, fy, cx, cy, extra }
    }

    fn fisheye_k(&self) -> [f64; 4] {
        [self.extra[0], self.extra[1], self.extra[2], self.extra[3]]
    }

    /// Distortion of normalised coordinates (identity for pinholes).
    #[inline]
    pub(crate) fn distort(&self, uv: &Vec2) -> Vec2 {
        match self.model {
            CameraModelId::SimplePinhole | CameraModelId::Pinhole => *uv,
            CameraModelId::OpenCvFisheye => {
                let (s, _) = fisheye_scale(&self.fisheye_k(), uv.norm_squared());
                uv * s
            }
            m => Brown::from_extra(m, &self.extra).distort(uv.x, uv.y),
        }
    }

    /// Distortion and its Jacobian w.r.t. the normalised coordinates.
    #[inline]
    pub(crate) fn distort_jac(&self, uv: &Vec2) -> (Vec2, Matrix2<f64>) {
        match self.model {
            CameraModelId::SimplePinhole | CameraModelId::Pinhole => (*uv, Matrix2::identity()),
            CameraModelId::OpenCvFisheye => {
                let (s, g) = fisheye_scale(&self.fisheye_k(), uv.norm_squared());
                (uv * s, Matrix2::identity() * s + uv * uv.transpose() * g)
            }
            m => Brown::from_extra(m, &self.extra).distort_jac(uv.x, uv.y),
        }
    }

    /// Normalised coordinates -> pixel.
    #[inline]
    pub(crate) fn img_from_normalized(&self, uv: &Vec2) -> Vec2 {
        let d = self.distort(uv);
        Vec2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy)
    }

    /// Camera-frame point -> pixel; `None` for z <= 0 or non-finite results.
    #[inline]
    pub(crate) fn img_from_cam(&self, p: &Vec3) -> Option<Vec2> {
        if !is_positive(p.z) {
            return None;
        }
        // Same arithmetic as `img_from_cam_with_jacobians`, so both return
        // bit-identical pixels.
        let iz = 1.0 / p.z;
        let px = self.img_from_normalized(&Vec2::new(p.x * iz, p.y * iz));
        (px.x.is_finite() && px.y.is_finite()).then_some(px)
    }

    /// Projection with Jacobians w.r.t. the point and all parameters.
    /// Normalised coordinates, their distorted image, the pixel and d pixel /
    /// d camera-frame point (no finiteness check).
    #[inline]
    fn project_point_jac(&self, p: &Vec3) -> Option<(Vec2, Vec2, Vec2, Matrix2x3<f64>)> {
        if !is_positive(p.z) {
            return None;
        }
        let iz = 1.0 / p.z;
        let uv = Vec2::new(p.x * iz, p.y * iz);
        let (d, j_uv) = self.distort_jac(&uv);
        let pixel = Vec2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy);
        // d(u, v)/d(x, y, z).
        let d_uv_d_p = Matrix2x3::new(iz, 0.0, -uv.x * iz, 0.0, iz, -uv.y * iz);
        let k = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        Some((uv, d, pixel, k * j_uv * d_uv_d_p))
    }

    /// Pixel and d pixel / d camera-frame point only: what bundle adjustment
    /// needs for a camera whose parameters are held constant.
    #[inline]
    pub(crate) fn img_from_cam_with_point_jacobian(&self, p: &Vec3) -> Option<(Vec2, Matrix2x3<f64>)> {
        let (_, _, pixel, d_point) = self.project_point_jac(p)?;
        let finite = pixel.iter().chain(d_point.iter()).all(|v| v.is_finite());
        finite.then_some((pixel, d_point))
    }

    pub(crate) fn img_from_cam_with_jacobians(&self, p: &Vec3) -> Option<Projection> {
        let (uv, d, pixel, d_point) = self.project_point_jac(p)?;

        let mut d_params = SMatrix::<f64, 2, MAX_PARAMS>::zeros();
        let fi = self.model.focal_length_idxs();
        let pi = self.model.principal_point_idxs();
        match fi {
            [f] => {
                d_params[(0, *f)] = d.x;
                d_params[(1, *f)] = d.y;
            }
            [f0, f1] => {
                d_params[(0, *f0)] = d.x;
                d_params[(1, *f1)] = d.y;
            }
            _ => {}
        }
        if let [c0, c1] = pi {
            d_params[(0, *c0)] = 1.0;
            d_params[(1, *c1)] = 1.0;
        }
        let extra_idxs = self.model.extra_params_idxs();
        match self.model {
            CameraModelId::SimplePinhole | CameraModelId::Pinhole => {}
            CameraModelId::OpenCvFisheye => {
                let r2 = uv.norm_squared();
                let r = r2.sqrt();
                let theta = r.atan();
                // d(u_d)/d k_i = u θ^(2i+3) / r; the limit θ/r → 1 as r → 0.
                let ratio = if r2 < FISHEYE_SMALL_R2 { 1.0 - r2 / 3.0 } else { theta / r };
                let t2 = theta * theta;
                let mut pw = t2;
                for &col in extra_idxs {
                    let f = ratio * pw;
                    d_params[(0, col)] = self.fx * uv.x * f;
                    d_params[(1, col)] = self.fy * uv.y * f;
                    pw *= t2;
                }
            }
            m => {
                let b = Brown::from_extra(m, &self.extra);
                let mut cols = [Vec2::zeros(); MAX_EXTRA];
                b.d_coefs(brown_layout(m), uv.x, uv.y, &mut cols);
                for (dc, &col) in cols.iter().zip(extra_idxs) {
                    d_params[(0, col)] = self.fx * dc.x;
                    d_params[(1, col)] = self.fy * dc.y;
                }
            }
        }
        let finite = pixel.iter().chain(d_point.iter()).chain(d_params.iter()).all(|v| v.is_finite());
        finite.then_some(Projection { pixel, d_point, d_params })
    }

    /// Pixel -> distorted normalised coordinates (inverse of K only).
    #[inline]
    pub(crate) fn distorted_from_img(&self, px: &Vec2) -> Vec2 {
        Vec2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy)
    }

    /// Pixel -> undistorted normalised coordinates; `None` when the
    /// iteration does not converge or the solution lies on a folded branch
    /// of the distortion (non-positive Jacobian determinant).
    pub(crate) fn cam_from_img(&self, px: &Vec2) -> Option<Vec2> {
        let target = self.distorted_from_img(px);
        if !(target.x.is_finite() && target.y.is_finite()) {
            return None;
        }
        match self.model {
            CameraModelId::SimplePinhole | CameraModelId::Pinhole => Some(target),
            CameraModelId::OpenCvFisheye => self.undistort_fisheye(&target),
            _ => self.undistort_newton(&target),
        }
    }

    fn undistort_newton(&self, target: &Vec2) -> Option<Vec2> {
        let scale = 1.0 + target.norm();
        // Start from one fixed-point step x = target / R(|target|²) (exact
        // for the radial part to first order), falling back to the target
        // itself when that is not finite or not closer.
        let mut x = *target;
        let start = self.distort(&x);
        let guess = target.component_div(&start).component_mul(target);
        if guess.x.is_finite()
            && guess.y.is_finite()
            && (self.distort(&guess) - target).norm() < (start - target).norm()
        {
            x = guess;
        }
        let (d0, mut j) = self.distort_jac(&x);
        let mut res = d0 - target;
        let mut res_norm = res.norm();
        if !res_norm.is_finite() {
            return None;
        }
        let mut converged = false;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            if res_norm == 0.0 {
                converged = true;
                break;
            }
            let step = j.try_inverse()? * res;
            if !(step.x.is_finite() && step.y.is_finite()) {
                return None;
            }
            // Backtracking: halve the step until the residual decreases, so
            // a poor start on a strongly curved distortion cannot diverge.
            let mut t = 1.0;
            let mut accepted = None;
            for _ in 0..MAX_BACKTRACKS {
                let cand = x - step * t;
                let (dc, jc) = self.distort_jac(&cand);
                let rc = dc - target;
                let rn = rc.norm();
                if rn < res_norm || rn <= f64::EPSILON * scale {
                    accepted = Some((cand, jc, rc, rn));
                    break;
                }
                t *= 0.5;
            }
            let step_norm = step.norm() * t;
            match accepted {
                Some((cand, jc, rc, rn)) => {
                    x = cand;
                    j = jc;
                    res = rc;
                    res_norm = rn;
                }
                // No decrease even for tiny steps: we sit at the floating
                // point floor of the residual.
                None => {
                    converged = res_norm <= ACCEPT_RESIDUAL * scale;
                    break;
                }
            }
            if step_norm <= UNDISTORT_TOLERANCE * (1.0 + x.norm()) {
                converged = true;
                break;
            }
        }
        if !converged && res_norm > ACCEPT_RESIDUAL * scale {
            return None;
        }
        // Reject solutions past a fold of the distortion (the physical
        // branch containing the principal point has det J > 0).
        (j.determinant() > 0.0 && x.x.is_finite() && x.y.is_finite()).then_some(x)
    }

    fn undistort_fisheye(&self, target: &Vec2) -> Option<Vec2> {
        let k = self.fisheye_k();
        let rd = target.norm();
        if rd * rd < FISHEYE_SMALL_R2 {
            // θ_d ≈ θ ≈ r near the axis: s = 1 + (k1 - 1/3) r², so invert to
            // first order in r² (exact to far below the tolerance here).
            let a = k[0] - 1.0 / 3.0;
            return Some(target / (1.0 + a * rd * rd));
        }
        let mut theta = rd.min(FISHEYE_MAX_THETA);
        let mut converged = false;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (td, dtd) = fisheye_theta_d(&k, theta);
            if !is_positive(dtd) {
                return None;
            }
            let step = (td - rd) / dtd;
            let mut next = theta - step;
            // Keep the iterate inside (0, π/2): halve towards the bound.
            if next <= 0.0 {
                next = theta * 0.5;
            } else if next > FISHEYE_MAX_THETA {
                next = 0.5 * (theta + FISHEYE_MAX_THETA);
            }
            let moved = (next - theta).abs();
            theta = next;
            if moved <= UNDISTORT_TOLERANCE * theta.max(1.0) {
                converged = true;
                break;
            }
        }
        let (td, dtd) = fisheye_theta_d(&k, theta);
        if !converged && (td - rd).abs() > ACCEPT_RESIDUAL * (1.0 + rd) {
            return None;
        }
        if !is_positive(dtd) || theta >= FISHEYE_MAX_THETA {
            return None;
        }
        let r = theta.tan();
        let uv = target * (r / rd);
        (uv.x.is_finite() && uv.y.is_finite()).then_some(uv)
    }
}

/// `v > 0` (false for NaN), for guards that must reject NaN.
#[inline]
pub(crate) fn is_positive(v: f64) -> bool {
    v > 0.0
}

//! Least-squares similarity between two point sets.
//!
//! S. Umeyama, "Least-squares estimation of transformation parameters between
//! two point patterns", IEEE TPAMI 13(4), 1991. The same closed form is what
//! evo (`evo_ape -a/-as`) and COLMAP's `EstimateSim3d` use.

use crate::{Mat3, Quat, Sim3, Vec3};

/// Why an alignment could not be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum UmeyamaError {
    /// The two point sets differ in length.
    #[error("point sets differ in length: {0} source vs {1} target points")]
    LengthMismatch(usize, usize),
    /// Fewer than three points (the problem is under-determined).
    #[error("need at least 3 point pairs for an alignment, got {0}")]
    TooFewPoints(usize),
    /// A coordinate is NaN or infinite.
    #[error("a point coordinate is not finite")]
    NonFinite,
    /// All source points coincide (zero variance): no rotation or scale is defined.
    #[error("source points are degenerate (zero spread)")]
    Degenerate,
}

/// Finds `dst ~ s R src + t` minimising the sum of squared distances. With
/// `with_scale = false` the scale is fixed to 1 (SE(3) alignment).
pub fn umeyama(src: &[Vec3], dst: &[Vec3], with_scale: bool) -> Result<Sim3, UmeyamaError> {
    if src.len() != dst.len() {
        return Err(UmeyamaError::LengthMismatch(src.len(), dst.len()));
    }
    let n = src.len();
    if n < 3 {
        return Err(UmeyamaError::TooFewPoints(n));
    }
    if src.iter().chain(dst).any(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(UmeyamaError::NonFinite);
    }
    let inv_n = 1.0 / n as f64;
    let mean_src = src.iter().sum::<Vec3>() * inv_n;
    let mean_dst = dst.iter().sum::<Vec3>() * inv_n;
    let mut sigma = Mat3::zeros();
    let mut var_src = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let ds = s - mean_src;
        sigma += (d - mean_dst) * ds.transpose();
        var_src += ds.norm_squared();
    }
    sigma *= inv_n;
    var_src *= inv_n;
    if var_src <= f64::EPSILON * mean_src.norm_squared().max(1.0) {
        return Err(UmeyamaError::Degenerate);
    }
    let svd = sigma.svd(true, true);
    // Both factors were requested above, so they are present.
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(UmeyamaError::Degenerate);
    };
    let mut s_diag = Vec3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s_diag[2] = -1.0;
    }
    let r = u * Mat3::from_diagonal(&s_diag) * v_t;
    let scale = if with_scale { svd.singular_values.dot(&s_diag) / var_src } else { 1.0 };
    let t = mean_dst - scale * (r * mean_src);
    let rot = nalgebra::Rotation3::from_matrix_unchecked(r);
    Ok(Sim3 { scale, rotation: Quat::from_rotation_matrix(&rot), translation: t })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SplitMix64;

    #[test]
    fn recovers_similarity() {
        let mut rng = SplitMix64::new(3);
        let truth = Sim3 {
            scale: 0.37,
            rotation: Quat::from_euler_angles(0.5, -1.0, 2.0),
            translation: Vec3::new(3.0, -1.0, 0.2),
        };
        let src: Vec<Vec3> = (0..50).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal())).collect();
        let dst: Vec<Vec3> = src.iter().map(|p| truth.transform_point(p)).collect();
        let est = umeyama(&src, &dst, true).unwrap();
        assert!((est.scale - truth.scale).abs() < 1e-12);
        assert!(est.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((est.translation - truth.translation).norm() < 1e-12);
        let rigid = umeyama(&src, &src, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert!(rigid.translation.norm() < 1e-12);
    }

    #[test]
    fn rejects_bad_input() {
        let p = vec![Vec3::zeros(); 5];
        assert_eq!(umeyama(&p, &p[..4], true), Err(UmeyamaError::LengthMismatch(5, 4)));
        assert_eq!(umeyama(&p[..2], &p[..2], true), Err(UmeyamaError::TooFewPoints(2)));
        assert_eq!(umeyama(&p, &p, true), Err(UmeyamaError::Degenerate));
        let mut q = p.clone();
        q[0].x = f64::NAN;
        assert_eq!(umeyama(&q, &p, true), Err(UmeyamaError::NonFinite));
    }
}

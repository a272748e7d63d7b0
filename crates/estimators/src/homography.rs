//! Homography: normalised DLT from four or more correspondences
//! (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., Alg. 4.2) and
//! its decomposition into (R, t, n) candidates following Ma, Soatto, Košecká
//! & Sastry, "An Invitation to 3-D Vision", §5.3.3 (the SVD form of
//! Faugeras & Lustman 1988), selected by cheirality.
//!
//! `H` maps camera-1 points to camera-2 points, `x2 ~ H x1`. For a plane
//! `nᵀ X1 = d` in camera 1 and `cam2_from_cam1 = (R, t)`,
//! `H = R + t nᵀ / d` (on normalised coordinates).

use crate::error::{EstimatorError, all_finite, check_pairs};
use crate::essential_5pt::{RecoveredPose, cheirality};
use crate::fundamental::{apply, normalizing_transform};
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use nalgebra::{DMatrix, SMatrix, SVector};

/// Minimal number of correspondences.
pub const SAMPLE_SIZE: usize = 4;
/// `|det H| / ‖H‖³` below this means a (near) rank-deficient homography,
/// e.g. from three collinear points in the sample.
const MIN_NORMALIZED_DET: f64 = 1e-10;
/// `(σ1² - σ3²)` of the normalised homography below this counts as a pure
/// rotation (no translation can be recovered).
const PURE_ROTATION_TOL: f64 = 1e-12;

/// Homography from `n >= 4` correspondences by the normalised DLT (least
/// squares for `n > 4`), scaled to unit Frobenius norm.
pub fn estimate_homography_dlt(x1: &[Vec2], x2: &[Vec2]) -> Result<Mat3, EstimatorError> {
    check_pairs("homography DLT", x1, x2, SAMPLE_SIZE)?;
    solve(x1, x2)
        .ok_or(EstimatorError::Degenerate { problem: "homography DLT", reason: "coincident or collinear points" })
}

pub(crate) fn solve(x1: &[Vec2], x2: &[Vec2]) -> Option<Mat3> {
    let t1 = normalizing_transform(x1)?;
    let t2 = normalizing_transform(x2)?;
    let n = x1.len();
    let rows = |i: usize| -> [SVector<f64, 9>; 2] {
        let a = apply(&t1, &x1[i]);
        let b = apply(&t2, &x2[i]);
        let (u, v, w) = (b.x, b.y, b.z);
        let mut r1 = SVector::<f64, 9>::zeros();
        let mut r2 = SVector::<f64, 9>::zeros();
        for k in 0..3 {
            // b × (H a) = 0, first two rows.
            r1[3 + k] = -w * a[k];
            r1[6 + k] = v * a[k];
            r2[k] = w * a[k];
            r2[6 + k] = -u * a[k];
        }
        [r1, r2]
    };
    let vt = if 2 * n < 9 {
        let mut m = SMatrix::<f64, 9, 9>::zeros();
        for i in 0..n {
            let [r1, r2] = rows(i);
            m.set_row(2 * i, &r1.transpose());
            m.set_row(2 * i + 1, &r2.transpose());
        }
        if !all_finite(m.iter()) {
            return None;
        }
        let svd = m.svd(false, true);
        // Eight independent equations are needed (rank 8).
        if !(svd.singular_values[7] > 1e-10 * svd.singular_values[0]) {
            return None;
        }
        svd.v_t?
    } else {
        let mut m = DMatrix::<f64>::zeros(2 * n, 9);
        for i in 0..n {
            let [r1, r2] = rows(i);
            m.set_row(2 * i, &r1.transpose());
            m.set_row(2 * i + 1, &r2.transpose());
        }
        if !all_finite(m.iter()) {
            return None;
        }
        let svd = m.svd(false, true);
        if !(svd.singular_values[7] > 1e-10 * svd.singular_values[0]) {
            return None;
        }
        let vt = svd.v_t?;
        SMatrix::<f64, 9, 9>::from_fn(|r, c| vt[(r, c)])
    };
    let hn = Mat3::from_fn(|i, j| vt[(8, 3 * i + j)]);
    let t2_inv = t2.try_inverse()?;
    let h = t2_inv * hn * t1;
    let nrm = h.norm();
    if !(nrm.is_finite() && nrm > 0.0) {
        return None;
    }
    let h = h / nrm;
    (h.determinant().abs() > MIN_NORMALIZED_DET).then_some(h)
}

/// Squared transfer error `‖x2 - π(H x1)‖²` (infinite when `H x1` is at
/// infinity).
pub fn transfer_error_sq(h: &Mat3, x1: &Vec2, x2: &Vec2) -> f64 {
    let p = h * Vec3::new(x1.x, x1.y, 1.0);
    if p.z.abs() <= f64::EPSILON * p.norm() {
        return f64::INFINITY;
    }
    (Vec2::new(p.x / p.z, p.y / p.z) - x2).norm_squared()
}

/// `H = R + t nᵀ / d` for `cam2_from_cam1 = (R, t)` and the plane `nᵀ X1 = d`.
pub fn homography_from_pose(cam2_from_cam1: &Rigid3, normal: &Vec3, distance: f64) -> Mat3 {
    cam2_from_cam1.rotation_matrix() + cam2_from_cam1.translation * normal.transpose() / distance
}

/// One decomposition of a homography.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomographyDecomposition {
    /// Rotation of `cam2_from_cam1`.
    pub rotation: Mat3,
    /// Translation of `cam2_from_cam1` divided by the plane distance `d`
    /// (zero for a pure rotation).
    pub translation: Vec3,
    /// Unit plane normal in camera 1.
    pub normal: Vec3,
}

/// The decompositions of `H` (defined up to scale; its sign is chosen so
/// that `det H > 0`, which holds when both cameras see the same side of the
/// plane). Returns four candidates, or one with zero translation when `H` is
/// a pure rotation.
pub fn decompose_homography(h: &Mat3) -> Result<Vec<HomographyDecomposition>, EstimatorError> {
    let sign = if h.determinant() < 0.0 { -1.0 } else { 1.0 };
    decompose_signed(&(h * sign))
}

fn decompose_signed(h: &Mat3) -> Result<Vec<HomographyDecomposition>, EstimatorError> {
    const PROBLEM: &str = "decompose homography";
    if !all_finite(h.iter()) {
        return Err(EstimatorError::NonFinite { problem: PROBLEM, index: 0 });
    }
    if !crate::error::all_in_range(h.iter()) {
        return Err(EstimatorError::OutOfRange { problem: PROBLEM, index: 0 });
    }
    let s = h.singular_values();
    if !(s[1] > 0.0) || s[2] <= MIN_NORMALIZED_DET.cbrt() * s[0] * 1e-3 {
        return Err(EstimatorError::Degenerate { problem: PROBLEM, reason: "rank-deficient homography" });
    }
    // Normalise so that the middle singular value is 1 (H = R + t nᵀ exactly).
    let hn = h / s[1];
    if !all_finite(hn.iter()) {
        return Err(EstimatorError::Degenerate { problem: PROBLEM, reason: "homography out of range" });
    }
    let svd = (hn.transpose() * hn).symmetric_eigen();
    // Sort eigenpairs descending: σ1² >= σ2² = 1 >= σ3².
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| svd.eigenvalues[b].total_cmp(&svd.eigenvalues[a]));
    let s1 = svd.eigenvalues[idx[0]];
    let s3 = svd.eigenvalues[idx[2]];
    let v1: Vec3 = svd.eigenvectors.column(idx[0]).into();
    let v2: Vec3 = svd.eigenvectors.column(idx[1]).into();
    let v3: Vec3 = svd.eigenvectors.column(idx[2]).into();
    if s1 - s3 < PURE_ROTATION_TOL {
        // H is (a multiple of) a rotation: project onto SO(3).
        let r = project_to_rotation(&hn);
        return Ok(vec![HomographyDecomposition { rotation: r, translation: Vec3::zeros(), normal: Vec3::z() }]);
    }
    let a = (1.0 - s3).max(0.0).sqrt();
    let b = (s1 - 1.0).max(0.0).sqrt();
    let c = (s1 - s3).sqrt();
    let u1 = (a * v1 + b * v3) / c;
    let u2 = (a * v1 - b * v3) / c;
    let mut out = Vec::with_capacity(4);
    for u in [u1, u2] {
        let um = Mat3::from_columns(&[v2, u, v2.cross(&u)]);
        let (hv2, hu) = (hn * v2, hn * u);
        let wm = Mat3::from_columns(&[hv2, hu, hv2.cross(&hu)]);
        let r = project_to_rotation(&(wm * um.transpose()));
        let n = v2.cross(&u);
        let t = (hn - r) * n;
        out.push(HomographyDecomposition { rotation: r, translation: t, normal: n });
        out.push(HomographyDecomposition { rotation: r, translation: -t, normal: -n });
    }
    Ok(out)
}

fn project_to_rotation(m: &Mat3) -> Mat3 {
    if !all_finite(m.iter()) {
        return Mat3::identity();
    }
    let svd = m.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let mut d = Mat3::identity();
            if (u * vt).determinant() < 0.0 {
                d[(2, 2)] = -1.0;
            }
            u * d * vt
        }
        _ => Mat3::identity(),
    }
}

/// Recovers `cam2_from_cam1` from a homography: fixes the sign of `H` so
/// that most correspondences satisfy `x2ᵀ H x1 > 0` (positive depths), then
/// keeps the decomposition with the most points in front of both cameras
/// (plane normal facing camera 1). The translation is returned with unit
/// norm, or zero for a pure rotation (then `valid` marks every point whose
/// rotated ray is in front of camera 2).
pub fn pose_from_homography(h: &Mat3, x1: &[Vec2], x2: &[Vec2]) -> Result<RecoveredPose, EstimatorError> {
    let cands = homography_poses(h, x1, x2)?;
    let mut best: Option<RecoveredPose> = None;
    for c in cands {
        if best.as_ref().is_none_or(|b| c.num_valid > b.num_valid) {
            best = Some(c);
        }
    }
    match best {
        Some(b) if b.num_valid > 0 => Ok(b),
        _ => Err(EstimatorError::Degenerate {
            problem: "pose from homography",
            reason: "no decomposition puts points in front of both cameras",
        }),
    }
}

/// Every decomposition of `H` whose plane faces camera 1, with its
/// cheirality support (the sign of `H` fixed as in [`pose_from_homography`]),
/// in decomposition order.
///
/// A plane seen from two views has two physically valid decompositions
/// (the translation and the plane normal trade places); when both keep most
/// points in front of both cameras the pose is ambiguous, and the caller
/// must not trust the best one (ORB-SLAM's `ReconstructH` asks for a clear
/// winner, Mur-Artal et al. 2015, IV-C).
pub fn homography_poses(h: &Mat3, x1: &[Vec2], x2: &[Vec2]) -> Result<Vec<RecoveredPose>, EstimatorError> {
    check_pairs("pose from homography", x1, x2, 1)?;
    let positive =
        x1.iter().zip(x2).filter(|(p, q)| Vec3::new(q.x, q.y, 1.0).dot(&(h * Vec3::new(p.x, p.y, 1.0))) > 0.0).count();
    let sign = if 2 * positive >= x1.len() { 1.0 } else { -1.0 };
    let cands = decompose_signed(&(h * sign))?;
    let mut out = Vec::with_capacity(cands.len());
    for c in &cands {
        let t_norm = c.translation.norm();
        let (valid, points3d, num_valid) = if t_norm == 0.0 {
            let valid: Vec<bool> = x1.iter().map(|p| (c.rotation * Vec3::new(p.x, p.y, 1.0)).z > 0.0).collect();
            let n = valid.iter().filter(|v| **v).count();
            (valid, vec![Vec3::repeat(f64::NAN); x1.len()], n)
        } else {
            // Plane in front of camera 1: nᵀ x1 > 0 for the observed rays.
            let facing = x1.iter().filter(|p| c.normal.dot(&Vec3::new(p.x, p.y, 1.0)) > 0.0).count();
            if 2 * facing < x1.len() {
                continue;
            }
            cheirality(&c.rotation, &(c.translation / t_norm), x1, x2)
        };
        let t = if t_norm > 0.0 { c.translation / t_norm } else { Vec3::zeros() };
        out.push(RecoveredPose {
            cam2_from_cam1: Rigid3::from_rotation_matrix(&c.rotation, t),
            valid,
            num_valid,
            points3d,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{planar_scene, rotation_error_deg, translation_dir_error_deg};

    fn plane_truth() -> (Vec3, f64) {
        // z = 4 + 0.3 x - 0.2 y  <=>  (-0.3, 0.2, 1) · X = 4.
        let n = Vec3::new(-0.3, 0.2, 1.0);
        let k = n.norm();
        (n / k, 4.0 / k)
    }

    #[test]
    fn dlt_exact() {
        let mut worst: f64 = 0.0;
        for seed in 0..100 {
            let s = planar_scene(seed, 4 + seed as usize % 10, 0.0, 0.0);
            let h = estimate_homography_dlt(&s.x1, &s.x2).unwrap();
            let (n, d) = plane_truth();
            let t = homography_from_pose(&s.cam2_from_cam1, &n, d);
            let t = t / t.norm();
            worst = worst.max((h - t).norm().min((h + t).norm()));
        }
        assert!(worst < 1e-8, "worst homography error {worst}");
    }

    #[test]
    fn decomposition_recovers_pose() {
        let mut num_ok = 0;
        for seed in 0..100 {
            let s = planar_scene(seed, 30, 0.0, 0.0);
            let (n, d) = plane_truth();
            let h = homography_from_pose(&s.cam2_from_cam1, &n, d) * -2.5;
            let pose = pose_from_homography(&h, &s.x1, &s.x2).unwrap();
            assert_eq!(pose.num_valid, 30);
            let decs = decompose_homography(&h).unwrap();
            // The true decomposition is among the candidates ...
            let true_rot = s.cam2_from_cam1.rotation_matrix();
            let t_over_d = s.cam2_from_cam1.translation / d;
            assert!(
                decs.iter().any(|c| (c.normal - n).norm() < 1e-8
                    && (c.rotation - true_rot).norm() < 1e-8
                    && (c.translation - t_over_d).norm() < 1e-8),
                "seed {seed}"
            );
            // ... and usually the selected one (two decompositions can both
            // satisfy cheirality: the classical two-fold ambiguity).
            let ok = rotation_error_deg(&pose.cam2_from_cam1, &s.cam2_from_cam1) < 1e-6
                && translation_dir_error_deg(&pose.cam2_from_cam1.translation, &s.cam2_from_cam1.translation) < 1e-6;
            num_ok += ok as usize;
        }
        eprintln!("homography: selected the true pose in {num_ok}/100");
        assert!(num_ok >= 50, "selected the true pose in {num_ok}/100");
    }

    #[test]
    fn pure_rotation_decomposes_to_zero_translation() {
        let r = Rigid3::new(colslam_geometry::Quat::from_euler_angles(0.1, -0.2, 0.05), Vec3::zeros());
        let h = r.rotation_matrix() * 3.0;
        let decs = decompose_homography(&h).unwrap();
        assert_eq!(decs.len(), 1);
        assert!(decs[0].translation.norm() == 0.0);
        assert!((decs[0].rotation - r.rotation_matrix()).norm() < 1e-12);
    }

    #[test]
    fn degenerate_inputs() {
        let p = vec![Vec2::new(0.1, 0.1); 6];
        assert!(estimate_homography_dlt(&p, &p).is_err());
        // Collinear points.
        let line: Vec<Vec2> = (0..6).map(|i| Vec2::new(0.1 * i as f64, 0.2 * i as f64)).collect();
        assert!(estimate_homography_dlt(&line, &line).is_err());
        assert!(matches!(estimate_homography_dlt(&p[..3], &p[..3]), Err(EstimatorError::TooFewPoints { .. })));
        assert!(decompose_homography(&Mat3::zeros()).is_err());
        let mut q = p.clone();
        q[5].x = f64::NAN;
        assert!(matches!(estimate_homography_dlt(&p, &q), Err(EstimatorError::NonFinite { index: 5, .. })));
    }
}

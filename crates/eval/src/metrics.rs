//! Absolute and relative pose errors (APE/ATE, RPE) and their statistics,
//! with the definitions of evo 1.38.1 (`evo.core.metrics`):
//!
//! * APE of pose `i`: `E_i = P_i^-1 Q_i` (estimate `P`, reference `Q`); the
//!   translation part is `|p_i - q_i|` on the camera centres.
//! * RPE of an index pair `(i, j)`: `E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`
//!   (Sturm et al., IROS 2012). Pairs use a frame delta: consecutive pairs
//!   `(0, d), (d, 2d), ...` by default, or all `(i, i + d)`.
//! * Statistics: rmse = sqrt(mean(e^2)), sse = sum(e^2), mean, median (mean
//!   of the two middle values for an even count), std (population, ddof 0),
//!   min, max.

use colslam_geometry::stats::{mean_and_variance, median_in_place};
use colslam_geometry::{Quat, Rigid3, nalgebra};

/// Which scalar is taken from an error pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseRelation {
    /// Norm of the translation (metres for the APE: the centre distance).
    TranslationPart,
    /// Rotation angle of the error, degrees.
    RotationAngleDeg,
    /// Rotation angle of the error, radians.
    RotationAngleRad,
    /// Frobenius norm of `R_E - I`.
    RotationPart,
    /// Frobenius norm of the 4x4 `E - I`.
    FullTransformation,
}

/// Summary statistics of an error vector.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Number of errors.
    pub count: usize,
}

/// Statistics of `errors`; `None` when it is empty.
pub fn statistics(errors: &[f64]) -> Option<Stats> {
    let (mean, var) = mean_and_variance(errors)?;
    let n = errors.len() as f64;
    let sse: f64 = errors.iter().map(|e| e * e).sum();
    let mut sorted = errors.to_vec();
    // Sorts `sorted` too; it is non-empty, so its ends are the min and max.
    let median = median_in_place(&mut sorted)?;
    Some(Stats {
        rmse: (sse / n).sqrt(),
        mean,
        median,
        std: var.sqrt(),
        min: sorted[0],
        max: sorted[sorted.len() - 1],
        sse,
        count: errors.len(),
    })
}

/// Rotation angle of a unit quaternion in radians, in [0, pi]. The atan2
/// form stays accurate for tiny angles, where `2 acos(w)` loses digits.
pub fn rotation_angle(q: &Quat) -> f64 {
    let q = q.quaternion();
    2.0 * q.imag().norm().atan2(q.w.abs())
}

/// The scalar of `relation` for an error pose.
pub fn pose_error(e: &Rigid3, relation: PoseRelation) -> f64 {
    match relation {
        PoseRelation::TranslationPart => e.translation.norm(),
        PoseRelation::RotationAngleRad => rotation_angle(&e.rotation),
        PoseRelation::RotationAngleDeg => rotation_angle(&e.rotation).to_degrees(),
        PoseRelation::RotationPart => (e.rotation_matrix() - nalgebra::Matrix3::identity()).norm(),
        PoseRelation::FullTransformation => (e.matrix4() - nalgebra::Matrix4::identity()).norm(),
    }
}

/// Per-pose absolute errors of `estimate` against `reference` (associated
/// and aligned; pose `i` pairs with pose `i`; extra poses of the longer
/// slice are ignored).
pub fn ape_errors(reference: &[Rigid3], estimate: &[Rigid3], relation: PoseRelation) -> Vec<f64> {
    reference
        .iter()
        .zip(estimate)
        .map(|(q, p)| match relation {
            // evo uses the position difference directly here.
            PoseRelation::TranslationPart => (p.translation - q.translation).norm(),
            _ => pose_error(&(p.inverse() * *q), relation),
        })
        .collect()
}

/// Index pairs with a frame distance of `delta` among `n` poses (evo's
/// `filter_pairs_by_index`): consecutive `(0, d), (d, 2d), ...`, or every
/// `(i, i + d)` when `all_pairs`. `delta == 0` gives no pairs.
pub fn rpe_pairs(n: usize, delta: usize, all_pairs: bool) -> Vec<(usize, usize)> {
    if delta == 0 {
        return Vec::new();
    }
    if all_pairs {
        (0..n.saturating_sub(delta)).map(|i| (i, i + delta)).collect()
    } else {
        let ids: Vec<usize> = (0..n).step_by(delta).collect();
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// The relative error pose of one pair (Sturm et al. 2012).
pub fn rpe_error_pose(q_i: &Rigid3, q_j: &Rigid3, p_i: &Rigid3, p_j: &Rigid3) -> Rigid3 {
    let q_rel = q_i.inverse() * *q_j;
    let p_rel = p_i.inverse() * *p_j;
    q_rel.inverse() * p_rel
}

/// Relative errors for `pairs` (indices out of range are skipped).
pub fn rpe_errors(
    reference: &[Rigid3],
    estimate: &[Rigid3],
    pairs: &[(usize, usize)],
    relation: PoseRelation,
) -> Vec<f64> {
    pairs
        .iter()
        .filter_map(|&(i, j)| {
            let e = rpe_error_pose(reference.get(i)?, reference.get(j)?, estimate.get(i)?, estimate.get(j)?);
            Some(pose_error(&e, relation))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_geometry::Vec3;

    #[test]
    fn statistics_by_hand() {
        let s = statistics(&[3.0, 1.0, 4.0, 2.0]).unwrap();
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.median, 2.5);
        assert_eq!(s.sse, 30.0);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.min, s.max, s.count), (1.0, 4.0, 4));
        let odd = statistics(&[5.0, 1.0, 2.0]).unwrap();
        assert_eq!(odd.median, 2.0);
        assert!(statistics(&[]).is_none());
    }

    #[test]
    fn ape_by_hand() {
        let q = vec![Rigid3::identity(), Rigid3::new(Quat::identity(), Vec3::new(1.0, 0.0, 0.0))];
        let rot = Quat::from_axis_angle(&Vec3::z_axis(), 0.1);
        let p =
            vec![Rigid3::new(Quat::identity(), Vec3::new(0.0, 3.0, 4.0)), Rigid3::new(rot, Vec3::new(1.0, 0.0, 0.0))];
        assert_eq!(ape_errors(&q, &p, PoseRelation::TranslationPart), vec![5.0, 0.0]);
        let ang = ape_errors(&q, &p, PoseRelation::RotationAngleDeg);
        assert_eq!(ang[0], 0.0);
        assert!((ang[1] - 0.1f64.to_degrees()).abs() < 1e-12);
        // ||R_z(a) - I||_F^2 = 2 (1 - cos a)^2 + 2 sin^2 a = 4 - 4 cos a.
        let rp = ape_errors(&q, &p, PoseRelation::RotationPart);
        assert!((rp[1] - (4.0 - 4.0 * 0.1f64.cos()).sqrt()).abs() < 1e-12);
        // Pose 0: E = P^-1 Q has translation -(0,3,4): full norm 5.
        let full = ape_errors(&q, &p, PoseRelation::FullTransformation);
        assert!((full[0] - 5.0).abs() < 1e-12);
    }

    #[test]
    fn rpe_pairs_and_errors() {
        assert_eq!(rpe_pairs(5, 1, false), vec![(0, 1), (1, 2), (2, 3), (3, 4)]);
        assert_eq!(rpe_pairs(6, 2, false), vec![(0, 2), (2, 4)]);
        assert_eq!(rpe_pairs(5, 2, true), vec![(0, 2), (1, 3), (2, 4)]);
        assert!(rpe_pairs(1, 1, false).is_empty());
        assert!(rpe_pairs(5, 0, false).is_empty());
        // Reference moves 1 m along x per step; the estimate 1.1 m and turns
        // 2 degrees about z once. RPE translation 0.1 m per pair; the rotation
        // error shows in the pair where it happens only.
        let yaw = Quat::from_axis_angle(&Vec3::z_axis(), 2f64.to_radians());
        let q: Vec<Rigid3> = (0..3).map(|i| Rigid3::new(Quat::identity(), Vec3::new(i as f64, 0.0, 0.0))).collect();
        let p = vec![
            Rigid3::new(Quat::identity(), Vec3::new(0.0, 0.0, 0.0)),
            Rigid3::new(Quat::identity(), Vec3::new(1.1, 0.0, 0.0)),
            Rigid3::new(yaw, Vec3::new(2.2, 0.0, 0.0)),
        ];
        let pairs = rpe_pairs(3, 1, false);
        let t = rpe_errors(&q, &p, &pairs, PoseRelation::TranslationPart);
        assert!((t[0] - 0.1).abs() < 1e-12 && (t[1] - 0.1).abs() < 1e-12, "{t:?}");
        let r = rpe_errors(&q, &p, &pairs, PoseRelation::RotationAngleDeg);
        assert!(r[0].abs() < 1e-12 && (r[1] - 2.0).abs() < 1e-12, "{r:?}");
        // The RPE is invariant to a rigid motion of the estimate.
        let g = Rigid3::new(Quat::from_euler_angles(0.3, 0.2, 0.1), Vec3::new(4.0, 5.0, 6.0));
        let moved: Vec<Rigid3> = p.iter().map(|x| g * *x).collect();
        let t2 = rpe_errors(&q, &moved, &pairs, PoseRelation::TranslationPart);
        assert!((t2[1] - t[1]).abs() < 1e-12);
    }

    #[test]
    fn small_angles_are_accurate() {
        let a = 1e-9;
        let q = Quat::from_axis_angle(&Vec3::x_axis(), a);
        assert!((rotation_angle(&q) - a).abs() < 1e-20);
        let q = Quat::from_axis_angle(&Vec3::y_axis(), 3.0);
        assert!((rotation_angle(&q) - 3.0).abs() < 1e-12);
    }
}

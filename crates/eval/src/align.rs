//! Alignment of an (associated) estimate onto its reference, as evo's
//! `PosePath3D.align`: Umeyama's closed form (S. Umeyama, IEEE TPAMI 13(4),
//! 1991) on the camera centres, the estimate being moved onto the reference.
//!
//! * `Se3` (`evo -a`): rotation + translation.
//! * `Sim3` (`evo -as`): rotation + translation + scale.
//! * `Scale` (`evo -s`): the scale of the full Sim(3) solution only; the
//!   estimate's positions are multiplied by it, nothing else changes.
//!
//! Poses are moved as evo does: the centre goes through the similarity and
//! the rotation is pre-multiplied by its rotation.

use crate::trajectory::Trajectory;
use colslam_geometry::{Sim3, Vec3, nalgebra};

/// Minimum number of position pairs for an alignment.
pub const MIN_ALIGN_POINTS: usize = 3;

/// How the estimate is aligned onto the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// No alignment.
    None,
    /// Rigid: rotation and translation (`evo -a`).
    Se3,
    /// Similarity: rotation, translation and scale (`evo -as`). Default, the
    /// project's protocol.
    #[default]
    Sim3,
    /// Scale only (`evo -s`).
    Scale,
}

impl std::fmt::Display for Alignment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Alignment::None => "none",
            Alignment::Se3 => "SE(3)",
            Alignment::Sim3 => "Sim(3)",
            Alignment::Scale => "scale",
        })
    }
}

/// Why an alignment failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// The two trajectories differ in length (they must be associated first).
    #[error("trajectories differ in length: {reference} reference vs {estimate} estimated poses")]
    LengthMismatch {
        /// Reference length.
        reference: usize,
        /// Estimate length.
        estimate: usize,
    },
    /// Fewer than [`MIN_ALIGN_POINTS`] pairs.
    #[error("{0} position pairs, at least {MIN_ALIGN_POINTS} are needed for an alignment")]
    TooFew(usize),
    /// The positions do not span enough dimensions.
    #[error("{0}")]
    Degenerate(String),
}

/// An alignment and the moved estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct AlignResult {
    /// The similarity applied to the estimate (`reference_from_estimate`).
    /// Identity for [`Alignment::None`]; pure scale for [`Alignment::Scale`].
    pub transform: Sim3,
    /// The estimate after the alignment.
    pub aligned: Trajectory,
}

/// Applies a similarity to every pose of a trajectory (centre transformed,
/// rotation pre-multiplied).
pub fn transform_trajectory(traj: &Trajectory, s: &Sim3) -> Trajectory {
    Trajectory {
        stamps: traj.stamps.clone(),
        poses: traj.poses.iter().map(|p| s.transform_world_from_cam(p)).collect(),
    }
}

/// Aligns `estimate` onto `reference` (both already associated: pose `i`
/// of one pairs with pose `i` of the other). `n_to_align` restricts the fit
/// to the first `n` pairs (evo's `--n_to_align`; more than there are means all).
pub fn align(
    reference: &Trajectory,
    estimate: &Trajectory,
    mode: Alignment,
    n_to_align: Option<usize>,
) -> Result<AlignResult, AlignError> {
    if reference.len() != estimate.len() {
        return Err(AlignError::LengthMismatch { reference: reference.len(), estimate: estimate.len() });
    }
    if mode == Alignment::None {
        return Ok(AlignResult { transform: Sim3::identity(), aligned: estimate.clone() });
    }
    let n = n_to_align.unwrap_or(usize::MAX).min(estimate.len());
    let src: Vec<Vec3> = estimate.poses.iter().take(n).map(|p| p.translation).collect();
    let dst: Vec<Vec3> = reference.poses.iter().take(n).map(|p| p.translation).collect();
    if n < MIN_ALIGN_POINTS {
        return Err(AlignError::TooFew(n));
    }
    check_rank(&src, &dst)?;
    let with_scale = matches!(mode, Alignment::Sim3 | Alignment::Scale);
    let sim = colslam_geometry::umeyama(&src, &dst, with_scale).map_err(|e| AlignError::Degenerate(e.to_string()))?;
    if !(sim.scale.is_finite() && sim.scale > 0.0) {
        return Err(AlignError::Degenerate(format!("alignment scale {} is not positive", sim.scale)));
    }
    let transform = if mode == Alignment::Scale { Sim3 { scale: sim.scale, ..Sim3::identity() } } else { sim };
    Ok(AlignResult { aligned: transform_trajectory(estimate, &transform), transform })
}

/// evo's degeneracy test: the cross-covariance of the two centred point sets
/// must have at least two singular values above machine epsilon (rank >= 2),
/// otherwise the rotation is undefined.
fn check_rank(src: &[Vec3], dst: &[Vec3]) -> Result<(), AlignError> {
    let inv_n = 1.0 / src.len() as f64;
    let mean_s = src.iter().sum::<Vec3>() * inv_n;
    let mean_d = dst.iter().sum::<Vec3>() * inv_n;
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for (s, d) in src.iter().zip(dst) {
        cov += (d - mean_d) * (s - mean_s).transpose();
    }
    cov *= inv_n;
    let sv = cov.singular_values();
    let rank = sv.iter().filter(|&&v| v > f64::EPSILON).count();
    if rank < 2 {
        return Err(AlignError::Degenerate(format!(
            "the position cross-covariance has rank {rank} (positions coincide or are collinear); Umeyama alignment is not possible"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_geometry::{Quat, Rigid3, SplitMix64};

    fn random_traj(n: usize, seed: u64) -> Trajectory {
        let mut rng = SplitMix64::new(seed);
        let poses = (0..n)
            .map(|_| {
                Rigid3::new(
                    Quat::from_euler_angles(rng.normal(), rng.normal(), rng.normal()),
                    Vec3::new(rng.normal(), rng.normal(), rng.normal()),
                )
            })
            .collect();
        Trajectory::new((0..n).map(|i| i as f64).collect(), poses)
    }

    fn truth() -> Sim3 {
        Sim3 { scale: 0.3, rotation: Quat::from_euler_angles(0.4, -0.7, 2.1), translation: Vec3::new(1.0, -2.0, 3.0) }
    }

    #[test]
    fn recovers_known_sim3_and_moves_rotations() {
        let reference = random_traj(40, 5);
        // estimate = truth^-1 applied to the reference, so aligning it recovers truth.
        let estimate = transform_trajectory(&reference, &truth().inverse());
        let r = align(&reference, &estimate, Alignment::Sim3, None).unwrap();
        assert!((r.transform.scale - 0.3).abs() < 1e-12);
        assert!(r.transform.rotation.angle_to(&truth().rotation) < 1e-12);
        assert!((r.transform.translation - truth().translation).norm() < 1e-12);
        for (a, b) in r.aligned.poses.iter().zip(&reference.poses) {
            assert!((a.translation - b.translation).norm() < 1e-12);
            assert!(a.rotation.angle_to(&b.rotation) < 1e-12);
        }
        // SE(3) on the same data keeps scale 1 and cannot fit exactly.
        let se3 = align(&reference, &estimate, Alignment::Se3, None).unwrap();
        assert_eq!(se3.transform.scale, 1.0);
        // Scale-only: positions scaled, rotations untouched.
        let sc = align(&reference, &estimate, Alignment::Scale, None).unwrap();
        assert!((sc.transform.scale - 0.3).abs() < 1e-12);
        assert_eq!(sc.aligned.poses[3].rotation, estimate.poses[3].rotation);
        assert!((sc.aligned.poses[3].translation - 0.3 * estimate.poses[3].translation).norm() < 1e-12);
        // None: unchanged.
        let none = align(&reference, &estimate, Alignment::None, None).unwrap();
        assert_eq!(none.aligned, estimate);
    }

    #[test]
    fn n_to_align_uses_prefix() {
        let reference = random_traj(20, 8);
        let mut estimate = transform_trajectory(&reference, &truth().inverse());
        // Corrupt the tail; aligning on the first 10 still recovers truth.
        for p in estimate.poses.iter_mut().skip(10) {
            p.translation += Vec3::new(5.0, 0.0, 0.0);
        }
        let r = align(&reference, &estimate, Alignment::Sim3, Some(10)).unwrap();
        assert!((r.transform.scale - 0.3).abs() < 1e-12);
        let all = align(&reference, &estimate, Alignment::Sim3, Some(1000)).unwrap();
        assert!((all.transform.scale - 0.3).abs() > 1e-3);
    }

    #[test]
    fn degenerate_and_too_few() {
        let reference = random_traj(10, 2);
        let mut collinear = reference.clone();
        for (i, p) in collinear.poses.iter_mut().enumerate() {
            p.translation = Vec3::new(i as f64, 2.0 * i as f64, 0.0);
        }
        let e = align(&reference, &collinear, Alignment::Sim3, None).unwrap_err();
        assert!(matches!(e, AlignError::Degenerate(_)), "{e}");
        assert_eq!(align(&reference, &reference, Alignment::Sim3, Some(2)).unwrap_err(), AlignError::TooFew(2));
        let short = reference.select(&[0, 1, 2]);
        assert!(matches!(align(&reference, &short, Alignment::Se3, None), Err(AlignError::LengthMismatch { .. })));
    }
}

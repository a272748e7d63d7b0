//! The error type shared by every estimator.

/// Why an estimator could not produce a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimatorError {
    /// Fewer correspondences than the problem needs.
    #[error("{problem}: need at least {needed} correspondences, got {got}")]
    TooFewPoints {
        /// The problem being solved.
        problem: &'static str,
        /// Minimum number of correspondences.
        needed: usize,
        /// Number given.
        got: usize,
    },
    /// Two input slices that must be parallel differ in length.
    #[error("{problem}: input lengths differ ({0} vs {1})", .lengths.0, .lengths.1)]
    LengthMismatch {
        /// The problem being solved.
        problem: &'static str,
        /// The two lengths.
        lengths: (usize, usize),
    },
    /// An input coordinate is NaN or infinite.
    #[error("{problem}: input {index} has a non-finite coordinate")]
    NonFinite {
        /// The problem being solved.
        problem: &'static str,
        /// Index of the first offending correspondence.
        index: usize,
    },
    /// An input coordinate is finite but so large (above [`MAX_COORD`]) that
    /// the solvers' products would overflow.
    #[error("{problem}: input {index} has a coordinate beyond ±{max:e}", max = MAX_COORD)]
    OutOfRange {
        /// The problem being solved.
        problem: &'static str,
        /// Index of the first offending correspondence.
        index: usize,
    },
    /// An options field is out of range.
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// The data admit no (or no unique) model: e.g. coincident or collinear points.
    #[error("{problem}: degenerate input ({reason})")]
    Degenerate {
        /// The problem being solved.
        problem: &'static str,
        /// What is degenerate.
        reason: &'static str,
    },
    /// RANSAC ran but no model reached the minimum support.
    #[error("{problem}: no model found after {trials} trials (best support {best_inliers} inliers)")]
    NoModel {
        /// The problem being solved.
        problem: &'static str,
        /// Trials run.
        trials: usize,
        /// Best inlier count seen.
        best_inliers: usize,
    },
}

/// Largest accepted magnitude of an input coordinate. Normalised image
/// coordinates and metric scene coordinates are many orders of magnitude
/// below; the bound keeps every product formed by the solvers (up to about
/// the sixth power of a coordinate) finite.
pub const MAX_COORD: f64 = 1e50;

/// True when every value is finite.
pub(crate) fn all_finite<'a, I: IntoIterator<Item = &'a f64>>(values: I) -> bool {
    values.into_iter().all(|v| v.is_finite())
}

/// True when every value is finite and at most [`MAX_COORD`] in magnitude.
pub(crate) fn all_in_range<'a, I: IntoIterator<Item = &'a f64>>(values: I) -> bool {
    values.into_iter().all(|v| v.abs() <= MAX_COORD)
}

/// Umeyama rigid alignment, refusing inputs whose squares could overflow (its
/// SVD would not terminate on non-finite entries).
pub(crate) fn rigid_align(src: &[crate::Vec3], dst: &[crate::Vec3]) -> Option<colslam_geometry::Rigid3> {
    if !all_in_range(src.iter().chain(dst).flat_map(|p| p.iter())) {
        return None;
    }
    let sim = colslam_geometry::umeyama(src, dst, false).ok()?;
    let pose = colslam_geometry::Rigid3::new(sim.rotation, sim.translation);
    all_finite(pose.translation.iter().chain(pose.rotation.coords.iter())).then_some(pose)
}

/// Checks that two slices are parallel, long enough and finite.
pub(crate) fn check_pairs<const DA: usize, const DB: usize>(
    problem: &'static str,
    a: &[nalgebra::SVector<f64, DA>],
    b: &[nalgebra::SVector<f64, DB>],
    needed: usize,
) -> Result<(), EstimatorError> {
    if a.len() != b.len() {
        return Err(EstimatorError::LengthMismatch { problem, lengths: (a.len(), b.len()) });
    }
    if a.len() < needed {
        return Err(EstimatorError::TooFewPoints { problem, needed, got: a.len() });
    }
    for (index, (p, q)) in a.iter().zip(b).enumerate() {
        if !all_finite(p.iter().chain(q.iter())) {
            return Err(EstimatorError::NonFinite { problem, index });
        }
        if !all_in_range(p.iter().chain(q.iter())) {
            return Err(EstimatorError::OutOfRange { problem, index });
        }
    }
    Ok(())
}

//! Timestamp association of a reference and an estimated trajectory, with
//! the exact rule of evo 1.38.1 (`evo.core.sync`, nearest-time method), so
//! that the matched pairs, and hence every metric, equal `evo_ape`'s.
//!
//! The rule, restated:
//! * The trajectory with fewer poses drives the search (on a tie, the
//!   estimate), so that none of its poses is lost; each of its stamps is
//!   matched to the nearest stamp of the other one, within `max_diff`.
//! * The time offset is added to the estimate's stamps (implemented as
//!   `+offset` on the estimate when it is searched, `-offset` on the
//!   reference when the reference is searched).
//! * When the searched stamps are sorted (non-decreasing), a binary search
//!   finds the first stamp strictly greater than the query; the upper
//!   neighbour wins only when strictly closer, so on a tie the earlier
//!   stamp wins. Otherwise a linear scan takes the first minimum.
//! * A stamp of the searched trajectory may be matched more than once.

use crate::EvalError;
use crate::trajectory::Trajectory;

/// Options of [`associate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AssociateOptions {
    /// Largest accepted |t_ref - (t_est + offset)|, seconds. Default 0.01
    /// (evo's `--t_max_diff` default).
    pub max_diff: f64,
    /// Added to the estimate's stamps before matching, seconds. Default 0.
    pub offset: f64,
}

impl Default for AssociateOptions {
    fn default() -> Self {
        Self { max_diff: DEFAULT_MAX_DIFF, offset: 0.0 }
    }
}

/// evo's default `--t_max_diff`, seconds.
pub const DEFAULT_MAX_DIFF: f64 = 0.01;

impl AssociateOptions {
    /// Checks that `max_diff` is finite and non-negative and `offset` finite.
    pub fn validate(&self) -> Result<(), EvalError> {
        if !(self.max_diff.is_finite() && self.max_diff >= 0.0) {
            return Err(EvalError::InvalidOptions(format!("max_diff must be finite and >= 0, got {}", self.max_diff)));
        }
        if !self.offset.is_finite() {
            return Err(EvalError::InvalidOptions(format!("offset must be finite, got {}", self.offset)));
        }
        Ok(())
    }
}

/// Matched index pairs: `reference.poses[ref_indices[k]]` pairs with
/// `estimate.poses[est_indices[k]]`. Order follows the driving (shorter)
/// trajectory, as in evo.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Association {
    /// Indices into the reference.
    pub ref_indices: Vec<usize>,
    /// Indices into the estimate.
    pub est_indices: Vec<usize>,
}

impl Association {
    /// Number of matched pairs.
    pub fn len(&self) -> usize {
        self.ref_indices.len()
    }

    /// True when nothing matched.
    pub fn is_empty(&self) -> bool {
        self.ref_indices.is_empty()
    }
}

/// For each stamp of `query`, the index of the nearest stamp of
/// `target + target_offset` within `max_diff` (evo's
/// `matching_time_indices`). Returns (matched query indices, matched target
/// indices).
pub fn matching_time_indices(
    query: &[f64],
    target: &[f64],
    max_diff: f64,
    target_offset: f64,
) -> (Vec<usize>, Vec<usize>) {
    let shifted: Vec<f64> = target.iter().map(|t| t + target_offset).collect();
    let mut out_q = Vec::new();
    let mut out_t = Vec::new();
    let (Some(&first), Some(&last)) = (shifted.first(), shifted.last()) else {
        return (out_q, out_t);
    };
    let sorted = shifted.windows(2).all(|w| w[1] - w[0] >= 0.0);
    if !sorted {
        // Linear scan; the first index of the minimum wins (np.argmin).
        for (iq, &q) in query.iter().enumerate() {
            let mut best = 0usize;
            let mut best_diff = f64::INFINITY;
            for (it, &t) in shifted.iter().enumerate() {
                let d = (t - q).abs();
                if d < best_diff {
                    best = it;
                    best_diff = d;
                }
            }
            if best_diff <= max_diff {
                out_q.push(iq);
                out_t.push(best);
            }
        }
        return (out_q, out_t);
    }
    let n = shifted.len();
    for (iq, &q) in query.iter().enumerate() {
        if q < first - max_diff || q > last + max_diff {
            continue;
        }
        // First index whose stamp is strictly greater than q (searchsorted
        // side="right"), clamped to the last index.
        let upper = shifted.partition_point(|&t| t <= q).min(n - 1);
        let diff_ub = shifted[upper] - q;
        let diff_lb = if upper > 0 { q - shifted[upper - 1] } else { f64::INFINITY };
        let best = if diff_ub <= max_diff && diff_ub < diff_lb {
            upper
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            upper - 1 // diff_lb is finite, so upper > 0.
        } else {
            continue;
        };
        out_q.push(iq);
        out_t.push(best);
    }
    (out_q, out_t)
}

/// Associates `reference` and `estimate` by timestamp like evo's
/// `associate_trajectories` (nearest-time method). An empty result is not an
/// error here; [`crate::evaluate`] turns it into one.
pub fn associate(reference: &Trajectory, estimate: &Trajectory, opts: &AssociateOptions) -> Association {
    // evo: traj_1 = reference, traj_2 = estimate. The shorter one drives;
    // on equal lengths the estimate drives.
    let est_longer = estimate.stamps.len() > reference.stamps.len();
    if est_longer {
        let (r, e) = matching_time_indices(&reference.stamps, &estimate.stamps, opts.max_diff, opts.offset);
        Association { ref_indices: r, est_indices: e }
    } else {
        let (e, r) = matching_time_indices(&estimate.stamps, &reference.stamps, opts.max_diff, -opts.offset);
        Association { ref_indices: r, est_indices: e }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use colslam_geometry::Rigid3;

    fn traj(stamps: &[f64]) -> Trajectory {
        Trajectory::new(stamps.to_vec(), vec![Rigid3::identity(); stamps.len()])
    }

    #[test]
    fn nearest_within_max_diff() {
        let (q, t) = matching_time_indices(&[0.0, 1.004, 2.02, 3.0], &[0.0, 1.0, 2.0, 3.009], 0.01, 0.0);
        assert_eq!(q, vec![0, 1, 3]);
        assert_eq!(t, vec![0, 1, 3]);
    }

    #[test]
    fn tie_prefers_earlier_stamp() {
        // 0.5 is exactly between 0.25 and 0.75 (both exact in binary).
        let (_, t) = matching_time_indices(&[0.5], &[0.25, 0.75], 0.3, 0.0);
        assert_eq!(t, vec![0]);
        // Strictly closer upper neighbour wins.
        let (_, t) = matching_time_indices(&[0.5], &[0.25, 0.625], 0.3, 0.0);
        assert_eq!(t, vec![1]);
        // Unsorted target: linear scan, first minimum wins.
        let (_, t) = matching_time_indices(&[0.5], &[0.75, 0.25, 0.0], 0.3, 0.0);
        assert_eq!(t, vec![0]);
    }

    #[test]
    fn outside_range_and_clamping() {
        // Beyond the last stamp but within max_diff: matches the last one.
        let (q, t) = matching_time_indices(&[-0.02, 3.005, 3.02], &[0.0, 1.0, 3.0], 0.01, 0.0);
        assert_eq!(q, vec![1]);
        assert_eq!(t, vec![2]);
        // Duplicate target stamps: the later of equal stamps is the lower neighbour.
        let (_, t) = matching_time_indices(&[1.0], &[0.0, 1.0, 1.0, 2.0], 0.01, 0.0);
        assert_eq!(t, vec![2]);
        // Empty target.
        assert_eq!(matching_time_indices(&[1.0], &[], 0.01, 0.0), (vec![], vec![]));
    }

    #[test]
    fn shorter_trajectory_drives_and_offset_applies_to_estimate() {
        // Reference longer: the estimate drives; both est stamps map to ref 1.
        let r = traj(&[0.0, 1.0, 2.0, 3.0]);
        let e = traj(&[0.995, 1.004]);
        let a = associate(&r, &e, &AssociateOptions::default());
        assert_eq!(a.est_indices, vec![0, 1]);
        assert_eq!(a.ref_indices, vec![1, 1]);
        // Estimate longer: the reference drives, each ref stamp once.
        let r2 = traj(&[1.0, 2.0]);
        let e2 = traj(&[0.995, 1.004, 1.999, 2.5]);
        let a2 = associate(&r2, &e2, &AssociateOptions::default());
        assert_eq!(a2.ref_indices, vec![0, 1]);
        assert_eq!(a2.est_indices, vec![1, 2]);
        // Offset: est stamps + 10 s line up with the reference, either way round.
        let e3 = traj(&[-10.0, -9.0, -8.0, -7.0, -6.5]);
        let opts = AssociateOptions { max_diff: 0.01, offset: 10.0 };
        let a3 = associate(&r, &e3, &opts);
        assert_eq!(a3.ref_indices, vec![0, 1, 2, 3]);
        assert_eq!(a3.est_indices, vec![0, 1, 2, 3]);
        let a4 = associate(&r, &traj(&[-9.0, -7.0]), &opts);
        assert_eq!(a4.ref_indices, vec![1, 3]);
        // Tie in length: the estimate drives.
        let a5 = associate(&traj(&[0.0, 1.0]), &traj(&[1.0, 1.0]), &AssociateOptions::default());
        assert_eq!(a5.est_indices, vec![0, 1]);
        assert_eq!(a5.ref_indices, vec![1, 1]);
    }

    #[test]
    fn options_validate() {
        assert!(AssociateOptions::default().validate().is_ok());
        assert!(AssociateOptions { max_diff: -1.0, offset: 0.0 }.validate().is_err());
        assert!(AssociateOptions { max_diff: 0.1, offset: f64::NAN }.validate().is_err());
    }
}

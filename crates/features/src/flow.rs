//! The optical-flow score used for keyframe selection (the paper, section
//! 3.2): for every match, the per-axis displacement divided by the focal
//! length, `(|x1 - x2| / fx, |y1 - y2| / fy)`; the score is the median of the
//! x parts plus the median of the y parts. A new keyframe needs the score to
//! exceed a threshold (0.05 in the paper), which rejects pairs with too small
//! a baseline.

use crate::FeatureError;
use crate::types::{Keypoint, Match};
use colslam_geometry::stats::median_in_place;

/// Result of [`flow_score`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlowScore {
    /// `median_x + median_y` (0 when there are no matches).
    pub score: f64,
    /// Median of `|x1 - x2| / fx` over the matches.
    pub median_x: f64,
    /// Median of `|y1 - y2| / fy` over the matches.
    pub median_y: f64,
    /// Number of matches used.
    pub num_matches: usize,
}

/// The paper's flow score of `matches` between keypoints `kps_a` (query side)
/// and `kps_b` (train side), for a camera with focal lengths `fx`, `fy` in
/// pixels. With no matches the score and medians are 0 (no measurable
/// motion). Errors on a non-positive or non-finite focal length and on a
/// match index out of range (naming the match).
pub fn flow_score(
    kps_a: &[Keypoint],
    kps_b: &[Keypoint],
    matches: &[Match],
    fx: f64,
    fy: f64,
) -> Result<FlowScore, FeatureError> {
    if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
        return Err(FeatureError::BadFocalLength { fx, fy });
    }
    let mut dx = Vec::with_capacity(matches.len());
    let mut dy = Vec::with_capacity(matches.len());
    for (index, m) in matches.iter().enumerate() {
        let a = kps_a.get(m.query as usize).ok_or(FeatureError::MatchOutOfRange {
            index,
            side: "query",
            keypoint: m.query,
            len: kps_a.len(),
        })?;
        let b = kps_b.get(m.train as usize).ok_or(FeatureError::MatchOutOfRange {
            index,
            side: "train",
            keypoint: m.train,
            len: kps_b.len(),
        })?;
        dx.push((a.x as f64 - b.x as f64).abs() / fx);
        dy.push((a.y as f64 - b.y as f64).abs() / fy);
    }
    if matches.is_empty() {
        return Ok(FlowScore { score: 0.0, median_x: 0.0, median_y: 0.0, num_matches: 0 });
    }
    // Non-empty here; the mean of the two middle values for an even count.
    let median_x = median_in_place(&mut dx).unwrap_or(0.0);
    let median_y = median_in_place(&mut dy).unwrap_or(0.0);
    Ok(FlowScore { score: median_x + median_y, median_x, median_y, num_matches: matches.len() })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kp(x: f32, y: f32) -> Keypoint {
        Keypoint { x, y, octave: 0, angle: 0.0, response: 0.0, size: 31.0 }
    }

    fn m(q: u32, t: u32) -> Match {
        Match { query: q, train: t, distance: 0.0 }
    }

    #[test]
    fn hand_computed_example() {
        // Displacements (dx, dy) in pixels: (10, 0), (20, 5), (30, 10), (400, 2).
        let a = [kp(100.0, 100.0), kp(200.0, 200.0), kp(300.0, 300.0), kp(0.0, 0.0)];
        let b = [kp(110.0, 100.0), kp(180.0, 205.0), kp(330.0, 290.0), kp(400.0, 2.0)];
        let ms = [m(0, 0), m(1, 1), m(2, 2), m(3, 3)];
        let f = flow_score(&a, &b, &ms, 500.0, 250.0).unwrap();
        // x: 10, 20, 30, 400 px / 500 -> median (20 + 30) / 2 / 500 = 0.05.
        // y: 0, 5, 10, 2 px / 250 -> sorted 0, 2, 5, 10 -> (2 + 5) / 2 / 250 = 0.014.
        assert!((f.median_x - 0.05).abs() < 1e-12, "{f:?}");
        assert!((f.median_y - 0.014).abs() < 1e-12, "{f:?}");
        assert!((f.score - 0.064).abs() < 1e-12);
        assert_eq!(f.num_matches, 4);
        // Odd count: the middle value; order of matches does not matter.
        let f3 = flow_score(&a, &b, &[m(2, 2), m(0, 0), m(1, 1)], 10.0, 10.0).unwrap();
        assert!((f3.median_x - 2.0).abs() < 1e-12 && (f3.median_y - 0.5).abs() < 1e-12, "{f3:?}");
        // Cross matches index the right sides.
        let fc = flow_score(&a, &b, &[m(0, 3)], 1.0, 1.0).unwrap();
        assert!((fc.median_x - 300.0).abs() < 1e-9 && (fc.median_y - 98.0).abs() < 1e-9);
    }

    #[test]
    fn empty_and_bad_inputs() {
        let a = [kp(0.0, 0.0)];
        let f = flow_score(&a, &a, &[], 500.0, 500.0).unwrap();
        assert_eq!((f.score, f.num_matches), (0.0, 0));
        assert!(matches!(flow_score(&a, &a, &[], 0.0, 1.0), Err(FeatureError::BadFocalLength { .. })));
        assert!(flow_score(&a, &a, &[], 1.0, f64::NAN).is_err());
        let e = flow_score(&a, &a, &[m(0, 0), m(0, 5)], 1.0, 1.0).unwrap_err();
        assert!(matches!(e, FeatureError::MatchOutOfRange { index: 1, side: "train", keypoint: 5, len: 1 }), "{e}");
        let e = flow_score(&a, &a, &[m(2, 0)], 1.0, 1.0).unwrap_err();
        assert!(e.to_string().contains("query keypoint 2"), "{e}");
    }
}

//! The keyframe decision (paper 3.2, 3.4) as a pure function of a frame's
//! matches to the reference keyframe and its flow score, so the table of
//! cases can be tested without a map; and the rotation-compensated flow
//! (`--parallax-threshold`) that can stand in for the paper's flow score.

use crate::options::KeyframeOptions;
use colslam_geometry::stats::median_in_place;
use colslam_geometry::{Quat, Vec2, Vec3};

/// Whether a frame must become a keyframe although it is no candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ForceKeyframe {
    /// No: tracking is safe.
    No,
    /// Tracking is about to be lost, and this frame still matches well
    /// enough to be registered.
    ThisFrame,
    /// Tracking is about to be lost and this frame matches too little: the
    /// previous frame becomes the keyframe, and this one is tracked against
    /// it.
    PreviousFrame,
}

/// What the keyframe test says of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeyframeDecision {
    /// The paper's test: enough matches and enough flow. A candidate is still
    /// checked for pure rotation before it is registered.
    pub candidate: bool,
    /// What to force when the frame is no keyframe after that (not a
    /// candidate, or rejected as a pure rotation; a candidate whose
    /// registration failed is not forced again).
    pub force: ForceKeyframe,
}

/// The keyframe decision for a frame with `matches` matches to the reference
/// keyframe and flow score `flow`.
pub fn keyframe_decision(matches: usize, flow: f64, opts: &KeyframeOptions) -> KeyframeDecision {
    let enough = matches >= opts.min_matches;
    let candidate = enough && flow > opts.flow_threshold;
    let force = if matches >= opts.force_keyframe_matches {
        ForceKeyframe::No
    } else if enough {
        ForceKeyframe::ThisFrame
    } else {
        ForceKeyframe::PreviousFrame
    };
    KeyframeDecision { candidate, force }
}

/// The paper's flow score (per-axis medians of the displacement over the
/// focal length, summed) after removing the rotation `kf_from_frame` between
/// a frame and its reference keyframe: each frame bearing is rotated into the
/// keyframe before its displacement to the matched keyframe point is taken.
/// `frame` and `keyframe` are the matched points' undistorted normalised
/// coordinates, pair by pair (pixels over the focal length, so the score has
/// the paper's units). What is left is the parallax the translation made,
/// the motion that triangulates: in a turn the raw flow is the rotation and
/// grows at every frame while the baseline does not (ORB-SLAM and DSO decide
/// keyframes on such rotation-free measures). `None` when no pair lies in
/// front of the keyframe after the rotation.
pub fn rotation_compensated_flow(frame: &[Vec2], keyframe: &[Vec2], kf_from_frame: &Quat) -> Option<f64> {
    let mut dx = Vec::with_capacity(frame.len());
    let mut dy = Vec::with_capacity(frame.len());
    for (f, k) in frame.iter().zip(keyframe) {
        let b = kf_from_frame * Vec3::new(f.x, f.y, 1.0);
        if b.z <= f64::EPSILON {
            continue;
        }
        dx.push((b.x / b.z - k.x).abs());
        dy.push((b.y / b.z - k.y).abs());
    }
    Some(median_in_place(&mut dx)? + median_in_place(&mut dy)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ForceKeyframe::*;

    /// Points seen by a camera at the origin and by one at `centre` turned by
    /// `rotation` (`cam_from_world`): (frame, keyframe) normalised points.
    fn pair(rotation: Quat, centre: Vec3) -> (Vec<Vec2>, Vec<Vec2>) {
        let mut frame = Vec::new();
        let mut keyframe = Vec::new();
        for i in 0..50 {
            let p = Vec3::new((i % 7) as f64 - 3.0, (i % 5) as f64 - 2.0, 8.0 + (i % 3) as f64);
            let q = rotation * (p - centre);
            keyframe.push(Vec2::new(p.x / p.z, p.y / p.z));
            frame.push(Vec2::new(q.x / q.z, q.y / q.z));
        }
        (frame, keyframe)
    }

    #[test]
    fn rotation_leaves_no_parallax_translation_does() {
        let turn = Quat::from_euler_angles(0.02, 0.15, 0.01);
        // A pure rotation: large raw displacement, no parallax left.
        let (f, k) = pair(turn, Vec3::zeros());
        let raw: f64 = f.iter().zip(&k).map(|(a, b)| (a - b).norm()).sum::<f64>() / f.len() as f64;
        assert!(raw > 0.1, "{raw}");
        let kf_from_frame = turn.inverse();
        assert!(rotation_compensated_flow(&f, &k, &kf_from_frame).unwrap() < 1e-12);
        // The same turn with a sideways step: the step's parallax remains.
        let (f, k) = pair(turn, Vec3::new(0.5, 0.0, 0.0));
        let parallax = rotation_compensated_flow(&f, &k, &kf_from_frame).unwrap();
        assert!(parallax > 0.03, "{parallax}");
        // Without the compensation the score would be the turn's.
        let uncompensated = rotation_compensated_flow(&f, &k, &Quat::identity()).unwrap();
        assert!(uncompensated > 2.0 * parallax, "{uncompensated} {parallax}");
        assert_eq!(rotation_compensated_flow(&[], &[], &kf_from_frame), None);
    }

    #[test]
    fn decision_table() {
        let o = KeyframeOptions::default(); // min 50 matches, flow > 0.05, force below 150
        let cases = [
            // (matches, flow, candidate, force)
            (500, 0.10, true, No),
            (500, 0.05, false, No), // the flow must exceed the threshold
            (500, 0.01, false, No),
            (150, 0.01, false, No), // exactly the force threshold: safe
            (149, 0.01, false, ThisFrame),
            (149, 0.20, true, ThisFrame),
            (50, 0.20, true, ThisFrame),
            (49, 0.20, false, PreviousFrame),
            (0, 0.0, false, PreviousFrame),
        ];
        for (m, f, candidate, force) in cases {
            assert_eq!(keyframe_decision(m, f, &o), KeyframeDecision { candidate, force }, "{m} matches, flow {f}");
        }
    }

    #[test]
    fn thresholds_come_from_the_options() {
        let o =
            KeyframeOptions { flow_threshold: 0.0, min_matches: 10, force_keyframe_matches: 0, ..Default::default() };
        assert_eq!(keyframe_decision(10, 1e-9, &o), KeyframeDecision { candidate: true, force: No });
        assert_eq!(keyframe_decision(9, 1.0, &o), KeyframeDecision { candidate: false, force: No });
        let o = KeyframeOptions { force_keyframe_matches: 1000, ..Default::default() };
        assert_eq!(keyframe_decision(999, 0.0, &o).force, ThisFrame);
    }
}

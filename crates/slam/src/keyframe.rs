//! The keyframe decision (paper 3.2, 3.4) as a pure function of a frame's
//! matches to the reference keyframe and its flow score, so the table of
//! cases can be tested without a map.

use crate::options::KeyframeOptions;

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

#[cfg(test)]
mod tests {
    use super::*;
    use ForceKeyframe::*;

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

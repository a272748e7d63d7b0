//! Per-stage wall times of a run (the paper's Table 2 breaks time down the
//! same way).

use serde::Serialize;
use std::time::{Duration, Instant};

/// A pipeline stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Decoding frames from the source (measured by the caller).
    Decode,
    /// Feature extraction.
    Features,
    /// Descriptor matching.
    Matching,
    /// Flow score and the keyframe decision (incl. the pure-rotation test).
    KeyframeTest,
    /// Map initialisation (pair search and two-view geometry; its BA and
    /// triangulation count in their own stages).
    Initialization,
    /// Absolute pose and correspondence-graph updates of keyframes.
    Registration,
    /// Triangulation, track merge/complete, filtering.
    Triangulation,
    /// Local bundle adjustment.
    LocalBa,
    /// Global bundle adjustment.
    GlobalBa,
    /// Loop detection (place index, candidates) and correction
    /// (`--loop-closure`; its matching, triangulation and global BA count in
    /// their own stages).
    LoopClosure,
    /// Refinement of the keyframes' observations by patch alignment
    /// (`--refine-observations`; reading the frames again counts here, its
    /// bundle adjustment in [`Stage::GlobalBa`]).
    ObservationRefinement,
    /// Localisation of non-keyframes.
    Localization,
    /// Writing the outputs.
    Output,
}

/// Accumulated wall time per stage, in seconds when serialised.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StageTimings {
    /// [`Stage::Decode`].
    pub decode: f64,
    /// [`Stage::Features`].
    pub features: f64,
    /// [`Stage::Matching`].
    pub matching: f64,
    /// [`Stage::KeyframeTest`].
    pub keyframe_test: f64,
    /// [`Stage::Initialization`].
    pub initialization: f64,
    /// [`Stage::Registration`].
    pub registration: f64,
    /// [`Stage::Triangulation`].
    pub triangulation: f64,
    /// [`Stage::LocalBa`].
    pub local_ba: f64,
    /// [`Stage::GlobalBa`].
    pub global_ba: f64,
    /// [`Stage::LoopClosure`].
    pub loop_closure: f64,
    /// [`Stage::ObservationRefinement`].
    pub observation_refinement: f64,
    /// [`Stage::Localization`].
    pub localization: f64,
    /// [`Stage::Output`].
    pub output: f64,
}

impl StageTimings {
    /// Adds a duration to a stage.
    pub fn add(&mut self, stage: Stage, d: Duration) {
        let s = d.as_secs_f64();
        let slot = match stage {
            Stage::Decode => &mut self.decode,
            Stage::Features => &mut self.features,
            Stage::Matching => &mut self.matching,
            Stage::KeyframeTest => &mut self.keyframe_test,
            Stage::Initialization => &mut self.initialization,
            Stage::Registration => &mut self.registration,
            Stage::Triangulation => &mut self.triangulation,
            Stage::LocalBa => &mut self.local_ba,
            Stage::GlobalBa => &mut self.global_ba,
            Stage::LoopClosure => &mut self.loop_closure,
            Stage::ObservationRefinement => &mut self.observation_refinement,
            Stage::Localization => &mut self.localization,
            Stage::Output => &mut self.output,
        };
        *slot += s;
    }

    /// Runs `f`, adding its wall time to `stage`.
    pub fn time<T>(&mut self, stage: Stage, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.add(stage, t.elapsed());
        out
    }

    /// Sum of all stages.
    pub fn total(&self) -> f64 {
        self.decode
            + self.features
            + self.matching
            + self.keyframe_test
            + self.initialization
            + self.registration
            + self.triangulation
            + self.local_ba
            + self.global_ba
            + self.loop_closure
            + self.observation_refinement
            + self.localization
            + self.output
    }
}

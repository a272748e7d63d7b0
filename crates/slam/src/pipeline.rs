//! The sequential keyframe pipeline (paper figure 1), the controller of the
//! mapper's steps as COLMAP's `IncrementalPipeline` is of its mapper:
//! initialise from the first frames, then for every frame match to the
//! reference keyframe, compute the flow score, decide on a keyframe
//! ([`crate::keyframe`]), register it; at the end refine, merge and localise
//! every map.

use crate::error::SlamError;
use crate::events::{Emitter, EventSink, SlamEvent};
use crate::frame::{FrameData, FrameId, FramePose, FrameRecord};
use crate::frontend::Frontend;
use crate::keyframe::{ForceKeyframe, keyframe_decision, rotation_compensated_flow};
use crate::mapper::init::{PairMatches, two_view};
use crate::mapper::observations::{FrameImages, ObservationRefinement, TrackTemplates};
use crate::mapper::{Mapper, RegisterFailure, Registration};
use crate::options::{GlobalBaTolerance, KEYFRAME_TWO_VIEW_TRIALS};
use crate::options::{KeyframeOptions, SlamOptions};
use crate::records::SpillConfig;
use crate::timing::{Stage, StageTimings};
use colslam_estimators::TwoViewConfig;
use colslam_features::{Match, flow_score};
use colslam_io::Frame;
use colslam_scene::ImageId;
use rayon::prelude::*;
use std::collections::{HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;

/// The geometric verification of a tracked frame against its reference
/// keyframe `kf` (`focal` in pixels): the two-view geometry of their matches (COLMAP's
/// verification of an image pair), computed when the pure-rotation `guard`
/// needs it, when a consumer draws the frame's flow or when the debug log
/// reports it (the same seed, so the guard's answer does not depend on who
/// looks). Returns the geometry and the flow the emitter sends.
fn verify_frame(
    emitter: &Emitter,
    opts: &SlamOptions,
    data: &FrameData,
    kf: &crate::mapper::Keyframe,
    matches: &[Match],
    focal: f64,
    guard: bool,
) -> (Option<colslam_estimators::TwoViewGeometry>, Option<crate::events::FrameFlow>) {
    let debug = tracing::enabled!(tracing::Level::DEBUG);
    if !(guard || debug || emitter.is_active()) {
        return (None, None);
    }
    let geometry = two_view(data, &kf.data, matches, focal, opts.seed, KEYFRAME_TWO_VIEW_TRIALS);
    // A failed estimate verifies nothing; the mask covers every match.
    let inliers = match &geometry {
        Some(g) if g.inlier_mask.len() == matches.len() => g.inlier_mask.clone(),
        _ => vec![false; matches.len()],
    };
    let num_inliers = inliers.iter().filter(|&&i| i).count();
    tracing::debug!(
        "frame {}: {} matches to keyframe {}, {num_inliers} verified (two-view inliers)",
        data.index(),
        matches.len(),
        kf.image_id.0
    );
    (geometry, emitter.flow(data, &kf.data, matches, &inliers))
}

/// True when a keyframe candidate's rotation-compensated flow to its
/// reference `kf` ([`rotation_compensated_flow`] over the two-view inliers)
/// is at most `threshold`. A candidate without a relative rotation (the
/// geometry failed or is uncalibrated) is not refused: the raw flow stands.
fn too_little_parallax(
    data: &FrameData,
    kf: &crate::mapper::Keyframe,
    matches: &[Match],
    geometry: &Option<colslam_estimators::TwoViewGeometry>,
    threshold: f64,
) -> bool {
    let Some(g) = geometry else { return false };
    let Some(kf_from_frame) = g.cam2_from_cam1.as_ref().map(|p| p.rotation) else { return false };
    let inliers = matches.iter().zip(&g.inlier_mask).filter(|(_, i)| **i).map(|(m, _)| m);
    let (mut x_frame, mut x_kf) = (Vec::new(), Vec::new());
    for m in inliers {
        if let (Some(a), Some(b)) = (data.normalized.get(m.query as usize), kf.data.normalized.get(m.train as usize)) {
            x_frame.push(*a);
            x_kf.push(*b);
        }
    }
    rotation_compensated_flow(&x_frame, &x_kf, &kf_from_frame).is_some_and(|p| p <= threshold)
}

/// A frame's search for its reference under map reuse
/// (`--reuse-keyframes N`): the keyframes it is matched to and what their
/// matches say about its view.
struct ReuseSearch<'a> {
    map: &'a Mapper,
    data: &'a FrameData,
    camera: &'a colslam_camera::Camera,
    kopts: &'a KeyframeOptions,
}

/// A keyframe the frame was matched to in a [`ReuseSearch`].
struct ReuseCandidate {
    /// The keyframe's position.
    pos: usize,
    /// The frame's matches to it.
    matches: Vec<Match>,
    /// The frame's flow to it; `None` when the matches are too few to track
    /// it safely ([`ReuseSearch::flow`]).
    flow: Option<f64>,
}

impl ReuseSearch<'_> {
    /// The flow of the frame to the keyframe at position `k` over the
    /// frame's matches `ms` to it; `None` when the matches are too few to
    /// track it safely (under the force-keyframe count).
    fn flow(&self, k: usize, ms: &[Match]) -> Result<Option<f64>, SlamError> {
        if ms.len() < self.kopts.force_keyframe_matches {
            return Ok(None);
        }
        let kps = &self.map.keyframes()[k].data.features.keypoints;
        let (fx, fy) = (self.camera.focal_x(), self.camera.focal_y());
        Ok(Some(flow_score(&self.data.features.keypoints, kps, ms, fx, fy)?.score))
    }

    /// True when a keyframe at this flow covers the view: tracked safely at
    /// a flow at most the keyframe threshold, so the frame is no keyframe
    /// candidate against it.
    fn covers(&self, flow: Option<f64>) -> bool {
        flow.is_some_and(|f| f <= self.kopts.flow_threshold)
    }

    /// Index in `candidates` of the reference: among the keyframes the
    /// frame tracks safely the one with the smallest flow, the nearest
    /// view, so the flow test asks whether any keyframe near the view
    /// exists; when none is safe, the one whose 3D points it matches most.
    /// Ties: the earlier candidate (the current reference first).
    fn choose(&self, candidates: &[ReuseCandidate]) -> usize {
        let mut nearest: Option<(usize, f64)> = None;
        for (i, c) in candidates.iter().enumerate() {
            if let Some(flow) = c.flow
                && nearest.is_none_or(|(_, f)| flow < f)
            {
                nearest = Some((i, flow));
            }
        }
        if let Some((i, _)) = nearest {
            return i;
        }
        let scores: Vec<usize> = candidates.iter().map(|c| map_points_matched(self.map, c.pos, &c.matches)).collect();
        (0..scores.len()).fold(0, |b, i| if scores[i] > scores[b] { i } else { b })
    }

    /// The keyframes a frame that its reference `current` (a candidate
    /// that does not cover the view) no longer covers is matched to: the
    /// reference's `n` most covisible keyframes in batches of
    /// [`REUSE_BATCH`], most covisible first, the newest keyframe with the
    /// first batch, after `current` itself. The search stops at the first
    /// batch holding a keyframe that covers the view, so a wide search (a
    /// revisit through a gap that culling left) costs one batch where the
    /// nearest covisible keyframes already cover the frame. When no batch
    /// covers it, the frame is a keyframe candidate and only the first
    /// batch is returned: keyframes less covisible with the reference are a
    /// reference only when they cover the view (as a registration reference
    /// they made TUM fr1/rpy drift on some seeds, docs/benchmarks.md).
    fn candidates(
        &self,
        frontend: &Frontend,
        current: ReuseCandidate,
        n: usize,
        timings: &mut StageTimings,
    ) -> Result<Vec<ReuseCandidate>, SlamError> {
        let newest = self.map.keyframes().len() - 1;
        let covisible = self.map.covisible_keyframes(current.pos, n);
        let mut batches = covisible.chunks(REUSE_BATCH).map(<[usize]>::to_vec).collect::<Vec<_>>();
        match batches.first_mut() {
            Some(b) => b.push(newest),
            None => batches.push(vec![newest]),
        }
        // Keeps the first of each: the current reference wins ties.
        let mut seen = HashSet::from([current.pos]);
        let mut candidates = vec![current];
        let mut first_batch = None;
        for mut batch in batches {
            batch.retain(|k| seen.insert(*k));
            if first_batch.is_some() {
                // Past the first batch a keyframe matters only if it covers
                // the view: one whose flow, predicted through the map points
                // the frame shares with it, is well above the threshold is
                // not matched.
                let (reference, to_reference) = (&candidates[0].pos, &candidates[0].matches);
                let mut kept = Vec::with_capacity(batch.len());
                for k in batch {
                    if predicted_flow(self.map, self.data, self.camera, *reference, to_reference, k)?
                        <= REUSE_PREDICTED_FLOW_MARGIN * self.kopts.flow_threshold
                    {
                        kept.push(k);
                    }
                }
                batch = kept;
            }
            let matched: Result<Vec<Vec<Match>>, SlamError> = timings.time(Stage::Matching, || {
                batch.par_iter().map(|&k| frontend.match_frames(self.data, &self.map.keyframes()[k].data)).collect()
            });
            for (pos, matches) in batch.into_iter().zip(matched?) {
                let flow = self.flow(pos, &matches)?;
                candidates.push(ReuseCandidate { pos, matches, flow });
            }
            if candidates.iter().any(|c| self.covers(c.flow)) {
                return Ok(candidates);
            }
            first_batch.get_or_insert(candidates.len());
        }
        candidates.truncate(first_batch.unwrap_or(candidates.len()));
        Ok(candidates)
    }
}

/// The flow of `data` to the keyframe of `map` at position `k`, predicted
/// without matching them: the frame's matches `to_ref` to the keyframe at
/// `reference` that reach a 3D point, carried along the point's track to its
/// observation in `k` (infinite when none reaches `k`).
pub(crate) fn predicted_flow(
    map: &Mapper,
    data: &FrameData,
    camera: &colslam_camera::Camera,
    reference: usize,
    to_ref: &[Match],
    k: usize,
) -> Result<f64, SlamError> {
    let rec = map.reconstruction();
    let keyframes = map.keyframes();
    let (Some(ref_img), Some(kf)) = (keyframes.get(reference).and_then(|r| rec.image(r.image_id)), keyframes.get(k))
    else {
        return Ok(f64::INFINITY);
    };
    let through: Vec<Match> = to_ref
        .iter()
        .filter_map(|m| {
            let pid = ref_img.points2d.get(m.train as usize)?.point3d_id?;
            let el = rec.point3d(pid)?.track.iter().find(|e| e.image_id == kf.image_id)?;
            Some(Match { query: m.query, train: el.point2d_idx, distance: 0.0 })
        })
        .collect();
    if through.is_empty() {
        return Ok(f64::INFINITY);
    }
    let (fx, fy) = (camera.focal_x(), camera.focal_y());
    Ok(flow_score(&data.features.keypoints, &kf.data.features.keypoints, &through, fx, fy)?.score)
}

/// Past the first batch of map reuse's search, a keyframe is matched only
/// when the flow predicted through the shared map points
/// ([`predicted_flow`]) is at most this many times the keyframe
/// threshold. On TUM fr1/rpy, KITTI odometry and Strecha herzjesu every
/// keyframe that covered a view was predicted within 1.31x of its measured
/// flow, and 96-99 % of the later batches' keyframes, which covered
/// nothing, were predicted above twice the threshold (docs/benchmarks.md).
const REUSE_PREDICTED_FLOW_MARGIN: f64 = 2.0;

/// Covisible keyframes matched at once by map reuse's search
/// (`--reuse-keyframes`): the search goes on batch by batch until a
/// keyframe covers the view.
const REUSE_BATCH: usize = 8;

/// How many of `matches` (a frame's matches to the keyframe at position
/// `k`) reach a keypoint of the keyframe that observes a 3D point: the map
/// points the frame tracks through that keyframe.
fn map_points_matched(map: &Mapper, k: usize, matches: &[Match]) -> usize {
    map.reconstruction().image(map.keyframes()[k].image_id).map_or(0, |img| {
        matches.iter().filter(|m| img.points2d.get(m.train as usize).is_some_and(|p| p.point3d_id.is_some())).count()
    })
}

/// The records' memory budget in bytes (`--record-memory` MiB).
fn record_budget(opts: &SlamOptions) -> usize {
    opts.refine.record_memory.saturating_mul(1 << 20)
}

/// A keyframe candidate is refused for too little rotation-compensated flow
/// only while it matches at least this many times the force-keyframe count.
const PARALLAX_SAFE_MATCHES: usize = 2;

/// Non-keyframes kept in memory until the next keyframe (they are matched
/// to it as well, then dropped). Bounds memory on long static stretches.
const MAX_PENDING_FRAMES: usize = 60;

/// Frames kept for relocalisation at the end (those no map tracked when they
/// came); bounds memory on long failures (about 0.2 MB per frame).
const MAX_ORPHANS: usize = 500;

/// Recent frames kept for tracking backwards from a new map (about 0.2 MB
/// each): a map initialised late extends itself over the frames before its
/// initial pair.
const MAX_HISTORY: usize = 120;

/// Relative distance between the focal length a map was made with
/// (a guess or an estimate) and the one its global BAs settled at, above
/// which the frames that map covered are mapped again with the settled one
/// once it fails or holds it ([`Slam::remap_camera`]). A map made under a focal length
/// far off carries its error in every pose and point its later BAs start
/// from: castle without calibration (guess 33 % long) broke at frame 10 of
/// 19 with the focal length settled at its true value two keyframes before,
/// and maps all 19 from that value (docs/benchmarks.md).
const REMAP_FOCAL_CHANGE: f64 = 0.1;

/// Growth of a map (registered images now over those then) over
/// which the focal length its global BAs refine must stay within
/// [`REMAP_STABLE_DRIFT`] for the frames so far to be mapped again with it
/// while the map still tracks ([`Slam::remap_camera`]). One BA that barely
/// moves it is too weak a test: KITTI's paused at 784 px for three BAs
/// (16-20 keyframes) on its way from the 1489 px guess to 708 (true ~719),
/// and a remap there went the wrong way on another seed
/// (docs/benchmarks.md).
const REMAP_STABLE_GROWTH: f64 = 1.5;

/// Largest relative change of the focal length over the last
/// [`REMAP_STABLE_GROWTH`] of a map's growth for it to count as
/// stable: KITTI's moved by 2.4 % from 24 to 36 keyframes and by under
/// 1 % after, against 9 % at the pause.
const REMAP_STABLE_DRIFT: f64 = 0.03;

/// Keyframes a map needs before a stable focal length (not a
/// failing map) has it mapped again.
const REMAP_STABLE_MIN_KEYFRAMES: usize = 12;

/// Least [`crate::calibrate::focal_sharpness`] of a map for its
/// stable focal length to count as constrained by its views: KITTI's
/// forward stretch held a wrong 1796 px (guess 1489, true ~719) over 10-14
/// keyframes at a sharpness of 0.010 (0.006 at 22), and the maps whose focal length was
/// right measured 0.066-0.09 (TUM), 0.11 (KITTI after its turn) and over
/// 0.5 (Strecha). Above `MIN_SHARPNESS`, the first frames' search
/// threshold, since a remap drops the map.
pub(crate) const REMAP_MIN_SHARPNESS: f64 = 0.03;

/// Frames the history keeps while the frames so far may still be mapped again
/// with a refined focal length ([`Slam::remap_camera`]; [`MAX_HISTORY`]
/// otherwise): about 80 MB at 0.2 MB each, only for a camera whose
/// intrinsics are refined.
const REMAP_HISTORY: usize = 400;

/// Consecutive frames a map fails to track (too few matches, or a
/// keyframe that does not register) before it counts as failing for
/// [`Slam::remap_camera`]: castle's map made under the guess failed every
/// frame after its tenth, too few for the 16 lost frames that end a map.
const REMAP_LOST_FRAMES: usize = 3;

/// Keyframes a failing map needs before the focal length it settled at is
/// trusted for mapping again: fewer do not constrain it (the two-view BA
/// of an initial pair moves it anywhere under forward motion).
const REMAP_MIN_KEYFRAMES: usize = 5;

/// After a failed initialisation the window is thinned (to span more time)
/// until it spans this many initialisation windows; then it slides.
const MAX_INIT_SPAN_WINDOWS: usize = 4;

/// A map of the finished run.
#[derive(Debug, Clone)]
pub struct MapResult {
    /// The map (reconstruction, graph, keyframes).
    pub map: Mapper,
    /// Poses of keyframes and localised frames, in frame order.
    pub poses: Vec<FramePose>,
    /// The rolling-shutter readout the map was compensated with, seconds
    /// (given or estimated; 0: none).
    pub readout_s: f64,
}

/// Counters and notes of a run.
#[derive(Debug, Clone, Default)]
pub struct RunStats {
    /// Notable events (map resets, failed initialisation, ...).
    pub notes: Vec<String>,
    /// Keyframe candidates rejected as pure rotation.
    pub rejected_rotation: usize,
    /// Keyframes forced to keep tracking.
    pub forced_keyframes: usize,
    /// Keyframes deregistered by the point-count check.
    pub deregistered: usize,
    /// Keyframe candidates refused for too little rotation-compensated flow
    /// (`--parallax-threshold`); tracked as non-keyframes, never counted as lost.
    pub refused_parallax: usize,
    /// Keyframe observations moved by `--refine-observations`, over all maps.
    pub refined_observations: usize,
}

/// Everything a run produced.
#[derive(Debug, Clone)]
pub struct SlamResult {
    /// Maps, largest (most localised frames) first.
    pub maps: Vec<MapResult>,
    /// Every frame the pipeline saw.
    pub frames: Vec<FrameId>,
    /// Frames localised in no map.
    pub not_localized: Vec<FrameId>,
    /// Per-stage wall times.
    pub timings: StageTimings,
    /// Counters and notes.
    pub stats: RunStats,
}

/// The last non-keyframe, its matches to the reference keyframe, its record
/// index and that reference: promoted to keyframe when tracking is about to
/// be lost.
type Previous = (FrameData, Vec<Match>, usize, ImageId);

/// What exists only while a map is tracked.
struct Tracking {
    map: Mapper,
    prev: Option<Previous>,
    /// Non-keyframes since the last keyframe, with their record indices.
    pending: Vec<(FrameData, usize)>,
    /// Consecutive frames that could not be tracked.
    lost: usize,
    /// True while tracking backwards (lost tracking ends the pass instead
    /// of the map).
    backward: bool,
    /// The keyframe frames are tracked against (map reuse,
    /// `--reuse-keyframes`); `None`: the last keyframe.
    reference: Option<ImageId>,
}

impl Tracking {
    fn new(map: Mapper) -> Self {
        Self { map, prev: None, pending: Vec::new(), lost: 0, backward: false, reference: None }
    }

    /// Forgets the frames of the current direction of travel.
    fn restart(&mut self) {
        self.prev = None;
        self.pending.clear();
        self.lost = 0;
        self.reference = None;
    }

    /// Position of the reference keyframe: the chosen one while it is still
    /// a keyframe, else the last.
    fn reference_position(&self) -> Option<usize> {
        let chosen = self.reference.and_then(|id| self.map.keyframe_position(id));
        chosen.or_else(|| self.map.keyframes().len().checked_sub(1))
    }
}

enum State {
    /// Collecting the initialisation window.
    Initializing { window: Vec<FrameData> },
    /// Tracking against the current map.
    Tracking(Box<Tracking>),
}

/// Why a map is checked for the frames so far to be mapped again with its refined
/// focal length ([`Slam::remap_camera`]), at which frame.
#[derive(Debug, Clone, Copy)]
enum Remap {
    /// It fails to track.
    Failing { frame: usize },
    /// A periodic global BA refined its focal length.
    Stable { frame: usize },
}

/// The camera to map the frames so far again with ([`Slam::remap_camera`]).
struct RemapTo {
    /// The settled camera.
    camera: colslam_camera::Camera,
    /// Registered images of the map it settled in.
    support: usize,
    /// The note that says so.
    note: String,
}

/// The pipeline. Feed frames in order with [`Slam::process`] (or
/// [`Slam::process_features`]), then call [`Slam::finish`]; or let
/// the driver (`run.rs`) feed it from a source.
pub struct Slam {
    opts: SlamOptions,
    /// Shared so that features can be extracted on another thread
    /// ([`Slam::frontend`], [`Slam::process_features`]).
    frontend: Arc<Frontend>,
    /// The run's camera (COLMAP convention) as the last finished map left
    /// it: the frontend's at first, refined by a map whose intrinsics were
    /// refined. The tracked map's reconstruction owns the camera while it
    /// lives ([`Slam::camera`]).
    camera: colslam_camera::Camera,
    /// Registered images of the map [`Slam::camera`]'s focal length was
    /// settled in, once the frames were mapped again with it or as a camera
    /// file says (0 for a guess or a calibration): a new map holds its
    /// intrinsics until it has as many ([`Mapper::initialize`]).
    camera_support: usize,
    emitter: Emitter,
    state: State,
    finished: Vec<Mapper>,
    /// Frames no map tracked when they came (relocalised at the end).
    orphans: Vec<FrameData>,
    /// The most recent frames (at most [`MAX_HISTORY`]), for the backward
    /// pass after an initialisation.
    history: VecDeque<FrameData>,
    frames: Vec<FrameId>,
    timings: StageTimings,
    stats: RunStats,
    /// Where the maps' records spill beyond their memory budget
    /// (`--record-memory`; [`crate::records`]).
    spill: SpillConfig,
    /// Set by an interruption (Ctrl-C): [`Slam::finish`] stops between its
    /// stages with [`SlamError::Cancelled`].
    interrupt: Option<Arc<std::sync::atomic::AtomicBool>>,
    /// Reads keyframes again for `--refine-observations` (none: that
    /// refinement is skipped).
    images: Option<Box<dyn FrameImages + Send>>,
    /// The camera to map the first frames again with, set when the first
    /// map broke far from the focal length it was made with
    /// ([`Slam::remap_camera`]); taken by [`Slam::process_features`].
    /// With the note that says so.
    remap_to: Option<RemapTo>,
    /// Set once the first frames were mapped again: at most once a run.
    remapped: bool,
    /// The map (index) and its registered images when [`Slam::remap_camera`] last
    /// measured whether its focal length is constrained: measured again only
    /// once the map grew by [`REMAP_STABLE_GROWTH`] since (three bundle
    /// adjustments each time).
    remap_checked_at: std::cell::Cell<(usize, usize)>,
    /// Frames between those the initialisation window takes: 1, doubled
    /// each time a failed window is thinned, back to 1 once a map starts.
    init_stride: usize,
}

impl std::fmt::Debug for Slam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Slam({:?}, {} frames)", self.frontend, self.frames.len())
    }
}

impl Slam {
    /// A pipeline for a camera calibrated in OpenCV's pixel convention (as
    /// camera files give it), sending events to `events`.
    pub fn new(
        mut opts: SlamOptions,
        camera_opencv: &colslam_camera::Camera,
        events: EventSink,
    ) -> Result<Self, SlamError> {
        opts.validate()?;
        let camera_opencv = &opts.settle_distortion_refinement(camera_opencv);
        let frontend = Arc::new(Frontend::new(&opts.frontend, camera_opencv)?);
        let spill = SpillConfig::temp(record_budget(&opts));
        frontend.keep_matches();
        Ok(Self {
            emitter: Emitter::new(events, opts.mapper.local_ba_images),
            camera: frontend.camera().clone(),
            camera_support: 0,
            opts,
            frontend,
            state: State::Initializing { window: Vec::new() },
            finished: Vec::new(),
            orphans: Vec::new(),
            history: VecDeque::new(),
            frames: Vec::new(),
            timings: StageTimings::default(),
            stats: RunStats::default(),
            spill,
            interrupt: None,
            images: None,
            remap_to: None,
            remapped: false,
            remap_checked_at: std::cell::Cell::new((0, 0)),
            init_stride: 1,
        })
    }

    /// How the frames can be read again after mapping, for the refinements
    /// that look at the pixels (`--refine-observations`); without it they
    /// are skipped.
    pub fn with_frame_images(mut self, images: Box<dyn FrameImages + Send>) -> Self {
        self.images = Some(images);
        self
    }

    /// Maps hold the camera's intrinsics, refined ones included, until they
    /// have `images` registered images: the camera was refined over as many
    /// in an earlier run (a camera file's `refined_over`).
    pub fn with_camera_support(mut self, images: usize) -> Self {
        self.camera_support = images;
        self
    }

    /// Records spill to a file named `prefix` + `PID-N` in `dir` (the
    /// driver: beside the output folder) instead of the system's temporary
    /// folder, once they exceed `--record-memory`.
    pub fn with_spill(mut self, (dir, prefix): (PathBuf, String)) -> Self {
        self.spill = SpillConfig { dir, prefix, budget: record_budget(&self.opts) };
        self
    }

    /// An interruption flag checked between the stages of [`Slam::finish`].
    pub fn set_interrupt(&mut self, flag: Arc<std::sync::atomic::AtomicBool>) {
        self.interrupt = Some(flag);
    }

    /// `Err(Cancelled)` once the interruption flag is set.
    fn check_interrupt(&self) -> Result<(), SlamError> {
        match &self.interrupt {
            Some(f) if f.load(std::sync::atomic::Ordering::SeqCst) => {
                Err(SlamError::Cancelled { frame: self.frames.len() })
            }
            _ => Ok(()),
        }
    }

    /// Sets a ground-truth trajectory for diagnostics: the keyframes' ATE
    /// (Sim(3)-aligned) is then logged at debug level after every keyframe.
    pub fn set_debug_ground_truth(&mut self, gt: colslam_eval::trajectory::Trajectory) {
        self.emitter.set_debug_ground_truth(gt);
    }

    /// Adds time spent outside the pipeline (decoding, features extracted
    /// on another thread) to a stage.
    pub fn add_time(&mut self, stage: Stage, d: std::time::Duration) {
        self.timings.add(stage, d);
    }

    /// The current map, if one is tracked.
    pub fn current_map(&self) -> Option<&Mapper> {
        match &self.state {
            State::Tracking(t) => Some(&t.map),
            State::Initializing { .. } => None,
        }
    }

    /// Registered keyframes in the current map.
    pub fn num_keyframes(&self) -> usize {
        self.current_map().map_or(0, |m| m.reconstruction().num_registered_images())
    }

    /// 3D points in the current map.
    pub fn num_points(&self) -> usize {
        self.current_map().map_or(0, |m| m.reconstruction().num_points3d())
    }

    /// The current map's reconstruction, if one exists.
    pub fn current_reconstruction(&self) -> Option<&colslam_scene::Reconstruction> {
        self.current_map().map(Mapper::reconstruction)
    }

    /// The camera (COLMAP pixel convention) mapping uses now: the tracked
    /// map's, refined there when intrinsics are refined; new frames are
    /// normalised with it.
    pub fn camera(&self) -> &colslam_camera::Camera {
        match &self.state {
            State::Tracking(t) => t.map.camera().unwrap_or(&self.camera),
            State::Initializing { .. } => &self.camera,
        }
    }

    fn tracking(&mut self) -> Option<&mut Tracking> {
        match &mut self.state {
            State::Tracking(t) => Some(t),
            State::Initializing { .. } => None,
        }
    }

    /// Processes the next frame.
    pub fn process(&mut self, frame: &Frame) -> Result<(), SlamError> {
        let data = {
            let frontend = &self.frontend;
            self.timings.time(Stage::Features, || frontend.process(frame))?
        };
        self.process_features(data)
    }

    /// The frontend, for extracting features ([`Frontend::process`]) on
    /// another thread while this one maps: feed the results in frame order
    /// to [`Slam::process_features`] (and their time to [`Slam::add_time`]).
    /// Gives the same result as [`Slam::process`].
    pub fn frontend(&self) -> Arc<Frontend> {
        Arc::clone(&self.frontend)
    }

    /// Processes a frame whose features were extracted with
    /// [`Slam::frontend`]. Frames must come in order.
    pub fn process_features(&mut self, mut data: FrameData) -> Result<(), SlamError> {
        if self.opts.refine.refine_intrinsics {
            // The frontend normalised with the camera it started with.
            data.normalize_with(self.camera());
        }
        self.frames.push(data.id.clone());
        let max_history = if self.may_remap() { REMAP_HISTORY } else { MAX_HISTORY };
        while self.history.len() >= max_history {
            self.history.pop_front();
        }
        self.history.push_back(data.clone());
        let stride = self.init_stride;
        match &mut self.state {
            State::Initializing { window } => {
                if window.last().is_some_and(|last| data.index() < last.index() + stride) {
                    // Between the thinned window's frames: tracked from the
                    // history once a map starts (`start_map`), else
                    // relocalised at the end, like the frames thinning dropped.
                    self.add_orphans(vec![data]);
                } else {
                    window.push(data);
                    if window.len() >= self.opts.init.init_frames {
                        self.try_initialize(false)?;
                    }
                }
            }
            State::Tracking(_) => self.track(data)?,
        }
        if let Some(to) = self.remap_to.take() {
            self.remap(to)?;
        }
        Ok(())
    }

    /// Whether the frames so far may still be mapped again with a refined
    /// focal length ([`Slam::remap_camera`]): intrinsics refined, no remap
    /// yet, and the history holds every frame so far.
    fn may_remap(&self) -> bool {
        self.opts.refine.refine_intrinsics && !self.remapped && self.history_complete()
    }

    /// The camera to map the frames so far again with, and the note that
    /// says so, when `map` was made with a focal length more than
    /// [`REMAP_FOCAL_CHANGE`] away from the plausible one its global BAs
    /// settled at (the last moved it under 1 %), kept that focal length
    /// while it grew by [`REMAP_STABLE_GROWTH`], its views constrain it (a
    /// [`crate::calibrate::focal_sharpness`] of [`REMAP_MIN_SHARPNESS`] or
    /// more, measured once per [`REMAP_STABLE_GROWTH`] of the map), and it
    /// either has [`REMAP_STABLE_MIN_KEYFRAMES`] keyframes (`Remap::Stable`,
    /// after a periodic global BA) or fails to track [`REMAP_LOST_FRAMES`]
    /// frames in a row up to `frame` with [`REMAP_MIN_KEYFRAMES`]
    /// (`Remap::Failing`): a map made under a focal length far off keeps
    /// that error in its poses and points, which its later BAs start from.
    /// A failing map's focal length settled by one BA alone was not enough
    /// either: KITTI's was still on its way (947 px from the 1489 px guess,
    /// true ~719). Only while [`Slam::may_remap`]. COLMAP's incremental
    /// mapper has no such step: its focal prior usually comes from EXIF.
    fn remap_camera(&self, map: &Mapper, why: Remap) -> Option<RemapTo> {
        let min_keyframes = match why {
            Remap::Failing { .. } => REMAP_MIN_KEYFRAMES,
            Remap::Stable { .. } => REMAP_STABLE_MIN_KEYFRAMES,
        };
        if !self.may_remap() || map.keyframes().len() < min_keyframes {
            return None;
        }
        let camera = map.settled_camera()?;
        let (start, settled) = (self.camera.mean_focal(), camera.mean_focal());
        let change = settled / start - 1.0;
        if change.abs() <= REMAP_FOCAL_CHANGE {
            return None;
        }
        let images = map.reconstruction().num_registered_images();
        if map.focal_drift_since(REMAP_STABLE_GROWTH)? >= REMAP_STABLE_DRIFT {
            return None;
        }
        let what = match why {
            Remap::Failing { frame } => format!("fails at frame {frame} with its focal length settled"),
            Remap::Stable { frame } => format!("kept its focal length while it grew up to frame {frame}"),
        };
        // Settled or stable can also mean unconstrained: under forward
        // motion the focal length stays wherever the map started it.
        let checked = match self.remap_checked_at.get() {
            (index, images) if index == map.index() => images,
            _ => 0,
        };
        if (images as f64) < REMAP_STABLE_GROWTH * checked as f64 {
            return None;
        }
        self.remap_checked_at.set((map.index(), images));
        let sharpness = match crate::calibrate::focal_sharpness(map.reconstruction(), settled) {
            Ok(s) => s,
            Err(e) => {
                tracing::debug!("map {}: the focal length's sharpness failed: {e}", map.index());
                return None;
            }
        };
        tracing::debug!(
            "map {}: focal length {settled:.1} px over {images} images, sharpness {sharpness:.4}",
            map.index()
        );
        if sharpness < REMAP_MIN_SHARPNESS {
            return None;
        }
        let note = format!(
            "map {} {what} at {settled:.1} px (sharpness {sharpness:.3}), {:+.1} % from the {start:.1} px it was \
             made with: the frames so far are mapped again with it",
            map.index(),
            100.0 * change
        );
        Some(RemapTo { camera: camera.clone(), support: images, note })
    }

    /// True while the history holds every frame so far.
    fn history_complete(&self) -> bool {
        self.history.front().map(FrameData::index) == self.frames.first().map(|f| f.index)
    }

    /// Maps the frames so far again from the start with `camera`, once
    /// ([`Slam::remap_camera`]): the maps made until now are dropped.
    fn remap(&mut self, RemapTo { camera, support, note }: RemapTo) -> Result<(), SlamError> {
        tracing::warn!("{note}");
        self.remapped = true;
        let frames: Vec<FrameData> = std::mem::take(&mut self.history).into();
        let first = frames.first().map_or(0, FrameData::index);
        self.camera = camera;
        self.camera_support = support;
        self.state = State::Initializing { window: Vec::new() };
        self.init_stride = 1;
        self.finished.clear();
        self.orphans.clear();
        self.frames.clear();
        let mut notes = std::mem::take(&mut self.stats.notes);
        notes.push(note);
        self.stats = RunStats { notes, ..RunStats::default() };
        let reason = "the frames so far mapped again with the settled focal length".to_string();
        self.emitter.send(SlamEvent::MapReset { new_map: 0, frame_index: first, reason });
        for data in frames {
            self.process_features(data)?;
        }
        Ok(())
    }

    /// Exhaustive matching in the window and the initial pair search; on
    /// failure the window is thinned or slides (paper 3.3: "try another
    /// pair"; we also move on rather than fail).
    fn try_initialize(&mut self, at_end: bool) -> Result<(), SlamError> {
        let State::Initializing { window } = &mut self.state else { return Ok(()) };
        let mut window = std::mem::take(window);
        if self.opts.refine.refine_intrinsics {
            // Frames kept from a map that refined the camera since.
            window.iter_mut().for_each(|d| d.normalize_with(&self.camera));
        }
        if window.len() < 2 {
            self.state = State::Initializing { window };
            return Ok(());
        }
        let pair_matches = self.match_window(&window)?;
        let map_index = self.finished.len();
        let started = std::time::Instant::now();
        let camera = self.camera.clone();
        let start = (&camera, self.camera_support);
        let init = Mapper::initialize(map_index, &window, &pair_matches, start, &self.opts, &mut self.timings)?;
        self.timings.add(Stage::Initialization, started.elapsed());
        match init {
            Some((mut map, i, j)) => {
                map.set_record_spill(Some(self.spill.clone()));
                self.start_map(map, window, i, j)
            }
            None => {
                self.initialization_failed(window, at_end);
                Ok(())
            }
        }
    }

    /// Matches every pair of the window.
    fn match_window(&mut self, window: &[FrameData]) -> Result<PairMatches, SlamError> {
        let n = window.len();
        let pairs: Vec<(usize, usize)> = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect();
        let frontend = &self.frontend;
        type Matched = ((usize, usize), Vec<Match>);
        let matched: Result<Vec<Matched>, SlamError> = self.timings.time(Stage::Matching, || {
            pairs
                .par_iter()
                .map(|&(i, j)| Ok(((i, j), frontend.match_frames_both_ways(&window[i], &window[j])?)))
                .collect()
        });
        Ok(matched?.into_iter().collect())
    }

    /// Too little motion in the window (a slow camera): thin it to every
    /// other frame and take only every other new frame from then on
    /// ([`Slam::init_stride`]), so the next attempt spans twice the time
    /// with the same number of frames. Thinning the window alone while new
    /// frames came in at the full rate kept its span under 45 frames, so a
    /// slow camera never initialised (`colslam demo --frames 1000`). Once it
    /// spans [`MAX_INIT_SPAN_WINDOWS`] windows, the frames are the problem
    /// (blur, a cut, no texture): keep the newest half and move on, at the
    /// same stride.
    fn initialization_failed(&mut self, window: Vec<FrameData>, at_end: bool) {
        let n = window.len();
        let (first, last) = (window[0].index(), window[n - 1].index());
        let how = if at_end { " (end of input)" } else { "; widening or sliding the window" };
        let note = format!("initialisation failed on frames {first}..={last}{how}");
        tracing::warn!("{note}");
        self.stats.notes.push(note);
        let (rest, dropped): (Vec<FrameData>, Vec<FrameData>) =
            if last.saturating_sub(first) < MAX_INIT_SPAN_WINDOWS * self.opts.init.init_frames {
                self.init_stride *= 2;
                let (odd, even): (Vec<_>, Vec<_>) = window.into_iter().enumerate().partition(|(k, _)| k % 2 == 1);
                (odd.into_iter().map(|(_, d)| d).collect(), even.into_iter().map(|(_, d)| d).collect())
            } else {
                let mut window = window;
                let rest = window.split_off(n - n / 2);
                (rest, window)
            };
        self.add_orphans(dropped);
        self.state = State::Initializing { window: rest };
    }

    /// Starts tracking a new map whose initial pair is `window[i]`,
    /// `window[j]`. Frames of the window before the second image (between
    /// the pair, then before it) are tracked backwards from it, with the
    /// earlier frames of the history; later ones go through tracking as
    /// usual.
    fn start_map(&mut self, map: Mapper, window: Vec<FrameData>, i: usize, j: usize) -> Result<(), SlamError> {
        let ids = [map.keyframes()[0].image_id, map.keyframes()[1].image_id];
        let (first_index, second_index) = (window[i].index(), window[j].index());
        let (mut before, mut later) = (Vec::new(), Vec::new());
        for (k, data) in window.into_iter().enumerate() {
            if k > j {
                later.push(data);
            } else if k != i && k != j {
                before.push(data);
            }
        }
        // The history's frames go with the window's: those before the pair
        // and, between and after its images, the frames a thinned window
        // skipped (`init_stride`), which then leave the frames to relocalise
        // at the end. `track_backward` drops the frames both lists hold.
        let pair = |d: &&FrameData| d.index() == first_index || d.index() == second_index;
        before.extend(self.history.iter().filter(|d| d.index() < second_index && !pair(d)).cloned());
        later.extend(self.history.iter().filter(|d| d.index() > second_index).cloned());
        later.sort_by_key(FrameData::index);
        later.dedup_by_key(|d| d.index());
        let tracked: std::collections::HashSet<usize> =
            before.iter().chain(&later).map(FrameData::index).filter(|&k| k > first_index).collect();
        self.orphans.retain(|o| !tracked.contains(&o.index()));
        self.emitter.new_map();
        self.init_stride = 1;
        self.state = State::Tracking(Box::new(Tracking::new(map)));
        if let State::Tracking(t) = &self.state {
            for id in ids {
                self.emitter.keyframe(&t.map, id);
            }
            self.emitter.map(&t.map, true);
        }
        self.track_backward(before)?;
        for data in later {
            self.track(data)?;
        }
        Ok(())
    }

    /// Tracks the frames before a new map's second initial image in reverse
    /// order, as the forward pass does after it (offline input allows it;
    /// COLMAP's incremental mapper has no direction at all). The reference
    /// is always the keyframe nearest in time
    /// ([`Mapper::order_keyframes_by_distance_to`]), and keyframes found on
    /// the way are added; the pass ends at the first frame or when tracking
    /// is lost, and the frames not reached are kept for relocalisation at
    /// the end.
    fn track_backward(&mut self, mut frames: Vec<FrameData>) -> Result<(), SlamError> {
        frames.sort_by_key(|d| std::cmp::Reverse(d.index()));
        frames.dedup_by_key(|d| d.index());
        let max_lost = self.opts.keyframes.max_lost_frames;
        let Some(t) = self.tracking().filter(|_| !frames.is_empty()) else { return Ok(()) };
        t.backward = true;
        t.restart();
        let mut rest = frames.into_iter();
        let mut result = Ok(());
        for data in rest.by_ref() {
            if let Some(t) = self.tracking() {
                t.map.order_keyframes_by_distance_to(data.index());
            }
            result = self.track(data);
            if result.is_err() || self.tracking().is_none_or(|t| t.lost > max_lost) {
                break;
            }
        }
        let unreached: Vec<FrameData> = rest.collect();
        if !unreached.is_empty() {
            tracing::debug!("backward tracking stopped with {} frames left", unreached.len());
        }
        self.add_orphans(unreached);
        if let Some(t) = self.tracking() {
            t.backward = false;
            t.restart();
            t.map.order_keyframes_by_time();
        }
        result
    }

    /// Tracks one frame against the reference keyframe and applies the
    /// keyframe decision.
    fn track(&mut self, data: FrameData) -> Result<(), SlamError> {
        if !matches!(self.state, State::Tracking(_)) {
            self.state = State::Initializing { window: vec![data] };
            return Ok(());
        }
        let Some((kf_pos, matches)) = self.reference_matches(&data)? else { return Ok(()) };
        let State::Tracking(t) = &self.state else { return Ok(()) };
        let kf = &t.map.keyframes()[kf_pos];
        let kf_id = kf.image_id;
        let camera = t.map.camera().unwrap_or(&self.camera);
        let (fx, fy) = (camera.focal_x(), camera.focal_y());
        let t0 = std::time::Instant::now();
        let flow = flow_score(&data.features.keypoints, &kf.data.features.keypoints, &matches, fx, fy)?;
        let decision = keyframe_decision(matches.len(), flow.score, &self.opts.keyframes);
        let kopts = &self.opts.keyframes;
        let guard = decision.candidate && (!kopts.allow_pure_rotation || kopts.parallax_threshold > 0.0);
        let (geometry, frame_flow) =
            verify_frame(&self.emitter, &self.opts, &data, kf, &matches, 0.5 * (fx + fy), guard);
        // Refused only while tracking is comfortably safe: a frame matching
        // little more than the force threshold may not register later.
        let refused = decision.candidate
            && kopts.parallax_threshold > 0.0
            && matches.len() >= PARALLAX_SAFE_MATCHES * kopts.force_keyframe_matches
            && too_little_parallax(&data, kf, &matches, &geometry, kopts.parallax_threshold);
        // With a viewer attached this includes every frame's verification.
        self.timings.add(Stage::KeyframeTest, t0.elapsed());
        // `failed`: a keyframe registration failed, the map could not explain
        // this frame (wrong matches, a cut, a collapsed map). A candidate
        // refused by a test is no failure: the frame is tracked.
        let (mut became, mut failed) = (false, false);
        let panoramic =
            !kopts.allow_pure_rotation && geometry.as_ref().is_some_and(|g| g.config == TwoViewConfig::Panoramic);
        if decision.candidate {
            if guard && panoramic {
                self.stats.rejected_rotation += 1;
                tracing::debug!("frame {}: keyframe candidate rejected (pure rotation)", data.index());
            } else if refused {
                self.stats.refused_parallax += 1;
                tracing::debug!("frame {}: keyframe candidate refused (rotation-compensated flow)", data.index());
            } else {
                became = self.try_keyframe(&data, kf_id, &matches)?;
                failed = !became;
            }
        }
        if !became && !failed {
            match decision.force {
                ForceKeyframe::No => {}
                ForceKeyframe::ThisFrame => {
                    became = self.try_keyframe(&data, kf_id, &matches)?;
                    failed = !became;
                    self.stats.forced_keyframes += usize::from(became);
                }
                ForceKeyframe::PreviousFrame => {
                    if self.promote_previous()? {
                        // Track this frame against the new keyframe instead.
                        return self.track(data);
                    }
                }
            }
        }
        self.emitter.frame(&data, frame_flow, flow.score, became);
        if became {
            tracing::debug!(
                "frame {}: keyframe ({}) against keyframe {}: {} matches, {} map points, flow {:.4}",
                data.index(),
                if decision.candidate { "candidate" } else { "forced" },
                kf_id.0,
                matches.len(),
                self.current_map()
                    .map_or(0, |m| m.keyframe_position(kf_id).map_or(0, |k| map_points_matched(m, k, &matches))),
                flow.score
            );
            if let Some(t) = self.tracking() {
                t.lost = 0;
            }
            return Ok(());
        }
        self.record_non_keyframe(data, kf_id, matches, failed)
    }

    /// Matches a frame to its reference keyframe; returns the reference's
    /// position and the matches. With map reuse (`--reuse-keyframes N`, not
    /// while tracking backwards), when the current reference no longer
    /// passes for the frame's view (fewer than the force-keyframe matches, or
    /// flow above the threshold: it would be a candidate), the frame is also
    /// matched to the last keyframe and the reference's N most covisible
    /// keyframes, in batches until one covers the view, and the nearest view
    /// among them becomes the reference ([`ReuseSearch`]; ORB-SLAM's
    /// reference keyframe is the one sharing most map points). Looking
    /// further only then keeps the cost of a frame the keyframe does cover
    /// at one matching.
    fn reference_matches(&mut self, data: &FrameData) -> Result<Option<(usize, Vec<Match>)>, SlamError> {
        let n = self.opts.keyframes.reuse_keyframes;
        let State::Tracking(t) = &mut self.state else { return Ok(None) };
        let Some(current) = t.reference_position() else { return Ok(None) };
        let (map, frontend) = (&t.map, &self.frontend);
        let first =
            self.timings.time(Stage::Matching, || frontend.match_frames(data, &map.keyframes()[current].data))?;
        let reuse = n > 0 && !t.backward;
        let camera = map.camera().unwrap_or(&self.camera);
        let search = ReuseSearch { map, data, camera, kopts: &self.opts.keyframes };
        // The flow is computed only under reuse: without it the frame is
        // matched to its reference and nothing else.
        let flow = if reuse { search.flow(current, &first)? } else { None };
        if !reuse || search.covers(flow) {
            t.reference = reuse.then(|| map.keyframes()[current].image_id);
            return Ok(Some((current, first)));
        }
        let start = ReuseCandidate { pos: current, matches: first, flow };
        let mut candidates = search.candidates(frontend, start, n, &mut self.timings)?;
        let best = search.choose(&candidates);
        let (count, chosen) = (candidates.len(), candidates.swap_remove(best));
        tracing::debug!(
            "frame {}: reference keyframe {} (candidate {best} of {count}, {} matches) instead of {}",
            data.index(),
            map.keyframes()[chosen.pos].image_id.0,
            chosen.matches.len(),
            map.keyframes()[current].image_id.0
        );
        t.reference = Some(map.keyframes()[chosen.pos].image_id);
        Ok(Some((chosen.pos, chosen.matches)))
    }

    /// Makes the previous frame a keyframe (tracking is about to be lost);
    /// true when it was registered.
    fn promote_previous(&mut self) -> Result<bool, SlamError> {
        let Some((prev, prev_matches, rec_idx, reference)) = self.tracking().and_then(|t| t.prev.take()) else {
            return Ok(false);
        };
        if !self.try_keyframe(&prev, reference, &prev_matches)? {
            return Ok(false);
        }
        self.stats.forced_keyframes += 1;
        tracing::debug!("frame {}: keyframe (previous frame forced) against keyframe {}", prev.index(), reference.0);
        if let Some(t) = self.tracking() {
            t.map.promote_record(rec_idx);
        }
        Ok(true)
    }

    /// Records a non-keyframe for localisation, counts lost frames and
    /// starts a new map once tracking is lost for good.
    fn record_non_keyframe(
        &mut self,
        data: FrameData,
        kf_id: colslam_scene::ImageId,
        matches: Vec<Match>,
        failed: bool,
    ) -> Result<(), SlamError> {
        let untracked = matches.len() < self.opts.keyframes.min_matches || failed;
        let max_lost = self.opts.keyframes.max_lost_frames;
        let Some(t) = self.tracking() else { return Ok(()) };
        let mut rec = FrameRecord::new(&data);
        rec.add_matches(&data, kf_id, &matches);
        let rec_idx = t.map.add_record(rec)?;
        t.lost = if untracked { t.lost + 1 } else { 0 };
        if t.pending.len() < MAX_PENDING_FRAMES {
            t.pending.push((data.clone(), rec_idx));
        }
        let orphan = untracked.then(|| data.clone());
        let frame = data.index();
        t.prev = Some((data, matches, rec_idx, kf_id));
        let reset = t.lost > max_lost && !t.backward;
        let failing = (t.lost >= REMAP_LOST_FRAMES && !t.backward).then_some(frame);
        self.add_orphans(orphan.into_iter().collect());
        if let Some(frame) = failing
            && self.remap_to.is_none()
        {
            self.remap_to = self.current_map().and_then(|map| self.remap_camera(map, Remap::Failing { frame }));
        }
        if reset && self.remap_to.is_none() {
            self.reset_map();
        }
        Ok(())
    }

    /// Registers a keyframe candidate; on success, matches the pending
    /// non-keyframes to it, runs a global refinement when the map grew
    /// enough, and emits events.
    fn try_keyframe(&mut self, data: &FrameData, reference: ImageId, matches: &[Match]) -> Result<bool, SlamError> {
        let State::Tracking(t) = &mut self.state else { return Ok(false) };
        let Some(ref_pos) = t.map.keyframe_position(reference) else { return Ok(false) };
        let (frontend, opts) = (&self.frontend, &self.opts);
        let culled_before = t.map.culled_keyframes();
        let image_id = match t.map.register_keyframe_from(data, ref_pos, matches, frontend, opts, &mut self.timings)? {
            Registration::Registered(id) => id,
            Registration::Rejected(failure) => {
                self.stats.deregistered += usize::from(matches!(failure, RegisterFailure::TooFewPoints(_)));
                tracing::debug!("frame {}: keyframe not registered: {failure}", data.index());
                return Ok(false);
            }
        };
        // Pending frames see the new keyframe too.
        let pending = std::mem::take(&mut t.pending);
        let frontend = &self.frontend;
        let extra: Result<Vec<(usize, Vec<Match>)>, SlamError> = self.timings.time(Stage::Matching, || {
            pending.par_iter().map(|(f, idx)| Ok((*idx, frontend.match_frames(f, data)?))).collect()
        });
        for ((f, _), (idx, ms)) in pending.iter().zip(extra?) {
            t.map.add_record_matches(idx, f, image_id, &ms);
        }
        t.prev = None;
        t.reference = None;
        let mut global = None;
        // A closed loop ends with a converged global BA and moves every
        // pose: the consumer gets a full snapshot.
        let looped = self.opts.mapper.loop_closure
            && t.map.close_loop(image_id, &self.frontend, &self.opts, &mut self.timings)?.is_some();
        if !looped && t.map.needs_global_refine(&self.opts) {
            global = Some(t.map.global_refine(GlobalBaTolerance::Periodic, &self.opts, &mut self.timings)?);
        }
        self.emitter.keyframe(&t.map, image_id);
        self.emitter.log_keyframe_ate(&t.map);
        if let Some(r) = &global {
            self.emitter.send(SlamEvent::BundleAdjusted {
                map: t.map.index(),
                global: true,
                final_cost: r.final_cost,
                iterations: r.iterations,
            });
        }
        // A culled keyframe is not in an increment (which only adds and
        // moves): a full snapshot replaces the consumer's copy without it.
        let full = global.is_some() || looped || t.map.culled_keyframes() > culled_before;
        self.emitter.map(&t.map, full);
        if global.is_some() && self.remap_to.is_none() {
            let why = Remap::Stable { frame: data.index() };
            self.remap_to = self.current_map().and_then(|map| self.remap_camera(map, why));
        }
        Ok(true)
    }

    fn add_orphans(&mut self, frames: Vec<FrameData>) {
        for f in frames {
            if self.orphans.len() >= MAX_ORPHANS {
                return;
            }
            if self.orphans.last().is_none_or(|o| o.index() != f.index()) {
                self.orphans.push(f);
            }
        }
    }

    /// Ends the current map (tracking lost) and starts collecting a new
    /// initialisation window with the last frame.
    fn reset_map(&mut self) {
        let state = std::mem::replace(&mut self.state, State::Initializing { window: Vec::new() });
        let State::Tracking(t) = state else {
            self.state = state;
            return;
        };
        let frame = self.frames.last().map_or(0, |f| f.index);
        let reason = format!("tracking lost for {} frames", t.lost);
        let note = format!("map {} ended at frame {frame}: {reason}; starting a new map", t.map.index());
        tracing::warn!("{note}");
        self.stats.notes.push(note);
        let new_map = t.map.index() + 1;
        let Tracking { map, prev, .. } = *t;
        if let Ok(c) = map.camera() {
            self.camera = c.clone();
        }
        // A map that held the camera leaves it as it was; one that grew
        // past the support refined it with more views.
        if self.camera_support > 0 {
            self.camera_support = self.camera_support.max(map.reconstruction().num_registered_images());
        }
        self.finished.push(map);
        self.emitter.send(SlamEvent::MapReset { new_map, frame_index: frame, reason });
        // The last frames start the next initialisation window.
        self.state = State::Initializing { window: prev.map(|(d, ..)| d).into_iter().collect() };
    }

    /// Ends the run: a last initialisation attempt if none succeeded, final
    /// global refinement of every map, merging of overlapping maps,
    /// relocalisation of untracked frames, localisation of every frame.
    pub fn finish(mut self) -> Result<SlamResult, SlamError> {
        if matches!(self.state, State::Initializing { .. }) {
            self.try_initialize(true)?;
        }
        // The first map may break in that last attempt's tracking.
        if let Some(to) = self.remap_to.take() {
            self.remap(to)?;
            if matches!(self.state, State::Initializing { .. }) {
                self.try_initialize(true)?;
            }
        }
        match std::mem::replace(&mut self.state, State::Initializing { window: Vec::new() }) {
            State::Initializing { window } => self.add_orphans(window),
            State::Tracking(t) => self.finished.push(t.map),
        }
        let mut finished = std::mem::take(&mut self.finished);
        if self.opts.refine.refine_observations && !self.opts.refines_observations() {
            let note = "observation refinement skipped: it assumes a global shutter, and a rolling-shutter readout is compensated";
            tracing::warn!("{note}");
            self.stats.notes.push(note.into());
        }
        for map in &mut finished {
            self.check_interrupt()?;
            if self.opts.mapper.cull_keyframes {
                let n = map.cull_all_keyframes()?;
                tracing::debug!("map {}: {n} keyframes culled at the end", map.index());
            }
            if self.opts.refine.match_overlapping > 0 {
                map.match_overlapping_pairs(&self.frontend, &self.opts, &mut self.timings)?;
            }
            map.finalize(&self.opts, &mut self.timings)?;
        }
        let kept = self.merge_maps(finished)?;
        let mut maps = Vec::new();
        for map in kept {
            self.check_interrupt()?;
            let mut done = self.localize_map(map)?;
            // Every frame is localised: the records (and their file) go.
            done.map.release_records();
            maps.push(done);
        }
        // The matches stay kept until here: a photo set's images that are no
        // keyframe are localised against keyframes they were matched with in
        // the first window.
        self.frontend.forget_matches();
        // Largest first; ties by earlier map.
        maps.sort_by(|a, b| b.poses.len().cmp(&a.poses.len()).then(a.map.index().cmp(&b.map.index())));
        let localized: HashSet<usize> = maps.iter().flat_map(|m| m.poses.iter().map(|p| p.frame.index)).collect();
        let not_localized = self.frames.iter().filter(|f| !localized.contains(&f.index)).cloned().collect();
        self.emitter.send(SlamEvent::Finished);
        Ok(SlamResult { maps, frames: self.frames, not_localized, timings: self.timings, stats: self.stats })
    }

    /// Offline recovery: merges maps into the largest where they overlap.
    fn merge_maps(&mut self, mut finished: Vec<Mapper>) -> Result<Vec<Mapper>, SlamError> {
        finished.sort_by(|a, b| {
            let (na, nb) = (a.reconstruction().num_registered_images(), b.reconstruction().num_registered_images());
            nb.cmp(&na).then(a.index().cmp(&b.index()))
        });
        let mut kept: Vec<Mapper> = Vec::new();
        for map in finished {
            let mut merged = false;
            if let Some(base) = kept.first_mut() {
                merged = base.merge(&map, &self.frontend, &self.opts, &mut self.timings)?.is_some();
                if merged {
                    self.stats.notes.push(format!("map {} merged into map {}", map.index(), base.index()));
                }
            }
            if !merged {
                kept.push(map);
            }
        }
        Ok(kept)
    }

    /// Refines the keyframes' observations of `map` when asked
    /// ([`SlamOptions::refines_observations`]); the tracks' templates for
    /// the non-keyframes.
    fn refine_observations(&mut self, map: &mut Mapper) -> Result<Option<TrackTemplates>, SlamError> {
        if !self.opts.refines_observations() {
            return Ok(None);
        }
        self.check_interrupt()?;
        let Some(images) = self.images.as_deref_mut() else { return Ok(None) };
        let (r, tracks) = map.refine_observations(images, &self.opts, &mut self.timings)?;
        self.stats.refined_observations += r.moved;
        self.note_unread(map, "keyframes", &r);
        Ok(Some(tracks))
    }

    /// The report's note on frames a refinement could not read again.
    fn note_unread(&mut self, map: &Mapper, what: &str, r: &ObservationRefinement) {
        if let Some(first) = &r.first_unread {
            self.stats.notes.push(format!(
                "map {}: {} {what} could not be read again for the observation refinement and kept their keypoints (first: {first})",
                map.index(),
                r.unread
            ));
        }
    }

    /// Relocalises the untracked frames in `map`, localises every frame,
    /// compensates rolling shutter and refines with all frames when asked,
    /// and colours the points.
    fn localize_map(&mut self, mut map: Mapper) -> Result<MapResult, SlamError> {
        let renormalized: Vec<FrameData>;
        let orphans: &[FrameData] = if self.opts.refine.refine_intrinsics {
            let camera = map.camera()?.clone();
            renormalized = self
                .orphans
                .iter()
                .cloned()
                .map(|mut d| {
                    d.normalize_with(&camera);
                    d
                })
                .collect();
            &renormalized
        } else {
            &self.orphans
        };
        let extra = map.relocalization_records(orphans, &self.frontend, &mut self.timings)?;
        map.add_records(extra)?;
        let tracks = self.refine_observations(&mut map)?;
        // Every normalised coordinate from the map's final camera.
        map.refresh_all()?;
        let mut loc = map.localize_all(&self.opts, &mut self.timings)?;
        // The templates go once the non-keyframes are aligned.
        if let Some(tracks) = tracks {
            self.check_interrupt()?;
            if let Some(images) = self.images.as_deref_mut() {
                let r = map.refine_frame_observations(&mut loc, &tracks, images, &self.opts, &mut self.timings)?;
                self.stats.refined_observations += r.moved;
                self.note_unread(&map, "non-keyframes", &r);
            }
        }
        let (mut loc, readout) = map.rolling_shutter(loc, &self.opts, &mut self.timings)?;
        if self.opts.refine.refine_all_frames {
            map.refine_with_all_frames(&mut loc.poses, &loc.inliers, &self.opts, &mut self.timings)?;
        }
        map.refresh_keyframes(0..map.keyframes().len())?;
        map.color_points();
        Ok(MapResult { map, poses: loc.poses, readout_s: readout })
    }
}

//! The sequential keyframe pipeline (paper figure 1): initialise from the
//! first frames, then for every frame match to the last keyframe, compute
//! the flow score, decide on a keyframe, register and triangulate it, bundle
//! adjust; localise every other frame against the map at the end.

use crate::events::{EventPoint, EventSink, SlamEvent};
use crate::frontend::{FrameData, Frontend};
use crate::map::{FramePose, FrameRecord, MapState, RegisterFailure, two_view};
use crate::timing::{Stage, StageTimings};
use crate::{SlamError, SlamOptions};
use colslam_estimators::TwoViewConfig;
use colslam_features::{Match, flow_score};
use colslam_io::Frame;
use rayon::prelude::*;
use std::collections::HashMap;

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

/// After a failed initialisation the window is thinned (to span more time)
/// until it spans this many initialisation windows; then it slides.
const MAX_INIT_SPAN_WINDOWS: usize = 4;

/// Flow lines sent per frame event (a subsample of the matches).
const MAX_FLOW_LINES: usize = 300;

/// A frame seen by the pipeline.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameInfo {
    /// Frame index (after skip).
    pub index: usize,
    /// Timestamp, seconds.
    pub timestamp: f64,
    /// Name.
    pub name: String,
}

/// A map of the finished run.
#[derive(Debug, Clone)]
pub struct MapResult {
    /// The map (reconstruction, graph, keyframes).
    pub map: MapState,
    /// Poses of keyframes and localised frames, in frame order.
    pub poses: Vec<FramePose>,
}

/// Everything a run produced.
#[derive(Debug, Clone)]
pub struct SlamResult {
    /// Maps, largest (most localised frames) first.
    pub maps: Vec<MapResult>,
    /// Every frame the pipeline saw.
    pub frames: Vec<FrameInfo>,
    /// Frames localised in no map.
    pub not_localized: Vec<FrameInfo>,
    /// Per-stage wall times.
    pub timings: StageTimings,
    /// Notable events (map resets, failed initialisation, ...).
    pub notes: Vec<String>,
    /// Keyframe candidates rejected as pure rotation.
    pub rejected_rotation: usize,
    /// Keyframes forced to keep tracking.
    pub forced_keyframes: usize,
    /// Keyframes deregistered by the point-count check.
    pub deregistered: usize,
}

enum State {
    /// Collecting the initialisation window.
    Initializing { window: Vec<FrameData> },
    /// Tracking against the current map.
    Tracking,
}

/// The pipeline. Feed frames in order with [`Slam::process`], then call
/// [`Slam::finish`].
pub struct Slam {
    opts: SlamOptions,
    /// Shared so that a caller can extract features on another thread
    /// ([`Slam::frontend`], [`Slam::process_features`]).
    frontend: std::sync::Arc<Frontend>,
    events: EventSink,
    state: State,
    map: Option<MapState>,
    finished: Vec<MapState>,
    /// The last non-keyframe, its matches to the last keyframe and its record
    /// index: promoted to keyframe when tracking is about to be lost.
    prev: Option<(FrameData, Vec<Match>, usize)>,
    /// Non-keyframes since the last keyframe, with their record indices.
    pending: Vec<(FrameData, usize)>,
    /// Frames no map tracked when they came (relocalised at the end).
    orphans: Vec<FrameData>,
    /// The most recent frames (at most [`MAX_HISTORY`]), for the backward
    /// pass after an initialisation.
    history: std::collections::VecDeque<FrameData>,
    /// True while tracking backwards (lost tracking ends the pass instead
    /// of the map).
    backward: bool,
    lost: usize,
    frames: Vec<FrameInfo>,
    timings: StageTimings,
    notes: Vec<String>,
    rejected_rotation: usize,
    forced_keyframes: usize,
    deregistered: usize,
    /// Ground truth for diagnostics: when set, the keyframes' ATE is logged
    /// (debug level) after every keyframe.
    debug_gt: Option<colslam_eval::trajectory::Trajectory>,
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
        opts: SlamOptions,
        camera_opencv: &colslam_camera::Camera,
        events: EventSink,
    ) -> Result<Self, SlamError> {
        opts.validate()?;
        let frontend = std::sync::Arc::new(Frontend::new(&opts, camera_opencv)?);
        Ok(Self {
            opts,
            frontend,
            events,
            state: State::Initializing { window: Vec::new() },
            map: None,
            finished: Vec::new(),
            prev: None,
            pending: Vec::new(),
            orphans: Vec::new(),
            history: std::collections::VecDeque::new(),
            backward: false,
            lost: 0,
            frames: Vec::new(),
            timings: StageTimings::default(),
            notes: Vec::new(),
            rejected_rotation: 0,
            forced_keyframes: 0,
            deregistered: 0,
            debug_gt: None,
        })
    }

    /// Sets a ground-truth trajectory for diagnostics: the keyframes' ATE
    /// (Sim(3)-aligned) is then logged at debug level after every keyframe.
    pub fn set_debug_ground_truth(&mut self, gt: colslam_eval::trajectory::Trajectory) {
        self.debug_gt = Some(gt);
    }

    fn log_keyframe_ate(&self) {
        let (Some(gt), Some(map)) = (&self.debug_gt, &self.map) else { return };
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let mut kfs: Vec<(f64, colslam_geometry::Rigid3)> = map
            .keyframes
            .iter()
            .filter_map(|k| {
                map.rec.image(k.image_id).filter(|i| i.registered).map(|i| (k.data.timestamp, i.cam_from_world))
            })
            .collect();
        kfs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let est = colslam_eval::trajectory::Trajectory::from_cam_from_world(
            kfs.iter().map(|k| k.0).collect(),
            &kfs.iter().map(|k| k.1).collect::<Vec<_>>(),
        );
        match colslam_eval::evaluate(gt, &est, &colslam_eval::EvalOptions::default()) {
            Ok(r) => tracing::debug!(
                "map {}: {} keyframes, ATE {:.4} m (max {:.4} m), scale {:.4}",
                map.index,
                r.matched,
                r.ate_rmse,
                r.ate_max,
                r.scale
            ),
            Err(e) => tracing::debug!("map {}: keyframe ATE not available: {e}", map.index),
        }
    }

    /// Time spent so far per stage (the caller may add decoding time).
    pub fn timings_mut(&mut self) -> &mut StageTimings {
        &mut self.timings
    }

    /// Registered keyframes in the current map.
    pub fn num_keyframes(&self) -> usize {
        self.map.as_ref().map_or(0, |m| m.rec.num_registered_images())
    }

    /// 3D points in the current map.
    pub fn num_points(&self) -> usize {
        self.map.as_ref().map_or(0, |m| m.rec.num_points3d())
    }

    /// The current map's reconstruction, if one exists.
    pub fn current_reconstruction(&self) -> Option<&colslam_scene::Reconstruction> {
        self.map.as_ref().map(|m| &m.rec)
    }

    fn focal(&self) -> f64 {
        let c = self.frontend.camera();
        0.5 * (c.focal_x() + c.focal_y())
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
    /// to [`Slam::process_features`] (and their time to
    /// [`Slam::timings_mut`]). Gives the same result as [`Slam::process`].
    pub fn frontend(&self) -> std::sync::Arc<Frontend> {
        std::sync::Arc::clone(&self.frontend)
    }

    /// Processes a frame whose features were extracted with
    /// [`Slam::frontend`]. Frames must come in order.
    pub fn process_features(&mut self, data: FrameData) -> Result<(), SlamError> {
        self.frames.push(FrameInfo { index: data.index, timestamp: data.timestamp, name: data.name.clone() });
        if self.history.len() >= MAX_HISTORY {
            self.history.pop_front();
        }
        self.history.push_back(data.clone());
        self.step(data)
    }

    fn step(&mut self, data: FrameData) -> Result<(), SlamError> {
        match &mut self.state {
            State::Initializing { window } => {
                window.push(data);
                if window.len() >= self.opts.init_frames {
                    self.try_initialize(false)?;
                }
                Ok(())
            }
            State::Tracking => self.track(data),
        }
    }

    /// Exhaustive matching in the window and the initial pair search; on
    /// failure the window slides forward by half (paper 3.3: "try another
    /// pair"; we also move on rather than fail).
    fn try_initialize(&mut self, at_end: bool) -> Result<(), SlamError> {
        let State::Initializing { window } = &mut self.state else { return Ok(()) };
        let window = std::mem::take(window);
        if window.len() < 2 {
            self.state = State::Initializing { window };
            return Ok(());
        }
        let n = window.len();
        let pairs: Vec<(usize, usize)> = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect();
        let frontend = &self.frontend;
        type PairMatches = ((usize, usize), Vec<Match>);
        let matched: Result<Vec<PairMatches>, SlamError> = self.timings.time(Stage::Matching, || {
            pairs.par_iter().map(|&(i, j)| Ok(((i, j), frontend.match_frames(&window[i], &window[j])?))).collect()
        });
        let pair_matches: HashMap<(usize, usize), Vec<Match>> = matched?.into_iter().collect();
        let map_index = self.finished.len() + usize::from(self.map.is_some());
        let started = std::time::Instant::now();
        let camera = self.frontend.camera().clone();
        let init = MapState::initialize(map_index, &window, &pair_matches, &camera, &self.opts, &mut self.timings)?;
        self.timings.add(Stage::Initialization, started.elapsed());
        let Some((map, i, j)) = init else {
            let note = format!(
                "initialisation failed on frames {}..={}{}",
                window[0].index,
                window[n - 1].index,
                if at_end { " (end of input)" } else { "; widening or sliding the window" }
            );
            tracing::warn!("{note}");
            self.notes.push(note);
            // Too little motion in the window (a slow camera): thin it to
            // every other frame, so the next attempt spans twice the time
            // with the same number of frames. Once it spans
            // MAX_INIT_SPAN_WINDOWS windows, the frames are the problem
            // (blur, a cut, no texture): keep the newest half and move on.
            let span = window[n - 1].index.saturating_sub(window[0].index);
            let (rest, dropped): (Vec<FrameData>, Vec<FrameData>) =
                if span < MAX_INIT_SPAN_WINDOWS * self.opts.init_frames {
                    let (odd, even): (Vec<_>, Vec<_>) = window.into_iter().enumerate().partition(|(k, _)| k % 2 == 1);
                    (odd.into_iter().map(|(_, d)| d).collect(), even.into_iter().map(|(_, d)| d).collect())
                } else {
                    let mut window = window;
                    let rest = window.split_off(n - n / 2);
                    (rest, window)
                };
            self.add_orphans(dropped);
            self.state = State::Initializing { window: rest };
            return Ok(());
        };
        // Frames of the window other than the pair: those before the second
        // image (between the pair, then before it) are tracked backwards
        // from it, with the earlier frames of the history; later ones go
        // through tracking as usual.
        let (ida, idb) = (map.keyframes[0].image_id, map.keyframes[1].image_id);
        let first_index = window[i].index;
        let mut later = Vec::new();
        let mut before = Vec::new();
        for (k, data) in window.into_iter().enumerate() {
            if k == i || k == j {
                continue;
            }
            if k > j {
                later.push(data);
            } else {
                before.push(data);
            }
        }
        if let Some(old) = self.map.take() {
            self.finished.push(old);
        }
        self.map = Some(map);
        self.state = State::Tracking;
        self.prev = None;
        self.pending.clear();
        self.lost = 0;
        for id in [ida, idb] {
            self.emit_keyframe(id);
        }
        self.emit_map(true);
        // `track_backward` drops the frames both lists hold.
        before.extend(self.history.iter().filter(|d| d.index < first_index).cloned());
        self.track_backward(before)?;
        for data in later {
            self.track(data)?;
        }
        Ok(())
    }

    /// Tracks the frames before a new map's second initial image in reverse
    /// order, as the forward pass does after it (offline input allows it;
    /// COLMAP's incremental mapper has no direction at all). The reference
    /// is always the keyframe nearest in time (keyframes are ordered by
    /// distance in time during the pass, nearest last), and keyframes found
    /// on the way are added; the pass ends at the first frame or when
    /// tracking is lost, and the frames not reached are kept for
    /// relocalisation at the end.
    fn track_backward(&mut self, mut frames: Vec<FrameData>) -> Result<(), SlamError> {
        frames.sort_by_key(|d| std::cmp::Reverse(d.index));
        frames.dedup_by_key(|d| d.index);
        if frames.is_empty() || self.map.is_none() {
            return Ok(());
        }
        self.backward = true;
        self.prev = None;
        self.pending.clear();
        self.lost = 0;
        let mut rest = frames.into_iter();
        let mut result = Ok(());
        for data in rest.by_ref() {
            // Nearest in time last: it is the reference, and the most
            // recent ones are those registration matches against.
            if let Some(map) = self.map.as_mut() {
                let at = data.index;
                map.keyframes.sort_by(|a, b| {
                    b.data.index.abs_diff(at).cmp(&a.data.index.abs_diff(at)).then(a.data.index.cmp(&b.data.index))
                });
            }
            result = self.track(data);
            if result.is_err() || self.lost > self.opts.max_lost_frames {
                break;
            }
        }
        let unreached: Vec<FrameData> = rest.collect();
        if !unreached.is_empty() {
            tracing::debug!("backward tracking stopped with {} frames left", unreached.len());
        }
        self.add_orphans(unreached);
        self.backward = false;
        self.prev = None;
        self.pending.clear();
        self.lost = 0;
        if let Some(map) = self.map.as_mut() {
            map.keyframes.sort_by_key(|k| k.data.index);
        }
        result
    }

    fn track(&mut self, data: FrameData) -> Result<(), SlamError> {
        let Some(map) = self.map.as_ref() else {
            self.state = State::Initializing { window: vec![data] };
            return Ok(());
        };
        let Some(kf) = map.last_keyframe() else { return Ok(()) };
        let kf_id = kf.image_id;
        let matches = {
            let frontend = &self.frontend;
            self.timings.time(Stage::Matching, || frontend.match_frames(&data, &kf.data))?
        };
        let (fx, fy) = (self.frontend.camera().focal_x(), self.frontend.camera().focal_y());
        let t0 = std::time::Instant::now();
        let flow = flow_score(&data.features.keypoints, &kf.data.features.keypoints, &matches, fx, fy)?;
        let n = matches.len();
        let mut became = false;
        // A keyframe registration that failed: the map could not explain
        // this frame (wrong matches, a cut, a collapsed map).
        let mut failed_attempt = false;
        if n >= self.opts.min_matches && flow.score > self.opts.flow_threshold {
            let rotation = self.opts.reject_pure_rotation
                && two_view(
                    &data,
                    &kf.data,
                    &matches,
                    0.5 * (fx + fy),
                    self.opts.seed,
                    crate::map::KEYFRAME_TWO_VIEW_TRIALS,
                )
                .is_some_and(|g| g.config == TwoViewConfig::Panoramic);
            self.timings.add(Stage::KeyframeTest, t0.elapsed());
            if rotation {
                self.rejected_rotation += 1;
                tracing::debug!("frame {}: keyframe candidate rejected (pure rotation)", data.index);
            } else {
                became = self.try_keyframe(&data, &matches)?;
                failed_attempt = !became;
            }
        } else {
            self.timings.add(Stage::KeyframeTest, t0.elapsed());
        }
        if !became && !failed_attempt && n < self.opts.force_keyframe_matches {
            // Tracking is about to be lost: force a keyframe, this frame if
            // it still matches well enough, else the previous frame.
            if n >= self.opts.min_matches {
                became = self.try_keyframe(&data, &matches)?;
                failed_attempt = !became;
                if became {
                    self.forced_keyframes += 1;
                }
            } else if let Some((prev, prev_matches, rec_idx)) = self.prev.take()
                && self.try_keyframe(&prev, &prev_matches)?
            {
                self.forced_keyframes += 1;
                if let Some(r) = self.map.as_mut().and_then(|m| m.records.get_mut(rec_idx)) {
                    r.promoted = true;
                }
                // Track this frame against the new keyframe instead.
                return self.track(data);
            }
        }
        self.send_frame_event(&data, &matches, flow.score, became);
        if became {
            self.lost = 0;
            return Ok(());
        }
        // A non-keyframe: record it for localisation.
        let Some(map) = self.map.as_mut() else { return Ok(()) };
        let mut rec = FrameRecord::new(&data);
        rec.add_matches(&data, kf_id, &matches);
        map.records.push(rec);
        let rec_idx = map.records.len() - 1;
        if n < self.opts.min_matches || failed_attempt {
            self.lost += 1;
            self.add_orphans(vec![data.clone()]);
        } else {
            self.lost = 0;
        }
        if self.pending.len() < MAX_PENDING_FRAMES {
            self.pending.push((data.clone(), rec_idx));
        }
        self.prev = Some((data, matches, rec_idx));
        if self.lost > self.opts.max_lost_frames && !self.backward {
            self.reset_map()?;
        }
        Ok(())
    }

    /// Registers a keyframe candidate; on success, matches the pending
    /// non-keyframes to it and emits events.
    fn try_keyframe(&mut self, data: &FrameData, matches: &[Match]) -> Result<bool, SlamError> {
        let Some(map) = self.map.as_mut() else { return Ok(false) };
        let result = map.register_keyframe(data, matches, &self.frontend, &self.opts, &mut self.timings)?;
        let image_id = match result {
            Ok(id) => id,
            Err(failure) => {
                if matches!(failure, RegisterFailure::TooFewPoints(_)) {
                    self.deregistered += 1;
                }
                tracing::debug!("frame {}: keyframe not registered: {failure}", data.index);
                return Ok(false);
            }
        };
        // Pending frames see the new keyframe too.
        let pending = std::mem::take(&mut self.pending);
        let frontend = &self.frontend;
        let extra: Result<Vec<(usize, Vec<Match>)>, SlamError> = self.timings.time(Stage::Matching, || {
            pending.par_iter().map(|(f, idx)| Ok((*idx, frontend.match_frames(f, data)?))).collect()
        });
        for ((f, _), (idx, ms)) in pending.iter().zip(extra?) {
            if let Some(r) = map.records.get_mut(idx) {
                r.add_matches(f, image_id, &ms);
            }
        }
        self.prev = None;
        let mut global = None;
        if map.needs_global_ba(&self.opts) {
            global = Some(map.periodic_global_ba(&self.opts, &mut self.timings)?);
        }
        self.emit_keyframe(image_id);
        self.log_keyframe_ate();
        if let Some(r) = &global {
            let m = self.map.as_ref().map_or(0, |m| m.index);
            self.events.send(SlamEvent::BundleAdjusted {
                map: m,
                global: true,
                final_cost: r.final_cost,
                iterations: r.iterations,
            });
        }
        self.emit_map(global.is_some());
        Ok(true)
    }

    /// Rolling-shutter compensation of a finished map
    /// ([`MapState::compensate_rolling_shutter`]) with the angular velocities
    /// of its first localisation, then a global BA at
    /// [`crate::map::ROLLING_SHUTTER_FINAL_TOLERANCE`] and the final
    /// localisation. One round: re-estimating the velocities from the
    /// compensated poses and repeating gave no better trajectory (TUM
    /// fr1/rpy at 1/30 s, ATE in cm for seeds 0 / 1 / 2: one round 1.07 /
    /// 1.22 / 0.94, two 1.08 / 1.09, three 1.11 / 1.02), at a global BA each.
    fn compensate_rolling_shutter(
        &mut self,
        map: &mut MapState,
        poses: Vec<FramePose>,
        inliers: HashMap<usize, crate::map::FrameInliers>,
    ) -> Result<(Vec<FramePose>, HashMap<usize, crate::map::FrameInliers>), SlamError> {
        let w = crate::rolling_shutter::angular_velocities(&poses, crate::map::ROLLING_SHUTTER_MAX_GAP_S);
        if map.compensate_rolling_shutter(&w, &self.opts, &mut self.timings)? == 0 {
            return Ok((poses, inliers));
        }
        // The compensation's BA stops at the periodic tolerance; a last
        // global BA settles the map on the compensated observations.
        map.global_ba_with_tolerance(&self.opts, &mut self.timings, crate::map::ROLLING_SHUTTER_FINAL_TOLERANCE)?;
        map.rec.update_point_errors()?;
        let (poses, _, inliers) = map.localize_all(self.focal(), &self.opts, &mut self.timings);
        Ok((poses, inliers))
    }

    fn add_orphans(&mut self, frames: Vec<FrameData>) {
        for f in frames {
            if self.orphans.len() >= MAX_ORPHANS {
                return;
            }
            if self.orphans.last().is_none_or(|o| o.index != f.index) {
                self.orphans.push(f);
            }
        }
    }

    fn reset_map(&mut self) -> Result<(), SlamError> {
        let Some(map) = self.map.take() else { return Ok(()) };
        let frame = self.frames.last().map_or(0, |f| f.index);
        let reason = format!("tracking lost for {} frames", self.lost);
        let note = format!("map {} ended at frame {frame}: {reason}; starting a new map", map.index);
        tracing::warn!("{note}");
        self.notes.push(note);
        let new_map = map.index + 1;
        self.finished.push(map);
        self.events.send(SlamEvent::MapReset { new_map, frame_index: frame, reason });
        // The last frames start the next initialisation window.
        let window: Vec<FrameData> = self.prev.take().map(|(d, _, _)| d).into_iter().collect();
        self.pending.clear();
        self.lost = 0;
        self.state = State::Initializing { window };
        Ok(())
    }

    fn send_frame_event(&mut self, data: &FrameData, matches: &[Match], flow: f64, is_keyframe: bool) {
        if !self.events.is_active() {
            return;
        }
        let kf = self.map.as_ref().and_then(|m| {
            // The keyframe the frame was matched to is the last one, or the
            // one before when this frame itself just became a keyframe.
            let k = m.keyframes.len().checked_sub(if is_keyframe { 2 } else { 1 })?;
            m.keyframes.get(k)
        });
        let step = (matches.len() / MAX_FLOW_LINES).max(1);
        let flow_lines = kf
            .map(|kf| {
                matches
                    .iter()
                    .step_by(step)
                    .filter_map(|m| {
                        let a = data.features.keypoints.get(m.query as usize)?;
                        let b = kf.data.features.keypoints.get(m.train as usize)?;
                        Some([a.x, a.y, b.x, b.y])
                    })
                    .collect()
            })
            .unwrap_or_default();
        self.events.send(SlamEvent::FrameProcessed {
            index: data.index,
            timestamp: data.timestamp,
            flow_score: flow,
            num_matches: matches.len(),
            flow_lines,
            is_keyframe,
        });
    }

    fn emit_keyframe(&mut self, image_id: colslam_scene::ImageId) {
        if !self.events.is_active() {
            return;
        }
        let Some(map) = self.map.as_ref() else { return };
        let Some(img) = map.rec.image(image_id) else { return };
        let frame_index = map.keyframes.iter().find(|k| k.image_id == image_id).map_or(0, |k| k.data.index);
        self.events.send(SlamEvent::KeyframeAdded {
            map: map.index,
            image_id: image_id.0,
            frame_index,
            cam_from_world: img.cam_from_world,
            num_points: img.num_points3d(),
        });
    }

    /// Sends the map's changes since the last update (or everything).
    fn emit_map(&mut self, full: bool) {
        if !self.events.is_active() {
            return;
        }
        let Some(map) = self.map.as_mut() else { return };
        let current: std::collections::HashSet<colslam_scene::Point3DId> = map.rec.point3d_ids().into_iter().collect();
        let removed: Vec<u64> =
            if full { Vec::new() } else { map.sent_points.difference(&current).map(|p| p.0).collect() };
        // Points of the newest keyframes moved in local BA; new points are
        // those not sent yet.
        let recent: std::collections::HashSet<colslam_scene::ImageId> =
            map.keyframes.iter().rev().take(self.opts.local_ba_images).map(|k| k.image_id).collect();
        let points: Vec<EventPoint> = map
            .rec
            .points3d()
            .filter(|(id, p)| {
                full || !map.sent_points.contains(id) || p.track.iter().any(|e| recent.contains(&e.image_id))
            })
            .map(|(id, p)| EventPoint { id: id.0, xyz: p.xyz, color: p.color })
            .collect();
        map.sent_points = current;
        let poses = map
            .keyframes
            .iter()
            .filter(|k| full || recent.contains(&k.image_id))
            .filter_map(|k| map.rec.image(k.image_id).map(|img| (k.image_id.0, k.data.index, img.cam_from_world)))
            .collect();
        let event = SlamEvent::MapUpdated {
            map: map.index,
            full,
            points,
            removed_points: removed,
            poses,
            keyframes: map.rec.num_registered_images(),
            num_points: map.rec.num_points3d(),
            observations: map.rec.num_observations(),
            mean_reproj_error: map.rec.mean_reprojection_error(),
        };
        self.events.send(event);
    }

    /// Ends the run: a last initialisation attempt if none succeeded, final
    /// global BA of every map, localisation of every frame.
    pub fn finish(mut self) -> Result<SlamResult, SlamError> {
        if matches!(self.state, State::Initializing { .. }) {
            self.try_initialize(true)?;
        }
        if let State::Initializing { window } = &mut self.state {
            let rest = std::mem::take(window);
            self.add_orphans(rest);
        }
        if let Some(map) = self.map.take() {
            self.finished.push(map);
        }
        let focal = self.focal();
        let mut finished = std::mem::take(&mut self.finished);
        for map in &mut finished {
            map.finalize(&self.opts, &mut self.timings)?;
        }
        // Offline recovery: merge maps into the largest where they overlap.
        finished.sort_by(|a, b| {
            b.rec.num_registered_images().cmp(&a.rec.num_registered_images()).then(a.index.cmp(&b.index))
        });
        let mut kept: Vec<MapState> = Vec::new();
        for map in finished {
            let mut merged = false;
            if let Some(base) = kept.first_mut() {
                merged = crate::merge::try_merge(base, &map, &self.frontend, &self.opts, &mut self.timings)?.is_some();
                if merged {
                    self.notes.push(format!("map {} merged into map {}", map.index, base.index));
                }
            }
            if !merged {
                kept.push(map);
            }
        }
        let mut maps = Vec::new();
        for mut map in kept {
            let extra = crate::merge::relocalization_records(&map, &self.orphans, &self.frontend, &mut self.timings)?;
            let mut by_index: HashMap<usize, usize> =
                map.records.iter().enumerate().map(|(i, r)| (r.index, i)).collect();
            for r in extra {
                match by_index.get(&r.index) {
                    Some(&i) => map.records[i].obs.extend(r.obs),
                    None => {
                        by_index.insert(r.index, map.records.len());
                        map.records.push(r);
                    }
                }
            }
            let (mut poses, _failed, mut inliers) = map.localize_all(focal, &self.opts, &mut self.timings);
            if self.opts.rolling_shutter_readout > 0.0 {
                (poses, inliers) = self.compensate_rolling_shutter(&mut map, poses, inliers)?;
            }
            if self.opts.refine_all_frames {
                map.refine_with_all_frames(&mut poses, &inliers, &self.opts, &mut self.timings)?;
            }
            map.color_points();
            maps.push(MapResult { map, poses });
        }
        // Largest first; ties by earlier map.
        maps.sort_by(|a, b| b.poses.len().cmp(&a.poses.len()).then(a.map.index.cmp(&b.map.index)));
        let localized: std::collections::HashSet<usize> =
            maps.iter().flat_map(|m| m.poses.iter().map(|p| p.index)).collect();
        let not_localized = self.frames.iter().filter(|f| !localized.contains(&f.index)).cloned().collect();
        self.events.send(SlamEvent::Finished);
        Ok(SlamResult {
            maps,
            frames: self.frames,
            not_localized,
            timings: self.timings,
            notes: self.notes,
            rejected_rotation: self.rejected_rotation,
            forced_keyframes: self.forced_keyframes,
            deregistered: self.deregistered,
        })
    }
}

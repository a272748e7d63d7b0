//! The bridge between a pipeline run and the browser viewer (paper section
//! 3.7): a thread that turns the pipeline's [`SlamEvent`]s and the decoded
//! frames into [`ViewerUpdate`]s, the run shared between `colslam run --view`
//! and the page's Run button ([`run_live`]), and the [`RunController`] that
//! the page's Run/Stop/Export buttons call ([`ViewController`]).
//!
//! The mapping loop never waits on the viewer: events go over the pipeline's
//! unbounded channel, frames over an unbounded channel too, but a frame's
//! picture is only attached while fewer than [`MAX_IMAGES_IN_FLIGHT`] wait
//! for the bridge (a lagging consumer gets the frame's number without the
//! picture). Pictures are downscaled on the bridge thread.
//!
//! The live map comes from `MapUpdated` increments. Those carry no tracks, so
//! a live point's observers are the keyframes that were new when the point
//! first appeared (what the page needs for "introduced at"); the final
//! model, read back from the output folder when the run ends, replaces the
//! live map with full tracks.
//!
//! A caller adds hooks of its own to a live run (the binary's progress bar)
//! with [`run_live`]'s `extra` ([`RunHooks::then`] combines them).

use crate::{
    ControlError, FrameUpdate, KeyframeUpdate, MapDelta, RunController, RunSettings, RunState, Summary, VIEW_MAX_WIDTH,
    ViewerCamera, ViewerHandle, ViewerPoint, ViewerUpdate, downscale_for_view,
};
use colslam_camera::Camera;
use colslam_image::Image;
use colslam_scene::Reconstruction;
use colslam_slam::error_chain;
use colslam_slam::run::{RunConfig, RunHooks, RunOptions, RunOutput, RunStart};
use colslam_slam::{EventSink, SlamError, SlamEvent};
use std::collections::{HashMap, HashSet, VecDeque};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Frame pictures sent to the bridge and not yet taken by it; beyond this the
/// run loop sends frames without their picture (the consumer lags).
pub const MAX_IMAGES_IN_FLIGHT: usize = 4;

/// Downscaled recent frames the bridge keeps, to show keyframes chosen
/// among earlier frames (the initialisation pair comes from a window of
/// `init_frames` frames) with their picture.
const MAX_RING: usize = 64;

/// Extra frames kept beyond the initialisation window.
const RING_MARGIN: usize = 8;

/// The bridge wakes at least this often to take frames (during
/// initialisation no events arrive for a while).
const POLL: Duration = Duration::from_millis(20);

/// Frame updates (other than keyframes) sent to the page at most this often:
/// a browser shows about 30 pictures a second, more only costs PNG encoding.
const MIN_FRAME_INTERVAL: Duration = Duration::from_millis(33);

/// The summary's frame rate is refreshed at most this often.
const SUMMARY_INTERVAL: Duration = Duration::from_millis(500);

/// How long an Export during a run waits for the run loop to copy the model
/// (it does so after the frame it is working on).
const SNAPSHOT_WAIT: Duration = Duration::from_secs(10);

/// A run's final state is sent no sooner than this after the page's start,
/// so that the server's own "running" (applied when `start` returns) cannot
/// overwrite a quick failure.
const MIN_RUN_STATE_DELAY: Duration = Duration::from_millis(100);

/// What the run loop sends the bridge besides the pipeline's events.
enum BridgeMsg {
    /// The run starts: its camera (OpenCV pixel convention, for the frusta)
    /// and its number of frames when the source knows it.
    Start { camera: Camera, frames: Option<usize> },
    /// A decoded frame; `image` is `None` when the bridge lagged.
    Frame { index: usize, name: String, image: Option<Image> },
}

/// A recent frame, downscaled for the page.
struct RingEntry {
    index: usize,
    name: String,
    /// The picture and the factor its coordinates were scaled by.
    image: Option<(Image, f32)>,
}

/// Where the bridge's updates go (the viewer; a collector in tests).
type UpdateSink = Box<dyn Fn(ViewerUpdate) + Send>;

/// The bridge thread's state.
struct Bridge {
    out: UpdateSink,
    in_flight: Arc<AtomicUsize>,
    flow_threshold: f64,
    min_matches: usize,
    ring_capacity: usize,
    ring: VecDeque<RingEntry>,
    camera: Option<Camera>,
    /// Full-resolution size of the last frame (frusta before the camera is known).
    frame_size: (usize, usize),
    started: Instant,
    frames_seen: usize,
    /// Frames the run will read, when known.
    total_frames: Option<usize>,
    /// No tracking events yet in the current map: frames are shown as they come.
    initializing: bool,
    last_frame_sent: Option<Instant>,
    last_summary_sent: Option<Instant>,
    summary: Summary,
    /// Live points and their observers (the keyframes new when each appeared).
    points: HashMap<u64, Vec<u32>>,
    /// Live cameras: image id -> (registration order, name).
    cameras: HashMap<u32, (u32, String)>,
    next_order: u32,
    /// Keyframes added since the last map update.
    new_keyframes: Vec<u32>,
    /// Names of keyframes by image id (from the frames' names).
    keyframe_names: HashMap<u32, String>,
}

impl Bridge {
    fn new(out: UpdateSink, in_flight: Arc<AtomicUsize>, opts: &RunOptions) -> Self {
        let s = &opts.slam;
        Self {
            out,
            in_flight,
            flow_threshold: s.keyframes.flow_threshold,
            min_matches: s.keyframes.min_matches,
            ring_capacity: (s.init.init_frames + RING_MARGIN).min(MAX_RING),
            ring: VecDeque::new(),
            camera: None,
            frame_size: (0, 0),
            started: Instant::now(),
            frames_seen: 0,
            total_frames: None,
            initializing: true,
            last_frame_sent: None,
            last_summary_sent: None,
            summary: Summary::default(),
            points: HashMap::new(),
            cameras: HashMap::new(),
            next_order: 0,
            new_keyframes: Vec::new(),
            keyframe_names: HashMap::new(),
        }
    }

    /// Runs until the pipeline's event channel closes (the run ended).
    ///
    /// Ordering: the run loop sends a frame before processing it, so when an
    /// event arrives, the frames it refers to are already in `msgs`; taking
    /// all of `msgs` before handling each event keeps them in step.
    fn run(mut self, events: Receiver<SlamEvent>, msgs: Receiver<BridgeMsg>) {
        loop {
            match events.recv_timeout(POLL) {
                Ok(ev) => {
                    self.drain(&msgs);
                    self.event(ev);
                }
                Err(RecvTimeoutError::Timeout) => self.drain(&msgs),
                Err(RecvTimeoutError::Disconnected) => {
                    self.drain(&msgs);
                    break;
                }
            }
        }
        self.send_summary();
    }

    fn drain(&mut self, msgs: &Receiver<BridgeMsg>) {
        while let Ok(m) = msgs.try_recv() {
            self.message(m);
        }
    }

    fn message(&mut self, m: BridgeMsg) {
        match m {
            BridgeMsg::Start { camera, frames } => {
                self.camera = Some(camera);
                self.total_frames = frames;
            }
            BridgeMsg::Frame { index, name, image } => {
                self.frames_seen += 1;
                let image = image.map(|img| {
                    self.in_flight.fetch_sub(1, Ordering::SeqCst);
                    self.frame_size = (img.width(), img.height());
                    downscale_for_view(&img, VIEW_MAX_WIDTH)
                });
                if self.ring.len() >= self.ring_capacity {
                    self.ring.pop_front();
                }
                self.ring.push_back(RingEntry { index, name, image });
                if self.initializing {
                    // No flow yet: show the frame as it comes.
                    let picture = self.ring.back().and_then(|e| e.image.as_ref().map(|(i, _)| i.clone()));
                    if self.frame_due(false) {
                        (self.out)(ViewerUpdate::Frame(FrameUpdate {
                            index,
                            image: picture,
                            flow_threshold: self.flow_threshold,
                            min_matches: self.min_matches,
                            ..FrameUpdate::default()
                        }));
                    }
                }
                let due = self.last_summary_sent.is_none_or(|t| t.elapsed() >= SUMMARY_INTERVAL);
                if due {
                    self.send_summary();
                }
            }
        }
    }

    /// Whether a frame update may go out now (keyframes always do).
    fn frame_due(&mut self, is_keyframe: bool) -> bool {
        let due = is_keyframe || self.last_frame_sent.is_none_or(|t| t.elapsed() >= MIN_FRAME_INTERVAL);
        if due {
            self.last_frame_sent = Some(Instant::now());
        }
        due
    }

    fn send_summary(&mut self) {
        let secs = self.started.elapsed().as_secs_f64();
        self.summary.fps = if secs > 0.0 { self.frames_seen as f64 / secs } else { 0.0 };
        self.summary.frames = self.frames_seen;
        self.summary.total_frames = self.total_frames;
        self.last_summary_sent = Some(Instant::now());
        (self.out)(ViewerUpdate::Summary(self.summary));
    }

    fn ring_entry(&self, index: usize) -> Option<&RingEntry> {
        self.ring.iter().rev().find(|e| e.index == index)
    }

    fn event(&mut self, ev: SlamEvent) {
        match ev {
            SlamEvent::FrameProcessed {
                index,
                flow_score,
                num_matches,
                num_inliers,
                flow_lines,
                outlier_lines,
                is_keyframe,
                ..
            } => {
                self.initializing = false;
                if !self.frame_due(is_keyframe) {
                    return;
                }
                let (image, scale) = match self.ring_entry(index).and_then(|e| e.image.as_ref()) {
                    Some((img, s)) => (Some(img.clone()), *s),
                    None => (None, 1.0),
                };
                // The pipeline sends [frame x, frame y, keyframe x, keyframe y];
                // the viewer wants the keyframe end first.
                let page = |lines: Vec<[f32; 4]>| -> Vec<[f32; 4]> {
                    lines.iter().map(|l| [l[2] * scale, l[3] * scale, l[0] * scale, l[1] * scale]).collect()
                };
                (self.out)(ViewerUpdate::Frame(FrameUpdate {
                    index,
                    image,
                    flow_lines: page(flow_lines),
                    outlier_lines: page(outlier_lines),
                    flow_score,
                    num_matches,
                    num_inliers,
                    flow_threshold: self.flow_threshold,
                    min_matches: self.min_matches,
                    is_keyframe,
                }));
            }
            SlamEvent::KeyframeAdded { image_id, frame_index, .. } => {
                self.new_keyframes.push(image_id);
                let (name, image) = match self.ring_entry(frame_index) {
                    Some(e) => (e.name.clone(), e.image.as_ref().map(|(i, _)| i.clone())),
                    None => (format!("frame {frame_index}"), None),
                };
                self.keyframe_names.insert(image_id, name.clone());
                (self.out)(ViewerUpdate::Keyframe(KeyframeUpdate { image_id, frame_index, name, image }));
            }
            SlamEvent::MapUpdated {
                full,
                points,
                removed_points,
                poses,
                keyframes,
                num_points,
                observations,
                mean_reproj_error,
                ..
            } => {
                let mut delta = MapDelta { removed_points, ..MapDelta::default() };
                if full {
                    let now: HashSet<u64> = points.iter().map(|p| p.id).collect();
                    delta.removed_points.extend(self.points.keys().filter(|id| !now.contains(id)));
                    let posed: HashSet<u32> = poses.iter().map(|p| p.0).collect();
                    delta.removed_cameras = self.cameras.keys().filter(|id| !posed.contains(id)).copied().collect();
                }
                for id in &delta.removed_points {
                    self.points.remove(id);
                }
                for id in &delta.removed_cameras {
                    self.cameras.remove(id);
                }
                let mut intro = std::mem::take(&mut self.new_keyframes);
                if intro.is_empty() {
                    intro.extend(poses.iter().map(|p| p.0).max());
                }
                intro.sort_unstable();
                intro.dedup();
                for p in points {
                    let observers = self.points.entry(p.id).or_insert_with(|| intro.clone()).clone();
                    delta.points.push(ViewerPoint {
                        id: p.id,
                        xyz: [p.xyz.x, p.xyz.y, p.xyz.z],
                        color: p.color,
                        observers,
                    });
                }
                for (image_id, frame_index, pose) in poses {
                    let next = self.next_order;
                    let name =
                        self.keyframe_names.get(&image_id).cloned().unwrap_or_else(|| format!("frame {frame_index}"));
                    let (order, name) = self.cameras.entry(image_id).or_insert((next, name)).clone();
                    if order == next {
                        self.next_order = next.saturating_add(1);
                    }
                    delta.cameras.push(self.viewer_camera(image_id, name, order, pose));
                }
                (self.out)(ViewerUpdate::MapDelta(delta));
                self.summary =
                    Summary { keyframes, points: num_points, observations, mean_reproj_error, ..self.summary };
                self.send_summary();
            }
            SlamEvent::BundleAdjusted { global: true, iterations, final_cost, .. } => {
                (self.out)(ViewerUpdate::Status(format!(
                    "global bundle adjustment: {iterations} iterations, final cost {final_cost:.3e}"
                )));
            }
            SlamEvent::BundleAdjusted { .. } => {}
            SlamEvent::MapReset { new_map, frame_index, reason } => {
                // The page shows the current map: clear the previous one.
                let delta = MapDelta {
                    removed_points: self.points.drain().map(|(id, _)| id).collect(),
                    removed_cameras: self.cameras.drain().map(|(id, _)| id).collect(),
                    ..MapDelta::default()
                };
                (self.out)(ViewerUpdate::MapDelta(delta));
                self.next_order = 0;
                self.new_keyframes.clear();
                self.initializing = true;
                self.summary = Summary::default();
                (self.out)(ViewerUpdate::Status(format!("map {new_map} started at frame {frame_index}: {reason}")));
            }
            SlamEvent::Finished => {
                (self.out)(ViewerUpdate::Status("frames done; writing outputs".into()));
            }
        }
    }

    /// The viewer's camera for a keyframe pose, with the run's intrinsics
    /// (or, before they are known, a guess from the frame size).
    fn viewer_camera(&self, image_id: u32, name: String, order: u32, pose: colslam_geometry::Rigid3) -> ViewerCamera {
        let (w, h, fx, fy, cx, cy) = match &self.camera {
            Some(c) => {
                let pp = c.principal_point();
                (c.width as f64, c.height as f64, c.focal_x(), c.focal_y(), pp.x, pp.y)
            }
            None => {
                let (w, h) = (self.frame_size.0 as f64, self.frame_size.1 as f64);
                let f = colslam_slam::run::guessed_focal(w, h);
                (w, h, f, f, 0.5 * w, 0.5 * h)
            }
        };
        let to_u32 = |v: f64| if v.is_finite() && v >= 0.0 { v.min(u32::MAX as f64) as u32 } else { 0 };
        ViewerCamera {
            image_id,
            name,
            order,
            cam_from_world: pose,
            width: to_u32(w),
            height: to_u32(h),
            fx,
            fy,
            cx,
            cy,
        }
    }
}

/// The model of a run for Export: copied by the run loop on request.
#[derive(Default)]
struct SnapshotSlot {
    /// Set by an Export; the run loop copies the model after its frame.
    want: AtomicBool,
    inner: Mutex<SnapInner>,
    ready: Condvar,
}

#[derive(Default)]
struct SnapInner {
    /// Bumped with every copy.
    serial: u64,
    latest: Option<Arc<Reconstruction>>,
    running: bool,
}

impl SnapshotSlot {
    fn lock(&self) -> MutexGuard<'_, SnapInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn store(&self, rec: Option<Arc<Reconstruction>>, running: bool) {
        let mut g = self.lock();
        if rec.is_some() || !running {
            g.latest = rec;
        }
        g.serial += 1;
        g.running = running;
        drop(g);
        self.ready.notify_all();
    }

    /// A run starts: no model yet.
    fn begin(&self) {
        let mut g = self.lock();
        g.latest = None;
        g.running = true;
    }

    /// The newest model: during a run, a copy made after the current frame
    /// (or the previous copy when the run loop is busy past [`SNAPSHOT_WAIT`]).
    fn get(&self) -> Option<Arc<Reconstruction>> {
        let g = self.lock();
        if !g.running {
            return g.latest.clone();
        }
        let serial = g.serial;
        self.want.store(true, Ordering::SeqCst);
        let (g, _) = self
            .ready
            .wait_timeout_while(g, SNAPSHOT_WAIT, |s| s.running && s.serial == serial)
            .unwrap_or_else(|e| e.into_inner());
        g.latest.clone()
    }
}

/// What runs share with the controller: the busy flag, the Stop flag and
/// the Export snapshot.
#[derive(Default)]
pub struct RunShared {
    busy: AtomicBool,
    cancel: Arc<AtomicBool>,
    snapshot: SnapshotSlot,
}

impl RunShared {
    /// Marks a run as started and clears an old Stop; false when one is
    /// already running. (Cleared here, before the run's thread starts, so a
    /// Stop right after the start is not lost.)
    pub fn try_begin(&self) -> bool {
        let began = self.busy.compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst).is_ok();
        if began {
            self.cancel.store(false, Ordering::SeqCst);
        }
        began
    }

    /// Marks the run as ended.
    pub fn end(&self) {
        self.busy.store(false, Ordering::SeqCst);
    }

    /// Asks the running pipeline to stop after its current frame.
    pub fn stop(&self) {
        self.cancel.store(true, Ordering::SeqCst);
    }
}

/// Runs the pipeline with the viewer following live: resets the page, feeds
/// frames, keyframes, map increments and the summary through the bridge
/// thread, then shows the final model (read back from the output folder)
/// and the run's end state, no sooner than `final_not_before` (a run started
/// from the page waits a moment so that the server's own "running", applied
/// when the start returns, cannot overwrite a quick failure; `Instant::now()`
/// for no wait). The caller took `shared`'s busy flag
/// ([`RunShared::try_begin`], which also clears an old Stop); it is released
/// right after the end state is sent.
///
/// `extra` are the caller's hooks (a progress bar; [`RunHooks::default`] for
/// none), called after the viewer's ([`RunHooks::then`]); the page's Stop and
/// `extra`'s cancel flag both stop the run.
pub fn run_live(
    config: &RunConfig,
    extra: RunHooks<'_>,
    handle: &ViewerHandle,
    shared: &RunShared,
    final_not_before: Instant,
) -> Result<RunOutput, SlamError> {
    shared.snapshot.begin();
    handle.apply(ViewerUpdate::Reset);
    handle.apply(ViewerUpdate::RunState(RunState::Running));
    handle.apply(ViewerUpdate::Status(format!("running on {}", config.input.display())));
    let (sink, events) = EventSink::channel();
    let (tx, msgs) = channel::<BridgeMsg>();
    let in_flight = Arc::new(AtomicUsize::new(0));
    let viewer = handle.clone();
    let bridge = Bridge::new(Box::new(move |u| viewer.apply(u)), Arc::clone(&in_flight), &config.options);
    let thread =
        std::thread::Builder::new().name("colslam-viewer-bridge".into()).spawn(move || bridge.run(events, msgs));
    let thread = match thread {
        Ok(t) => Some(t),
        Err(e) => {
            tracing::warn!("viewer bridge thread failed to start ({e}); the run goes on without live view");
            None
        }
    };
    let result = {
        let (camera_tx, frame_tx) = (tx.clone(), tx);
        let hooks = RunHooks {
            cancel: vec![Arc::clone(&shared.cancel)],
            interrupt: None,
            on_start: Some(Box::new(move |s: &RunStart| {
                let _ = camera_tx.send(BridgeMsg::Start { camera: s.camera.clone(), frames: s.frames });
            })),
            before_frame: Some(Box::new(move |f: &colslam_io::Frame| {
                // Never wait for the bridge: attach the picture only while it keeps up.
                let image = (in_flight.load(Ordering::SeqCst) < MAX_IMAGES_IN_FLIGHT).then(|| {
                    in_flight.fetch_add(1, Ordering::SeqCst);
                    f.image.clone()
                });
                let _ = frame_tx.send(BridgeMsg::Frame { index: f.index, name: f.name.clone(), image });
            })),
            after_frame: Some(Box::new(|slam: &colslam_slam::Slam| {
                if shared.snapshot.want.swap(false, Ordering::SeqCst) {
                    let rec = slam.current_reconstruction().map(|r| Arc::new(r.clone()));
                    shared.snapshot.store(rec, true);
                }
            })),
        };
        colslam_slam::run::run(config, sink, hooks.then(extra))
    };
    // The hooks and the event sink are gone: the bridge drains and ends.
    if let Some(t) = thread {
        let _ = t.join();
    }
    let final_model = match &result {
        Ok(_) => read_final_model(&config.output),
        Err(_) => None,
    };
    if let Some(rec) = &final_model {
        handle.set_reconstruction_from(rec, &config.output.display().to_string());
        // `--gt`: the comparison layer on the final poses, as `view --gt`
        // shows it for a loaded model; the run's report holds the same ATE.
        if let (Some(gt), Ok(o)) = (&config.gt, &result) {
            let stamps: HashMap<&str, f64> = o.result.frames.iter().map(|f| (f.name.as_str(), f.timestamp)).collect();
            match crate::GroundTruthLayer::read(rec, gt, &|image| stamps.get(image).copied()) {
                Ok(layer) => handle.set_ground_truth(Some(layer)),
                Err(e) => tracing::warn!("no ground-truth layer for {}: {}", gt.display(), error_chain(&e)),
            }
        }
    }
    if let Some(rest) = final_not_before.checked_duration_since(Instant::now()) {
        std::thread::sleep(rest);
    }
    match &result {
        Ok(o) => {
            let r = &o.report;
            if let Some(rec) = &final_model
                && r.wall_time_s > 0.0
            {
                let fps = r.frames as f64 / r.wall_time_s;
                let (frames, total_frames) = (r.frames, Some(r.frames));
                handle.apply(ViewerUpdate::Summary(Summary { fps, frames, total_frames, ..Summary::of(rec) }));
            }
            let line = r.outcome(&config.output);
            handle.apply(ViewerUpdate::Status(line.clone()));
            handle.apply(ViewerUpdate::RunState(match r.stopped_after {
                Some(_) => RunState::Stopped(line),
                None => RunState::Finished(line),
            }));
        }
        Err(e) => handle.apply(ViewerUpdate::RunState(RunState::Failed(error_chain(e)))),
    }
    shared.snapshot.store(final_model.map(Arc::new), false);
    shared.end();
    result
}

/// The model the run wrote (its largest map), if any.
fn read_final_model(out: &Path) -> Option<Reconstruction> {
    match colslam_scene::read_model(out) {
        Ok(rec) => Some(rec),
        Err(e) => {
            tracing::debug!("no final model to show from {}: {e}", out.display());
            None
        }
    }
}

/// The page's Run/Stop/Export buttons: runs on a worker thread.
pub struct ViewController {
    handle: ViewerHandle,
    shared: Arc<RunShared>,
    /// Options the page does not set (feature count, seed, ...).
    base: RunOptions,
    worker: Mutex<Option<JoinHandle<()>>>,
}

impl ViewController {
    /// A controller feeding `handle`, with `base` for the options the page does not set.
    pub fn new(handle: ViewerHandle, shared: Arc<RunShared>, base: RunOptions) -> Self {
        Self { handle, shared, base, worker: Mutex::new(None) }
    }
}

/// The run the page's settings select, on top of `base`, validated by the
/// library's options (the output may not be a file).
pub fn run_args_from_settings(base: &RunOptions, s: &RunSettings) -> Result<RunConfig, ControlError> {
    let config = s.to_config(base)?;
    config.validate()?;
    Ok(config)
}

impl RunController for ViewController {
    fn start(&self, settings: RunSettings) -> Result<(), ControlError> {
        let args = run_args_from_settings(&self.base, &settings)?;
        // A bad or busy output and a bad input are reported to the page at
        // once rather than as a failed run.
        args.check_output()?;
        let src = args.options.source();
        colslam_io::probe_source(&args.input, &src)?;
        if !self.shared.try_begin() {
            return Err(ControlError::Busy);
        }
        let (handle, shared) = (self.handle.clone(), Arc::clone(&self.shared));
        let not_before = Instant::now() + MIN_RUN_STATE_DELAY;
        let spawned = std::thread::Builder::new().name("colslam-run".into()).spawn(move || {
            match run_live(&args, RunHooks::default(), &handle, &shared, not_before) {
                Ok(_) => {
                    tracing::info!("run on {} finished; outputs in {}", args.input.display(), args.output.display())
                }
                Err(e) => tracing::error!("run on {} failed: {}", args.input.display(), error_chain(&e)),
            }
        });
        match spawned {
            Ok(t) => {
                let mut w = self.worker.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(old) = w.replace(t) {
                    // The previous run ended (busy was free): reap its thread.
                    let _ = old.join();
                }
                Ok(())
            }
            Err(e) => {
                self.shared.end();
                Err(ControlError::Thread(e))
            }
        }
    }

    fn stop(&self) {
        self.shared.stop();
    }

    fn max_frames_for(&self, input: &Path, skip: usize) -> Result<usize, ControlError> {
        let opts = colslam_io::SourceOptions { skip: skip.max(1), ..Default::default() };
        let info = colslam_io::probe_source(input, &opts)?;
        info.frames.ok_or_else(|| ControlError::UnknownFrameCount(input.to_path_buf()))
    }

    fn snapshot(&self) -> Option<Reconstruction> {
        self.shared.snapshot.get().map(|r| (*r).clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> RunOptions {
        RunOptions::default()
    }

    #[test]
    fn a_run_into_an_unusable_output_is_refused_before_it_starts() {
        // Regression: the page's run was accepted and failed only in the
        // run (after the compute), for an output under a file or busy.
        let dir = tempfile::tempdir().expect("tempdir");
        let input = dir.path().join("seq");
        std::fs::create_dir(&input).expect("mkdir");
        for i in 0..2 {
            Image::new(32, 24, 1).write_png(&input.join(format!("{i:06}.png"))).expect("png");
        }
        let file = dir.path().join("file");
        std::fs::write(&file, "x").expect("write");
        let viewer =
            crate::Viewer::start(crate::ViewerOptions { port: 0, ..crate::ViewerOptions::default() }).expect("viewer");
        let shared = Arc::new(RunShared::default());
        let controller = ViewController::new(viewer.handle(), Arc::clone(&shared), base());
        let settings = |output: &Path| RunSettings {
            input: input.clone(),
            output: output.to_path_buf(),
            ..RunSettings::default()
        };
        let e = controller.start(settings(&file.join("out"))).expect_err("under a file");
        assert!(matches!(e, ControlError::Run(_)) && e.status() == 400, "{e:?}");
        assert!(error_chain(&e).contains("is a file"), "{e}");
        let out = dir.path().join("out");
        let busy = colslam_slam::begin_run_output(&out).expect("lock");
        let e = controller.start(settings(&out)).expect_err("busy");
        assert!(error_chain(&e).contains("another process"), "{e}");
        drop(busy);
        assert!(shared.try_begin(), "no run was started");
    }

    #[test]
    fn settings_map_to_run_args() {
        let s = RunSettings {
            input: "in".into(),
            output: "out".into(),
            skip: 3,
            max_frames: Some(50),
            init_frames: 10,
            flow_threshold: 0.1,
            ..RunSettings::default()
        };
        let a = run_args_from_settings(&base(), &s).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(a.input, Path::new("in"));
        assert_eq!(a.output, Path::new("out"));
        let o = &a.options;
        assert_eq!((o.input.skip, o.input.max_frames, o.slam.init.init_frames), (3, Some(50), 10));
        assert_eq!(o.slam.keyframes.flow_threshold, 0.1);
        assert_eq!(
            (o.slam.frontend.features, o.slam.frontend.matcher),
            (colslam_slam::FeatureKind::Orb, colslam_slam::MatcherKind::Nn)
        );
        let bad = RunSettings { skip: 0, ..s };
        assert!(run_args_from_settings(&base(), &bad).is_err());
    }

    /// A bridge whose updates are collected.
    fn collecting() -> (Bridge, Arc<Mutex<Vec<ViewerUpdate>>>, Arc<AtomicUsize>) {
        let got = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&got);
        let in_flight = Arc::new(AtomicUsize::new(0));
        let out: UpdateSink = Box::new(move |u| sink.lock().unwrap_or_else(|e| e.into_inner()).push(u));
        (Bridge::new(out, Arc::clone(&in_flight), &base()), got, in_flight)
    }

    fn take(got: &Mutex<Vec<ViewerUpdate>>) -> Vec<ViewerUpdate> {
        std::mem::take(&mut *got.lock().unwrap_or_else(|e| e.into_inner()))
    }

    fn point(id: u64) -> colslam_slam::EventPoint {
        colslam_slam::EventPoint { id, xyz: colslam_geometry::Vec3::new(id as f64, 0.0, 1.0), color: [1, 2, 3] }
    }

    fn map_updated(full: bool, ids: &[u64], removed: &[u64], poses: &[u32]) -> SlamEvent {
        SlamEvent::MapUpdated {
            map: 0,
            full,
            points: ids.iter().map(|&i| point(i)).collect(),
            removed_points: removed.to_vec(),
            poses: poses.iter().map(|&p| (p, p as usize * 10, colslam_geometry::Rigid3::identity())).collect(),
            keyframes: poses.len(),
            num_points: ids.len(),
            observations: 2 * ids.len(),
            mean_reproj_error: 0.5,
        }
    }

    #[test]
    fn bridge_turns_events_into_viewer_updates() {
        let (mut b, got, in_flight) = collecting();
        let cam = Camera::simple_pinhole(1280, 960, 1000.0, 639.5, 479.5);
        b.message(BridgeMsg::Start { camera: cam, frames: Some(40) });
        // A 1280-wide frame while initialising: shown at once, downscaled by 2.
        in_flight.store(1, Ordering::SeqCst);
        b.message(BridgeMsg::Frame { index: 10, name: "a.png".into(), image: Some(Image::new(1280, 960, 1)) });
        assert_eq!(in_flight.load(Ordering::SeqCst), 0, "the picture was taken");
        let ups = take(&got);
        let frame = ups.iter().find_map(|u| match u {
            ViewerUpdate::Frame(f) => Some(f),
            _ => None,
        });
        let frame = frame.unwrap_or_else(|| panic!("a frame update: {ups:?}"));
        assert_eq!(frame.image.as_ref().map(|i| (i.width(), i.height())), Some((640, 480)));

        // The initialisation pair: keyframe with the ring's picture and name.
        b.event(SlamEvent::KeyframeAdded {
            map: 0,
            image_id: 1,
            frame_index: 10,
            cam_from_world: colslam_geometry::Rigid3::identity(),
            num_points: 3,
        });
        b.event(SlamEvent::KeyframeAdded {
            map: 0,
            image_id: 2,
            frame_index: 20,
            cam_from_world: colslam_geometry::Rigid3::identity(),
            num_points: 3,
        });
        b.event(map_updated(true, &[1, 2, 3], &[], &[1, 2]));
        let ups = take(&got);
        let kf: Vec<&KeyframeUpdate> = ups
            .iter()
            .filter_map(|u| match u {
                ViewerUpdate::Keyframe(k) => Some(k),
                _ => None,
            })
            .collect();
        assert_eq!(kf.len(), 2);
        assert_eq!((kf[0].name.as_str(), kf[0].image.is_some()), ("a.png", true));
        assert_eq!((kf[1].name.as_str(), kf[1].image.is_some()), ("frame 20", false), "frame 20 was never seen");
        let delta = ups.iter().find_map(|u| match u {
            ViewerUpdate::MapDelta(d) => Some(d),
            _ => None,
        });
        let delta = delta.unwrap_or_else(|| panic!("a map delta: {ups:?}"));
        assert_eq!(delta.points.len(), 3);
        assert!(delta.points.iter().all(|p| p.observers == vec![1, 2]), "introduced by the pair");
        let orders: Vec<(u32, u32)> = delta.cameras.iter().map(|c| (c.image_id, c.order)).collect();
        assert_eq!(orders, vec![(1, 0), (2, 1)]);
        assert_eq!((delta.cameras[0].width, delta.cameras[0].fx), (1280, 1000.0), "the run's intrinsics");

        // A tracked frame: lines swapped to keyframe-first and scaled by 1/2.
        b.message(BridgeMsg::Frame { index: 30, name: "c.png".into(), image: Some(Image::new(1280, 960, 1)) });
        b.last_frame_sent = None;
        b.event(SlamEvent::FrameProcessed {
            index: 30,
            timestamp: 1.0,
            flow_score: 0.1,
            num_matches: 50,
            num_inliers: 1,
            flow_lines: vec![[100.0, 50.0, 60.0, 40.0]],
            outlier_lines: vec![[10.0, 20.0, 30.0, 40.0]],
            is_keyframe: true,
        });
        b.event(SlamEvent::KeyframeAdded {
            map: 0,
            image_id: 3,
            frame_index: 30,
            cam_from_world: colslam_geometry::Rigid3::identity(),
            num_points: 3,
        });
        // An increment: point 4 is new (introduced by keyframe 3), 1 removed,
        // 2 moved (keeps its observers).
        b.event(map_updated(false, &[2, 4], &[1], &[3]));
        let ups = take(&got);
        // The last frame update: frame 30's message may also show the bare
        // picture first when the frame interval since frame 10 has passed
        // (the bridge is still initialising then), which depends on timing.
        let lines = ups.iter().rev().find_map(|u| match u {
            ViewerUpdate::Frame(f) => Some((f.flow_lines.clone(), f.outlier_lines.clone(), f.num_inliers)),
            _ => None,
        });
        assert_eq!(lines, Some((vec![[30.0, 20.0, 50.0, 25.0]], vec![[15.0, 20.0, 5.0, 10.0]], 1)));
        let summary = ups.iter().rev().find_map(|u| match u {
            ViewerUpdate::Summary(s) => Some(*s),
            _ => None,
        });
        assert_eq!(summary.map(|s| (s.frames, s.total_frames)), Some((2, Some(40))), "progress: 2 of 40 frames read");
        let delta = ups.iter().find_map(|u| match u {
            ViewerUpdate::MapDelta(d) => Some(d.clone()),
            _ => None,
        });
        let delta = delta.unwrap_or_else(|| panic!("a map delta: {ups:?}"));
        assert_eq!(delta.removed_points, vec![1]);
        let obs: Vec<(u64, Vec<u32>)> = delta.points.iter().map(|p| (p.id, p.observers.clone())).collect();
        assert_eq!(obs, vec![(2, vec![1, 2]), (4, vec![3])]);
        assert_eq!(delta.cameras.iter().map(|c| (c.image_id, c.order)).collect::<Vec<_>>(), vec![(3, 2)]);

        // A full snapshot without point 3 and camera 1 removes them.
        b.event(map_updated(true, &[2, 4], &[], &[2, 3]));
        let ups = take(&got);
        let delta = ups.iter().find_map(|u| match u {
            ViewerUpdate::MapDelta(d) => Some(d.clone()),
            _ => None,
        });
        let delta = delta.unwrap_or_else(|| panic!("a map delta: {ups:?}"));
        assert_eq!((delta.removed_points, delta.removed_cameras), (vec![3], vec![1]));

        // A new map clears the old one.
        b.event(SlamEvent::MapReset { new_map: 1, frame_index: 40, reason: "lost".into() });
        let ups = take(&got);
        let delta = ups.iter().find_map(|u| match u {
            ViewerUpdate::MapDelta(d) => Some(d.clone()),
            _ => None,
        });
        let mut delta = delta.unwrap_or_else(|| panic!("a map delta: {ups:?}"));
        delta.removed_points.sort_unstable();
        delta.removed_cameras.sort_unstable();
        assert_eq!((delta.removed_points, delta.removed_cameras), (vec![2, 4], vec![2, 3]));
        assert!(b.initializing && b.next_order == 0);
    }

    #[test]
    fn snapshot_waits_for_the_run_loop() {
        let slot = Arc::new(SnapshotSlot::default());
        assert!(slot.get().is_none());
        slot.begin();
        let s2 = Arc::clone(&slot);
        let t = std::thread::spawn(move || {
            // The run loop: serve the request once it is made.
            while !s2.want.swap(false, Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(1));
            }
            s2.store(Some(Arc::new(Reconstruction::default())), true);
        });
        assert!(slot.get().is_some());
        let _ = t.join();
        slot.store(None, false);
        assert!(slot.get().is_none());
    }
}

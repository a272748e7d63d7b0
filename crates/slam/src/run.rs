//! The driver: a source end to end, as `colslam run`, the viewer and the
//! Python binding run it. It validates every option before anything is
//! read, opens the source, resolves the camera, reads and extracts frames on
//! a thread of their own ahead of the mapper, feeds the pipeline, honours a
//! stop request, writes the outputs and then the report (with the
//! evaluation when ground truth is given) in one trip.

use crate::error::SlamError;
use crate::events::EventSink;
use crate::frame::FrameData;
use crate::options::SlamOptions;
use crate::output::{OutputFormat, RunReport, write_outputs, write_report};
use crate::pipeline::{Slam, SlamResult};
use crate::timing::Stage;
use colslam_camera::{Camera, presets};
use colslam_io::{Frame, FrameSource, SourceOptions, open_source};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Focal length prior for unknown cameras, as a multiple of the larger image
/// side (COLMAP's default prior, `default_focal_length_factor` 1.2).
pub const DEFAULT_FOCAL_FACTOR: f64 = 1.2;

/// Frames decoded and extracted ahead of the mapper (bounds the memory the
/// reader thread can hold: a VGA frame with its features is about 1.2 MB).
const PREFETCH_FRAMES: usize = 4;

/// Where the camera comes from. Without any, a camera file beside the input
/// is used, else the focal length is guessed and refined.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Camera"))]
#[serde(default, deny_unknown_fields)]
pub struct CameraOptions {
    /// Camera file (YAML/TOML; see the camera crate). Default: a camera file found beside the input.
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "preset"))]
    pub camera: Option<PathBuf>,
    /// Built-in camera preset.
    #[cfg_attr(feature = "cli", arg(long, value_parser = clap::builder::PossibleValuesParser::new(presets::preset_names())))]
    pub preset: Option<String>,
    /// Focal length in pixels of an unknown camera (principal point at the image centre).
    #[cfg_attr(feature = "cli", arg(long, conflicts_with_all = ["camera", "preset"]))]
    pub focal: Option<f64>,
}

/// How the source is read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Input"))]
#[serde(default, deny_unknown_fields)]
pub struct InputOptions {
    /// Use every s-th frame, at least 1.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = InputOptions::default().skip))]
    pub skip: usize,
    /// Process at most this many frames (after skip), at least 1.
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_frames: Option<usize>,
}

impl Default for InputOptions {
    fn default() -> Self {
        Self { skip: 1, max_frames: None }
    }
}

/// Everything of a run but its input, output, camera and ground truth: what
/// `colslam run` and `colslam demo` share and the viewer's runs start from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct RunOptions {
    /// How the source is read.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub input: InputOptions,
    /// The pipeline.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub slam: SlamOptions,
    /// Worker threads (0: all cores).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0, help_heading = "Output"))]
    pub threads: usize,
    /// Write the COLMAP model as text instead of binary.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Output"))]
    pub text: bool,
}

impl RunOptions {
    /// Checks every option.
    pub fn validate(&self) -> Result<(), SlamError> {
        let bad = |name, value: String, reason: &str| SlamError::InvalidOption { name, value, reason: reason.into() };
        if self.input.skip == 0 {
            return Err(bad("skip", "0".into(), "must be at least 1"));
        }
        if self.input.max_frames == Some(0) {
            return Err(bad("max-frames", "0".into(), "must be at least 1"));
        }
        self.slam.validate()
    }

    /// The source options these select.
    pub fn source(&self) -> SourceOptions {
        SourceOptions { skip: self.input.skip, max_frames: self.input.max_frames, ..SourceOptions::default() }
    }
}

/// A whole run: input, output, camera, ground truth and options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RunConfig {
    /// Video file or image sequence folder (TUM, EuRoC, KITTI layouts or plain images).
    pub input: PathBuf,
    /// Output folder.
    #[cfg_attr(feature = "cli", arg(short, long))]
    pub output: PathBuf,
    /// Ground-truth trajectory (TUM format) to evaluate the result against.
    #[cfg_attr(feature = "cli", arg(long))]
    pub gt: Option<PathBuf>,
    /// Where the camera comes from.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub camera: CameraOptions,
    /// The run's options.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub options: RunOptions,
}

impl RunConfig {
    /// A run of `input` into `output` with default options.
    pub fn new(input: impl Into<PathBuf>, output: impl Into<PathBuf>) -> Self {
        Self {
            input: input.into(),
            output: output.into(),
            gt: None,
            camera: CameraOptions::default(),
            options: RunOptions::default(),
        }
    }

    /// Checks every option and that the output can be a folder; nothing is
    /// read or written.
    pub fn validate(&self) -> Result<(), SlamError> {
        self.options.validate()?;
        if let Some(f) = self.camera.focal
            && !(f.is_finite() && f > 0.0)
        {
            return Err(SlamError::InvalidOption {
                name: "focal",
                value: f.to_string(),
                reason: "must be a positive number of pixels".into(),
            });
        }
        if let Some(name) = &self.camera.preset {
            preset_camera(name)?;
        }
        if self.output.exists() && !self.output.is_dir() {
            let reason = "the output exists and is not a folder".to_string();
            return Err(SlamError::Path { path: self.output.clone(), reason });
        }
        Ok(())
    }
}

/// The built-in camera `name`, or an error listing the known ones.
fn preset_camera(name: &str) -> Result<Camera, SlamError> {
    presets::preset(name).ok_or_else(|| SlamError::InvalidOption {
        name: "preset",
        value: name.to_string(),
        reason: format!("unknown camera preset (known: {})", presets::preset_names().join(", ")),
    })
}

/// The camera of a run and whether its focal length is a guess.
#[derive(Debug, Clone)]
pub struct ResolvedCamera {
    /// The calibration (OpenCV pixel convention, as camera files give it).
    pub camera: Camera,
    /// No calibration was given: the focal length is
    /// [`DEFAULT_FOCAL_FACTOR`] times the larger image side.
    pub guessed: bool,
}

/// The camera `opts` select for `source`: a camera file, a preset, a camera
/// file beside the input, or a pinhole camera with the given or a guessed
/// focal length and the principal point at the centre.
pub fn resolve_camera(
    opts: &CameraOptions,
    input: &Path,
    source: &dyn FrameSource,
) -> Result<ResolvedCamera, SlamError> {
    if let Some(path) = &opts.camera {
        return Ok(ResolvedCamera { camera: colslam_camera::file::read_camera_file(path)?, guessed: false });
    }
    if let Some(name) = &opts.preset {
        return Ok(ResolvedCamera { camera: preset_camera(name)?, guessed: false });
    }
    if opts.focal.is_none()
        && let Some(path) = source.camera_file()
    {
        let camera = colslam_camera::file::read_camera_file(&path)?;
        tracing::info!("camera from {}", path.display());
        return Ok(ResolvedCamera { camera, guessed: false });
    }
    let Some((w, h)) = source.image_size() else {
        let reason = "cannot tell the image size; give --camera or --preset".to_string();
        return Err(SlamError::Path { path: input.to_path_buf(), reason });
    };
    let guessed = opts.focal.is_none();
    let f = opts.focal.unwrap_or(DEFAULT_FOCAL_FACTOR * w.max(h) as f64);
    // OpenCV convention: the centre of a w-pixel row is at (w - 1) / 2.
    let camera = Camera::simple_pinhole(w as u64, h as u64, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    if guessed {
        tracing::warn!(
            "no calibration: focal length guessed as {f:.1} px (principal point at the centre) and refined by bundle \
             adjustment; give --camera, --preset or --focal for a known camera"
        );
    } else {
        tracing::info!("camera: focal {f:.1} px as given, principal point at the centre");
    }
    Ok(ResolvedCamera { camera, guessed })
}

/// What the driver knows before the first frame.
#[derive(Debug, Clone)]
pub struct RunStart {
    /// The camera (OpenCV pixel convention).
    pub camera: Camera,
    /// Frames the source will give, when known.
    pub frames: Option<usize>,
    /// A description of the source.
    pub description: String,
}

/// A hook called with a value of the run (see [`RunHooks`]).
pub type Hook<'a, T> = Box<dyn FnMut(&T) + 'a>;

/// Optional hooks into a run (a progress bar, the live viewer); the default
/// has none and costs nothing. Hooks run on the mapper's thread, so they must
/// not block.
#[derive(Default)]
pub struct RunHooks<'a> {
    /// Stop flags, checked before every frame: once one is set, no more
    /// frames are read and the run finishes with the frames so far (outputs
    /// are written as usual, and the report says where it stopped).
    pub cancel: Vec<Arc<AtomicBool>>,
    /// Called once before the first frame.
    pub on_start: Option<Hook<'a, RunStart>>,
    /// Called with every decoded frame before the pipeline processes it.
    pub before_frame: Option<Hook<'a, Frame>>,
    /// Called with the pipeline after every processed frame.
    pub after_frame: Option<Hook<'a, Slam>>,
}

impl<'a> RunHooks<'a> {
    /// These hooks, each followed by `other`'s; a stop flag of either stops
    /// the run (a front end's hooks and a caller's progress bar, say).
    pub fn then(mut self, other: RunHooks<'a>) -> Self {
        self.cancel.extend(other.cancel);
        Self {
            cancel: self.cancel,
            on_start: chain(self.on_start, other.on_start),
            before_frame: chain(self.before_frame, other.before_frame),
            after_frame: chain(self.after_frame, other.after_frame),
        }
    }

    /// True once a stop flag is set.
    pub fn cancelled(&self) -> bool {
        self.cancel.iter().any(|c| c.load(Ordering::SeqCst))
    }
}

/// Both hooks, `a` first.
fn chain<'a, T: 'a>(a: Option<Hook<'a, T>>, b: Option<Hook<'a, T>>) -> Option<Hook<'a, T>> {
    match (a, b) {
        (Some(mut a), Some(mut b)) => Some(Box::new(move |v: &T| {
            a(v);
            b(v);
        })),
        (a, b) => a.or(b),
    }
}

/// What a run produced.
#[derive(Debug)]
pub struct RunOutput {
    /// The report, as written to `report.json`.
    pub report: RunReport,
    /// The maps, poses and statistics.
    pub result: SlamResult,
}

/// A frame with its features, from the reader thread.
struct ExtractedFrame {
    frame: Frame,
    data: Result<FrameData, SlamError>,
    decode: Duration,
    features: Duration,
}

/// What the reader thread hands to the mapper.
enum Extracted {
    Frame(Box<ExtractedFrame>),
    Skipped { error: String, decode: Duration },
}

/// Runs the pipeline on `config.input` into `config.output`.
pub fn run(config: &RunConfig, events: EventSink, mut hooks: RunHooks<'_>) -> Result<RunOutput, SlamError> {
    let started = Instant::now();
    config.validate()?;
    let opts = &config.options;
    if opts.threads > 0 {
        // Fails only when a global pool already exists (a second run in one
        // process), which keeps the first setting.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(opts.threads).build_global();
    }
    let source = open_source(&config.input, &opts.source())?;
    let resolved = resolve_camera(&config.camera, &config.input, source.as_ref())?;
    let mut slam_opts = opts.slam.clone();
    // A guessed focal length is only a prior: bundle adjustment refines it.
    slam_opts.refine.refine_intrinsics |= resolved.guessed;
    let mut slam = Slam::new(slam_opts.clone(), &resolved.camera, events)?;
    if let Some(gt) = &config.gt {
        slam.set_debug_ground_truth(colslam_eval::trajectory::Trajectory::read_tum(gt)?);
    }
    std::fs::create_dir_all(&config.output).map_err(|source| SlamError::Io { path: config.output.clone(), source })?;
    tracing::info!("{}", source.describe());
    if let Some(f) = hooks.on_start.as_mut() {
        f(&RunStart { camera: resolved.camera.clone(), frames: source.len_hint(), description: source.describe() });
    }
    let fed = feed(&mut slam, source, &mut hooks)?;
    // A run that read nothing has nothing to write: empty outputs and a zero
    // exit status would hide that every frame failed.
    if fed.processed == 0 && fed.stopped_after.is_none() {
        return Err(SlamError::NoFramesRead {
            input: config.input.clone(),
            skipped: fed.skipped,
            first_error: fed.first_error.unwrap_or_else(|| "the source yielded none".into()),
        });
    }
    let stopped_after = fed.stopped_after;
    let mut result = slam.finish()?;
    let t = Instant::now();
    let format = if opts.text { OutputFormat::Text } else { OutputFormat::Binary };
    let input = config.input.display().to_string();
    let mut report = write_outputs(&result, &config.output, &input, &slam_opts, format)?;
    if let Some(gt) = &config.gt {
        report.eval = Some(evaluate(gt, &config.output)?);
    }
    result.timings.add(Stage::Output, t.elapsed());
    if let Some(n) = stopped_after {
        report.notes.push(format!("stopped on request after {n} frames"));
    }
    report.stopped_after = stopped_after;
    report.camera_guessed = resolved.guessed;
    report.timings_s = result.timings.clone();
    report.wall_time_s = started.elapsed().as_secs_f64();
    report.ms_per_frame = if report.frames > 0 { 1e3 * report.wall_time_s / report.frames as f64 } else { 0.0 };
    write_report(&report, &config.output)?;
    Ok(RunOutput { report, result })
}

/// ATE of `out/trajectory.tum` against `gt` (what `colslam eval` gives on
/// the written file), with a plot beside it.
fn evaluate(gt: &Path, out: &Path) -> Result<colslam_eval::EvalReport, SlamError> {
    let est = out.join("trajectory.tum");
    let report = colslam_eval::evaluate_files(gt, &est, &colslam_eval::EvalOptions::default())?;
    colslam_eval::plot::plot_evaluation(&report, &out.join("trajectory.eval.png"))?;
    Ok(report)
}

/// Feeds every frame of `source` to `slam`. Decoding and feature extraction
/// run up to [`PREFETCH_FRAMES`] frames ahead of the mapping on a thread of
/// their own, so the second core has work while the mapper runs its serial
/// parts; features are the same as on one thread, so the output is too.
/// Returns how many frames were processed and skipped, and whether a stop was requested.
fn feed(slam: &mut Slam, mut source: Box<dyn FrameSource>, hooks: &mut RunHooks<'_>) -> Result<Fed, SlamError> {
    let frontend = slam.frontend();
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Extracted>(PREFETCH_FRAMES);
        let producer = scope.spawn(move || {
            loop {
                let t = Instant::now();
                let Some(next) = source.next() else { break };
                let decode = t.elapsed();
                let item = match next {
                    Ok(frame) => {
                        let t = Instant::now();
                        let data = frontend.process(&frame);
                        Extracted::Frame(Box::new(ExtractedFrame { frame, data, decode, features: t.elapsed() }))
                    }
                    Err(e) => Extracted::Skipped { error: error_chain(&e), decode },
                };
                // The receiver is gone once the run stops early.
                if tx.send(item).is_err() {
                    break;
                }
            }
        });
        let fed = consume(slam, &rx, hooks);
        drop(rx);
        producer.join().map_err(|_| SlamError::ReaderPanicked)?;
        fed
    })
}

/// What [`feed`] did.
#[derive(Debug, Default)]
struct Fed {
    /// Frames given to the pipeline.
    processed: usize,
    /// Frames that could not be read (and were skipped).
    skipped: usize,
    /// The first skipped frame's error, with its causes.
    first_error: Option<String>,
    /// Frames processed when a stop was requested (`None`: ran to the end).
    stopped_after: Option<usize>,
}

/// `e` and its causes, joined by ": ".
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut msg = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        msg.push_str(": ");
        msg.push_str(&s.to_string());
        source = s.source();
    }
    msg
}

/// The mapper's side of [`feed`].
fn consume(
    slam: &mut Slam,
    rx: &std::sync::mpsc::Receiver<Extracted>,
    hooks: &mut RunHooks<'_>,
) -> Result<Fed, SlamError> {
    let mut fed = Fed::default();
    for item in rx.iter() {
        if hooks.cancelled() {
            fed.stopped_after = Some(fed.processed);
            return Ok(fed);
        }
        let ExtractedFrame { frame, data, decode, features } = match item {
            Extracted::Frame(f) => *f,
            Extracted::Skipped { error, decode } => {
                slam.add_time(Stage::Decode, decode);
                tracing::warn!("skipping a frame: {error}");
                fed.skipped += 1;
                fed.first_error.get_or_insert(error);
                continue;
            }
        };
        slam.add_time(Stage::Decode, decode);
        slam.add_time(Stage::Features, features);
        if let Some(f) = hooks.before_frame.as_mut() {
            f(&frame);
        }
        let in_frame =
            |e: SlamError| SlamError::Frame { index: frame.index, name: frame.name.clone(), source: Box::new(e) };
        slam.process_features(data.map_err(in_frame)?).map_err(in_frame)?;
        fed.processed += 1;
        if let Some(f) = hooks.after_frame.as_mut() {
            f(slam);
        }
    }
    Ok(fed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chained_hooks_run_in_order_and_either_flag_stops() {
        let calls = std::cell::RefCell::new(Vec::new());
        let (a, b) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
        let first = RunHooks {
            cancel: vec![Arc::clone(&a)],
            on_start: Some(Box::new(|_: &RunStart| calls.borrow_mut().push("first"))),
            ..RunHooks::default()
        };
        let then = RunHooks {
            cancel: vec![Arc::clone(&b)],
            on_start: Some(Box::new(|_: &RunStart| calls.borrow_mut().push("then"))),
            ..RunHooks::default()
        };
        let mut hooks = first.then(then);
        assert!(hooks.before_frame.is_none(), "no hook where neither has one");
        let start = RunStart {
            camera: Camera::simple_pinhole(640, 480, 500.0, 319.5, 239.5),
            frames: None,
            description: String::new(),
        };
        let mut on_start = hooks.on_start.take().unwrap_or_else(|| panic!("an on_start hook"));
        on_start(&start);
        on_start(&start);
        assert_eq!(*calls.borrow(), vec!["first", "then", "first", "then"]);
        assert!(!hooks.cancelled());
        b.store(true, Ordering::SeqCst);
        assert!(hooks.cancelled(), "the second flag stops the run");
        b.store(false, Ordering::SeqCst);
        a.store(true, Ordering::SeqCst);
        assert!(hooks.cancelled(), "the first flag stops the run");
        assert!(!RunHooks::default().then(RunHooks::default()).cancelled());
    }
}

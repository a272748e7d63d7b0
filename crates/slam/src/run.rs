//! The driver: a source end to end, as `colslam run`, the viewer and the
//! Python binding run it. It validates every option and takes the output
//! folder (checks it can be written, locks it and creates the staging folder
//! the outputs go into) before anything is read, opens the source, resolves
//! the camera, reads and extracts frames on a thread of their own ahead of
//! the mapper, feeds the pipeline, honours a stop request, writes the
//! outputs and then the report (with the evaluation when ground truth is
//! given) and swaps them into the output folder in one trip.

use crate::error::SlamError;
use crate::events::EventSink;
use crate::frame::FrameData;
use crate::options::SlamOptions;
use crate::output::{IntrinsicsSummary, OutputFormat, RunReport, begin_run_output, write_outputs, write_report};
use crate::pipeline::{Slam, SlamResult};
use crate::timing::Stage;
use colslam_camera::{Camera, presets};
use colslam_image::Image;
use colslam_image::OutputDir;
use colslam_io::exif::{self, ExifFocalKind};
use colslam_io::{Frame, FrameSource, SourceOptions, open_source};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Focal length prior for unknown cameras, as a multiple of the geometric
/// mean of the image sides, `sqrt(w h)` (see [`guessed_focal`]).
pub const DEFAULT_FOCAL_FACTOR: f64 = 1.0;

/// The focal length (pixels) an unknown `w` x `h` camera is guessed to
/// have: [`DEFAULT_FOCAL_FACTOR`] x `sqrt(w h)`, a field of view of 60 deg
/// across a 4:3 frame and 67 deg across a 16:9 one, as phones, webcams and
/// drones film. COLMAP's prior for photos, 1.2 x the larger side, reads
/// a wide crop (a rectified car camera at 3.3:1) as a telephoto: twice
/// the focal length, where a map made under the guess breaks before the
/// bundle adjustments can refine it (docs/benchmarks.md, "The focal length
/// guessed from the image area").
pub fn guessed_focal(w: f64, h: f64) -> f64 {
    DEFAULT_FOCAL_FACTOR * (w * h).sqrt()
}

/// Frames decoded and extracted ahead of the mapper (bounds the memory the
/// reader thread can hold: a VGA frame with its features is about 1.2 MB).
const PREFETCH_FRAMES: usize = 4;

/// Bytes of gray images kept from the run for the refinements that read
/// frames again after mapping (`--refine-observations`): every sequence of
/// the suite fits (KITTI's 300 frames are 140 MB), so a short sequence is
/// decoded once; a longer one reads the frames past the budget again.
const KEPT_FRAME_BYTES: usize = 256 << 20;

/// Gray images of the first frames the run read, up to [`KEPT_FRAME_BYTES`]
/// (shared by the run's feeding, which fills it, and [`SourceImages`],
/// which serves from it).
#[derive(Default)]
struct KeptFrames {
    frames: BTreeMap<usize, Image>,
    bytes: usize,
}

impl KeptFrames {
    /// Keeps frame `index`'s gray image if it fits in the budget.
    fn keep(&mut self, index: usize, image: &Image) {
        let bytes = image.width() * image.height();
        if self.bytes + bytes <= KEPT_FRAME_BYTES {
            self.bytes += bytes;
            self.frames.insert(index, image.to_gray());
        }
    }
}

/// Where the camera comes from. Without any, a camera file beside the input
/// is used, else the focal length is guessed and refined.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = "Camera"))]
#[serde(default, deny_unknown_fields)]
pub struct CameraOptions {
    /// Camera file (YAML or TOML; OpenCV, ORB-SLAM and EuRoC layouts). Default: camera.yaml beside the input.
    #[cfg_attr(feature = "cli", arg(long, value_name = "FILE", conflicts_with = "preset"))]
    pub camera: Option<PathBuf>,
    /// Built-in camera preset.
    #[cfg_attr(feature = "cli", arg(long, value_name = "NAME", value_parser = clap::builder::PossibleValuesParser::new(presets::preset_names())))]
    pub preset: Option<String>,
    /// Focal length in pixels of an unknown camera (principal point at the image centre).
    ///
    /// Kept as given; --refine-intrinsics refines it by bundle adjustment.
    #[cfg_attr(feature = "cli", arg(long, value_name = "PIXELS", conflicts_with_all = ["camera", "preset"]))]
    pub focal: Option<f64>,
    /// No calibration: estimate the focal length from the first N frames (0: guess and refine).
    ///
    /// With 0 the focal length is guessed as sqrt(width x height) pixels
    /// and refined by bundle adjustment. Off by default: where the first frames constrain the focal length, refining the guess by bundle
    /// adjustment ends as close and costs less; where they do not (forward motion), the guess is kept fixed.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = DEFAULT_FOCAL_SEARCH_FRAMES))]
    pub focal_search_frames: usize,
}

impl Default for CameraOptions {
    fn default() -> Self {
        Self { camera: None, preset: None, focal: None, focal_search_frames: DEFAULT_FOCAL_SEARCH_FRAMES }
    }
}

/// Frames the focal-length search of an uncalibrated run reconstructs
/// ([`crate::calibrate`]).
pub const DEFAULT_FOCAL_SEARCH_FRAMES: usize = 0;

impl CameraOptions {
    /// Whether bundle adjustment refines the intrinsics of a camera from
    /// `source`: with `--refine-intrinsics`, always for a guess, and for an
    /// estimate when the first frames constrained it (else it runs away
    /// under forward motion, as the guess does on the KITTI clip). A
    /// measured focal length (`--focal`, EXIF) is kept: refined from the
    /// first keyframes it runs away on the KITTI clip (984 to 22825 px, 40
    /// of 268 frames; docs/history.md).
    pub fn refines(&self, source: &CameraSource, refine_intrinsics: bool) -> bool {
        refine_intrinsics
            || match source {
                CameraSource::Guessed => true,
                CameraSource::Estimated { estimate } => !estimate.unconstrained(),
                _ => false,
            }
    }
}

/// The help heading of a run's input and output flags (the first group of
/// `colslam run --help`).
#[cfg(feature = "cli")]
const IO_HEADING: &str = "Input and output";

/// How the source is read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(next_help_heading = IO_HEADING))]
#[serde(default, deny_unknown_fields)]
pub struct InputOptions {
    /// Use every N-th frame, at least 1.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N", default_value_t = InputOptions::default().skip))]
    pub skip: usize,
    /// Process at most this many frames (after skip), at least 1. Default: all.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N"))]
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
    /// Worker threads (0: all cores). Not a flag of its own: the binary
    /// sets it from its global `--threads`, which every subcommand shares.
    #[cfg_attr(feature = "cli", arg(skip))]
    pub threads: usize,
    /// Write the COLMAP model as text instead of binary.
    #[cfg_attr(feature = "cli", arg(long, help_heading = IO_HEADING))]
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
    /// Output folder (created; a previous run's output there is replaced as a whole).
    #[cfg_attr(feature = "cli", arg(short, long, value_name = "DIR", help_heading = IO_HEADING))]
    pub output: PathBuf,
    /// Ground-truth trajectory (TUM format) to evaluate the result against.
    #[cfg_attr(feature = "cli", arg(long, value_name = "FILE", help_heading = IO_HEADING))]
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

    /// Checks that the output folder can be written now, as [`run`] does
    /// before its first frame (see [`begin_run_output`]): takes its lock and
    /// creates its staging folder, then releases both. For a front end that
    /// answers a request before it starts the run on a thread of its own.
    pub fn check_output(&self) -> Result<(), SlamError> {
        begin_run_output(&self.output).map(drop)
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

/// Where a run's camera came from (reported in `report.json`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum CameraSource {
    /// `--camera FILE`.
    File {
        /// The file.
        path: PathBuf,
    },
    /// `--preset NAME`.
    Preset {
        /// The preset.
        name: String,
    },
    /// A camera file found beside the input.
    BesideInput {
        /// The file.
        path: PathBuf,
    },
    /// `--focal F` with the principal point at the centre.
    Focal,
    /// The EXIF focal length of the first image, principal point at the centre.
    Exif {
        /// The image.
        path: PathBuf,
        /// The tags used: `35mm_equivalent` or `focal_plane`.
        tags: String,
    },
    /// No calibration: the focal length is [`guessed_focal`], refined by
    /// bundle adjustment.
    Guessed,
    /// No calibration (`--focal-search-frames N`): the focal length
    /// estimated from the first frames ([`crate::calibrate`]), principal
    /// point at the centre, refined by bundle adjustment; when the frames
    /// do not constrain it, the guess kept fixed; when their map is too
    /// small to judge, the guess refined.
    Estimated {
        /// The estimate and the candidates scored.
        #[serde(flatten)]
        estimate: crate::calibrate::FocalEstimate,
    },
}

/// The camera of a run and where it came from.
#[derive(Debug, Clone)]
pub struct ResolvedCamera {
    /// The calibration (OpenCV pixel convention, as camera files give it).
    pub camera: Camera,
    /// Where it came from.
    pub source: CameraSource,
    /// The rolling-shutter readout time a camera file gives (`readout_s`).
    pub readout_s: Option<f64>,
    /// The registered images a camera file's intrinsics were refined over
    /// (`refined_over`, as a run writes it when it refined them).
    pub refined_over: Option<usize>,
}

impl CameraSource {
    /// A focal length that is only a prior (given, read from EXIF or
    /// guessed), not a calibration.
    pub fn is_prior(&self) -> bool {
        matches!(self, Self::Focal | Self::Exif { .. } | Self::Guessed | Self::Estimated { .. })
    }
}

impl ResolvedCamera {
    /// The camera of a camera file, with what a run wrote beside it.
    fn from_file(file: colslam_camera::file::CameraFile, source: CameraSource) -> Self {
        Self { camera: file.camera, source, readout_s: file.readout_s, refined_over: file.refined_over }
    }

    /// No calibration was given: the focal length is a guess.
    pub fn guessed(&self) -> bool {
        self.source == CameraSource::Guessed
    }
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
        let file = colslam_camera::file::read_camera_file_report(path)?;
        tracing::info!("camera from {}", path.display());
        let source = CameraSource::File { path: path.clone() };
        return Ok(ResolvedCamera::from_file(file, source));
    }
    if let Some(name) = &opts.preset {
        tracing::info!("camera from the preset {name}");
        return Ok(ResolvedCamera {
            camera: preset_camera(name)?,
            source: CameraSource::Preset { name: name.clone() },
            readout_s: None,
            refined_over: None,
        });
    }
    if opts.focal.is_none()
        && let Some(path) = source.camera_file()
    {
        let file = colslam_camera::file::read_camera_file_report(&path)?;
        tracing::info!("camera from {}", path.display());
        let source = CameraSource::BesideInput { path };
        return Ok(ResolvedCamera::from_file(file, source));
    }
    let Some((w, h)) = source.image_size() else {
        let reason = "cannot tell the image size; give --camera or --preset".to_string();
        return Err(SlamError::Path { path: input.to_path_buf(), reason });
    };
    // OpenCV convention: the centre of a w-pixel row is at (w - 1) / 2.
    let centred = |f: f64| crate::calibrate::centred_camera(w as u32, h as u32, f);
    if opts.focal.is_none()
        && let Some(path) = source.first_image()
        && let Some((f, kind)) = exif::read_exif_focal(path).and_then(|e| e.focal_px(w, h))
    {
        let tags = match kind {
            ExifFocalKind::Equivalent35mm => "35mm_equivalent",
            ExifFocalKind::FocalPlane => "focal_plane",
        };
        tracing::info!(
            "camera: focal {f:.1} px from the EXIF block of {} ({tags}), principal point at the centre",
            path.display()
        );
        return Ok(ResolvedCamera {
            camera: centred(f),
            source: CameraSource::Exif { path: path.to_path_buf(), tags: tags.into() },
            readout_s: None,
            refined_over: None,
        });
    }
    let guessed = opts.focal.is_none();
    let f = opts.focal.unwrap_or_else(|| guessed_focal(w as f64, h as f64));
    let camera = centred(f);
    if guessed && opts.focal_search_frames > 0 {
        tracing::warn!(
            "no calibration: the focal length will be estimated from the first {} frames (principal point at the \
             centre); give --camera, --preset or --focal for a known camera",
            opts.focal_search_frames
        );
    } else if guessed {
        tracing::warn!(
            "no calibration: focal length guessed as {f:.1} px (principal point at the centre); give --camera, \
             --preset or --focal for a known camera"
        );
    } else {
        tracing::info!("camera: focal {f:.1} px as given, principal point at the centre");
    }
    let source = if guessed { CameraSource::Guessed } else { CameraSource::Focal };
    Ok(ResolvedCamera { camera, source, readout_s: None, refined_over: None })
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
    /// Interruption flag (Ctrl-C), checked before every frame and between
    /// the final stages: once set, the run ends with
    /// [`SlamError::Cancelled`] and writes nothing; its temporary files and
    /// staging folder are removed as it unwinds.
    pub interrupt: Option<Arc<AtomicBool>>,
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
            interrupt: self.interrupt.or(other.interrupt),
            on_start: chain(self.on_start, other.on_start),
            before_frame: chain(self.before_frame, other.before_frame),
            after_frame: chain(self.after_frame, other.after_frame),
        }
    }

    /// True once a stop flag is set.
    pub fn cancelled(&self) -> bool {
        self.cancel.iter().any(|c| c.load(Ordering::SeqCst))
    }

    /// True once the interruption flag is set.
    pub fn interrupted(&self) -> bool {
        self.interrupt.as_ref().is_some_and(|c| c.load(Ordering::SeqCst))
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

/// A camera file's readout time (`readout_s`, as a run writes it beside its
/// outputs) is compensated unless `--rolling-shutter` asks for something
/// else than the default (no compensation), so the file reproduces the run
/// it came from.
fn apply_file_readout(resolved: &ResolvedCamera, opts: &mut SlamOptions) {
    let Some(r) = resolved.readout_s.filter(|&r| r > 0.0) else { return };
    if opts.refine.rolling_shutter.is_on() {
        tracing::info!(
            "rolling shutter: --rolling-shutter {} replaces the camera file's readout {r} s",
            opts.refine.rolling_shutter
        );
        return;
    }
    tracing::info!("rolling shutter: readout {r} s from the camera file");
    opts.refine.rolling_shutter = crate::options::RollingShutter::Seconds(r);
}

/// Runs the pipeline on `config.input` into `config.output`.
pub fn run(config: &RunConfig, events: EventSink, mut hooks: RunHooks<'_>) -> Result<RunOutput, SlamError> {
    let started = Instant::now();
    config.validate()?;
    // A bad or busy output fails here, before any frame is read.
    let output = begin_run_output(&config.output)?;
    let opts = &config.options;
    if opts.threads > 0 {
        // Fails only when a global pool already exists (a second run in one
        // process), which keeps the first setting.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(opts.threads).build_global();
    }
    let mut source = open_source(&config.input, &opts.source())?;
    let mut resolved = resolve_camera(&config.camera, &config.input, source.as_ref())?;
    let prefix = estimate_camera(&mut resolved, config, source.as_mut(), &hooks)?;
    let mut slam_opts = opts.slam.clone();
    apply_file_readout(&resolved, &mut slam_opts);
    // A focal length that is only a prior is refined by bundle adjustment,
    // and so are intrinsics a run refined (a camera file's `refined_over`):
    // given back, the file reproduces that run.
    slam_opts.refine.refine_intrinsics =
        config.camera.refines(&resolved.source, slam_opts.refine.refine_intrinsics) || resolved.refined_over.is_some();
    // A focal length alone (`--focal`, EXIF) is no calibration of the lens:
    // it is kept as given, as before, so a written camera given back
    // reproduces the run; `--refine-intrinsics` refines it with the rest.
    if resolved.source.is_prior() {
        slam_opts.refine.refine_distortion = false;
    }
    if let Some(n) = resolved.refined_over {
        tracing::info!(
            "intrinsics: refined by bundle adjustment from the camera file's, held until a map has {n} images"
        );
    } else if slam_opts.refine.refine_intrinsics {
        tracing::info!("intrinsics: refined by bundle adjustment");
    } else if slam_opts.refines_distortion_of(&resolved.camera) {
        tracing::info!(
            "intrinsics: focal length kept as given, the first radial distortion term refined (--refine-distortion)"
        );
    } else if resolved.source.is_prior() {
        tracing::info!("intrinsics: kept as given (--refine-intrinsics refines them)");
    }
    // Records beyond the memory budget spill beside the output: the file
    // system the user chose for it, cleaned up with its staging folder.
    // Frames are kept only when a refinement will read them again.
    let kept = slam_opts.refines_observations().then(|| Arc::new(Mutex::new(KeptFrames::default())));
    let images = Box::new(SourceImages { input: config.input.clone(), options: opts.source(), kept: kept.clone() });
    let mut slam = Slam::new(slam_opts.clone(), &resolved.camera, events)?
        .with_spill(output.scratch_prefix())
        .with_frame_images(images)
        .with_camera_support(resolved.refined_over.unwrap_or(0));
    if let Some(flag) = &hooks.interrupt {
        slam.set_interrupt(flag.clone());
    }
    if let Some(gt) = &config.gt {
        slam.set_debug_ground_truth(colslam_eval::trajectory::Trajectory::read_tum(gt)?);
    }
    tracing::info!("{}", source.describe());
    if let Some(f) = hooks.on_start.as_mut() {
        f(&RunStart { camera: resolved.camera.clone(), frames: source.len_hint(), description: source.describe() });
    }
    let fed = feed(&mut slam, prefix, source, kept.as_deref(), &mut hooks)?;
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
    if stopped_after.is_none() {
        note_unknown_calibration(&resolved.source, &mut result);
    }
    let focal_start = 0.5 * (resolved.camera.focal_x() + resolved.camera.focal_y());
    let end =
        RunEnd { options: &slam_opts, stopped_after, camera_source: resolved.source.clone(), focal_start, started };
    let report = publish(output, config, &end, &mut result)?;
    Ok(RunOutput { report, result })
}

/// The run's input opened again for a second pass over chosen frames
/// (`--refine-observations`): frames the run kept are served from memory;
/// for the others an image folder reads only those files, a video is
/// decoded again up to the last.
struct SourceImages {
    input: PathBuf,
    options: SourceOptions,
    kept: Option<Arc<Mutex<KeptFrames>>>,
}

impl crate::FrameImages for SourceImages {
    fn read(
        &mut self,
        frames: &[usize],
        visit: &mut dyn FnMut(usize, Result<colslam_image::Image, String>),
    ) -> Result<(), SlamError> {
        // Opened on the first frame not kept.
        let mut source = None;
        // The index of the frame the source yields next.
        let mut next = 0;
        for &want in frames {
            // A poisoned lock (a panic elsewhere) only loses the kept frames.
            let kept = self.kept.as_ref().and_then(|k| k.lock().ok().and_then(|k| k.frames.get(&want).cloned()));
            if let Some(image) = kept {
                visit(want, Ok(image));
                continue;
            }
            let source = match &mut source {
                Some(s) => s,
                None => source.insert(open_source(&self.input, &self.options)?),
            };
            let Some(skip) = want.checked_sub(next) else {
                visit(want, Err("frames were asked out of order".into()));
                continue;
            };
            next = want + 1;
            match source.nth(skip) {
                None => visit(want, Err("the input ended before it".into())),
                Some(Err(e)) => visit(want, Err(crate::error::error_chain(&e))),
                Some(Ok(f)) if f.index != want => {
                    visit(want, Err(format!("the input gave frame {} in its place", f.index)))
                }
                Some(Ok(f)) => visit(want, Ok(f.image)),
            }
        }
        Ok(())
    }
}

/// Without calibration (a guessed focal length) and with
/// `--focal-search-frames N` above 0, reads and extracts the first N frames
/// and estimates the focal length from them ([`crate::calibrate`]); the
/// camera becomes the estimate. Returns the frames read, for the pipeline
/// to process first. A stop requested meanwhile leaves the guess.
fn estimate_camera(
    resolved: &mut ResolvedCamera,
    config: &RunConfig,
    source: &mut dyn FrameSource,
    hooks: &RunHooks<'_>,
) -> Result<Vec<Extracted>, SlamError> {
    let n = config.camera.focal_search_frames;
    if !resolved.guessed() || n == 0 {
        return Ok(Vec::new());
    }
    let frontend = crate::frontend::Frontend::new(&config.options.slam.frontend, &resolved.camera)?;
    let mut prefix = Vec::new();
    let mut frames = Vec::new();
    while frames.len() < n && !hooks.cancelled() {
        let t = Instant::now();
        let Some(next) = source.next() else { break };
        let decode = t.elapsed();
        match next {
            Ok(frame) => {
                let t = Instant::now();
                let data = frontend.process(&frame);
                if let Ok(d) = &data {
                    frames.push(d.clone());
                }
                prefix.push(Extracted::Frame(Box::new(ExtractedFrame { frame, data, decode, features: t.elapsed() })));
            }
            Err(e) => prefix.push(Extracted::Skipped { error: crate::error::error_chain(&e), decode }),
        }
    }
    if hooks.cancelled() {
        return Ok(prefix);
    }
    let (w, h) = (resolved.camera.width as u32, resolved.camera.height as u32);
    let t = Instant::now();
    let start = resolved.camera.focal_x();
    let estimate = crate::calibrate::estimate_focal(&frames, w, h, start, &config.options.slam)?;
    let Some(estimate) = estimate else {
        tracing::warn!("focal search: no candidate made a map of the first {} frames; keeping the guess", frames.len());
        return Ok(prefix);
    };
    if estimate.unconstrained() {
        tracing::warn!(
            "focal search: the first {} frames do not constrain the focal length (sharpness {:.4}: a forward or \
             planar motion); it is kept at the guess {start:.1} px and not refined; give --focal or --camera",
            frames.len(),
            estimate.sharpness
        );
    } else if !estimate.constrained() {
        tracing::warn!(
            "focal search: the map of the first {} frames is too small to judge the estimate ({} keyframes); the \
             guess {start:.1} px is refined by bundle adjustment",
            frames.len(),
            estimate.keyframes
        );
    } else {
        tracing::info!(
            "camera: focal {:.1} px estimated from the first {} frames in {:.1} s (sharpness {:.4}; principal point at \
             the centre)",
            estimate.focal_px,
            frames.len(),
            t.elapsed().as_secs_f64(),
            estimate.sharpness
        );
        resolved.camera = crate::calibrate::centred_camera(w, h, estimate.focal_px);
    }
    resolved.source = CameraSource::Estimated { estimate };
    Ok(prefix)
}

/// Says so, in the log and the report's notes, when a camera without
/// calibration (`--focal`, EXIF, the guess) could not be estimated because
/// no map could be made: a static camera or a pure rotation has no
/// parallax, so neither the map nor the focal length is observable, and
/// the run must say what to pass rather than leave an empty or wrong map
/// unexplained.
fn note_unknown_calibration(source: &CameraSource, result: &mut SlamResult) {
    if !source.is_prior() || !result.maps.is_empty() {
        return;
    }
    let note = "calibration could not be estimated: no map could be made (the frames show no parallax: a static \
                camera or a pure rotation); give the camera with --camera FILE or --preset NAME, or its focal \
                length with --focal PIXELS, and a part of the video where the camera moves";
    tracing::warn!("{note}");
    result.stats.notes.push(note.to_string());
}

/// The focal length's story for the report and the log: where it started,
/// where it ended, whether it was refined and over how many keyframes.
fn intrinsics_summary(end: &RunEnd<'_>, report: &RunReport) -> Option<IntrinsicsSummary> {
    let focal_end = *report.camera.params.first()?;
    let refined = end.options.refine.refine_intrinsics;
    let summary = IntrinsicsSummary {
        refined,
        focal_start_px: end.focal_start,
        focal_end_px: focal_end,
        keyframes: report.keyframes,
    };
    if refined {
        let change = 100.0 * (focal_end / end.focal_start - 1.0);
        tracing::info!(
            "camera: focal {focal_end:.1} px, refined over {} keyframes from {:.1} px ({change:+.1} %)",
            report.keyframes,
            end.focal_start
        );
    }
    Some(summary)
}

/// What the report says of a finished run besides its result.
struct RunEnd<'a> {
    options: &'a SlamOptions,
    stopped_after: Option<usize>,
    camera_source: CameraSource,
    focal_start: f64,
    started: Instant,
}

/// Writes the outputs of a finished run and its report into `output`'s
/// staging folder and swaps them into the output folder.
fn publish(
    output: OutputDir,
    config: &RunConfig,
    end: &RunEnd<'_>,
    result: &mut SlamResult,
) -> Result<RunReport, SlamError> {
    let t = Instant::now();
    let dir = output.path();
    let format = if config.options.text { OutputFormat::Text } else { OutputFormat::Binary };
    let input = config.input.display().to_string();
    let mut report = write_outputs(result, dir, &input, end.options, format)?;
    if let Some(gt) = &config.gt {
        report.eval = Some(evaluate(gt, dir, output.target())?);
    }
    result.timings.add(Stage::Output, t.elapsed());
    if let Some(n) = end.stopped_after {
        report.notes.push(format!("stopped on request after {n} frames"));
    }
    report.stopped_after = end.stopped_after;
    report.camera_guessed = matches!(end.camera_source, CameraSource::Guessed | CameraSource::Estimated { .. });
    report.camera_source = Some(end.camera_source.clone());
    report.intrinsics = intrinsics_summary(end, &report);
    report.timings_s = result.timings.clone();
    report.wall_time_s = end.started.elapsed().as_secs_f64();
    report.ms_per_frame = if report.frames > 0 { 1e3 * report.wall_time_s / report.frames as f64 } else { 0.0 };
    write_report(&report, dir)?;
    output.commit()?;
    Ok(report)
}

/// ATE of `out/trajectory.tum` against `gt` (what `colslam eval` gives on
/// the written file), with a plot beside it. `out` is the staging folder;
/// the report names the file where it will be, in `target`.
fn evaluate(gt: &Path, out: &Path, target: &Path) -> Result<colslam_eval::EvalReport, SlamError> {
    let est = out.join("trajectory.tum");
    let mut report = colslam_eval::evaluate_files(gt, &est, &colslam_eval::EvalOptions::default())?;
    report.estimate = target.join("trajectory.tum").display().to_string();
    colslam_eval::plot::plot_evaluation(&report, &out.join("trajectory.eval.png"))?;
    Ok(report)
}

/// Feeds every frame of `source` to `slam`. Decoding and feature extraction
/// run up to [`PREFETCH_FRAMES`] frames ahead of the mapping on a thread of
/// their own, so the second core has work while the mapper runs its serial
/// parts; features are the same as on one thread, so the output is too.
/// Returns how many frames were processed and skipped, and whether a stop was requested.
fn feed(
    slam: &mut Slam,
    prefix: Vec<Extracted>,
    mut source: Box<dyn FrameSource>,
    kept: Option<&Mutex<KeptFrames>>,
    hooks: &mut RunHooks<'_>,
) -> Result<Fed, SlamError> {
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
                    Err(e) => Extracted::Skipped { error: crate::error::error_chain(&e), decode },
                };
                // The receiver is gone once the run stops early.
                if tx.send(item).is_err() {
                    break;
                }
            }
        });
        let fed = consume(slam, prefix.into_iter().chain(rx.iter()), kept, hooks);
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

/// The mapper's side of [`feed`].
fn consume(
    slam: &mut Slam,
    items: impl Iterator<Item = Extracted>,
    kept: Option<&Mutex<KeptFrames>>,
    hooks: &mut RunHooks<'_>,
) -> Result<Fed, SlamError> {
    let mut fed = Fed::default();
    for item in items {
        if hooks.interrupted() {
            return Err(SlamError::Cancelled { frame: fed.processed });
        }
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
        if let Some(mut k) = kept.and_then(|k| k.lock().ok()) {
            k.keep(frame.index, &frame.image);
        }
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
    use colslam_image::{OutputError, fault};

    /// A synthetic image sequence on disk (plain PNG folder) of `n` frames.
    fn sequence(dir: &Path, n: usize) -> PathBuf {
        let opts = colslam_synth::SynthOptions {
            frames: n,
            width: 160,
            height: 120,
            focal: 131.25,
            seed: 5,
            ..colslam_synth::SynthOptions::default()
        };
        let seq = colslam_synth::SyntheticSequence::new(&opts).unwrap_or_else(|e| panic!("sequence: {e}"));
        let input = dir.join("seq");
        std::fs::create_dir_all(&input).unwrap_or_else(|e| panic!("mkdir: {e}"));
        for i in 0..n {
            let img = seq.render(i).unwrap_or_else(|e| panic!("render: {e}"));
            img.write_png(&input.join(format!("{i:06}.png"))).unwrap_or_else(|e| panic!("png: {e}"));
        }
        input
    }

    fn config(input: &Path, output: &Path, max_frames: usize, text: bool) -> RunConfig {
        let mut c = RunConfig::new(input, output);
        c.camera.focal = Some(131.25);
        c.options.input.max_frames = Some(max_frames);
        c.options.text = text;
        c
    }

    /// Names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .map(|r| r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
            .unwrap_or_default();
        v.sort();
        v
    }

    fn poses_in(path: &Path) -> usize {
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()).count()
    }

    /// The output folder holds one whole run: a model that loads, and a
    /// report and trajectories that agree with it. Returns its frame count.
    fn assert_one_whole_run(out: &Path, context: &str) -> u64 {
        let rec = colslam_scene::read_model(out).unwrap_or_else(|e| panic!("{context}: no model: {e}"));
        let text = std::fs::read_to_string(out.join("report.json")).unwrap_or_else(|e| panic!("{context}: {e}"));
        let report: serde_json::Value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{context}: {e}"));
        let n = |k: &str| report[k].as_u64().unwrap_or_else(|| panic!("{context}: report.{k}"));
        assert!(n("keyframes") >= 2, "{context}: a model to check");
        assert_eq!(rec.num_registered_images() as u64, n("keyframes"), "{context}: model vs report");
        assert_eq!(rec.num_points3d() as u64, n("points"), "{context}: model vs report");
        assert_eq!(poses_in(&out.join("trajectory.tum")) as u64, n("localized"), "{context}: trajectory vs report");
        assert_eq!(poses_in(&out.join("keyframes.tum")) as u64, n("keyframes"), "{context}: keyframes vs report");
        let files = names(out);
        let one_format = files.iter().filter(|f| f.ends_with(".bin") || f.ends_with(".txt")).count() == 5;
        assert!(one_format, "{context}: model files of one run and format: {files:?}");
        n("frames")
    }

    #[test]
    fn frames_kept_from_the_run_are_served_from_memory_and_the_rest_read_again() {
        use crate::FrameImages;
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(root.path(), 6);
        let from_disk = |i: usize| {
            colslam_image::Image::read(&input.join(format!("{i:06}.png")))
                .unwrap_or_else(|e| panic!("read: {e}"))
                .to_gray()
        };
        // Marked copies of frames 1 and 3 (black), so a frame served from
        // memory is told from one read again.
        let mut kept = KeptFrames::default();
        for i in [1, 3] {
            let mut black = from_disk(i);
            black.data_mut().fill(0);
            kept.keep(i, &black);
        }
        assert_eq!(kept.bytes, 2 * 160 * 120, "gray bytes counted");
        let mut images = SourceImages {
            input: input.clone(),
            options: SourceOptions::default(),
            kept: Some(Arc::new(Mutex::new(kept))),
        };
        let mut seen = Vec::new();
        images
            .read(&[0, 1, 3, 4], &mut |i, image| {
                let image = image.unwrap_or_else(|e| panic!("frame {i}: {e}"));
                seen.push((i, image.data().iter().all(|&v| v == 0), image.to_gray() == from_disk(i)));
            })
            .unwrap_or_else(|e| panic!("read: {e}"));
        assert_eq!(seen, [(0, false, true), (1, true, false), (3, true, false), (4, false, true)]);
        // Past the budget nothing more is kept.
        let mut full = KeptFrames { bytes: KEPT_FRAME_BYTES, ..KeptFrames::default() };
        full.keep(0, &from_disk(0));
        assert!(full.frames.is_empty());
    }

    #[test]
    fn a_run_killed_at_any_output_step_leaves_one_whole_run() {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(root.path(), 20);
        let out = root.path().join("out");
        // Two different runs (frames, format) into one folder.
        let (a, b) = (config(&input, &out, 20, false), config(&input, &out, 14, true));
        // A second run started while the first runs is refused at once.
        let second_run = std::cell::RefCell::new(None);
        let missing = root.path().join("missing");
        let concurrent = RunHooks {
            on_start: Some(Box::new(|_: &RunStart| {
                let r = run(&config(&missing, &out, 5, false), EventSink::none(), RunHooks::default());
                *second_run.borrow_mut() = Some(r.map(|_| ()));
            })),
            ..RunHooks::default()
        };
        let mut first = run(&a, EventSink::none(), concurrent).unwrap_or_else(|e| panic!("run: {e}"));
        let refused = second_run.borrow_mut().take();
        assert!(matches!(refused, Some(Err(SlamError::Output(OutputError::Locked { .. })))), "{refused:?}");
        assert_eq!(assert_one_whole_run(&out, "first run"), 20);
        let mut second = run(&b, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(assert_one_whole_run(&out, "second run"), 14);
        assert_eq!(names(root.path()), ["out", "seq"], "nothing beside the output");
        // The output steps of the driver (what `run` does after its last frame).
        let opts = a.options.slam.clone();
        let publish_run = |c: &RunConfig, r: &mut SlamResult| -> Result<RunReport, SlamError> {
            let end = RunEnd {
                options: &opts,
                stopped_after: None,
                camera_source: CameraSource::Focal,
                focal_start: 500.0,
                started: Instant::now(),
            };
            publish(begin_run_output(&c.output)?, c, &end, r)
        };
        let mut runs = [(&a, &mut first.result, 20), (&b, &mut second.result, 14)];
        let mut steps = usize::MAX;
        for (c, r, _) in runs.iter_mut() {
            fault::kill_at(Some(usize::MAX));
            publish_run(c, r).unwrap_or_else(|e| panic!("publish: {e}"));
            steps = steps.min(fault::steps());
            fault::kill_at(None);
        }
        assert!(steps >= 20, "{steps} file-system steps");
        // The folder holds the second run; each step kills a run of the
        // other, then that run is done again in full.
        for k in 0..steps {
            let (previous, next) = if k % 2 == 0 { (14, 0) } else { (20, 1) };
            let (c, r, frames) = &mut runs[next];
            fault::kill_at(Some(k));
            assert!(publish_run(c, r).is_err(), "step {k}: the kill stops the run");
            fault::kill_at(None);
            let found = assert_one_whole_run(&out, &format!("killed at step {k}"));
            assert!(found == previous || found == *frames, "step {k}: {found} frames");
            // The next run cleans up whatever the killed one left.
            publish_run(c, r).unwrap_or_else(|e| panic!("step {k}: next run: {e}"));
            assert_eq!(assert_one_whole_run(&out, &format!("after step {k}")), *frames);
            assert_eq!(names(root.path()), ["out", "seq"], "step {k}: leftovers beside the output");
        }
        // A whole run killed at its first file-system step fails before it
        // reads a frame (as on a read-only file system).
        let frames = std::cell::Cell::new(0usize);
        let hooks =
            RunHooks { before_frame: Some(Box::new(|_: &Frame| frames.set(frames.get() + 1))), ..RunHooks::default() };
        fault::kill_at(Some(0));
        let e = run(&a, EventSink::none(), hooks);
        fault::kill_at(None);
        assert!(matches!(e, Err(SlamError::Output(OutputError::Io { .. }))), "{e:?}");
        assert_eq!(frames.get(), 0, "the output is checked before the first frame");
    }

    /// Asserts that the files `names` of two runs' folders are identical.
    fn assert_same_files(first: &Path, second: &Path, names: &[&str]) {
        for name in names {
            let read = |dir: &Path| std::fs::read(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(read(first) == read(second), "{name} differs when the written camera is given back");
        }
    }

    /// A temporary folder (kept alive by the first value) with a 20-frame
    /// sequence and the output folders of a first run and of a second run
    /// given what the first wrote.
    fn two_runs() -> (tempfile::TempDir, PathBuf, PathBuf, PathBuf) {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(root.path(), 20);
        let (first, second) = (root.path().join("first"), root.path().join("second"));
        (root, input, first, second)
    }

    #[test]
    fn the_written_camera_file_reproduces_the_run() {
        let (_root, input, first, second) = two_runs();
        let a = run(&config(&input, &first, 20, false), EventSink::none(), RunHooks::default())
            .unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(a.report.camera_source, Some(CameraSource::Focal));
        let written = first.join("camera.yaml");
        let camera = colslam_camera::file::read_camera_file(&written).unwrap_or_else(|e| panic!("camera.yaml: {e}"));
        // The pinhole of `--focal 131.25` at the centre, in OpenCV's convention.
        assert_eq!((camera.width, camera.height), (160, 120));
        assert_eq!(camera.params, [131.25, 79.5, 59.5]);
        let mut c = config(&input, &second, 20, false);
        c.camera = CameraOptions { camera: Some(written.clone()), ..CameraOptions::default() };
        // A camera file without distortion terms has its radial term refined
        // by default; the first run held it (a focal length alone).
        c.options.slam.refine.refine_distortion = false;
        let b = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(b.report.camera_source, Some(CameraSource::File { path: written }));
        assert_same_files(
            &first,
            &second,
            &["trajectory.tum", "cameras.bin", "images.bin", "points3D.bin", "camera.yaml"],
        );
    }

    #[test]
    fn the_camera_a_run_refined_is_refined_again_from_its_file() {
        let (_root, input, first, second) = two_runs();
        let mut c = config(&input, &first, 20, false);
        c.camera.focal = None;
        let a = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(a.report.camera_source, Some(CameraSource::Guessed));
        let written = first.join("camera.yaml");
        let file = colslam_camera::file::read_camera_file_report(&written).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.refined_over, Some(a.report.keyframes), "the keyframes of the map that refined it");
        let mut c = config(&input, &second, 20, false);
        c.camera = CameraOptions { camera: Some(written.clone()), ..CameraOptions::default() };
        let b = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        // Refined again as the first run did, not held with a radial term
        // added as a calibration without distortion terms would be.
        assert!(b.report.options.refine.refine_intrinsics);
        let again = colslam_camera::file::read_camera_file_report(&second.join("camera.yaml"))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(again.camera.model, file.camera.model);
        assert!(again.refined_over.is_some());
        let start = b.report.intrinsics.as_ref().map(|i| i.focal_start_px);
        assert_eq!(start, Some(file.camera.focal_x()), "from where the first run ended");
        assert!(b.report.localized >= a.report.localized, "{} then {}", a.report.localized, b.report.localized);
    }

    #[test]
    fn the_written_camera_file_carries_the_readout() {
        let (_root, input, first, second) = two_runs();
        let mut c = config(&input, &first, 20, false);
        c.options.slam.refine.rolling_shutter = crate::options::RollingShutter::Seconds(0.02);
        let a = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(a.report.camera.readout_s, 0.02);
        let written = first.join("camera.yaml");
        let file = colslam_camera::file::read_camera_file_report(&written).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.readout_s, Some(0.02));
        // Given back with the default options, the file's readout is compensated.
        let mut c = config(&input, &second, 20, false);
        c.camera = CameraOptions { camera: Some(written), ..CameraOptions::default() };
        c.options.slam.refine.refine_distortion = false;
        let b = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        assert_eq!(b.report.options.refine.rolling_shutter, crate::options::RollingShutter::Seconds(0.02));
        assert_same_files(&first, &second, &["trajectory.tum", "images.bin", "points3D.bin", "camera.yaml"]);
    }

    #[test]
    fn a_given_focal_is_kept_unless_refinement_is_asked() {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(root.path(), 20);
        let mut c = config(&input, &root.path().join("free"), 20, false);
        c.options.slam.refine.refine_intrinsics = true;
        let free = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        let i = free.report.intrinsics.clone().unwrap_or_else(|| panic!("no intrinsics in the report"));
        assert!(i.refined, "{i:?}");
        assert_eq!(i.focal_start_px, 131.25);
        assert!(i.focal_end_px != 131.25, "refined: {i:?}");
        let fixed = run(&config(&input, &root.path().join("fixed"), 20, false), EventSink::none(), RunHooks::default())
            .unwrap_or_else(|e| panic!("run: {e}"));
        let i = fixed.report.intrinsics.clone().unwrap_or_else(|| panic!("no intrinsics in the report"));
        assert!(!i.refined && i.focal_end_px == 131.25, "{i:?}");
        // Only a guess is refined without being asked.
        let o = CameraOptions::default();
        assert!(o.refines(&CameraSource::Guessed, false));
        let exif = CameraSource::Exif { path: "a.jpg".into(), tags: "35mm_equivalent".into() };
        for source in [CameraSource::Focal, exif, CameraSource::Preset { name: "x".into() }] {
            assert!(!o.refines(&source, false) && o.refines(&source, true), "{source:?}");
        }
    }

    #[test]
    fn a_photo_folder_takes_its_focal_length_from_exif() {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let dir = root.path().join("photos");
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        // An EXIF block (28 mm equivalent) and a frame header of 640x480.
        let mut jpeg = exif::exif_jpeg_head(Some((50, 10)), Some(28), None);
        jpeg.extend([0xFF, 0xC0, 0, 17, 8, 0x01, 0xE0, 0x02, 0x80, 3]);
        jpeg.extend([1, 0x22, 0, 2, 0x11, 1, 3, 0x11, 1, 0xFF, 0xD9]);
        for name in ["0000.jpg", "0001.jpg"] {
            std::fs::write(dir.join(name), &jpeg).unwrap_or_else(|e| panic!("{e}"));
        }
        let source = open_source(&dir, &SourceOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        let r = resolve_camera(&CameraOptions::default(), &dir, source.as_ref()).unwrap_or_else(|e| panic!("{e}"));
        let want = CameraSource::Exif { path: dir.join("0000.jpg"), tags: "35mm_equivalent".into() };
        assert_eq!(r.source, want);
        assert!((r.camera.focal_x() - 28.0 * 640.0 / 36.0).abs() < 1e-9, "{:?}", r.camera);
        // A given focal length wins over EXIF.
        let given = CameraOptions { focal: Some(400.0), ..CameraOptions::default() };
        let r = resolve_camera(&given, &dir, source.as_ref()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((r.source, r.camera.focal_x()), (CameraSource::Focal, 400.0));
    }

    #[test]
    fn a_static_camera_without_calibration_says_what_to_pass() {
        // A pure rotation is not caught yet: it makes a small wrong map
        // (docs/history.md, issue 16); a static camera makes none.
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let opts = colslam_synth::SynthOptions { frames: 2, width: 160, height: 120, seed: 5, ..Default::default() };
        let seq = colslam_synth::SyntheticSequence::new(&opts).unwrap_or_else(|e| panic!("sequence: {e}"));
        let input = root.path().join("static");
        std::fs::create_dir_all(&input).unwrap_or_else(|e| panic!("mkdir: {e}"));
        let image = seq.render(0).unwrap_or_else(|e| panic!("render: {e}"));
        for i in 0..25 {
            image.write_png(&input.join(format!("{i:06}.png"))).unwrap_or_else(|e| panic!("png: {e}"));
        }
        let said = |c: &RunConfig| {
            let r = run(c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
            assert!(r.result.maps.is_empty(), "no map from a static camera");
            r.report.notes.iter().any(|n| n.contains("calibration could not be estimated") && n.contains("--camera"))
        };
        assert!(said(&RunConfig::new(&input, root.path().join("guessed"))), "the guess is named");
        // A calibrated camera needs no calibration advice.
        let mut calibrated = RunConfig::new(&input, root.path().join("preset"));
        calibrated.camera.camera = Some(root.path().join("camera.yaml"));
        let camera = Camera::pinhole(160, 120, 131.25, 131.25, 79.5, 59.5);
        std::fs::write(root.path().join("camera.yaml"), colslam_camera::file::to_yaml_string(&camera))
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(!said(&calibrated));
    }

    #[test]
    fn the_evaluation_names_the_published_trajectory() {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(root.path(), 20);
        let out = root.path().join("out");
        run(&config(&input, &out, 20, false), EventSink::none(), RunHooks::default())
            .unwrap_or_else(|e| panic!("run: {e}"));
        let gt = root.path().join("gt.tum");
        std::fs::copy(out.join("trajectory.tum"), &gt).unwrap_or_else(|e| panic!("copy: {e}"));
        let mut c = config(&input, &out, 20, false);
        c.gt = Some(gt);
        let r = run(&c, EventSink::none(), RunHooks::default()).unwrap_or_else(|e| panic!("run: {e}"));
        let eval = r.report.eval.unwrap_or_else(|| panic!("no evaluation"));
        // Not the staging folder the file was evaluated in before the swap.
        assert_eq!(eval.estimate, out.join("trajectory.tum").display().to_string());
        assert!(eval.ate_rmse < 1e-6, "the same trajectory: {}", eval.ate_rmse);
        let text = std::fs::read_to_string(out.join("report.json")).unwrap_or_else(|e| panic!("{e}"));
        assert!(!text.contains("staging"), "report.json names a staging folder");
    }

    #[test]
    fn bad_or_busy_outputs_fail_before_the_input_is_read() {
        let root = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let file = root.path().join("file");
        std::fs::write(&file, "x").unwrap_or_else(|e| panic!("{e}"));
        // A missing input: only the output is looked at first.
        let missing = root.path().join("missing");
        let err = |out: &Path| match run(&config(&missing, out, 5, false), EventSink::none(), RunHooks::default()) {
            Err(e) => e,
            Ok(_) => panic!("a run into {} succeeded", out.display()),
        };
        assert!(matches!(err(&file), SlamError::Path { .. }));
        let e = err(&file.join("out"));
        assert!(matches!(e, SlamError::Output(OutputError::UnderFile { .. })), "{e}");
        assert!(e.to_string().contains("is a file"), "{e}");
        // A folder of other files is not a run's to replace.
        let photos = root.path().join("photos");
        std::fs::create_dir(&photos).unwrap_or_else(|e| panic!("{e}"));
        std::fs::write(photos.join("a.jpg"), "x").unwrap_or_else(|e| panic!("{e}"));
        let e = err(&photos);
        assert!(matches!(e, SlamError::Output(OutputError::Foreign { .. })), "{e}");
        assert_eq!(names(&photos), ["a.jpg"]);
        // A second run into a folder another run is writing is refused.
        let out = root.path().join("out");
        let busy = begin_run_output(&out).unwrap_or_else(|e| panic!("{e}"));
        let e = err(&out);
        assert!(matches!(e, SlamError::Output(OutputError::Locked { .. })), "{e}");
        assert!(e.to_string().contains("another process"), "{e}");
        let config = config(&missing, &out, 5, false);
        assert!(config.check_output().is_err(), "the check sees the lock too");
        drop(busy);
        config.check_output().unwrap_or_else(|e| panic!("free again: {e}"));
        assert_eq!(names(root.path()), ["file", "photos"], "the checks leave nothing behind");
    }

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

    /// An error in the middle of a run (here an interruption, as Ctrl-C
    /// sends it) ends it with `Cancelled`, and the record store it had
    /// spilled to, its staging folder and its lock are gone.
    #[test]
    fn an_interrupted_run_leaves_no_record_store() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
        let input = sequence(dir.path(), 30);
        let out = dir.path().join("out");
        let mut c = config(&input, &out, 30, false);
        c.options.slam.refine.record_memory = 0;
        let flag = Arc::new(AtomicBool::new(false));
        let (seen, setter, count) = (std::cell::RefCell::new(None), flag.clone(), std::cell::Cell::new(0));
        let hooks = RunHooks {
            interrupt: Some(flag),
            after_frame: Some(Box::new(|_: &Slam| {
                count.set(count.get() + 1);
                let stores: Vec<String> =
                    names(dir.path()).into_iter().filter(|n| n.starts_with(".out.scratch-")).collect();
                if !stores.is_empty() && seen.borrow().is_none() {
                    *seen.borrow_mut() = Some((count.get(), stores));
                    setter.store(true, Ordering::SeqCst);
                }
            })),
            ..RunHooks::default()
        };
        let r = run(&c, EventSink::none(), hooks);
        let (frame, stores) = seen.into_inner().unwrap_or_else(|| panic!("the run never spilled a record"));
        assert_eq!(stores.len(), 1, "{stores:?}");
        assert!(matches!(r, Err(SlamError::Cancelled { frame: f }) if f == frame), "{r:?}");
        assert_eq!(names(dir.path()), ["seq"], "no record store, staging folder, lock or output left");
    }
}

//! The viewer's own update types (what a pipeline sends to the page) and the
//! run settings / controller the page's Run and Stop buttons drive.

use colslam_geometry::Rigid3;
use colslam_image::Image;
use colslam_scene::{Image as SceneImage, Reconstruction};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One map point as the viewer shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewerPoint {
    /// The 3D point id (COLMAP `POINT3D_ID`).
    pub id: u64,
    /// World position.
    pub xyz: [f64; 3],
    /// RGB colour.
    pub color: [u8; 3],
    /// Ids of the images observing it, each once, sorted ascending. The page
    /// derives a point's "introduced at" registration order from these (the
    /// smallest order among its registered observers).
    pub observers: Vec<u32>,
}

impl ViewerPoint {
    /// The viewer's copy of a reconstruction point (observers deduplicated).
    pub fn from_point(id: colslam_scene::Point3DId, p: &colslam_scene::Point3D) -> Self {
        let mut observers: Vec<u32> = p.track.iter().map(|t| t.image_id.0).collect();
        observers.sort_unstable();
        observers.dedup();
        Self { id: id.0, xyz: [p.xyz.x, p.xyz.y, p.xyz.z], color: p.color, observers }
    }
}

/// One registered camera (image) as the viewer shows it: pose and the
/// intrinsics that shape its frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewerCamera {
    /// The image id.
    pub image_id: u32,
    /// The image name.
    pub name: String,
    /// Registration order: 0 for the first registered image, increasing. It
    /// orders the green-to-red recency colouring and the clip range.
    pub order: u32,
    /// World-to-camera pose.
    pub cam_from_world: Rigid3,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x in pixels.
    pub fx: f64,
    /// Focal length along y in pixels.
    pub fy: f64,
    /// Principal point x in pixels.
    pub cx: f64,
    /// Principal point y in pixels.
    pub cy: f64,
}

impl ViewerCamera {
    /// The viewer's copy of a registered image of `rec`, with the given
    /// registration order. `None` when its camera is missing from `rec`.
    pub fn from_image(rec: &Reconstruction, image: &SceneImage, order: u32) -> Option<Self> {
        let cam = &rec.camera(image.camera_id)?.camera;
        let (w, h) = (cam.width as f64, cam.height as f64);
        // Models without a focal length (none in COLMAP's table, but a NaN
        // read back from odd parameters) fall back to a 90-degree-ish shape.
        let finite_or = |v: f64, d: f64| if v.is_finite() && v > 0.0 { v } else { d };
        let pp = cam.principal_point();
        Some(Self {
            image_id: image.id.0,
            name: image.name.clone(),
            order,
            cam_from_world: image.cam_from_world,
            width: u32::try_from(cam.width).unwrap_or(u32::MAX),
            height: u32::try_from(cam.height).unwrap_or(u32::MAX),
            fx: finite_or(cam.focal_x(), w.max(1.0)),
            fy: finite_or(cam.focal_y(), w.max(1.0)),
            cx: if pp.x.is_finite() { pp.x } else { 0.5 * w },
            cy: if pp.y.is_finite() { pp.y } else { 0.5 * h },
        })
    }
}

/// Changes to the map since the last update.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MapDelta {
    /// New or changed points.
    pub points: Vec<ViewerPoint>,
    /// Ids of deleted points.
    pub removed_points: Vec<u64>,
    /// New or changed cameras.
    pub cameras: Vec<ViewerCamera>,
    /// Image ids of deregistered cameras.
    pub removed_cameras: Vec<u32>,
}

/// The frame being processed, with its flow against the last keyframe.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameUpdate {
    /// Frame index in the input sequence (after skipping).
    pub index: usize,
    /// The frame (gray or RGB; downscale it first with
    /// [`crate::downscale_for_view`] to keep the page light). `None` shows no
    /// picture, only the numbers.
    pub image: Option<Image>,
    /// Flow lines `[x_keyframe, y_keyframe, x_frame, y_frame]` in the pixel
    /// coordinates of `image`, one per verified match (geometric inlier).
    pub flow_lines: Vec<[f32; 4]>,
    /// The same for a subsample of the matches verification rejected (the
    /// page draws them on request, in another colour).
    pub outlier_lines: Vec<[f32; 4]>,
    /// The frame's flow score (paper section 3.2).
    pub flow_score: f64,
    /// Matches against the last keyframe.
    pub num_matches: usize,
    /// Of those, the verified ones (the pipeline's geometric inliers).
    pub num_inliers: usize,
    /// The flow score a keyframe must exceed.
    pub flow_threshold: f64,
    /// The matches a keyframe needs.
    pub min_matches: usize,
    /// Whether this frame became a keyframe.
    pub is_keyframe: bool,
}

/// The last registered keyframe.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KeyframeUpdate {
    /// Its image id in the reconstruction.
    pub image_id: u32,
    /// Its frame index in the input sequence.
    pub frame_index: usize,
    /// Its name.
    pub name: String,
    /// The picture (downscaled), if any.
    pub image: Option<Image>,
}

/// A running summary of the reconstruction.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Summary {
    /// Registered keyframes.
    pub keyframes: usize,
    /// 3D points.
    pub points: usize,
    /// Observations (track elements).
    pub observations: usize,
    /// Mean reprojection error in pixels.
    pub mean_reproj_error: f64,
    /// Frames processed per second.
    pub fps: f64,
    /// Frames of the run read so far (0 for a loaded model).
    pub frames: usize,
    /// Frames the run will read, when the source knows.
    pub total_frames: Option<usize>,
}

impl Summary {
    /// Keyframes, points, observations and mean reprojection error of `rec`
    /// (no run: `fps` and `frames` left at 0).
    pub fn of(rec: &Reconstruction) -> Self {
        Self {
            keyframes: rec.num_registered_images(),
            points: rec.num_points3d(),
            observations: rec.num_observations(),
            mean_reproj_error: rec.mean_reprojection_error(),
            ..Self::default()
        }
    }
}

/// The pipeline's run state as the page shows it.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum RunState {
    /// Nothing running.
    #[default]
    Idle,
    /// A run is in progress (its progress is in the [`Summary`]).
    Running,
    /// Stop was requested.
    Stopping,
    /// The last run finished normally: what it made and where, in one line.
    Finished(String),
    /// The last run was stopped on request and wrote what it had: one line.
    Stopped(String),
    /// The last run failed with this message.
    Failed(String),
}

impl RunState {
    /// Lower-case name sent to the page.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::Running => "running",
            Self::Stopping => "stopping",
            Self::Finished(_) => "finished",
            Self::Stopped(_) => "stopped",
            Self::Failed(_) => "failed",
        }
    }

    /// The line that goes with an ended run (empty otherwise).
    pub fn message(&self) -> &str {
        match self {
            Self::Finished(m) | Self::Stopped(m) | Self::Failed(m) => m,
            Self::Idle | Self::Running | Self::Stopping => "",
        }
    }
}

/// An update from the pipeline (or any producer) to the viewer.
#[derive(Debug, Clone, PartialEq)]
pub enum ViewerUpdate {
    /// Drop the map, frames and summary (e.g. a new run starts).
    Reset,
    /// The frame being processed.
    Frame(FrameUpdate),
    /// A new keyframe was registered.
    Keyframe(KeyframeUpdate),
    /// Points and cameras changed.
    MapDelta(MapDelta),
    /// Summary numbers.
    Summary(Summary),
    /// A one-line status message.
    Status(String),
    /// The run state changed.
    RunState(RunState),
}

/// Feature extractor choice (paper section 3.1): the pipeline's own option.
pub use colslam_slam::FeatureKind as Extractor;
/// Feature matcher choice: the pipeline's own option.
pub use colslam_slam::MatcherKind as Matcher;

/// The settings the page's Run button sends (paper section 3.7.3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSettings {
    /// Input: image folder, dataset folder or video.
    pub input: PathBuf,
    /// Output folder.
    pub output: PathBuf,
    /// Take every `skip`-th frame; at least 1. Default 1.
    #[serde(default = "default_skip")]
    pub skip: i64,
    /// Process at most this many frames (after skipping); `None` = all.
    #[serde(default)]
    pub max_frames: Option<i64>,
    /// Frames considered for initialisation; at least 2. Default 20.
    #[serde(default = "default_init_frames")]
    pub init_frames: i64,
    /// Flow threshold for keyframes, in `[0, 1]`. Default 0.05.
    #[serde(default = "default_flow_threshold")]
    pub flow_threshold: f64,
    /// Feature extractor. Default ORB.
    #[serde(default)]
    pub extractor: Extractor,
    /// Feature matcher. Default NN.
    #[serde(default)]
    pub matcher: Matcher,
}

// The page's defaults are the pipeline's (one declaration).
fn default_skip() -> i64 {
    colslam_slam::InputOptions::default().skip as i64
}
fn default_init_frames() -> i64 {
    colslam_slam::options::InitOptions::default().init_frames as i64
}
fn default_flow_threshold() -> f64 {
    colslam_slam::options::KeyframeOptions::default().flow_threshold
}

impl Default for RunSettings {
    fn default() -> Self {
        Self {
            input: PathBuf::new(),
            output: PathBuf::new(),
            skip: default_skip(),
            max_frames: None,
            init_frames: default_init_frames(),
            flow_threshold: default_flow_threshold(),
            extractor: Extractor::default(),
            matcher: Matcher::default(),
        }
    }
}

/// Why a `POST /api/run` body is not a run: the message the page shows.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// Not JSON, or JSON that is not [`RunSettings`] (unknown fields, wrong types).
    #[error("invalid settings: {0}")]
    Json(#[from] serde_json::Error),
    /// A path or count the page must give is missing or out of range.
    #[error("invalid settings: {0}")]
    Invalid(String),
    /// Settings outside the pipeline's option ranges (its own message).
    #[error("invalid settings: {0}")]
    Options(#[source] colslam_slam::SlamError),
}

/// Why a [`RunController`] refused what the page asked; the page shows
/// [`colslam_slam::error_chain`] of it, with [`ControlError::status`].
#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    /// The settings do not describe a run.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The pipeline refused the run before it started (a bad or busy output).
    #[error(transparent)]
    Run(#[from] colslam_slam::SlamError),
    /// The input cannot be read.
    #[error(transparent)]
    Input(#[from] colslam_io::SourceError),
    /// A run is going on.
    #[error("a run is already in progress; stop it first")]
    Busy,
    /// The input does not tell its number of frames before it is read.
    #[error("{}: the number of frames is not known in advance", .0.display())]
    UnknownFrameCount(PathBuf),
    /// The run's thread could not be started.
    #[error("cannot start the run thread")]
    Thread(#[source] std::io::Error),
}

impl ControlError {
    /// The HTTP status the server answers with.
    pub fn status(&self) -> u16 {
        match self {
            Self::Busy => 409,
            Self::Thread(_) => 500,
            _ => 400,
        }
    }
}

impl RunSettings {
    /// Parses and validates the page's JSON body: what `POST /api/run`
    /// does before it starts anything (a pure function, for tests and fuzzing).
    pub fn from_json(body: &[u8]) -> Result<RunSettings, SettingsError> {
        let settings: RunSettings = serde_json::from_slice(body)?;
        settings.validate()?;
        Ok(settings)
    }

    /// Checks the settings with the pipeline's own validation (the page
    /// checks the same before sending): input and output paths given, and
    /// every option in its range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        self.to_config(&colslam_slam::RunOptions::default()).map(|_| ())
    }

    /// The run these settings select on top of `base` (the options the page
    /// does not set), validated by the pipeline's options.
    pub fn to_config(&self, base: &colslam_slam::RunOptions) -> Result<colslam_slam::RunConfig, SettingsError> {
        if self.input.as_os_str().is_empty() {
            return Err(SettingsError::Invalid("input path is missing".into()));
        }
        if self.output.as_os_str().is_empty() {
            return Err(SettingsError::Invalid("output path is missing".into()));
        }
        let count = |name: &str, v: i64| {
            usize::try_from(v).map_err(|_| SettingsError::Invalid(format!("{name} must be at least 1, got {v}")))
        };
        let mut options = base.clone();
        options.slam.frontend.features = self.extractor;
        options.slam.frontend.matcher = self.matcher;
        options.input.skip = count("frame skip", self.skip)?;
        options.input.max_frames = self.max_frames.map(|m| count("maximum frames", m)).transpose()?;
        options.slam.init.init_frames = count("initialisation frames", self.init_frames)?;
        options.slam.keyframes.flow_threshold = self.flow_threshold;
        let config = colslam_slam::RunConfig { options, ..colslam_slam::RunConfig::new(&self.input, &self.output) };
        config.options.validate().map_err(SettingsError::Options)?;
        Ok(config)
    }

    /// `skip` as an unsigned count (valid settings only; 1 otherwise).
    pub fn skip_usize(&self) -> usize {
        usize::try_from(self.skip).unwrap_or(1).max(1)
    }
}

/// What the page's Run/Stop buttons call: provided by the binary that owns
/// the pipeline. Methods are called from server threads, so they must return
/// promptly (start the run on its own thread).
pub trait RunController: Send + Sync {
    /// Starts a run with validated settings; an error is shown in the page.
    fn start(&self, settings: RunSettings) -> Result<(), ControlError>;
    /// Asks the running pipeline to stop.
    fn stop(&self);
    /// The number of frames `input` yields with this skip (the bound of the
    /// maximum-frames slider).
    fn max_frames_for(&self, input: &std::path::Path, skip: usize) -> Result<usize, ControlError>;
    /// The current reconstruction of a run, for export while it runs. The
    /// default says none (export then uses the last model given to
    /// [`crate::Viewer::set_reconstruction`]).
    fn snapshot(&self) -> Option<Reconstruction> {
        None
    }
}

//! Exports of a run for Gaussian splatting and NeRF tools: the layout the
//! original 3D Gaussian splatting code (graphdeco `scene/dataset_readers.py`)
//! and gsplat (`examples/datasets/colmap.py`) read, and nerfstudio's
//! `transforms.json` (`nerfstudio/data/dataparsers/nerfstudio_dataparser.py`).
//!
//! One entry, [`export_scene`], used by `colslam export -f nerfstudio|3dgs`
//! and the Python binding. It reads a run folder (the COLMAP model of the
//! keyframes, `trajectory.tum` of every localised frame, `report.json` naming
//! the input), reads the input once, in order, one frame at a time (a video is
//! decoded sequentially, never held whole), and writes every selected frame
//! that has a pose into `images/`:
//!
//! * keyframes take their pose from the model (matched by image name),
//!   other frames from `trajectory.tum` (matched by timestamp, the one the run
//!   gave the frame); frames without a pose are left out;
//! * file names are the source's (photos, TUM pngs); frames of a video get
//!   `frame_000094.png` (PNG, lossless); an image that had to be resampled
//!   (undistorted) from a JPEG source is written as PNG under the same stem.
//!
//! Formats:
//!
//! * [`SceneFormat::Gaussian3d`]: `images/` undistorted to a PINHOLE camera
//!   ([`colslam_camera::UndistortMap`], COLMAP's choice of the output camera:
//!   only valid pixels) and `sparse/0/` with that camera, every exported frame
//!   as an image (keyframes with their keypoints undistorted into the pinhole
//!   camera and their tracks, other frames without keypoints) and the 3D
//!   points (graphdeco turns `points3D.bin` into its initial splats; gsplat
//!   pairs the sorted model names with the sorted files of `images/`, so the
//!   folder holds exactly the model's images).
//! * [`SceneFormat::Nerfstudio`]: `images/` as the source has them (nerfstudio
//!   undistorts with the OPENCV terms itself), `transforms.json` and
//!   `sparse_pc.ply`. A camera nerfstudio cannot represent (FULL_OPENCV with
//!   its rational terms k4..k6) gets undistorted images and `PINHOLE`.
//!
//! The output folder is written as a whole ([`colslam_image::OutputDir`]).

use colslam_camera::undistort::{UndistortMap, UndistortOptions, is_undistorted};
use colslam_camera::{Camera, CameraModelId};
use colslam_eval::Trajectory;
use colslam_geometry::{Mat3, Rigid3, Sim3, Vec2, Vec3};
use colslam_image::{Image, OutputDir, OutputError};
use colslam_io::{FrameSource, ImageSequence, Layout, SourceError, SourceOptions, VideoColor, detect_layout};
use colslam_scene::{CameraId, ImageId, Point2D, Point3D, Reconstruction, SceneError, TrackElement};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// The entries an export folder holds (both formats: exporting the other
/// format into the same folder replaces it as a whole).
pub const EXPORT_OUTPUT_NAMES: [&str; 4] = ["images", "sparse", "transforms.json", "sparse_pc.ply"];

/// Largest difference (seconds) between a frame's timestamp and a
/// `trajectory.tum` stamp that still pairs them. The trajectory writes the
/// timestamps the run read from the same input with Rust's round-trip
/// formatting, so a pair is equal in practice; the tolerance only absorbs a
/// rewritten file, and is far below any frame interval.
const TIMESTAMP_TOLERANCE_S: f64 = 1e-6;

/// nerfstudio's `applied_transform` as its COLMAP converter writes it
/// (`colmap_utils.py`, `colmap_to_json`): the rows of the identity permuted
/// to (x, z, y) and the new z negated, a proper rotation that takes COLMAP's
/// world (y down for a level first camera) to nerfstudio's (z up).
const NERFSTUDIO_APPLIED: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];

/// The export formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneFormat {
    /// nerfstudio: `transforms.json`, `images/`, `sparse_pc.ply`.
    Nerfstudio,
    /// 3D Gaussian splatting (graphdeco, gsplat): undistorted `images/` and a
    /// PINHOLE COLMAP model in `sparse/0/`.
    Gaussian3d,
}

/// Which frames an export holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameSelection {
    /// Every localised frame (what splatting wants). Default.
    #[default]
    All,
    /// The model's keyframes only.
    Keyframes,
}

/// What to export.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneExport {
    /// A run's output folder (model, `trajectory.tum`, `report.json`).
    pub run: PathBuf,
    /// The export folder (written as a whole).
    pub output: PathBuf,
    /// The format.
    pub format: SceneFormat,
    /// Which frames.
    pub frames: FrameSelection,
    /// The input to read the images from instead of the one `report.json`
    /// names (the same sequence folder or video, moved).
    pub images: Option<PathBuf>,
    /// Which map of a run that ended with several: 0 is the largest, the
    /// model at the run folder's root; `k` is `maps/<k>/`. Maps do not share
    /// a frame of reference, so an export holds one.
    pub map: usize,
}

impl SceneExport {
    /// Every localised frame of `run` into `output`, images from the run's input.
    pub fn new(run: impl Into<PathBuf>, output: impl Into<PathBuf>, format: SceneFormat) -> Self {
        Self { run: run.into(), output: output.into(), format, frames: FrameSelection::All, images: None, map: 0 }
    }
}

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSummary {
    /// The export folder.
    pub output: PathBuf,
    /// Frames written (images in `images/`, frames in the model or `transforms.json`).
    pub frames: usize,
    /// Of those, keyframes.
    pub keyframes: usize,
    /// Frames of the input left out because they have no pose.
    pub not_localized: usize,
    /// 3D points written.
    pub points: usize,
    /// The camera model of the export (`PINHOLE`, `OPENCV`, ...).
    pub camera_model: String,
    /// Whether the images were undistorted.
    pub undistorted: bool,
    /// Exported image size.
    pub width: u64,
    /// Exported image height.
    pub height: u64,
}

/// One written frame, for a progress display.
#[derive(Debug, Clone, Copy)]
pub struct ExportProgress<'a> {
    /// Frames written so far (this one included).
    pub done: usize,
    /// Frames to write.
    pub total: usize,
    /// The written file's name in `images/`.
    pub name: &'a str,
}

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The run folder lacks a file every run writes.
    #[error("{path} is not a colslam run folder: {missing} is missing (give the -o folder of `colslam run`)")]
    NotARun {
        /// The folder.
        path: PathBuf,
        /// The missing file.
        missing: &'static str,
    },
    /// The run has no map of the requested index.
    #[error("{path} has no map {map}: the run ended with {maps} map(s), numbered from 0")]
    NoSuchMap {
        /// The run folder.
        path: PathBuf,
        /// The requested map.
        map: usize,
        /// How many maps the run has.
        maps: usize,
    },
    /// `report.json` cannot be read or names no input.
    #[error("{path}: {reason}")]
    Report {
        /// The report.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The model cannot be read or rebuilt.
    #[error("model")]
    Scene(#[from] SceneError),
    /// `trajectory.tum` cannot be read.
    #[error("trajectory")]
    Trajectory(#[from] colslam_eval::EvalError),
    /// The model has no usable camera.
    #[error("{path}: {reason}")]
    Camera {
        /// The model folder.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Undistortion failed.
    #[error("cannot undistort the camera")]
    Undistort(#[from] colslam_camera::CameraError),
    /// The input (images or video) cannot be opened.
    #[error("cannot open the run's input {path} (give its new place with --images)")]
    Input {
        /// The input.
        path: PathBuf,
        /// The cause.
        source: SourceError,
    },
    /// A frame of the input cannot be read.
    #[error("cannot read frame {name} of {input}")]
    Frame {
        /// The frame's name (file name or `frame_NNNNNN`).
        name: String,
        /// The input.
        input: PathBuf,
        /// The cause.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A frame's size is not the camera's.
    #[error("frame {name} of {input} is {width}x{height} but the run's camera is {cam_width}x{cam_height}")]
    FrameSize {
        /// The frame.
        name: String,
        /// The input.
        input: PathBuf,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
        /// Camera width.
        cam_width: u64,
        /// Camera height.
        cam_height: u64,
    },
    /// Keyframes of the model, or trajectory stamps, match no frame of the input.
    #[error("{input} is not the run's input: {what}")]
    Mismatch {
        /// The input.
        input: PathBuf,
        /// What did not match.
        what: String,
    },
    /// The export folder cannot be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A file of the export cannot be written.
    #[error("cannot write {path}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Exports a run (see the module docs).
pub fn export_scene(req: &SceneExport) -> Result<ExportSummary, ExportError> {
    export_scene_with(req, &mut |_| {})
}

/// [`export_scene`], calling `on_frame` after each written frame.
pub fn export_scene_with(
    req: &SceneExport,
    on_frame: &mut dyn FnMut(&ExportProgress<'_>),
) -> Result<ExportSummary, ExportError> {
    let run = RunFolder::open(&req.run, req.map)?;
    let out = OutputDir::begin(&req.output, &EXPORT_OUTPUT_NAMES)?;
    let input = req.images.clone().unwrap_or_else(|| run.input.clone());
    let camera = CameraPlan::new(&run.camera, req.format)?;
    tracing::info!(
        "exporting {} ({} keyframes, {} localised frames) from {} to {} as {}",
        req.run.display(),
        run.keyframes.len(),
        run.trajectory.len(),
        input.display(),
        req.output.display(),
        match req.format {
            SceneFormat::Nerfstudio => "nerfstudio",
            SceneFormat::Gaussian3d => "3dgs",
        }
    );
    let images_dir = out.path().join("images");
    create_dir(&images_dir)?;
    let total = match req.frames {
        FrameSelection::All => run.trajectory.len().max(run.keyframes.len()),
        FrameSelection::Keyframes => run.keyframes.len(),
    };
    let mut matcher = PoseMatcher::new(&run, req.frames);
    let mut written: Vec<Written> = Vec::new();
    let mut skipped = 0usize;
    let mut select = |name: &str, t: f64| {
        let pose = matcher.pose(name, t);
        skipped += usize::from(pose.is_none());
        pose
    };
    // Frames are resampled and encoded in parallel, a bounded batch at a
    // time (memory stays a few frames), and recorded in input order.
    let batch_len = (2 * rayon::current_num_threads()).max(2);
    let mut pending: Vec<(InputFrame, Posed)> = Vec::with_capacity(batch_len);
    let mut flush = |pending: &mut Vec<(InputFrame, Posed)>| -> Result<(), ExportError> {
        use rayon::prelude::*;
        let done: Vec<Result<(String, Posed), ExportError>> = std::mem::take(pending)
            .into_par_iter()
            .map(|(frame, pose)| camera.write_image(frame, &images_dir, &input).map(|name| (name, pose)))
            .collect();
        for result in done {
            let (name, pose) = result?;
            tracing::debug!("exported {name} ({}/{total})", written.len() + 1);
            on_frame(&ExportProgress { done: written.len() + 1, total, name: &name });
            written.push(Written { name, pose });
        }
        Ok(())
    };
    for_each_frame(&input, &mut select, &mut |frame, pose| {
        pending.push((frame, pose));
        if pending.len() >= batch_len { flush(&mut pending) } else { Ok(()) }
    })?;
    flush(&mut pending)?;
    matcher.check_complete(&input)?;
    let summary = match req.format {
        SceneFormat::Gaussian3d => write_gaussian(&run, &camera, &written, out.path())?,
        SceneFormat::Nerfstudio => write_nerfstudio(&run, &camera, &written, out.path())?,
    };
    out.commit()?;
    let summary = ExportSummary { output: req.output.clone(), not_localized: skipped, ..summary };
    tracing::info!(
        "exported {} frames ({} keyframes, {} points) to {}",
        summary.frames,
        summary.keyframes,
        summary.points,
        req.output.display()
    );
    Ok(summary)
}

/// The parts of a run folder an export reads.
struct RunFolder {
    rec: Reconstruction,
    camera_id: CameraId,
    camera: Camera,
    /// Registered images by name.
    keyframes: HashMap<String, ImageId>,
    trajectory: Trajectory,
    input: PathBuf,
}

impl RunFolder {
    /// Map `map` of the run folder `run`: the root's model for 0, else the
    /// one in `maps/<map>/`; `report.json` is the root's for every map.
    fn open(run: &Path, map: usize) -> Result<Self, ExportError> {
        if !run.is_dir() {
            return Err(ExportError::NotARun { path: run.to_path_buf(), missing: "the folder itself" });
        }
        if !run.join("report.json").is_file() {
            return Err(ExportError::NotARun { path: run.to_path_buf(), missing: "report.json" });
        }
        let maps = map_count(run);
        if map >= maps {
            return Err(ExportError::NoSuchMap { path: run.to_path_buf(), map, maps });
        }
        if map == 0 && maps > 1 {
            tracing::warn!(
                "{} holds {maps} maps that do not share a frame of reference: exporting map 0, the largest \
                 (--map K exports maps/K)",
                run.display()
            );
        }
        let dir = if map == 0 { run.to_path_buf() } else { run.join("maps").join(map.to_string()) };
        let dir = dir.as_path();
        if !dir.join("trajectory.tum").is_file() {
            return Err(ExportError::NotARun { path: dir.to_path_buf(), missing: "trajectory.tum" });
        }
        if !dir.join("cameras.bin").is_file() && !dir.join("cameras.txt").is_file() {
            return Err(ExportError::NotARun { path: dir.to_path_buf(), missing: "the model (cameras.bin)" });
        }
        let report = run.join("report.json");
        let bad = |reason: String| ExportError::Report { path: report.clone(), reason };
        let text = std::fs::read(&report).map_err(|e| bad(format!("cannot be read: {e}")))?;
        let json: serde_json::Value =
            serde_json::from_slice(&text).map_err(|e| bad(format!("is not a run report: {e}")))?;
        let input = json
            .get("input")
            .and_then(|v| v.as_str())
            .filter(|s| !s.is_empty())
            .map(PathBuf::from)
            .ok_or_else(|| bad("names no input".into()))?;
        let rec = colslam_scene::read_model(dir)?;
        let trajectory = Trajectory::read_tum(&dir.join("trajectory.tum"))?;
        let mut keyframes = HashMap::new();
        let mut camera_id = None;
        for id in rec.registered_image_ids() {
            let Some(img) = rec.image(*id) else { continue };
            if camera_id.is_some_and(|c| c != img.camera_id) {
                return Err(ExportError::Camera {
                    path: dir.to_path_buf(),
                    reason: "the model's images use more than one camera; an export needs one".into(),
                });
            }
            camera_id = Some(img.camera_id);
            keyframes.insert(img.name.clone(), *id);
        }
        let camera_id = camera_id.ok_or_else(|| ExportError::Camera {
            path: dir.to_path_buf(),
            reason: "the model has no registered image".into(),
        })?;
        let camera = rec
            .camera(camera_id)
            .map(|c| c.camera.clone())
            .ok_or_else(|| ExportError::Camera { path: dir.to_path_buf(), reason: format!("no camera {camera_id}") })?;
        Ok(Self { rec, camera_id, camera, keyframes, trajectory, input })
    }
}

/// How many maps a run folder holds: the root's and those in `maps/<k>/`
/// (numbered 1.. without gaps, as the run writes them).
fn map_count(run: &Path) -> usize {
    (1..).find(|k: &usize| !run.join("maps").join(k.to_string()).is_dir()).unwrap_or(1)
}

/// A frame's pose in the export.
#[derive(Debug, Clone, Copy)]
struct Posed {
    cam_from_world: Rigid3,
    /// The model's image, for a keyframe.
    keyframe: Option<ImageId>,
}

/// A written frame.
struct Written {
    /// File name in `images/`.
    name: String,
    pose: Posed,
}

/// Pairs input frames with poses: keyframes by name, others by timestamp.
struct PoseMatcher<'a> {
    run: &'a RunFolder,
    selection: FrameSelection,
    /// Trajectory stamps sorted, with their index.
    stamps: Vec<(f64, usize)>,
    used_stamps: Vec<bool>,
    keyframes_seen: std::collections::HashSet<ImageId>,
}

impl<'a> PoseMatcher<'a> {
    fn new(run: &'a RunFolder, selection: FrameSelection) -> Self {
        let mut stamps: Vec<(f64, usize)> = run.trajectory.stamps.iter().copied().zip(0..).collect();
        stamps.sort_by(|a, b| a.0.total_cmp(&b.0));
        Self { run, selection, used_stamps: vec![false; stamps.len()], stamps, keyframes_seen: Default::default() }
    }

    /// The trajectory entry at `t`, if any (marked used).
    fn stamp(&mut self, t: f64) -> Option<usize> {
        let k = self.stamps.partition_point(|s| s.0 < t);
        let near = [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter(|&i| i < self.stamps.len())
            .min_by(|&a, &b| (self.stamps[a].0 - t).abs().total_cmp(&(self.stamps[b].0 - t).abs()))?;
        if (self.stamps[near].0 - t).abs() > TIMESTAMP_TOLERANCE_S {
            return None;
        }
        self.used_stamps[near] = true;
        Some(self.stamps[near].1)
    }

    fn pose(&mut self, name: &str, t: f64) -> Option<Posed> {
        let stamp = self.stamp(t);
        if let Some(&id) = self.run.keyframes.get(name)
            && let Some(img) = self.run.rec.image(id)
        {
            self.keyframes_seen.insert(id);
            return Some(Posed { cam_from_world: img.cam_from_world, keyframe: Some(id) });
        }
        match self.selection {
            FrameSelection::Keyframes => None,
            FrameSelection::All => {
                let i = stamp?;
                let world_from_cam = self.run.trajectory.poses.get(i)?;
                Some(Posed { cam_from_world: world_from_cam.inverse(), keyframe: None })
            }
        }
    }

    /// Every keyframe, and with [`FrameSelection::All`] every trajectory
    /// entry, must have met its frame: otherwise the input is not the run's.
    fn check_complete(&self, input: &Path) -> Result<(), ExportError> {
        let kf = self.run.keyframes.len();
        if self.keyframes_seen.len() != kf {
            let mut missing: Vec<&String> =
                self.run.keyframes.iter().filter(|(_, id)| !self.keyframes_seen.contains(id)).map(|(n, _)| n).collect();
            missing.sort();
            return Err(ExportError::Mismatch {
                input: input.to_path_buf(),
                what: format!(
                    "{} of the model's {kf} keyframes are not among its frames (the first: {:?})",
                    missing.len(),
                    missing.first().map(|s| s.as_str()).unwrap_or_default()
                ),
            });
        }
        let unused = self.used_stamps.iter().filter(|u| !**u).count();
        if self.selection == FrameSelection::All && unused > 0 {
            return Err(ExportError::Mismatch {
                input: input.to_path_buf(),
                what: format!(
                    "{unused} of the {} timestamps of trajectory.tum match no frame (was the run made with another --fps?)",
                    self.stamps.len()
                ),
            });
        }
        Ok(())
    }
}

/// A selected frame of the input, before it is read.
enum InputFrame {
    /// A file of an image sequence (read when written).
    File { name: String, path: PathBuf },
    /// A decoded video frame.
    Decoded { name: String, image: Image },
}

/// Walks the input once, in order: `select(name, timestamp)` decides for
/// each frame, and `write` gets the selected ones. Image files are only read
/// when selected (by `write`); a video is decoded frame by frame.
fn for_each_frame(
    input: &Path,
    select: &mut dyn FnMut(&str, f64) -> Option<Posed>,
    write: &mut dyn FnMut(InputFrame, Posed) -> Result<(), ExportError>,
) -> Result<(), ExportError> {
    let open_err = |source| ExportError::Input { path: input.to_path_buf(), source };
    match detect_layout(input).map_err(open_err)? {
        Layout::Video { file } => {
            let mut opts = SourceOptions::default();
            // Splatting and NeRF want colour; a gray video stays gray in RGB.
            opts.video.color = VideoColor::Rgb;
            let source = colslam_io::VideoSource::open(&file, &opts).map_err(open_err)?;
            tracing::info!("decoding {}", source.describe());
            for (k, frame) in source.enumerate() {
                let frame = frame.map_err(|e| ExportError::Frame {
                    name: format!("frame_{k:06}"),
                    input: input.to_path_buf(),
                    source: Box::new(e),
                })?;
                if let Some(pose) = select(&frame.name, frame.timestamp) {
                    write(InputFrame::Decoded { name: frame.name, image: frame.image }, pose)?;
                }
            }
        }
        layout => {
            let seq = ImageSequence::open_layout(input, layout, &SourceOptions::default()).map_err(open_err)?;
            for listed in seq.listed() {
                if let Some(pose) = select(&listed.name, listed.timestamp) {
                    write(InputFrame::File { name: listed.name, path: listed.path.to_path_buf() }, pose)?;
                }
            }
        }
    }
    Ok(())
}

/// The exported camera and how images get to it.
struct CameraPlan {
    /// The run's camera.
    source: Camera,
    /// The camera of the exported images.
    exported: Camera,
    /// Present when images are undistorted.
    undistort: Option<UndistortMap>,
}

impl CameraPlan {
    fn new(camera: &Camera, format: SceneFormat) -> Result<Self, ExportError> {
        let needs = match format {
            SceneFormat::Gaussian3d => !is_undistorted(camera),
            SceneFormat::Nerfstudio => nerfstudio_camera(camera).is_none(),
        };
        if needs {
            let map = UndistortMap::new(camera, &UndistortOptions::default())?;
            let exported = map.undistorted_camera().clone();
            tracing::info!(
                "undistorting {} {}x{} to PINHOLE {}x{}",
                camera.model.name(),
                camera.width,
                camera.height,
                exported.width,
                exported.height
            );
            return Ok(Self { source: camera.clone(), exported, undistort: Some(map) });
        }
        let exported = match (format, camera.model) {
            // graphdeco and gsplat read SIMPLE_PINHOLE too; one model keeps
            // the readers' checks simple.
            (SceneFormat::Gaussian3d, _) => {
                let c = camera.principal_point();
                Camera::pinhole(camera.width, camera.height, camera.focal_x(), camera.focal_y(), c.x, c.y)
            }
            _ => camera.clone(),
        };
        Ok(Self { source: camera.clone(), exported, undistort: None })
    }

    /// Writes one frame into `dir`; returns its file name.
    fn write_image(&self, frame: InputFrame, dir: &Path, input: &Path) -> Result<String, ExportError> {
        let frame_err = |name: &str, source: Box<dyn std::error::Error + Send + Sync>| ExportError::Frame {
            name: name.to_string(),
            input: input.to_path_buf(),
            source,
        };
        let (name, image) = match frame {
            InputFrame::File { name, path } => {
                let (w, h) = colslam_io::image_size(&path).map_err(|e| frame_err(&name, Box::new(e)))?;
                self.check_size(&name, input, w, h)?;
                let bytes = std::fs::read(&path).map_err(|e| frame_err(&name, Box::new(e)))?;
                // Decoded even when copied, so a damaged file is refused here
                // rather than by the trainer.
                let image = Image::decode(&bytes, &path).map_err(|e| frame_err(&name, Box::new(e)))?;
                if self.undistort.is_none() {
                    // The source file itself: no re-encoding, its name and format kept.
                    let to = dir.join(&name);
                    std::fs::write(&to, &bytes)
                        .map_err(|e| ExportError::Write { path: to.clone(), source: Box::new(e) })?;
                    return Ok(name);
                }
                (name, image)
            }
            InputFrame::Decoded { name, image } => (name, image),
        };
        self.check_size(&name, input, image.width(), image.height())?;
        let image = match &self.undistort {
            Some(map) => map.remap(&image)?,
            None => image,
        };
        let stem = Path::new(&name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let file = format!("{stem}.png");
        let path = dir.join(&file);
        image.write_png(&path).map_err(|e| ExportError::Write { path, source: Box::new(e) })?;
        Ok(file)
    }

    fn check_size(&self, name: &str, input: &Path, width: usize, height: usize) -> Result<(), ExportError> {
        if width as u64 != self.source.width || height as u64 != self.source.height {
            return Err(ExportError::FrameSize {
                name: name.to_string(),
                input: input.to_path_buf(),
                width,
                height,
                cam_width: self.source.width,
                cam_height: self.source.height,
            });
        }
        Ok(())
    }

    /// Keypoints of the source camera in the exported one.
    fn keypoints(&self, points: &[Point2D]) -> Vec<Option<Vec2>> {
        match &self.undistort {
            Some(map) => map.undistort_points(&points.iter().map(|p| p.xy).collect::<Vec<_>>()),
            None => points.iter().map(|p| Some(p.xy)).collect(),
        }
    }
}

fn create_dir(dir: &Path) -> Result<(), ExportError> {
    std::fs::create_dir_all(dir).map_err(|e| ExportError::Write { path: dir.to_path_buf(), source: Box::new(e) })
}

/// The `sparse/0` model: the exported camera, every written frame, the
/// keyframes' keypoints in the exported camera with their tracks.
fn gaussian_model(run: &RunFolder, camera: &CameraPlan, written: &[Written]) -> Result<Reconstruction, ExportError> {
    let mut rec = Reconstruction::new();
    rec.add_camera_with_id(run.camera_id, camera.exported.clone())?;
    // Keyframes keep their ids so the tracks stay valid; other frames follow.
    let mut next = run.rec.next_image_id().0;
    // A keypoint that cannot be undistorted loses its observation.
    let mut dropped: BTreeMap<ImageId, Vec<bool>> = BTreeMap::new();
    for w in written {
        let (id, points2d) = match w.pose.keyframe.and_then(|id| run.rec.image(id)) {
            Some(img) => {
                let moved = camera.keypoints(&img.points2d);
                dropped.insert(img.id, moved.iter().map(Option::is_none).collect());
                let pts = moved
                    .iter()
                    .zip(&img.points2d)
                    .map(|(m, p)| Point2D { xy: m.unwrap_or(p.xy), point3d_id: None })
                    .collect();
                (img.id, pts)
            }
            None => {
                let id = ImageId(next);
                next += 1;
                (id, Vec::new())
            }
        };
        rec.add_image(colslam_scene::Image {
            id,
            name: w.name.clone(),
            camera_id: run.camera_id,
            cam_from_world: w.pose.cam_from_world,
            points2d,
            registered: true,
        })?;
    }
    for (pid, p) in run.rec.points3d() {
        let track: Vec<TrackElement> = p
            .track
            .iter()
            .filter(|el| {
                dropped.get(&el.image_id).and_then(|d| d.get(el.point2d_idx as usize)).is_some_and(|gone| !*gone)
            })
            .copied()
            .collect();
        if track.is_empty() {
            continue;
        }
        rec.add_point3d_with_id(pid, Point3D { xyz: p.xyz, color: p.color, error: p.error, track })?;
    }
    Ok(rec)
}

fn write_gaussian(
    run: &RunFolder,
    camera: &CameraPlan,
    written: &[Written],
    out: &Path,
) -> Result<ExportSummary, ExportError> {
    let rec = gaussian_model(run, camera, written)?;
    let dir = out.join("sparse").join("0");
    create_dir(&dir)?;
    colslam_scene::write_model_files(&rec, &dir, colslam_scene::ModelFormat::Binary)?;
    Ok(summary(camera, written, rec.num_points3d(), camera.exported.model.name()))
}

fn summary(camera: &CameraPlan, written: &[Written], points: usize, model: &str) -> ExportSummary {
    ExportSummary {
        output: PathBuf::new(),
        frames: written.len(),
        keyframes: written.iter().filter(|w| w.pose.keyframe.is_some()).count(),
        not_localized: 0,
        points,
        camera_model: model.to_string(),
        undistorted: camera.undistort.is_some(),
        width: camera.exported.width,
        height: camera.exported.height,
    }
}

/// nerfstudio's camera model and distortion terms for `camera`, as its
/// COLMAP converter maps them (`parse_colmap_camera_params`): the pinhole
/// and radial family as OPENCV (its distortion is `1 + k1 r^2 + k2 r^4 +
/// k3 r^6 + k4 r^8` with p1, p2, so FULL_OPENCV fits only without the
/// rational k4..k6), OPENCV_FISHEYE as itself. `None`: not representable.
fn nerfstudio_camera(camera: &Camera) -> Option<(&'static str, Vec<(&'static str, f64)>)> {
    let p = &camera.params;
    let at = |i: usize| p.get(i).copied().unwrap_or(0.0);
    let opencv = |k1, k2, p1, p2| vec![("k1", k1), ("k2", k2), ("p1", p1), ("p2", p2)];
    Some(match camera.model {
        CameraModelId::SimplePinhole | CameraModelId::Pinhole => ("OPENCV", opencv(0.0, 0.0, 0.0, 0.0)),
        CameraModelId::SimpleRadial => ("OPENCV", opencv(at(3), 0.0, 0.0, 0.0)),
        CameraModelId::Radial => ("OPENCV", opencv(at(3), at(4), 0.0, 0.0)),
        CameraModelId::OpenCv => ("OPENCV", opencv(at(4), at(5), at(6), at(7))),
        CameraModelId::OpenCvFisheye => {
            ("OPENCV_FISHEYE", vec![("k1", at(4)), ("k2", at(5)), ("k3", at(6)), ("k4", at(7))])
        }
        CameraModelId::FullOpenCv => {
            if [9, 10, 11].iter().any(|&i| at(i) != 0.0) {
                return None;
            }
            let mut terms = opencv(at(4), at(5), at(6), at(7));
            terms.push(("k3", at(8)));
            ("OPENCV", terms)
        }
    })
}

/// `applied_transform` as a rotation.
fn nerfstudio_applied() -> Mat3 {
    let a = NERFSTUDIO_APPLIED;
    Mat3::new(a[0][0], a[0][1], a[0][2], a[1][0], a[1][1], a[1][2], a[2][0], a[2][1], a[2][2])
}

/// A frame's `transform_matrix`: nerfstudio's camera-to-world in its OpenGL
/// camera convention (x right, y up, looking down -z; COLMAP's camera looks
/// down +z with y down, so the y and z axes flip) in the world rotated by
/// `applied_transform`, as `colmap_to_json` computes it.
fn nerfstudio_matrix(cam_from_world: &Rigid3) -> [[f64; 4]; 4] {
    let world_from_cam = cam_from_world.inverse();
    let a = nerfstudio_applied();
    let r = a * world_from_cam.rotation_matrix();
    let t = a * world_from_cam.translation;
    let flip = [1.0, -1.0, -1.0];
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().take(3).enumerate() {
        for (j, v) in row.iter_mut().take(3).enumerate() {
            *v = r[(i, j)] * flip[j];
        }
        row[3] = t[i];
    }
    m[3][3] = 1.0;
    m
}

fn write_nerfstudio(
    run: &RunFolder,
    camera: &CameraPlan,
    written: &[Written],
    out: &Path,
) -> Result<ExportSummary, ExportError> {
    let exported = &camera.exported;
    // Undistorted images: PINHOLE. Otherwise the run's camera as nerfstudio's
    // converter writes it (a pinhole camera as OPENCV with zero terms).
    let (model, terms) = match (&camera.undistort, nerfstudio_camera(exported)) {
        (None, Some(m)) => m,
        _ => ("PINHOLE", Vec::new()),
    };
    let c = exported.principal_point();
    let mut meta = serde_json::Map::new();
    meta.insert("camera_model".into(), model.into());
    // COLMAP's pixel convention is nerfstudio's (pixel centres at +0.5).
    for (k, v) in [("fl_x", exported.focal_x()), ("fl_y", exported.focal_y()), ("cx", c.x), ("cy", c.y)] {
        meta.insert(k.into(), v.into());
    }
    meta.insert("w".into(), exported.width.into());
    meta.insert("h".into(), exported.height.into());
    for (k, v) in terms {
        meta.insert(k.into(), v.into());
    }
    let frames: Vec<serde_json::Value> = written
        .iter()
        .map(|w| {
            let mut f = serde_json::json!({
                "file_path": format!("images/{}", w.name),
                "transform_matrix": nerfstudio_matrix(&w.pose.cam_from_world),
            });
            if let Some(id) = w.pose.keyframe {
                f["colmap_im_id"] = id.0.into();
            }
            f
        })
        .collect();
    meta.insert("frames".into(), frames.into());
    let a = NERFSTUDIO_APPLIED;
    let applied: Vec<[f64; 4]> = a.iter().map(|r| [r[0], r[1], r[2], 0.0]).collect();
    meta.insert("applied_transform".into(), serde_json::json!(applied));
    meta.insert("ply_file_path".into(), "sparse_pc.ply".into());
    let mut text = serde_json::to_string_pretty(&serde_json::Value::Object(meta))
        .map_err(|e| ExportError::Write { path: out.join("transforms.json"), source: Box::new(e) })?;
    text.push('\n');
    let path = out.join("transforms.json");
    std::fs::write(&path, text).map_err(|e| ExportError::Write { path: path.clone(), source: Box::new(e) })?;
    // The points in the same world as the transforms.
    let mut points = run.rec.clone();
    let rotation = Rigid3::from_rotation_matrix(&nerfstudio_applied(), Vec3::zeros()).rotation;
    points.transform(&Sim3 { scale: 1.0, rotation, translation: Vec3::zeros() });
    colslam_scene::write_ply(&points, &out.join("sparse_pc.ply"))?;
    Ok(summary(camera, written, points.num_points3d(), model))
}

//! Frame sources for colslam: image folders, TUM RGB-D, EuRoC and KITTI
//! layouts, and video files (decoded by the `ffmpeg` program), all behind one
//! lazy [`FrameSource`] iterator with frame skip and limit.
//!
//! Sources never hold decoded frames: an image sequence keeps only the list of
//! file paths it will read, and a video keeps one `ffmpeg` child process whose
//! output pipe is read one frame per [`Iterator::next`]. So a 10,000-frame
//! video costs one frame of memory at a time.
//!
//! ```no_run
//! use colslam_io::{open_source, SourceOptions};
//! let opts = SourceOptions { skip: 2, max_frames: Some(100), ..Default::default() };
//! let source = open_source(std::path::Path::new("datasets/tum_fr1_rpy_sub"), &opts)?;
//! for frame in source {
//!     let frame = frame?;
//!     println!("{} {} {}x{}", frame.index, frame.timestamp, frame.image.width(), frame.image.height());
//! }
//! # Ok::<(), colslam_io::SourceError>(())
//! ```

mod detect;
mod error;
pub mod exif;
mod header;
mod layouts;
mod natural;
mod options;
mod sequence;
mod video;

use std::path::{Path, PathBuf};

pub use detect::{Layout, detect_layout};
pub use error::SourceError;
pub use header::image_size;
pub use natural::natural_cmp;
pub use options::{
    DEFAULT_FFMPEG, DEFAULT_FFPROBE, DEFAULT_SKIP, DEFAULT_START, SourceOptions, VideoColor, VideoOptions,
};
pub use sequence::{ImageSequence, ListedFrame};
pub use video::{DEFAULT_VIDEO_FPS, VideoSource};

/// File names searched, in this order, for a camera file beside the data.
pub const CAMERA_FILE_NAMES: [&str; 3] = ["camera.yaml", "camera.yml", "camera.toml"];
/// Image file extensions read from folders (compared case-insensitively).
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];
/// Video file extensions (compared case-insensitively). Any other regular
/// file that is not an image or a known list file is also tried as a video.
pub const VIDEO_EXTENSIONS: [&str; 8] = ["mp4", "mkv", "avi", "mov", "webm", "m4v", "mpg", "mpeg"];

/// One frame of a sequence.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Position in the output sequence (after start, skip and limit): 0, 1, 2, ...
    pub index: usize,
    /// Index in the original sequence: `start + index * skip`.
    pub source_index: usize,
    /// Timestamp in seconds (from the list file, the video's pts, or `index / fps`).
    pub timestamp: f64,
    /// The image's file name, or `frame_000123` (source index) for videos.
    pub name: String,
    /// The pixels: RGB or gray, 8-bit.
    pub image: colslam_image::Image,
}

/// The kind of a frame source.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// A video file decoded by ffmpeg.
    Video,
    /// A TUM RGB-D folder (`rgb.txt`).
    Tum,
    /// A EuRoC MAV folder (`mav0/cam0/data.csv`).
    Euroc,
    /// A KITTI odometry sequence (`image_0/` or `image_2/` with `times.txt`).
    Kitti,
    /// A plain folder of PNG/JPEG images in natural order.
    Folder,
}

impl std::fmt::Display for SourceKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SourceKind::Video => "video",
            SourceKind::Tum => "TUM sequence",
            SourceKind::Euroc => "EuRoC sequence",
            SourceKind::Kitti => "KITTI sequence",
            SourceKind::Folder => "image folder",
        })
    }
}

/// A lazy sequence of frames. Each item is one frame or the error that
/// prevented reading it; errors name the file at fault.
pub trait FrameSource: Iterator<Item = Result<Frame, SourceError>> + Send {
    /// Frames this source will yield after start, skip and `max_frames`
    /// (`None` when unknown).
    fn len_hint(&self) -> Option<usize>;
    /// Frames in the underlying sequence, before start, skip and limit.
    fn total_source_frames(&self) -> Option<usize>;
    /// `(width, height)` of the frames, when known without decoding.
    fn image_size(&self) -> Option<(usize, usize)>;
    /// A camera file (`camera.yaml`, `camera.yml` or `camera.toml`) found
    /// beside the data, for the caller to load with `colslam_camera`.
    fn camera_file(&self) -> Option<PathBuf>;
    /// A calibration file in the dataset's own format that `colslam_camera`
    /// may not read (EuRoC `sensor.yaml`, KITTI `calib.txt`), for reference.
    fn native_calibration_file(&self) -> Option<PathBuf> {
        None
    }
    /// The first image file of an image sequence (its EXIF block may name
    /// the focal length); `None` for a video.
    fn first_image(&self) -> Option<&Path> {
        None
    }
    /// The kind of source.
    fn kind(&self) -> SourceKind;
    /// Its path as given (folder or video file).
    fn path(&self) -> &Path;
    /// One line for logs, e.g. `TUM sequence /x (200 frames)`.
    fn describe(&self) -> String;
}

/// What [`probe_source`] learns about a source without decoding any frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceInfo {
    /// The kind of source.
    pub kind: SourceKind,
    /// The path as given.
    pub path: PathBuf,
    /// Frames before start/skip/limit (`None` when unknown).
    pub total_source_frames: Option<usize>,
    /// Frames that will be yielded (`None` when unknown).
    pub frames: Option<usize>,
    /// `(width, height)` when known.
    pub image_size: Option<(usize, usize)>,
    /// A camera file beside the data (see [`FrameSource::camera_file`]).
    pub camera_file: Option<PathBuf>,
    /// A native calibration file (see [`FrameSource::native_calibration_file`]).
    pub native_calibration_file: Option<PathBuf>,
    /// One-line description.
    pub description: String,
}

/// Opens a frame source, detecting its kind (see [`detect_layout`] for the
/// order): a video file, a TUM, EuRoC or KITTI folder, or a plain image
/// folder. Nothing is decoded until the first `next()`.
pub fn open_source(path: &Path, opts: &SourceOptions) -> Result<Box<dyn FrameSource>, SourceError> {
    opts.validate()?;
    Ok(match detect_layout(path)? {
        Layout::Video { file } => Box::new(VideoSource::open(&file, opts)?),
        layout => Box::new(ImageSequence::open_layout(path, layout, opts)?),
    })
}

/// Kind, counts, image size and camera file of a source, without decoding
/// frames (a video is probed with `ffprobe`, images by their headers).
pub fn probe_source(path: &Path, opts: &SourceOptions) -> Result<SourceInfo, SourceError> {
    let src = open_source(path, opts)?;
    Ok(SourceInfo {
        kind: src.kind(),
        path: src.path().to_path_buf(),
        total_source_frames: src.total_source_frames(),
        frames: src.len_hint(),
        image_size: src.image_size(),
        camera_file: src.camera_file(),
        native_calibration_file: src.native_calibration_file(),
        description: src.describe(),
    })
}

/// The first of [`CAMERA_FILE_NAMES`] that exists in the first of `dirs`
/// holding one.
pub fn find_camera_file(dirs: &[&Path]) -> Option<PathBuf> {
    dirs.iter().flat_map(|d| CAMERA_FILE_NAMES.iter().map(move |n| d.join(n))).find(|p| p.is_file())
}

/// True if the file name has one of [`IMAGE_EXTENSIONS`].
pub fn is_image_file(path: &Path) -> bool {
    has_extension(path, &IMAGE_EXTENSIONS)
}

/// True if the file name has one of [`VIDEO_EXTENSIONS`].
pub fn is_video_file(path: &Path) -> bool {
    has_extension(path, &VIDEO_EXTENSIONS)
}

fn has_extension(path: &Path, exts: &[&str]) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| exts.iter().any(|x| x.eq_ignore_ascii_case(e)))
}

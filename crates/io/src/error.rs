//! The error type of every frame source.

use std::path::PathBuf;

/// Errors from opening or reading a frame source. Every variant names the
/// file or folder it is about. A variant with a cause (an OS or decoding
/// error) does not repeat it in its message: the cause is its
/// [`source`](std::error::Error::source), so print the chain (`{:#}` with
/// anyhow) to show both once.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The given path does not exist.
    #[error("{path}: no such file or folder")]
    NotFound {
        /// The path.
        path: PathBuf,
    },
    /// A folder holds no usable images.
    #[error(
        "no images in {dir} (expected .png, .jpg or .jpeg files, an rgb.txt, a EuRoC mav0/cam0/data.csv or a KITTI image_0/times.txt layout){hint}"
    )]
    NoImages {
        /// The folder.
        dir: PathBuf,
        /// Extra hint (e.g. video files found in the folder), empty or starting with "; ".
        hint: String,
    },
    /// The path is a single image file, not a sequence.
    #[error("{path}: is a single image, not a sequence; pass the folder that holds the images")]
    SingleImage {
        /// The image file.
        path: PathBuf,
    },
    /// An image named by a list file (rgb.txt, data.csv, times.txt layout) is missing.
    #[error("image {image} listed in {list} (line {line}) does not exist")]
    MissingListedImage {
        /// The missing image.
        image: PathBuf,
        /// The list file naming it.
        list: PathBuf,
        /// 1-based line number in the list file (0 when the image was paired by position).
        line: usize,
    },
    /// An image named by a list file exists but is not a regular file (a
    /// folder, a device), or its metadata cannot be read (permissions).
    #[error("image {image} listed in {list} (line {line}) {problem}")]
    UnusableListedImage {
        /// The image path.
        image: PathBuf,
        /// The list file naming it.
        list: PathBuf,
        /// 1-based line number in the list file (0 when paired by position).
        line: usize,
        /// What it is instead ("is a folder, not an image file", "cannot be read").
        problem: String,
        /// The OS error, when there is one.
        source: Option<std::io::Error>,
    },
    /// A path that must be a file (a video) exists but is something else.
    #[error("{path}: is {what}, not a regular file")]
    NotAFile {
        /// The path.
        path: PathBuf,
        /// What it is: "a folder", "a special file".
        what: &'static str,
    },
    /// A line of a list file (rgb.txt, data.csv, times.txt) cannot be parsed.
    #[error("{file}:{line}: {reason}: {content:?}")]
    MalformedLine {
        /// The list file.
        file: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The offending line.
        content: String,
        /// What is wrong.
        reason: String,
    },
    /// The files of a layout do not agree with each other.
    #[error("{path}: {reason}")]
    Layout {
        /// The file or folder at fault.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// An image could not be read or decoded (the source names the file).
    #[error("cannot read image{context}")]
    Image {
        /// The decoding error.
        source: colslam_image::ImageError,
        /// Extra context (e.g. " (listed in rgb.txt line 4)"), empty or starting with " ".
        context: String,
    },
    /// A frame's size differs from the first frame's.
    #[error("{path}: image is {width}x{height} but the sequence's first frame is {expected_width}x{expected_height}")]
    SizeMismatch {
        /// The image file.
        path: PathBuf,
        /// Its width.
        width: usize,
        /// Its height.
        height: usize,
        /// The first frame's width.
        expected_width: usize,
        /// The first frame's height.
        expected_height: usize,
    },
    /// A file or folder could not be read.
    #[error("{path}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The options are invalid.
    #[error("invalid frame source options: {0}")]
    InvalidOptions(String),
    /// The `ffmpeg` or `ffprobe` program cannot be run.
    #[error(
        "cannot run `{program}` to read video {path}: {reason}; install ffmpeg (e.g. `apt-get install ffmpeg`) or set the program path in the video options"
    )]
    FfmpegMissing {
        /// The program that could not be started.
        program: PathBuf,
        /// The video.
        path: PathBuf,
        /// Why it could not be started.
        reason: String,
    },
    /// The video cannot be opened or decoded (ffprobe/ffmpeg's message is included).
    #[error("video {path}: {reason}")]
    Video {
        /// The video file.
        path: PathBuf,
        /// What went wrong, with ffmpeg's own message where there is one.
        reason: String,
    },
    /// The video ended early: a partial final frame or ffmpeg reporting errors
    /// before the expected frame count.
    #[error("video {path} is truncated or damaged after {frames_read} frame(s): {reason}")]
    VideoTruncated {
        /// The video file.
        path: PathBuf,
        /// Frames delivered before the failure.
        frames_read: usize,
        /// What went wrong, with ffmpeg's message where there is one.
        reason: String,
    },
    /// The source yields no frames (empty video, or start/skip selecting nothing).
    #[error("{path}: no frames to read{reason}")]
    NoFrames {
        /// The file or folder.
        path: PathBuf,
        /// Why, empty or starting with ": ".
        reason: String,
    },
}

/// What stands in the way of reading `path` as a regular file.
#[derive(Debug)]
pub(crate) enum FileProblem {
    /// Nothing is there.
    Missing,
    /// Something other than a regular file is there ("a folder", "a special file").
    NotAFile(&'static str),
    /// Its metadata cannot be read (e.g. a folder on the way is not searchable).
    Unreadable(std::io::Error),
}

/// Checks that `path` is a regular file (following symbolic links), telling
/// a missing path from a folder or special file and from one that cannot be
/// examined, so that no message says "does not exist" of a path that does.
pub(crate) fn check_regular_file(path: &std::path::Path) -> Result<(), FileProblem> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_file() => Ok(()),
        Ok(m) if m.is_dir() => Err(FileProblem::NotAFile("a folder")),
        Ok(_) => Err(FileProblem::NotAFile("a special file")),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(FileProblem::Missing),
        Err(e) => Err(FileProblem::Unreadable(e)),
    }
}

impl SourceError {
    /// The error for a path that must be a regular file but is not.
    pub(crate) fn not_a_file(path: impl Into<PathBuf>, problem: FileProblem) -> Self {
        let path = path.into();
        match problem {
            FileProblem::Missing => SourceError::NotFound { path },
            FileProblem::NotAFile(what) => SourceError::NotAFile { path, what },
            FileProblem::Unreadable(source) => SourceError::Io { path, source },
        }
    }

    /// Wraps an image decoding error with extra context.
    pub(crate) fn image(source: colslam_image::ImageError, context: String) -> Self {
        SourceError::Image { source, context }
    }

    /// An I/O error on `path`.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SourceError::Io { path: path.into(), source }
    }
}

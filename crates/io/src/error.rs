//! The error type of every frame source.

use std::path::PathBuf;

/// Errors from opening or reading a frame source. Every variant names the
/// file or folder it is about.
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
    /// An image could not be read or decoded (the inner error names the file).
    #[error("{source}{context}")]
    Image {
        /// The decoding error.
        source: colslam_image::ImageError,
        /// Extra context (e.g. "; listed in rgb.txt line 4"), empty or starting with "; ".
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
    #[error("{path}: {source}")]
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

impl SourceError {
    /// Wraps an image decoding error with extra context.
    pub(crate) fn image(source: colslam_image::ImageError, context: String) -> Self {
        SourceError::Image { source, context }
    }

    /// An I/O error on `path`.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SourceError::Io { path: path.into(), source }
    }
}

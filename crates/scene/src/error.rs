//! Errors of the scene layer. File errors always name the file.

use crate::ids::{CameraId, ImageId, Point3DId};
use std::path::PathBuf;

/// Everything that can go wrong in this crate.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// An operating-system error on a file.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// An output folder cannot be written (its location, its lock, its
    /// swap into place).
    #[error(transparent)]
    Output(#[from] colslam_image::OutputError),
    /// A model folder lacks the files of either format.
    #[error("{dir}: no COLMAP model found (need cameras, images and points3D as .bin or .txt); missing {missing}")]
    MissingFiles {
        /// The folder.
        dir: PathBuf,
        /// What is missing.
        missing: String,
    },
    /// A binary file ends before a record is complete, or a count in it
    /// promises more data than the file holds.
    #[error("{path}: truncated at byte {offset}: {what}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Byte offset where the read failed.
        offset: usize,
        /// What was being read.
        what: String,
    },
    /// A binary file holds a value that cannot be right.
    #[error("{path}: corrupt at byte {offset}: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Byte offset of the bad value.
        offset: usize,
        /// What is wrong.
        what: String,
    },
    /// A text file has a malformed line.
    #[error("{path}:{line}: {what}")]
    BadLine {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// A camera model id or name that this crate does not support.
    #[error("{path}: camera {camera}: unknown camera model {model}")]
    UnknownCameraModel {
        /// The file.
        path: PathBuf,
        /// The camera.
        camera: u32,
        /// The model id or name as found.
        model: String,
    },
    /// A camera with the wrong number of parameters for its model.
    #[error("{path}: camera {camera}: model {model} takes {expected} parameters, got {got}")]
    ParamCount {
        /// The file.
        path: PathBuf,
        /// The camera.
        camera: u32,
        /// Model name.
        model: &'static str,
        /// Expected count.
        expected: usize,
        /// Found count.
        got: usize,
    },
    /// A camera's values are unusable: a non-finite parameter, a focal
    /// length that is not positive, a zero size or a principal point far
    /// outside the image (the cause, [`colslam_camera::Camera::validate`]'s
    /// error, says which).
    #[error("{path}: {location}: camera {camera} is invalid")]
    InvalidCamera {
        /// The file.
        path: PathBuf,
        /// Where in it: "line 4" (text) or "record at byte 12" (binary).
        location: String,
        /// The camera.
        camera: u32,
        /// What is wrong (boxed: it would more than double the size of
        /// every `Result` of this crate).
        source: Box<colslam_camera::CameraError>,
    },
    /// The model in a set of files is inconsistent (dangling references,
    /// duplicate ids, disagreeing links).
    #[error("{path}: {what}")]
    Inconsistent {
        /// The file in which the bad reference was found.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A value cannot be written in the requested format.
    #[error("{path}: cannot write: {what}")]
    Unwritable {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
    /// No camera with this id.
    #[error("no camera {0}")]
    UnknownCamera(CameraId),
    /// No image with this id.
    #[error("no image {0}")]
    UnknownImage(ImageId),
    /// No 3D point with this id.
    #[error("no 3D point {0}")]
    UnknownPoint3D(Point3DId),
    /// An id already in use.
    #[error("{0} already exists")]
    DuplicateId(String),
    /// An observation that cannot be added or removed.
    #[error("image {image} point2D {point2d_idx}: {what}")]
    BadObservation {
        /// The image.
        image: ImageId,
        /// The keypoint index.
        point2d_idx: u32,
        /// What is wrong.
        what: String,
    },
    /// An operation needs a registered (or unregistered) image.
    #[error("image {image}: {what}")]
    Registration {
        /// The image.
        image: ImageId,
        /// What is wrong.
        what: String,
    },
    /// Options outside their valid range.
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// The in-memory model violates an invariant (from `check_consistency`).
    #[error("inconsistent reconstruction: {0}")]
    Invariant(String),
}

impl SceneError {
    /// Wraps an I/O error with its file.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
}

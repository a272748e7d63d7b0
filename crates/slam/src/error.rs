//! Errors of the SLAM pipeline.

use std::path::PathBuf;

/// Errors of the SLAM pipeline. Conditions a run survives (a frame that
/// cannot be localised, a lost map) are reported, not raised. A variant with
/// a cause does not repeat it in its message: the cause is its
/// [`source`](std::error::Error::source), so print the chain (`{:#}` with
/// anyhow) to show both once.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// An option is out of range.
    #[error("invalid option {name} = {value}: {reason}")]
    InvalidOption {
        /// Option name (as on the command line).
        name: &'static str,
        /// Its value.
        value: String,
        /// Why.
        reason: String,
    },
    /// The camera is unusable.
    #[error("camera")]
    Camera(#[from] colslam_camera::CameraError),
    /// A frame's size differs from the camera's.
    #[error("frame {name} is {width}x{height} but the camera is {cam_width}x{cam_height}")]
    FrameSize {
        /// Frame name.
        name: String,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
        /// Camera width.
        cam_width: u64,
        /// Camera height.
        cam_height: u64,
    },
    /// Feature extraction or matching failed.
    #[error("features")]
    Features(#[from] colslam_features::FeatureError),
    /// The input could not be read.
    #[error(transparent)]
    Source(#[from] colslam_io::SourceError),
    /// An error of the SfM layer.
    #[error(transparent)]
    Sfm(#[from] colslam_sfm::SfmError),
    /// An error of the scene layer.
    #[error(transparent)]
    Scene(#[from] colslam_scene::SceneError),
    /// The output folder cannot be written (its location, its lock, its
    /// swap into place).
    #[error(transparent)]
    Output(#[from] colslam_image::OutputError),
    /// Writing an output failed.
    #[error("{path}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Writing a trajectory failed.
    #[error(transparent)]
    Trajectory(#[from] colslam_eval::EvalError),
    /// Processing one frame failed.
    #[error("processing frame {index} ({name})")]
    Frame {
        /// Frame index.
        index: usize,
        /// Frame name.
        name: String,
        /// What failed.
        source: Box<SlamError>,
    },
    /// The input or output cannot be used as given.
    #[error("{path}: {reason}")]
    Path {
        /// The input or output path.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// No frame of the input could be read (every one failed to decode, or
    /// the source yielded none), so there is nothing to write.
    #[error("{input}: no frame could be read ({skipped} skipped); the first failed with: {first_error}")]
    NoFramesRead {
        /// The input as given.
        input: PathBuf,
        /// Frames that failed and were skipped.
        skipped: usize,
        /// The first failure, with its causes.
        first_error: String,
    },
    /// The thread that reads and extracts frames ahead of the mapper panicked.
    #[error("the frame reader thread panicked")]
    ReaderPanicked,
    /// The temporary store of the frames' records failed
    /// (`crate::records`).
    #[error("record store {}: {action}", path.display())]
    RecordStore {
        /// The temporary file.
        path: std::path::PathBuf,
        /// What failed.
        action: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The run was interrupted (Ctrl-C): nothing was written.
    #[error("interrupted at frame {frame}")]
    Cancelled {
        /// Frames processed when the interruption was seen.
        frame: usize,
    },
    /// Serialising the report failed.
    #[error("report")]
    Json(#[from] serde_json::Error),
}

/// `e` and its sources, joined by ": " (a source whose text already ends
/// the message is left out): the one line a front end shows for an error,
/// since library errors leave their cause to `source()`.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut msg = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let text = s.to_string();
        if !msg.ends_with(&text) {
            msg.push_str(": ");
            msg.push_str(&text);
        }
        source = s.source();
    }
    msg
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failure_message_names_the_causes() {
        let io = std::io::Error::new(std::io::ErrorKind::PermissionDenied, "denied");
        let e = SlamError::Io { path: "out".into(), source: io };
        assert_eq!(error_chain(&e), "out: denied", "a source already in the message is not repeated");
        let e = SlamError::Frame { index: 3, name: "a.png".into(), source: Box::new(e) };
        assert_eq!(error_chain(&e), "processing frame 3 (a.png): out: denied");
        #[derive(Debug, thiserror::Error)]
        #[error("outer")]
        struct Outer(#[source] std::io::Error);
        let e = Outer(std::io::Error::other("inner"));
        assert_eq!(error_chain(&e), "outer: inner", "a source not in the message is appended");
    }
}

//! Library errors as the Python exceptions of `colslam.errors`, by kind,
//! with the message `colslam` prints (the error and its causes).

use colslam_slam::{SlamError, error_chain};
use pyo3::prelude::*;
use std::path::Path;

/// The exception classes of `colslam.errors`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// `ColslamError`: anything else (a failure inside the pipeline).
    Base,
    /// `InputError`: the input (or ground truth) cannot be read.
    Input,
    /// `CameraError`: the camera is unusable.
    Camera,
    /// `OptionsError` (also a `ValueError`): an option's value is refused.
    Options,
    /// `UnknownOptionError` (an `OptionsError` and a `TypeError`): no such option.
    UnknownOption,
    /// `OutputError`: the output cannot be written.
    Output,
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::Base => "ColslamError",
            Kind::Input => "InputError",
            Kind::Camera => "CameraError",
            Kind::Options => "OptionsError",
            Kind::UnknownOption => "UnknownOptionError",
            Kind::Output => "OutputError",
        }
    }
}

/// The exception of `kind` with `message` (or the error met while making it).
pub fn raise(py: Python<'_>, kind: Kind, message: impl Into<String>) -> PyErr {
    let make = || -> PyResult<PyErr> {
        let class = py.import("colslam.errors")?.getattr(kind.class_name())?;
        Ok(PyErr::from_value(class.call1((message.into(),))?))
    };
    make().unwrap_or_else(|e| e)
}

/// The exception for a run's error; `output` is the run's output folder
/// (a path error names it or the input).
pub fn slam_error(py: Python<'_>, e: &SlamError, output: &Path) -> PyErr {
    raise(py, slam_kind(e, output), error_chain(e))
}

fn slam_kind(e: &SlamError, output: &Path) -> Kind {
    match e {
        SlamError::InvalidOption { .. } => Kind::Options,
        SlamError::Camera(_) | SlamError::FrameSize { .. } => Kind::Camera,
        SlamError::Source(_) | SlamError::NoFramesRead { .. } | SlamError::Trajectory(_) => Kind::Input,
        SlamError::Output(_) | SlamError::Io { .. } => Kind::Output,
        SlamError::Path { path, .. } => {
            if path == output {
                Kind::Output
            } else {
                Kind::Input
            }
        }
        SlamError::Frame { source, .. } => slam_kind(source, output),
        _ => Kind::Base,
    }
}

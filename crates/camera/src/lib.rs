//! COLMAP camera models with COLMAP's ids, names and parameter order.
//!
//! (Skeleton: the model table. Projection, unprojection, Jacobians,
//! undistortion, camera files and presets are filled in by `models`, `file`
//! and `presets`.)

pub mod model_id;

pub use model_id::CameraModelId;

/// Errors of the camera layer.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The parameter vector has the wrong length for the model.
    #[error("camera model {model} takes {expected} parameters ({names}), got {got}")]
    ParamCount {
        /// Model name.
        model: &'static str,
        /// Expected count.
        expected: usize,
        /// Parameter names in order.
        names: &'static str,
        /// Given count.
        got: usize,
    },
    /// Unknown model id or name.
    #[error("unknown camera model {0:?}")]
    UnknownModel(String),
    /// A parameter is out of its valid range.
    #[error("camera parameter {name} = {value} is invalid: {reason}")]
    InvalidParam {
        /// Parameter name.
        name: String,
        /// Its value.
        value: f64,
        /// Why.
        reason: String,
    },
}

/// A camera: model, image size in pixels and parameters in COLMAP order.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// The model.
    pub model: CameraModelId,
    /// Image width in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// Parameters in COLMAP order (see [`CameraModelId::param_names`]).
    pub params: Vec<f64>,
}

impl Camera {
    /// Builds a camera, checking the parameter count.
    pub fn new(model: CameraModelId, width: u64, height: u64, params: Vec<f64>) -> Result<Self, CameraError> {
        if params.len() != model.num_params() {
            return Err(CameraError::ParamCount {
                model: model.name(),
                expected: model.num_params(),
                names: model.param_names(),
                got: params.len(),
            });
        }
        Ok(Self { model, width, height, params })
    }
}

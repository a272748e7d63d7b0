//! Errors of the SfM layer.

use colslam_scene::ImageId;

/// Errors of the SfM layer.
#[derive(Debug, thiserror::Error)]
pub enum SfmError {
    /// An image was added twice.
    #[error("image {0} is already in the correspondence graph")]
    DuplicateImage(ImageId),
    /// An image is unknown to the graph or the reconstruction.
    #[error("image {0} is not in the correspondence graph")]
    UnknownImage(ImageId),
    /// A keypoint index is out of range for its image.
    #[error("keypoint {idx} is out of range for image {image} ({len} keypoints)")]
    KeypointOutOfRange {
        /// The image.
        image: ImageId,
        /// The index.
        idx: u32,
        /// The number of keypoints of the image.
        len: usize,
    },
    /// Matches between an image and itself.
    #[error("cannot add correspondences between image {0} and itself")]
    SelfMatch(ImageId),
    /// Invalid options.
    #[error("invalid option {name} = {value}: {reason}")]
    InvalidOption {
        /// Option name.
        name: &'static str,
        /// Its value.
        value: String,
        /// Why it is invalid.
        reason: &'static str,
    },
    /// An error of the scene layer.
    #[error(transparent)]
    Scene(#[from] colslam_scene::SceneError),
    /// An error of bundle adjustment.
    #[error("bundle adjustment")]
    Bundle(#[from] colslam_optim::BaError),
    /// An error of a geometric estimator.
    #[error(transparent)]
    Estimator(#[from] colslam_estimators::EstimatorError),
}

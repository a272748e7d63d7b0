//! Robust geometric estimators for colslam.
//!
//! The layout follows PoseLib's "one minimal solver per file, free functions
//! `estimate_<problem>`" style, and the robust layer follows COLMAP's
//! `src/colmap/estimators` (LO-RANSAC, two-view geometry classification).
//!
//! Conventions:
//! * Image points are **normalised** (calibrated) image-plane coordinates
//!   `(x/z, y/z)` unless a function says otherwise; thresholds are in the same
//!   units (a pixel threshold divided by the focal length).
//! * Poses follow COLMAP: `cam2_from_cam1` maps points of camera 1 into
//!   camera 2, `cam_from_world` maps world points into the camera.
//! * Epipolar matrices satisfy `x2ᵀ E x1 = 0`; homographies map `x2 ~ H x1`.
//! * Everything is deterministic: randomness comes from a seeded
//!   [`colslam_geometry::SplitMix64`].

// Range checks are written `!(x > 0.0)` on purpose throughout: NaN must fail
// them, which `x <= 0.0` would not do.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod absolute_pose;
pub mod epnp;
pub mod error;
pub mod essential_5pt;
pub mod fundamental;
pub mod homography;
pub mod p3p;
mod poly;
pub mod ransac;
pub mod relative_pose;
pub mod synthetic;
pub mod triangulation;
pub mod two_view_geometry;

// Generic robust estimation.
pub use ransac::{Estimator, RansacOptions, RansacReport, Support, SupportAccumulator, SupportMeasure, ransac};
// Minimal and non-minimal solvers (one per file).
pub use epnp::estimate_epnp;
pub use essential_5pt::{
    RecoveredPose, decompose_essential, essential_from_pose, estimate_essential_5pt, pose_from_essential,
    sampson_error_sq,
};
pub use fundamental::{estimate_fundamental_7pt, estimate_fundamental_8pt};
pub use homography::{
    HomographyDecomposition, decompose_homography, estimate_homography_dlt, homography_from_pose, homography_poses,
    pose_from_homography, transfer_error_sq,
};
pub use p3p::{estimate_p3p, estimate_p3p_grunert};
// Robust pipelines.
pub use absolute_pose::{
    AbsolutePoseOptions, AbsolutePoseReport, PoseRefineOptions, PoseRefineSummary, RobustLoss, estimate_absolute_pose,
    estimate_absolute_pose_guided, refine_absolute_pose,
};
pub use relative_pose::{
    EssentialEstimator, FundamentalEstimator, HomographyEstimator, RelativePoseOptions, RelativePoseRefineOptions,
    RelativePoseReport, estimate_essential, estimate_fundamental, estimate_homography, estimate_relative_pose,
    refine_relative_pose,
};
pub use triangulation::{
    TriangulatedPoint, TriangulationOptions, TriangulationRejection, triangulate_multiview, triangulate_two_view,
    triangulation_angle,
};
pub use two_view_geometry::{
    TwoViewConfig, TwoViewGeometry, TwoViewGeometryOptions, estimate_two_view_geometry, median_tri_angle_deg,
};
// Errors and re-exports from colslam-geometry (Umeyama similarity included).
pub use colslam_geometry::{Rigid3, Sim3, UmeyamaError, umeyama};
pub use error::{EstimatorError, MAX_COORD};

/// 2-vector of f64 (a normalised image point).
pub type Vec2 = colslam_geometry::Vec2;
/// 3-vector of f64.
pub type Vec3 = colslam_geometry::Vec3;
/// 3x3 matrix of f64.
pub type Mat3 = colslam_geometry::Mat3;

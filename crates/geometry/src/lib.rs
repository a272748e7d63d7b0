//! Pure geometry for colslam: rigid (SE(3)) and similarity (Sim(3)) transforms,
//! quaternion conventions, Umeyama alignment, a small deterministic RNG and
//! the sample statistics ([`stats`]: medians, mean and variance) the crates share.
//!
//! Conventions follow COLMAP: a transform named `a_from_b` maps coordinates
//! expressed in frame `b` into frame `a` (`x_a = a_from_b * x_b`). An image's
//! pose is stored as `cam_from_world`. TUM trajectories store `world_from_cam`.

pub mod random;
pub mod rigid;
pub mod stats;
pub mod umeyama;

pub use nalgebra;
pub use random::SplitMix64;
pub use rigid::{Rigid3, Sim3};
pub use umeyama::{UmeyamaError, umeyama};

/// 3-vector of f64.
pub type Vec3 = nalgebra::Vector3<f64>;
/// 2-vector of f64.
pub type Vec2 = nalgebra::Vector2<f64>;
/// 3x3 matrix of f64.
pub type Mat3 = nalgebra::Matrix3<f64>;
/// Unit quaternion of f64.
pub type Quat = nalgebra::UnitQuaternion<f64>;

//! Bundle adjustment for colslam: a native replacement for the Ceres-based
//! bundle adjustment of COLMAP.
//!
//! * [`Problem`]: cameras (with a chosen subset of refined intrinsics), poses
//!   (`cam_from_world`, fixed, variable, or with fixed translation
//!   coordinates for the gauge), points and observations.
//! * [`BundleAdjuster::solve`]: Levenberg-Marquardt on the reduced camera
//!   system (points eliminated by Schur complement), analytic Jacobians
//!   chained through `colslam_camera`, robust losses with Ceres' semantics
//!   ([`LossFunction`]), parallel deterministic assembly (rayon), and a dense
//!   Cholesky, sparse Cholesky (faer) or block-Jacobi PCG reduced solver
//!   chosen by problem size ([`LinearSolverType`]).
//! * [`synthetic`]: seeded synthetic scenes for tests and benchmarks.
//!
//! Memory is linear in the number of observations: Jacobians are stored per
//! observation, the reduced matrix as its non-zero blocks.

mod layout;
mod linear;
pub mod loss;
pub mod options;
pub mod problem;
pub mod residual;
mod small;
mod solver;
pub mod synthetic;

pub use loss::{LossFunction, LossValue};
pub use options::{BaError, BaOptions, BaReport, BaTimings, LinearSolverType, Termination};
pub use problem::{BaCamera, BaPoint, BaPose, IntrinsicsRefinement, Observation, Problem};
pub use residual::{pose_plus, reprojection_jacobians, reprojection_residual, ResidualJacobians};
pub use solver::BundleAdjuster;

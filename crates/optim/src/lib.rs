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
//! Memory is linear in the number of observations (about 750 bytes each,
//! measured at 1.3 M observations): Jacobians are stored per observation, the
//! `W = J_c^T J_p` blocks per (point, block) pair, the reduced matrix as its
//! non-zero blocks. Nothing is dense in the number of points.
//!
//! Semantics follow Ceres as COLMAP 4 uses it: cost `0.5 * sum rho(|r|^2)`,
//! Ceres' loss functions and corrector, LM with Ceres' trust-region update,
//! LM diagonal clamping and tolerances, and COLMAP's zero residual for a
//! point behind its camera ([`BehindCamera`]). On the same data
//! (`examples/bench_ba.rs`, `scripts/bench-ba-ceres.py`, test
//! `tests/ceres_peer.rs`) pycolmap 4.2.1's Ceres BA reaches the same initial
//! and final cost (to 1e-5, all four losses) in the same number of
//! iterations. Timings on the shared 2-core development machine (under load;
//! single thread, CPU seconds): 100 poses / 20,000 points / 268 k
//! observations, 2 % outliers, Cauchy(1): 2.7-2.9 s vs Ceres 4.6-4.9 s
//! (SPARSE_SCHUR); 7 poses / 3,000 points: 0.09-0.11 s vs 0.14-0.15 s.
//! Jacobi column scaling (Ceres' `jacobi_scaling`) is not applied: with the
//! LM diagonal `diag(J^T J)` the damped system is the same.

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
pub use options::{BaError, BaOptions, BaReport, BaTimings, BehindCamera, LinearSolverType, Termination};
pub use problem::{BaCamera, BaPoint, BaPose, IntrinsicsRefinement, Observation, Problem};
pub use residual::{
    ResidualJacobians, pose_plus, reprojection_jacobians, reprojection_jacobians_with, reprojection_residual,
};
pub use solver::BundleAdjuster;

//! Options, report and errors of the bundle adjuster.

use crate::LossFunction;
use std::time::Duration;

/// How the reduced camera system is solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LinearSolverType {
    /// Dense Schur up to [`BaOptions::max_poses_dense`] variable poses, sparse
    /// Schur up to [`BaOptions::max_poses_sparse`], iterative Schur beyond
    /// (COLMAP's rule, with its thresholds raised for a fast dense Cholesky).
    #[default]
    Auto,
    /// Dense Cholesky of the reduced camera matrix.
    DenseSchur,
    /// Sparse (supernodal/simplicial, AMD-ordered) Cholesky of the reduced
    /// camera matrix (faer).
    SparseSchur,
    /// Preconditioned conjugate gradients on the reduced camera matrix with a
    /// block-Jacobi (Schur-Jacobi) preconditioner.
    IterativeSchur,
}

/// Treatment of observations whose point does not project (behind the
/// camera or on its plane).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BehindCamera {
    /// Residual and Jacobian are zero, as in COLMAP 4's Ceres cost
    /// functions (so pycolmap gives the same costs and steps). A point that
    /// BA moves behind a camera stops costing anything there; the mapper's
    /// negative-depth filter removes such observations after BA.
    #[default]
    ZeroResidual,
    /// Stricter: observations not projecting at the start are skipped, and a
    /// step that moves a used observation's point behind its camera is
    /// rejected.
    Reject,
}

/// Options of [`crate::BundleAdjuster::solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct BaOptions {
    /// Robust loss on the squared reprojection error (pixels^2). Default
    /// trivial (COLMAP's default for BA; its mapper uses Cauchy(1) for
    /// global BA only when asked).
    pub loss: LossFunction,
    /// Refine focal lengths of cameras with [`crate::IntrinsicsRefinement::FromOptions`]. Default true (COLMAP).
    pub refine_focal_length: bool,
    /// Refine principal points. Default false (COLMAP).
    pub refine_principal_point: bool,
    /// Refine distortion parameters. Default true (COLMAP).
    pub refine_extra_params: bool,
    /// Maximum LM iterations, successful or not. Default 100 (COLMAP).
    pub max_iterations: usize,
    /// Stop when `|cost change| <= function_tolerance * cost`. Default 1e-6 (Ceres).
    pub function_tolerance: f64,
    /// Stop when the max-norm of the gradient `<= gradient_tolerance`. Default 1e-10 (Ceres).
    pub gradient_tolerance: f64,
    /// Stop when `|step| <= parameter_tolerance * (|x| + parameter_tolerance)`. Default 1e-8 (Ceres).
    pub parameter_tolerance: f64,
    /// With refined intrinsics: also stop after an accepted step that lowered
    /// the cost by at most `10 * function_tolerance` of it and moved every
    /// camera's focal length by at most this fraction of itself. 0 (the
    /// default) is off. A robust BA that refines the focal length can creep
    /// along the focal length's valley, each Gauss-Newton step lowering the
    /// cost a little and moving the focal length by hundredths of a pixel,
    /// for as many iterations as it is allowed.
    pub focal_step_tolerance: f64,
    /// Initial trust-region radius (1 / initial LM damping). Default 1e4 (Ceres).
    pub initial_trust_region_radius: f64,
    /// Threads for assembly; 0 uses the global rayon pool. Default 0.
    pub num_threads: usize,
    /// Reduced-system solver. Default [`LinearSolverType::Auto`].
    pub linear_solver: LinearSolverType,
    /// `Auto` picks dense Schur up to this many variable poses. Default 200.
    pub max_poses_dense: usize,
    /// `Auto` picks sparse Schur up to this many variable poses, iterative
    /// beyond. Default 1000 (COLMAP).
    pub max_poses_sparse: usize,
    /// Relative residual at which PCG stops. Default 1e-6.
    pub pcg_tolerance: f64,
    /// Maximum PCG iterations per LM step. Default 500 (Ceres).
    pub pcg_max_iterations: usize,
    /// Variable points with fewer observations than this are held constant
    /// (a point seen once is not constrained). Default 2.
    pub min_point_observations: usize,
    /// What an observation whose point does not project (behind the camera)
    /// contributes. Default [`BehindCamera::ZeroResidual`] (COLMAP 4's cost
    /// functions).
    pub behind_camera: BehindCamera,
}

impl Default for BaOptions {
    fn default() -> Self {
        Self {
            loss: LossFunction::Trivial,
            refine_focal_length: true,
            refine_principal_point: false,
            refine_extra_params: true,
            max_iterations: 100,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            focal_step_tolerance: 0.0,
            initial_trust_region_radius: 1e4,
            num_threads: 0,
            linear_solver: LinearSolverType::Auto,
            max_poses_dense: 200,
            max_poses_sparse: 1000,
            pcg_tolerance: 1e-6,
            pcg_max_iterations: 500,
            min_point_observations: 2,
            behind_camera: BehindCamera::ZeroResidual,
        }
    }
}

impl BaOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), BaError> {
        let bad = |m: String| Err(BaError::InvalidOptions(m));
        if let Err(m) = self.loss.validate() {
            return bad(m);
        }
        for (name, v) in [
            ("function_tolerance", self.function_tolerance),
            ("gradient_tolerance", self.gradient_tolerance),
            ("parameter_tolerance", self.parameter_tolerance),
            ("focal_step_tolerance", self.focal_step_tolerance),
            ("pcg_tolerance", self.pcg_tolerance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        let r = self.initial_trust_region_radius;
        if !(r.is_finite() && r > 0.0) {
            return bad(format!("initial_trust_region_radius must be finite and > 0, got {r}"));
        }
        if self.pcg_max_iterations == 0 {
            return bad("pcg_max_iterations must be > 0".into());
        }
        if self.min_point_observations == 0 {
            return bad("min_point_observations must be >= 1".into());
        }
        Ok(())
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// Relative cost change below `function_tolerance`.
    FunctionTolerance,
    /// Gradient max-norm below `gradient_tolerance`.
    GradientTolerance,
    /// Step below `parameter_tolerance`.
    ParameterTolerance,
    /// `max_iterations` reached.
    MaxIterations,
    /// The trust region shrank below its minimum: no step decreases the cost.
    TrustRegionCollapsed,
    /// Nothing to optimise (no observations or every parameter constant):
    /// the problem was left unchanged.
    NothingToOptimize,
}

impl Termination {
    /// True for the convergence criteria (tolerances met).
    pub fn is_converged(self) -> bool {
        matches!(self, Self::FunctionTolerance | Self::GradientTolerance | Self::ParameterTolerance)
    }
}

/// What a solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct BaReport {
    /// Cost `0.5 * sum rho(|r|^2)` before.
    pub initial_cost: f64,
    /// Cost after.
    pub final_cost: f64,
    /// LM iterations (successful and unsuccessful steps).
    pub iterations: usize,
    /// Steps that were accepted.
    pub successful_steps: usize,
    /// Wall time of the whole solve.
    pub time: Duration,
    /// Time in the reduced-system solves (factorisation or PCG only).
    pub linear_solver_time: Duration,
    /// Time per phase.
    pub timings: BaTimings,
    /// Why it stopped.
    pub termination: Termination,
    /// Number of scalar residuals (2 per used observation).
    pub num_residuals: usize,
    /// Observations used.
    pub num_observations: usize,
    /// Observations skipped because their point did not project at the start
    /// (with [`BehindCamera::Reject`]; always 0 with
    /// [`BehindCamera::ZeroResidual`]).
    pub num_skipped_observations: usize,
    /// Variable poses.
    pub num_variable_poses: usize,
    /// Cameras with refined intrinsics.
    pub num_variable_cameras: usize,
    /// Variable points.
    pub num_variable_points: usize,
    /// Variable points held constant for having fewer than
    /// `min_point_observations` observations.
    pub num_points_held_fixed: usize,
    /// Size of the reduced camera system.
    pub num_reduced_parameters: usize,
    /// The linear solver used.
    pub linear_solver: LinearSolverType,
}

/// Wall time per phase of a solve.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BaTimings {
    /// Building the problem layout (index lists, matrix pattern, symbolic
    /// factorisation).
    pub setup: Duration,
    /// Cost evaluations of candidate steps.
    pub evaluate: Duration,
    /// Residuals and Jacobians.
    pub linearize: Duration,
    /// Per-point and camera-side normal-equation terms.
    pub assemble: Duration,
    /// Forming the damped reduced system (Schur complement).
    pub schur: Duration,
    /// Back-substitution and model-cost evaluation.
    pub back_substitution: Duration,
}

/// Errors of the bundle adjuster.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BaError {
    /// An option is out of range.
    #[error("invalid bundle-adjustment options: {0}")]
    InvalidOptions(String),
    /// A camera is malformed.
    #[error("camera {index}: {reason}")]
    InvalidCamera {
        /// Camera index.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// A value is NaN or infinite.
    #[error("{what} {index} has a non-finite value")]
    NonFinite {
        /// Which kind of item.
        what: &'static str,
        /// Its index.
        index: usize,
    },
    /// An observation refers to a missing item.
    #[error("observation {observation}: {what} index {index} out of range ({len} {what}s)")]
    IndexOutOfRange {
        /// Observation index.
        observation: usize,
        /// Which kind of item.
        what: &'static str,
        /// The bad index.
        index: usize,
        /// How many there are.
        len: usize,
    },
    /// The thread pool could not be built.
    #[error("cannot build a thread pool of {0} threads: {1}")]
    ThreadPool(usize, String),
    /// A file could not be written.
    #[error("cannot write {path}: {message}")]
    Io {
        /// The file or folder.
        path: std::path::PathBuf,
        /// The operating-system error.
        message: String,
    },
    /// The sparse solver failed to allocate or analyse the system.
    #[error("linear solver failure: {0}")]
    LinearSolver(String),
}

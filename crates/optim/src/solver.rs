//! Levenberg-Marquardt on the reduced camera system.
//!
//! Each iteration solves `(J^T J + lambda D) delta = -J^T r` by eliminating
//! the points (Schur complement), with `D = diag(J^T J)` clamped to
//! `[MIN_LM_DIAGONAL, MAX_LM_DIAGONAL]` and `lambda = 1 / radius`. The
//! trust-region radius follows Ceres' Levenberg-Marquardt strategy
//! (Nocedal & Wright; Madsen, Nielsen & Tingleff, "Methods for non-linear
//! least squares problems", 2004): on an accepted step with gain ratio `rho`
//! it grows by `1 / max(1/3, 1 - (2 rho - 1)^3)`, on a rejected one it shrinks
//! by a factor that doubles with each consecutive rejection.
//!
//! Parallelism (rayon) never changes results: every parallel loop either
//! writes disjoint outputs or produces partial sums over fixed-size chunks
//! that are then added in chunk order.

use crate::layout::{BlockKind, Layout, MAX_TASK_ROWS, POSE_GROUP};
use crate::linear::{ReducedSolver, SparsePattern};
use crate::loss::Corrector;
use crate::problem::Problem;
use crate::residual::{POSE_DIM, pose_plus, reprojection_jacobians_with, reprojection_residual};
use crate::small::{add_j_x, add_jt_j, add_jt_j_fixed, add_jt_r, spd_inverse3};
use crate::{BaError, BaOptions, BaReport, BaTimings, LinearSolverType, LossFunction, Termination};
use colslam_camera::Camera;
use colslam_geometry::{Rigid3, Vec3};
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Observations per parallel work item (fixed, so sums are reproducible
/// whatever the number of threads).
const OBS_CHUNK: usize = 2048;
/// Bounds of the LM diagonal (Ceres' `min_lm_diagonal`, `max_lm_diagonal`).
const MIN_LM_DIAGONAL: f64 = 1e-6;
const MAX_LM_DIAGONAL: f64 = 1e32;
/// Trust-region radius bounds (Ceres' defaults).
const MAX_TRUST_REGION_RADIUS: f64 = 1e16;
const MIN_TRUST_REGION_RADIUS: f64 = 1e-32;
/// A step is accepted when the gain ratio exceeds this (Ceres' `min_relative_decrease`).
const MIN_RELATIVE_DECREASE: f64 = 1e-3;
/// Largest block of the reduced system: 12 intrinsics (poses have 6).
const MAX_BLOCK_SIZE: usize = crate::residual::MAX_CAMERA_PARAMS;
/// Marks "no pattern entry" in the per-row column lookup.
const NO_ENTRY: usize = usize::MAX;

/// The bundle adjuster.
#[derive(Debug, Clone, Copy, Default)]
pub struct BundleAdjuster;

impl BundleAdjuster {
    /// Refines the variable poses, points and intrinsics of `problem` in
    /// place. Errors on invalid options or problem data (indices out of
    /// range, non-finite values); a problem with nothing to optimise returns
    /// a report with [`Termination::NothingToOptimize`] and is left unchanged.
    pub fn solve(problem: &mut Problem, options: &BaOptions) -> Result<BaReport, BaError> {
        options.validate()?;
        problem.validate()?;
        if options.num_threads > 0 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(options.num_threads)
                .build()
                .map_err(|e| BaError::ThreadPool(options.num_threads, e.to_string()))?;
            pool.install(|| solve_impl(problem, options))
        } else {
            solve_impl(problem, options)
        }
    }
}

/// Parameter values during the solve.
#[derive(Debug, Clone)]
struct State {
    poses: Vec<Rigid3>,
    cameras: Vec<Camera>,
    points: Vec<Vec3>,
}

impl State {
    /// The problem's current values.
    fn from_problem(problem: &Problem) -> Self {
        Self {
            poses: problem.poses.iter().map(|p| p.cam_from_world).collect(),
            cameras: problem.cameras.iter().map(|c| c.camera.clone()).collect(),
            points: problem.points.iter().map(|p| p.xyz).collect(),
        }
    }
}

/// The robustified residuals and Jacobians of the used observations.
/// Jacobians are stored column-major, two values per column, compacted to
/// the free parameters of their block.
struct Jacobians {
    r: Vec<[f64; 2]>,
    j_pose: Vec<[f64; 2 * POSE_DIM]>,
    j_point: Vec<[f64; 6]>,
    j_cam: Vec<f64>,
    /// Stride of `j_cam` per observation (>= 2 so chunking is well defined).
    cam_stride2: usize,
}

impl Jacobians {
    /// Zeroed buffers for the used observations of `layout`.
    fn zeroed(layout: &Layout) -> Self {
        let n = layout.obs.len();
        let stride = 2 * layout.cam_stride.max(1);
        Self {
            r: vec![[0.0; 2]; n],
            j_pose: vec![[0.0; 2 * POSE_DIM]; n],
            j_point: vec![[0.0; 6]; n],
            j_cam: vec![0.0; stride * n],
            cam_stride2: stride,
        }
    }
}

/// Quantities of one linearisation that do not depend on the damping.
struct Linearization {
    /// `V_j = J_p^T J_p` per variable point (3x3 row-major).
    v: Vec<[f64; 9]>,
    /// `g_j = J_p^T r` per variable point.
    g_point: Vec<[f64; 3]>,
    /// `W = J_c^T J_p` per (point, block) entry.
    w: Vec<f64>,
    /// The camera-side terms `J_c^T J_c` in the layout of the reduced matrix.
    u: Vec<f64>,
    /// `g_c = J_c^T r`.
    g_cam: Vec<f64>,
}

/// One LM step.
struct Step {
    d_cam: Vec<f64>,
    d_point: Vec<[f64; 3]>,
    model_change: f64,
}

fn solve_impl(problem: &mut Problem, options: &BaOptions) -> Result<BaReport, BaError> {
    let start = Instant::now();
    let layout = Layout::new(problem, options);
    let mut state = State::from_problem(problem);
    let loss = options.loss;
    let linear_solver_type = match options.linear_solver {
        LinearSolverType::Auto if layout.num_pose_blocks <= options.max_poses_dense => LinearSolverType::DenseSchur,
        LinearSolverType::Auto if layout.num_pose_blocks <= options.max_poses_sparse => LinearSolverType::SparseSchur,
        LinearSolverType::Auto => LinearSolverType::IterativeSchur,
        other => other,
    };
    let initial_cost = evaluate_cost(problem, &layout, &state, &loss).unwrap_or(f64::NAN);
    let mut report = BaReport {
        initial_cost,
        final_cost: initial_cost,
        iterations: 0,
        successful_steps: 0,
        time: Duration::ZERO,
        linear_solver_time: Duration::ZERO,
        timings: BaTimings::default(),
        termination: Termination::NothingToOptimize,
        num_residuals: 2 * layout.obs.len(),
        num_observations: layout.obs.len(),
        num_skipped_observations: layout.num_skipped_observations,
        num_variable_poses: layout.num_pose_blocks,
        num_variable_cameras: layout.blocks.len() - layout.num_pose_blocks,
        num_variable_points: layout.var_points.len(),
        num_points_held_fixed: layout.num_points_held_fixed,
        num_reduced_parameters: layout.reduced_dim,
        linear_solver: linear_solver_type,
    };
    if layout.obs.is_empty() || (layout.blocks.is_empty() && layout.var_points.is_empty()) {
        report.final_cost = if layout.obs.is_empty() { 0.0 } else { initial_cost };
        report.initial_cost = report.final_cost;
        report.time = start.elapsed();
        return Ok(report);
    }
    if !initial_cost.is_finite() {
        // Every used observation projected in `Layout::new`, so only an
        // overflow can get here.
        return Err(BaError::NonFinite { what: "initial cost of problem", index: 0 });
    }
    let solver = match linear_solver_type {
        LinearSolverType::SparseSchur if layout.reduced_dim > 0 => {
            ReducedSolver::Sparse(Box::new(SparsePattern::new(&layout)?))
        }
        LinearSolverType::IterativeSchur => {
            ReducedSolver::Iterative { tolerance: options.pcg_tolerance, max_iterations: options.pcg_max_iterations }
        }
        // Dense, or sparse with an empty reduced system (nothing to factor).
        _ => ReducedSolver::Dense,
    };
    report.linear_solver = linear_solver_type;

    let mut jac = Jacobians::zeroed(&layout);
    let mut cost = initial_cost;
    report.timings.setup = start.elapsed();
    let t = Instant::now();
    let lin_cost = linearize(problem, &layout, &state, &loss, &mut jac);
    if lin_cost.is_none() {
        return Err(BaError::NonFinite { what: "Jacobian of problem", index: 0 });
    }
    report.timings.linearize += t.elapsed();
    let t = Instant::now();
    let mut lin = Linearization {
        v: vec![[0.0; 9]; layout.var_points.len()],
        g_point: vec![[0.0; 3]; layout.var_points.len()],
        w: vec![0.0; layout.w_offset.last().copied().unwrap_or(0)],
        u: vec![0.0; layout.s_offset.last().copied().unwrap_or(0)],
        g_cam: vec![0.0; layout.reduced_dim],
    };
    assemble(&layout, &jac, &mut lin);
    report.timings.assemble += t.elapsed();
    let mut radius = options.initial_trust_region_radius;
    let mut decrease_factor = 2.0;
    report.termination = Termination::MaxIterations;
    if gradient_max_norm(&lin) <= options.gradient_tolerance {
        report.termination = Termination::GradientTolerance;
    } else {
        let mut x_norm = parameter_norm(&layout, &state);
        while report.iterations < options.max_iterations {
            report.iterations += 1;
            let lambda = 1.0 / radius;
            let step = compute_step(&layout, &jac, &lin, lambda, &solver, &mut report);
            let mut accepted = false;
            if let Some(step) = step {
                let step_norm = (step.d_cam.iter().map(|v| v * v).sum::<f64>()
                    + step.d_point.iter().flatten().map(|v| v * v).sum::<f64>())
                .sqrt();
                if step_norm <= options.parameter_tolerance * (x_norm + options.parameter_tolerance) {
                    report.termination = Termination::ParameterTolerance;
                    break;
                }
                let t = Instant::now();
                let candidate = apply_step(&layout, &state, &step);
                let new_cost = evaluate_cost(problem, &layout, &candidate, &loss);
                report.timings.evaluate += t.elapsed();
                if let Some(new_cost) = new_cost.filter(|c| c.is_finite()) {
                    let cost_change = cost - new_cost;
                    let rho = if step.model_change > 0.0 { cost_change / step.model_change } else { f64::NEG_INFINITY };
                    let converged = cost_change.abs() <= options.function_tolerance * cost;
                    if rho > MIN_RELATIVE_DECREASE || (converged && cost_change >= 0.0) {
                        accepted = true;
                        let creeping = options.focal_step_tolerance > 0.0
                            && layout.blocks.len() > layout.num_pose_blocks
                            && cost_change.abs() <= 10.0 * options.function_tolerance * cost
                            && focal_steps_within(&state.cameras, &candidate.cameras, options.focal_step_tolerance);
                        state = candidate;
                        cost = new_cost;
                        report.successful_steps += 1;
                        let factor = (1.0 / 3.0f64).max(1.0 - (2.0 * rho - 1.0).powi(3));
                        radius = (radius / factor).min(MAX_TRUST_REGION_RADIUS);
                        decrease_factor = 2.0;
                        if converged || creeping {
                            report.termination = Termination::FunctionTolerance;
                            break;
                        }
                        let t = Instant::now();
                        let lin_ok = linearize(problem, &layout, &state, &loss, &mut jac).is_some();
                        report.timings.linearize += t.elapsed();
                        if !lin_ok {
                            // The candidate's cost was finite with every
                            // observation projecting, so this cannot happen;
                            // stop with the accepted state if it does.
                            report.termination = Termination::TrustRegionCollapsed;
                            break;
                        }
                        let t = Instant::now();
                        assemble(&layout, &jac, &mut lin);
                        report.timings.assemble += t.elapsed();
                        x_norm = parameter_norm(&layout, &state);
                        if gradient_max_norm(&lin) <= options.gradient_tolerance {
                            report.termination = Termination::GradientTolerance;
                            break;
                        }
                    } else if converged {
                        report.termination = Termination::FunctionTolerance;
                        break;
                    }
                }
            }
            if !accepted {
                radius /= decrease_factor;
                decrease_factor *= 2.0;
                if radius < MIN_TRUST_REGION_RADIUS {
                    report.termination = Termination::TrustRegionCollapsed;
                    break;
                }
            }
        }
    }

    // Write back.
    for (p, s) in problem.poses.iter_mut().zip(&state.poses) {
        p.cam_from_world = *s;
    }
    for (c, s) in problem.cameras.iter_mut().zip(state.cameras) {
        c.camera = s;
    }
    for (p, s) in problem.points.iter_mut().zip(&state.points) {
        p.xyz = *s;
    }
    report.final_cost = cost;
    report.time = start.elapsed();
    Ok(report)
}

/// True when every camera's focal lengths moved by at most `tol` of
/// themselves from `before` to `after`.
fn focal_steps_within(before: &[Camera], after: &[Camera], tol: f64) -> bool {
    before.iter().zip(after).all(|(a, b)| {
        [(a.focal_x(), b.focal_x()), (a.focal_y(), b.focal_y())]
            .iter()
            .all(|(f0, f1)| (f1 - f0).abs() <= tol * f0.abs())
    })
}

/// `0.5 * sum rho(|r|^2)` over the used observations; `None` when one of them
/// does not project.
fn evaluate_cost(problem: &Problem, layout: &Layout, state: &State, loss: &LossFunction) -> Option<f64> {
    let zero_unprojectable = layout.zero_unprojectable;
    let partial: Vec<Option<f64>> = layout
        .obs
        .par_chunks(OBS_CHUNK)
        .map(|chunk| {
            let mut sum = 0.0;
            for o in chunk {
                let ob = &problem.observations[o.obs];
                let r = reprojection_residual(
                    &state.cameras[o.camera],
                    &state.poses[o.pose],
                    &state.points[o.point],
                    &ob.pixel,
                )
                .map(|r| r * ob.weight);
                let Some(r) = r else {
                    if zero_unprojectable {
                        continue;
                    }
                    return None;
                };
                sum += loss.evaluate(r.norm_squared()).rho;
            }
            Some(sum)
        })
        .collect();
    let mut total = 0.0;
    for p in partial {
        total += p?;
    }
    Some(0.5 * total)
}

/// Evaluates robustified residuals and Jacobians; returns the cost, or `None`
/// when an observation does not project.
fn linearize(
    problem: &Problem,
    layout: &Layout,
    state: &State,
    loss: &LossFunction,
    jac: &mut Jacobians,
) -> Option<f64> {
    let zero_unprojectable = layout.zero_unprojectable;
    let stride = jac.cam_stride2;
    let partial: Vec<Option<f64>> = jac
        .r
        .par_chunks_mut(OBS_CHUNK)
        .zip(jac.j_pose.par_chunks_mut(OBS_CHUNK))
        .zip(jac.j_point.par_chunks_mut(OBS_CHUNK))
        .zip(jac.j_cam.par_chunks_mut(OBS_CHUNK * stride))
        .zip(layout.obs.par_chunks(OBS_CHUNK))
        .map(|((((rs, jps), jpts), jcs), obs)| {
            let mut sum = 0.0;
            for (k, o) in obs.iter().enumerate() {
                let ob = &problem.observations[o.obs];
                let rj = reprojection_jacobians_with(
                    &state.cameras[o.camera],
                    &state.poses[o.pose],
                    &state.points[o.point],
                    &ob.pixel,
                    o.cam_block.is_some(),
                )
                .map(|mut rj| {
                    // Whitening by the measurement's inverse standard deviation.
                    if ob.weight != 1.0 {
                        rj.residual *= ob.weight;
                        rj.d_pose *= ob.weight;
                        rj.d_point *= ob.weight;
                        rj.d_params *= ob.weight;
                    }
                    rj
                });
                let Some(rj) = rj else {
                    if !zero_unprojectable {
                        return None;
                    }
                    // Zero residual and Jacobian (the buffers are reused).
                    rs[k] = [0.0; 2];
                    jps[k] = [0.0; 2 * POSE_DIM];
                    jpts[k] = [0.0; 6];
                    jcs[k * stride..(k + 1) * stride].iter_mut().for_each(|v| *v = 0.0);
                    continue;
                };
                let r = rj.residual;
                let s = r.norm_squared();
                if !s.is_finite() {
                    return None;
                }
                let v = loss.evaluate(s);
                sum += v.rho;
                let c = Corrector::new(s, &v);
                let fix = |col: nalgebra::VectorView2<f64, nalgebra::U1, nalgebra::U2>| -> [f64; 2] {
                    let d = c.alpha_sq_norm * r.dot(&col);
                    [c.sqrt_rho1 * (col[0] - d * r[0]), c.sqrt_rho1 * (col[1] - d * r[1])]
                };
                rs[k] = [c.residual_scale * r[0], c.residual_scale * r[1]];
                if let Some(b) = o.pose_block
                    && let BlockKind::Pose { dims, .. } = &layout.blocks[b].kind
                {
                    for (m, &d) in dims.iter().enumerate() {
                        let col = fix(rj.d_pose.column(d));
                        jps[k][2 * m] = col[0];
                        jps[k][2 * m + 1] = col[1];
                    }
                }
                if let Some(b) = o.cam_block
                    && let BlockKind::Camera { params, .. } = &layout.blocks[b].kind
                {
                    let jc = &mut jcs[k * stride..(k + 1) * stride];
                    for (m, &p) in params.iter().enumerate() {
                        let col = fix(rj.d_params.column(p));
                        jc[2 * m] = col[0];
                        jc[2 * m + 1] = col[1];
                    }
                }
                if o.var_point.is_some() {
                    for m in 0..3 {
                        let col = fix(rj.d_point.column(m));
                        jpts[k][2 * m] = col[0];
                        jpts[k][2 * m + 1] = col[1];
                    }
                }
            }
            Some(sum)
        })
        .collect();
    let mut total = 0.0;
    for p in partial {
        total += p?;
    }
    Some(0.5 * total)
}

/// Splits `data` into consecutive mutable pieces of the given lengths.
fn split_lengths(mut data: &mut [f64], lengths: impl Iterator<Item = usize>) -> Vec<&mut [f64]> {
    let mut out = Vec::new();
    for len in lengths {
        let (head, tail) = std::mem::take(&mut data).split_at_mut(len);
        out.push(head);
        data = tail;
    }
    out
}

/// The camera-side Jacobian of observation `k` for block `b` (a pose or a
/// camera block of that observation).
#[inline]
fn cam_side_jacobian<'a>(layout: &Layout, jac: &'a Jacobians, k: usize, b: usize) -> &'a [f64] {
    if b < layout.num_pose_blocks {
        &jac.j_pose[k][..]
    } else {
        &jac.j_cam[k * jac.cam_stride2..(k + 1) * jac.cam_stride2]
    }
}

/// Builds the damping-independent terms: per-point `V`, `g`, `W`, and the
/// camera-side `U` and `g_c`.
/// The buffers of `lin` are reused across iterations (sized by the layout).
fn assemble(layout: &Layout, jac: &Jacobians, lin: &mut Linearization) {
    let np = layout.var_points.len();
    let Linearization { v, g_point, w, u, g_cam } = lin;
    v.iter_mut().for_each(|x| *x = [0.0; 9]);
    g_point.iter_mut().for_each(|x| *x = [0.0; 3]);
    w.iter_mut().for_each(|x| *x = 0.0);
    u.iter_mut().for_each(|x| *x = 0.0);
    g_cam.iter_mut().for_each(|x| *x = 0.0);
    {
        let w_pieces = split_lengths(
            w,
            (0..np)
                .map(|j| layout.w_offset[layout.point_blocks.ptr[j + 1]] - layout.w_offset[layout.point_blocks.ptr[j]]),
        );
        v.par_iter_mut().zip(g_point.par_iter_mut()).zip(w_pieces.into_par_iter()).enumerate().for_each(
            |(j, ((vj, gj), wj))| {
                let base = layout.w_offset[layout.point_blocks.ptr[j]];
                for &k in layout.point_obs.row(j) {
                    let jp = &jac.j_point[k];
                    add_jt_j_fixed::<3, 3>(vj, jp, jp);
                    add_jt_r(gj, jp, 3, &jac.r[k]);
                    let o = &layout.obs[k];
                    for (entry, blk) in [(o.pose_entry, o.pose_block), (o.cam_entry, o.cam_block)] {
                        if let (Some(e), Some(b)) = (entry, blk) {
                            let size = layout.blocks[b].size;
                            let jc = cam_side_jacobian(layout, jac, k, b);
                            let off = layout.w_offset[e] - base;
                            if size == POSE_DIM {
                                add_jt_j_fixed::<POSE_DIM, 3>(&mut wj[off..off + 3 * size], jc, jp);
                            } else {
                                add_jt_j(&mut wj[off..off + 3 * size], jc, size, jp, 3);
                            }
                        }
                    }
                }
            },
        );
    }
    // Camera-side terms. Pose rows are filled per group of consecutive pose
    // blocks (each group owns its rows), camera rows one per task; every
    // row's sum runs in increasing observation order (deterministic).
    let nb = layout.blocks.len();
    let npb = layout.num_pose_blocks;
    let row_start = |b: usize| layout.s_offset[layout.s_cols.ptr[b]];
    let vec_start = |b: usize| layout.blocks.get(b).map_or(layout.reduced_dim, |bb| bb.offset);
    let (u_pose, u_cams) = u.split_at_mut(row_start(npb));
    let (g_pose, g_cams) = g_cam.split_at_mut(vec_start(npb));
    let ngroups = layout.pose_group_obs.ptr.len() - 1;
    let group_end = |g: usize| ((g + 1) * POSE_GROUP).min(npb);
    let u_groups = split_lengths(u_pose, (0..ngroups).map(|g| row_start(group_end(g)) - row_start(g * POSE_GROUP)));
    let g_groups = split_lengths(g_pose, (0..ngroups).map(|g| vec_start(group_end(g)) - vec_start(g * POSE_GROUP)));
    u_groups.into_par_iter().zip(g_groups.into_par_iter()).enumerate().for_each(|(g, (ug, gg))| {
        let b0 = g * POSE_GROUP;
        let (ubase, gbase) = (row_start(b0), vec_start(b0));
        let diag: Vec<Option<usize>> =
            (b0..group_end(g)).map(|b| layout.s_entry(b, b).map(|e| layout.s_offset[e] - ubase)).collect();
        // Last (camera block, value offset) coupling of each pose block: a
        // pose is nearly always seen through one camera.
        let mut last: Vec<Option<(usize, usize)>> = vec![None; diag.len()];
        for &(k, b, cam_block) in layout.pose_group_obs.row(g) {
            let size = layout.blocks[b].size;
            let jc = &jac.j_pose[k][..];
            let goff = layout.blocks[b].offset - gbase;
            add_jt_r(&mut gg[goff..goff + size], jc, size, &jac.r[k]);
            if let Some(d) = diag[b - b0] {
                if size == POSE_DIM {
                    add_jt_j_fixed::<POSE_DIM, POSE_DIM>(&mut ug[d..d + size * size], jc, jc);
                } else {
                    add_jt_j(&mut ug[d..d + size * size], jc, size, jc, size);
                }
            }
            // Pose-intrinsics coupling of the same observation.
            let Some(cb) = cam_block else { continue };
            let off = match last[b - b0] {
                Some((c, off)) if c == cb => off,
                _ => {
                    let Some(e) = layout.s_entry(b, cb) else { continue };
                    let off = layout.s_offset[e] - ubase;
                    last[b - b0] = Some((cb, off));
                    off
                }
            };
            let cs = layout.blocks[cb].size;
            let jcam = cam_side_jacobian(layout, jac, k, cb);
            add_jt_j(&mut ug[off..off + size * cs], jc, size, jcam, cs);
        }
    });
    let u_rows = split_lengths(u_cams, (npb..nb).map(|b| row_start(b + 1) - row_start(b)));
    let g_rows = split_lengths(g_cams, layout.blocks[npb..].iter().map(|b| b.size));
    u_rows.into_par_iter().zip(g_rows.into_par_iter()).enumerate().for_each(|(i, (ub, gb))| {
        let b = npb + i;
        let size = layout.blocks[b].size;
        let Some(d) = layout.s_entry(b, b).map(|e| layout.s_offset[e] - row_start(b)) else { return };
        for &k in layout.block_obs.row(b) {
            let jc = cam_side_jacobian(layout, jac, k, b);
            add_jt_r(gb, jc, size, &jac.r[k]);
            add_jt_j(&mut ub[d..d + size * size], jc, size, jc, size);
        }
    });
}

fn gradient_max_norm(lin: &Linearization) -> f64 {
    lin.g_cam.iter().chain(lin.g_point.iter().flatten()).fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Norm of the variable parameters in their ambient representation
/// (quaternion and translation, refined intrinsics, point coordinates).
fn parameter_norm(layout: &Layout, state: &State) -> f64 {
    let mut sq = 0.0;
    for b in &layout.blocks {
        match &b.kind {
            BlockKind::Pose { pose, .. } => sq += 1.0 + state.poses[*pose].translation.norm_squared(),
            BlockKind::Camera { camera, params } => {
                sq += params.iter().map(|&p| state.cameras[*camera].params[p].powi(2)).sum::<f64>()
            }
        }
    }
    sq += layout.var_points.iter().map(|&j| state.points[j].norm_squared()).sum::<f64>();
    sq.sqrt()
}

#[inline]
fn clamp_diag(d: f64) -> f64 {
    d.clamp(MIN_LM_DIAGONAL, MAX_LM_DIAGONAL)
}

/// Solves the damped normal equations by Schur complement; `None` when a
/// factorisation fails.
fn compute_step(
    layout: &Layout,
    jac: &Jacobians,
    lin: &Linearization,
    lambda: f64,
    solver: &ReducedSolver,
    report: &mut BaReport,
) -> Option<Step> {
    let t = Instant::now();
    let np = layout.var_points.len();
    // 1. Damped point blocks and their inverses.
    let v_inv: Vec<Option<[f64; 9]>> = lin
        .v
        .par_iter()
        .map(|v| {
            let mut a = *v;
            for i in 0..3 {
                a[4 * i] += lambda * clamp_diag(v[4 * i]);
            }
            spd_inverse3(&a)
        })
        .collect();
    let v_inv: Vec<[f64; 9]> = v_inv.into_iter().collect::<Option<Vec<_>>>()?;

    // 2. Reduced matrix S = U + lambda D - W V^-1 W^T and rhs = -g_c + W V^-1 g_p.
    // Each task owns a run of block rows (a group of consecutive poses, or
    // one camera) and walks its points in increasing order, so every S
    // block sums its point terms in the same order whatever the threads.
    let mut s = lin.u.clone();
    let mut rhs = vec![0.0; layout.reduced_dim];
    {
        let nb = layout.blocks.len();
        let row_start = |b: usize| layout.s_offset[layout.s_cols.ptr[b]];
        let vec_start = |b: usize| layout.blocks.get(b).map_or(layout.reduced_dim, |bb| bb.offset);
        let tasks = &layout.schur_tasks;
        let s_parts = split_lengths(&mut s, tasks.iter().map(|&(b0, b1)| row_start(b1) - row_start(b0)));
        let rhs_parts = split_lengths(&mut rhs, tasks.iter().map(|&(b0, b1)| vec_start(b1) - vec_start(b0)));
        // Per-thread scratch: (row - b0, column block) -> value offset in the
        // task's slice (NO_ENTRY elsewhere); filled and cleared per task.
        s_parts.into_par_iter().zip(rhs_parts.into_par_iter()).enumerate().for_each_init(
            || vec![NO_ENTRY; MAX_TASK_ROWS * nb],
            |col_off, (task, (st, rt))| {
                let (b0, b1) = tasks[task];
                let (sbase, vbase) = (row_start(b0), vec_start(b0));
                for b in b0..b1 {
                    for e in layout.s_cols.range(b) {
                        col_off[(b - b0) * nb + layout.s_cols.val[e]] = layout.s_offset[e] - sbase;
                    }
                    let size = layout.blocks[b].size;
                    let d = col_off[(b - b0) * nb + b];
                    if d != NO_ENTRY {
                        for i in 0..size {
                            let idx = d + i * size + i;
                            st[idx] += lambda * clamp_diag(lin.u[sbase + idx]);
                        }
                    }
                    let off = layout.blocks[b].offset;
                    for (ri, g) in rt[off - vbase..off - vbase + size].iter_mut().zip(&lin.g_cam[off..off + size]) {
                        *ri = -g;
                    }
                }
                let mut y = [0.0; 3 * MAX_BLOCK_SIZE];
                for &j in layout.schur_task_points.row(task) {
                    let vi = &v_inv[j];
                    let gp = &lin.g_point[j];
                    let entries = layout.point_blocks.range(j);
                    for e in entries.clone() {
                        let b = layout.point_blocks.val[e];
                        if b < b0 || b >= b1 {
                            continue;
                        }
                        let size = layout.blocks[b].size;
                        let we = &lin.w[layout.w_offset[e]..layout.w_offset[e + 1]];
                        // Y = W_e V^-1 (size x 3).
                        for i in 0..size {
                            for m in 0..3 {
                                y[3 * i + m] =
                                    we[3 * i] * vi[m] + we[3 * i + 1] * vi[3 + m] + we[3 * i + 2] * vi[6 + m];
                            }
                        }
                        let ro = layout.blocks[b].offset - vbase;
                        for i in 0..size {
                            rt[ro + i] += y[3 * i] * gp[0] + y[3 * i + 1] * gp[1] + y[3 * i + 2] * gp[2];
                        }
                        for e2 in e..entries.end {
                            let b2 = layout.point_blocks.val[e2];
                            let off = col_off[(b - b0) * nb + b2];
                            if off == NO_ENTRY {
                                // Every pair of blocks of one point is in the pattern.
                                continue;
                            }
                            let s2 = layout.blocks[b2].size;
                            let w2 = &lin.w[layout.w_offset[e2]..layout.w_offset[e2 + 1]];
                            let out = &mut st[off..off + size * s2];
                            if size == POSE_DIM && s2 == POSE_DIM {
                                sub_y_wt::<POSE_DIM, POSE_DIM>(out, &y, w2);
                            } else {
                                sub_y_wt_dyn(out, &y, size, w2, s2);
                            }
                        }
                    }
                }
                for b in b0..b1 {
                    for e in layout.s_cols.range(b) {
                        col_off[(b - b0) * nb + layout.s_cols.val[e]] = NO_ENTRY;
                    }
                }
            },
        );
    }
    report.timings.schur += t.elapsed();

    // 3. Reduced solve.
    let t = Instant::now();
    let d_cam = solver.solve(layout, &s, &rhs);
    report.linear_solver_time += t.elapsed();
    let d_cam = d_cam?;
    let t = Instant::now();

    // 4. Back-substitution: dp_j = V_j^-1 (-g_j - sum W^T dc).
    let d_point: Vec<[f64; 3]> = (0..np)
        .into_par_iter()
        .map(|j| {
            let mut t = lin.g_point[j].map(|g| -g);
            for e in layout.point_blocks.range(j) {
                let bb = &layout.blocks[layout.point_blocks.val[e]];
                let we = &lin.w[layout.w_offset[e]..layout.w_offset[e + 1]];
                let dc = &d_cam[bb.offset..bb.offset + bb.size];
                for i in 0..bb.size {
                    for m in 0..3 {
                        t[m] -= we[3 * i + m] * dc[i];
                    }
                }
            }
            let vi = &v_inv[j];
            [0, 1, 2].map(|m| (0..3).map(|q| vi[3 * m + q] * t[q]).sum())
        })
        .collect();

    // 5. Model decrease -(g^T d + 0.5 |J d|^2), summed per observation.
    let partial: Vec<f64> = layout
        .obs
        .par_chunks(OBS_CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut sum = 0.0;
            for (i, o) in chunk.iter().enumerate() {
                let k = c * OBS_CHUNK + i;
                let mut u = [0.0; 2];
                for b in [o.pose_block, o.cam_block].into_iter().flatten() {
                    let bb = &layout.blocks[b];
                    add_j_x(
                        &mut u,
                        cam_side_jacobian(layout, jac, k, b),
                        bb.size,
                        &d_cam[bb.offset..bb.offset + bb.size],
                    );
                }
                if let Some(j) = o.var_point {
                    add_j_x(&mut u, &jac.j_point[k], 3, &d_point[j]);
                }
                let r = &jac.r[k];
                sum += r[0] * u[0] + r[1] * u[1] + 0.5 * (u[0] * u[0] + u[1] * u[1]);
            }
            sum
        })
        .collect();
    let model_change = -partial.iter().sum::<f64>();
    report.timings.back_substitution += t.elapsed();
    Some(Step { d_cam, d_point, model_change })
}

/// `out (R x C) -= y w^T` with `y` R x 3 and `w` C x 3, row-major; fixed
/// sizes so the compiler unrolls the common pose-pose case.
#[inline]
fn sub_y_wt<const R: usize, const C: usize>(out: &mut [f64], y: &[f64], w: &[f64]) {
    let (out, y, w) = (&mut out[..R * C], &y[..3 * R], &w[..3 * C]);
    for i in 0..R {
        for k in 0..C {
            out[i * C + k] -= y[3 * i] * w[3 * k] + y[3 * i + 1] * w[3 * k + 1] + y[3 * i + 2] * w[3 * k + 2];
        }
    }
}

/// [`sub_y_wt`] for run-time sizes.
#[inline]
fn sub_y_wt_dyn(out: &mut [f64], y: &[f64], r: usize, w: &[f64], c: usize) {
    for i in 0..r {
        for k in 0..c {
            out[i * c + k] -= y[3 * i] * w[3 * k] + y[3 * i + 1] * w[3 * k + 1] + y[3 * i + 2] * w[3 * k + 2];
        }
    }
}

/// The state moved by a step.
fn apply_step(layout: &Layout, state: &State, step: &Step) -> State {
    let mut out = state.clone();
    for b in &layout.blocks {
        let d = &step.d_cam[b.offset..b.offset + b.size];
        match &b.kind {
            BlockKind::Pose { pose, dims } => {
                let mut delta = [0.0; POSE_DIM];
                for (&dim, v) in dims.iter().zip(d) {
                    delta[dim] = *v;
                }
                out.poses[*pose] = pose_plus(&state.poses[*pose], &delta);
            }
            BlockKind::Camera { camera, params } => {
                for (&p, v) in params.iter().zip(d) {
                    out.cameras[*camera].params[p] += v;
                }
            }
        }
    }
    for (j, &pt) in layout.var_points.iter().enumerate() {
        let d = step.d_point[j];
        out.points[pt] += Vec3::new(d[0], d[1], d[2]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::IntrinsicsRefinement;
    use crate::synthetic::{SyntheticOptions, perturb, synthetic_scene};

    /// A BA that refines the focal length stops once a step moves it by
    /// under `focal_step_tolerance` of itself and lowers the cost by under
    /// ten times the function tolerance, at the cost the full solve reaches
    /// (to 1e-4); with the intrinsics held the option changes nothing.
    #[test]
    fn a_creeping_focal_length_ends_the_solve() {
        let camera = crate::residual::tests::sample_camera(colslam_camera::CameraModelId::SimpleRadial);
        let s = synthetic_scene(&SyntheticOptions {
            num_poses: 8,
            num_points: 300,
            camera: camera.clone(),
            pixel_noise: 1.0,
            seed: 5,
            ..Default::default()
        })
        .unwrap();
        let mut start = s.problem.clone();
        perturb(&mut start, 0.01, 0.02, 0.05, 6);
        start.poses[0].fixed = true;
        start.poses[1].fixed_translation[2] = true;
        let solve = |refine: bool, focal_step_tolerance: f64| {
            let mut p = start.clone();
            p.cameras[0].refine = if refine {
                IntrinsicsRefinement::Params((0..p.cameras[0].camera.params.len()).collect())
            } else {
                IntrinsicsRefinement::Fixed
            };
            let o = BaOptions {
                loss: LossFunction::Cauchy(1.0),
                function_tolerance: 1e-9,
                max_iterations: 200,
                focal_step_tolerance,
                ..Default::default()
            };
            let r = BundleAdjuster::solve(&mut p, &o).unwrap();
            (r, p)
        };
        let (full, _) = solve(true, 0.0);
        let (stopped, _) = solve(true, 1e-4);
        assert!(stopped.iterations < full.iterations, "{} against {} iterations", stopped.iterations, full.iterations);
        assert_eq!(stopped.termination, Termination::FunctionTolerance);
        assert!((stopped.final_cost - full.final_cost).abs() <= 1e-4 * full.final_cost, "{stopped:?} {full:?}");
        let ((held, p_held), (held_opt, p_held_opt)) = (solve(false, 0.0), solve(false, 1e-4));
        assert_eq!((held.iterations, held.final_cost), (held_opt.iterations, held_opt.final_cost));
        assert_eq!(
            p_held.points.iter().map(|p| p.xyz).collect::<Vec<_>>(),
            p_held_opt.points.iter().map(|p| p.xyz).collect::<Vec<_>>()
        );
        assert!(focal_steps_within(std::slice::from_ref(&camera), std::slice::from_ref(&camera), 0.0));
    }

    /// The assembled gradient `J~^T r~` (robust corrector, compacted free
    /// dims, fixed translation coordinate) equals the finite-difference
    /// gradient of the robust cost, for every camera model.
    #[test]
    fn gradient_matches_finite_differences_of_the_cost() {
        // Every model on a tiny scene; one scene with several pose groups of
        // the camera-side pass.
        let cases = colslam_camera::CameraModelId::ALL.into_iter().map(|m| (m, 3, 15)).chain([(
            colslam_camera::CameraModelId::SimpleRadial,
            2 * POSE_GROUP + 3,
            60,
        )]);
        for (model, num_poses, num_points) in cases {
            let camera = crate::residual::tests::sample_camera(model);
            let mut s = synthetic_scene(&SyntheticOptions {
                num_poses,
                num_points,
                camera,
                pixel_noise: 2.0,
                seed: 21,
                ..Default::default()
            })
            .unwrap();
            let mut problem = s.problem.clone();
            perturb(&mut problem, 0.01, 0.02, 0.05, 22);
            problem.poses[1].fixed_translation[2] = true;
            problem.poses[num_poses - 1].fixed = true;
            let n = problem.cameras[0].camera.params.len();
            problem.cameras[0].refine = IntrinsicsRefinement::Params((0..n).collect());
            s.problem = problem;
            let options = BaOptions { loss: LossFunction::Cauchy(1.5), ..Default::default() };
            let layout = Layout::new(&s.problem, &options);
            assert_eq!(layout.obs.len(), s.problem.observations.len(), "{model}");
            let state = State::from_problem(&s.problem);
            let mut jac = Jacobians::zeroed(&layout);
            let cost = linearize(&s.problem, &layout, &state, &options.loss, &mut jac).unwrap();
            let cost_eval = evaluate_cost(&s.problem, &layout, &state, &options.loss).unwrap();
            assert!((cost - cost_eval).abs() < 1e-12 * cost);
            let mut lin = Linearization {
                v: vec![[0.0; 9]; layout.var_points.len()],
                g_point: vec![[0.0; 3]; layout.var_points.len()],
                w: vec![0.0; *layout.w_offset.last().unwrap()],
                u: vec![0.0; *layout.s_offset.last().unwrap()],
                g_cam: vec![0.0; layout.reduced_dim],
            };
            assemble(&layout, &jac, &mut lin);
            // Pose 1: 5 dims, the last pose fixed, the others 6; then all intrinsics.
            assert_eq!(layout.reduced_dim, 6 * (num_poses - 2) + 5 + n, "{model}");
            let first_intrinsic = layout.reduced_dim - n;
            let zero = Step {
                d_cam: vec![0.0; layout.reduced_dim],
                d_point: vec![[0.0; 3]; layout.var_points.len()],
                model_change: 0.0,
            };
            let fd = |set: &dyn Fn(&mut Step, f64), h: f64| {
                let mut plus = Step { d_cam: zero.d_cam.clone(), d_point: zero.d_point.clone(), model_change: 0.0 };
                set(&mut plus, h);
                let mut minus = Step { d_cam: zero.d_cam.clone(), d_point: zero.d_point.clone(), model_change: 0.0 };
                set(&mut minus, -h);
                let cp =
                    evaluate_cost(&s.problem, &layout, &apply_step(&layout, &state, &plus), &options.loss).unwrap();
                let cm =
                    evaluate_cost(&s.problem, &layout, &apply_step(&layout, &state, &minus), &options.loss).unwrap();
                (cp - cm) / (2.0 * h)
            };
            for i in 0..layout.reduced_dim {
                let scale = if i >= first_intrinsic {
                    state.cameras[0].params[i - first_intrinsic].abs().max(1e-2)
                } else {
                    1.0
                };
                let h = 1e-6 * scale;
                let g = fd(&|st: &mut Step, h: f64| st.d_cam[i] = h, h);
                assert!(
                    (g - lin.g_cam[i]).abs() < 1e-5 * (1.0 + g.abs()),
                    "{model} reduced param {i}: fd {g} vs {}",
                    lin.g_cam[i]
                );
            }
            for j in 0..layout.var_points.len() {
                for m in 0..3 {
                    let g = fd(&|st: &mut Step, h: f64| st.d_point[j][m] = h, 1e-6);
                    let a = lin.g_point[j][m];
                    assert!((g - a).abs() < 1e-5 * (1.0 + g.abs()), "{model} point {j}.{m}: fd {g} vs {a}");
                }
            }
        }
    }

    /// The Schur-complement step (every reduced solver) equals the solution of
    /// the full damped normal equations built from a dense Jacobian, and the
    /// model decrease matches `-(g^T d + 0.5 |J d|^2)`.
    #[test]
    fn schur_step_matches_dense_normal_equations() {
        let mut s = synthetic_scene(&SyntheticOptions {
            num_poses: 2 * POSE_GROUP + 3,
            num_points: 60,
            pixel_noise: 1.0,
            seed: 31,
            ..Default::default()
        })
        .unwrap();
        perturb(&mut s.problem, 0.01, 0.02, 0.05, 32);
        s.problem.fix_gauge(0, 1);
        // One point fixed: its observations contribute to U only.
        s.problem.points[5].fixed = true;
        let options = BaOptions { loss: LossFunction::Huber(2.0), ..Default::default() };
        let layout = Layout::new(&s.problem, &options);
        assert!(layout.schur_tasks.len() >= 4);
        let state = State::from_problem(&s.problem);
        let mut jac = Jacobians::zeroed(&layout);
        let (n_obs, stride) = (layout.obs.len(), jac.cam_stride2);
        linearize(&s.problem, &layout, &state, &options.loss, &mut jac).unwrap();
        let mut lin = Linearization {
            v: vec![[0.0; 9]; layout.var_points.len()],
            g_point: vec![[0.0; 3]; layout.var_points.len()],
            w: vec![0.0; *layout.w_offset.last().unwrap()],
            u: vec![0.0; *layout.s_offset.last().unwrap()],
            g_cam: vec![0.0; layout.reduced_dim],
        };
        assemble(&layout, &jac, &mut lin);
        // Dense Jacobian.
        let nc = layout.reduced_dim;
        let n = nc + 3 * layout.var_points.len();
        let mut j = nalgebra::DMatrix::<f64>::zeros(2 * n_obs, n);
        let mut r = nalgebra::DVector::<f64>::zeros(2 * n_obs);
        for (k, o) in layout.obs.iter().enumerate() {
            for row in 0..2 {
                r[2 * k + row] = jac.r[k][row];
                if let Some(b) = o.pose_block {
                    for m in 0..layout.blocks[b].size {
                        j[(2 * k + row, layout.blocks[b].offset + m)] = jac.j_pose[k][2 * m + row];
                    }
                }
                if let Some(b) = o.cam_block {
                    for m in 0..layout.blocks[b].size {
                        j[(2 * k + row, layout.blocks[b].offset + m)] = jac.j_cam[k * stride + 2 * m + row];
                    }
                }
                if let Some(p) = o.var_point {
                    for m in 0..3 {
                        j[(2 * k + row, nc + 3 * p + m)] = jac.j_point[k][2 * m + row];
                    }
                }
            }
        }
        let lambda = 1e-3;
        let jt = j.transpose();
        let mut a = &jt * &j;
        let g = &jt * &r;
        for i in 0..n {
            a[(i, i)] += lambda * clamp_diag(a[(i, i)]);
        }
        let full = a.cholesky().unwrap().solve(&(-&g));
        for solver in [
            ReducedSolver::Dense,
            ReducedSolver::Sparse(Box::new(SparsePattern::new(&layout).unwrap())),
            ReducedSolver::Iterative { tolerance: 1e-12, max_iterations: 1000 },
        ] {
            let mut report = solve_impl(&mut Problem::default(), &options).unwrap();
            let step = compute_step(&layout, &jac, &lin, lambda, &solver, &mut report).unwrap();
            let mut got = nalgebra::DVector::<f64>::zeros(n);
            for i in 0..nc {
                got[i] = step.d_cam[i];
            }
            for (p, d) in step.d_point.iter().enumerate() {
                for m in 0..3 {
                    got[nc + 3 * p + m] = d[m];
                }
            }
            let err = (&got - &full).norm() / full.norm();
            assert!(err < 1e-8, "relative step error {err}");
            let jd = &j * &got;
            let model = -(g.dot(&got) + 0.5 * jd.norm_squared());
            assert!((model - step.model_change).abs() < 1e-9 * model.abs(), "{model} vs {}", step.model_change);
        }
    }
}

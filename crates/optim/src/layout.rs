//! The structure of a problem, computed once per solve: which parameters
//! vary, the parameter blocks of the reduced camera system, and the index
//! lists (compressed rows) that the parallel assembly walks.
//!
//! Reduced-system blocks: one per variable pose (its free tangent dims), then
//! one per camera with refined intrinsics. Points are eliminated (Schur).
//! Block order puts every pose block before every camera block, so the
//! pose-intrinsics coupling of an observation always lies in the upper
//! triangle at (pose block, camera block).

use crate::problem::{IntrinsicsRefinement, Problem};
use crate::residual::reprojection_residual;
use crate::{BaOptions, BehindCamera};

/// Pose blocks per group in the camera-side assembly pass (more than a
/// typical track length, so that a group's observations are dense).
pub(crate) const POSE_GROUP: usize = 16;

/// Most block rows one task of the Schur assembly owns.
pub(crate) const MAX_TASK_ROWS: usize = POSE_GROUP;

/// Compressed rows: row `i` holds `val[ptr[i]..ptr[i + 1]]`.
/// Invariant: `ptr.len() == rows + 1`, non-decreasing, `ptr[rows] == val.len()`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Csr<T> {
    pub ptr: Vec<usize>,
    pub val: Vec<T>,
}

impl<T: Copy + Default> Csr<T> {
    /// Groups `(row, value)` pairs by row, keeping their order within a row
    /// (a stable counting sort, so the result is deterministic).
    pub fn from_pairs(rows: usize, pairs: &[(usize, T)]) -> Self {
        let mut ptr = vec![0usize; rows + 1];
        for &(r, _) in pairs {
            ptr[r + 1] += 1;
        }
        for i in 0..rows {
            ptr[i + 1] += ptr[i];
        }
        let mut next = ptr.clone();
        let mut val = vec![T::default(); pairs.len()];
        for &(r, v) in pairs {
            val[next[r]] = v;
            next[r] += 1;
        }
        Self { ptr, val }
    }

    /// Row `i`'s index range into `val`.
    #[inline]
    pub fn range(&self, i: usize) -> std::ops::Range<usize> {
        self.ptr[i]..self.ptr[i + 1]
    }

    /// Row `i`.
    #[inline]
    pub fn row(&self, i: usize) -> &[T] {
        &self.val[self.range(i)]
    }
}

/// `(observation, pose block, camera block)` of a pose group's pass.
pub(crate) type GroupObs = (usize, usize, Option<usize>);

/// What a reduced-system block parameterises.
#[derive(Debug, Clone)]
pub(crate) enum BlockKind {
    /// A pose: index and free tangent dims (subset of 0..6).
    Pose { pose: usize, dims: Vec<usize> },
    /// A camera: index and refined parameter indices.
    Camera { camera: usize, params: Vec<usize> },
}

/// One block of the reduced system.
#[derive(Debug, Clone)]
pub(crate) struct Block {
    pub kind: BlockKind,
    /// Number of scalar parameters.
    pub size: usize,
    /// Offset into the reduced vector.
    pub offset: usize,
}

/// One used observation with its block and point references.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ObsRef {
    /// Index into `Problem::observations`.
    pub obs: usize,
    pub pose: usize,
    pub camera: usize,
    pub point: usize,
    pub pose_block: Option<usize>,
    pub cam_block: Option<usize>,
    /// Index of the variable point.
    pub var_point: Option<usize>,
    /// Global index of the (point, pose block) entry in `point_blocks`.
    pub pose_entry: Option<usize>,
    /// Global index of the (point, camera block) entry in `point_blocks`.
    pub cam_entry: Option<usize>,
}

/// The layout of one solve.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    /// Observations that do not project get a zero residual
    /// ([`crate::BehindCamera::ZeroResidual`]) instead of failing the evaluation.
    pub zero_unprojectable: bool,
    pub blocks: Vec<Block>,
    /// Number of pose blocks (they come first).
    pub num_pose_blocks: usize,
    /// Size of the reduced system.
    pub reduced_dim: usize,
    /// Largest number of refined intrinsics of a camera (the stride of the
    /// stored intrinsics Jacobians is `2 * cam_stride`).
    pub cam_stride: usize,
    pub obs: Vec<ObsRef>,
    pub num_skipped_observations: usize,
    /// Problem point index of each variable point.
    pub var_points: Vec<usize>,
    pub num_points_held_fixed: usize,
    /// Used observations of each variable point.
    pub point_obs: Csr<usize>,
    /// Used observations of each camera block (rows of pose blocks are
    /// empty: see `pose_group_obs`).
    pub block_obs: Csr<usize>,
    /// For each group of [`POSE_GROUP`] consecutive pose blocks: its used
    /// observations `(observation, pose block, camera block)` by increasing
    /// observation. Consecutive poses share most points, so a group's
    /// observations are nearly contiguous and its pass streams through the
    /// Jacobians instead of hopping (one pose alone sees one observation in
    /// every track-length many).
    pub pose_group_obs: Csr<GroupObs>,
    /// Sorted blocks touched by each variable point (the "entries" whose
    /// W = J_c^T J_p blocks the assembly stores).
    pub point_blocks: Csr<usize>,
    /// Offset of each entry's W block (`size x 3`, row-major); one extra at the end.
    pub w_offset: Vec<usize>,
    /// Tasks of the Schur assembly: block-row ranges `[b0, b1)`, a group of
    /// at most [`POSE_GROUP`] pose blocks or a single camera block.
    pub schur_tasks: Vec<(usize, usize)>,
    /// For each task, the sorted variable points with an entry in its rows.
    pub schur_task_points: Csr<usize>,
    /// Reduced matrix pattern: for each block row, the sorted column blocks
    /// `>= row` with a non-zero block.
    pub s_cols: Csr<usize>,
    /// Offset of each pattern entry's values (`size_row x size_col`,
    /// row-major); one extra at the end.
    pub s_offset: Vec<usize>,
    /// For each block column, the (row block, pattern entry) pairs with
    /// row `<` column, by increasing row.
    pub s_lower: Csr<(usize, usize)>,
}

/// Refined parameter indices of one camera under the options.
pub(crate) fn refined_params(problem: &Problem, camera: usize, options: &BaOptions) -> Vec<usize> {
    let Some(c) = problem.cameras.get(camera) else { return Vec::new() };
    let model = c.camera.model;
    let mut idx: Vec<usize> = match &c.refine {
        IntrinsicsRefinement::Fixed => Vec::new(),
        IntrinsicsRefinement::Params(p) => p.clone(),
        IntrinsicsRefinement::FromOptions => {
            let mut v = Vec::new();
            if options.refine_focal_length {
                v.extend_from_slice(model.focal_length_idxs());
            }
            if options.refine_principal_point {
                v.extend_from_slice(model.principal_point_idxs());
            }
            if options.refine_extra_params {
                v.extend_from_slice(model.extra_params_idxs());
            }
            v
        }
    };
    idx.sort_unstable();
    idx.dedup();
    idx.retain(|&k| k < c.camera.params.len());
    idx
}

impl Layout {
    /// Builds the layout. The problem must be validated (indices in range).
    pub fn new(problem: &Problem, options: &BaOptions) -> Self {
        // 1. Observations that project at the start are used; the others are
        // skipped for the whole solve (a step that makes a used one
        // unprojectable is rejected instead).
        let zero_unprojectable = options.behind_camera == BehindCamera::ZeroResidual;
        let mut used: Vec<usize> = Vec::with_capacity(problem.observations.len());
        for (i, o) in problem.observations.iter().enumerate() {
            let (cam, pose, pt) = (&problem.cameras[o.camera], &problem.poses[o.pose], &problem.points[o.point]);
            let keep = zero_unprojectable
                || reprojection_residual(&cam.camera, &pose.cam_from_world, &pt.xyz, &o.pixel).is_some();
            if keep {
                used.push(i);
            }
        }
        let num_skipped_observations = problem.observations.len() - used.len();

        // 2. Variable points: not fixed and observed often enough.
        let mut point_count = vec![0usize; problem.points.len()];
        let mut pose_count = vec![0usize; problem.poses.len()];
        let mut cam_count = vec![0usize; problem.cameras.len()];
        for &i in &used {
            let o = &problem.observations[i];
            point_count[o.point] += 1;
            pose_count[o.pose] += 1;
            cam_count[o.camera] += 1;
        }
        // Locality: points are visited in the order of the first pose that
        // sees them, and observations grouped by point in that order. Then
        // the observations of one pose (and the points of one pose block)
        // lie in a narrow index window, which keeps the per-pose passes of
        // the assembly in cache; in a SLAM sequence this is nearly the order
        // of creation.
        let mut first_pose = vec![usize::MAX; problem.points.len()];
        for &i in &used {
            let o = &problem.observations[i];
            first_pose[o.point] = first_pose[o.point].min(o.pose);
        }
        let mut point_order: Vec<usize> = (0..problem.points.len()).collect();
        point_order.sort_by_key(|&j| (first_pose[j], j));
        let mut rank = vec![0usize; problem.points.len()];
        for (r, &j) in point_order.iter().enumerate() {
            rank[j] = r;
        }
        used.sort_by_key(|&i| {
            let o = &problem.observations[i];
            (rank[o.point], o.pose, i)
        });
        let mut var_point_of = vec![None; problem.points.len()];
        let mut var_points = Vec::new();
        let mut num_points_held_fixed = 0;
        for &j in &point_order {
            let p = &problem.points[j];
            if p.fixed || point_count[j] == 0 {
                continue;
            }
            if point_count[j] < options.min_point_observations {
                num_points_held_fixed += 1;
                continue;
            }
            var_point_of[j] = Some(var_points.len());
            var_points.push(j);
        }

        // 3. Blocks: observed variable poses, then observed refined cameras.
        let mut blocks = Vec::new();
        let mut offset = 0;
        let mut pose_block = vec![None; problem.poses.len()];
        for (i, p) in problem.poses.iter().enumerate() {
            let dims = p.free_dims();
            if dims.is_empty() || pose_count[i] == 0 {
                continue;
            }
            pose_block[i] = Some(blocks.len());
            let size = dims.len();
            blocks.push(Block { kind: BlockKind::Pose { pose: i, dims }, size, offset });
            offset += size;
        }
        let num_pose_blocks = blocks.len();
        let mut cam_block = vec![None; problem.cameras.len()];
        let mut cam_stride = 0;
        for c in 0..problem.cameras.len() {
            let params = refined_params(problem, c, options);
            if params.is_empty() || cam_count[c] == 0 {
                continue;
            }
            cam_block[c] = Some(blocks.len());
            let size = params.len();
            cam_stride = cam_stride.max(size);
            blocks.push(Block { kind: BlockKind::Camera { camera: c, params }, size, offset });
            offset += size;
        }
        let reduced_dim = offset;

        // 4. Observation references and per-point / per-block lists.
        let mut obs: Vec<ObsRef> = used
            .iter()
            .map(|&i| {
                let o = &problem.observations[i];
                ObsRef {
                    obs: i,
                    pose: o.pose,
                    camera: o.camera,
                    point: o.point,
                    pose_block: pose_block[o.pose],
                    cam_block: cam_block[o.camera],
                    var_point: var_point_of[o.point],
                    pose_entry: None,
                    cam_entry: None,
                }
            })
            .collect();
        let pairs: Vec<(usize, usize)> =
            obs.iter().enumerate().filter_map(|(k, o)| o.var_point.map(|j| (j, k))).collect();
        let point_obs = Csr::from_pairs(var_points.len(), &pairs);
        let pairs: Vec<(usize, usize)> =
            obs.iter().enumerate().filter_map(|(k, o)| o.cam_block.map(|b| (b, k))).collect();
        let block_obs = Csr::from_pairs(blocks.len(), &pairs);
        let pairs: Vec<(usize, GroupObs)> = obs
            .iter()
            .enumerate()
            .filter_map(|(k, o)| o.pose_block.map(|b| (b / POSE_GROUP, (k, b, o.cam_block))))
            .collect();
        let pose_group_obs = Csr::from_pairs(num_pose_blocks.div_ceil(POSE_GROUP), &pairs);

        // Sorted unique blocks of each variable point.
        let mut pb_pairs = Vec::new();
        let mut tmp = Vec::new();
        for j in 0..var_points.len() {
            tmp.clear();
            for &k in point_obs.row(j) {
                tmp.extend(obs[k].pose_block);
                tmp.extend(obs[k].cam_block);
            }
            tmp.sort_unstable();
            tmp.dedup();
            pb_pairs.extend(tmp.iter().map(|&b| (j, b)));
        }
        let point_blocks = Csr::from_pairs(var_points.len(), &pb_pairs);
        let mut w_offset = Vec::with_capacity(point_blocks.val.len() + 1);
        let mut acc = 0;
        for &b in &point_blocks.val {
            w_offset.push(acc);
            acc += 3 * blocks[b].size;
        }
        w_offset.push(acc);
        for j in 0..var_points.len() {
            let range = point_blocks.range(j);
            let row = point_blocks.row(j);
            for &k in point_obs.row(j) {
                let o = &mut obs[k];
                // Every block of this point's observations is in its sorted row.
                o.pose_entry = o.pose_block.and_then(|b| row.binary_search(&b).ok()).map(|p| range.start + p);
                o.cam_entry = o.cam_block.and_then(|b| row.binary_search(&b).ok()).map(|p| range.start + p);
            }
        }
        let mut schur_tasks: Vec<(usize, usize)> =
            (0..num_pose_blocks).step_by(POSE_GROUP).map(|b0| (b0, (b0 + POSE_GROUP).min(num_pose_blocks))).collect();
        schur_tasks.extend((num_pose_blocks..blocks.len()).map(|b| (b, b + 1)));
        let mut task_of_block = vec![0usize; blocks.len()];
        for (t, &(b0, b1)) in schur_tasks.iter().enumerate() {
            task_of_block[b0..b1].iter_mut().for_each(|x| *x = t);
        }
        let mut tp_pairs = Vec::new();
        let mut tasks_of_point = Vec::new();
        for j in 0..var_points.len() {
            tasks_of_point.clear();
            tasks_of_point.extend(point_blocks.row(j).iter().map(|&b| task_of_block[b]));
            // Blocks are sorted and tasks are runs of blocks, so equal tasks are adjacent.
            tasks_of_point.dedup();
            tp_pairs.extend(tasks_of_point.iter().map(|&t| (t, j)));
        }
        let schur_task_points = Csr::from_pairs(schur_tasks.len(), &tp_pairs);

        // 5. Pattern of the reduced matrix (upper block triangle), one row at
        // a time with a marker array, so the temporary memory is the pattern
        // itself (not the sum of squared track lengths).
        let nb = blocks.len();
        let mut direct: Vec<(usize, usize)> = obs.iter().filter_map(|o| o.pose_block.zip(o.cam_block)).collect();
        direct.sort_unstable();
        direct.dedup();
        let direct = Csr::from_pairs(nb, &direct);
        let mut mark = vec![usize::MAX; nb];
        let mut s_pairs = Vec::new();
        let mut cols = Vec::new();
        for (t, &(b0, b1)) in schur_tasks.iter().enumerate() {
            for b in b0..b1 {
                cols.clear();
                cols.push(b);
                mark[b] = b;
                for &c in direct.row(b) {
                    if mark[c] != b {
                        mark[c] = b;
                        cols.push(c);
                    }
                }
                for &j in schur_task_points.row(t) {
                    let row = point_blocks.row(j);
                    let Ok(p) = row.binary_search(&b) else { continue };
                    for &c in &row[p..] {
                        if mark[c] != b {
                            mark[c] = b;
                            cols.push(c);
                        }
                    }
                }
                cols.sort_unstable();
                s_pairs.extend(cols.iter().map(|&c| (b, c)));
            }
        }
        let s_cols = Csr::from_pairs(blocks.len(), &s_pairs);
        let mut s_offset = Vec::with_capacity(s_cols.val.len() + 1);
        let mut acc = 0;
        for b in 0..blocks.len() {
            for e in s_cols.range(b) {
                s_offset.push(acc);
                acc += blocks[b].size * blocks[s_cols.val[e]].size;
            }
        }
        s_offset.push(acc);
        let mut low_pairs = Vec::new();
        for b in 0..blocks.len() {
            for e in s_cols.range(b) {
                let c = s_cols.val[e];
                if c > b {
                    low_pairs.push((c, (b, e)));
                }
            }
        }
        let s_lower = Csr::from_pairs(blocks.len(), &low_pairs);

        Self {
            zero_unprojectable,
            blocks,
            num_pose_blocks,
            reduced_dim,
            cam_stride,
            obs,
            num_skipped_observations,
            var_points,
            num_points_held_fixed,
            point_obs,
            block_obs,
            pose_group_obs,
            point_blocks,
            w_offset,
            schur_tasks,
            schur_task_points,
            s_cols,
            s_offset,
            s_lower,
        }
    }

    /// Position of column block `c` in row `b` of the pattern (global entry index).
    #[inline]
    pub fn s_entry(&self, b: usize, c: usize) -> Option<usize> {
        let range = self.s_cols.range(b);
        self.s_cols.row(b).binary_search(&c).ok().map(|p| range.start + p)
    }
}

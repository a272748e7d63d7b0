//! Solvers for the reduced camera system `S x = b`.
//!
//! `S` is stored as the upper block triangle of [`Layout::s_cols`] with
//! row-major blocks at [`Layout::s_offset`]. Three solvers:
//! * dense: the blocks are scattered into a dense matrix, faer's dense
//!   Cholesky;
//! * sparse: a scalar CSC upper triangle whose pattern (and AMD-ordered
//!   symbolic factorisation) is built once per solve, faer's sparse Cholesky;
//! * iterative: conjugate gradients preconditioned by the inverses of the
//!   diagonal blocks of `S` (Schur-Jacobi in Ceres' terms, since `S` is the
//!   Schur complement).
//!
//! Every solver returns `None` when `S` is not numerically positive definite;
//! the LM loop then treats the step as failed and increases the damping.

use crate::BaError;
use crate::layout::Layout;
use crate::small::{cholesky_in_place, cholesky_solve};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt as SparseLlt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Mat, Side};
use rayon::prelude::*;

/// A solver ready for one problem structure.
pub(crate) enum ReducedSolver {
    /// Dense Cholesky.
    Dense,
    /// Sparse Cholesky with a precomputed pattern.
    Sparse(Box<SparsePattern>),
    /// PCG with a block-Jacobi preconditioner.
    Iterative {
        /// Relative residual to reach.
        tolerance: f64,
        /// Iteration cap.
        max_iterations: usize,
    },
}

/// The scalar upper-triangle CSC pattern of `S` and its symbolic factorisation.
pub(crate) struct SparsePattern {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// For each CSC value, its index into the block value array.
    gather: Vec<usize>,
    symbolic: SymbolicLlt<usize>,
}

impl SparsePattern {
    /// Builds the pattern and its symbolic factorisation.
    pub fn new(layout: &Layout) -> Result<Self, BaError> {
        let n = layout.reduced_dim;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut gather = Vec::new();
        col_ptr.push(0);
        for (c_blk, cb) in layout.blocks.iter().enumerate() {
            // Entries of block column c_blk: the strictly-upper blocks (by
            // increasing row block), then the diagonal block, which has the
            // largest row indices; so row indices come out sorted.
            let diag = layout.s_entry(c_blk, c_blk);
            for c_local in 0..cb.size {
                for &(r_blk, e) in layout.s_lower.row(c_blk) {
                    let rb = &layout.blocks[r_blk];
                    for r_local in 0..rb.size {
                        row_idx.push(rb.offset + r_local);
                        gather.push(layout.s_offset[e] + r_local * cb.size + c_local);
                    }
                }
                if let Some(e) = diag {
                    for r_local in 0..=c_local {
                        row_idx.push(cb.offset + r_local);
                        gather.push(layout.s_offset[e] + r_local * cb.size + c_local);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        // The pattern above is sorted, in range and consistent by construction.
        let sym = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let symbolic = SymbolicLlt::try_new(sym, Side::Upper).map_err(|e| BaError::LinearSolver(format!("{e:?}")))?;
        Ok(Self { col_ptr, row_idx, gather, symbolic })
    }
}

impl ReducedSolver {
    /// Solves `S x = rhs`; `None` when `S` is not positive definite.
    pub fn solve(&self, layout: &Layout, s: &[f64], rhs: &[f64]) -> Option<Vec<f64>> {
        let n = layout.reduced_dim;
        if n == 0 {
            return Some(Vec::new());
        }
        match self {
            Self::Dense => {
                let mut a = Mat::<f64>::zeros(n, n);
                for (b, bb) in layout.blocks.iter().enumerate() {
                    for e in layout.s_cols.range(b) {
                        let cb = &layout.blocks[layout.s_cols.val[e]];
                        let vals = &s[layout.s_offset[e]..layout.s_offset[e + 1]];
                        for i in 0..bb.size {
                            for k in 0..cb.size {
                                let v = vals[i * cb.size + k];
                                a[(bb.offset + i, cb.offset + k)] = v;
                                a[(cb.offset + k, bb.offset + i)] = v;
                            }
                        }
                    }
                }
                let llt = a.as_ref().llt(Side::Lower).ok()?;
                let mut x = Mat::<f64>::from_fn(n, 1, |i, _| rhs[i]);
                llt.solve_in_place(x.as_mut());
                let out: Vec<f64> = (0..n).map(|i| x[(i, 0)]).collect();
                out.iter().all(|v| v.is_finite()).then_some(out)
            }
            Self::Sparse(p) => {
                let vals: Vec<f64> = p.gather.iter().map(|&g| s[g]).collect();
                // Same arrays as validated in `SparsePattern::new`.
                let sym = SymbolicSparseColMatRef::new_checked(n, n, &p.col_ptr, None, &p.row_idx);
                let mat = SparseColMatRef::new(sym, &vals);
                let llt = SparseLlt::try_new_with_symbolic(p.symbolic.clone(), mat, Side::Upper).ok()?;
                let mut x = Mat::<f64>::from_fn(n, 1, |i, _| rhs[i]);
                llt.solve_in_place(x.as_mut());
                let out: Vec<f64> = (0..n).map(|i| x[(i, 0)]).collect();
                out.iter().all(|v| v.is_finite()).then_some(out)
            }
            Self::Iterative { tolerance, max_iterations } => pcg(layout, s, rhs, *tolerance, *max_iterations),
        }
    }
}

/// `y = S x` with `S` in upper block storage; parallel over block rows, each
/// row summed in a fixed order (deterministic).
pub(crate) fn block_matvec(layout: &Layout, s: &[f64], x: &[f64]) -> Vec<f64> {
    let per_block: Vec<Vec<f64>> = (0..layout.blocks.len())
        .into_par_iter()
        .map(|b| {
            let bb = &layout.blocks[b];
            let mut y = vec![0.0; bb.size];
            for e in layout.s_cols.range(b) {
                let cb = &layout.blocks[layout.s_cols.val[e]];
                let vals = &s[layout.s_offset[e]..];
                let xs = &x[cb.offset..cb.offset + cb.size];
                for (i, yi) in y.iter_mut().enumerate() {
                    let row = &vals[i * cb.size..(i + 1) * cb.size];
                    *yi += row.iter().zip(xs).map(|(a, b)| a * b).sum::<f64>();
                }
            }
            for &(r_blk, e) in layout.s_lower.row(b) {
                let rb = &layout.blocks[r_blk];
                let vals = &s[layout.s_offset[e]..];
                let xs = &x[rb.offset..rb.offset + rb.size];
                // Block (r_blk, b) transposed: y_i += sum_k S[k][i] x_k.
                for (k, xk) in xs.iter().enumerate() {
                    let row = &vals[k * bb.size..(k + 1) * bb.size];
                    for (yi, a) in y.iter_mut().zip(row) {
                        *yi += a * xk;
                    }
                }
            }
            y
        })
        .collect();
    per_block.concat()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Preconditioned conjugate gradients with block-Jacobi preconditioning.
fn pcg(layout: &Layout, s: &[f64], rhs: &[f64], tolerance: f64, max_iterations: usize) -> Option<Vec<f64>> {
    let n = layout.reduced_dim;
    // Cholesky factors of the diagonal blocks.
    let mut precond: Vec<Vec<f64>> = Vec::with_capacity(layout.blocks.len());
    for (b, bb) in layout.blocks.iter().enumerate() {
        let e = layout.s_entry(b, b)?;
        let mut l = s[layout.s_offset[e]..layout.s_offset[e + 1]].to_vec();
        if !cholesky_in_place(&mut l, bb.size) {
            return None;
        }
        precond.push(l);
    }
    let apply_precond = |r: &[f64]| -> Vec<f64> {
        let mut z = r.to_vec();
        for (bb, l) in layout.blocks.iter().zip(&precond) {
            cholesky_solve(l, bb.size, &mut z[bb.offset..bb.offset + bb.size]);
        }
        z
    };
    let rhs_norm = dot(rhs, rhs).sqrt();
    let mut x = vec![0.0; n];
    if rhs_norm == 0.0 {
        return Some(x);
    }
    let mut r = rhs.to_vec();
    let mut z = apply_precond(&r);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    for _ in 0..max_iterations {
        let ap = block_matvec(layout, s, &p);
        let pap = dot(&p, &ap);
        if !(pap > 0.0 && pap.is_finite()) {
            // Not positive definite along p (or breakdown): fail unless we
            // already have a useful iterate.
            break;
        }
        let alpha = rz / pap;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        if dot(&r, &r).sqrt() <= tolerance * rhs_norm {
            break;
        }
        z = apply_precond(&r);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    (x.iter().all(|v| v.is_finite()) && x.iter().any(|v| *v != 0.0)).then_some(x)
}

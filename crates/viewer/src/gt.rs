//! The trajectory comparison layer: a model's cameras against a ground
//! truth, with `colslam-eval`'s association, Sim(3) alignment and ATE (the
//! numbers of `colslam eval` on the model's TUM export). The page draws the
//! estimate in the model's frame, so the ground truth is brought into it
//! with the inverse of the alignment.

use crate::export::model_trajectory_timed;
use colslam_eval::{EvalError, EvalOptions, Trajectory, evaluate_named};
use colslam_scene::Reconstruction;
use serde_json::{Value, json};
use std::collections::HashMap;

/// A model compared with its ground truth, as the page draws it.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruthLayer {
    /// Label of the ground truth (its file).
    pub name: String,
    /// ATE RMSE in the ground truth's unit (metres for TUM).
    pub ate_rmse: f64,
    /// Associated pose pairs.
    pub matched: usize,
    /// Scale of the alignment (ground truth per model unit).
    pub scale: f64,
    /// Every ground-truth position in the model's frame, in time order.
    pub path: Vec<[f64; 3]>,
    /// Per associated camera: image id and its ATE (ground-truth unit).
    pub errors: Vec<(u32, f64)>,
}

impl GroundTruthLayer {
    /// Compares the registered images of `rec` (timestamps from their names,
    /// as the TUM export writes them) with `gt` using `colslam eval`'s
    /// defaults (Sim(3) alignment, 10 ms association).
    pub fn compute(rec: &Reconstruction, gt: &Trajectory, name: &str) -> Result<GroundTruthLayer, EvalError> {
        Self::compute_timed(rec, gt, name, &|_| None)
    }

    /// [`Self::compute_timed`] against the TUM trajectory in `file` (the
    /// layer named by the file), as `view --gt` and `run --view --gt` show it.
    pub fn read(
        rec: &Reconstruction,
        file: &std::path::Path,
        stamp_of: &dyn Fn(&str) -> Option<f64>,
    ) -> Result<GroundTruthLayer, EvalError> {
        let gt = Trajectory::read_tum(file)?;
        Self::compute_timed(rec, &gt, &file.display().to_string(), stamp_of)
    }

    /// [`Self::compute`] with the images' timestamps that `stamp_of` knows
    /// by image name (a finished run knows every frame's time, which an
    /// image name need not hold).
    pub fn compute_timed(
        rec: &Reconstruction,
        gt: &Trajectory,
        name: &str,
        stamp_of: &dyn Fn(&str) -> Option<f64>,
    ) -> Result<GroundTruthLayer, EvalError> {
        let (est, ids) = model_trajectory_timed(rec, stamp_of);
        let report = evaluate_named(gt, &est, name, "the model's cameras", &EvalOptions::default())?;
        let detail = &report.detail;
        let model_from_gt = detail.transform.inverse();
        let path = gt
            .positions()
            .iter()
            .map(|p| {
                let q = model_from_gt.transform_point(p);
                [q.x, q.y, q.z]
            })
            .collect();
        // Stamps are unique in a trajectory that passed association, so the
        // bit pattern finds the camera of each associated estimate pose.
        let by_stamp: HashMap<u64, u32> = est.stamps.iter().zip(&ids).map(|(t, id)| (t.to_bits(), *id)).collect();
        let errors = detail
            .stamps
            .iter()
            .zip(&detail.ate_errors)
            .filter_map(|(t, e)| by_stamp.get(&t.to_bits()).map(|id| (*id, *e)))
            .collect();
        Ok(GroundTruthLayer {
            name: name.to_string(),
            ate_rmse: report.ate_rmse,
            matched: report.matched,
            scale: report.scale,
            path,
            errors,
        })
    }

    /// The layer as the page reads it.
    pub(crate) fn to_json(&self) -> Value {
        let path: Vec<f32> = self.path.iter().flatten().map(|&v| v as f32).collect();
        let (ids, errs): (Vec<u32>, Vec<f64>) = self.errors.iter().copied().unzip();
        json!({
            "name": self.name, "ate_rmse": self.ate_rmse, "matched": self.matched, "scale": self.scale,
            "path": path, "ids": ids, "errors": errs,
        })
    }
}

//! Trajectory evaluation for colslam: TUM trajectory I/O, timestamp
//! association, Umeyama alignment, ATE and RPE, and PNG plots.
//!
//! The numbers equal those of evo 1.38.1 (M. Grupp, github.com/MichaelGrupp/evo):
//! `evo_ape tum GT EST -as` for the ATE and `evo_rpe tum GT EST -as` for the
//! RPE (delta 1 frame, consecutive pairs, translation part and rotation
//! angle in degrees). The crate's integration tests check this against evo
//! itself. The flow of [`evaluate`] is evo's: associate (the shorter
//! trajectory drives), align the associated estimate onto the associated
//! reference, then compute the errors of the associated pairs.

pub mod align;
pub mod associate;
mod error;
pub mod metrics;
pub mod plot;
pub mod trajectory;

pub use align::{AlignResult, Alignment};
pub use error::EvalError;
pub use trajectory::Trajectory;

use align::AlignError;
use associate::AssociateOptions;
use colslam_geometry::{Sim3, Vec3};
use metrics::{PoseRelation, Stats};
use std::path::Path;

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalOptions {
    /// Largest timestamp difference of an associated pair, seconds.
    /// Default 0.01 (evo's `--t_max_diff`).
    pub max_diff: f64,
    /// Added to the estimate's stamps before association, seconds (evo's
    /// `--t_offset`). Default 0.
    pub offset: f64,
    /// Alignment of the estimate onto the reference. Default `Sim3` (`-as`).
    pub align: Alignment,
    /// Align on the first `n` associated pairs only (evo's `--n_to_align`).
    /// Default `None` (all); `Some(n)` needs `n >= 3`.
    pub n_to_align: Option<usize>,
    /// RPE frame distance (evo's `--delta` with `--delta_unit f`). Default 1.
    /// Only frame deltas are offered; evo's `rel_delta_tol` applies to metre
    /// and degree deltas only, so it plays no part here.
    pub rpe_delta: usize,
    /// RPE over all pairs `(i, i + delta)` instead of consecutive ones (evo's
    /// `--all_pairs`). Default false.
    pub rpe_all_pairs: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            max_diff: associate::DEFAULT_MAX_DIFF,
            offset: 0.0,
            align: Alignment::Sim3,
            n_to_align: None,
            rpe_delta: 1,
            rpe_all_pairs: false,
        }
    }
}

impl EvalOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), EvalError> {
        self.associate_options().validate()?;
        if self.rpe_delta == 0 {
            return Err(EvalError::InvalidOptions("rpe_delta must be at least 1 frame".into()));
        }
        if let Some(n) = self.n_to_align
            && n < align::MIN_ALIGN_POINTS
        {
            return Err(EvalError::InvalidOptions(format!(
                "n_to_align must be at least {}, got {n}",
                align::MIN_ALIGN_POINTS
            )));
        }
        Ok(())
    }

    /// The association part of the options.
    pub fn associate_options(&self) -> AssociateOptions {
        AssociateOptions { max_diff: self.max_diff, offset: self.offset }
    }
}

/// Per-pose data of an evaluation, for plots and further analysis (not
/// serialised with the report).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EvalDetail {
    /// Stamps of the associated estimate poses (the estimate's own clock).
    pub stamps: Vec<f64>,
    /// `stamps[i] - stamps[0]`, seconds (evo's `seconds_from_start`).
    pub seconds_from_start: Vec<f64>,
    /// ATE (translation) per associated pose, metres.
    pub ate_errors: Vec<f64>,
    /// Associated reference positions.
    pub reference_positions: Vec<Vec3>,
    /// Associated estimate positions after alignment.
    pub aligned_positions: Vec<Vec3>,
    /// RPE index pairs into the associated poses.
    pub rpe_pairs: Vec<(usize, usize)>,
    /// RPE translation per pair, metres (after alignment, so in the
    /// reference's scale when the alignment has a scale).
    pub rpe_trans_errors: Vec<f64>,
    /// RPE rotation angle per pair, degrees.
    pub rpe_rot_errors_deg: Vec<f64>,
    /// The alignment applied to the estimate (`reference_from_estimate`).
    pub transform: Sim3,
}

/// Result of [`evaluate`]: evo's statistics as flat fields (lengths in
/// metres, angles in degrees). Serialises to JSON without the per-pose
/// [`EvalDetail`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EvalReport {
    /// Reference file or label.
    pub reference: String,
    /// Estimate file or label.
    pub estimate: String,
    /// Alignment used.
    pub align: Alignment,
    /// Poses in the reference.
    pub ref_poses: usize,
    /// Poses in the estimate.
    pub est_poses: usize,
    /// Associated pose pairs.
    pub matched: usize,
    /// ATE RMSE, m.
    pub ate_rmse: f64,
    /// ATE mean, m.
    pub ate_mean: f64,
    /// ATE median, m.
    pub ate_median: f64,
    /// ATE maximum, m.
    pub ate_max: f64,
    /// ATE minimum, m.
    pub ate_min: f64,
    /// ATE standard deviation (population), m.
    pub ate_std: f64,
    /// ATE sum of squares, m^2.
    pub ate_sse: f64,
    /// Absolute rotation error RMSE (evo_ape `-r angle_deg`), degrees.
    pub ate_rot_rmse_deg: f64,
    /// Absolute rotation error mean, degrees.
    pub ate_rot_mean_deg: f64,
    /// Absolute rotation error median, degrees.
    pub ate_rot_median_deg: f64,
    /// Absolute rotation error maximum, degrees.
    pub ate_rot_max_deg: f64,
    /// Scale of the alignment (1 without scale).
    pub scale: f64,
    /// Rotation of the alignment, (w, x, y, z).
    pub align_rotation_wxyz: [f64; 4],
    /// Translation of the alignment, m.
    pub align_translation: [f64; 3],
    /// RPE frame delta.
    pub rpe_delta: usize,
    /// RPE pairs.
    pub rpe_pairs: usize,
    /// RPE translation RMSE, m.
    pub rpe_trans_rmse: f64,
    /// RPE translation mean, m.
    pub rpe_trans_mean: f64,
    /// RPE translation median, m.
    pub rpe_trans_median: f64,
    /// RPE translation maximum, m.
    pub rpe_trans_max: f64,
    /// RPE translation minimum, m.
    pub rpe_trans_min: f64,
    /// RPE translation standard deviation, m.
    pub rpe_trans_std: f64,
    /// RPE translation sum of squares, m^2.
    pub rpe_trans_sse: f64,
    /// RPE rotation RMSE, degrees.
    pub rpe_rot_rmse_deg: f64,
    /// RPE rotation mean, degrees.
    pub rpe_rot_mean_deg: f64,
    /// RPE rotation median, degrees.
    pub rpe_rot_median_deg: f64,
    /// RPE rotation maximum, degrees.
    pub rpe_rot_max_deg: f64,
    /// RPE rotation minimum, degrees.
    pub rpe_rot_min_deg: f64,
    /// RPE rotation standard deviation, degrees.
    pub rpe_rot_std_deg: f64,
    /// RPE rotation sum of squares, deg^2.
    pub rpe_rot_sse_deg: f64,
    /// Per-pose data (not serialised).
    #[serde(skip)]
    pub detail: EvalDetail,
}

impl std::fmt::Display for EvalReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "reference: {} ({} poses)", self.reference, self.ref_poses)?;
        writeln!(f, "estimate:  {} ({} poses)", self.estimate, self.est_poses)?;
        writeln!(f, "matched:   {} pairs, alignment {} (scale {:.6})", self.matched, self.align, self.scale)?;
        writeln!(f, "{:<22}{:>12}{:>12}{:>12}{:>12}{:>12}{:>12}", "", "rmse", "mean", "median", "std", "min", "max")?;
        let row = |f: &mut std::fmt::Formatter<'_>, name: &str, v: [f64; 6]| {
            writeln!(
                f,
                "{name:<22}{:>12.6}{:>12.6}{:>12.6}{:>12.6}{:>12.6}{:>12.6}",
                v[0], v[1], v[2], v[3], v[4], v[5]
            )
        };
        row(f, "ATE [m]", [self.ate_rmse, self.ate_mean, self.ate_median, self.ate_std, self.ate_min, self.ate_max])?;
        row(
            f,
            &format!("RPE trans [m] (d={})", self.rpe_delta),
            [
                self.rpe_trans_rmse,
                self.rpe_trans_mean,
                self.rpe_trans_median,
                self.rpe_trans_std,
                self.rpe_trans_min,
                self.rpe_trans_max,
            ],
        )?;
        row(
            f,
            &format!("RPE rot [deg] (d={})", self.rpe_delta),
            [
                self.rpe_rot_rmse_deg,
                self.rpe_rot_mean_deg,
                self.rpe_rot_median_deg,
                self.rpe_rot_std_deg,
                self.rpe_rot_min_deg,
                self.rpe_rot_max_deg,
            ],
        )
    }
}

/// Label used for the reference in errors when no file name is known.
const REFERENCE_LABEL: &str = "reference";
/// Label used for the estimate in errors when no file name is known.
const ESTIMATE_LABEL: &str = "estimate";

/// Evaluates `est` against `gt` (see the crate documentation for the flow).
pub fn evaluate(gt: &Trajectory, est: &Trajectory, opts: &EvalOptions) -> Result<EvalReport, EvalError> {
    evaluate_named(gt, est, REFERENCE_LABEL, ESTIMATE_LABEL, opts)
}

/// Reads two TUM files and evaluates them; errors name the files.
pub fn evaluate_files(gt: &Path, est: &Path, opts: &EvalOptions) -> Result<EvalReport, EvalError> {
    opts.validate()?;
    let g = Trajectory::read_tum(gt)?;
    let e = Trajectory::read_tum(est)?;
    evaluate_named(&g, &e, &gt.display().to_string(), &est.display().to_string(), opts)
}

/// [`evaluate`] with the labels used in the report and in errors.
pub fn evaluate_named(
    gt: &Trajectory,
    est: &Trajectory,
    gt_name: &str,
    est_name: &str,
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    opts.validate()?;
    for (t, name) in [(gt, gt_name), (est, est_name)] {
        t.validate(name)?;
        if t.is_empty() {
            return Err(EvalError::Empty { name: name.to_string() });
        }
    }
    let assoc = associate::associate(gt, est, &opts.associate_options());
    if assoc.is_empty() {
        return Err(EvalError::NoMatches {
            reference: gt_name.to_string(),
            estimate: est_name.to_string(),
            max_diff: opts.max_diff,
            offset: opts.offset,
        });
    }
    let reference = gt.select(&assoc.ref_indices);
    let estimate = est.select(&assoc.est_indices);
    let matched = assoc.len();
    let too_few = |needed: usize, purpose: &'static str| EvalError::TooFewMatches {
        reference: gt_name.to_string(),
        estimate: est_name.to_string(),
        matched,
        needed,
        purpose,
    };

    let aligned = align::align(&reference, &estimate, opts.align, opts.n_to_align).map_err(|e| match e {
        AlignError::TooFew(_) | AlignError::LengthMismatch { .. } => too_few(align::MIN_ALIGN_POINTS, "alignment"),
        AlignError::Degenerate(reason) => {
            EvalError::Degenerate { reference: gt_name.to_string(), estimate: est_name.to_string(), reason }
        }
    })?;
    let est_aligned = &aligned.aligned;

    let ate_errors = metrics::ape_errors(&reference.poses, &est_aligned.poses, PoseRelation::TranslationPart);
    let ate_rot = metrics::ape_errors(&reference.poses, &est_aligned.poses, PoseRelation::RotationAngleDeg);
    let pairs = metrics::rpe_pairs(matched, opts.rpe_delta, opts.rpe_all_pairs);
    let rpe_t = metrics::rpe_errors(&reference.poses, &est_aligned.poses, &pairs, PoseRelation::TranslationPart);
    let rpe_r = metrics::rpe_errors(&reference.poses, &est_aligned.poses, &pairs, PoseRelation::RotationAngleDeg);
    let (Some(ate), Some(ate_r)) = (metrics::statistics(&ate_errors), metrics::statistics(&ate_rot)) else {
        return Err(too_few(1, "the ATE"));
    };
    let (Some(rt), Some(rr)) = (metrics::statistics(&rpe_t), metrics::statistics(&rpe_r)) else {
        return Err(too_few(opts.rpe_delta + 1, "the RPE"));
    };

    let first = estimate.stamps.first().copied().unwrap_or(0.0);
    let transform = aligned.transform;
    let q = transform.rotation.quaternion();
    let detail = EvalDetail {
        seconds_from_start: estimate.stamps.iter().map(|t| t - first).collect(),
        stamps: estimate.stamps.clone(),
        ate_errors,
        reference_positions: reference.positions(),
        aligned_positions: est_aligned.positions(),
        rpe_pairs: pairs.clone(),
        rpe_trans_errors: rpe_t,
        rpe_rot_errors_deg: rpe_r,
        transform,
    };
    Ok(report_from(
        gt_name,
        est_name,
        gt.len(),
        est.len(),
        matched,
        opts,
        &ate,
        &ate_r,
        &rt,
        &rr,
        [q.w, q.i, q.j, q.k],
        detail,
    ))
}

#[allow(clippy::too_many_arguments)] // a private constructor of a flat struct
fn report_from(
    gt_name: &str,
    est_name: &str,
    ref_poses: usize,
    est_poses: usize,
    matched: usize,
    opts: &EvalOptions,
    ate: &Stats,
    ate_r: &Stats,
    rt: &Stats,
    rr: &Stats,
    align_rotation_wxyz: [f64; 4],
    detail: EvalDetail,
) -> EvalReport {
    let t = detail.transform.translation;
    EvalReport {
        reference: gt_name.to_string(),
        estimate: est_name.to_string(),
        align: opts.align,
        ref_poses,
        est_poses,
        matched,
        ate_rmse: ate.rmse,
        ate_mean: ate.mean,
        ate_median: ate.median,
        ate_max: ate.max,
        ate_min: ate.min,
        ate_std: ate.std,
        ate_sse: ate.sse,
        ate_rot_rmse_deg: ate_r.rmse,
        ate_rot_mean_deg: ate_r.mean,
        ate_rot_median_deg: ate_r.median,
        ate_rot_max_deg: ate_r.max,
        scale: detail.transform.scale,
        align_rotation_wxyz,
        align_translation: [t.x, t.y, t.z],
        rpe_delta: opts.rpe_delta,
        rpe_pairs: rt.count,
        rpe_trans_rmse: rt.rmse,
        rpe_trans_mean: rt.mean,
        rpe_trans_median: rt.median,
        rpe_trans_max: rt.max,
        rpe_trans_min: rt.min,
        rpe_trans_std: rt.std,
        rpe_trans_sse: rt.sse,
        rpe_rot_rmse_deg: rr.rmse,
        rpe_rot_mean_deg: rr.mean,
        rpe_rot_median_deg: rr.median,
        rpe_rot_max_deg: rr.max,
        rpe_rot_min_deg: rr.min,
        rpe_rot_std_deg: rr.std,
        rpe_rot_sse_deg: rr.sse,
        detail,
    }
}

//! Generic LO-RANSAC.
//!
//! Plain RANSAC (Fischler & Bolles 1981) with adaptive termination and the
//! local optimisation of LO-RANSAC (Chum, Matas & Kittler 2003; Lebeda, Matas
//! & Chum 2012), in the form COLMAP uses (`estimators/loransac.h`): whenever
//! a minimal sample yields a new best model, the model is re-estimated from
//! its inliers with a non-minimal solver and kept while the support improves.
//!
//! Support is measured either by MSAC (Torr & Zisserman 2000: the sum of
//! squared residuals truncated at the threshold, smaller is better; the
//! default, as in PoseLib) or by the inlier count with ties broken by the
//! residual sum (COLMAP's `InlierSupportMeasurer`). Counting lets the local
//! optimisation bend a model to swallow a couple of outliers at the cost of
//! every inlier's fit; MSAC does not reward that.

use crate::error::EstimatorError;
use colslam_geometry::SplitMix64;

/// A model-fitting problem that RANSAC can solve.
///
/// The estimator owns (or borrows) its data; RANSAC only deals in indices.
pub trait Estimator {
    /// The fitted model.
    type Model: Clone;

    /// Name used in error messages.
    fn name(&self) -> &'static str;

    /// Number of data points in a minimal sample (at least 1).
    fn sample_size(&self) -> usize;

    /// Number of data points.
    fn num_data(&self) -> usize;

    /// Solves from a minimal sample of `sample_size()` distinct indices,
    /// pushing every solution (possibly none) onto `models`.
    fn estimate_minimal(&self, sample: &[usize], models: &mut Vec<Self::Model>);

    /// Re-estimates from a (larger) set of inliers, starting from the current
    /// best model `current` where that helps (iterative refinement). The
    /// default does nothing, which disables local optimisation.
    fn estimate_nonminimal(&self, _inliers: &[usize], _current: &Self::Model, _models: &mut Vec<Self::Model>) {}

    /// The indices minimal samples are drawn from (distinct, each below
    /// `num_data()`), when some data are known to be likelier inliers than
    /// the rest: guided sampling, the idea behind PROSAC (Chum & Matas,
    /// CVPR 2005) without its progressive schedule. Every datum still
    /// counts towards the support, and the adaptive termination follows the
    /// inlier ratio within the pool. `None` (the default): every datum.
    fn sample_pool(&self) -> Option<&[usize]> {
        None
    }

    /// Writes the **squared** residual of every data point into `out`
    /// (`out.len() == num_data()`). Non-finite values count as outliers.
    fn squared_residuals(&self, model: &Self::Model, out: &mut [f64]);

    /// Support of `model` at the squared threshold `max_sq`, or `None` once
    /// it is certain that the model cannot be strictly better than `bound`
    /// under `measure` (early exit: most models of a RANSAC run are wrong).
    /// `buf` has `num_data()` entries of scratch space. The default scores
    /// every residual from [`Estimator::squared_residuals`]; overriding it
    /// must give the same support for models that are not rejected.
    fn score(
        &self,
        model: &Self::Model,
        max_sq: f64,
        measure: SupportMeasure,
        bound: Option<&Support>,
        buf: &mut [f64],
    ) -> Option<Support> {
        let _ = (measure, bound);
        self.squared_residuals(model, buf);
        let mut s = SupportAccumulator::default();
        s.add_all(buf, max_sq);
        Some(s.finish(max_sq))
    }
}

/// Running support of a model, for [`Estimator::score`] implementations.
#[derive(Debug, Clone, Copy, Default)]
pub struct SupportAccumulator {
    num_inliers: usize,
    num_outliers: usize,
    residual_sum: f64,
}

impl SupportAccumulator {
    /// Adds squared residuals (non-finite ones count as outliers).
    #[inline]
    pub fn add_all(&mut self, squared_residuals: &[f64], max_sq: f64) {
        for &r in squared_residuals {
            // `r <= max_sq` is false for NaN.
            if r <= max_sq {
                self.num_inliers += 1;
                self.residual_sum += r;
            } else {
                self.num_outliers += 1;
            }
        }
    }

    /// True when, with `remaining` residuals still to add, the final support
    /// cannot be strictly better than `bound` under `measure`.
    #[inline]
    pub fn cannot_beat(&self, bound: &Support, measure: SupportMeasure, max_sq: f64, remaining: usize) -> bool {
        match measure {
            // The MSAC cost only grows as residuals are added.
            SupportMeasure::Msac => self.residual_sum + self.num_outliers as f64 * max_sq >= bound.msac_cost,
            SupportMeasure::InlierCount => self.num_inliers + remaining < bound.num_inliers,
        }
    }

    /// The support of the residuals added so far.
    pub fn finish(&self, max_sq: f64) -> Support {
        Support {
            num_inliers: self.num_inliers,
            residual_sum: self.residual_sum,
            msac_cost: self.residual_sum + self.num_outliers as f64 * max_sq,
        }
    }
}

/// How the support of a model is scored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SupportMeasure {
    /// Sum of squared residuals truncated at `max_error²` (smaller wins).
    #[default]
    Msac,
    /// Inlier count (larger wins), ties broken by the inliers' residual sum.
    InlierCount,
}

/// Options of [`ransac`].
#[derive(Debug, Clone, PartialEq)]
pub struct RansacOptions {
    /// Inlier threshold on the residual (not squared), in the estimator's
    /// units. Default 1e-3 (about 0.5 px at a 500 px focal length for
    /// normalised coordinates); callers almost always set it.
    pub max_error: f64,
    /// Probability of having drawn at least one all-inlier sample when the
    /// adaptive termination stops. In (0, 1). Default 0.999.
    pub confidence: f64,
    /// Trials always run (unless every sample is exhausted). Default 0.
    pub min_trials: usize,
    /// Hard cap on trials. Default 10 000.
    pub max_trials: usize,
    /// Multiplies the adaptive trial count, as COLMAP's
    /// `dyn_num_trials_multiplier` (>= 1 keeps the confidence guarantee).
    /// Default 3.0.
    pub dyn_trials_multiplier: f64,
    /// Lower bound assumed for the inlier ratio: caps the trial count at what
    /// this ratio would need. In (0, 1]. Default 0.1.
    pub min_inlier_ratio: f64,
    /// Enables the LO step (re-estimate from inliers on each new best
    /// model, plus a final re-estimate). Default true.
    pub local_optimization: bool,
    /// Maximum re-estimation rounds per LO step. Default 10.
    pub lo_max_iterations: usize,
    /// Seed of the sampler. Default 0.
    pub seed: u64,
    /// Support measure. Default [`SupportMeasure::Msac`].
    pub support_measure: SupportMeasure,
}

impl Default for RansacOptions {
    fn default() -> Self {
        Self {
            max_error: 1e-3,
            confidence: 0.999,
            min_trials: 0,
            max_trials: 10_000,
            dyn_trials_multiplier: 3.0,
            min_inlier_ratio: 0.1,
            local_optimization: true,
            lo_max_iterations: 10,
            seed: 0,
            support_measure: SupportMeasure::Msac,
        }
    }
}

impl RansacOptions {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), EstimatorError> {
        let bad = |m: String| Err(EstimatorError::InvalidOptions(m));
        if !(self.max_error.is_finite() && self.max_error > 0.0) {
            return bad(format!("ransac max_error must be positive and finite, got {}", self.max_error));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return bad(format!("ransac confidence must lie in (0, 1), got {}", self.confidence));
        }
        if self.max_trials == 0 || self.min_trials > self.max_trials {
            return bad(format!(
                "ransac needs 0 <= min_trials <= max_trials and max_trials > 0, got {} and {}",
                self.min_trials, self.max_trials
            ));
        }
        if !(self.dyn_trials_multiplier.is_finite() && self.dyn_trials_multiplier > 0.0) {
            return bad(format!("ransac dyn_trials_multiplier must be positive, got {}", self.dyn_trials_multiplier));
        }
        if !(self.min_inlier_ratio > 0.0 && self.min_inlier_ratio <= 1.0) {
            return bad(format!("ransac min_inlier_ratio must lie in (0, 1], got {}", self.min_inlier_ratio));
        }
        Ok(())
    }
}

/// Support of a model.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Support {
    /// Points whose residual is at most `max_error`.
    pub num_inliers: usize,
    /// Sum of the squared residuals of the inliers.
    pub residual_sum: f64,
    /// MSAC cost: `residual_sum` plus `max_error²` per outlier.
    pub msac_cost: f64,
}

impl Support {
    /// True when `self` is strictly better than `other` under `measure`.
    pub fn is_better_than(&self, other: &Support, measure: SupportMeasure) -> bool {
        match measure {
            SupportMeasure::Msac => self.msac_cost < other.msac_cost,
            SupportMeasure::InlierCount => {
                self.num_inliers > other.num_inliers
                    || (self.num_inliers == other.num_inliers && self.residual_sum < other.residual_sum)
            }
        }
    }
}

/// Result of a successful [`ransac`] run.
#[derive(Debug, Clone)]
pub struct RansacReport<M> {
    /// The best model.
    pub model: M,
    /// `inlier_mask[i]` is true when point `i` is an inlier of `model`.
    pub inlier_mask: Vec<bool>,
    /// Number of inliers (`inlier_mask` count).
    pub num_inliers: usize,
    /// Minimal samples drawn.
    pub num_trials: usize,
    /// Support of `model`.
    pub support: Support,
    /// How many times local optimisation improved the best model.
    pub num_lo_improvements: usize,
}

/// Number of trials needed to draw an all-inlier sample with probability
/// `confidence` at the given inlier ratio: `log(1 - p) / log(1 - w^s)`.
pub fn required_trials(inlier_ratio: f64, sample_size: usize, confidence: f64, multiplier: f64) -> usize {
    let prob_all_inliers = inlier_ratio.clamp(0.0, 1.0).powi(sample_size.min(i32::MAX as usize) as i32);
    if prob_all_inliers >= 1.0 {
        return 1;
    }
    let denom = (1.0 - prob_all_inliers).ln();
    if denom == 0.0 {
        // The ratio is so small that no finite count suffices.
        return usize::MAX;
    }
    let n = ((1.0 - confidence).ln() / denom * multiplier).ceil();
    if n.is_finite() && n >= 0.0 && n < usize::MAX as f64 { n as usize } else { usize::MAX }
}

fn inliers_of(buf: &[f64], max_sq: f64, out: &mut Vec<usize>) {
    out.clear();
    out.extend(buf.iter().enumerate().filter(|(_, r)| **r <= max_sq).map(|(i, _)| i));
}

struct Best<M> {
    model: M,
    support: Support,
}

/// Runs LO-RANSAC on `est`.
///
/// Returns [`EstimatorError::TooFewPoints`] when there are fewer data than a
/// minimal sample, and [`EstimatorError::NoModel`] when no model has at least
/// `sample_size()` inliers.
pub fn ransac<E: Estimator>(est: &E, opts: &RansacOptions) -> Result<RansacReport<E::Model>, EstimatorError> {
    opts.validate()?;
    let n = est.num_data();
    let s = est.sample_size();
    let problem = est.name();
    if s == 0 {
        return Err(EstimatorError::InvalidOptions(format!("{problem}: sample size must be positive")));
    }
    if n < s {
        return Err(EstimatorError::TooFewPoints { problem, needed: s, got: n });
    }
    let max_sq = opts.max_error * opts.max_error;
    let mut rng = SplitMix64::new(opts.seed);
    let pool = est.sample_pool();
    let mut perm: Vec<usize> = match pool {
        None => (0..n).collect(),
        Some(pool) => {
            let mut seen = vec![false; n];
            for &i in pool {
                if i >= n || std::mem::replace(&mut seen[i], true) {
                    return Err(EstimatorError::InvalidOptions(format!(
                        "{problem}: sample pool index {i} repeated or not below {n} data"
                    )));
                }
            }
            if pool.len() < s {
                return Err(EstimatorError::TooFewPoints { problem, needed: s, got: pool.len() });
            }
            pool.to_vec()
        }
    };
    let m = perm.len();
    let mut sample = vec![0usize; s];
    let mut models: Vec<E::Model> = Vec::new();
    let mut lo_models: Vec<E::Model> = Vec::new();
    let mut buf = vec![0.0; n];
    let mut inliers: Vec<usize> = Vec::new();
    let mut best: Option<Best<E::Model>> = None;
    let mut num_lo_improvements = 0usize;

    let cap = required_trials(opts.min_inlier_ratio, s, opts.confidence, opts.dyn_trials_multiplier)
        .min(opts.max_trials)
        .max(opts.min_trials);
    let mut max_trials = cap;
    let mut trials = 0usize;

    while trials < max_trials {
        trials += 1;
        // Partial Fisher-Yates: the first `s` entries of `perm` become a
        // uniform sample of distinct indices; `perm` stays a permutation.
        for k in 0..s {
            let j = k + rng.below(m - k);
            perm.swap(k, j);
            sample[k] = perm[k];
        }
        models.clear();
        est.estimate_minimal(&sample, &mut models);
        for model in models.drain(..) {
            let bound = best.as_ref().map(|b| &b.support);
            let Some(support) = est.score(&model, max_sq, opts.support_measure, bound, &mut buf) else {
                continue;
            };
            let improves = bound.is_none_or(|b| support.is_better_than(b, opts.support_measure));
            if !improves {
                continue;
            }
            let mut cur = Best { model, support };
            if opts.local_optimization {
                // LO step: re-estimate from the inliers while support improves.
                for _ in 0..opts.lo_max_iterations {
                    est.squared_residuals(&cur.model, &mut buf);
                    inliers_of(&buf, max_sq, &mut inliers);
                    if inliers.len() < s {
                        break;
                    }
                    lo_models.clear();
                    est.estimate_nonminimal(&inliers, &cur.model, &mut lo_models);
                    let mut improved = false;
                    for m in lo_models.drain(..) {
                        let sup = est.score(&m, max_sq, opts.support_measure, Some(&cur.support), &mut buf);
                        if let Some(sup) = sup.filter(|s| s.is_better_than(&cur.support, opts.support_measure)) {
                            cur = Best { model: m, support: sup };
                            improved = true;
                        }
                    }
                    if !improved {
                        break;
                    }
                    num_lo_improvements += 1;
                }
            }
            let ratio = match pool {
                None => cur.support.num_inliers as f64 / n as f64,
                Some(pool) => {
                    est.squared_residuals(&cur.model, &mut buf);
                    pool.iter().filter(|&&i| buf[i] <= max_sq).count() as f64 / m as f64
                }
            };
            let needed = required_trials(ratio, s, opts.confidence, opts.dyn_trials_multiplier);
            max_trials = needed.max(opts.min_trials).min(cap);
            best = Some(cur);
        }
    }

    let Some(mut best) = best else {
        return Err(EstimatorError::NoModel { problem, trials, best_inliers: 0 });
    };
    if opts.local_optimization {
        // Final re-estimate from all inliers of the best model.
        est.squared_residuals(&best.model, &mut buf);
        inliers_of(&buf, max_sq, &mut inliers);
        if inliers.len() >= s {
            lo_models.clear();
            est.estimate_nonminimal(&inliers, &best.model, &mut lo_models);
            for m in lo_models.drain(..) {
                let sup = est.score(&m, max_sq, opts.support_measure, Some(&best.support), &mut buf);
                if let Some(sup) = sup.filter(|s| s.is_better_than(&best.support, opts.support_measure)) {
                    best = Best { model: m, support: sup };
                    num_lo_improvements += 1;
                }
            }
        }
    }
    if best.support.num_inliers < s {
        return Err(EstimatorError::NoModel { problem, trials, best_inliers: best.support.num_inliers });
    }
    est.squared_residuals(&best.model, &mut buf);
    let inlier_mask: Vec<bool> = buf.iter().map(|r| *r <= max_sq).collect();
    let num_inliers = inlier_mask.iter().filter(|b| **b).count();
    Ok(RansacReport {
        model: best.model,
        inlier_mask,
        num_inliers,
        num_trials: trials,
        support: best.support,
        num_lo_improvements,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 2D line `a x + b y + c = 0` (unit normal) from two points.
    struct LineEstimator<'a> {
        pts: &'a [[f64; 2]],
    }

    impl Estimator for LineEstimator<'_> {
        type Model = [f64; 3];
        fn name(&self) -> &'static str {
            "line"
        }
        fn sample_size(&self) -> usize {
            2
        }
        fn num_data(&self) -> usize {
            self.pts.len()
        }
        fn estimate_minimal(&self, sample: &[usize], models: &mut Vec<[f64; 3]>) {
            let (p, q) = (self.pts[sample[0]], self.pts[sample[1]]);
            let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
            let norm = (dx * dx + dy * dy).sqrt();
            if norm > 1e-12 {
                let (a, b) = (-dy / norm, dx / norm);
                models.push([a, b, -(a * p[0] + b * p[1])]);
            }
        }
        fn squared_residuals(&self, m: &[f64; 3], out: &mut [f64]) {
            for (o, p) in out.iter_mut().zip(self.pts) {
                *o = (m[0] * p[0] + m[1] * p[1] + m[2]).powi(2);
            }
        }
    }

    fn line_data(seed: u64, n: usize, inlier_ratio: f64) -> (Vec<[f64; 2]>, usize) {
        let mut rng = SplitMix64::new(seed);
        let n_in = (n as f64 * inlier_ratio).round() as usize;
        let mut pts = Vec::with_capacity(n);
        for i in 0..n {
            if i < n_in {
                let x = rng.uniform(-1.0, 1.0);
                pts.push([x, 0.3 * x + 0.1]);
            } else {
                pts.push([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)]);
            }
        }
        (pts, n_in)
    }

    #[test]
    fn support_measures_differ() {
        // More inliers but a worse fit: counting prefers `a`, MSAC prefers `b`.
        let a = Support { num_inliers: 10, residual_sum: 9.0, msac_cost: 9.0 + 2.0 };
        let b = Support { num_inliers: 9, residual_sum: 1.0, msac_cost: 1.0 + 3.0 };
        assert!(a.is_better_than(&b, SupportMeasure::InlierCount));
        assert!(b.is_better_than(&a, SupportMeasure::Msac));
        assert!(!a.is_better_than(&a, SupportMeasure::Msac));
    }

    #[test]
    fn required_trials_formula() {
        assert_eq!(required_trials(1.0, 5, 0.99, 1.0), 1);
        // w = 0.5, s = 2: log(0.01) / log(0.75) = 16.008 -> 17.
        assert_eq!(required_trials(0.5, 2, 0.99, 1.0), 17);
        assert_eq!(required_trials(0.0, 2, 0.99, 1.0), usize::MAX);
    }

    #[test]
    fn finds_line_deterministically() {
        let (pts, n_in) = line_data(5, 200, 0.3);
        let est = LineEstimator { pts: &pts };
        let opts = RansacOptions { max_error: 1e-6, ..Default::default() };
        let a = ransac(&est, &opts).unwrap();
        let b = ransac(&est, &opts).unwrap();
        assert!(a.num_inliers >= n_in);
        assert_eq!(a.inlier_mask, b.inlier_mask);
        assert_eq!(a.num_trials, b.num_trials);
        assert!(a.inlier_mask[..n_in].iter().all(|x| *x));
    }

    #[test]
    fn too_few_points_and_bad_options() {
        let pts = [[0.0, 0.0]];
        let est = LineEstimator { pts: &pts };
        assert!(matches!(ransac(&est, &RansacOptions::default()), Err(EstimatorError::TooFewPoints { .. })));
        let pts = [[0.0, 0.0], [1.0, 1.0]];
        let est = LineEstimator { pts: &pts };
        let bad = RansacOptions { confidence: 1.0, ..Default::default() };
        assert!(matches!(ransac(&est, &bad), Err(EstimatorError::InvalidOptions(_))));
        let bad = RansacOptions { max_error: f64::NAN, ..Default::default() };
        assert!(matches!(ransac(&est, &bad), Err(EstimatorError::InvalidOptions(_))));
    }

    #[test]
    fn identical_points_give_no_model() {
        let pts = vec![[0.5, 0.5]; 20];
        let est = LineEstimator { pts: &pts };
        assert!(matches!(ransac(&est, &RansacOptions::default()), Err(EstimatorError::NoModel { .. })));
    }

    /// Empirical check of the adaptive stopping rule: with multiplier 1 and no
    /// LO, the fraction of runs that find the true (noise-free) line must be
    /// at least the requested confidence.
    #[test]
    fn confidence_holds_empirically() {
        let confidence = 0.95;
        let runs = 400;
        let mut ok = 0;
        for seed in 0..runs {
            let (pts, n_in) = line_data(1000 + seed, 60, 0.3);
            let est = LineEstimator { pts: &pts };
            let opts = RansacOptions {
                max_error: 1e-9,
                confidence,
                dyn_trials_multiplier: 1.0,
                min_inlier_ratio: 0.01,
                local_optimization: false,
                seed,
                ..Default::default()
            };
            if let Ok(r) = ransac(&est, &opts)
                && r.num_inliers >= n_in
            {
                ok += 1;
            }
        }
        let rate = ok as f64 / runs as f64;
        assert!(rate >= confidence, "success rate {rate} below confidence {confidence}");
    }
}

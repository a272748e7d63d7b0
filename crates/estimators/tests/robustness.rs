//! Acceptance tests across many seeds: noisy data with outliers for relative
//! and absolute pose, and the empirical confidence of the adaptive RANSAC
//! stopping rule. The heavy versions are `#[ignore]`d: run them with
//! `cargo test -p colslam-estimators --release -- --ignored`.

use colslam_estimators::ransac::required_trials;
use colslam_estimators::synthetic::{
    absolute_scene, relative_scene_wide, rotation_error_deg, translation_dir_error_deg,
};
use colslam_estimators::{
    AbsolutePoseOptions, Estimator, RansacOptions, RelativePoseOptions, estimate_absolute_pose, estimate_relative_pose,
    ransac,
};
use colslam_geometry::SplitMix64;

/// 1 px at a 500 px focal length, in normalised units.
const ONE_PIXEL: f64 = 1.0 / 500.0;

/// Relative pose over `seeds` (90-degree field of view, 1000 matches, 1 px
/// noise, 50 % outliers). Returns the rotation errors (degrees, sorted) and
/// the worst translation direction error.
///
/// Even the maximum-likelihood pose (refined from the ground truth on the
/// true inliers) exceeds 0.1 degrees of rotation error for a few percent of
/// such random scenes (up to 0.17 degrees at a 62-degree field of view): the
/// rotation/translation ambiguity of a narrow field of view makes it
/// inherent. So the bound is asserted on the 95th percentile, with a hard
/// cap of 0.2 degrees on every scene.
fn check_relative(seeds: std::ops::Range<u64>) -> (Vec<f64>, f64) {
    let mut rot = Vec::new();
    let mut worst_t = 0.0f64;
    for seed in seeds {
        let s = relative_scene_wide(seed, 1000, ONE_PIXEL, 0.5);
        let opts = RelativePoseOptions {
            ransac: RansacOptions { seed, ..RelativePoseOptions::default().ransac },
            ..Default::default()
        };
        let r = estimate_relative_pose(&s.x1, &s.x2, &opts).unwrap();
        let er = rotation_error_deg(&r.cam2_from_cam1, &s.cam2_from_cam1);
        let et = translation_dir_error_deg(&r.cam2_from_cam1.translation, &s.cam2_from_cam1.translation);
        assert!(er < 0.2, "seed {seed}: rotation error {er} deg");
        assert!(et < 1.0, "seed {seed}: translation direction error {et} deg");
        rot.push(er);
        worst_t = worst_t.max(et);
    }
    rot.sort_by(f64::total_cmp);
    let p95 = rot[(rot.len() * 95).div_ceil(100) - 1];
    assert!(p95 < 0.1, "95th percentile rotation error {p95} deg");
    (rot, worst_t)
}

fn check_absolute(seeds: std::ops::Range<u64>) -> (f64, f64) {
    let (mut worst_r, mut worst_p) = (0.0f64, 0.0f64);
    for seed in seeds {
        let s = absolute_scene(seed, 1000, ONE_PIXEL, 0.5);
        let opts = AbsolutePoseOptions {
            ransac: RansacOptions { seed, ..AbsolutePoseOptions::default().ransac },
            ..Default::default()
        };
        let r = estimate_absolute_pose(&s.points2d, &s.points3d, &opts).unwrap();
        let er = rotation_error_deg(&r.cam_from_world, &s.cam_from_world);
        // Points are 2-8 units deep: 2 cm is ~0.4 % of the mean depth.
        let ep = (r.cam_from_world.center() - s.cam_from_world.center()).norm();
        assert!(er < 0.1, "seed {seed}: rotation error {er} deg");
        assert!(ep < 0.02, "seed {seed}: position error {ep}");
        worst_r = worst_r.max(er);
        worst_p = worst_p.max(ep);
    }
    (worst_r, worst_p)
}

#[test]
fn relative_pose_noise_outliers_few_seeds() {
    let (r, t) = check_relative(0..3);
    eprintln!("relative pose rotation errors {r:?} deg, worst translation {t:.4} deg");
}

#[test]
fn absolute_pose_noise_outliers_few_seeds() {
    let (r, p) = check_absolute(0..5);
    eprintln!("absolute pose worst: rotation {r:.4} deg, position {p:.5}");
}

#[test]
#[ignore = "statistical, ~1 min in release; run with --release -- --ignored"]
fn relative_pose_noise_outliers_many_seeds() {
    let (r, t) = check_relative(0..100);
    let mean = r.iter().sum::<f64>() / r.len() as f64;
    eprintln!(
        "relative pose over 100 seeds: rotation mean {mean:.4}, p95 {:.4}, max {:.4} deg; worst translation {t:.4} deg",
        r[94], r[99]
    );
}

#[test]
#[ignore = "statistical, ~1 min in release; run with --release -- --ignored"]
fn absolute_pose_noise_outliers_many_seeds() {
    let (r, p) = check_absolute(0..100);
    eprintln!("absolute pose worst over 100 seeds: rotation {r:.4} deg, position {p:.5}");
}

/// A cheap estimator: 2D line through two points.
struct Line<'a>(&'a [[f64; 2]]);

impl Estimator for Line<'_> {
    type Model = [f64; 3];
    fn name(&self) -> &'static str {
        "line"
    }
    fn sample_size(&self) -> usize {
        2
    }
    fn num_data(&self) -> usize {
        self.0.len()
    }
    fn estimate_minimal(&self, s: &[usize], models: &mut Vec<[f64; 3]>) {
        let (p, q) = (self.0[s[0]], self.0[s[1]]);
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        let n = (dx * dx + dy * dy).sqrt();
        if n > 1e-12 {
            models.push([-dy / n, dx / n, (dy * p[0] - dx * p[1]) / n]);
        }
    }
    fn squared_residuals(&self, m: &[f64; 3], out: &mut [f64]) {
        for (o, p) in out.iter_mut().zip(self.0) {
            *o = (m[0] * p[0] + m[1] * p[1] + m[2]).powi(2);
        }
    }
}

/// Fraction of `runs` RANSAC runs (multiplier 1, no LO) that find every
/// true inlier of a noise-free line with 20 % inliers, and the mean number of
/// trials divided by the number the stopping rule needs at the true ratio.
/// The first must reach the confidence (the rule does not stop too early),
/// the second must stay near 1 (it does not run far too long).
fn confidence_rate(confidence: f64, runs: u64) -> (f64, f64) {
    let mut ok = 0;
    let mut trials = 0usize;
    for seed in 0..runs {
        let mut rng = SplitMix64::new(seed * 7 + 1);
        let n_in = 20;
        let pts: Vec<[f64; 2]> = (0..100)
            .map(|i| {
                let x = rng.uniform(-1.0, 1.0);
                if i < n_in { [x, -0.7 * x + 0.2] } else { [x, rng.uniform(-1.0, 1.0)] }
            })
            .collect();
        let opts = RansacOptions {
            max_error: 1e-9,
            confidence,
            dyn_trials_multiplier: 1.0,
            min_inlier_ratio: 0.01,
            local_optimization: false,
            seed,
            ..Default::default()
        };
        if let Ok(r) = ransac(&Line(&pts), &opts) {
            trials += r.num_trials;
            if r.inlier_mask[..n_in].iter().all(|b| *b) {
                ok += 1;
            }
        }
    }
    let needed = required_trials(0.2, 2, confidence, 1.0) as f64;
    (ok as f64 / runs as f64, trials as f64 / runs as f64 / needed)
}

#[test]
fn ransac_confidence_holds_300_runs() {
    let (rate, overrun) = confidence_rate(0.95, 300);
    assert!(rate >= 0.95, "success rate {rate}");
    assert!(overrun < 1.3, "mean trials {overrun} x the needed number");
}

#[test]
#[ignore = "statistical, run with --release -- --ignored"]
fn ransac_confidence_holds_1000_runs() {
    for confidence in [0.9, 0.99, 0.999] {
        let (rate, overrun) = confidence_rate(confidence, 1000);
        eprintln!("confidence {confidence}: success rate {rate}, mean trials {overrun:.3} x needed");
        assert!(rate >= confidence, "success rate {rate} below {confidence}");
        assert!(overrun < 1.3, "mean trials {overrun} x the needed number");
    }
}

/// Finite but huge coordinates overflow inside the solvers; they must still
/// return (an error or no model), not hang or panic.
#[test]
fn huge_coordinates_do_not_hang() {
    for big in [1e200, 1e49, 1e20] {
        huge(big);
    }
}

fn huge(big: f64) {
    use colslam_estimators::*;
    let x1: Vec<Vec2> = (0..20).map(|i| Vec2::new(big * (i as f64 + 1.0), -big * (i % 3) as f64)).collect();
    let x2: Vec<Vec2> = (0..20).map(|i| Vec2::new(-big * (i % 5) as f64, big * (i as f64 + 2.0))).collect();
    let p3: Vec<Vec3> = (0..20).map(|i| Vec3::new(big * i as f64, big, -big * (i % 4) as f64)).collect();
    let _ = estimate_essential_5pt(&x1[..5], &x2[..5]);
    let _ = estimate_fundamental_7pt(&x1, &x2);
    let _ = estimate_fundamental_8pt(&x1, &x2);
    let _ = estimate_homography_dlt(&x1, &x2);
    let _ = estimate_p3p(&x1, &p3);
    let _ = estimate_p3p_grunert(&x1, &p3);
    let _ = estimate_epnp(&x1, &p3);
    let quick = RansacOptions { max_trials: 50, ..Default::default() };
    let _ = estimate_relative_pose(&x1, &x2, &RelativePoseOptions { ransac: quick.clone(), ..Default::default() });
    let _ = estimate_absolute_pose(&x1, &p3, &AbsolutePoseOptions { ransac: quick.clone(), ..Default::default() });
    let _ = estimate_two_view_geometry(&x1, &x2, &TwoViewGeometryOptions { ransac: quick, ..Default::default() });
    let poses = [
        colslam_geometry::Rigid3::identity(),
        colslam_geometry::Rigid3::new(colslam_geometry::Quat::identity(), Vec3::new(big, 0.0, 0.0)),
    ];
    let _ = triangulate_multiview(&poses, &x1[..2], &TriangulationOptions::default());
}

/// 80 % outliers: the adaptive trial count still finds the pose.
#[test]
fn absolute_pose_with_80_percent_outliers() {
    let s = absolute_scene(42, 1000, ONE_PIXEL, 0.8);
    let r = estimate_absolute_pose(&s.points2d, &s.points3d, &AbsolutePoseOptions::default()).unwrap();
    let er = rotation_error_deg(&r.cam_from_world, &s.cam_from_world);
    assert!(er < 0.2, "rotation error {er} deg");
    assert!((r.inlier_ratio - 0.2).abs() < 0.03, "inlier ratio {}", r.inlier_ratio);
}

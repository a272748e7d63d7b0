//! Acceptance tests across many seeds: noisy data with outliers for relative
//! and absolute pose, and the empirical confidence of the adaptive RANSAC
//! stopping rule. The heavy versions are `#[ignore]`d: run them with
//! `cargo test -p colslam-estimators --release -- --ignored`.

use colslam_estimators::ransac::required_trials;
use colslam_estimators::synthetic::{
    RelativeScene, absolute_scene, relative_scene, relative_scene_wide, rotation_error_deg, translation_dir_error_deg,
};
use colslam_estimators::{
    AbsolutePoseOptions, Estimator, Mat3, RansacOptions, RelativePoseOptions, RelativePoseRefineOptions, RobustLoss,
    Vec2, Vec3, essential_from_pose, estimate_absolute_pose, estimate_relative_pose, ransac, refine_relative_pose,
};
use colslam_geometry::{Quat, Rigid3, SplitMix64};
use nalgebra::SMatrix;

/// 1 px at a 500 px focal length, in normalised units.
const ONE_PIXEL: f64 = 1.0 / 500.0;

/// Relative pose over `seeds`, asserting the bound on every scene:
/// rotation error under 0.1 degrees and translation direction error under
/// 1 degree. Returns the rotation errors (degrees, sorted) and the worst
/// translation direction error.
///
/// Configuration ([`relative_scene_wide`]): a 1000 x 1000 px image at a
/// 500 px focal length (90-degree field of view, a wide-angle camera),
/// 1 px Gaussian noise in both views, 1000 correspondences of which 50 % are
/// outliers (a random point of the second image), points 2-8 m deep,
/// baseline 0.5-1 m in a random direction (forward, lateral or oblique),
/// rotation up to 17 degrees, 2 px Sampson threshold. The Cramér-Rao bound
/// on the rotation (RMS, from the 500 true inliers) is 0.031 deg on average
/// and at most 0.043 deg over seeds 0..100, so 0.1 deg is reachable on every
/// scene; ours measured mean 0.033, max 0.081 deg (the maximum-likelihood
/// pose on the true inliers: 0.028 and 0.081).
fn check_relative(seeds: std::ops::Range<u64>) -> (Vec<f64>, f64) {
    let mut rot = Vec::new();
    let mut worst_t = 0.0f64;
    for seed in seeds {
        let s = relative_scene_wide(seed, 1000, ONE_PIXEL, 0.5);
        let r = estimate_relative_pose(&s.x1, &s.x2, &relative_options(seed)).unwrap();
        let er = rotation_error_deg(&r.cam2_from_cam1, &s.cam2_from_cam1);
        let et = translation_dir_error_deg(&r.cam2_from_cam1.translation, &s.cam2_from_cam1.translation);
        assert!(er < 0.1, "seed {seed}: rotation error {er} deg");
        assert!(et < 1.0, "seed {seed}: translation direction error {et} deg");
        rot.push(er);
        worst_t = worst_t.max(et);
    }
    rot.sort_by(f64::total_cmp);
    (rot, worst_t)
}

fn relative_options(seed: u64) -> RelativePoseOptions {
    RelativePoseOptions {
        ransac: RansacOptions { seed, ..RelativePoseOptions::default().ransac },
        ..Default::default()
    }
}

/// Signed Sampson residuals of `x1[i] <-> x2[i]` under `pose`.
fn signed_sampson(pose: &Rigid3, x1: &[Vec2], x2: &[Vec2]) -> Vec<f64> {
    let e = essential_from_pose(pose);
    x1.iter()
        .zip(x2)
        .map(|(p, q)| {
            let a = Vec3::new(p.x, p.y, 1.0);
            let b = Vec3::new(q.x, q.y, 1.0);
            let (ea, etb) = (e * a, e.transpose() * b);
            b.dot(&ea) / (ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y).sqrt()
        })
        .collect()
}

/// Cramér-Rao bound of the relative rotation of a scene: the covariance
/// (radians², left perturbation) of an unbiased estimator from the
/// noise-free true inliers with isotropic Gaussian image noise `sigma` in
/// both views. The Sampson residual is the first-order geometric error, of
/// variance `sigma²`, so the Fisher information is `JᵀJ / sigma²` over the
/// five pose parameters (rotation, unit translation direction).
fn rotation_crlb(s: &RelativeScene, sigma: f64) -> Mat3 {
    let pose = Rigid3::new(s.cam2_from_cam1.rotation, s.cam2_from_cam1.translation.normalize());
    let proj = |p: &Vec3| Vec2::new(p.x / p.z, p.y / p.z);
    let inl = s.points.iter().zip(&s.is_inlier).filter(|(_, i)| **i).map(|(p, _)| p);
    let x1: Vec<Vec2> = inl.clone().map(proj).collect();
    let x2: Vec<Vec2> = inl.map(|p| proj(&pose.transform_point(p))).collect();
    let t = pose.translation;
    let b1 = t.cross(&if t.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() }).normalize();
    let b2 = t.cross(&b1);
    let perturbed = |k: usize, h: f64| {
        let mut d = [0.0; 5];
        d[k] = h;
        let q = Quat::from_scaled_axis(Vec3::new(d[0], d[1], d[2])) * pose.rotation;
        Rigid3::new(q, (t + b1 * d[3] + b2 * d[4]).normalize())
    };
    let h = 1e-6;
    let cols: Vec<Vec<f64>> = (0..5)
        .map(|k| {
            let (p, m) = (signed_sampson(&perturbed(k, h), &x1, &x2), signed_sampson(&perturbed(k, -h), &x1, &x2));
            p.iter().zip(&m).map(|(a, b)| (a - b) / (2.0 * h)).collect()
        })
        .collect();
    let jtj = SMatrix::<f64, 5, 5>::from_fn(|a, b| cols[a].iter().zip(&cols[b]).map(|(u, v)| u * v).sum());
    let cov = jtj.try_inverse().expect("the true pose of a general scene is observable") * (sigma * sigma);
    cov.fixed_view::<3, 3>(0, 0).into_owned()
}

/// Probability that a zero-mean Gaussian rotation error of covariance `cov`
/// (radians²) exceeds `deg` degrees, by Monte Carlo with a seeded RNG.
fn prob_rotation_exceeds(cov: &Mat3, deg: f64, rng: &mut SplitMix64) -> f64 {
    let l = cov.cholesky().expect("a covariance is positive definite").l();
    let draws = 4000;
    let hits = (0..draws)
        .filter(|_| (l * Vec3::new(rng.normal(), rng.normal(), rng.normal())).norm().to_degrees() > deg)
        .count();
    hits as f64 / draws as f64
}

/// Rotation error (degrees) of the maximum-likelihood pose from the true
/// inliers only (an oracle: Sampson-error least squares from the ground
/// truth, no outlier among its points).
fn oracle_rotation_error_deg(s: &RelativeScene) -> f64 {
    let pick = |x: &[Vec2]| -> Vec<Vec2> { x.iter().zip(&s.is_inlier).filter(|(_, i)| **i).map(|(p, _)| *p).collect() };
    let opts = RelativePoseRefineOptions { loss: RobustLoss::Trivial, max_iterations: 200, function_tolerance: 1e-14 };
    let (ml, _) = refine_relative_pose(&s.cam2_from_cam1, &pick(&s.x1), &pick(&s.x2), &opts)
        .expect("refinement from the true pose succeeds");
    rotation_error_deg(&ml, &s.cam2_from_cam1)
}

/// The narrower 62-degree field of view ([`relative_scene`]: a 600 x 600 px
/// image at a 500 px focal length, close to a 640 x 480 camera at 500 px,
/// 65 x 51 degrees; otherwise the configuration of [`check_relative`]).
/// There the statistical limit itself exceeds 0.1 deg on many scenes: the
/// rotation/translation ambiguity of a narrow field of view (a small
/// rotation about an axis orthogonal to the baseline mimics a change of the
/// translation direction) leaves the Cramér-Rao RMS rotation error at
/// 0.060 deg on average, 0.093 at the 95th percentile and 0.101 deg at
/// worst over seeds 0..100, worst for lateral baselines. An efficient
/// estimator then exceeds 0.1 deg on 8.7 of those 100 scenes (summed
/// Monte-Carlo probabilities) and the maximum-likelihood pose on the true
/// inliers does on 6 (ours: 7; mean 0.055 deg against the oracle's 0.048). So this test compares against those limits instead of
/// the fixed bound: ours must stay within 25 % of the oracle's mean error,
/// exceed 0.1 deg on at most 1.5 x the predicted number of scenes (+ 2),
/// and stay under 0.2 deg everywhere.
fn check_relative_narrow(seeds: std::ops::Range<u64>) -> (f64, f64, f64, usize, f64) {
    let (mut ours, mut oracle, mut expected_over, mut over) = (0.0, 0.0, 0.0, 0);
    let mut worst = 0.0f64;
    let mut mc = SplitMix64::new(99);
    let count = seeds.end - seeds.start;
    for seed in seeds {
        let s = relative_scene(seed, 1000, ONE_PIXEL, 0.5);
        let r = estimate_relative_pose(&s.x1, &s.x2, &relative_options(seed)).unwrap();
        let er = rotation_error_deg(&r.cam2_from_cam1, &s.cam2_from_cam1);
        let et = translation_dir_error_deg(&r.cam2_from_cam1.translation, &s.cam2_from_cam1.translation);
        assert!(er < 0.2, "seed {seed}: rotation error {er} deg");
        assert!(et < 1.0, "seed {seed}: translation direction error {et} deg");
        ours += er;
        oracle += oracle_rotation_error_deg(&s);
        expected_over += prob_rotation_exceeds(&rotation_crlb(&s, ONE_PIXEL), 0.1, &mut mc);
        over += usize::from(er > 0.1);
        worst = worst.max(er);
    }
    let (ours, oracle) = (ours / count as f64, oracle / count as f64);
    assert!(ours <= 1.25 * oracle, "mean rotation error {ours} deg vs the oracle's {oracle} deg");
    assert!(
        over as f64 <= 1.5 * expected_over + 2.0,
        "{over} scenes over 0.1 deg, {expected_over:.1} expected from the Cramér-Rao bound"
    );
    (ours, oracle, expected_over, over, worst)
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
#[ignore = "statistical, ~10 s in release; run with --release -- --ignored"]
fn relative_pose_noise_outliers_many_seeds() {
    let (r, t) = check_relative(0..100);
    let mean = r.iter().sum::<f64>() / r.len() as f64;
    eprintln!(
        "relative pose over 100 seeds: rotation mean {mean:.4}, p95 {:.4}, max {:.4} deg; worst translation {t:.4} deg",
        r[94], r[99]
    );
}

#[test]
fn relative_pose_narrow_fov_few_seeds() {
    let (ours, oracle, expected, over, worst) = check_relative_narrow(0..5);
    eprintln!(
        "62-deg FOV: mean {ours:.4} vs oracle {oracle:.4} deg; {over} over 0.1 ({expected:.2} expected); max {worst:.4}"
    );
}

#[test]
#[ignore = "statistical, ~15 s in release; run with --release -- --ignored"]
fn relative_pose_narrow_fov_many_seeds() {
    let (ours, oracle, expected, over, worst) = check_relative_narrow(0..100);
    eprintln!(
        "62-deg FOV over 100 seeds: rotation mean {ours:.4} vs oracle {oracle:.4} deg; {over} scenes over 0.1 deg \
         ({expected:.1} expected from the Cramér-Rao bound); max {worst:.4} deg"
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

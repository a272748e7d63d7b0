//! End-to-end bundle-adjustment tests on seeded synthetic scenes.

use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_optim::synthetic::{SyntheticOptions, SyntheticScene, perturb, synthetic_scene};
use colslam_optim::{
    BaError, BaOptions, BaPose, BehindCamera, BundleAdjuster, IntrinsicsRefinement, LinearSolverType, LossFunction,
    Problem, Termination,
};

fn scene(num_poses: usize, num_points: usize, seed: u64) -> SyntheticScene {
    synthetic_scene(&SyntheticOptions { num_poses, num_points, seed, ..Default::default() }).unwrap()
}

/// Fixes the gauge on poses 0 and 1, perturbs everything, then puts the
/// gauge-fixed values back to the truth so the optimum is the ground truth.
fn perturb_with_gauge(s: &mut SyntheticScene, rot: f64, trans: f64, pt: f64, seed: u64) {
    s.problem.fix_gauge(0, 1);
    perturb(&mut s.problem, rot, trans, pt, seed);
    s.problem.poses[0].cam_from_world = s.true_poses[0];
    let k = s.problem.poses[1].fixed_translation.iter().position(|&f| f).unwrap();
    s.problem.poses[1].cam_from_world.translation[k] = s.true_poses[1].translation[k];
}

/// Largest relative error of points and pose translations/rotations against the truth.
fn max_rel_error(problem: &Problem, poses: &[Rigid3], points: &[Vec3]) -> f64 {
    let mut e: f64 = 0.0;
    for (p, t) in problem.points.iter().zip(points) {
        e = e.max((p.xyz - t).norm() / t.norm());
    }
    for (p, t) in problem.poses.iter().zip(poses) {
        e = e.max((p.cam_from_world.center() - t.center()).norm() / t.center().norm().max(1.0));
        e = e.max(p.cam_from_world.rotation.angle_to(&t.rotation));
    }
    e
}

#[test]
fn noise_free_problem_has_zero_cost() {
    let mut s = scene(8, 300, 1);
    let report = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap();
    assert!(report.initial_cost < 1e-18, "{report:?}");
    assert!(report.final_cost < 1e-18, "{report:?}");
    assert_eq!(report.num_observations, s.problem.observations.len());
}

#[test]
fn perturbed_problem_returns_to_ground_truth() {
    let mut s = scene(10, 400, 2);
    perturb_with_gauge(&mut s, 0.01, 0.05, 0.1, 7);
    let before = max_rel_error(&s.problem, &s.true_poses, &s.true_points);
    assert!(before > 1e-3);
    let options = BaOptions {
        function_tolerance: 0.0,
        parameter_tolerance: 1e-14,
        gradient_tolerance: 1e-14,
        ..Default::default()
    };
    let report = BundleAdjuster::solve(&mut s.problem, &options).unwrap();
    let after = max_rel_error(&s.problem, &s.true_poses, &s.true_points);
    assert!(report.final_cost < 1e-12 && report.initial_cost > 1.0, "{report:?}");
    assert!(after < 1e-6, "relative error {after} after BA ({report:?})");
    assert_eq!(report.num_variable_poses, 9);
}

#[test]
fn refines_focal_length_and_distortion() {
    let mut s = scene(10, 400, 3);
    perturb_with_gauge(&mut s, 0.002, 0.01, 0.02, 8);
    s.problem.cameras[0].camera.params[0] *= 1.02; // f
    s.problem.cameras[0].camera.params[3] = 0.0; // k
    let options = BaOptions {
        function_tolerance: 0.0,
        parameter_tolerance: 1e-14,
        gradient_tolerance: 1e-14,
        ..Default::default()
    };
    let report = BundleAdjuster::solve(&mut s.problem, &options).unwrap();
    assert_eq!(report.num_variable_cameras, 1);
    let got = &s.problem.cameras[0].camera.params;
    let truth = &s.true_camera.params;
    assert!((got[0] - truth[0]).abs() < 1e-6 * truth[0], "f {} vs {}", got[0], truth[0]);
    assert!((got[3] - truth[3]).abs() < 1e-8, "k {} vs {}", got[3], truth[3]);
    // The principal point is not refined by default.
    assert_eq!(got[1], truth[1]);
    assert!(max_rel_error(&s.problem, &s.true_poses, &s.true_points) < 1e-6);
}

fn outlier_scene() -> SyntheticScene {
    synthetic_scene(&SyntheticOptions {
        num_poses: 12,
        num_points: 600,
        pixel_noise: 0.5,
        outlier_ratio: 0.02,
        seed: 4,
        ..Default::default()
    })
    .unwrap()
}

/// Runs BA with `loss` on the outlier scene (optionally dropping the
/// outliers first); returns the median point error against the truth and the
/// median inlier residual.
fn run_outlier_scene(loss: LossFunction, drop_outliers: bool) -> (f64, f64) {
    let mut s = outlier_scene();
    assert!(s.outliers.iter().filter(|&&o| o).count() > 50);
    if drop_outliers {
        let keep: Vec<_> =
            s.problem.observations.iter().zip(&s.outliers).filter(|(_, o)| !**o).map(|(x, _)| *x).collect();
        s.problem.observations = keep;
        s.outliers = vec![false; s.problem.observations.len()];
    }
    s.problem.cameras[0].refine = IntrinsicsRefinement::Fixed;
    perturb_with_gauge(&mut s, 0.002, 0.01, 0.05, 9);
    // Reject (not COLMAP's zero residual) for points pushed behind a camera:
    // with zero residuals, Huber and soft-L1 (which still pull on gross
    // outliers) "hide" outliers by moving points behind cameras.
    let options = BaOptions { loss, behind_camera: BehindCamera::Reject, ..Default::default() };
    let report = BundleAdjuster::solve(&mut s.problem, &options).unwrap();
    // Plain least squares and Huber (linear growth) can keep sliding points
    // that gross outliers pushed behind a camera; the others converge.
    if matches!(loss, LossFunction::Cauchy(_) | LossFunction::SoftL1(_)) || drop_outliers {
        assert!(report.termination.is_converged(), "{loss:?}: {report:?}");
    }
    // Point errors after a similarity alignment to the truth: the gauge is
    // fixed by a short baseline, so the scale itself is noisy.
    let est: Vec<Vec3> = s.problem.points.iter().map(|p| p.xyz).collect();
    let sim = colslam_geometry::umeyama(&est, &s.true_points, true).unwrap();
    let mut err: Vec<f64> = est.iter().zip(&s.true_points).map(|(p, t)| (sim.transform_point(p) - t).norm()).collect();
    err.sort_by(f64::total_cmp);
    let mut inl: Vec<f64> = s
        .problem
        .observations
        .iter()
        .zip(&s.outliers)
        .filter(|(_, o)| !**o)
        .map(|(o, _)| {
            colslam_optim::reprojection_residual(
                &s.problem.cameras[o.camera].camera,
                &s.problem.poses[o.pose].cam_from_world,
                &s.problem.points[o.point].xyz,
                &o.pixel,
            )
            // Behind the camera (plain least squares can get there): infinite.
            .map_or(f64::INFINITY, |r| r.norm())
        })
        .collect();
    inl.sort_by(f64::total_cmp);
    (err[err.len() / 2], inl[inl.len() / 2])
}

#[test]
fn robust_loss_downweights_outliers() {
    let (err_oracle, med_oracle) = run_outlier_scene(LossFunction::Trivial, true);
    let (err_l2, med_l2) = run_outlier_scene(LossFunction::Trivial, false);
    let (err_cauchy, med_cauchy) = run_outlier_scene(LossFunction::Cauchy(1.0), false);
    let (err_huber, _) = run_outlier_scene(LossFunction::Huber(1.0), false);
    let (err_soft, _) = run_outlier_scene(LossFunction::SoftL1(1.0), false);
    eprintln!(
        "median point error: inliers-only L2 {err_oracle:.4}, L2 {err_l2:.4}, Cauchy {err_cauchy:.4}, Huber {err_huber:.4}, \
         soft-L1 {err_soft:.4}; median inlier residual: oracle {med_oracle:.3}, L2 {med_l2:.3}, Cauchy {med_cauchy:.3}"
    );
    // Robust fits with 2 % gross outliers come close to the outlier-free fit;
    // plain least squares does not.
    // (Measured: oracle 0.014, L2 3.5, robust 0.03.)
    assert!(err_l2 > 50.0 * err_oracle, "L2 {err_l2} vs oracle {err_oracle}");
    for (name, e) in [("Cauchy", err_cauchy), ("Huber", err_huber), ("soft-L1", err_soft)] {
        assert!(e < 3.0 * err_oracle, "{name} {e} vs oracle {err_oracle}");
    }
    assert!(med_cauchy < 1.1 * med_oracle && med_l2 > 2.0 * med_oracle);
}

#[test]
fn dense_sparse_and_iterative_agree() {
    let base = synthetic_scene(&SyntheticOptions {
        num_poses: 40,
        num_points: 1500,
        pixel_noise: 0.5,
        seed: 5,
        ..Default::default()
    })
    .unwrap();
    let mut results = Vec::new();
    for solver in [LinearSolverType::DenseSchur, LinearSolverType::SparseSchur, LinearSolverType::IterativeSchur] {
        let mut p = base.problem.clone();
        p.fix_gauge(0, 1);
        perturb(&mut p, 0.002, 0.01, 0.05, 10);
        let options =
            BaOptions { linear_solver: solver, function_tolerance: 1e-12, pcg_tolerance: 1e-10, ..Default::default() };
        let report = BundleAdjuster::solve(&mut p, &options).unwrap();
        assert_eq!(report.linear_solver, solver);
        assert!(report.termination.is_converged(), "{solver:?}: {report:?}");
        results.push((report, p));
    }
    let (r0, p0) = &results[0];
    for (r, p) in &results[1..] {
        assert!((r.final_cost - r0.final_cost).abs() < 1e-8 * r0.final_cost, "{} vs {}", r.final_cost, r0.final_cost);
        for (a, b) in p.points.iter().zip(&p0.points) {
            assert!((a.xyz - b.xyz).norm() < 1e-6 * b.xyz.norm(), "{:?} vs {:?}", a.xyz, b.xyz);
        }
        for (a, b) in p.poses.iter().zip(&p0.poses) {
            assert!((a.cam_from_world.translation - b.cam_from_world.translation).norm() < 1e-6);
        }
    }
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let base = synthetic_scene(&SyntheticOptions {
        num_poses: 12,
        num_points: 5000,
        pixel_noise: 0.5,
        seed: 6,
        ..Default::default()
    })
    .unwrap();
    let run = |threads: usize| {
        let mut p = base.problem.clone();
        p.fix_gauge(0, 1);
        perturb(&mut p, 0.002, 0.01, 0.05, 11);
        let r = BundleAdjuster::solve(&mut p, &BaOptions { num_threads: threads, ..Default::default() }).unwrap();
        (r.final_cost, r.iterations, p)
    };
    let (c1, i1, p1) = run(1);
    let (c2, i2, p2) = run(2);
    assert_eq!((c1.to_bits(), i1), (c2.to_bits(), i2));
    assert_eq!(p1, p2);
}

#[test]
fn free_gauge_still_converges() {
    // No pose fixed: the normal equations are singular along the 7 gauge
    // directions; the LM damping keeps every step well defined.
    let mut s = synthetic_scene(&SyntheticOptions {
        num_poses: 8,
        num_points: 300,
        pixel_noise: 0.3,
        seed: 17,
        ..Default::default()
    })
    .unwrap();
    perturb(&mut s.problem, 0.003, 0.01, 0.03, 18);
    let report = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap();
    assert!(report.termination.is_converged(), "{report:?}");
    // Expected optimum: about 0.5 * sigma^2 * (residuals - parameters).
    let dof = (report.num_residuals - report.num_reduced_parameters - 3 * report.num_variable_points) as f64;
    assert!(report.final_cost < 1.5 * 0.5 * 0.09 * dof, "{report:?}");
}

#[test]
fn degenerate_problems_do_not_panic() {
    // No observations.
    let mut empty = Problem::default();
    let r = BundleAdjuster::solve(&mut empty, &BaOptions::default()).unwrap();
    assert_eq!(r.termination, Termination::NothingToOptimize);
    assert_eq!(r.final_cost, 0.0);

    // Everything fixed: a no-op report with the cost.
    let mut s = scene(4, 50, 12);
    perturb(&mut s.problem, 0.0, 0.0, 0.01, 13);
    for p in &mut s.problem.poses {
        p.fixed = true;
    }
    for p in &mut s.problem.points {
        p.fixed = true;
    }
    s.problem.cameras[0].refine = IntrinsicsRefinement::Fixed;
    let before = s.problem.clone();
    let r = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap();
    assert_eq!(r.termination, Termination::NothingToOptimize);
    assert!(r.final_cost > 0.0 && r.final_cost == r.initial_cost);
    assert_eq!(s.problem, before);

    // A point seen once is held constant; the rest still solves.
    let mut s = scene(4, 50, 14);
    let lone = s.problem.add_point(Vec3::new(0.1, 0.0, 5.0), false);
    let px = colslam_optim::reprojection_residual(
        &s.problem.cameras[0].camera,
        &s.problem.poses[0].cam_from_world,
        &Vec3::new(0.1, 0.0, 5.0),
        &Vec2::zeros(),
    )
    .unwrap();
    s.problem.add_observation(0, 0, lone, px + Vec2::new(3.0, 0.0));
    s.problem.fix_gauge(0, 1);
    let r = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap();
    assert_eq!(r.num_points_held_fixed, 1);
    assert_eq!(s.problem.points[lone].xyz, Vec3::new(0.1, 0.0, 5.0));

    // NaN inputs and bad indices are errors naming the item.
    let mut s = scene(3, 20, 15);
    s.problem.points[3].xyz.x = f64::NAN;
    assert_eq!(
        BundleAdjuster::solve(&mut s.problem, &BaOptions::default()),
        Err(BaError::NonFinite { what: "point", index: 3 })
    );
    let mut s = scene(3, 20, 15);
    s.problem.observations[2].pixel.y = f64::INFINITY;
    assert!(matches!(
        BundleAdjuster::solve(&mut s.problem, &BaOptions::default()),
        Err(BaError::NonFinite { index: 2, .. })
    ));
    let mut s = scene(3, 20, 15);
    s.problem.observations[5].pose = 99;
    let e = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap_err();
    assert!(e.to_string().contains("observation 5"), "{e}");
    let mut s = scene(3, 20, 15);
    s.problem.cameras[0].camera.params.pop();
    assert!(matches!(
        BundleAdjuster::solve(&mut s.problem, &BaOptions::default()),
        Err(BaError::InvalidCamera { index: 0, .. })
    ));
    let mut s = scene(3, 20, 15);
    s.problem.poses[1] =
        BaPose::variable(Rigid3::new(s.problem.poses[1].cam_from_world.rotation, Vec3::new(f64::NAN, 0.0, 0.0)));
    assert!(matches!(
        BundleAdjuster::solve(&mut s.problem, &BaOptions::default()),
        Err(BaError::NonFinite { what: "pose", index: 1 })
    ));

    // Bad options.
    let mut s = scene(3, 20, 15);
    for bad in [
        BaOptions { loss: LossFunction::Cauchy(-1.0), ..Default::default() },
        BaOptions { function_tolerance: f64::NAN, ..Default::default() },
        BaOptions { initial_trust_region_radius: 0.0, ..Default::default() },
    ] {
        assert!(matches!(BundleAdjuster::solve(&mut s.problem, &bad), Err(BaError::InvalidOptions(_))));
    }

    // A point behind a camera: its observation is skipped, not a panic.
    let mut s = scene(4, 50, 16);
    let behind = s.problem.add_point(Vec3::new(0.0, 0.0, -5.0), false);
    s.problem.add_observation(0, 0, behind, Vec2::new(10.0, 10.0));
    s.problem.add_observation(1, 0, behind, Vec2::new(10.0, 10.0));
    s.problem.fix_gauge(0, 1);
    let strict = BaOptions { behind_camera: BehindCamera::Reject, ..Default::default() };
    let r = BundleAdjuster::solve(&mut s.problem.clone(), &strict).unwrap();
    assert_eq!(r.num_skipped_observations, 2);
    // COLMAP semantics (default): zero residual, nothing skipped.
    let r = BundleAdjuster::solve(&mut s.problem, &BaOptions::default()).unwrap();
    assert_eq!(r.num_skipped_observations, 0);
    assert!(r.final_cost.is_finite() && r.final_cost < 1e-12, "{r:?}");
}

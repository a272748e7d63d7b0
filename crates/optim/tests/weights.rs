//! Observation weights whiten residuals: uniform weights scale the cost by
//! their square and leave the solution unchanged; a down-weighted outlier
//! pulls the solution less.

use colslam_optim::synthetic::{SyntheticOptions, perturb, synthetic_scene};
use colslam_optim::{BaOptions, BundleAdjuster, IntrinsicsRefinement};

fn scene() -> colslam_optim::Problem {
    let mut s = synthetic_scene(&SyntheticOptions { num_poses: 6, num_points: 200, ..SyntheticOptions::default() })
        .expect("scene");
    for c in &mut s.problem.cameras {
        c.refine = IntrinsicsRefinement::Fixed;
    }
    s.problem.fix_gauge(0, 1);
    perturb(&mut s.problem, 1e-3, 1e-2, 1e-2, 7);
    s.problem
}

#[test]
fn uniform_weights_scale_the_cost_only() {
    let mut a = scene();
    let mut b = a.clone();
    for o in &mut b.observations {
        o.weight = 3.0;
    }
    let ra = BundleAdjuster::solve(&mut a, &BaOptions::default()).expect("solve");
    let rb = BundleAdjuster::solve(&mut b, &BaOptions::default()).expect("solve");
    assert!((rb.initial_cost - 9.0 * ra.initial_cost).abs() <= 1e-9 * rb.initial_cost.max(1.0));
    for (pa, pb) in a.points.iter().zip(&b.points) {
        assert!((pa.xyz - pb.xyz).norm() < 1e-6, "{} vs {}", pa.xyz, pb.xyz);
    }
}

#[test]
fn down_weighting_a_corrupted_observation_reduces_its_pull() {
    let base = scene();
    let mut plain = base.clone();
    let k = 5;
    plain.observations[k].pixel.x += 30.0;
    let mut weighted = plain.clone();
    weighted.observations[k].weight = 0.01;
    let mut clean = base.clone();
    BundleAdjuster::solve(&mut clean, &BaOptions::default()).expect("solve");
    BundleAdjuster::solve(&mut plain, &BaOptions::default()).expect("solve");
    BundleAdjuster::solve(&mut weighted, &BaOptions::default()).expect("solve");
    let p = base.observations[k].point;
    let d_plain = (plain.points[p].xyz - clean.points[p].xyz).norm();
    let d_weighted = (weighted.points[p].xyz - clean.points[p].xyz).norm();
    assert!(d_weighted < 0.1 * d_plain, "weighted {d_weighted} vs plain {d_plain}");
    let mut bad = base;
    bad.observations[0].weight = f64::NAN;
    assert!(BundleAdjuster::solve(&mut bad, &BaOptions::default()).is_err());
}

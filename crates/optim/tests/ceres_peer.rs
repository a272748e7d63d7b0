//! Cross-check against Ceres through pycolmap 4.2 (`scripts/bench-ba-ceres.py`):
//! same data, same loss, same tolerances must give the same initial cost (the
//! cost definition, loss and pixel convention agree) and the same final cost,
//! with COLMAP's treatment of points behind a camera (zero residual).

use colslam_optim::synthetic::{SyntheticOptions, perturb, synthetic_scene, write_colmap_text};
use colslam_optim::{BaOptions, BundleAdjuster, LossFunction};
use std::process::Command;

/// Pulls `"key": number` out of the script's one-line JSON.
fn json_number(text: &str, key: &str) -> f64 {
    let pat = format!("\"{key}\": ");
    let start = text.find(&pat).unwrap_or_else(|| panic!("no {key} in {text}")) + pat.len();
    let rest = &text[start..];
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    rest[..end].trim().parse().unwrap_or_else(|e| panic!("{key}: {e} in {text}"))
}

#[test]
fn matches_pycolmap_ceres_bundle_adjustment() {
    let Some(python) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let scene = synthetic_scene(&SyntheticOptions {
        num_poses: 7,
        num_points: 800,
        pixel_noise: 0.5,
        outlier_ratio: 0.02,
        seed: 41,
        ..Default::default()
    })
    .unwrap();
    let mut problem = scene.problem;
    problem.fix_gauge(0, 1);
    perturb(&mut problem, 0.002, 0.01, 0.05, 42);
    let dir = std::env::temp_dir().join(format!("colslam-optim-ceres-peer-{}", std::process::id()));
    write_colmap_text(&problem, &dir).unwrap();
    let script = colslam_testutil::workspace_root().join("scripts/bench-ba-ceres.py");
    let losses = [
        ("cauchy", LossFunction::Cauchy(1.0)),
        ("huber", LossFunction::Huber(2.0)),
        ("soft_l1", LossFunction::SoftL1(1.5)),
        ("trivial", LossFunction::Trivial),
    ];
    for (name, loss) in losses {
        let scale = loss.scale().unwrap_or(1.0).to_string();
        let out = Command::new(&python)
            .arg(&script)
            .arg(&dir)
            .args(["--loss", name, "--scale", &scale, "--threads", "1", "--json"])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(out.status.success(), "{}\n{}", text, String::from_utf8_lossy(&out.stderr));
        let mut p = problem.clone();
        let report = BundleAdjuster::solve(&mut p, &BaOptions { loss, ..Default::default() }).unwrap();
        let (ceres_initial, ceres_final) = (json_number(&text, "initial_cost"), json_number(&text, "final_cost"));
        eprintln!(
            "{name}: ours {} -> {} in {} iterations; ceres {text}",
            report.initial_cost, report.final_cost, report.iterations
        );
        assert!(
            (report.initial_cost - ceres_initial).abs() < 1e-9 * ceres_initial,
            "{name}: {} vs {ceres_initial}",
            report.initial_cost
        );
        // Plain least squares with 2 % gross outliers takes ~60 chaotic
        // iterations; the paths drift apart at round-off level.
        let tol = if loss == LossFunction::Trivial { 1e-4 } else { 1e-5 };
        assert!(
            (report.final_cost - ceres_final).abs() < tol * ceres_final,
            "{name}: {} vs {ceres_final}",
            report.final_cost
        );
        assert_eq!(json_number(&text, "num_residuals") as usize, report.num_residuals);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

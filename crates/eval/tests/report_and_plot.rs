//! End-to-end behaviour of `evaluate`, its errors, the JSON report and the
//! PNG plot (synthetic data; the dataset is used when present).

use colslam_eval::plot::{self, ERROR_COLOR, ESTIMATE_COLOR, PlotOptions, REFERENCE_COLOR};
use colslam_eval::{Alignment, EvalError, EvalOptions, Trajectory, evaluate, evaluate_files};
use colslam_geometry::{Quat, Rigid3, Sim3, SplitMix64, Vec3};
use colslam_image::Image;
use std::path::Path;

/// A figure-eight in the x-z plane with a little y, 30 Hz, 10 s.
fn figure_eight() -> Trajectory {
    let n = 300;
    let mut t = Trajectory::default();
    for i in 0..n {
        let s = i as f64 / 30.0;
        let a = s * 2.0 * std::f64::consts::PI / 10.0;
        let c = Vec3::new(2.0 * a.sin(), 0.1 * a.cos(), 1.0 * (2.0 * a).sin());
        t.stamps.push(1_305_031_000.0 + s);
        t.poses.push(Rigid3::new(Quat::from_euler_angles(0.1 * a, a, 0.0), c));
    }
    t
}

fn perturbed(gt: &Trajectory, seed: u64, sigma: f64, s: &Sim3) -> Trajectory {
    let mut rng = SplitMix64::new(seed);
    Trajectory::new(
        gt.stamps.clone(),
        gt.poses
            .iter()
            .map(|p| {
                let noisy = Rigid3::new(
                    p.rotation,
                    p.translation + Vec3::new(rng.normal(), rng.normal(), rng.normal()) * sigma,
                );
                s.transform_world_from_cam(&noisy)
            })
            .collect(),
    )
}

fn count_color(img: &Image, x0: usize, x1: usize, color: [u8; 3]) -> usize {
    let mut n = 0;
    for y in 0..img.height() {
        for x in x0..x1 {
            if [img.get(x, y, 0), img.get(x, y, 1), img.get(x, y, 2)] == color {
                n += 1;
            }
        }
    }
    n
}

#[test]
fn exact_sim3_estimate_has_zero_error() {
    let gt = figure_eight();
    let s =
        Sim3 { scale: 0.3, rotation: Quat::from_euler_angles(0.3, 0.2, -1.0), translation: Vec3::new(1.0, 2.0, 3.0) };
    let est = perturbed(&gt, 1, 0.0, &s);
    let r = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
    assert_eq!(r.matched, 300);
    assert!(r.ate_rmse < 1e-9, "{}", r.ate_rmse);
    assert!((r.scale - 1.0 / 0.3).abs() < 1e-9);
    assert!(r.rpe_trans_rmse < 1e-9 && r.rpe_rot_rmse_deg < 1e-6);
    assert_eq!(r.rpe_pairs, 299);
    // Without alignment the error is large; with SE(3) the scale stays 1.
    let none = evaluate(&gt, &est, &EvalOptions { align: Alignment::None, ..Default::default() }).unwrap();
    assert!(none.ate_rmse > 1.0);
    let se3 = evaluate(&gt, &est, &EvalOptions { align: Alignment::Se3, ..Default::default() }).unwrap();
    assert_eq!(se3.scale, 1.0);
    assert!(se3.ate_rmse > 0.1);
    // Delta 5: consecutive pairs (0,5), (5,10), ...
    let d5 = evaluate(&gt, &est, &EvalOptions { rpe_delta: 5, ..Default::default() }).unwrap();
    assert_eq!(d5.rpe_pairs, 59);
}

#[test]
fn json_report_has_flat_fields_and_no_detail() {
    let gt = figure_eight();
    let est = perturbed(&gt, 2, 0.01, &Sim3::identity());
    let r = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
    let v = serde_json::to_value(&r).unwrap();
    for key in [
        "ate_rmse",
        "ate_mean",
        "ate_median",
        "ate_max",
        "ate_min",
        "ate_std",
        "ate_sse",
        "scale",
        "matched",
        "rpe_trans_rmse",
        "rpe_trans_mean",
        "rpe_trans_median",
        "rpe_trans_max",
        "rpe_rot_rmse_deg",
    ] {
        assert!(v.get(key).is_some_and(|x| x.is_number()), "missing {key}: {v}");
    }
    assert_eq!(v["align"], "sim3");
    assert!(v.get("detail").is_none());
    assert_eq!(r.detail.ate_errors.len(), 300);
    // Noise of 1 cm per axis: ATE RMSE close to sqrt(3) cm.
    assert!((r.ate_rmse - 0.0173).abs() < 0.003, "{}", r.ate_rmse);
    let text = r.to_string();
    assert!(text.contains("ATE [m]") && text.contains("RPE rot [deg]"), "{text}");
}

#[test]
fn errors_name_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let gt = figure_eight();
    let gt_path = dir.path().join("gt.txt");
    gt.write_tum(&gt_path).unwrap();

    // No stamps in common.
    let mut late = gt.clone();
    late.stamps.iter_mut().for_each(|t| *t += 100.0);
    let late_path = dir.path().join("late.txt");
    late.write_tum(&late_path).unwrap();
    let e = evaluate_files(&gt_path, &late_path, &EvalOptions::default()).unwrap_err();
    assert!(matches!(e, EvalError::NoMatches { .. }));
    let msg = e.to_string();
    assert!(msg.contains("gt.txt") && msg.contains("late.txt") && msg.contains("no matching timestamps"), "{msg}");
    // ... but the offset brings them back.
    let ok = evaluate_files(&gt_path, &late_path, &EvalOptions { offset: -100.0, ..Default::default() }).unwrap();
    assert_eq!(ok.matched, 300);

    // Two matches only.
    let two_path = dir.path().join("two.txt");
    gt.select(&[3, 50]).write_tum(&two_path).unwrap();
    let msg = evaluate_files(&gt_path, &two_path, &EvalOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("two.txt") && msg.contains("only 2 matched") && msg.contains("alignment"), "{msg}");

    // All estimated positions equal: degenerate.
    let mut still = gt.clone();
    still.poses.iter_mut().for_each(|p| p.translation = Vec3::new(1.0, 1.0, 1.0));
    let still_path = dir.path().join("still.txt");
    still.write_tum(&still_path).unwrap();
    let msg = evaluate_files(&gt_path, &still_path, &EvalOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("still.txt") && msg.contains("degenerate"), "{msg}");

    // A malformed line.
    let bad_path = dir.path().join("bad.txt");
    std::fs::write(&bad_path, "# x\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n").unwrap();
    let msg = evaluate_files(&gt_path, &bad_path, &EvalOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("bad.txt:3:"), "{msg}");

    // Empty file, invalid options.
    let empty_path = dir.path().join("empty.txt");
    std::fs::write(&empty_path, "# nothing\n").unwrap();
    let msg = evaluate_files(&gt_path, &empty_path, &EvalOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("empty.txt") && msg.contains("no poses"), "{msg}");
    for bad in [
        EvalOptions { max_diff: -1.0, ..Default::default() },
        EvalOptions { rpe_delta: 0, ..Default::default() },
        EvalOptions { n_to_align: Some(2), ..Default::default() },
    ] {
        assert!(matches!(bad.validate(), Err(EvalError::InvalidOptions(_))));
    }
}

fn check_plot(path: &Path, opts: &PlotOptions) {
    let img = Image::read(path).expect("plot decodes");
    assert_eq!((img.width(), img.height()), (opts.width, opts.height));
    assert_eq!(img.channels(), 3);
    let half = img.width() / 2;
    let r = count_color(&img, 0, half, REFERENCE_COLOR);
    let e = count_color(&img, 0, half, ESTIMATE_COLOR);
    assert!(r > 100 && e > 100, "top view: {r} reference and {e} estimate pixels");
    let err = count_color(&img, half, img.width(), ERROR_COLOR);
    assert!(err > 100, "error panel: {err} pixels");
    assert_eq!(count_color(&img, half, img.width(), REFERENCE_COLOR), 0, "reference leaked into the error panel");
}

#[test]
fn plot_png_has_both_trajectories() {
    let dir = tempfile::tempdir().unwrap();
    let gt = figure_eight();
    let est = perturbed(&gt, 3, 0.03, &Sim3 { scale: 2.0, ..Sim3::identity() });
    let r = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
    let path = dir.path().join("eval.png");
    plot::plot_evaluation(&r, &path).unwrap();
    check_plot(&path, &PlotOptions::default());
    let small = PlotOptions { width: 800, height: 400, title: Some("custom".into()) };
    let p2 = dir.path().join("small.png");
    plot::plot_evaluation_with(&r, &p2, &small).unwrap();
    check_plot(&p2, &small);
    assert!(plot::plot_evaluation_with(&r, &p2, &PlotOptions { width: 10, ..Default::default() }).is_err());
}

#[test]
fn plot_of_dataset_ground_truth() {
    let Some(data) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let gt = Trajectory::read_tum(&data.join("groundtruth.txt")).unwrap();
    let idx: Vec<usize> = (0..gt.len()).step_by(7).collect();
    let s =
        Sim3 { scale: 0.5, rotation: Quat::from_euler_angles(0.0, 0.0, 1.0), translation: Vec3::new(0.1, 0.0, 0.0) };
    let est = perturbed(&gt.select(&idx), 4, 0.01, &s);
    let r = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = std::env::var_os("COLSLAM_EVAL_PLOT").map(std::path::PathBuf::from);
    let path = out.unwrap_or_else(|| dir.path().join("rpy.png"));
    plot::plot_evaluation(&r, &path).unwrap();
    check_plot(&path, &PlotOptions::default());
}

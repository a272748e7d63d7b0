//! `colslam bench` sequence suite, end to end on a tiny selection: one short
//! synthetic sequence (40 frames at 320x240), a one-value sweep, and a
//! deliberately failing sequence (a folder that does not exist). Checks the
//! reports and plots, that the failure is a row while the rest goes on, and
//! that the suite's ATE equals `evo_ape tum -as` on the same files.

use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// The suite's ATE and evo's must agree to this (metres).
const EVO_TOL: f64 = 1e-6;
/// A generous bound on the tiny synthetic run's ATE (metres): the pipeline
/// reaches a few millimetres there; a broken evaluation gives decimetres.
const SYNTHETIC_ATE_BOUND: f64 = 0.05;

/// evo's own `evo_ape` entry point, results saved to a zip; prints the RMSE
/// with full precision.
const EVO_APE: &str = r#"
import json, sys, zipfile
from evo.cli.entry_points import ape
gt, est, out = sys.argv[1], sys.argv[2], sys.argv[3]
sys.argv = ["evo_ape", "tum", gt, est, "-as", "--save_results", out, "--no_warnings", "--silent"]
try:
    ape()
except SystemExit as e:
    if e.code not in (None, 0):
        raise
with zipfile.ZipFile(out) as z:
    print("EVO_RMSE", repr(json.loads(z.read("stats.json"))["rmse"]))
"#;

fn is_png(path: &Path) -> bool {
    std::fs::read(path).map(|b| b.len() > 1000 && b.starts_with(b"\x89PNG")).unwrap_or(false)
}

#[test]
fn tiny_suite_with_a_failing_sequence() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let out = tmp.path().join("bench");
    let missing = tmp.path().join("no_such_sequence");
    let status = Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["-q", "bench", "--only", "synthetic-40", "--synthetic-size", "320x240", "--timeout", "300"])
        .args(["--sweep", "skip=2"])
        .arg("--sequence")
        .arg(&missing)
        .arg("--out")
        .arg(&out)
        .status()
        .expect("run colslam bench");
    assert!(status.success(), "the suite must finish although one sequence fails");

    let md = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    let report: Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report.json")).unwrap();
    let runs = report["runs"].as_array().expect("runs");
    let summary = report["summary"].as_array().expect("summary");

    // The failing sequence is a failure row with its reason, in both reports.
    let failed = runs.iter().find(|r| r["sequence"] == "no_such_sequence").expect("failure row");
    assert_eq!(failed["status"], "failed");
    let reason = failed["reason"].as_str().expect("reason");
    assert!(reason.contains("exit status") && reason.contains("no_such_sequence"), "{reason}");
    assert!(md.contains("| no_such_sequence | colslam | FAILED |"), "{md}");
    assert!(md.contains("Failures"), "{md}");

    // The synthetic run went on and succeeded, with every column filled.
    let syn = runs.iter().find(|r| r["sequence"] == "synthetic-40" && r["setting"] == "").expect("synthetic row");
    assert_eq!(syn["status"], "ok", "{syn}");
    assert_eq!(syn["frames"], 40);
    let ate = syn["ate_rmse_m"].as_f64().expect("ATE");
    assert!(ate > 0.0 && ate < SYNTHETIC_ATE_BOUND, "ATE {ate}");
    assert!(syn["ate_kf_rmse_m"].as_f64().is_some(), "keyframe ATE");
    for key in ["wall_s", "cpu_s", "peak_rss_mib", "ms_per_frame", "init_s", "registration_ms_per_frame"] {
        let v = syn[key].as_f64().unwrap_or_else(|| panic!("{key} missing: {syn}"));
        assert!(v.is_finite() && v >= 0.0, "{key} = {v}");
    }
    assert!(syn["peak_rss_mib"].as_f64().unwrap() > 1.0, "peak RSS must be measured");
    assert!(syn["keyframes"].as_u64().unwrap() >= 2 && syn["points"].as_u64().unwrap() > 0);
    assert!(md.contains("| synthetic-40 | colslam | ok | 1/1 | 40/40 (100.0 %) |"), "{md}");

    // The sweep ran as its own row.
    let sweep = summary.iter().find(|s| s["setting"] == "skip=2").expect("sweep row");
    assert_eq!(sweep["frames"], 20.0);
    assert!(md.contains("colslam (skip=2)"), "{md}");

    // Plots: top view + ATE over time, and the side view.
    let plots: Vec<&str> = syn["plots"].as_array().expect("plots").iter().filter_map(Value::as_str).collect();
    assert_eq!(plots.len(), 2, "{plots:?}");
    for p in &plots {
        assert!(is_png(&out.join(p)), "{p} is not a PNG");
    }
    assert!(md.contains("side.png") && md.contains("ate.png"));

    // The reference tables are there, marked as not measured by this run.
    assert!(md.contains("measured earlier, not this run") && md.contains("10.93"));

    // The suite's ATE equals evo_ape tum -as on the same files.
    let Some(py) = colslam_testutil::peer_python(&["evo"]) else { return };
    let run_dir = out.join(syn["output_dir"].as_str().expect("output dir"));
    let gt = out.join("data/synthetic-40/groundtruth.txt");
    let zip = tmp.path().join("evo.zip");
    let printed = colslam_testutil::run_python(
        &py,
        &["-c", EVO_APE, gt.to_str().unwrap(), run_dir.join("trajectory.tum").to_str().unwrap(), zip.to_str().unwrap()],
    );
    // evo prints a notice of its own when it first creates its settings
    // (a machine where it never ran): take the tagged line.
    let evo: f64 = printed
        .lines()
        .find_map(|l| l.strip_prefix("EVO_RMSE "))
        .unwrap_or_else(|| panic!("no rmse in evo's output:\n{printed}"))
        .trim()
        .parse()
        .expect("evo rmse");
    assert!((evo - ate).abs() < EVO_TOL, "suite ATE {ate} vs evo_ape {evo}");
}

#[test]
fn bad_arguments_are_errors() {
    for args in [&["bench", "--sweep", "bogus=1"][..], &["bench", "--only", "nope"], &["bench", "--runs", "0"]] {
        let out = Command::new(env!("CARGO_BIN_EXE_colslam"))
            .args(args)
            .arg("--out")
            .arg(std::env::temp_dir().join("colslam-bench-bad"))
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?} must fail");
        assert!(!String::from_utf8_lossy(&out.stderr).is_empty(), "{args:?} must say why");
    }
}

/// `colslam bench precision` on one tiny synthetic sequence: the keypoint
/// localisation table (integer against sub-pixel), the final model's
/// reprojection errors and track-length buckets, and the ATE, in both
/// reports; flags after `--` reach the run.
#[test]
fn precision_report_on_a_tiny_synthetic_sequence() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let out = tmp.path().join("precision");
    let status = Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["-q", "bench", "precision", "--only", "synthetic-40", "--synthetic-size", "320x240"])
        .args(["--pairs", "5", "--gap", "1", "--timeout", "300", "--out"])
        .arg(&out)
        .args(["--", "--max-frames", "30"])
        .status()
        .expect("run colslam bench precision");
    assert!(status.success());
    let md = std::fs::read_to_string(out.join("precision.md")).expect("precision.md");
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("precision.json")).expect("precision.json")).unwrap();
    assert_eq!(report["run_flags"], serde_json::json!(["--max-frames", "30"]));
    let row = &report["rows"][0];
    assert_eq!(row["sequence"], "synthetic-40");
    assert_eq!(row["status"], "ok", "{row}");
    for kind in ["keypoints_integer", "keypoints_subpixel"] {
        let k = &row[kind];
        assert_eq!(k["pairs"], 5);
        assert!(k["inliers"].as_u64().unwrap() > 100, "{k}");
        assert!(k["median_px"].as_f64().unwrap() > 0.0 && k["median_px"].as_f64().unwrap() < 2.0, "{k}");
    }
    let ate = row["ate_rmse_m"].as_f64().expect("ATE");
    assert!(ate > 0.0 && ate < SYNTHETIC_ATE_BOUND, "ATE {ate}");
    let model = &row["model"];
    assert!(model["images"].as_u64().unwrap() >= 2, "{model}");
    let (points, buckets) = (model["points"].as_u64().unwrap(), model["track_buckets"].as_array().unwrap());
    assert_eq!(buckets.len(), 5);
    assert_eq!(buckets.iter().map(|b| b.as_u64().unwrap()).sum::<u64>(), points, "every track has 2+ views");
    let mean = model["mean_reprojection_px"].as_f64().unwrap();
    let median = model["median_reprojection_px"].as_f64().unwrap();
    assert!(median > 0.0 && median <= mean && mean < 4.0, "{model}");
    assert!(md.contains("| synthetic-40 | sub-pixel |") && md.contains("| synthetic-40 | ok |"), "{md}");
    assert!(md.contains("--max-frames 30"), "{md}");
}

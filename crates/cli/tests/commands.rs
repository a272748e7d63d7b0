//! The small commands end to end through the binary: `demo --generate-only`,
//! `eval` (JSON keys, plot, agreement with the library), `info`, `export`,
//! and clear errors on bad input.

use std::path::Path;

mod common;
use common::{colslam, ok};

#[test]
fn demo_eval_info_export() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = dir.path().join("seq");
    let seq_s = seq.to_str().expect("utf-8 path");
    ok(&["-q", "demo", "--generate-only", "-o", seq_s, "--frames", "12", "--width", "160", "--height", "120"]);
    for f in ["rgb.txt", "groundtruth.txt", "camera.yaml", "scene.json", "rgb/000011.png"] {
        assert!(seq.join(f).exists(), "{f} missing");
    }
    let info = ok(&["info", seq_s]);
    assert!(info.contains("12") && info.contains("160x120"), "{info}");

    // An estimate: the ground truth scaled by 2 and shifted in time by 1 ms.
    let gt = seq.join("groundtruth.txt");
    let est = dir.path().join("est.tum");
    let text = std::fs::read_to_string(&gt).expect("read gt");
    let lines: Vec<String> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().expect("number")).collect();
            format!("{} {} {} {} {} {} {} {}", v[0] + 0.001, 2.0 * v[1], 2.0 * v[2], 2.0 * v[3], v[4], v[5], v[6], v[7])
        })
        .collect();
    std::fs::write(&est, lines.join("\n")).expect("write est");
    let plot = dir.path().join("plot.png");
    let json = ok(&[
        "eval",
        "--gt",
        gt.to_str().expect("utf-8"),
        "--est",
        est.to_str().expect("utf-8"),
        "--json",
        "--plot",
        plot.to_str().expect("utf-8"),
    ]);
    let v: serde_json::Value = serde_json::from_str(json.trim()).expect("one JSON object");
    for k in ["ate_rmse", "ate_mean", "ate_median", "ate_max", "ate_std", "scale", "matched"] {
        assert!(v.get(k).is_some(), "missing {k} in {json}");
    }
    assert_eq!(v["matched"].as_u64(), Some(12));
    assert!(v["ate_rmse"].as_f64().expect("number") < 1e-9);
    assert!((v["scale"].as_f64().expect("number") - 0.5).abs() < 1e-9);
    let img = colslam_image::Image::read(&plot).expect("plot is a PNG");
    assert!(img.width() > 400 && img.height() > 200);
}

#[test]
fn run_and_export_a_model() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = dir.path().join("seq");
    let out = dir.path().join("out");
    let (seq_s, out_s) = (seq.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    ok(&["-q", "demo", "--generate-only", "-o", seq_s, "--frames", "40", "--width", "320", "--height", "240"]);
    ok(&["-q", "run", seq_s, "-o", out_s]);
    for f in
        ["cameras.bin", "images.bin", "points3D.bin", "trajectory.tum", "keyframes.tum", "points.ply", "report.json"]
    {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report")).expect("json");
    assert_eq!(report["frames"].as_u64(), Some(40));
    assert!(report["timings_s"]["features"].as_f64().is_some());
    // Deterministic through the binary too, where features come from the
    // reader thread and the mapper runs on a pool of another size.
    let again = dir.path().join("again");
    ok(&["-q", "run", seq_s, "-o", again.to_str().expect("utf-8"), "--threads", "1"]);
    for f in ["cameras.bin", "images.bin", "points3D.bin", "trajectory.tum", "keyframes.tum", "points.ply"] {
        let (a, b) = (std::fs::read(out.join(f)).expect("first"), std::fs::read(again.join(f)).expect("second"));
        assert!(a == b, "{f} differs between two runs of the same input");
    }
    let info = ok(&["info", out_s]);
    assert!(info.contains("points3D"), "{info}");
    let txt = dir.path().join("txt");
    ok(&["export", out_s, "-o", txt.to_str().expect("utf-8"), "-f", "txt"]);
    assert!(txt.join("images.txt").exists());
    // Converted in place, nothing of the text model is left for readers to
    // pick up (regression: the old files stayed beside the new ones).
    ok(&["export", txt.to_str().expect("utf-8"), "-o", txt.to_str().expect("utf-8"), "-f", "bin"]);
    let mut left: Vec<String> =
        std::fs::read_dir(&txt).expect("ls").flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    left.sort();
    assert_eq!(left, ["cameras.bin", "frames.bin", "images.bin", "points3D.bin", "rigs.bin"]);
    // A folder that is not a model is not replaced.
    let mine = dir.path().join("mine");
    std::fs::create_dir(&mine).expect("mkdir");
    std::fs::write(mine.join("notes.md"), "keep").expect("write");
    let refused = colslam(&["export", out_s, "-o", mine.to_str().expect("utf-8"), "-f", "txt"]);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("notes.md") && err.contains("refusing"), "{err}");
    assert!(mine.join("notes.md").exists());
    let tum = dir.path().join("model.tum");
    ok(&["export", txt.to_str().expect("utf-8"), "-o", tum.to_str().expect("utf-8"), "-f", "tum"]);
    let n = std::fs::read_to_string(&tum).expect("tum").lines().filter(|l| !l.starts_with('#')).count();
    assert_eq!(n as u64, report["keyframes"].as_u64().expect("keyframes"));
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("nope");
    let out = colslam(&["run", missing.to_str().expect("utf-8"), "-o", dir.path().join("o").to_str().expect("utf-8")]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let bad_gt = dir.path().join("gt.txt");
    std::fs::write(&bad_gt, "1.0 2.0 three\n").expect("write");
    let out = colslam(&["eval", "--gt", bad_gt.to_str().expect("utf-8"), "--est", bad_gt.to_str().expect("utf-8")]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("gt.txt:1") && err.contains("8 fields"), "{err}");
    let out = colslam(&["info", Path::new("/dev/null/x").to_str().expect("utf-8")]);
    assert!(!out.status.success());
}

//! `colslam bench scale` end to end on a few hundred frames: a synthetic
//! looping path and tum_fr1_rpy_sub played forward and back, each at two
//! lengths. Checks the rows, the growth against the shorter length, and the
//! forward-back folder (links, timestamps, ground truth).

use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// Source frame shown at position `k` of the forward-back playback of 200
/// frames: 0..199, then 198 down.
fn source_of(k: usize) -> usize {
    if k < 200 { k } else { 398 - k }
}

fn file_name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

#[test]
fn scale_rows_growth_and_forward_back_sequence() {
    let Some(tum) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let tmp = tempfile::tempdir().expect("temp dir");
    let out = tmp.path().join("scale");
    let status = Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["-q", "bench", "scale", "--sequences", "loop,forward-back", "--lengths", "60,240"])
        .arg("--data")
        .arg(tum.parent().unwrap())
        .arg("--out")
        .arg(&out)
        .status()
        .expect("run colslam bench scale");
    assert!(status.success());

    let report: Value = serde_json::from_slice(&std::fs::read(out.join("scale.json")).expect("scale.json")).unwrap();
    let rows = report["rows"].as_array().expect("rows");
    let names: Vec<(&str, u64)> =
        rows.iter().map(|r| (r["sequence"].as_str().unwrap(), r["length"].as_u64().unwrap())).collect();
    assert_eq!(
        names,
        [
            ("synthetic-loop", 60),
            ("synthetic-loop", 240),
            ("tum_fr1_rpy_sub-forward-back", 60),
            ("tum_fr1_rpy_sub-forward-back", 240)
        ]
    );
    for r in rows {
        assert!(r["reason"].is_null(), "{r}");
        assert_eq!(r["frames"], r["length"], "{r}");
        assert!(r["peak_rss_mib"].as_f64().unwrap() > 1.0, "{r}");
        assert!(r["cpu_s_per_frame"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["observations"].as_u64().unwrap() > r["points"].as_u64().unwrap(), "{r}");
        assert!(r["ate_rmse_m"].as_f64().unwrap() < 0.1, "{r}");
        let g = &r["growth"];
        assert_eq!(g["base_length"], 60, "{r}");
        let want = r["length"].as_f64().unwrap() / 60.0;
        assert_eq!(g["frames"].as_f64().unwrap(), want, "{r}");
    }
    let md = std::fs::read_to_string(out.join("scale.md")).expect("scale.md");
    assert!(md.contains("| synthetic-loop | 240 |") && md.contains("| tum_fr1_rpy_sub-forward-back | 60 |"), "{md}");

    // The forward-back folder: frame k links to source frame k, then back.
    let fb = out.join("data/tum_fr1_rpy_sub-forward-back");
    let mut sources: Vec<String> = std::fs::read_to_string(tum.join("rgb.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().nth(1).unwrap().to_string())
        .collect();
    sources.iter_mut().for_each(|s| *s = file_name(Path::new(s)));
    let list = std::fs::read_to_string(fb.join("rgb.txt")).unwrap();
    let entries: Vec<(f64, &str)> = list
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let mut it = l.split_whitespace();
            (it.next().unwrap().parse().unwrap(), it.next().unwrap())
        })
        .collect();
    assert_eq!(entries.len(), 240);
    assert!(entries.windows(2).all(|w| w[1].0 > w[0].0), "timestamps must increase");
    for (k, (_, name)) in entries.iter().enumerate() {
        let target = std::fs::read_link(fb.join(name)).expect("a link");
        assert_eq!(file_name(&target), sources[source_of(k)], "frame {k}");
    }
    let gt = std::fs::read_to_string(fb.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.lines().filter(|l| !l.starts_with('#')).count(), 240);
    assert!(fb.join("camera.yaml").is_file());
}

#[test]
fn bad_scale_arguments_are_errors() {
    let dir = std::env::temp_dir().join("colslam-bench-scale-bad");
    for args in [&["--sequences", "spiral"][..], &["--lengths", "1"], &["--synthetic-size", "big"]] {
        let out = Command::new(env!("CARGO_BIN_EXE_colslam"))
            .args(["bench", "scale"])
            .args(args)
            .arg("--out")
            .arg(&dir)
            .output()
            .expect("run colslam");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && !err.contains("panicked"), "{args:?}: {err}");
    }
}

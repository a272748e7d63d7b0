//! The TUM-layout output: determinism, idempotency, readability, errors.

mod common;

use std::path::Path;

use colslam_synth::{Distortion, SynthError, SynthOptions, SyntheticSequence, generate};

fn tiny(seed: u64) -> SynthOptions {
    SynthOptions { seed, texel_size: 0.02, ..common::small_opts(4, 96, 72) }
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in ["", "rgb"] {
        let d = dir.join(sub);
        let mut names: Vec<_> =
            std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_file()).collect();
        names.sort();
        for p in names {
            out.push((p.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&p).unwrap()));
        }
    }
    out
}

/// Data lines (not comments) of a text file.
fn data_lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(str::to_string)
        .collect()
}

#[test]
fn same_seed_gives_identical_files_and_other_seed_differs() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let c = tempfile::tempdir().unwrap();
    let calls = std::cell::Cell::new(0);
    let progress = |done: usize, total: usize| {
        assert_eq!(total, 4);
        assert!(done >= 1 && done <= total);
        calls.set(calls.get() + 1);
    };
    let ra = generate(&tiny(1), a.path(), Some(&progress)).unwrap();
    assert_eq!(calls.get(), 4);
    assert_eq!(ra.frames_written, 4);
    assert!(!ra.up_to_date);
    generate(&tiny(1), b.path(), None).unwrap();
    let fa = files(a.path());
    assert_eq!(fa.len(), 4 + 4, "{:?}", fa.iter().map(|f| &f.0).collect::<Vec<_>>());
    assert_eq!(fa, files(b.path()));
    generate(&tiny(2), c.path(), None).unwrap();
    for i in 0..4 {
        let name = format!("rgb/{i:06}.png");
        let x = fa.iter().find(|f| f.0 == name).unwrap();
        let y = std::fs::read(c.path().join(&name)).unwrap();
        assert_ne!(x.1, y, "{name} equal for different seeds");
    }
}

#[test]
fn complete_folder_is_left_alone_and_partial_is_rewritten() {
    let dir = tempfile::tempdir().unwrap();
    let opts = tiny(3);
    generate(&opts, dir.path(), None).unwrap();
    let before = files(dir.path());
    let mtime = |p: &str| std::fs::metadata(dir.path().join(p)).unwrap().modified().unwrap();
    let m0 = mtime("rgb/000001.png");
    let r = generate(&opts, dir.path(), None).unwrap();
    assert!(r.up_to_date);
    assert_eq!(r.frames_written, 0);
    assert!(r.path_length > 1.0);
    assert_eq!(mtime("rgb/000001.png"), m0);
    // A missing frame makes the folder partial: everything is rewritten.
    std::fs::remove_file(dir.path().join("rgb/000002.png")).unwrap();
    let r = generate(&opts, dir.path(), None).unwrap();
    assert!(!r.up_to_date);
    assert_eq!(r.frames_written, 4);
    assert_eq!(files(dir.path()), before);
    // So does a missing marker (an interrupted run).
    std::fs::remove_file(dir.path().join("scene.json")).unwrap();
    assert_eq!(generate(&opts, dir.path(), None).unwrap().frames_written, 4);
    // Other options rewrite the folder; stale frames beyond the end go.
    let shorter = SynthOptions { frames: 3, ..opts.clone() };
    let r = generate(&shorter, dir.path(), None).unwrap();
    assert_eq!(r.frames_written, 3);
    assert!(!dir.path().join("rgb/000003.png").exists());
    assert_eq!(data_lines(&dir.path().join("rgb.txt")).len(), 3);
}

#[test]
fn folder_reads_as_tum() {
    let dir = tempfile::tempdir().unwrap();
    let opts = tiny(4);
    let report = generate(&opts, dir.path(), None).unwrap();
    let seq = SyntheticSequence::new(&opts).unwrap();
    let rgb = data_lines(&dir.path().join("rgb.txt"));
    let gt = data_lines(&dir.path().join("groundtruth.txt"));
    assert_eq!(rgb.len(), opts.frames);
    assert_eq!(gt.len(), opts.frames);
    for (i, (r, g)) in rgb.iter().zip(&gt).enumerate() {
        let rf: Vec<&str> = r.split_whitespace().collect();
        assert_eq!(rf.len(), 2);
        assert_eq!(rf[1], format!("rgb/{i:06}.png"));
        assert!((rf[0].parse::<f64>().unwrap() - i as f64 / opts.fps).abs() < 1e-6);
        let img = colslam_image::Image::read(&dir.path().join(rf[1])).unwrap();
        assert_eq!((img.width(), img.height(), img.channels()), (96, 72, 3));
        let v: Vec<f64> = g.split_whitespace().map(|t| t.parse().unwrap()).collect();
        assert_eq!(v.len(), 8);
        assert_eq!(v[0].to_string(), rf[0].parse::<f64>().unwrap().to_string(), "timestamps differ");
        // Full precision: the pose reads back bit for bit.
        let p = seq.world_from_cam()[i];
        assert_eq!([v[1], v[2], v[3]], [p.translation.x, p.translation.y, p.translation.z]);
        assert_eq!([v[4], v[5], v[6], v[7]], p.quat_xyzw());
    }
    // camera.yaml: the keys of the datasets' files, readable by the camera crate.
    let yaml = std::fs::read_to_string(dir.path().join("camera.yaml")).unwrap();
    for key in ["model:", "width:", "height:", "fx:", "fy:", "cx:", "cy:", "fps:"] {
        assert!(yaml.lines().any(|l| l.starts_with(key)), "camera.yaml lacks {key}:\n{yaml}");
    }
    assert!(yaml.contains("model: PINHOLE"));
    let cam = colslam_camera::file::read_camera_file_report(&dir.path().join("camera.yaml")).unwrap();
    assert_eq!(&cam.camera, seq.camera());
    assert_eq!(cam.fps, Some(opts.fps));
    // scene.json: extent, seed, options.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("scene.json")).unwrap()).unwrap();
    assert_eq!(json["seed"], 4);
    assert_eq!(json["options"]["frames"], 4);
    assert!((json["scene_diagonal"].as_f64().unwrap() - report.scene_diagonal).abs() < 1e-12);
    assert!(json["boxes"].as_array().unwrap().len() >= 20);
}

#[test]
fn distorted_camera_is_written_as_opencv() {
    let dir = tempfile::tempdir().unwrap();
    let d: Distortion = [-0.2, 0.05, 0.001, -0.002];
    let opts = SynthOptions { distortion: Some(d), frames: 2, ..tiny(5) };
    generate(&opts, dir.path(), None).unwrap();
    let yaml = std::fs::read_to_string(dir.path().join("camera.yaml")).unwrap();
    assert!(yaml.contains("model: OPENCV"), "{yaml}");
    for key in ["k1:", "k2:", "p1:", "p2:"] {
        assert!(yaml.lines().any(|l| l.starts_with(key)), "{key}");
    }
    let cam = colslam_camera::file::read_camera_file(&dir.path().join("camera.yaml")).unwrap();
    assert_eq!(cam.model.name(), "OPENCV");
    assert_eq!(&cam.params[4..], &d);
}

#[test]
fn invalid_options_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    for (opts, name) in [
        (SynthOptions { frames: 0, ..tiny(1) }, "frames"),
        (SynthOptions { width: 0, ..tiny(1) }, "width"),
        (SynthOptions { height: 0, ..tiny(1) }, "height"),
        (SynthOptions { noise_sigma: -2.0, ..tiny(1) }, "noise_sigma"),
    ] {
        let e = generate(&opts, dir.path(), None).unwrap_err();
        assert!(matches!(e, SynthError::InvalidOption { .. }), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains(name), "{msg}");
    }
    // Nothing was written for invalid options.
    assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
    // A folder that cannot be created names the path.
    let file = dir.path().join("plain-file");
    std::fs::write(&file, b"x").unwrap();
    let e = generate(&tiny(1), &file.join("sub"), None).unwrap_err().to_string();
    assert!(e.contains("plain-file"), "{e}");
    // Strong distortion that folds inside the image is refused, not rendered wrongly.
    let folded = SynthOptions { distortion: Some([-0.5, 0.0, 0.0, 0.0]), ..tiny(1) };
    let e = SyntheticSequence::new(&folded);
    assert!(e.is_err(), "folded distortion accepted");
}

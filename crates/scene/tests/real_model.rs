//! A real model: strecha_fountain_P11 reconstructed by pycolmap with
//! scripts/make-real-model.py (cached under target/test-fixtures), then
//! load, round trip, interop and damaged-file checks.

mod common;

use colslam_scene::{ModelFormat, NormalizeOptions, read_model, read_model_format, write_model};
use common::{FILES, assert_json_eq, assert_same_files, model_file, pycolmap_dump, to_json};
use std::path::PathBuf;
use std::sync::OnceLock;

/// The fixture folder (with `sparse/` and `sparse-text/`), built once.
fn fixture() -> Option<(PathBuf, PathBuf)> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let py = colslam_testutil::peer_python(&["pycolmap"])?;
        let images = colslam_testutil::dataset("strecha_fountain_P11")?.join("rgb");
        let root = colslam_testutil::workspace_root().join("target/test-fixtures");
        let dir = root.join("fountain-model");
        if !dir.join("sparse/points3D.bin").is_file() || !dir.join("sparse-text/points3D.txt").is_file() {
            // Build beside and rename, so an interrupted run leaves no half fixture.
            let tmp = root.join(format!("fountain-model.tmp-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&tmp);
            std::fs::create_dir_all(&tmp).unwrap();
            let script = colslam_testutil::workspace_root().join("scripts/make-real-model.py");
            let t = std::time::Instant::now();
            let out = colslam_testutil::run_python(
                &py,
                &[script.to_str().unwrap(), images.to_str().unwrap(), tmp.to_str().unwrap()],
            );
            eprintln!("make-real-model.py: {} ({:.1} s)", out.trim(), t.elapsed().as_secs_f64());
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::rename(&tmp, &dir).unwrap();
        }
        Some(dir)
    });
    dir.as_ref().map(|d| (d.join("sparse"), d.join("sparse-text")))
}

#[test]
fn real_model_loads_and_round_trips_byte_for_byte() {
    let Some((bin, txt)) = fixture() else { return };
    let a = read_model_format(&bin, ModelFormat::Binary).unwrap();
    let b = read_model_format(&txt, ModelFormat::Text).unwrap();
    a.check_consistency().unwrap();
    assert_eq!(a, b, "pycolmap's binary and text models differ after loading");
    assert!(a.num_registered_images() >= 9, "{} images", a.num_registered_images());
    assert!(a.num_points3d() > 1000, "{} points", a.num_points3d());
    assert!(a.mean_track_length() > 2.0);
    for (src, format) in [(&bin, ModelFormat::Binary), (&txt, ModelFormat::Text)] {
        let out = tempfile::tempdir().unwrap();
        write_model(&a, out.path(), format).unwrap();
        assert_same_files(src, out.path(), format);
    }
    // Recomputed errors agree with pycolmap's (SIMPLE_RADIAL camera).
    let mut r = a.clone();
    r.update_point_errors().unwrap();
    for (id, p) in a.points3d() {
        let e = r.point3d(id).unwrap().error;
        assert!((e - p.error).abs() < 1e-9, "point {id}: {e} vs {}", p.error);
    }
}

#[test]
fn real_model_interop_with_pycolmap() {
    let Some((bin, _)) = fixture() else { return };
    let Some(py) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let rec = read_model(&bin).unwrap();
    assert_json_eq(&to_json(&rec, false), &pycolmap_dump(&py, &bin, "bin"), "pycolmap's model");
    // Change it the way a mapper would, write, and let pycolmap read it.
    let mut edited = rec.clone();
    edited.normalize(&NormalizeOptions::default()).unwrap();
    let victim = edited.registered_image_ids()[3];
    let report = edited.deregister_image(victim).unwrap();
    assert!(report.observations_removed > 0);
    edited.update_point_errors().unwrap();
    edited.check_consistency().unwrap();
    for (format, mode) in [(ModelFormat::Binary, "bin"), (ModelFormat::Text, "txt")] {
        let out = tempfile::tempdir().unwrap();
        write_model(&edited, out.path(), format).unwrap();
        assert_json_eq(&to_json(&edited, true), &pycolmap_dump(&py, out.path(), mode), mode);
    }
}

#[test]
fn damaged_real_files_fail_cleanly() {
    let Some((bin, _)) = fixture() else { return };
    let dir = tempfile::tempdir().unwrap();
    for base in FILES {
        let src = model_file(&bin, base, ModelFormat::Binary);
        std::fs::copy(&src, model_file(dir.path(), base, ModelFormat::Binary)).unwrap();
    }
    for base in FILES {
        let path = model_file(dir.path(), base, ModelFormat::Binary);
        let bytes = std::fs::read(&path).unwrap();
        let n = bytes.len();
        let name = format!("{base}.bin");
        for cut in [0, 1, 7, 8, 9, 20, 64, n / 3, n / 2, n - 9, n - 1] {
            if cut >= n {
                continue;
            }
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let result = std::panic::catch_unwind(|| read_model(dir.path()));
            let err = match result {
                Ok(Err(e)) => e,
                Ok(Ok(_)) => panic!("{name} cut at {cut} loaded"),
                Err(_) => panic!("{name} cut at {cut} panicked"),
            };
            assert!(err.to_string().contains(&name), "{err}");
        }
        // A count claiming far more records than the file holds.
        let mut big = bytes.clone();
        big[..8].copy_from_slice(&(u64::MAX - 3).to_le_bytes());
        std::fs::write(&path, &big).unwrap();
        let err = read_model(dir.path()).unwrap_err();
        assert!(err.to_string().contains(&name), "{err}");
        std::fs::write(&path, &bytes).unwrap();
    }
    read_model(dir.path()).unwrap();
}

//! Interoperability with pycolmap 4.2 on synthetic models, both directions
//! and both formats, plus PLY import.

mod common;

use colslam_scene::{ModelFormat, PlyFormat, read_model_format, write_model, write_ply_with};
use common::{assert_json_eq, assert_same_files, pycolmap_dump, script, synthetic_model, to_json};

#[test]
fn pycolmap_models_load_identically_and_rewrite_byte_for_byte() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let bin = tempfile::tempdir().unwrap();
    let txt = tempfile::tempdir().unwrap();
    colslam_testutil::run_python(
        &py,
        &[script("make_model.py").to_str().unwrap(), bin.path().to_str().unwrap(), txt.path().to_str().unwrap()],
    );
    for (dir, format, mode) in [(&bin, ModelFormat::Binary, "bin"), (&txt, ModelFormat::Text, "txt")] {
        let ours = read_model_format(dir.path(), format).unwrap();
        ours.check_consistency().unwrap();
        // pycolmap registered images 5, 2, 11, 3, 8 in that order.
        let order: Vec<u32> = ours.registered_image_ids().iter().map(|i| i.0).collect();
        assert_eq!(order, [5, 2, 11, 3, 8]);
        assert_json_eq(&to_json(&ours, false), &pycolmap_dump(&py, dir.path(), mode), mode);
        let again = tempfile::tempdir().unwrap();
        write_model(&ours, again.path(), format).unwrap();
        assert_same_files(dir.path(), again.path(), format);

        // Our reprojection errors (with our camera models) match pycolmap's.
        let mut recomputed = ours.clone();
        recomputed.update_point_errors().unwrap();
        for (id, p) in ours.points3d() {
            let e = recomputed.point3d(id).unwrap().error;
            assert!((e - p.error).abs() <= 1e-9 * p.error.max(1.0), "point {id}: ours {e}, pycolmap {}", p.error);
        }
        assert!((recomputed.mean_reprojection_error() - ours.mean_reprojection_error()).abs() < 1e-9);
    }
    // pycolmap's text and binary files hold the same model.
    let a = read_model_format(bin.path(), ModelFormat::Binary).unwrap();
    let b = read_model_format(txt.path(), ModelFormat::Text).unwrap();
    assert_eq!(a, b);
}

#[test]
fn pycolmap_reads_our_models() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let rec = synthetic_model(21);
    for (format, mode) in [(ModelFormat::Binary, "bin"), (ModelFormat::Text, "txt")] {
        let dir = tempfile::tempdir().unwrap();
        write_model(&rec, dir.path(), format).unwrap();
        // pycolmap sees the registered images (the format has no others).
        assert_json_eq(&to_json(&rec, true), &pycolmap_dump(&py, dir.path(), mode), mode);
        // Also without rigs/frames (pycolmap then makes trivial ones itself).
        for f in ["rigs", "frames"] {
            std::fs::remove_file(dir.path().join(format!("{f}.{}", format.extension()))).unwrap();
        }
        assert_json_eq(&to_json(&rec, true), &pycolmap_dump(&py, dir.path(), mode), "legacy layout");
    }
}

#[test]
fn pycolmap_rewrites_our_files_byte_for_byte() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let rec = synthetic_model(23);
    for (format, mode) in [(ModelFormat::Binary, "bin"), (ModelFormat::Text, "txt")] {
        let ours = tempfile::tempdir().unwrap();
        let theirs = tempfile::tempdir().unwrap();
        write_model(&rec, ours.path(), format).unwrap();
        colslam_testutil::run_python(
            &py,
            &[
                script("rewrite_model.py").to_str().unwrap(),
                ours.path().to_str().unwrap(),
                theirs.path().to_str().unwrap(),
                mode,
            ],
        );
        // pycolmap re-registers images in frame (id) order on reading, so its
        // images file follows id order while ours keeps registration order;
        // every other file must be identical.
        for base in ["rigs", "cameras", "frames", "points3D"] {
            let name = format!("{base}.{}", format.extension());
            let a = std::fs::read(ours.path().join(&name)).unwrap();
            let b = std::fs::read(theirs.path().join(&name)).unwrap();
            assert!(a == b, "{name} differs after a pycolmap rewrite");
        }
        // With the registration order sorted, images match as well.
        let sorted = read_model_format(theirs.path(), format).unwrap();
        let again = tempfile::tempdir().unwrap();
        write_model(&sorted, again.path(), format).unwrap();
        assert_same_files(theirs.path(), again.path(), format);
    }
}

#[test]
fn pycolmap_imports_our_ply() {
    let Some(py) = colslam_testutil::peer_python(&["pycolmap"]) else { return };
    let rec = synthetic_model(22);
    for format in [PlyFormat::BinaryLittleEndian, PlyFormat::Ascii] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("points.ply");
        write_ply_with(&rec, &path, format).unwrap();
        let out = colslam_testutil::run_python(&py, &[script("read_ply.py").to_str().unwrap(), path.to_str().unwrap()]);
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["n"].as_u64().unwrap() as usize, rec.num_points3d());
        for ((_, p), (xyz, rgb)) in
            rec.points3d().zip(v["xyz"].as_array().unwrap().iter().zip(v["rgb"].as_array().unwrap()))
        {
            for k in 0..3 {
                let theirs = xyz[k].as_f64().unwrap();
                assert_eq!(theirs as f32, p.xyz[k] as f32, "{format:?}");
                assert_eq!(rgb[k].as_u64().unwrap(), u64::from(p.color[k]));
            }
        }
    }
}

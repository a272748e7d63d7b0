//! COLMAP model I/O on a synthetic model: round trips, format conversion and
//! every error case (no panics, messages name the file).

mod common;

use colslam_scene::{ImageId, ModelFormat, Reconstruction, SceneError, read_model, read_model_format, write_model};
use common::{FILES, assert_same_files, model_file, synthetic_model, to_json};
use std::path::Path;

/// The registered part of `orig` must equal `read` exactly.
fn assert_equal_registered(orig: &Reconstruction, read: &Reconstruction) {
    assert_eq!(read.registered_image_ids(), orig.registered_image_ids(), "registration order");
    assert_eq!(read.num_images(), orig.num_registered_images());
    assert!(read.images().all(|i| i.registered));
    assert_eq!(to_json(read, true), to_json(orig, true));
    for c in orig.cameras() {
        assert_eq!(read.camera(c.id), Some(c));
    }
    for &id in orig.registered_image_ids() {
        assert_eq!(read.image(id), orig.image(id), "image {id}");
    }
    for (id, p) in orig.points3d() {
        assert_eq!(read.point3d(id), Some(p), "point {id}");
    }
    read.check_consistency().unwrap();
}

#[test]
fn binary_and_text_round_trips_are_exact() {
    let rec = synthetic_model(11);
    assert_eq!(rec.num_registered_images(), 6);
    assert_eq!(rec.num_images(), 8);
    for format in [ModelFormat::Binary, ModelFormat::Text] {
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        write_model(&rec, a.path(), format).unwrap();
        let read = read_model_format(a.path(), format).unwrap();
        assert_equal_registered(&rec, &read);
        write_model(&read, b.path(), format).unwrap();
        assert_same_files(a.path(), b.path(), format);
        // read_model auto-detects the format.
        assert_equal_registered(&rec, &read_model(a.path()).unwrap());
    }
}

#[test]
fn text_binary_conversion_preserves_everything() {
    let rec = synthetic_model(12);
    let bin = tempfile::tempdir().unwrap();
    let txt = tempfile::tempdir().unwrap();
    let bin2 = tempfile::tempdir().unwrap();
    write_model(&rec, bin.path(), ModelFormat::Binary).unwrap();
    let from_bin = read_model(bin.path()).unwrap();
    write_model(&from_bin, txt.path(), ModelFormat::Text).unwrap();
    let from_txt = read_model(txt.path()).unwrap();
    // %.17g text keeps every bit.
    assert_eq!(from_txt, from_bin);
    assert_equal_registered(&rec, &from_txt);
    write_model(&from_txt, bin2.path(), ModelFormat::Binary).unwrap();
    assert_same_files(bin.path(), bin2.path(), ModelFormat::Binary);
}

#[test]
fn text_headers_carry_counts_and_means() {
    let rec = synthetic_model(13);
    let dir = tempfile::tempdir().unwrap();
    write_model(&rec, dir.path(), ModelFormat::Text).unwrap();
    let images = std::fs::read_to_string(dir.path().join("images.txt")).unwrap();
    let want = format!(
        "# Number of images: 6, mean observations per image: {}\n",
        colslam_scene::io::format_g17(rec.mean_observations_per_registered_image())
    );
    assert!(images.contains(&want), "{want}");
    let points = std::fs::read_to_string(dir.path().join("points3D.txt")).unwrap();
    assert!(points.contains(&format!("# Number of points: {}, mean track length: ", rec.num_points3d())));
    let rigs = std::fs::read_to_string(dir.path().join("rigs.txt")).unwrap();
    assert!(rigs.contains("# Number of rigs: 7\n1 1 CAMERA 1\n3 1 CAMERA 3\n"), "{rigs}");
    let frames = std::fs::read_to_string(dir.path().join("frames.txt")).unwrap();
    assert!(frames.contains("# Number of frames: 6\n2 3 "), "{frames}");
}

#[test]
fn read_model_reports_missing_files() {
    let dir = tempfile::tempdir().unwrap();
    let err = read_model(dir.path()).unwrap_err();
    assert!(matches!(err, SceneError::MissingFiles { .. }), "{err}");
    assert!(err.to_string().contains("cameras.bin"), "{err}");
    write_model(&synthetic_model(1), dir.path(), ModelFormat::Binary).unwrap();
    std::fs::remove_file(dir.path().join("images.bin")).unwrap();
    let err = read_model_format(dir.path(), ModelFormat::Binary).unwrap_err();
    assert!(err.to_string().contains("images.bin"), "{err}");
    // Without rigs/frames (COLMAP 3 layout) the model still loads.
    let dir = tempfile::tempdir().unwrap();
    write_model(&synthetic_model(1), dir.path(), ModelFormat::Text).unwrap();
    std::fs::remove_file(dir.path().join("rigs.txt")).unwrap();
    std::fs::remove_file(dir.path().join("frames.txt")).unwrap();
    read_model(dir.path()).unwrap();
}

fn write_fixture(format: ModelFormat) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    write_model(&synthetic_model(5), dir.path(), format).unwrap();
    dir
}

/// Reading must fail (not panic) with a message naming `file`.
fn expect_error(dir: &Path, format: ModelFormat, file: &str) -> SceneError {
    let result = std::panic::catch_unwind(|| read_model_format(dir, format));
    let err = match result {
        Ok(Ok(_)) => panic!("reading with a damaged {file} succeeded"),
        Ok(Err(e)) => e,
        Err(_) => panic!("reading with a damaged {file} panicked"),
    };
    assert!(err.to_string().contains(file), "error does not name {file}: {err}");
    err
}

#[test]
fn truncated_binary_files_fail_cleanly_at_many_offsets() {
    let dir = write_fixture(ModelFormat::Binary);
    for base in FILES {
        let path = model_file(dir.path(), base, ModelFormat::Binary);
        let bytes = std::fs::read(&path).unwrap();
        let name = format!("{base}.bin");
        // Every offset of the first records, then a stride through the rest
        // (each cut is a file write; all offsets would be slow on this disk).
        let cuts = (0..bytes.len().min(400)).chain((400..bytes.len()).step_by(37));
        for cut in cuts {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            expect_error(dir.path(), ModelFormat::Binary, &name);
        }
        // Trailing garbage is an error too.
        let mut longer = bytes.clone();
        longer.push(0);
        std::fs::write(&path, &longer).unwrap();
        let err = expect_error(dir.path(), ModelFormat::Binary, &name);
        assert!(err.to_string().contains("trailing"), "{err}");
        std::fs::write(&path, &bytes).unwrap();
    }
    read_model(dir.path()).unwrap();
}

fn patch(path: &Path, offset: usize, new: &[u8]) -> Vec<u8> {
    let orig = std::fs::read(path).unwrap();
    let mut b = orig.clone();
    b[offset..offset + new.len()].copy_from_slice(new);
    std::fs::write(path, &b).unwrap();
    orig
}

#[test]
fn corrupt_binary_counts_and_values_fail_cleanly() {
    let dir = write_fixture(ModelFormat::Binary);
    let d = dir.path();
    let rec = synthetic_model(5);
    let first = rec.image(rec.registered_image_ids()[0]).unwrap();
    // Offset of the first image's keypoint count: count, id, pose, camera, name + NUL.
    let np_offset = 8 + 4 + 56 + 4 + first.name.len() + 1;
    // Offset of the first point's track length: count, id, xyz, rgb, error.
    let track_offset = 8 + 8 + 24 + 3 + 8;
    let cases: Vec<(&str, usize, Vec<u8>, &str)> = vec![
        ("cameras.bin", 0, u64::MAX.to_le_bytes().to_vec(), "truncated"),
        ("cameras.bin", 0, (1u64 << 40).to_le_bytes().to_vec(), "truncated"),
        ("images.bin", 0, u64::MAX.to_le_bytes().to_vec(), "truncated"),
        ("images.bin", np_offset, (1u64 << 50).to_le_bytes().to_vec(), "number of points2d"),
        ("points3D.bin", 0, (u64::MAX / 2).to_le_bytes().to_vec(), "truncated"),
        ("points3D.bin", track_offset, (1u64 << 61).to_le_bytes().to_vec(), "track length"),
        ("rigs.bin", 0, u64::MAX.to_le_bytes().to_vec(), "truncated"),
        ("frames.bin", 0, u64::MAX.to_le_bytes().to_vec(), "truncated"),
        // Camera model id 99 does not exist.
        ("cameras.bin", 8 + 4, 99i32.to_le_bytes().to_vec(), "unknown camera model"),
        // The first image's camera id: 1000 is not a camera.
        ("images.bin", 8 + 4 + 56, 1000u32.to_le_bytes().to_vec(), "missing camera 1000"),
        // The first image's qw = 7: not a unit quaternion.
        ("images.bin", 8 + 4, 7f64.to_le_bytes().to_vec(), "norm"),
        // The first point's first track element: image 4000 does not exist.
        ("points3D.bin", track_offset + 8, 4000u32.to_le_bytes().to_vec(), "missing image 4000"),
        // ... and a keypoint index far out of range.
        ("points3D.bin", track_offset + 12, 900_000u32.to_le_bytes().to_vec(), "900000"),
        // Frame 2's pose no longer matches image 2's.
        ("frames.bin", 8 + 4 + 4 + 32, 9f64.to_le_bytes().to_vec(), "disagrees"),
        // The frame names camera 77, which its rig lacks.
        ("frames.bin", 8 + 4 + 4 + 56 + 4 + 4, 77u32.to_le_bytes().to_vec(), "lacks"),
        // The rig names a missing camera.
        ("rigs.bin", 8 + 4 + 4 + 4, 55u32.to_le_bytes().to_vec(), "missing camera 55"),
    ];
    for (file, offset, bytes, needle) in cases {
        let path = d.join(file);
        let orig = patch(&path, offset, &bytes);
        let err = expect_error(d, ModelFormat::Binary, file);
        assert!(err.to_string().to_lowercase().contains(needle), "{file}@{offset}: {err}");
        std::fs::write(&path, orig).unwrap();
    }
    read_model(d).unwrap();
}

fn edit_text(path: &Path, f: impl Fn(&str) -> String) -> String {
    let orig = std::fs::read_to_string(path).unwrap();
    std::fs::write(path, f(&orig)).unwrap();
    orig
}

/// Replaces the first data (non-comment) line with `f(line)`.
fn edit_first_data_line(text: &str, f: &dyn Fn(&str) -> String) -> String {
    let mut done = false;
    text.lines()
        .map(|l| {
            if !done && !l.starts_with('#') && !l.is_empty() {
                done = true;
                f(l)
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

#[test]
fn malformed_text_lines_name_file_and_line() {
    let dir = write_fixture(ModelFormat::Text);
    let d = dir.path();
    type Edit = Box<dyn Fn(&str) -> String>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        ("cameras.txt", Box::new(|l: &str| l.replacen("SIMPLE_RADIAL", "FOO_MODEL", 1)), "unknown camera model"),
        ("cameras.txt", Box::new(|l: &str| l.rsplit_once(' ').unwrap().0.to_string()), "takes 4 parameters, got 3"),
        ("cameras.txt", Box::new(|_: &str| "1 PINHOLE abc 480 1 2 3 4".into()), "cameras.txt:4"),
        ("images.txt", Box::new(|l: &str| l.replacen(' ', " x", 1)), "images.txt:5"),
        ("images.txt", Box::new(|l: &str| l.split(' ').take(5).collect::<Vec<_>>().join(" ")), "missing"),
        ("points3D.txt", Box::new(|l: &str| format!("{l} 5")), "points3D.txt:4"),
        ("points3D.txt", Box::new(|l: &str| l.replacen(' ', " nope ", 1)), "points3D.txt:4"),
        ("rigs.txt", Box::new(|_: &str| "1 1 LIDAR 1".into()), "unknown sensor type"),
        ("frames.txt", Box::new(|l: &str| format!("{l} extra")), "frames.txt:4"),
    ];
    for (file, f, needle) in cases {
        let path = d.join(file);
        let orig = edit_text(&path, |t| edit_first_data_line(t, &*f));
        let err = expect_error(d, ModelFormat::Text, file);
        assert!(err.to_string().contains(needle), "{file}: {err}");
        std::fs::write(&path, orig).unwrap();
    }
    // A keypoint line with a broken triple.
    let path = d.join("images.txt");
    let orig = edit_text(&path, |t| {
        let mut lines: Vec<String> = t.lines().map(String::from).collect();
        lines[5] = format!("{} 1.5", lines[5].trim_end());
        lines.join("\n") + "\n"
    });
    let err = expect_error(d, ModelFormat::Text, "images.txt");
    assert!(err.to_string().contains("images.txt:6") && err.to_string().contains("multiple of 3"), "{err}");
    // A missing keypoint line at the end of the file.
    std::fs::write(&path, orig.lines().take(5).collect::<Vec<_>>().join("\n")).unwrap();
    let err = expect_error(d, ModelFormat::Text, "images.txt");
    assert!(err.to_string().contains("POINTS2D"), "{err}");
    std::fs::write(&path, orig).unwrap();
    // A point whose track names a missing image.
    let path = d.join("points3D.txt");
    let orig = edit_text(&path, |t| edit_first_data_line(t, &|l: &str| format!("{l} 999 0")));
    let err = expect_error(d, ModelFormat::Text, "points3D.txt");
    assert!(err.to_string().contains("missing image 999"), "{err}");
    std::fs::write(&path, orig).unwrap();
    // Every line truncated at a random-ish place: no panics.
    for file in ["cameras.txt", "images.txt", "points3D.txt", "rigs.txt", "frames.txt"] {
        let path = d.join(file);
        let orig = std::fs::read_to_string(&path).unwrap();
        for cut in (0..orig.len()).step_by(31) {
            std::fs::write(&path, &orig[..cut]).unwrap();
            let _ = std::panic::catch_unwind(|| read_model_format(d, ModelFormat::Text))
                .unwrap_or_else(|_| panic!("{file} cut at {cut} panicked"));
        }
        std::fs::write(&path, orig).unwrap();
    }
    read_model(d).unwrap();
}

#[test]
fn unwritable_names_are_reported() {
    let mut rec = Reconstruction::new();
    let cam = rec.add_camera(
        colslam_camera::Camera::new(colslam_camera::CameraModelId::SimplePinhole, 10, 10, vec![1.0, 5.0, 5.0]).unwrap(),
    );
    let mut img = colslam_scene::Image::new(ImageId(1), "has space.png", cam, Vec::new());
    img.registered = true;
    rec.add_image(img).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let err = write_model(&rec, dir.path(), ModelFormat::Text).unwrap_err();
    assert!(err.to_string().contains("images.txt"), "{err}");
    // Binary keeps such names.
    write_model(&rec, dir.path(), ModelFormat::Binary).unwrap();
    assert_eq!(read_model(dir.path()).unwrap().image(ImageId(1)).unwrap().name, "has space.png");
}

#[test]
fn unusable_camera_values_are_refused_with_their_location() {
    // Text: the first camera line (line 4 after the header) with a NaN, then
    // a negative focal length.
    let dir = write_fixture(ModelFormat::Text);
    let d = dir.path();
    let path = d.join("cameras.txt");
    for (value, needle) in [("nan", "finite"), ("-500", "focal length must be positive")] {
        let orig = edit_text(&path, |t| {
            edit_first_data_line(t, &|_: &str| format!("1 SIMPLE_RADIAL 640 480 {value} 320 240 0"))
        });
        let err = expect_error(d, ModelFormat::Text, "cameras.txt");
        assert!(matches!(err, SceneError::InvalidCamera { camera: 1, .. }), "{err}");
        let chain = anyhow_like(&err);
        assert!(chain.contains("cameras.txt: line 4: camera 1") && chain.contains(needle), "{chain}");
        std::fs::write(&path, orig).unwrap();
    }
    read_model(d).unwrap();

    // Binary: the first camera's first parameter (count, id, model, width, height).
    let dir = write_fixture(ModelFormat::Binary);
    let d = dir.path();
    for value in [f64::NAN, f64::INFINITY, -1.0, 0.0] {
        let orig = patch(&d.join("cameras.bin"), 8 + 4 + 4 + 8 + 8, &value.to_le_bytes());
        let err = expect_error(d, ModelFormat::Binary, "cameras.bin");
        assert!(matches!(err, SceneError::InvalidCamera { .. }), "{value}: {err}");
        assert!(err.to_string().contains("record at byte 8"), "{err}");
        std::fs::write(d.join("cameras.bin"), orig).unwrap();
    }
    read_model(d).unwrap();
}

/// The error and its causes, joined by ": ".
fn anyhow_like(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        s = format!("{s}: {c}");
        cause = c.source();
    }
    s
}

//! Fuzzing of the COLMAP model readers (binary and text): mutated model
//! folders give a model or an error, never a panic, a hang or a huge
//! allocation. See `colslam_testutil::fuzz`; the long run is in
//! docs/benchmarks.md ("Fuzzing").

mod common;

use colslam_camera::{Camera, CameraModelId};
use colslam_geometry::{Quat, Rigid3, Vec2, Vec3};
use colslam_scene::{
    CameraId, Image, ImageId, ModelFormat, Reconstruction, TrackElement, read_model_format, write_model,
};
use colslam_testutil::fuzz::{Corpus, Scratch, fuzz};

colslam_testutil::fuzz_allocator!();

/// Inputs per reader in the default test run.
const CI_ITERS: u64 = 4_000;

/// Model files in the order of the corpus parts; the last two are optional
/// (an empty part stands for an absent file, as in models before COLMAP 4).
const FILES: [&str; 5] = ["cameras", "images", "points3D", "rigs", "frames"];
const OPTIONAL_FROM: usize = 3;

/// One camera, two registered images with two keypoints each, one point
/// seen by both: small, so that mutations hit the structure, not the data.
fn tiny_model() -> Reconstruction {
    let mut rec = Reconstruction::new();
    let cam = Camera::new(CameraModelId::SimpleRadial, 64, 48, vec![50.0, 32.0, 24.0, 0.01]).unwrap();
    rec.add_camera_with_id(CameraId(1), cam).unwrap();
    for (k, id) in [ImageId(1), ImageId(2)].into_iter().enumerate() {
        let mut img =
            Image::new(id, format!("im{k}.png"), CameraId(1), vec![Vec2::new(10.0, 12.0), Vec2::new(30.5, 20.25)]);
        img.cam_from_world = Rigid3::new(Quat::identity(), Vec3::new(k as f64 * 0.1, 0.0, 0.0));
        img.registered = true;
        rec.add_image(img).unwrap();
    }
    let track = vec![TrackElement::new(ImageId(1), 0), TrackElement::new(ImageId(2), 1)];
    rec.add_point3d(Vec3::new(0.1, 0.2, 3.0), [10, 20, 30], track).unwrap();
    rec
}

/// The files of `models` written by `write_model` in `format`, each model
/// also without its rigs and frames.
fn corpus(format: ModelFormat, models: &[Reconstruction]) -> Corpus {
    let ext = format.extension();
    let names = FILES.map(|f| format!("{f}.{ext}"));
    let mut corpus = Corpus::new(names.clone());
    let dir = tempfile::tempdir().unwrap();
    for rec in models {
        write_model(rec, dir.path(), format).unwrap();
        let parts: Vec<Vec<u8>> = names.iter().map(|n| std::fs::read(dir.path().join(n)).unwrap()).collect();
        let mut without_rigs = parts.clone();
        without_rigs.truncate(OPTIONAL_FROM);
        without_rigs.resize(FILES.len(), Vec::new());
        corpus = corpus.sample_parts(parts).sample_parts(without_rigs);
    }
    corpus
}

/// Fuzzes one format's reader through a model folder.
fn fuzz_format(name: &str, format: ModelFormat) {
    let models = [tiny_model(), Reconstruction::new(), common::synthetic_model(3)];
    let corpus = corpus(format, &models)
        .words(CameraModelId::ALL.map(CameraModelId::name))
        .words(["CAMERA", "IMU", "INVALID", "-1", "\n\n", "# c\n"]);
    let names = corpus.names().to_vec();
    let mut scratch = Scratch::new();
    let report = fuzz(name, &corpus, CI_ITERS, |parts| {
        for (k, (n, bytes)) in names.iter().zip(parts).enumerate() {
            let absent = k >= OPTIONAL_FROM && bytes.is_empty();
            scratch.put(n, (!absent).then_some(bytes.as_slice()));
        }
        read_model_format(scratch.path(), format)
    });
    assert!(report.accepted >= corpus.samples().len() as u64, "{report}");
}

#[test]
fn fuzz_model_binary() {
    fuzz_format("model-bin", ModelFormat::Binary);
}

#[test]
fn fuzz_model_text() {
    fuzz_format("model-txt", ModelFormat::Text);
}

//! Rotation and scale invariance of ORB + nearest-neighbour matching on
//! synthetic similarity warps of a real TUM frame and of a procedural image:
//! at least 80 % of the matches must land within 3 px of the true position.

mod common;

use colslam_features::{Features, Matcher, NnMatcher, NnMatcherOptions, OrbExtractor, OrbOptions};
use colslam_image::Image;
use common::{Warp, procedural_image, tum_frame, warp_image};

/// A match is correct when the warped query keypoint lies this close to the
/// train keypoint (level-0 pixels of the warped image).
const TOLERANCE_PX: f64 = 3.0;
/// Required share of correct matches.
const MIN_CORRECT: f64 = 0.8;
/// Required number of matches, so that an empty result cannot pass.
const MIN_MATCHES: usize = 100;

struct Outcome {
    matches: usize,
    correct: usize,
}

fn evaluate(img: &Image, angle: f64, scale: f64) -> Outcome {
    let (warped, warp) = warp_image(img, angle, scale);
    let ex = OrbExtractor::new(OrbOptions::default()).unwrap();
    let a = colslam_features::FeatureExtractor::extract(&ex, img).unwrap();
    let b = colslam_features::FeatureExtractor::extract(&ex, &warped).unwrap();
    let m = NnMatcher::new(NnMatcherOptions::default()).unwrap();
    let matches = m.match_features(&a, &b).unwrap();
    let correct = count_correct(&a, &b, &matches, &warp);
    Outcome { matches: matches.len(), correct }
}

fn count_correct(a: &Features, b: &Features, matches: &[colslam_features::Match], warp: &Warp) -> usize {
    matches
        .iter()
        .filter(|m| {
            let ka = a.keypoints[m.query as usize];
            let kb = b.keypoints[m.train as usize];
            let (x, y) = warp.apply(ka.x as f64, ka.y as f64);
            (x - kb.x as f64).hypot(y - kb.y as f64) <= TOLERANCE_PX
        })
        .count()
}

fn check(name: &str, img: &Image, cases: &[(f64, f64)]) {
    let mut failures = Vec::new();
    for &(angle, scale) in cases {
        let o = evaluate(img, angle, scale);
        let share = o.correct as f64 / o.matches.max(1) as f64;
        eprintln!(
            "{name}: rotation {angle} deg, scale {scale}: {} / {} correct ({:.1} %)",
            o.correct,
            o.matches,
            100.0 * share
        );
        if o.matches < MIN_MATCHES || share < MIN_CORRECT {
            failures.push(format!("rotation {angle}, scale {scale}: {} / {} correct", o.correct, o.matches));
        }
    }
    assert!(failures.is_empty(), "{name}: {failures:?}");
}

const CASES: [(f64, f64); 6] = [(30.0, 1.0), (90.0, 1.0), (0.0, 1.2), (0.0, 1.5), (0.0, 0.7), (45.0, 1.2)];

#[test]
fn invariance_on_procedural_image() {
    check("procedural", &procedural_image(7), &CASES);
}

#[test]
fn invariance_on_tum_frame() {
    let Some(img) = tum_frame(0) else { return };
    check("tum_fr1_rpy_sub[0]", &img, &CASES);
}

/// Our ORB + matcher against OpenCV's ORB with the same matching rules on
/// the same warps of the TUM frame: at least 90 % as many correct matches and
/// a correct share at most 5 points lower. Skips without the dataset or the
/// peer Python (opencv-python).
#[test]
fn not_worse_than_opencv_orb() {
    let Some(dir) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let Some(py) = colslam_testutil::peer_python(&["cv2", "numpy"]) else { return };
    let mut files: Vec<_> =
        std::fs::read_dir(dir.join("rgb")).unwrap().filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    let path = files[0].to_str().unwrap().to_string();
    let img = Image::read(&files[0]).unwrap().to_gray();
    let script = format!("{}/tests/peer/opencv_orb_invariance.py", env!("CARGO_MANIFEST_DIR"));
    for (angle, scale) in [(30.0, 1.0), (0.0, 1.5), (45.0, 1.2)] {
        let out = colslam_testutil::run_python(&py, &[&script, &path, &angle.to_string(), &scale.to_string()]);
        let v: Vec<usize> = out.split_whitespace().map(|t| t.parse().unwrap()).collect();
        let (cv_correct, cv_matches) = (v[0], v[1]);
        let ours = evaluate(&img, angle, scale);
        let cv_share = cv_correct as f64 / cv_matches.max(1) as f64;
        let share = ours.correct as f64 / ours.matches.max(1) as f64;
        eprintln!(
            "rotation {angle}, scale {scale}: ours {} / {} correct, OpenCV {cv_correct} / {cv_matches}",
            ours.correct, ours.matches
        );
        assert!(cv_correct > 50, "OpenCV baseline too weak to compare: {cv_correct}");
        assert!(ours.correct as f64 >= 0.9 * cv_correct as f64, "{} vs OpenCV {cv_correct}", ours.correct);
        assert!(share >= cv_share - 0.05, "{share:.3} vs OpenCV {cv_share:.3}");
    }
}

#[test]
fn identity_warp_matches_almost_everything() {
    // Sanity check of the test harness: the same image matched to itself.
    let img = procedural_image(3);
    let o = evaluate(&img, 0.0, 1.0);
    assert!(o.matches > 500, "{}", o.matches);
    assert!(o.correct as f64 >= 0.99 * o.matches as f64, "{} / {}", o.correct, o.matches);
}

#[test]
fn harness_detects_a_wrong_warp() {
    // The check must be able to fail: claiming a 30 degree rotation for a
    // 90 degree warp makes almost every match "incorrect".
    let img = procedural_image(7);
    let (warped, _) = warp_image(&img, 90.0, 1.0);
    let (_, wrong) = warp_image(&img, 30.0, 1.0);
    let ex = OrbExtractor::new(OrbOptions::default()).unwrap();
    let a = colslam_features::FeatureExtractor::extract(&ex, &img).unwrap();
    let b = colslam_features::FeatureExtractor::extract(&ex, &warped).unwrap();
    let m = NnMatcher::new(NnMatcherOptions::default()).unwrap().match_features(&a, &b).unwrap();
    assert!(count_correct(&a, &b, &m, &wrong) < m.len() / 10);
}

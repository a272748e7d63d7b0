//! Bad and degenerate inputs: never a panic, either zero features or a clear
//! error. Also determinism and independence from the thread count.

mod common;

use colslam_features::{
    Descriptors, FeatureError, FeatureExtractor, Matcher, NnMatcher, NnMatcherOptions, OrbExtractor, OrbOptions,
    Selection, extractor_by_name, flow_score,
};
use colslam_image::Image;
use common::procedural_image;

fn orb() -> OrbExtractor {
    OrbExtractor::new(OrbOptions::default()).unwrap()
}

#[test]
fn empty_image_is_a_clear_error() {
    for (w, h) in [(0, 0), (0, 10), (10, 0)] {
        let e = orb().extract(&Image::new(w, h, 1)).unwrap_err();
        assert!(matches!(e, FeatureError::EmptyImage { .. }), "{e}");
        assert!(e.to_string().contains("empty image"), "{e}");
    }
}

#[test]
fn tiny_images_give_zero_features() {
    // Smaller than the 2 * 19 + 1 px needed for one keypoint, and just above.
    for (w, h) in [(1, 1), (5, 3), (31, 31), (38, 200), (200, 38), (39, 39), (45, 41)] {
        let mut img = Image::new(w, h, 1);
        for (i, v) in img.data_mut().iter_mut().enumerate() {
            *v = ((i * 37) % 251) as u8;
        }
        let f = orb().extract(&img).unwrap();
        f.validate().unwrap();
        if w < 39 || h < 39 {
            assert!(f.is_empty(), "{w}x{h}: {}", f.len());
        }
        for k in &f.keypoints {
            assert!(k.x >= 0.0 && k.y >= 0.0 && k.x < w as f32 && k.y < h as f32);
        }
    }
}

#[test]
fn uniform_images_give_zero_features() {
    for v in [0u8, 128, 255] {
        let img = Image::from_vec(640, 480, 1, vec![v; 640 * 480]).unwrap();
        let f = orb().extract(&img).unwrap();
        assert!(f.is_empty());
        assert_eq!(f.descriptors, Descriptors::Binary(Vec::new()));
    }
}

#[test]
fn rgb_input_equals_gray_input() {
    let gray = procedural_image(1);
    let rgb = gray.to_rgb();
    assert_eq!(orb().extract(&rgb).unwrap(), orb().extract(&gray).unwrap());
}

#[test]
fn keypoints_are_well_formed_and_spread() {
    let img = procedural_image(2);
    let (f, report) = orb().extract_with_report(&img).unwrap();
    f.validate().unwrap();
    assert_eq!(f.len(), 1000, "{report:?}");
    assert_eq!(report.levels.len(), 8);
    assert_eq!(report.levels.iter().map(|l| l.kept).sum::<usize>(), 1000);
    for k in &f.keypoints {
        assert!(k.x >= 0.0 && k.x <= 639.0 && k.y >= 0.0 && k.y <= 479.0, "{k:?}");
        assert!((0.0..360.0).contains(&k.angle), "{k:?}");
        assert!(k.octave < 8);
        let expected = 31.0 * 1.2f32.powi(k.octave as i32);
        assert!((k.size - expected).abs() < 0.02 * expected, "{k:?}");
    }
    // Levels hold their geometric quota.
    assert_eq!(report.levels[0].kept, 217);
    // Spread (the quadtree selection): every cell of a 4x4 grid over the
    // image holds keypoints.
    let quadtree = OrbExtractor::new(OrbOptions { selection: Selection::Quadtree, ..OrbOptions::default() }).unwrap();
    let (f, report) = quadtree.extract_with_report(&img).unwrap();
    f.validate().unwrap();
    assert_eq!(f.len(), 1000, "{report:?}");
    assert_eq!(report.levels[0].kept, 217);
    let mut cells = [0usize; 16];
    for k in &f.keypoints {
        cells[((k.y / 120.0) as usize).min(3) * 4 + ((k.x / 160.0) as usize).min(3)] += 1;
    }
    assert!(cells.iter().all(|&c| c > 10), "{cells:?}");
}

#[test]
fn deterministic_and_thread_count_independent() {
    let img = procedural_image(4);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let f = orb().extract(&img).unwrap();
            let g = orb().extract(&procedural_image(5)).unwrap();
            let m = NnMatcher::new(NnMatcherOptions::default()).unwrap().match_features(&f, &g).unwrap();
            (f, m)
        })
    };
    let (f1, m1) = run(1);
    let (f3, m3) = run(3);
    assert_eq!(f1, f3);
    assert_eq!(m1, m3);
    assert_eq!(run(1).0, f1);
}

#[test]
fn registry_and_flow_on_real_features() {
    let ex = extractor_by_name("orb", &Default::default()).unwrap();
    let a = ex.extract(&procedural_image(8)).unwrap();
    // A pure translation by (12, -5) px: the flow score is |12|/fx + |5|/fy.
    let img = procedural_image(8);
    let mut shifted = Image::new(640, 480, 1);
    for y in 0..480 {
        for x in 0..640 {
            let (sx, sy) = (x as i64 - 12, y as i64 + 5);
            let v =
                if (0..640).contains(&sx) && (0..480).contains(&sy) { img.get(sx as usize, sy as usize, 0) } else { 0 };
            shifted.set(x, y, 0, v);
        }
    }
    let b = ex.extract(&shifted).unwrap();
    let m = NnMatcher::new(NnMatcherOptions::default()).unwrap().match_features(&a, &b).unwrap();
    assert!(m.len() > 300, "{}", m.len());
    let f = flow_score(&a.keypoints, &b.keypoints, &m, 500.0, 400.0).unwrap();
    // Within half a pixel: keypoints of coarse levels move by non-integer
    // level pixels.
    assert!((f.median_x - 12.0 / 500.0).abs() < 0.5 / 500.0, "{f:?}");
    assert!((f.median_y - 5.0 / 400.0).abs() < 0.5 / 400.0, "{f:?}");
    assert!((f.score - (12.0 / 500.0 + 5.0 / 400.0)).abs() < 1e-3);
}

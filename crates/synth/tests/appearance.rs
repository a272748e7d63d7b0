//! Appearance: feature-rich textures in every frame, noise, motion blur, seeds.

mod common;

use colslam_synth::{SynthOptions, SyntheticSequence};
use common::{min_block_std, small_opts, strong_gradient_share};

/// Gradient threshold (gray levels per pixel) counted as a strong gradient.
const STRONG_GRADIENT: f32 = 8.0;
/// Tile edge (pixels at 320x240, i.e. 64 at 640x480) for the uniform-region check.
const BLOCK: usize = 32;

#[test]
fn every_frame_is_feature_rich() {
    // The whole default path at half resolution, 15 frames, no noise (noise
    // would hide uniform regions).
    let seq = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, ..small_opts(15, 320, 240) }).unwrap();
    for i in 0..seq.num_frames() {
        let img = seq.render(i).unwrap();
        let share = strong_gradient_share(&img, STRONG_GRADIENT);
        let flat = min_block_std(&img, BLOCK);
        eprintln!("frame {i}: strong-gradient share {share:.3}, least textured {BLOCK}px block std {flat:.2}");
        assert!(share > 0.25, "frame {i}: only {share:.3} of pixels have a strong gradient");
        assert!(flat > 3.0, "frame {i}: a {BLOCK}x{BLOCK} block is nearly uniform (std {flat:.2})");
    }
}

#[test]
fn noise_has_the_requested_sigma() {
    let base = SynthOptions { noise_sigma: 0.0, ..small_opts(2, 160, 120) };
    let clean = SyntheticSequence::new(&base).unwrap().render(1).unwrap();
    let noisy = SyntheticSequence::new(&SynthOptions { noise_sigma: 4.0, ..base }).unwrap().render(1).unwrap();
    let d: Vec<f64> = clean
        .data()
        .iter()
        .zip(noisy.data())
        .filter(|(a, _)| **a > 20 && **a < 235) // away from clipping
        .map(|(a, b)| *b as f64 - *a as f64)
        .collect();
    let (mean, var) = colslam_geometry::stats::mean_and_variance(&d).unwrap();
    let std = var.sqrt();
    assert!(mean.abs() < 0.1, "noise mean {mean}");
    assert!((std - 4.0).abs() < 0.25, "noise std {std}");
}

#[test]
fn motion_blur_smooths_the_image() {
    let sharp = SynthOptions { noise_sigma: 0.0, ..small_opts(15, 160, 120) };
    let blurred = SynthOptions { motion_blur: 1.0, blur_samples: 6, ..sharp.clone() };
    let a = SyntheticSequence::new(&sharp).unwrap().render(7).unwrap();
    let b = SyntheticSequence::new(&blurred).unwrap().render(7).unwrap();
    assert_ne!(a, b);
    let (ga, gb) = (strong_gradient_share(&a, STRONG_GRADIENT), strong_gradient_share(&b, STRONG_GRADIENT));
    assert!(gb < 0.9 * ga, "blurred share {gb} vs sharp {ga}");
}

#[test]
fn seeds_change_scene_and_path() {
    let a = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, ..small_opts(2, 160, 120) }).unwrap();
    let b = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, seed: 7, ..small_opts(2, 160, 120) }).unwrap();
    let (ia, ib) = (a.render(0).unwrap(), b.render(0).unwrap());
    let mad = ia.data().iter().zip(ib.data()).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum::<f64>()
        / ia.data().len() as f64;
    assert!(mad > 20.0, "mean abs difference {mad}");
    assert_ne!(a.world_from_cam()[0], b.world_from_cam()[0]);
    // Same seed: identical render.
    let c = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, ..small_opts(2, 160, 120) }).unwrap();
    assert_eq!(c.render(0).unwrap(), ia);
}

/// The full default sequence (150 frames, 640x480, default textures and
/// noise): every frame feature-rich, and the render time per frame.
/// Heavy in the dev profile: run with
/// `cargo test --release -p colslam-synth --test appearance -- --ignored --nocapture`.
#[test]
#[ignore = "renders the whole default sequence (about 10 s in release, minutes in the dev profile)"]
fn full_default_sequence_is_feature_rich() {
    let t = std::time::Instant::now();
    let seq = SyntheticSequence::new(&SynthOptions::default()).unwrap();
    eprintln!("setup {:.2} s", t.elapsed().as_secs_f64());
    let t = std::time::Instant::now();
    let mut worst_share = f64::INFINITY;
    let mut worst_block = f64::INFINITY;
    for i in 0..seq.num_frames() {
        let img = seq.render(i).unwrap();
        worst_share = worst_share.min(strong_gradient_share(&img, STRONG_GRADIENT));
        worst_block = worst_block.min(min_block_std(&img, 2 * BLOCK));
    }
    let ms = t.elapsed().as_secs_f64() * 1e3 / seq.num_frames() as f64;
    eprintln!(
        "{ms:.1} ms per frame (render + checks); worst strong-gradient share {worst_share:.3}, least textured 64px block std {worst_block:.2}"
    );
    // Full resolution magnifies the textures (5 mm texels are ~2 px at
    // 1.2 m), so the per-pixel gradients are weaker than at half size.
    assert!(worst_share > 0.2, "strong-gradient share {worst_share}");
    assert!(worst_block > 3.0, "nearly uniform 64x64 block (std {worst_block})");
}

#[test]
fn rendering_does_not_depend_on_the_thread_count() {
    let opts = SynthOptions { motion_blur: 0.5, blur_samples: 2, ..small_opts(3, 96, 72) };
    let build_and_render = || {
        let seq = SyntheticSequence::new(&opts).unwrap();
        (seq.render(1).unwrap(), seq.render_depth(2).unwrap())
    };
    let many = build_and_render();
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(build_and_render);
    assert!(one == many, "single-threaded render differs");
}

#[test]
fn a_rolling_shutter_sees_each_row_from_its_own_time() {
    // Each row of a rolling-shutter frame is the same row of the sharp view
    // from the pose at that row's time; a global shutter is not.
    let gs = SynthOptions { noise_sigma: 0.0, jitter_rotation_deg: 5.0, ..small_opts(15, 160, 120) };
    let rs = SynthOptions { readout: 0.03, ..gs.clone() };
    let (gs, rs) = (SyntheticSequence::new(&gs).unwrap(), SyntheticSequence::new(&rs).unwrap());
    let i = 7;
    let (global, rolling) = (gs.render(i).unwrap(), rs.render(i).unwrap());
    let row = |img: &colslam_image::Image, j: usize| img.data()[j * 160 * 3..(j + 1) * 160 * 3].to_vec();
    for j in [0, 37, 119] {
        let pose = rs.trajectory().world_from_cam(rs.row_time(rs.timestamp(i), j));
        assert_eq!(row(&rolling, j), row(&rs.render_pose(&pose), j), "row {j}");
    }
    assert_ne!(row(&rolling, 0), row(&global, 0), "the first row is read 15 ms early");
    // Middle row time is the frame time.
    assert!((rs.row_time(1.0, 59) + rs.row_time(1.0, 60) - 2.0).abs() < 1e-12);
    assert!((rs.row_time(1.0, 119) - rs.row_time(1.0, 0) - 0.03 * 119.0 / 120.0).abs() < 1e-12);
    // Longer than a frame is refused.
    let long = SynthOptions { readout: 0.5, ..small_opts(15, 160, 120) };
    assert!(SyntheticSequence::new(&long).is_err());
}

//! Shared helpers of the integration tests.
#![allow(dead_code)]

use colslam_image::Image;
use colslam_synth::SynthOptions;

/// A cheap sequence sampling the default trajectory: `frames` frames over the
/// same 5 s (the frame rate is lowered to match), at `width x height` with the
/// default field of view and coarser textures.
pub fn small_opts(frames: usize, width: usize, height: usize) -> SynthOptions {
    let d = SynthOptions::default();
    let duration = (d.frames - 1) as f64 / d.fps;
    SynthOptions {
        frames,
        fps: if frames > 1 { (frames - 1) as f64 / duration } else { d.fps },
        width,
        height,
        focal: d.focal * width as f64 / d.width as f64,
        texel_size: 0.01,
        ..d
    }
}

/// Gray values as f32.
pub fn gray(img: &Image) -> Vec<f32> {
    img.to_gray().data().iter().map(|&v| v as f32).collect()
}

/// Share of interior pixels whose central-difference gradient magnitude
/// exceeds `threshold` gray levels per pixel.
pub fn strong_gradient_share(img: &Image, threshold: f32) -> f64 {
    let g = gray(img);
    let (w, h) = (img.width(), img.height());
    let mut strong = 0usize;
    let mut total = 0usize;
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let gx = 0.5 * (g[y * w + x + 1] - g[y * w + x - 1]);
            let gy = 0.5 * (g[(y + 1) * w + x] - g[(y - 1) * w + x]);
            total += 1;
            if (gx * gx + gy * gy).sqrt() > threshold {
                strong += 1;
            }
        }
    }
    strong as f64 / total as f64
}

/// Smallest standard deviation of gray values over the `block x block` tiles.
pub fn min_block_std(img: &Image, block: usize) -> f64 {
    let g = gray(img);
    let (w, h) = (img.width(), img.height());
    let mut min = f64::INFINITY;
    for by in 0..h / block {
        for bx in 0..w / block {
            let mut s = 0.0;
            let mut s2 = 0.0;
            for y in by * block..(by + 1) * block {
                for x in bx * block..(bx + 1) * block {
                    let v = g[y * w + x] as f64;
                    s += v;
                    s2 += v * v;
                }
            }
            let n = (block * block) as f64;
            let var = (s2 / n - (s / n).powi(2)).max(0.0);
            min = min.min(var.sqrt());
        }
    }
    min
}

//! Shared helpers for the integration tests: a procedural test image, a
//! similarity warp with bilinear sampling, and the TUM frame loader.

#![allow(dead_code)]

use colslam_geometry::SplitMix64;
use colslam_image::Image;

/// A 2D similarity about the image centres: `dst = s R(theta) (src - c_src) + c_dst`.
#[derive(Debug, Clone, Copy)]
pub struct Warp {
    pub angle_deg: f64,
    pub scale: f64,
    pub src_centre: (f64, f64),
    pub dst_centre: (f64, f64),
}

impl Warp {
    /// Maps a source pixel (OpenCV convention, centre of pixel (0,0) at 0) to
    /// the destination image.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.angle_deg.to_radians().sin_cos();
        let (dx, dy) = (x - self.src_centre.0, y - self.src_centre.1);
        (self.scale * (c * dx - s * dy) + self.dst_centre.0, self.scale * (s * dx + c * dy) + self.dst_centre.1)
    }

    /// Inverse map: destination pixel to source pixel.
    pub fn invert(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.angle_deg.to_radians().sin_cos();
        let (dx, dy) = ((x - self.dst_centre.0) / self.scale, (y - self.dst_centre.1) / self.scale);
        (c * dx + s * dy + self.src_centre.0, -s * dx + c * dy + self.src_centre.1)
    }
}

/// Warps a gray image by rotation `angle_deg` and `scale` about its centre
/// into an image that holds the whole rotated, scaled frame. Bilinear
/// sampling; pixels falling outside the source replicate the nearest border
/// pixel (less artificial structure than a constant fill).
pub fn warp_image(src: &Image, angle_deg: f64, scale: f64) -> (Image, Warp) {
    let (w, h) = (src.width() as f64, src.height() as f64);
    let (s, c) = angle_deg.to_radians().sin_cos();
    // Bounding box of the warped frame.
    let ow = (scale * (w * c.abs() + h * s.abs())).round() as usize;
    let oh = (scale * (w * s.abs() + h * c.abs())).round() as usize;
    let warp = Warp {
        angle_deg,
        scale,
        src_centre: ((w - 1.0) / 2.0, (h - 1.0) / 2.0),
        dst_centre: ((ow as f64 - 1.0) / 2.0, (oh as f64 - 1.0) / 2.0),
    };
    let mut out = Image::new(ow, oh, 1);
    for y in 0..oh {
        for x in 0..ow {
            let (sx, sy) = warp.invert(x as f64, y as f64);
            let sx = sx.clamp(0.0, w - 1.0);
            let sy = sy.clamp(0.0, h - 1.0);
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(src.width() - 1), (y0 + 1).min(src.height() - 1));
            let (fx, fy) = (sx - x0 as f64, sy - y0 as f64);
            let p = |xx: usize, yy: usize| src.get(xx, yy, 0) as f64;
            let v =
                (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x1, y0)) + fy * ((1.0 - fx) * p(x0, y1) + fx * p(x1, y1));
            out.set(x, y, 0, v.round().clamp(0.0, 255.0) as u8);
        }
    }
    (out, warp)
}

/// A deterministic 640x480 textured test image: overlapping random
/// rectangles and discs of random gray levels over a smooth background,
/// lightly anti-aliased. Rich in corners, not repetitive.
pub fn procedural_image(seed: u64) -> Image {
    let (w, h) = (640usize, 480usize);
    let mut rng = SplitMix64::new(seed);
    let mut v: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            100.0 + 40.0 * (x / 97.0).sin() * (y / 71.0).cos()
        })
        .collect();
    for _ in 0..350 {
        let level = rng.uniform(0.0, 255.0);
        let cx = rng.uniform(0.0, w as f64);
        let cy = rng.uniform(0.0, h as f64);
        let a = rng.uniform(4.0, 40.0);
        let b = rng.uniform(4.0, 40.0);
        let disc = rng.next_f64() < 0.3;
        let (xa, xb) = ((cx - a).max(0.0) as usize, ((cx + a) as usize).min(w - 1));
        let (ya, yb) = ((cy - b).max(0.0) as usize, ((cy + b) as usize).min(h - 1));
        for y in ya..=yb {
            for x in xa..=xb {
                let inside = if disc {
                    let (dx, dy) = ((x as f64 - cx) / a, (y as f64 - cy) / b);
                    dx * dx + dy * dy <= 1.0
                } else {
                    true
                };
                if inside {
                    v[y * w + x] = level;
                }
            }
        }
    }
    // 3x3 box filter for anti-aliasing, plus mild noise.
    let mut out = Image::new(w, h, 1);
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let xx = (x as i64 + dx).clamp(0, w as i64 - 1) as usize;
                    let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                    s += v[yy * w + xx];
                }
            }
            let noise = rng.uniform(-2.0, 2.0);
            out.set(x, y, 0, (s / 9.0 + noise).round().clamp(0.0, 255.0) as u8);
        }
    }
    out
}

/// The first frame of the TUM fr1 rpy subset in gray, if the dataset is present.
pub fn tum_frame(index: usize) -> Option<Image> {
    let dir = colslam_testutil::dataset("tum_fr1_rpy_sub")?.join("rgb");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    files.sort();
    let f = files.get(index).unwrap_or_else(|| panic!("{}: fewer than {} frames", dir.display(), index + 1));
    Some(Image::read(f).unwrap_or_else(|e| panic!("{e}")).to_gray())
}

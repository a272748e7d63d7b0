//! Procedural, feature-rich surface textures, baked once into texel maps and
//! sampled bilinearly (continuous in the surface coordinates, so features are
//! sub-pixel stable from frame to frame).
//!
//! Each texture is a sum of layers drawn with its own palette: multi-octave
//! value noise (Perlin 1985 style lattice noise with quintic fade), soft
//! blobs, rotated rectangles, striped patches and glyph-like strokes. Shapes
//! are rasterised with anti-aliased coverage from their signed distance, so
//! their edges are smooth at the texel scale. Nothing repeats: every shape
//! and every noise lattice value comes from the seeded generator, which keeps
//! descriptors distinctive.

use colslam_geometry::SplitMix64;

/// Base frequency of the noise layer, in cycles per metre.
const NOISE_BASE_FREQ: f64 = 2.5;
/// Octaves of the noise layer.
const NOISE_OCTAVES: u32 = 5;
/// Frequency ratio between octaves (not 2, to avoid aligned lattices).
const NOISE_LACUNARITY: f64 = 2.13;
/// Amplitude ratio between octaves.
const NOISE_GAIN: f64 = 0.55;
/// Shapes per square metre (all kinds together).
const SHAPE_DENSITY: f64 = 70.0;
/// Colours in a surface palette.
const PALETTE_SIZE: usize = 5;

/// A baked RGB texture covering `[0, width_m] x [0, height_m]` of a surface.
#[derive(Clone)]
pub struct Texture {
    /// Texels along u.
    tw: usize,
    /// Texels along v.
    th: usize,
    /// 1 / texel edge in metres.
    inv_texel: f64,
    /// RGB (+ 1 padding byte for aligned loads), row-major (v rows).
    /// 8 bits per channel keep the ~6 M texels of a room cache-friendly.
    data: Vec<[u8; 4]>,
}

impl std::fmt::Debug for Texture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Texture({}x{} texels)", self.tw, self.th)
    }
}

impl Texture {
    /// Bakes a texture for a `width_m x height_m` surface with texel edge
    /// `texel` metres, deterministically from `seed`.
    pub fn bake(width_m: f64, height_m: f64, texel: f64, seed: u64) -> Texture {
        // At least 2 texels per axis so that bilinear lookup always has a
        // neighbour (invariant used by `sample`).
        let tw = ((width_m / texel).ceil() as usize).max(2);
        let th = ((height_m / texel).ceil() as usize).max(2);
        let mut rng = SplitMix64::new(seed);
        let palette = make_palette(&mut rng);
        let noise_seed = rng.next_u64();
        let hue_seed = rng.next_u64();
        let mut data = vec![[0f32; 3]; tw * th];
        // Layer 1: noise through the palette (the palette index is itself
        // warped by a second, slower noise so colours vary across the surface).
        for (j, row) in data.chunks_exact_mut(tw).enumerate() {
            let v = (j as f64 + 0.5) * texel;
            for (i, px) in row.iter_mut().enumerate() {
                let u = (i as f64 + 0.5) * texel;
                let n = fbm(u, v, noise_seed);
                let h = value_noise(u * 0.8, v * 0.8, hue_seed);
                *px = palette_lookup(&palette, (0.65 * n + 0.35 * h).clamp(0.0, 1.0));
            }
        }
        let mut canvas = Canvas { tw, th, texel, data };
        // Layer 2: shapes.
        let count = (width_m * height_m * SHAPE_DENSITY).round() as usize;
        for _ in 0..count {
            let colour = shape_colour(&mut rng, &palette);
            let cu = rng.uniform(0.0, width_m);
            let cv = rng.uniform(0.0, height_m);
            let angle = rng.uniform(0.0, std::f64::consts::PI);
            let (sa, ca) = angle.sin_cos();
            match rng.below(10) {
                // Soft-edged ellipse.
                0..=2 => {
                    let ra = rng.uniform(0.015, 0.10);
                    let rb = ra * rng.uniform(0.4, 1.0);
                    let r = ra.max(rb);
                    canvas.draw(cu, cv, r, colour, |du, dv| {
                        let x = ca * du + sa * dv;
                        let y = -sa * du + ca * dv;
                        let q = ((x / ra).powi(2) + (y / rb).powi(2)).sqrt();
                        (q - 1.0) * rb
                    });
                }
                // Rotated rectangle (sharp corners: good FAST corners).
                3..=5 => {
                    let ha = rng.uniform(0.01, 0.12);
                    let hb = rng.uniform(0.01, 0.12);
                    canvas.draw(cu, cv, (ha * ha + hb * hb).sqrt(), colour, |du, dv| {
                        let x = (ca * du + sa * dv).abs() - ha;
                        let y = (-sa * du + ca * dv).abs() - hb;
                        let outside = (x.max(0.0).powi(2) + y.max(0.0).powi(2)).sqrt();
                        outside + x.max(y).min(0.0)
                    });
                }
                // Striped patch.
                6 => {
                    let ha = rng.uniform(0.04, 0.15);
                    let hb = rng.uniform(0.04, 0.15);
                    let period = rng.uniform(0.012, 0.04);
                    canvas.draw(cu, cv, (ha * ha + hb * hb).sqrt(), colour, |du, dv| {
                        let x = ca * du + sa * dv;
                        let y = -sa * du + ca * dv;
                        let bx = x.abs() - ha;
                        let by = y.abs() - hb;
                        let rect = bx.max(by);
                        let f = (x / period).rem_euclid(1.0);
                        let stripe = ((f - 0.5).abs() - 0.25) * period;
                        rect.max(stripe)
                    });
                }
                // Glyph: 2-4 strokes (capsules) inside a small cell.
                _ => {
                    let cell = rng.uniform(0.02, 0.07);
                    let width = cell * rng.uniform(0.08, 0.18);
                    let strokes = 2 + rng.below(3);
                    let mut segs = [[0.0f64; 4]; 4];
                    for s in segs.iter_mut().take(strokes) {
                        *s = [
                            rng.uniform(-0.5, 0.5) * cell,
                            rng.uniform(-0.5, 0.5) * cell,
                            rng.uniform(-0.5, 0.5) * cell,
                            rng.uniform(-0.5, 0.5) * cell,
                        ];
                    }
                    canvas.draw(cu, cv, cell, colour, |du, dv| {
                        let mut d = f64::INFINITY;
                        for s in segs.iter().take(strokes) {
                            d = d.min(segment_distance(du, dv, s));
                        }
                        d - width
                    });
                }
            }
        }
        let data = canvas
            .data
            .iter()
            .map(|p| {
                let q = |v: f32| v.round().clamp(0.0, 255.0) as u8;
                [q(p[0]), q(p[1]), q(p[2]), 0]
            })
            .collect();
        Texture { tw, th, inv_texel: 1.0 / texel, data }
    }

    /// Bilinear lookup at surface coordinates `(u, v)` in metres; clamps at
    /// the borders. Continuous in `(u, v)`.
    #[inline]
    pub fn sample(&self, u: f64, v: f64) -> [f32; 3] {
        // Texel centres sit at (i + 0.5) * texel.
        let fx = (u * self.inv_texel - 0.5).clamp(0.0, (self.tw - 1) as f64);
        let fy = (v * self.inv_texel - 0.5).clamp(0.0, (self.th - 1) as f64);
        // tw, th >= 2 (see `bake`), so x0 + 1 <= tw - 1 after the min.
        let x0 = (fx as usize).min(self.tw - 2);
        let y0 = (fy as usize).min(self.th - 2);
        let ax = (fx - x0 as f64) as f32;
        let ay = (fy - y0 as f64) as f32;
        let i00 = y0 * self.tw + x0;
        let (p00, p10, p01, p11) =
            (self.data[i00], self.data[i00 + 1], self.data[i00 + self.tw], self.data[i00 + self.tw + 1]);
        let mut out = [0f32; 3];
        for c in 0..3 {
            let (a, b, cc, d) = (p00[c] as f32, p10[c] as f32, p01[c] as f32, p11[c] as f32);
            let top = a + (b - a) * ax;
            let bot = cc + (d - cc) * ax;
            out[c] = top + (bot - top) * ay;
        }
        out
    }

    /// Number of texels.
    pub fn texels(&self) -> usize {
        self.data.len()
    }
}

/// A texel buffer that shapes are rasterised into.
struct Canvas {
    tw: usize,
    th: usize,
    texel: f64,
    data: Vec<[f32; 3]>,
}

impl Canvas {
    /// Blends `colour` over the texels within `radius` of `(cu, cv)` with the
    /// anti-aliased coverage of the signed distance `sd(du, dv)` (metres,
    /// negative inside).
    fn draw(&mut self, cu: f64, cv: f64, radius: f64, colour: [f32; 3], sd: impl Fn(f64, f64) -> f64) {
        let inv = 1.0 / self.texel;
        let r = radius + 2.0 * self.texel;
        let i0 = ((cu - r) * inv).floor().max(0.0) as usize;
        let i1 = (((cu + r) * inv).ceil().max(0.0) as usize).min(self.tw);
        let j0 = ((cv - r) * inv).floor().max(0.0) as usize;
        let j1 = (((cv + r) * inv).ceil().max(0.0) as usize).min(self.th);
        for j in j0..j1 {
            let dv = (j as f64 + 0.5) * self.texel - cv;
            for i in i0..i1 {
                let du = (i as f64 + 0.5) * self.texel - cu;
                // Coverage ramps over one texel around the edge.
                let a = (0.5 - sd(du, dv) * inv).clamp(0.0, 1.0) as f32;
                if a > 0.0 {
                    // i < tw and j < th by the bounds above.
                    let px = &mut self.data[j * self.tw + i];
                    for c in 0..3 {
                        px[c] += (colour[c] - px[c]) * a;
                    }
                }
            }
        }
    }
}

/// Distance from `(x, y)` to the segment `s = [x0, y0, x1, y1]`.
fn segment_distance(x: f64, y: f64, s: &[f64; 4]) -> f64 {
    let (ax, ay, bx, by) = (s[0], s[1], s[2], s[3]);
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 { (((x - ax) * dx + (y - ay) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
    let (px, py) = (ax + t * dx - x, ay + t * dy - y);
    (px * px + py * py).sqrt()
}

/// A 64-bit integer hash (the SplitMix64 finaliser) of a lattice point.
#[inline]
fn hash3(ix: i64, iy: i64, seed: u64) -> u64 {
    let mut z =
        seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[inline]
fn lattice(ix: i64, iy: i64, seed: u64) -> f64 {
    (hash3(ix, iy, seed) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Quintic fade (C2-continuous interpolation weight).
#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Value noise in [0, 1] at `(x, y)` (lattice spacing 1).
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let (tx, ty) = (fade(x - fx), fade(y - fy));
    let a = lattice(ix, iy, seed);
    let b = lattice(ix + 1, iy, seed);
    let c = lattice(ix, iy + 1, seed);
    let d = lattice(ix + 1, iy + 1, seed);
    let top = a + (b - a) * tx;
    let bot = c + (d - c) * tx;
    top + (bot - top) * ty
}

/// Fractal (multi-octave) value noise in [0, 1], with a contrast stretch so
/// that the full palette range is used.
fn fbm(u: f64, v: f64, seed: u64) -> f64 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut amp = 1.0;
    let mut freq = NOISE_BASE_FREQ;
    for o in 0..NOISE_OCTAVES {
        sum += amp * value_noise(u * freq, v * freq, seed.wrapping_add(o as u64 * 0x1234_5678_9ABC));
        norm += amp;
        amp *= NOISE_GAIN;
        freq *= NOISE_LACUNARITY;
    }
    // Sums of noise concentrate around 0.5; stretch by 2 around it.
    (0.5 + 2.0 * (sum / norm - 0.5)).clamp(0.0, 1.0)
}

/// HSV (all in [0, 1]) to RGB in [0, 255].
fn hsv(h: f64, s: f64, v: f64) -> [f32; 3] {
    let h6 = (h.rem_euclid(1.0)) * 6.0;
    let i = h6.floor();
    let f = h6 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    let (r, g, b) = match i as i32 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [(r * 255.0) as f32, (g * 255.0) as f32, (b * 255.0) as f32]
}

/// A palette of colours ordered from dark to bright, around a random base
/// hue, so that the noise layer maps to strong luminance contrast.
fn make_palette(rng: &mut SplitMix64) -> [[f32; 3]; PALETTE_SIZE] {
    let base = rng.next_f64();
    let spread = rng.uniform(0.05, 0.4);
    let mut out = [[0f32; 3]; PALETTE_SIZE];
    for (k, c) in out.iter_mut().enumerate() {
        let t = k as f64 / (PALETTE_SIZE - 1) as f64;
        let h = base + spread * rng.uniform(-1.0, 1.0);
        let s = rng.uniform(0.15, 0.75);
        let v = 0.12 + 0.83 * t + rng.uniform(-0.05, 0.05);
        *c = hsv(h, s, v.clamp(0.05, 1.0));
    }
    out
}

fn palette_lookup(p: &[[f32; 3]; PALETTE_SIZE], t: f64) -> [f32; 3] {
    let x = t * (PALETTE_SIZE - 1) as f64;
    let i = (x.floor() as usize).min(PALETTE_SIZE - 2);
    let a = (x - i as f64) as f32;
    let (c0, c1) = (p[i], p[i + 1]);
    [c0[0] + (c1[0] - c0[0]) * a, c0[1] + (c1[1] - c0[1]) * a, c0[2] + (c1[2] - c0[2]) * a]
}

/// A shape colour: mostly a palette extreme (strong contrast with the
/// mid-tones of the noise), sometimes a random saturated colour.
fn shape_colour(rng: &mut SplitMix64, p: &[[f32; 3]; PALETTE_SIZE]) -> [f32; 3] {
    match rng.below(5) {
        0 => hsv(rng.next_f64(), rng.uniform(0.4, 0.9), rng.uniform(0.3, 0.95)),
        1 | 2 => p[0],
        _ => p[PALETTE_SIZE - 1],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bake_is_deterministic_and_seed_dependent() {
        let a = Texture::bake(0.5, 0.4, 0.01, 1);
        let b = Texture::bake(0.5, 0.4, 0.01, 1);
        let c = Texture::bake(0.5, 0.4, 0.01, 2);
        assert_eq!(a.data, b.data);
        assert_ne!(a.data, c.data);
    }

    #[test]
    fn sample_is_continuous_and_hits_texel_centres() {
        let t = Texture::bake(0.3, 0.3, 0.01, 5);
        // At a texel centre, the lookup returns the texel.
        let texel = t.data[20 * t.tw + 10];
        assert_eq!(t.sample(0.105, 0.205), [texel[0] as f32, texel[1] as f32, texel[2] as f32]);
        // Small steps give small changes (continuity): bounded by the
        // largest texel difference times the step in texels.
        let mut prev = t.sample(0.0, 0.1);
        for k in 1..3000 {
            let u = k as f64 * 1e-4;
            let cur = t.sample(u, 0.1);
            for c in 0..3 {
                assert!((cur[c] - prev[c]).abs() <= 255.0 * 1e-2 + 1e-3, "jump at u = {u}");
            }
            prev = cur;
        }
    }

    #[test]
    fn texture_has_contrast() {
        let t = Texture::bake(1.0, 1.0, 0.005, 9);
        let lum: Vec<f32> =
            t.data.iter().map(|p| 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32).collect();
        let mean = lum.iter().sum::<f32>() / lum.len() as f32;
        let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f32>() / lum.len() as f32;
        assert!(var.sqrt() > 30.0, "luminance std {}", var.sqrt());
    }
}

//! Photometric patch alignment for the refinement of track observations
//! (issue 14, item 3): a smoothed gray image (with its gradients where a
//! template is cut), a patch of one observation's neighbourhood as the
//! template (its gradients carried along), and the Gauss-Newton
//! search for the translation that best aligns it in another image, from
//! the affine warp the map predicts, corrected along the way (Lucas-Kanade
//! with a zero-mean, unit-variance normalisation, so a change of exposure
//! does not move the result).
//!
//! The idea is Pixel-Perfect SfM's (Lindenberger et al., ICCV 2021):
//! detections are independent, so a track's keypoints disagree by their
//! detection noise (about half a pyramid-level pixel for ORB); aligning the
//! appearance of every observation to one reference measures where the same
//! surface point lies in each image. Here on the image intensities (no
//! learned features) with the warp predicted from the map, as the direct
//! alignment of DSO and SVO does.

use colslam_geometry::Vec2;
use colslam_geometry::nalgebra::{Matrix2, SMatrix, SVector, Vector2};
use colslam_image::Image;
use rayon::prelude::*;

/// Half side of the square patch, pixels (9 x 9 samples).
pub const PATCH_HALF: i32 = 4;
/// Samples in a patch.
pub const PATCH_LEN: usize = ((2 * PATCH_HALF + 1) * (2 * PATCH_HALF + 1)) as usize;
/// Standard deviation of the Gaussian smoothing of the images, pixels: the
/// alignment's gradients need a smooth image, and noise then averages out.
pub const SMOOTHING_SIGMA: f64 = 1.0;
/// Standard deviation of the Gaussian weight of a patch's samples relative
/// to its half side: the centre, which the observation names, counts most.
const WEIGHT_SIGMA: f64 = 0.75;
/// A template whose intensities spread less than this (gray levels, after
/// smoothing) has no structure to align.
pub const MIN_TEMPLATE_STD: f64 = 1.0;
/// Gauss-Newton iterations at most, and the step length (pixels) below
/// which the search has converged.
const MAX_ITERATIONS: usize = 10;
const CONVERGED: f64 = 1e-3;
/// Damping of the linear correction's parameters, relative to the largest
/// diagonal entry of the translation's: a numerical floor for patches
/// whose texture leaves a deformation unconstrained. A stronger prior
/// towards the map's warp brings back the slant's bias (KITTI 0.31 m at 1,
/// 0.43 m at 10: docs/benchmarks.md).
const LINEAR_DAMPING: f64 = 0.025;
/// Largest entry of the linear correction: beyond it the patch no longer
/// looks like the template's surface.
pub const MAX_LINEAR_CORRECTION: f64 = 0.5;

/// A gray image smoothed by [`SMOOTHING_SIGMA`]; pixel `(i, j)` is the value
/// at array coordinates `(i, j)`. What an alignment samples.
#[derive(Debug, Clone)]
pub struct SmoothImage {
    width: usize,
    height: usize,
    value: Vec<f32>,
}

/// A [`SmoothImage`] with its central-difference gradients: what a template
/// is cut from.
#[derive(Debug, Clone)]
pub struct GradientImage {
    smooth: SmoothImage,
    dx: Vec<f32>,
    dy: Vec<f32>,
}

impl GradientImage {
    /// The smoothed gray version of `image` and its gradients.
    pub fn new(image: &Image) -> Self {
        let smooth = SmoothImage::new(image);
        let (width, height, value) = (smooth.width, smooth.height, &smooth.value);
        let mut dx = vec![0f32; value.len()];
        let mut dy = vec![0f32; value.len()];
        for y in 1..height.saturating_sub(1) {
            for x in 1..width.saturating_sub(1) {
                let i = y * width + x;
                dx[i] = 0.5 * (value[i + 1] - value[i - 1]);
                dy[i] = 0.5 * (value[i + width] - value[i - width]);
            }
        }
        Self { smooth, dx, dy }
    }

    /// Bilinear value and gradient at array coordinates `(x, y)`.
    fn sample(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let (i, fx, fy) = self.smooth.cell(x, y)?;
        let width = self.smooth.width;
        let (a, b, c, d) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let lerp = |m: &[f32]| {
            a * f64::from(m[i])
                + b * f64::from(m[i + 1])
                + c * f64::from(m[i + width])
                + d * f64::from(m[i + width + 1])
        };
        Some([lerp(&self.smooth.value), lerp(&self.dx), lerp(&self.dy)])
    }

    /// The patch around `center` (COLMAP pixel convention) as a template:
    /// intensities normalised to zero mean and unit variance, with their
    /// gradients; `None` near the border or without structure
    /// ([`MIN_TEMPLATE_STD`]).
    pub fn template(&self, center: &Vec2) -> Option<Template> {
        let (cx, cy) = (center.x - 0.5, center.y - 0.5);
        let mut values = [0f32; PATCH_LEN];
        let mut gradients = [[0f32; 2]; PATCH_LEN];
        for ((v, g), d) in values.iter_mut().zip(&mut gradients).zip(offsets()) {
            let [value, gx, gy] = self.sample(cx + d.x, cy + d.y)?;
            *v = value as f32;
            *g = [gx as f32, gy as f32];
        }
        let (mean, std) = mean_std(values.iter().map(|v| f64::from(*v)));
        if std < MIN_TEMPLATE_STD {
            return None;
        }
        for v in &mut values {
            *v = ((f64::from(*v) - mean) / std) as f32;
        }
        for g in &mut gradients {
            *g = [(f64::from(g[0]) / std) as f32, (f64::from(g[1]) / std) as f32];
        }
        Some(Template { values, gradients })
    }
}

impl SmoothImage {
    /// The smoothed gray version of `image`.
    pub fn new(image: &Image) -> Self {
        let gray = image.to_gray();
        let (width, height) = (gray.width(), gray.height());
        let value = gaussian_blur(gray.data(), width, height, SMOOTHING_SIGMA);
        Self { width, height, value }
    }

    /// The top-left pixel of the bilinear cell holding array coordinates
    /// `(x, y)` (as an index) and the fractions across it; `None` outside
    /// the pixels whose gradients are defined.
    fn cell(&self, x: f64, y: f64) -> Option<(usize, f64, f64)> {
        let (w, h) = (self.width as f64, self.height as f64);
        if !(x >= 1.0 && y >= 1.0 && x < w - 2.0 && y < h - 2.0) {
            return None;
        }
        let (x0, y0) = (x.floor(), y.floor());
        // In range: 1 <= x0 and x0 + 1 < width - 1 by the test above.
        Some((y0 as usize * self.width + x0 as usize, x - x0, y - y0))
    }

    /// Bilinear value at array coordinates `(x, y)`.
    fn value(&self, x: f64, y: f64) -> Option<f64> {
        let (i, fx, fy) = self.cell(x, y)?;
        let m = &self.value;
        let top = f64::from(m[i]) + fx * (f64::from(m[i + 1]) - f64::from(m[i]));
        let j = i + self.width;
        let bottom = f64::from(m[j]) + fx * (f64::from(m[j + 1]) - f64::from(m[j]));
        Some(top + fy * (bottom - top))
    }

    /// Aligns `template` in this image: the translation `s` and the linear
    /// correction `A` that make the patch sampled at `start + s + (I + A)
    /// warp d` (COLMAP pixel convention, `d` the template's offsets) match
    /// it, by Gauss-Newton from `s = 0, A = 0`; the translation is the
    /// result. The Jacobian is the template's gradient carried through the
    /// warp, fixed over the iterations (as in the inverse compositional
    /// method of Baker & Matthews 2004), so each iteration samples only the
    /// image's values.
    ///
    /// Why `A`: `warp` is the map's guess of the patch's shape, the plane
    /// through the point facing the reference camera. A surface seen at a
    /// slant (a road ahead of a car) has another shape, and a translation
    /// alone then settles off the point: on KITTI odometry the refined
    /// observations drifted 0.26 -> 0.45 m, with `A` 0.24 m
    /// (docs/benchmarks.md, "Affine patch alignment"), the shape-adapting
    /// affine tracker of Shi and Tomasi (1994).
    ///
    /// `None` when the patch leaves the image, the search moves farther than
    /// `max_shift` pixels or deforms the patch by more than
    /// [`MAX_LINEAR_CORRECTION`], or the template does not constrain the
    /// parameters.
    pub fn align(&self, template: &Template, start: &Vec2, warp: &Matrix2<f64>, max_shift: f64) -> Option<Alignment> {
        let weights = weights();
        // The template's offsets under the map's warp, computed once.
        let offsets: Vec<Vector2<f64>> = offsets().map(|d| warp * d).collect();
        let to_image = warp.try_inverse()?.transpose();
        let grads: Vec<Vector2<f64>> =
            template.gradients.iter().map(|g| to_image * Vector2::new(f64::from(g[0]), f64::from(g[1]))).collect();
        // Jacobian columns: the translation (the template's gradients in the
        // image's coordinates), then the linear correction's four entries,
        // each times the offset it scales; their means are removed below
        // (the patch's mean follows the parameters).
        let mut jac: Vec<SVector<f64, 6>> = grads
            .iter()
            .zip(&offsets)
            .map(|(j, e)| SVector::<f64, 6>::from_column_slice(&[j.x, j.y, j.x * e.x, j.x * e.y, j.y * e.x, j.y * e.y]))
            .collect();
        let mean: SVector<f64, 6> = jac.iter().sum::<SVector<f64, 6>>() / PATCH_LEN as f64;
        let mut h = SMatrix::<f64, 6, 6>::zeros();
        for (j, w) in jac.iter_mut().zip(&weights) {
            *j -= mean;
            h += *w * *j * j.transpose();
        }
        for k in 2..6 {
            h[(k, k)] += LINEAR_DAMPING * h[(0, 0)].max(h[(1, 1)]);
        }
        let inverse = h.try_inverse()?;
        let (sx, sy) = (start.x - 0.5, start.y - 0.5);
        let mut p = SVector::<f64, 6>::zeros();
        let mut values = [0f64; PATCH_LEN];
        let sample = |p: &SVector<f64, 6>, values: &mut [f64; PATCH_LEN]| -> Option<(f64, f64)> {
            let a = Matrix2::new(1.0 + p[2], p[3], p[4], 1.0 + p[5]);
            for (v, d) in values.iter_mut().zip(&offsets) {
                let e = a * d;
                *v = self.value(sx + p[0] + e.x, sy + p[1] + e.y)?;
            }
            let (mean, std) = mean_std(values.iter().copied());
            (std >= 1e-3).then_some((mean, std))
        };
        for _ in 0..MAX_ITERATIONS {
            let (mean, std) = sample(&p, &mut values)?;
            let mut b = SVector::<f64, 6>::zeros();
            for ((v, t), (j, w)) in values.iter().zip(&template.values).zip(jac.iter().zip(&weights)) {
                b += *w * ((v - mean) / std - f64::from(*t)) * j;
            }
            let step = -inverse * b;
            p += step;
            if Vector2::new(p[0], p[1]).norm() > max_shift || p.rows(2, 4).abs().max() > MAX_LINEAR_CORRECTION {
                return None;
            }
            if Vector2::new(step[0], step[1]).norm() < CONVERGED {
                break;
            }
        }
        let (mean, std) = sample(&p, &mut values)?;
        // Weighted correlation of the two normalised patches, and their
        // weighted sum of squared differences.
        let (mut vt, mut vv, mut tt, mut rss) = (0.0, 0.0, 0.0, 0.0);
        for ((v, t), w) in values.iter().zip(&template.values).zip(&weights) {
            let (v, t) = ((v - mean) / std, f64::from(*t));
            vt += w * v * t;
            vv += w * v * v;
            tt += w * t * t;
            rss += w * (v - t).powi(2);
        }
        let zncc = vt / (vv * tt).sqrt().max(f64::MIN_POSITIVE);
        // The translation's covariance: the residuals' variance times the
        // translation block of the inverse normal matrix (the affine
        // parameters marginalised out), the weights taken as the samples'
        // relative precisions. The smoothing correlates the noise of
        // neighbouring samples over about 4 pi sigma^2 pixels (the sum of
        // the Gaussian's autocorrelation), so the samples count as that
        // many times fewer independent ones; without this the prediction
        // was 2.7-3.7x short of the errors of a noisy image (the test below).
        let correlated = 4.0 * std::f64::consts::PI * SMOOTHING_SIGMA * SMOOTHING_SIGMA;
        let variance = correlated * rss / (PATCH_LEN - 6) as f64;
        let block = inverse.fixed_view::<2, 2>(0, 0).into_owned() * variance;
        let sigma_px = block.symmetric_eigenvalues().max().max(0.0).sqrt();
        Some(Alignment { shift: Vec2::new(p[0], p[1]), zncc, sigma_px })
    }
}

/// The normalised intensities of a patch (row by row, [`PATCH_LEN`]) and
/// their gradients.
#[derive(Debug, Clone)]
pub struct Template {
    values: [f32; PATCH_LEN],
    /// Gradients of the normalised intensities, x and y.
    gradients: [[f32; 2]; PATCH_LEN],
}

/// The result of [`SmoothImage::align`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// Translation from the start, pixels.
    pub shift: Vec2,
    /// Weighted zero-mean normalised cross-correlation with the template
    /// once aligned (1: identical up to gain and offset).
    pub zncc: f64,
    /// Standard deviation of the translation along its least constrained
    /// direction, pixels, as the alignment itself predicts it (the
    /// residuals' spread through the inverse normal matrix): large on an
    /// edge (the aperture problem), a smooth patch or a poor match, small
    /// on a sharp corner that matches well.
    pub sigma_px: f64,
}

/// The template's sample offsets, row by row.
fn offsets() -> impl Iterator<Item = Vector2<f64>> {
    (-PATCH_HALF..=PATCH_HALF).flat_map(|y| (-PATCH_HALF..=PATCH_HALF).map(move |x| Vector2::new(x as f64, y as f64)))
}

fn weights() -> [f64; PATCH_LEN] {
    let sigma = WEIGHT_SIGMA * f64::from(PATCH_HALF);
    let mut w = [0f64; PATCH_LEN];
    for (w, d) in w.iter_mut().zip(offsets()) {
        *w = (-d.norm_squared() / (2.0 * sigma * sigma)).exp();
    }
    w
}

fn mean_std(values: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = values.clone().count().max(1) as f64;
    let mean = values.clone().sum::<f64>() / n;
    let var = values.map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// Separable Gaussian blur of an 8-bit plane, borders replicated.
fn gaussian_blur(src: &[u8], width: usize, height: usize, sigma: f64) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let plane: Vec<f32> = src.iter().map(|v| f32::from(*v)).collect();
    let rows = convolve(&plane, width, height, &kernel, (1, 0));
    convolve(&rows, width, height, &kernel, (0, 1))
}

/// One pass of a separable filter of odd length along `(dx, dy)` (one of
/// them 1), borders replicated. Rows in parallel; away from the borders
/// the taps are accumulated tap by tap over a whole run of pixels, which
/// vectorises (each value still sums its taps in the same order as the
/// clamped sum at the borders).
fn convolve(src: &[f32], width: usize, height: usize, kernel: &[f32], (dx, dy): (usize, usize)) -> Vec<f32> {
    let radius = kernel.len() / 2;
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let clamped = |x: usize, y: usize| -> f32 {
        kernel
            .iter()
            .enumerate()
            .map(|(k, w)| {
                let o = k as isize - radius as isize;
                let (sx, sy) =
                    (clamp(x as isize + o * dx as isize, width), clamp(y as isize + o * dy as isize, height));
                w * src[sy * width + sx]
            })
            .sum()
    };
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(width.max(1)).enumerate().for_each(|(y, row)| {
        // The pixels whose taps all lie inside the image.
        let inner = if dx == 1 {
            radius..width.saturating_sub(radius).max(radius)
        } else if y >= radius && y + radius < height {
            0..width
        } else {
            0..0
        };
        for (x, o) in row.iter_mut().enumerate().filter(|(x, _)| !inner.contains(x)) {
            *o = clamped(x, y);
        }
        if inner.is_empty() {
            return;
        }
        let dst = &mut row[inner.clone()];
        for (k, w) in kernel.iter().enumerate() {
            // The first source pixel of this tap for the run's first pixel.
            let first = if dx == 1 { y * width + inner.start + k - radius } else { (y + k - radius) * width };
            for (o, v) in dst.iter_mut().zip(&src[first..first + inner.len()]) {
                *o += w * v;
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gray level of a smooth blob texture at `(u, v)`.
    fn pattern(u: f64, v: f64) -> u8 {
        let f = 128.0 + 50.0 * (u * 0.31).sin() * (v * 0.23).cos() + 40.0 * ((u + v) * 0.17).sin();
        f.clamp(0.0, 255.0) as u8
    }

    /// A smooth blob texture, shifted by `(ox, oy)` pixels.
    fn texture(width: usize, height: usize, ox: f64, oy: f64) -> Image {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(pattern(x as f64 - ox, y as f64 - oy));
            }
        }
        Image::from_vec(width, height, 1, data).unwrap()
    }

    #[test]
    fn a_shifted_image_is_found_to_a_tenth_of_a_pixel() {
        let a = GradientImage::new(&texture(64, 64, 0.0, 0.0));
        let b = SmoothImage::new(&texture(64, 64, 1.3, -0.7));
        let center = Vec2::new(32.5, 30.5);
        let t = a.template(&center).unwrap();
        let found = b.align(&t, &center, &Matrix2::identity(), 3.0).unwrap();
        assert!((found.shift - Vec2::new(1.3, -0.7)).norm() < 0.1, "{found:?}");
        assert!(found.zncc > 0.95, "{found:?}");
        // Too far for the allowed shift.
        assert!(b.align(&t, &center, &Matrix2::identity(), 1.0).is_none());
    }

    /// The texture seen through `m` about `c` and shifted by `o`: image
    /// point `p` shows the texture at `m (p - c) + c - o`.
    fn deformed(width: usize, height: usize, m: &Matrix2<f64>, c: &Vec2, o: &Vec2) -> Image {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let q = m * (Vec2::new(x as f64, y as f64) - c) + c - o;
                data.push(pattern(q.x, q.y));
            }
        }
        Image::from_vec(width, height, 1, data).unwrap()
    }

    #[test]
    fn a_patch_of_another_shape_than_the_warp_predicts_is_found_to_a_tenth_of_a_pixel() {
        // A slanted surface: 20 % shorter one way, sheared, against the
        // identity warp the map would predict for it.
        let m = Matrix2::new(1.0, 0.15, 0.0, 1.25);
        let c = Vec2::new(31.0, 30.0);
        let o = Vec2::new(0.8, -0.6);
        let a = GradientImage::new(&texture(64, 64, 0.0, 0.0));
        let b = SmoothImage::new(&deformed(64, 64, &m, &c, &o));
        // Array coordinates (x, y) are pixel centres x + 0.5 in the COLMAP
        // convention of `align`.
        let center = c + Vec2::new(0.5, 0.5);
        let t = a.template(&center).unwrap();
        let truth = m.try_inverse().unwrap() * o;
        let found = b.align(&t, &center, &Matrix2::identity(), 3.0).unwrap();
        assert!((found.shift - truth).norm() < 0.1, "{found:?} against {truth:?}");
        assert!(found.zncc > 0.95, "{found:?}");
    }

    #[test]
    fn the_predicted_spread_follows_the_error_of_a_noisy_image() {
        // The shifted texture with seeded noise of growing strength: the
        // alignment's own prediction of its spread (`sigma_px`) grows with
        // the noise and stays within a small factor of the errors found.
        let a = GradientImage::new(&texture(64, 64, 0.0, 0.0));
        let truth = Vec2::new(0.6, -0.4);
        let clean = texture(64, 64, truth.x, truth.y);
        let mut rng = colslam_geometry::SplitMix64::new(7);
        let mut spreads = Vec::new();
        for amplitude in [0.0, 20.0, 60.0] {
            let (mut err2, mut predicted, mut n) = (0.0, 0.0, 0.0);
            for trial in 0..40 {
                let data: Vec<u8> = clean
                    .data()
                    .iter()
                    .map(|v| (f64::from(*v) + amplitude * rng.uniform(-0.5, 0.5)).clamp(0.0, 255.0) as u8)
                    .collect();
                let b = SmoothImage::new(&Image::from_vec(64, 64, 1, data).unwrap());
                let center = Vec2::new(20.5 + f64::from(trial % 5) * 6.0, 20.5 + f64::from(trial / 5) * 3.0);
                let t = a.template(&center).unwrap();
                let Some(found) = b.align(&t, &center, &Matrix2::identity(), 3.0) else { continue };
                err2 += (found.shift - truth).norm_squared() / 2.0;
                predicted += found.sigma_px.powi(2);
                n += 1.0;
            }
            let (rms, sigma) = ((err2 / n).sqrt(), (predicted / n).sqrt());
            eprintln!("noise {amplitude}: {n} aligned, error per axis {rms:.4} px, predicted {sigma:.4} px");
            spreads.push((rms, sigma));
        }
        assert!(spreads[0].1 < 0.05, "{spreads:?}");
        assert!(spreads[0].1 < spreads[1].1 && spreads[1].1 < spreads[2].1, "{spreads:?}");
        for (rms, sigma) in &spreads[1..] {
            assert!(*rms < 1.5 * sigma && *sigma < 1.5 * rms, "{spreads:?}");
        }
    }

    #[test]
    fn a_flat_patch_is_no_template() {
        let flat = Image::from_vec(32, 32, 1, vec![90; 32 * 32]).unwrap();
        assert!(GradientImage::new(&flat).template(&Vec2::new(16.5, 16.5)).is_none());
        // Nor is a patch that leaves the image.
        assert!(GradientImage::new(&texture(32, 32, 0.0, 0.0)).template(&Vec2::new(2.5, 16.5)).is_none());
    }
}

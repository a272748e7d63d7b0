//! Ray-cast rendering of the scene: colour (supersampled, optionally motion
//! blurred, with image noise) and depth.
//!
//! Pixel convention: OpenCV/TUM, as the datasets' `camera.yaml`: pixel
//! `(i, j)` has its centre at continuous coordinates `(i, j)`, so the image
//! centre is `((w - 1) / 2, (h - 1) / 2)`. The rays of all samples are computed
//! once per sequence through [`colslam_camera::Camera::cam_from_img`] (exact
//! for distorted cameras); a ray's direction in the camera is `(x, y, 1)`, so
//! its hit parameter is the depth (camera z) of the hit.

use colslam_camera::{Camera, CameraModelId};
use colslam_geometry::{Rigid3, SplitMix64, Vec2, Vec3};
use colslam_image::Image;
use rayon::prelude::*;

use crate::options::{SynthError, SynthOptions};
use crate::scene::{FACES_PER_BOX, Hit, Scene, slab};

/// Samples behind the camera plane closer than this (metres, camera z) make
/// a box's screen-space bound unbounded (it is then tested for every ray).
const CULL_MIN_DEPTH: f64 = 1e-6;

/// Builds the camera of a sequence: PINHOLE, or OPENCV with distortion; the
/// principal point is the image centre in the OpenCV pixel convention.
pub fn make_camera(opts: &SynthOptions) -> Result<Camera, SynthError> {
    let (w, h) = (opts.width as f64, opts.height as f64);
    let (cx, cy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
    let cam = match &opts.distortion {
        None => Camera::new(
            CameraModelId::Pinhole,
            opts.width as u64,
            opts.height as u64,
            vec![opts.focal, opts.focal, cx, cy],
        ),
        Some(d) => Camera::new(
            CameraModelId::OpenCv,
            opts.width as u64,
            opts.height as u64,
            vec![opts.focal, opts.focal, cx, cy, d[0], d[1], d[2], d[3]],
        ),
    };
    cam.map_err(|e| SynthError::Camera(e.to_string()))
}

/// The normalised image-plane coordinates of every sample ray.
#[derive(Clone)]
pub struct RayTable {
    width: usize,
    /// Samples per pixel and axis.
    ss: usize,
    /// `(x, y)` per sample, rows of `width * ss` samples, `height * ss` rows.
    xy: Vec<[f64; 2]>,
    /// Per pixel row: min/max of y over its samples.
    row_y: Vec<(f64, f64)>,
    /// `(x, y)` of every pixel centre (for depth renders).
    centers: Vec<[f64; 2]>,
}

impl std::fmt::Debug for RayTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RayTable({} samples, {}x{} per pixel)", self.xy.len(), self.ss, self.ss)
    }
}

fn unproject(cam: &Camera, px: Vec2) -> Result<[f64; 2], SynthError> {
    cam.cam_from_img(&px).map(|v| [v.x, v.y]).ok_or_else(|| {
        SynthError::Camera(format!(
            "pixel ({}, {}) cannot be unprojected: the distortion folds inside the image; use smaller coefficients",
            px.x, px.y
        ))
    })
}

impl RayTable {
    /// Unprojects the `ss x ss` sub-pixel sample positions (regular grid,
    /// centred in each pixel) and the pixel centres.
    pub fn new(cam: &Camera, width: usize, height: usize, ss: usize) -> Result<RayTable, SynthError> {
        let sw = width * ss;
        let xy: Vec<[f64; 2]> = (0..height * ss)
            .into_par_iter()
            .flat_map_iter(|sj| {
                let y = (sj as f64 + 0.5) / ss as f64 - 0.5;
                (0..sw).map(move |si| {
                    let x = (si as f64 + 0.5) / ss as f64 - 0.5;
                    unproject(cam, Vec2::new(x, y))
                })
            })
            .collect::<Result<_, _>>()?;
        let centers: Vec<[f64; 2]> = (0..height)
            .into_par_iter()
            .flat_map_iter(|j| (0..width).map(move |i| unproject(cam, Vec2::new(i as f64, j as f64))))
            .collect::<Result<_, _>>()?;
        let row_y = xy
            .chunks_exact(sw * ss)
            .map(|rows| {
                rows.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[1]), hi.max(p[1])))
            })
            .collect();
        Ok(RayTable { width, ss, xy, row_y, centers })
    }
}

/// Where a box can appear on the normalised image plane in one frame.
#[derive(Debug, Clone, Copy)]
enum Cull {
    /// Entirely behind the camera: never hit.
    Never,
    /// Straddles the camera plane: test every ray.
    Always,
    /// Inside this rectangle `[x0, x1] x [y0, y1]` (the projection of a
    /// convex body in front of the camera lies in the hull of its corners').
    Rect(f64, f64, f64, f64),
}

impl Cull {
    #[inline]
    fn contains(&self, x: f64, y: f64) -> bool {
        match *self {
            Cull::Never => false,
            Cull::Always => true,
            Cull::Rect(x0, x1, y0, y1) => x >= x0 && x <= x1 && y >= y0 && y <= y1,
        }
    }
    fn overlaps_rows(&self, y0: f64, y1: f64) -> bool {
        match *self {
            Cull::Never => false,
            Cull::Always => true,
            Cull::Rect(_, _, by0, by1) => by0 <= y1 && by1 >= y0,
        }
    }
}

/// A box prepared for one frame: its screen bound, a lower bound of the
/// depth of any of its points, and its corners relative to the camera centre.
#[derive(Debug, Clone, Copy)]
struct FrameBox {
    index: usize,
    cull: Cull,
    min_depth: f64,
    lo: [f64; 3],
    hi: [f64; 3],
}

/// The boxes that can appear in a frame, nearest first (by `min_depth`), so
/// that a ray stops testing once the next box cannot be nearer than its hit.
fn frame_boxes(scene: &Scene, world_from_cam: &Rigid3) -> Vec<FrameBox> {
    let cam_from_world = world_from_cam.inverse();
    let o = world_from_cam.translation;
    let mut out: Vec<FrameBox> = scene
        .boxes()
        .iter()
        .enumerate()
        .filter_map(|(index, b)| {
            let cs = b.aabb.corners().map(|c| cam_from_world.transform_point(&c));
            // A ray's parameter is its depth, and a box's points have depths
            // between its corners' (depth is linear): a lower bound.
            let min_depth = cs.iter().map(|c| c.z).fold(f64::INFINITY, f64::min).max(0.0);
            let cull = cull_of(&cs);
            let lo = [b.aabb.min[0] - o.x, b.aabb.min[1] - o.y, b.aabb.min[2] - o.z];
            let hi = [b.aabb.max[0] - o.x, b.aabb.max[1] - o.y, b.aabb.max[2] - o.z];
            (!matches!(cull, Cull::Never)).then_some(FrameBox { index, cull, min_depth, lo, hi })
        })
        .collect();
    out.sort_by(|a, b| a.min_depth.total_cmp(&b.min_depth).then(a.index.cmp(&b.index)));
    out
}

fn cull_of(cs: &[Vec3; 8]) -> Cull {
    if cs.iter().all(|c| c.z <= 0.0) {
        return Cull::Never;
    }
    if cs.iter().any(|c| c.z < CULL_MIN_DEPTH) {
        return Cull::Always;
    }
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for c in cs {
        let (x, y) = (c.x / c.z, c.y / c.z);
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    // A relative margin absorbs rounding in the division.
    let m = 1e-9 * (1.0 + x1.abs().max(x0.abs()).max(y0.abs()).max(y1.abs()));
    Cull::Rect(x0 - m, x1 + m, y0 - m, y1 + m)
}

/// Adds `weight` times the supersampled radiance of the view from
/// `world_from_cam` into `acc` (`width * height * 3` floats).
pub(crate) fn accumulate(scene: &Scene, rays: &RayTable, world_from_cam: &Rigid3, weight: f32, acc: &mut [f32]) {
    let boxes = frame_boxes(scene, world_from_cam);
    let w = rays.width;
    acc.par_chunks_exact_mut(w * 3)
        .enumerate()
        .for_each(|(j, row)| shade_row(scene, rays, world_from_cam, &boxes, weight, j, row));
}

/// [`accumulate`] for a rolling shutter: pixel row `j` is seen from
/// `pose_of_row(j)` (each row culls the boxes for its own pose).
pub(crate) fn accumulate_rolling(
    scene: &Scene,
    rays: &RayTable,
    pose_of_row: &(dyn Fn(usize) -> Rigid3 + Sync),
    weight: f32,
    acc: &mut [f32],
) {
    let w = rays.width;
    acc.par_chunks_exact_mut(w * 3).enumerate().for_each(|(j, row)| {
        let pose = pose_of_row(j);
        let boxes = frame_boxes(scene, &pose);
        shade_row(scene, rays, &pose, &boxes, weight, j, row);
    });
}

/// Adds `weight` times the supersampled radiance of pixel row `j` seen from
/// `world_from_cam` (with its culled `boxes`) into `row` (`width * 3` floats).
fn shade_row(
    scene: &Scene,
    rays: &RayTable,
    world_from_cam: &Rigid3,
    boxes: &[FrameBox],
    weight: f32,
    j: usize,
    row: &mut [f32],
) {
    let r = world_from_cam.rotation_matrix();
    let o = world_from_cam.translation;
    let (w, ss) = (rays.width, rays.ss);
    let sw = w * ss;
    let per_sample = weight / (ss * ss) as f32;
    let (ylo, yhi) = rays.row_y.get(j).copied().unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
    let cand: Vec<FrameBox> = boxes.iter().filter(|b| b.cull.overlaps_rows(ylo, yhi)).copied().collect();
    for sj in 0..ss {
        let srow = (j * ss + sj) * sw;
        let Some(samples) = rays.xy.get(srow..srow + sw) else { continue };
        for (si, s) in samples.iter().enumerate() {
            let (x, y) = (s[0], s[1]);
            let d = r * Vec3::new(x, y, 1.0);
            let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
            let mut hit = scene.room_exit(&o, &d, &inv);
            for b in &cand {
                if b.min_depth >= hit.t {
                    break;
                }
                if b.cull.contains(x, y)
                    && let Some((t, face)) = slab(&b.lo, &b.hi, &inv)
                    && t < hit.t
                {
                    hit = Hit { t, surface: FACES_PER_BOX * (b.index + 1) + face };
                }
            }
            let p = o + d * hit.t;
            let c = scene.radiance(hit.surface, &p);
            let i = si / ss;
            // i < w since si < sw = w * ss; row holds w * 3 floats.
            let px = &mut row[3 * i..3 * i + 3];
            px[0] += c[0] * per_sample;
            px[1] += c[1] * per_sample;
            px[2] += c[2] * per_sample;
        }
    }
}

/// Depth (camera z) of the scene at every pixel centre, row-major.
pub(crate) fn depth_map(scene: &Scene, rays: &RayTable, world_from_cam: &Rigid3) -> Vec<f64> {
    let r = world_from_cam.rotation_matrix();
    let o = world_from_cam.translation;
    rays.centers
        .par_iter()
        .map(|s| {
            let d = r * Vec3::new(s[0], s[1], 1.0);
            scene.cast(&o, &d).t
        })
        .collect()
}

/// Turns accumulated radiance into an 8-bit RGB image with additive noise
/// (deterministic: one generator per row, seeded from `noise_seed` and the row).
pub(crate) fn quantise(acc: &[f32], width: usize, height: usize, sigma: f64, noise_seed: u64) -> Image {
    let mut data = vec![0u8; width * height * 3];
    let sigma = sigma as f32;
    data.par_chunks_exact_mut(width * 3).zip(acc.par_chunks_exact(width * 3)).enumerate().for_each(|(j, (out, a))| {
        let mut rng = SplitMix64::new(noise_seed ^ (j as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93));
        for (o, &v) in out.iter_mut().zip(a) {
            let n = if sigma > 0.0 { sigma * approx_normal(&mut rng) } else { 0.0 };
            *o = (v + n).round().clamp(0.0, 255.0) as u8;
        }
    });
    // The buffer has exactly width * height * 3 bytes by construction.
    Image::from_vec(width, height, 3, data).unwrap_or_else(|_| Image::new(width, height, 3))
}

/// Approximately standard normal: the sum of four 16-bit uniforms from one
/// 64-bit draw (Irwin-Hall with n = 4), rescaled to unit variance. Much cheaper than Box-Muller and plenty for image noise.
#[inline]
fn approx_normal(rng: &mut SplitMix64) -> f32 {
    let z = rng.next_u64();
    let s = (z & 0xFFFF) + ((z >> 16) & 0xFFFF) + ((z >> 32) & 0xFFFF) + (z >> 48);
    // Mean of the sum is 4 * 65535 / 2; its variance 4 * (65536^2 - 1) / 12.
    const MEAN: f32 = 2.0 * 65535.0;
    const INV_STD: f32 = 1.0 / 37_837.23; // 1 / sqrt(4 * (65536^2 - 1) / 12)
    (s as f32 - MEAN) * INV_STD
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approx_normal_has_unit_variance() {
        let mut rng = SplitMix64::new(3);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| approx_normal(&mut rng) as f64).collect();
        let (mean, var) = colslam_geometry::stats::mean_and_variance(&xs).unwrap();
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.02, "{var}");
    }

    #[test]
    fn ray_table_pinhole_matches_k_inverse() {
        let opts = SynthOptions { width: 8, height: 6, focal: 100.0, ..Default::default() };
        let cam = make_camera(&opts).unwrap();
        let t = RayTable::new(&cam, 8, 6, 2).unwrap();
        assert_eq!(t.xy.len(), 16 * 12);
        // Sample (3, 1) of the supersampled grid is at pixel (1.25, 0.25) - 0.5 offsets:
        // x = (3 + 0.5) / 2 - 0.5 = 1.25, y = (1 + 0.5) / 2 - 0.5 = 0.25.
        let s = t.xy[16 + 3];
        assert!((s[0] - (1.25 - 3.5) / 100.0).abs() < 1e-15);
        assert!((s[1] - (0.25 - 2.5) / 100.0).abs() < 1e-15);
        let c = t.centers[8 + 2];
        assert!((c[0] - (2.0 - 3.5) / 100.0).abs() < 1e-15 && (c[1] - (1.0 - 2.5) / 100.0).abs() < 1e-15);
    }
}

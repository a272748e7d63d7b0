//! Undistortion: a remap table from a distorted camera to a PINHOLE one,
//! image remapping (bilinear, gray or RGB) and point undistortion.
//!
//! The output camera is chosen by [`UndistortOutput`]:
//!
//! * [`UndistortOutput::Fit`] (default), after COLMAP's `UndistortCamera`
//!   (`src/colmap/image/undistortion.cc`): a PINHOLE camera with the source
//!   focal lengths, whose size and principal point are scaled per axis so the
//!   output shows only valid pixels (`blank_pixels = 0`), every source pixel
//!   (`blank_pixels = 1`), or a blend; the scale is clamped to
//!   `[min_scale, max_scale]` and the result to `max_image_size`.
//! * [`UndistortOutput::KeepCalibration`]: PINHOLE with the source
//!   `fx, fy, cx, cy` and the source size (simple; corners may be blank or
//!   cropped).
//!
//! Pixel coordinates follow [`UndistortOptions::pixel_convention`]; the
//! source and output cameras must use the same one.

use colslam_image::Image;

use crate::{Camera, CameraError, CameraModelId, PixelConvention, Vec2};

/// How the undistorted camera is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UndistortOutput {
    /// COLMAP-style: source focal lengths, size and principal point scaled
    /// to the valid region (see [`UndistortOptions::blank_pixels`]).
    #[default]
    Fit,
    /// Source `fx, fy, cx, cy` and size.
    KeepCalibration,
}

/// Options of [`UndistortMap::new`].
#[derive(Debug, Clone, PartialEq)]
pub struct UndistortOptions {
    /// How the output camera is chosen. Default [`UndistortOutput::Fit`].
    pub output: UndistortOutput,
    /// For [`UndistortOutput::Fit`]: 0 keeps only valid pixels (crops),
    /// 1 keeps every source pixel (blank corners), in between blends the
    /// two scales. Default 0 (COLMAP's default).
    pub blank_pixels: f64,
    /// Smallest allowed scale of the output size relative to the source.
    /// Default 0.2 (COLMAP).
    pub min_scale: f64,
    /// Largest allowed scale. Default 2.0 (COLMAP).
    pub max_scale: f64,
    /// Largest output width or height in pixels; 0 = unlimited. Default 0.
    pub max_image_size: u64,
    /// Pixel convention of the cameras and images. Default COLMAP's.
    pub pixel_convention: PixelConvention,
    /// Value written to output pixels that see no source pixel. Default 0.
    pub fill: u8,
}

impl Default for UndistortOptions {
    fn default() -> Self {
        Self {
            output: UndistortOutput::Fit,
            blank_pixels: 0.0,
            min_scale: 0.2,
            max_scale: 2.0,
            max_image_size: 0,
            pixel_convention: PixelConvention::Colmap,
            fill: 0,
        }
    }
}

impl UndistortOptions {
    /// Checks the ranges of the options.
    pub fn validate(&self) -> Result<(), CameraError> {
        let bad = |name: &str, value: f64, reason: &str| {
            Err(CameraError::InvalidParam { name: name.into(), value, reason: reason.into() })
        };
        if !(0.0..=1.0).contains(&self.blank_pixels) {
            return bad("blank_pixels", self.blank_pixels, "must be in [0, 1]");
        }
        if !(self.min_scale.is_finite() && self.min_scale > 0.0) {
            return bad("min_scale", self.min_scale, "must be positive and finite");
        }
        if !(self.max_scale.is_finite() && self.max_scale >= self.min_scale) {
            return bad("max_scale", self.max_scale, "must be finite and >= min_scale");
        }
        Ok(())
    }
}

/// A remap table from a distorted camera to an undistorted PINHOLE camera.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    distorted: Camera,
    undistorted: Camera,
    convention: PixelConvention,
    fill: u8,
    /// For each output pixel (row-major), the source position in pixel
    /// *index* space (pixel (i, j) has its centre at (i, j)); NaN where the
    /// output pixel has no source.
    map: Vec<[f32; 2]>,
}

/// Source positions within this many pixels outside the outermost pixel
/// centres are clamped onto the image (the half-pixel border of the image
/// rectangle, plus rounding).
const BORDER_CLAMP: f64 = 0.5 + 1e-6;

/// The undistorted PINHOLE camera for `distorted` (see the module docs).
pub fn undistorted_camera(distorted: &Camera, options: &UndistortOptions) -> Result<Camera, CameraError> {
    options.validate()?;
    distorted.validate()?;
    let (fx, fy) = (distorted.focal_x(), distorted.focal_y());
    let c = distorted.principal_point();
    let (w, h) = (distorted.width as f64, distorted.height as f64);
    let base = Camera::pinhole(distorted.width, distorted.height, fx, fy, c.x, c.y);
    if options.output == UndistortOutput::KeepCalibration {
        return Ok(base);
    }
    // Work in COLMAP's convention (image = [0, w] x [0, h]).
    let o = options.pixel_convention.offset_to(PixelConvention::Colmap);
    let (cxc, cyc) = (c.x + o, c.y + o);
    let to_out =
        |px: Vec2| distorted.cam_from_img(&Vec2::new(px.x - o, px.y - o)).map(|uv| (fx * uv.x + cxc, fy * uv.y + cyc));
    // Extremes of the undistorted border: [min, max] of each side.
    let mut left = [f64::MAX, f64::MIN];
    let mut right = left;
    let mut top = left;
    let mut bottom = left;
    let widen = |r: &mut [f64; 2], v: f64| {
        r[0] = r[0].min(v);
        r[1] = r[1].max(v);
    };
    // Pixel centres of the outermost rows/columns (as COLMAP samples them).
    for j in 0..distorted.height {
        let y = j as f64 + 0.5;
        if let Some((x, _)) = to_out(Vec2::new(0.5, y)) {
            widen(&mut left, x);
        }
        if let Some((x, _)) = to_out(Vec2::new(w - 0.5, y)) {
            widen(&mut right, x);
        }
    }
    for i in 0..distorted.width {
        let x = i as f64 + 0.5;
        if let Some((_, y)) = to_out(Vec2::new(x, 0.5)) {
            widen(&mut top, y);
        }
        if let Some((_, y)) = to_out(Vec2::new(x, h - 0.5)) {
            widen(&mut bottom, y);
        }
    }
    if [left, right, top, bottom].iter().any(|r| r[0] > r[1]) {
        return Err(CameraError::InvalidParam {
            name: "distortion".into(),
            value: f64::NAN,
            reason: "no border pixel of the image can be undistorted".into(),
        });
    }
    // Scale s maps the output extent [c - s c, c + s (w - c)]; keep only
    // valid pixels (inner extremes) or all pixels (outer extremes).
    let axis_scale = |c: f64, size: f64, lo: [f64; 2], hi: [f64; 2]| {
        let inner = ((c - lo[1]) / c).min((hi[0] - c) / (size - c));
        let outer = ((c - lo[0]) / c).max((hi[1] - c) / (size - c));
        let s = inner * (1.0 - options.blank_pixels) + outer * options.blank_pixels;
        if s.is_finite() { s.clamp(options.min_scale, options.max_scale) } else { 1.0 }
    };
    let sx = axis_scale(cxc, w, left, right);
    let sy = axis_scale(cyc, h, top, bottom);
    let mut out_w = (sx * w).round().max(1.0);
    let mut out_h = (sy * h).round().max(1.0);
    let mut f = (fx, fy);
    let (mut ocx, mut ocy) = (cxc * out_w / w, cyc * out_h / h);
    if options.max_image_size > 0 {
        let m = options.max_image_size as f64;
        let down = (m / out_w.max(out_h)).min(1.0);
        if down < 1.0 {
            let (nw, nh) = ((out_w * down).round().max(1.0), (out_h * down).round().max(1.0));
            f = (f.0 * nw / out_w, f.1 * nh / out_h);
            ocx *= nw / out_w;
            ocy *= nh / out_h;
            out_w = nw;
            out_h = nh;
        }
    }
    Ok(Camera::pinhole(out_w as u64, out_h as u64, f.0, f.1, ocx - o, ocy - o))
}

impl UndistortMap {
    /// Builds the map for `distorted` with the output camera chosen by
    /// `options`.
    pub fn new(distorted: &Camera, options: &UndistortOptions) -> Result<Self, CameraError> {
        let target = undistorted_camera(distorted, options)?;
        Self::with_target(distorted, &target, options.pixel_convention, options.fill)
    }

    /// Builds the map to an arbitrary `target` camera (any model, e.g. a
    /// rescaled pinhole).
    pub fn with_target(
        distorted: &Camera,
        target: &Camera,
        convention: PixelConvention,
        fill: u8,
    ) -> Result<Self, CameraError> {
        distorted.validate()?;
        target.validate()?;
        let c0 = convention.center_of(0.0);
        let (w, h) = (distorted.width as f64, distorted.height as f64);
        let mut map = Vec::with_capacity((target.width * target.height) as usize);
        for j in 0..target.height {
            for i in 0..target.width {
                let px = Vec2::new(i as f64 + c0, j as f64 + c0);
                let src = target.cam_from_img(&px).map(|uv| distorted.img_from_normalized(&uv) - Vec2::new(c0, c0));
                let entry = match src {
                    Some(s)
                        if s.x >= -BORDER_CLAMP
                            && s.y >= -BORDER_CLAMP
                            && s.x <= w - 1.0 + BORDER_CLAMP
                            && s.y <= h - 1.0 + BORDER_CLAMP =>
                    {
                        [s.x.clamp(0.0, w - 1.0) as f32, s.y.clamp(0.0, h - 1.0) as f32]
                    }
                    _ => [f32::NAN, f32::NAN],
                };
                map.push(entry);
            }
        }
        Ok(Self { distorted: distorted.clone(), undistorted: target.clone(), convention, fill, map })
    }

    /// The source (distorted) camera.
    pub fn distorted_camera(&self) -> &Camera {
        &self.distorted
    }

    /// The output (undistorted) camera.
    pub fn undistorted_camera(&self) -> &Camera {
        &self.undistorted
    }

    /// Share of output pixels that see a source pixel.
    pub fn valid_fraction(&self) -> f64 {
        let valid = self.map.iter().filter(|m| !m[0].is_nan()).count();
        valid as f64 / self.map.len().max(1) as f64
    }

    /// Source position (pixel index space, centre of pixel (i, j) at
    /// (i, j)) of output pixel `(i, j)`, or `None` if it has none.
    pub fn source_of(&self, i: usize, j: usize) -> Option<Vec2> {
        if i >= self.undistorted.width as usize {
            return None;
        }
        let m = self.map.get(j * self.undistorted.width as usize + i)?;
        (!m[0].is_nan()).then(|| Vec2::new(m[0] as f64, m[1] as f64))
    }

    /// Remaps a distorted image (gray or RGB, the source camera's size) to
    /// the undistorted camera, bilinearly.
    pub fn remap(&self, image: &Image) -> Result<Image, CameraError> {
        let (w, h) = (image.width(), image.height());
        if w as u64 != self.distorted.width || h as u64 != self.distorted.height {
            return Err(CameraError::InvalidParam {
                name: "image size".into(),
                value: f64::NAN,
                reason: format!(
                    "image is {w}x{h} but the distorted camera is {}x{}",
                    self.distorted.width, self.distorted.height
                ),
            });
        }
        let ch = image.channels();
        let (ow, oh) = (self.undistorted.width as usize, self.undistorted.height as usize);
        let src = image.data();
        let mut out = vec![self.fill; ow * oh * ch];
        for (k, m) in self.map.iter().enumerate() {
            if m[0].is_nan() {
                continue;
            }
            // Invariant: map entries are clamped to [0, w-1] x [0, h-1].
            let (x, y) = (m[0] as f64, m[1] as f64);
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (ax, ay) = (x - x0 as f64, y - y0 as f64);
            for c in 0..ch {
                let at = |xx: usize, yy: usize| src.get((yy * w + xx) * ch + c).copied().unwrap_or(0) as f64;
                let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
                let bot = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
                let v = top * (1.0 - ay) + bot * ay;
                if let Some(o) = out.get_mut(k * ch + c) {
                    *o = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        Image::from_vec(ow, oh, ch, out).map_err(|e| CameraError::InvalidParam {
            name: "image".into(),
            value: f64::NAN,
            reason: e.to_string(),
        })
    }

    /// Distorted pixels -> pixels of the undistorted camera (`None` where
    /// unprojection fails).
    pub fn undistort_points(&self, points: &[Vec2]) -> Vec<Option<Vec2>> {
        undistort_points(&self.distorted, &self.undistorted, points)
    }

    /// Pixels of the undistorted camera -> distorted pixels.
    pub fn distort_points(&self, points: &[Vec2]) -> Vec<Option<Vec2>> {
        undistort_points(&self.undistorted, &self.distorted, points)
    }

    /// The pixel convention the map was built in.
    pub fn pixel_convention(&self) -> PixelConvention {
        self.convention
    }
}

/// Pixels of `from` -> pixels of `to` through normalised coordinates
/// (`None` where `from` cannot unproject the pixel). Both cameras must use
/// the same pixel convention.
pub fn undistort_points(from: &Camera, to: &Camera, points: &[Vec2]) -> Vec<Option<Vec2>> {
    points.iter().map(|p| from.cam_from_img(p).map(|uv| to.img_from_normalized(&uv))).collect()
}

/// Distorted pixels -> normalised coordinates (`x/z, y/z`).
pub fn normalize_points(camera: &Camera, points: &[Vec2]) -> Vec<Option<Vec2>> {
    points.iter().map(|p| camera.cam_from_img(p)).collect()
}

/// True if `camera` needs no undistortion (a pinhole model or all-zero
/// distortion).
pub fn is_undistorted(camera: &Camera) -> bool {
    matches!(camera.model, CameraModelId::SimplePinhole | CameraModelId::Pinhole) || !camera.has_distortion()
}

//! COLMAP camera models with COLMAP's ids, names and parameter order:
//! projection, unprojection, analytic Jacobians, undistortion, camera files
//! and presets.
//!
//! * [`Camera`]: model + size + parameters, with projection
//!   ([`Camera::img_from_cam`]), unprojection ([`Camera::cam_from_img`]) and
//!   Jacobians ([`Camera::img_from_cam_with_jacobians`]); the maths is in
//!   [`models`].
//! * [`undistort`]: remap maps from a distorted camera to a pinhole one.
//! * [`mod@file`]: reading/writing camera files (flat YAML, TOML-style, ORB-SLAM).
//! * [`presets`]: published calibrations (TUM fr1/2/3, KITTI-984 video).
//!
//! Pixel convention: the camera model itself is convention-free (pixels are
//! whatever the principal point was calibrated in). Where a convention
//! matters (rescaling, undistortion's sampling grid), it is explicit as a
//! [`PixelConvention`]; COLMAP's (pixel `(i, j)` covers `[i, i+1) x [j, j+1)`,
//! its centre at `(i + 0.5, j + 0.5)`) is the default of [`Camera::scaled`].
//! OpenCV/TUM calibrations put pixel centres at integer coordinates.

pub mod file;
pub mod model_id;
pub mod models;
pub mod presets;
pub mod undistort;

pub use colslam_geometry::{Vec2, Vec3};
pub use model_id::CameraModelId;
pub use models::{MAX_PARAMS, Projection, UNDISTORT_TOLERANCE};

use models::Intrinsics;
use std::path::PathBuf;

/// A principal point may lie at most this many image sizes outside the
/// image before [`Camera::validate`] rejects it (catches swapped or
/// mis-scaled parameters without rejecting off-centre crops).
pub const MAX_PRINCIPAL_POINT_OUTSIDE: f64 = 1.0;

/// Errors of the camera layer.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The parameter vector has the wrong length for the model.
    #[error("camera model {model} takes {expected} parameters ({names}), got {got}")]
    ParamCount {
        /// Model name.
        model: &'static str,
        /// Expected count.
        expected: usize,
        /// Parameter names in order.
        names: &'static str,
        /// Given count.
        got: usize,
    },
    /// Unknown model id or name.
    #[error("unknown camera model {0:?}")]
    UnknownModel(String),
    /// A parameter is out of its valid range.
    #[error("camera parameter {name} = {value} is invalid: {reason}")]
    InvalidParam {
        /// Parameter name.
        name: String,
        /// Its value.
        value: f64,
        /// Why.
        reason: String,
    },
    /// A camera file could not be read or written.
    #[error("{path}: {action}")]
    Io {
        /// The file.
        path: PathBuf,
        /// "cannot read" / "cannot write".
        action: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
    /// A camera file has a bad, missing or out-of-range entry.
    #[error("{path}: key `{key}`: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// The key concerned (e.g. `fx`, `model`, `width`).
        key: String,
        /// What is wrong.
        reason: String,
    },
}

/// How pixel coordinates relate to pixel indices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PixelConvention {
    /// COLMAP: the image spans `[0, w] x [0, h]`; pixel `(i, j)` has its
    /// centre at `(i + 0.5, j + 0.5)`.
    #[default]
    Colmap,
    /// OpenCV / TUM / ORB-SLAM: pixel `(i, j)` has its centre at `(i, j)`;
    /// the image spans `[-0.5, w - 0.5] x [-0.5, h - 0.5]`.
    OpenCv,
}

impl PixelConvention {
    /// Coordinate of the centre of pixel index `i` along one axis.
    pub fn center_of(self, i: f64) -> f64 {
        match self {
            Self::Colmap => i + 0.5,
            Self::OpenCv => i,
        }
    }

    /// Offset to add to a coordinate in `self` to express it in `other`.
    pub fn offset_to(self, other: PixelConvention) -> f64 {
        other.center_of(0.0) - self.center_of(0.0)
    }
}

/// A camera: model, image size in pixels and parameters in COLMAP order.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// The model.
    pub model: CameraModelId,
    /// Image width in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// Parameters in COLMAP order (see [`CameraModelId::param_names`]).
    pub params: Vec<f64>,
}

impl Camera {
    /// Builds a camera, checking the parameter count (not the values; see
    /// [`Camera::validate`]).
    pub fn new(model: CameraModelId, width: u64, height: u64, params: Vec<f64>) -> Result<Self, CameraError> {
        if params.len() != model.num_params() {
            return Err(CameraError::ParamCount {
                model: model.name(),
                expected: model.num_params(),
                names: model.param_names(),
                got: params.len(),
            });
        }
        Ok(Self { model, width, height, params })
    }

    /// SIMPLE_PINHOLE camera `f, cx, cy`.
    pub fn simple_pinhole(width: u64, height: u64, f: f64, cx: f64, cy: f64) -> Self {
        Self { model: CameraModelId::SimplePinhole, width, height, params: vec![f, cx, cy] }
    }

    /// PINHOLE camera `fx, fy, cx, cy`.
    pub fn pinhole(width: u64, height: u64, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { model: CameraModelId::Pinhole, width, height, params: vec![fx, fy, cx, cy] }
    }

    fn intrinsics(&self) -> Intrinsics {
        Intrinsics::new(self.model, &self.params)
    }

    fn param(&self, idx: Option<&usize>) -> f64 {
        idx.and_then(|&i| self.params.get(i)).copied().unwrap_or(f64::NAN)
    }

    /// Focal length along x in pixels (`f` for single-focal models; NaN if
    /// the parameter vector is malformed).
    pub fn focal_x(&self) -> f64 {
        self.param(self.model.focal_length_idxs().first())
    }

    /// Focal length along y in pixels (`f` for single-focal models).
    pub fn focal_y(&self) -> f64 {
        self.param(self.model.focal_length_idxs().last())
    }

    /// Mean focal length in pixels.
    pub fn mean_focal(&self) -> f64 {
        0.5 * (self.focal_x() + self.focal_y())
    }

    /// Principal point `(cx, cy)` in pixels.
    pub fn principal_point(&self) -> Vec2 {
        let idx = self.model.principal_point_idxs();
        Vec2::new(self.param(idx.first()), self.param(idx.last()))
    }

    /// The extra (distortion) parameters in COLMAP order (empty if the
    /// parameter vector is too short).
    pub fn extra_params(&self) -> &[f64] {
        let idx = self.model.extra_params_idxs();
        match (idx.first(), idx.last()) {
            (Some(&a), Some(&b)) => self.params.get(a..=b).unwrap_or(&[]),
            _ => &[],
        }
    }

    /// Sets the focal length(s): both `fx` and `fy` for two-focal models.
    pub fn set_focal(&mut self, fx: f64, fy: f64) {
        let idx = self.model.focal_length_idxs();
        match idx {
            [f] => {
                if let Some(p) = self.params.get_mut(*f) {
                    *p = 0.5 * (fx + fy);
                }
            }
            _ => {
                for (&i, v) in idx.iter().zip([fx, fy]) {
                    if let Some(p) = self.params.get_mut(i) {
                        *p = v;
                    }
                }
            }
        }
    }

    /// Sets the principal point.
    pub fn set_principal_point(&mut self, c: Vec2) {
        for (&i, v) in self.model.principal_point_idxs().iter().zip([c.x, c.y]) {
            if let Some(p) = self.params.get_mut(i) {
                *p = v;
            }
        }
    }

    /// True if any distortion parameter is non-zero.
    pub fn has_distortion(&self) -> bool {
        self.extra_params().iter().any(|&k| k != 0.0)
    }

    /// This camera with a radial distortion term at 0, for bundle
    /// adjustment to estimate: a pinhole becomes the same camera in the
    /// model with that term (PINHOLE: OPENCV, SIMPLE_PINHOLE:
    /// SIMPLE_RADIAL); a model with distortion terms is returned as it is.
    pub fn with_radial_term(&self) -> Self {
        let (model, extra): (CameraModelId, &[f64]) = match self.model {
            CameraModelId::Pinhole => (CameraModelId::OpenCv, &[0.0; 4]),
            CameraModelId::SimplePinhole => (CameraModelId::SimpleRadial, &[0.0]),
            _ => return self.clone(),
        };
        // The pinhole's parameters lead both models' in the same order.
        Self { model, params: [self.params.as_slice(), extra].concat(), ..*self }
    }

    /// This SIMPLE_RADIAL camera as RADIAL with its second radial term at 0
    /// (the one-term fit of a lens that needs two, for bundle adjustment to
    /// extend); any other model is returned as it is.
    pub fn with_second_radial_term(&self) -> Self {
        if self.model != CameraModelId::SimpleRadial {
            return self.clone();
        }
        // SIMPLE_RADIAL's f, cx, cy, k lead RADIAL's f, cx, cy, k1, k2.
        Self { model: CameraModelId::Radial, params: [self.params.as_slice(), &[0.0]].concat(), ..*self }
    }

    /// Checks parameter count, finiteness, positive focal length(s),
    /// positive size and a principal point within
    /// [`MAX_PRINCIPAL_POINT_OUTSIDE`] image sizes of the image.
    pub fn validate(&self) -> Result<(), CameraError> {
        if self.params.len() != self.model.num_params() {
            return Err(CameraError::ParamCount {
                model: self.model.name(),
                expected: self.model.num_params(),
                names: self.model.param_names(),
                got: self.params.len(),
            });
        }
        let invalid = |name: &str, value: f64, reason: &str| CameraError::InvalidParam {
            name: name.to_string(),
            value,
            reason: reason.to_string(),
        };
        if self.width == 0 {
            return Err(invalid("width", 0.0, "image width must be positive"));
        }
        if self.height == 0 {
            return Err(invalid("height", 0.0, "image height must be positive"));
        }
        for (name, &v) in self.model.param_name_list().zip(&self.params) {
            if !v.is_finite() {
                return Err(invalid(name, v, "must be finite"));
            }
        }
        for &i in self.model.focal_length_idxs() {
            let v = self.param(Some(&i));
            if !models::is_positive(v) {
                let name = self.model.param_name_list().nth(i).unwrap_or("f");
                return Err(invalid(name, v, "focal length must be positive"));
            }
        }
        let c = self.principal_point();
        let (w, h) = (self.width as f64, self.height as f64);
        let m = MAX_PRINCIPAL_POINT_OUTSIDE;
        if c.x < -m * w || c.x > (1.0 + m) * w {
            return Err(invalid("cx", c.x, &format!("principal point is far outside the image (width {w})")));
        }
        if c.y < -m * h || c.y > (1.0 + m) * h {
            return Err(invalid("cy", c.y, &format!("principal point is far outside the image (height {h})")));
        }
        Ok(())
    }

    /// Camera-frame 3D point -> pixel; `None` if `z <= 0` (or the result is
    /// not finite).
    pub fn img_from_cam(&self, p: &Vec3) -> Option<Vec2> {
        self.intrinsics().img_from_cam(p)
    }

    /// Normalised image-plane coordinates `(x/z, y/z)` -> pixel (distortion
    /// then K).
    pub fn img_from_normalized(&self, uv: &Vec2) -> Vec2 {
        self.intrinsics().img_from_normalized(uv)
    }

    /// Pixel -> normalised image-plane coordinates `(x/z, y/z)` by Newton
    /// iteration on the analytic distortion Jacobian (relative tolerance
    /// [`UNDISTORT_TOLERANCE`]); `None` if it does not converge, if the pixel
    /// lies beyond a fold of the distortion, or (fisheye) if its ray is 90°
    /// or more off the optical axis.
    pub fn cam_from_img(&self, px: &Vec2) -> Option<Vec2> {
        self.intrinsics().cam_from_img(px)
    }

    /// Pixel -> unit bearing vector in the camera frame (see
    /// [`Camera::cam_from_img`]).
    pub fn bearing_from_img(&self, px: &Vec2) -> Option<Vec3> {
        self.cam_from_img(px).map(|uv| Vec3::new(uv.x, uv.y, 1.0).normalize())
    }

    /// Projection with Jacobians w.r.t. the camera-frame point and all
    /// parameters (for bundle adjustment; does not allocate). `None` if
    /// `z <= 0` or anything is non-finite.
    pub fn img_from_cam_with_jacobians(&self, p: &Vec3) -> Option<Projection> {
        self.intrinsics().img_from_cam_with_jacobians(p)
    }

    /// Projection with the Jacobian w.r.t. the camera-frame point only (for
    /// bundle adjustment with constant intrinsics; the same pixel and
    /// `d_point` as [`Camera::img_from_cam_with_jacobians`]). `None` if
    /// `z <= 0` or anything is non-finite.
    pub fn img_from_cam_with_point_jacobian(&self, p: &Vec3) -> Option<(Vec2, nalgebra::Matrix2x3<f64>)> {
        self.intrinsics().img_from_cam_with_point_jacobian(p)
    }

    /// The camera for images resized by `factor` (e.g. 0.5 for half size),
    /// in COLMAP's pixel convention (pixel centres at `i + 0.5`), as COLMAP's
    /// `Camera::Rescale`: the new size is `round(factor * size)` (at least
    /// 1), and focal lengths and principal point are multiplied by the
    /// per-axis ratio new/old size (single-focal models use the mean ratio).
    /// Distortion parameters act on normalised coordinates and are kept.
    pub fn scaled(&self, factor: f64) -> Result<Camera, CameraError> {
        self.scaled_with_convention(factor, PixelConvention::Colmap)
    }

    /// Like [`Camera::scaled`] in the given pixel convention. For
    /// [`PixelConvention::OpenCv`] the principal point maps as
    /// `c' = (c + 0.5) s - 0.5`.
    pub fn scaled_with_convention(&self, factor: f64, convention: PixelConvention) -> Result<Camera, CameraError> {
        if !(factor.is_finite() && factor > 0.0) {
            return Err(CameraError::InvalidParam {
                name: "scale factor".into(),
                value: factor,
                reason: "must be positive and finite".into(),
            });
        }
        let new_w = ((self.width as f64) * factor).round().max(1.0);
        let new_h = ((self.height as f64) * factor).round().max(1.0);
        let sx = new_w / self.width.max(1) as f64;
        let sy = new_h / self.height.max(1) as f64;
        let mut out = self.clone();
        out.width = new_w as u64;
        out.height = new_h as u64;
        if self.model.has_single_focal() {
            let f = self.focal_x() * 0.5 * (sx + sy);
            out.set_focal(f, f);
        } else {
            out.set_focal(self.focal_x() * sx, self.focal_y() * sy);
        }
        let o = convention.offset_to(PixelConvention::Colmap);
        let c = self.principal_point();
        out.set_principal_point(Vec2::new((c.x + o) * sx - o, (c.y + o) * sy - o));
        Ok(out)
    }

    /// The same camera with its principal point re-expressed from pixel
    /// convention `from` to `to` (a shift by ±0.5 px).
    pub fn convert_pixel_convention(&self, from: PixelConvention, to: PixelConvention) -> Camera {
        let o = from.offset_to(to);
        let mut out = self.clone();
        out.set_principal_point(self.principal_point() + Vec2::new(o, o));
        out
    }

    /// The pinhole part of the camera as a 3x3 calibration matrix K.
    pub fn calibration_matrix(&self) -> colslam_geometry::Mat3 {
        let c = self.principal_point();
        colslam_geometry::Mat3::new(self.focal_x(), 0.0, c.x, 0.0, self.focal_y(), c.y, 0.0, 0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_radial_term_keeps_the_pinhole_and_starts_at_zero() {
        let c = Camera::pinhole(640, 480, 500.0, 510.0, 320.0, 240.0).with_radial_term();
        assert_eq!(c.model, CameraModelId::OpenCv);
        assert_eq!(c.params, [500.0, 510.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0]);
        c.validate().unwrap();
        let s = Camera::simple_pinhole(640, 480, 500.0, 320.0, 240.0).with_radial_term();
        assert_eq!((s.model, s.params.as_slice()), (CameraModelId::SimpleRadial, &[500.0, 320.0, 240.0, 0.0][..]));
        assert_eq!(s.with_radial_term(), s, "a model with distortion terms stays as it is");
        let r = Camera { params: vec![500.0, 320.0, 240.0, 0.05], ..s.clone() }.with_second_radial_term();
        assert_eq!((r.model, r.params.as_slice()), (CameraModelId::Radial, &[500.0, 320.0, 240.0, 0.05, 0.0][..]));
        assert_eq!(r.with_second_radial_term(), r, "only SIMPLE_RADIAL gains a term");
    }

    #[test]
    fn accessors_and_validate() {
        let c = Camera::pinhole(640, 480, 500.0, 510.0, 320.0, 240.0);
        assert_eq!(c.focal_x(), 500.0);
        assert_eq!(c.focal_y(), 510.0);
        assert_eq!(c.principal_point(), Vec2::new(320.0, 240.0));
        assert!(!c.has_distortion());
        c.validate().unwrap();
        let mut bad = c.clone();
        bad.params[1] = -1.0;
        assert!(bad.validate().unwrap_err().to_string().contains("fy"));
        let mut bad = c.clone();
        bad.params[2] = f64::NAN;
        assert!(bad.validate().unwrap_err().to_string().contains("cx"));
        let mut bad = c.clone();
        bad.params[3] = 5000.0;
        assert!(bad.validate().unwrap_err().to_string().contains("far outside"));
        let mut bad = c.clone();
        bad.width = 0;
        assert!(bad.validate().unwrap_err().to_string().contains("width"));
        let mut bad = c;
        bad.params.pop();
        assert!(bad.validate().is_err());
        // Malformed parameter vectors give None, not a panic.
        assert!(bad.img_from_cam(&Vec3::new(0.0, 0.0, 1.0)).is_none());
        assert!(bad.img_from_cam_with_jacobians(&Vec3::new(0.0, 0.0, 1.0)).is_none());
    }

    #[test]
    fn scaled_follows_pixel_conventions() {
        let c = Camera::simple_pinhole(640, 480, 500.0, 320.0, 240.0);
        let h = c.scaled(0.5).unwrap();
        assert_eq!((h.width, h.height), (320, 240));
        assert_eq!(h.params, vec![250.0, 160.0, 120.0]);
        // OpenCV convention (Strecha camera.yaml): c' = (c + 0.5)/2 - 0.5.
        let o = Camera::pinhole(3072, 2048, 2759.48, 2764.16, 1520.69, 1006.81)
            .scaled_with_convention(0.5, PixelConvention::OpenCv)
            .unwrap();
        let want = [1379.74, 1382.08, 760.095, 503.155];
        for (a, b) in o.params.iter().zip(want) {
            assert!((a - b).abs() < 1e-9, "{a} vs {b}");
        }
        assert!(c.scaled(0.0).is_err());
        assert!(c.scaled(f64::NAN).is_err());
        // A pixel centre maps to the same ray before and after scaling.
        let uv = Vec2::new(0.1, -0.2);
        let p = c.img_from_normalized(&uv);
        let q = h.img_from_normalized(&uv);
        assert!(((p.x + 0.5) * 0.5 - (q.x + 0.5)).abs() > 0.1); // conventions differ
        assert!((p.x * 0.5 - q.x).abs() < 1e-12);
        let back = c.convert_pixel_convention(PixelConvention::OpenCv, PixelConvention::Colmap);
        assert_eq!(back.principal_point(), Vec2::new(320.5, 240.5));
    }
}

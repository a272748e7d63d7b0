//! Published calibrations, by name.
//!
//! * `tum-fr1`, `tum-fr2`: TUM RGB-D benchmark (Sturm et al., IROS 2012),
//!   Kinect colour cameras at 640x480, from the dataset's "intrinsic camera
//!   calibration" page (OpenCV plumb-bob `d0..d4 = k1 k2 p1 p2 k3`), as
//!   FULL_OPENCV with `k4 = k5 = k6 = 0` because `k3 != 0`. The calibration
//!   is in OpenCV's pixel convention (pixel centres at integer coordinates).
//! * `tum-fr3`: the fr3 colour images are already undistorted, so PINHOLE.
//! * `kitti-984`: twitchslam's `test_kitti984.mp4` (1242x375), focal 984 px
//!   with the principal point at the image centre `(w/2, h/2)` (COLMAP's
//!   convention; twitchslam itself uses integer `H//2 = 187`), SIMPLE_PINHOLE.

use crate::{Camera, CameraModelId};

/// Names accepted by [`preset`].
const NAMES: [&str; 4] = ["tum-fr1", "tum-fr2", "tum-fr3", "kitti-984"];

/// The preset names, in a stable order.
pub fn preset_names() -> &'static [&'static str] {
    &NAMES
}

/// The camera of a preset (case-insensitive; `_` is accepted for `-`), or
/// `None` for an unknown name.
pub fn preset(name: &str) -> Option<Camera> {
    let n = name.trim().to_ascii_lowercase().replace('_', "-");
    let (model, width, height, params): (CameraModelId, u64, u64, Vec<f64>) = match n.as_str() {
        "tum-fr1" => (
            CameraModelId::FullOpenCv,
            640,
            480,
            vec![517.3, 516.5, 318.6, 255.3, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633, 0.0, 0.0, 0.0],
        ),
        "tum-fr2" => (
            CameraModelId::FullOpenCv,
            640,
            480,
            vec![520.9, 521.0, 325.1, 249.7, 0.2312, -0.7849, -0.0033, -0.0001, 0.9172, 0.0, 0.0, 0.0],
        ),
        "tum-fr3" => (CameraModelId::Pinhole, 640, 480, vec![535.4, 539.2, 320.1, 247.6]),
        "kitti-984" => (CameraModelId::SimplePinhole, 1242, 375, vec![984.0, 621.0, 187.5]),
        _ => return None,
    };
    Some(Camera { model, width, height, params })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Vec2;

    #[test]
    fn presets_validate_and_unproject_whole_image() {
        for name in preset_names() {
            let cam = preset(name).unwrap_or_else(|| panic!("{name}"));
            cam.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            for (x, y) in [(0.0, 0.0), (cam.width as f64, cam.height as f64), (0.0, cam.height as f64)] {
                let px = Vec2::new(x, y);
                let uv = cam.cam_from_img(&px).unwrap_or_else(|| panic!("{name}: corner ({x}, {y})"));
                assert!((cam.img_from_normalized(&uv) - px).norm() < 1e-10);
            }
        }
        assert_eq!(preset("TUM_FR1").map(|c| c.model), Some(CameraModelId::FullOpenCv));
        assert_eq!(preset("tum-fr3").map(|c| c.has_distortion()), Some(false));
        assert!(preset("kitti").is_none());
    }
}

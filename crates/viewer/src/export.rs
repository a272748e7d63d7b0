//! Export of the shown reconstruction: COLMAP binary/text, PLY, TUM.

use colslam_scene::{ModelFormat, Reconstruction, SceneError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Formats the page's Export button offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    /// COLMAP binary model folder.
    ColmapBinary,
    /// COLMAP text model folder.
    ColmapText,
    /// Binary PLY point cloud with colours.
    Ply,
    /// TUM trajectory: `timestamp tx ty tz qx qy qz qw` per registered image
    /// (camera-to-world pose).
    Tum,
}

impl ExportFormat {
    /// Parses the page's names: `colmap-bin`, `colmap-txt`, `ply`, `tum`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "colmap-bin" => Some(Self::ColmapBinary),
            "colmap-txt" => Some(Self::ColmapText),
            "ply" => Some(Self::Ply),
            "tum" => Some(Self::Tum),
            _ => None,
        }
    }
}

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// Writing the model or point cloud failed.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// Writing the trajectory failed.
    #[error("{path}: cannot write")]
    Io {
        /// The target file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

/// Writes `rec` to `path` in `format` (a folder for COLMAP models, a file
/// otherwise); files are written atomically.
pub fn export_reconstruction(rec: &Reconstruction, path: &Path, format: ExportFormat) -> Result<(), ExportError> {
    match format {
        ExportFormat::ColmapBinary => colslam_scene::write_model(rec, path, ModelFormat::Binary)?,
        ExportFormat::ColmapText => colslam_scene::write_model(rec, path, ModelFormat::Text)?,
        ExportFormat::Ply => colslam_scene::write_ply(rec, path)?,
        ExportFormat::Tum => {
            let text = tum_trajectory(rec);
            colslam_image::write_atomic(path, text.as_bytes())
                .map_err(|source| ExportError::Io { path: path.to_path_buf(), source })?;
        }
    }
    Ok(())
}

/// The TUM trajectory of the registered images in registration order. The
/// timestamp is the image name's stem when it is a number (TUM, EuRoC
/// names), else the registration index.
pub fn tum_trajectory(rec: &Reconstruction) -> String {
    let mut out = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for (order, id) in rec.registered_image_ids().iter().enumerate() {
        let Some(img) = rec.image(*id) else { continue };
        let stem = Path::new(&img.name).file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let stamp = match stem.parse::<f64>() {
            Ok(t) if t.is_finite() => stem.to_string(),
            _ => order.to_string(),
        };
        let world_from_cam = img.cam_from_world.inverse();
        let t = world_from_cam.translation;
        let [qx, qy, qz, qw] = world_from_cam.quat_xyzw();
        // Writing into a String cannot fail.
        let _ = writeln!(out, "{stamp} {} {} {} {qx} {qy} {qz} {qw}", t.x, t.y, t.z);
    }
    out
}

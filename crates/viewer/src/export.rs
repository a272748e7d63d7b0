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
        // The stem's own text keeps every digit of the name.
        let stamp = match name_timestamp(&img.name) {
            Some(_) => Path::new(&img.name).file_stem().and_then(|s| s.to_str()).unwrap_or("").to_string(),
            None => order.to_string(),
        };
        let world_from_cam = img.cam_from_world.inverse();
        let t = world_from_cam.translation;
        let [qx, qy, qz, qw] = world_from_cam.quat_xyzw();
        // Writing into a String cannot fail.
        let _ = writeln!(out, "{stamp} {} {} {} {qx} {qy} {qz} {qw}", t.x, t.y, t.z);
    }
    out
}

/// The timestamp an image name carries: its stem when that is a finite
/// number (TUM, EuRoC names), else `None`.
pub(crate) fn name_timestamp(name: &str) -> Option<f64> {
    let stem = Path::new(name).file_stem()?.to_str()?;
    stem.parse::<f64>().ok().filter(|t| t.is_finite())
}

/// The registered images of `rec` as a trajectory (sorted by time), and the
/// image id of each pose: the timestamps `stamp_of` knows by image name (a
/// run knows its frames' times), else those of [`tum_trajectory`].
pub(crate) fn model_trajectory_timed(
    rec: &Reconstruction,
    stamp_of: &dyn Fn(&str) -> Option<f64>,
) -> (colslam_eval::Trajectory, Vec<u32>) {
    let mut rows: Vec<(f64, u32, colslam_geometry::Rigid3)> = rec
        .registered_image_ids()
        .iter()
        .enumerate()
        .filter_map(|(order, id)| {
            let img = rec.image(*id)?;
            let t = stamp_of(&img.name).or_else(|| name_timestamp(&img.name)).unwrap_or(order as f64);
            Some((t, id.0, img.cam_from_world))
        })
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    let stamps = rows.iter().map(|r| r.0).collect();
    let poses: Vec<_> = rows.iter().map(|r| r.2).collect();
    let ids = rows.iter().map(|r| r.1).collect();
    (colslam_eval::Trajectory::from_cam_from_world(stamps, &poses), ids)
}

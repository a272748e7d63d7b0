//! Auto-detection of a source's layout from its path.

use std::path::{Path, PathBuf};

use crate::{SourceError, is_image_file, is_video_file};

/// TUM RGB-D image list.
pub(crate) const TUM_LIST: &str = "rgb.txt";
/// EuRoC image list inside a camera folder.
pub(crate) const EUROC_LIST: &str = "data.csv";
/// EuRoC camera folders, relative to the dataset root, in search order.
pub(crate) const EUROC_CAM_DIRS: [&str; 2] = ["mav0/cam0", "cam0"];
/// KITTI timestamps file.
pub(crate) const KITTI_TIMES: &str = "times.txt";
/// KITTI calibration file (projection matrices, not a camera file).
pub(crate) const KITTI_CALIB: &str = "calib.txt";
/// KITTI image folders in preference order: left gray, then left colour.
pub(crate) const KITTI_IMAGE_DIRS: [&str; 2] = ["image_0", "image_2"];
/// Extensions of files that are certainly not videos (so they are not handed
/// to ffprobe): list, calibration and text files.
const TEXT_EXTENSIONS: [&str; 7] = ["txt", "csv", "yaml", "yml", "toml", "json", "md"];

/// The layout of a source, as found by [`detect_layout`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Layout {
    /// A video file.
    Video {
        /// The file.
        file: PathBuf,
    },
    /// A TUM RGB-D folder.
    Tum {
        /// The folder holding `rgb.txt`; image paths are relative to it.
        dir: PathBuf,
        /// The `rgb.txt` file.
        list: PathBuf,
    },
    /// A EuRoC MAV folder.
    Euroc {
        /// The dataset root (holding `mav0/` or `cam0/`), or the camera folder
        /// when `data.csv` itself was given.
        root: PathBuf,
        /// The camera folder (`data.csv`, `data/`, `sensor.yaml`).
        cam_dir: PathBuf,
        /// The `data.csv` file.
        list: PathBuf,
    },
    /// A KITTI odometry sequence.
    Kitti {
        /// The sequence folder.
        dir: PathBuf,
        /// `image_0/` or `image_2/`.
        image_dir: PathBuf,
        /// `times.txt`.
        times: PathBuf,
    },
    /// A plain folder of images.
    Folder {
        /// The folder.
        dir: PathBuf,
    },
}

/// Detects the layout at `path`, in this order: a video file (by extension,
/// or any regular file that is neither an image nor a text/list file); a
/// folder with `rgb.txt` (TUM); with `mav0/cam0/data.csv` or `cam0/data.csv`
/// (EuRoC); with `image_0/` or `image_2/` and `times.txt` (KITTI); otherwise
/// a plain image folder. A path to `rgb.txt`, `data.csv` or `times.txt`
/// itself selects that layout.
pub fn detect_layout(path: &Path) -> Result<Layout, SourceError> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => SourceError::NotFound { path: path.to_path_buf() },
        _ => SourceError::io(path, e),
    })?;
    if meta.is_dir() {
        return Ok(detect_folder(path));
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    if name == TUM_LIST {
        return Ok(Layout::Tum { dir: parent, list: path.to_path_buf() });
    }
    if name == EUROC_LIST {
        return Ok(Layout::Euroc { root: parent.clone(), cam_dir: parent, list: path.to_path_buf() });
    }
    if name == KITTI_TIMES {
        return match detect_folder(&parent) {
            l @ Layout::Kitti { .. } => Ok(l),
            _ => Err(SourceError::Layout {
                path: path.to_path_buf(),
                reason: format!(
                    "a KITTI times.txt needs an {} or {} folder beside it",
                    KITTI_IMAGE_DIRS[0], KITTI_IMAGE_DIRS[1]
                ),
            }),
        };
    }
    if is_video_file(path) {
        return Ok(Layout::Video { file: path.to_path_buf() });
    }
    if is_image_file(path) {
        return Err(SourceError::SingleImage { path: path.to_path_buf() });
    }
    let is_text = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| TEXT_EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)));
    if is_text {
        return Err(SourceError::Layout {
            path: path.to_path_buf(),
            reason: "is a text file, neither a video nor a sequence folder (pass the folder, rgb.txt, data.csv or times.txt)".into(),
        });
    }
    Ok(Layout::Video { file: path.to_path_buf() })
}

fn detect_folder(dir: &Path) -> Layout {
    let list = dir.join(TUM_LIST);
    if list.is_file() {
        return Layout::Tum { dir: dir.to_path_buf(), list };
    }
    for cam in EUROC_CAM_DIRS {
        let cam_dir = dir.join(cam);
        let list = cam_dir.join(EUROC_LIST);
        if list.is_file() {
            return Layout::Euroc { root: dir.to_path_buf(), cam_dir, list };
        }
    }
    let times = dir.join(KITTI_TIMES);
    if times.is_file()
        && let Some(image_dir) = KITTI_IMAGE_DIRS.iter().map(|d| dir.join(d)).find(|d| d.is_dir())
    {
        return Layout::Kitti { dir: dir.to_path_buf(), image_dir, times };
    }
    Layout::Folder { dir: dir.to_path_buf() }
}

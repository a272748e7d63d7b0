//! Helpers shared by every crate's tests and by the bench lab
//! (`colslam-bench`): where the datasets and the Python peer environment are.
//!
//! * Datasets are found through `COLSLAM_DATA`, else the first existing of
//!   `./datasets`, `../shared/datasets` (both relative to the current
//!   directory) and `../shared/datasets` beside the workspace.
//! * Cross-checks against Python peers (pycolmap, evo, OpenCV) use the venv
//!   made by `scripts/setup-peers.sh`: `COLSLAM_PYTHON` naming an
//!   interpreter, else the first `.venv/bin/python` in the current directory
//!   or one above it, beside the executable or one above it, else in the
//!   workspace.
//!
//! [`find_data_dir`], [`find_upwards`] and [`find_peer_python`] only look and
//! return what they found; the bench lab reports their errors. The test
//! wrappers [`data_dir`], [`dataset`] and [`peer_python`] skip with a message
//! when something is absent, and fail in CI (`CI=true`) instead. Panicking is
//! the right failure mode for those: they run only inside tests.
//!
//! [`fuzz`] is the parsers' mutation fuzzer (see its docs).

use std::path::{Path, PathBuf};
use std::process::Command;

pub mod fuzz;

/// The workspace root (two levels above this crate).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."))
}

/// Why [`find_data_dir`] found no datasets folder.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DataDirError {
    /// `COLSLAM_DATA` is set but names no folder.
    #[error("COLSLAM_DATA={} is not a folder", .0.display())]
    EnvNotAFolder(PathBuf),
    /// None of the default places holds the folder (the places looked in).
    #[error("dataset folder not found (looked in {}); set COLSLAM_DATA", display_list(.0))]
    NotFound(Vec<PathBuf>),
}

fn display_list(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
}

/// The datasets folder: `COLSLAM_DATA`, else the first folder of
/// `./datasets`, `../shared/datasets` (relative to the current directory)
/// and `../shared/datasets` beside the workspace that exists.
pub fn find_data_dir() -> Result<PathBuf, DataDirError> {
    if let Some(d) = std::env::var_os("COLSLAM_DATA") {
        let d = PathBuf::from(d);
        return if d.is_dir() { Ok(d) } else { Err(DataDirError::EnvNotAFolder(d)) };
    }
    let candidates =
        [PathBuf::from("datasets"), PathBuf::from("../shared/datasets"), workspace_root().join("../shared/datasets")];
    candidates.iter().find(|d| d.is_dir()).cloned().ok_or_else(|| DataDirError::NotFound(candidates.to_vec()))
}

/// The first ancestor (itself included) of the current directory, else of the
/// executable, in which `rel` exists.
pub fn find_upwards(rel: impl AsRef<Path>) -> Option<PathBuf> {
    let rel = rel.as_ref();
    let starts = [std::env::current_dir().ok(), std::env::current_exe().ok()];
    starts.iter().flatten().flat_map(|s| s.ancestors()).find(|a| a.join(rel).exists()).map(Path::to_path_buf)
}

/// Where the peer venv's interpreter lies inside its folder's parent.
const VENV_PYTHON: &str = ".venv/bin/python";

/// Why [`find_peer_python`] found no interpreter.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PeerPythonError {
    /// `COLSLAM_PYTHON` names a path that does not exist (it may still be a
    /// command name on `PATH`, which is the caller's call).
    #[error("COLSLAM_PYTHON={} does not exist (run scripts/setup-peers.sh)", .0.display())]
    EnvMissing(PathBuf),
    /// No `.venv/bin/python` in any place looked in.
    #[error(
        "peer Python venv not found (.venv/bin/python in or above the current directory or the executable, or \
         in the workspace): run scripts/setup-peers.sh (or set COLSLAM_PYTHON)"
    )]
    NotFound,
}

/// The peer venv's Python interpreter: `COLSLAM_PYTHON` when it exists, else
/// the first `.venv/bin/python` found by [`find_upwards`], else the
/// workspace's. Whether it can import anything is not checked.
pub fn find_peer_python() -> Result<PathBuf, PeerPythonError> {
    if let Some(p) = std::env::var_os("COLSLAM_PYTHON") {
        let p = PathBuf::from(p);
        return if p.exists() { Ok(p) } else { Err(PeerPythonError::EnvMissing(p)) };
    }
    find_upwards(VENV_PYTHON)
        .map(|root| root.join(VENV_PYTHON))
        .or_else(|| Some(workspace_root().join(VENV_PYTHON)).filter(|p| p.exists()))
        .ok_or(PeerPythonError::NotFound)
}

/// True when running in CI (`CI=true`), where nothing may be skipped.
pub fn in_ci() -> bool {
    std::env::var("CI").map(|v| v == "true" || v == "1").unwrap_or(false)
}

fn skip_or_fail(what: &str) {
    if in_ci() {
        panic!("CI=true but {what}");
    }
    eprintln!("SKIPPED: {what}");
}

/// True when ffmpeg and ffprobe run (the video source needs both); outside
/// CI a missing ffmpeg skips the video tests with a message, in CI
/// (`CI=true`) it fails them.
pub fn have_ffmpeg() -> bool {
    let ok = ["ffmpeg", "ffprobe"]
        .iter()
        .all(|p| Command::new(p).arg("-version").output().map(|o| o.status.success()).unwrap_or(false));
    if !ok {
        skip_or_fail("ffmpeg/ffprobe are not installed");
    }
    ok
}

/// The KITTI clip's dataset folder (twitchslam's street video).
pub const KITTI_CLIP_FOLDER: &str = "twitchslam_kitti984";
/// The video inside [`KITTI_CLIP_FOLDER`].
pub const KITTI_CLIP_VIDEO: &str = "test_kitti984.mp4";

/// The KITTI clip's video file, or `None` (after a skip message, or a
/// failure in CI) when its dataset or ffmpeg is absent: reading it needs
/// both.
pub fn kitti_clip() -> Option<PathBuf> {
    let dir = dataset(KITTI_CLIP_FOLDER)?;
    have_ffmpeg().then(|| dir.join(KITTI_CLIP_VIDEO))
}

/// The datasets folder ([`find_data_dir`]), or `None` (after printing a skip
/// message) when absent outside CI.
pub fn data_dir() -> Option<PathBuf> {
    find_data_dir().map_err(|e| skip_or_fail(&e.to_string())).ok()
}

/// One dataset folder (e.g. `tum_fr1_rpy_sub`), or `None` when absent outside CI.
pub fn dataset(name: &str) -> Option<PathBuf> {
    let dir = data_dir()?.join(name);
    if dir.exists() {
        Some(dir)
    } else {
        skip_or_fail(&format!("dataset {} not found", dir.display()));
        None
    }
}

/// The peer Python interpreter ([`find_peer_python`]), if it can import every
/// module in `modules`; `None` (after a skip message) otherwise, outside CI.
pub fn peer_python(modules: &[&str]) -> Option<PathBuf> {
    let import = format!("import {}", if modules.is_empty() { "sys".to_string() } else { modules.join(", ") });
    let py = find_peer_python().map_err(|e| skip_or_fail(&e.to_string())).ok()?;
    let ok = Command::new(&py).args(["-c", &import]).output().map(|o| o.status.success()).unwrap_or(false);
    if ok {
        Some(py)
    } else {
        skip_or_fail(&format!("peer Python {} cannot `{import}` (run scripts/setup-peers.sh)", py.display()));
        None
    }
}

/// Runs a Python snippet or script with arguments in the peer environment and
/// returns its stdout; panics with stderr on failure.
pub fn run_python(py: &Path, args: &[&str]) -> String {
    let out = Command::new(py).args(args).output().expect("spawn python");
    assert!(out.status.success(), "python {:?} failed:\n{}", args, String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[cfg(test)]
crate::fuzz_allocator!();

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_workspace_upwards() {
        // Tests run in this crate's folder, two levels below the workspace.
        let found = find_upwards("crates/testutil/Cargo.toml").expect("an ancestor holds this crate");
        assert_eq!(found.canonicalize().unwrap(), workspace_root());
        assert_eq!(find_upwards("no/such/file/anywhere-9f1c"), None);
    }

    #[test]
    fn error_messages_name_the_variable_and_the_places() {
        let e = DataDirError::EnvNotAFolder(PathBuf::from("/nope"));
        assert_eq!(e.to_string(), "COLSLAM_DATA=/nope is not a folder");
        let e = DataDirError::NotFound(vec![PathBuf::from("datasets"), PathBuf::from("../shared/datasets")]);
        assert_eq!(
            e.to_string(),
            "dataset folder not found (looked in datasets, ../shared/datasets); set COLSLAM_DATA"
        );
        let e = PeerPythonError::EnvMissing(PathBuf::from("/nope/python"));
        assert_eq!(e.to_string(), "COLSLAM_PYTHON=/nope/python does not exist (run scripts/setup-peers.sh)");
        assert!(PeerPythonError::NotFound.to_string().contains("run scripts/setup-peers.sh (or set COLSLAM_PYTHON)"));
    }
}

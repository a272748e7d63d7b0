//! Test-only helpers shared by every crate's tests.
//!
//! * Datasets are found through `COLSLAM_DATA` (default `../shared/datasets`
//!   beside the workspace). When they are absent, data tests skip with a
//!   message; in CI (`CI=true`) a missing dataset fails the test instead.
//! * Cross-checks against Python peers (pycolmap, evo, OpenCV) use the venv
//!   made by `scripts/setup-peers.sh` (default `<workspace>/.venv`, or
//!   `COLSLAM_PYTHON` naming an interpreter). Same skip/fail rule.
//!
//! Panicking is the right failure mode here: these run only inside tests.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace root (two levels above this crate).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."))
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

/// The datasets folder, or `None` (after printing a skip message) when absent
/// outside CI.
pub fn data_dir() -> Option<PathBuf> {
    let dir = match std::env::var_os("COLSLAM_DATA") {
        Some(d) => PathBuf::from(d),
        None => workspace_root().join("../shared/datasets"),
    };
    if dir.is_dir() {
        Some(dir)
    } else {
        skip_or_fail(&format!("dataset folder {} not found (set COLSLAM_DATA)", dir.display()));
        None
    }
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

/// The peer Python interpreter, if it can import every module in `modules`;
/// `None` (after a skip message) otherwise, outside CI.
pub fn peer_python(modules: &[&str]) -> Option<PathBuf> {
    let py = match std::env::var_os("COLSLAM_PYTHON") {
        Some(p) => PathBuf::from(p),
        None => workspace_root().join(".venv/bin/python"),
    };
    let import = format!("import {}", if modules.is_empty() { "sys".to_string() } else { modules.join(", ") });
    let ok =
        py.exists() && Command::new(&py).args(["-c", &import]).output().map(|o| o.status.success()).unwrap_or(false);
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

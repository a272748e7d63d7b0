//! Input problems and terminal behaviour through the binary: a closed stdout
//! pipe ends a command quietly, OS errors are printed once, paths that exist
//! but are not what is expected are named for what they are, and a run in
//! which no frame could be read fails.

use std::path::Path;
use std::process::{Command, Stdio};

mod common;
use common::fails;

fn png(path: &Path, width: usize, height: usize) {
    std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
    colslam_image::Image::new(width, height, 1).write_png(path).expect("write png");
}

#[test]
fn closed_stdout_ends_quietly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = dir.path().join("seq");
    png(&seq.join("000.png"), 16, 12);
    // The reader is closed before the child starts, so its first write to
    // stdout fails with EPIPE (as in `colslam info SEQ | head -0`).
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["info", seq.to_str().expect("utf-8")])
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("run colslam");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "status {:?}, stderr: {stderr}", out.status);
    assert!(!stderr.contains("panicked") && !stderr.contains("Broken pipe"), "{stderr}");
}

/// Occurrences of `needle` in `hay`.
fn count(hay: &str, needle: &str) -> usize {
    hay.matches(needle).count()
}

#[test]
fn os_errors_are_printed_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("plain");
    std::fs::write(&file, "x").expect("write");
    // A path under a regular file: ENOTDIR.
    let under = file.join("seq");
    let err = fails(&["info", under.to_str().expect("utf-8")]);
    assert!(err.contains("plain/seq"), "{err}");
    assert_eq!(count(&err, "os error 20"), 1, "{err}");
    // A missing ground truth: ENOENT, from the eval crate.
    let gt = dir.path().join("missing-gt.txt");
    let err = fails(&["eval", "--gt", gt.to_str().expect("utf-8"), "--est", gt.to_str().expect("utf-8")]);
    assert!(err.contains("missing-gt.txt"), "{err}");
    assert_eq!(count(&err, "os error 2)"), 1, "{err}");
    // An output folder under a regular file.
    let seq = dir.path().join("seq");
    png(&seq.join("000.png"), 32, 24);
    let out = file.join("out");
    let err = fails(&["run", seq.to_str().expect("utf-8"), "-o", out.to_str().expect("utf-8")]);
    assert!(count(&err, "os error") <= 1, "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn a_run_that_reads_no_frame_fails() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = dir.path().join("broken");
    // Valid headers (the size is known) but no pixel data: every frame fails to decode.
    for i in 0..3 {
        let p = seq.join(format!("{i:03}.png"));
        png(&p, 32, 24);
        let bytes = std::fs::read(&p).expect("read");
        std::fs::write(&p, &bytes[..40]).expect("truncate");
    }
    let out = dir.path().join("out");
    let err = fails(&["run", seq.to_str().expect("utf-8"), "-o", out.to_str().expect("utf-8")]);
    assert!(err.contains("broken") && err.contains("no frame could be read") && err.contains("3 skipped"), "{err}");
    assert!(err.contains("000.png"), "the first failure is named: {err}");
}

#[test]
fn paths_that_exist_are_not_called_missing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = dir.path().join("tum");
    png(&seq.join("rgb/1.png"), 16, 12);
    std::fs::create_dir_all(seq.join("rgb/2.png")).expect("mkdir");
    std::fs::write(seq.join("rgb.txt"), "1.0 rgb/1.png\n2.0 rgb/2.png\n").expect("write");
    let err = fails(&["info", seq.to_str().expect("utf-8")]);
    assert!(err.contains("rgb.txt (line 2) is a folder") && !err.contains("does not exist"), "{err}");
}

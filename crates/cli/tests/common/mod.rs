//! The binary as the CLI tests call it. Each test file is its own crate and
//! uses a subset of these, hence `dead_code` allowed here.
#![allow(dead_code)]

use std::process::{Command, Output};

/// Runs `colslam ARGS`.
pub fn colslam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_colslam")).args(args).output().expect("run colslam")
}

/// Runs `colslam ARGS`, which must succeed; its stdout.
pub fn ok(args: &[&str]) -> String {
    let out = colslam(args);
    assert!(out.status.success(), "colslam {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `colslam ARGS`, which must fail with an error, not a panic; its stderr.
pub fn fails(args: &[&str]) -> String {
    let out = colslam(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "colslam {args:?} should fail");
    assert!(!err.contains("panicked"), "{err}");
    err
}

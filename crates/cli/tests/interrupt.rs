//! Ctrl-C during a long run (issue 15): the run stops with exit status 130,
//! its temporary record store and staging folder are gone and no output
//! folder appears; a store left by a killed run is removed by the next run.
#![cfg(unix)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A synthetic sequence of `n` frames: `unique` rendered frames played
/// forward and back (hard links), so a long input costs few renders.
fn sequence(dir: &Path, unique: usize, n: usize) -> PathBuf {
    let opts = colslam_synth::SynthOptions {
        frames: unique,
        width: 160,
        height: 120,
        focal: 131.25,
        seed: 5,
        ..colslam_synth::SynthOptions::default()
    };
    let seq = colslam_synth::SyntheticSequence::new(&opts).unwrap_or_else(|e| panic!("sequence: {e}"));
    let (input, frames) = (dir.join("seq"), dir.join("frames"));
    for d in [&input, &frames] {
        std::fs::create_dir_all(d).unwrap_or_else(|e| panic!("mkdir: {e}"));
    }
    for i in 0..unique {
        let img = seq.render(i).unwrap_or_else(|e| panic!("render: {e}"));
        img.write_png(&frames.join(format!("{i:06}.png"))).unwrap_or_else(|e| panic!("png: {e}"));
    }
    for k in 0..n {
        let lap = k / unique;
        let i = if lap.is_multiple_of(2) { k % unique } else { unique - 1 - k % unique };
        std::fs::hard_link(frames.join(format!("{i:06}.png")), input.join(format!("{k:06}.png")))
            .unwrap_or_else(|e| panic!("link: {e}"));
    }
    input
}

/// A run into `dir/out` with every record past the newest spilled.
fn spawn(input: &Path, dir: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["-q", "run"])
        .arg(input)
        .arg("-o")
        .arg(dir.join("out"))
        .args(["--focal", "131.25", "--record-memory", "0"])
        .spawn()
        .unwrap_or_else(|e| panic!("spawn: {e}"))
}

/// Hidden names of `dir` that start with `.out.scratch-` (record stores).
fn stores(dir: &Path) -> Vec<String> {
    let names = std::fs::read_dir(dir).map(|r| r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()));
    names.into_iter().flatten().filter(|n| n.starts_with(".out.scratch-")).collect()
}

/// Waits until a record store exists beside the output (the run spilled).
fn wait_for_store(child: &mut Child, dir: &Path) {
    let started = Instant::now();
    while stores(dir).is_empty() {
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the run ended ({status}) before it spilled a record");
        }
        assert!(started.elapsed() < Duration::from_secs(300), "no record store after 300 s");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn signal(child: &Child, sig: libc::c_int) {
    let pid = libc::pid_t::try_from(child.id()).unwrap_or_else(|e| panic!("pid: {e}"));
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(pid, sig) }, 0, "kill");
}

fn wait(child: &mut Child) -> std::process::ExitStatus {
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap_or_else(|e| panic!("wait: {e}")) {
            return status;
        }
        if started.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("the run did not stop within 120 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn ctrl_c_removes_the_record_store_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
    let input = sequence(dir.path(), 40, 4000);
    let mut child = spawn(&input, dir.path());
    wait_for_store(&mut child, dir.path());
    signal(&child, libc::SIGINT);
    let status = wait(&mut child);
    assert_eq!(status.code(), Some(130), "{status}");
    let mut left: Vec<String> = std::fs::read_dir(dir.path())
        .map(|r| r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    left.sort();
    assert_eq!(left, ["frames", "seq"], "no store, staging folder, lock or output left");
}

#[test]
fn the_next_run_removes_the_store_of_a_killed_run() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"));
    let input = sequence(dir.path(), 40, 4000);
    let mut child = spawn(&input, dir.path());
    wait_for_store(&mut child, dir.path());
    signal(&child, libc::SIGKILL);
    wait(&mut child);
    let stale = stores(dir.path());
    assert_eq!(stale.len(), 1, "a killed run leaves its store: {stale:?}");
    // The next run to the same output (a few frames; its outcome does not
    // matter) removes it before it reads a frame.
    let out = Command::new(env!("CARGO_BIN_EXE_colslam"))
        .args(["-q", "run"])
        .arg(&input)
        .arg("-o")
        .arg(dir.path().join("out"))
        .args(["--focal", "131.25", "--max-frames", "12"])
        .output()
        .unwrap_or_else(|e| panic!("run: {e}"));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
    assert!(!dir.path().join(&stale[0]).exists(), "{} left", stale[0]);
}

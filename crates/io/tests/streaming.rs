//! Streaming: reading a whole video keeps about one frame in memory. Alone in
//! its own test binary so the peak-RSS measurement sees no other test.

mod common;

use colslam_io::{SourceOptions, open_source};

/// Peak resident set size of this process in KiB (Linux `VmHWM`).
fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[test]
fn whole_video_in_constant_memory() {
    if !colslam_testutil::have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // 200 frames of 640x480 RGB = 184 MB if they were all held.
    let (w, h, n) = (640, 480, 200);
    let file = common::testsrc(dir.path(), "stream.mkv", w, h, n, &["-c:v", "ffv1", "-pix_fmt", "bgr0"]);
    let Some(before) = peak_rss_kib() else {
        eprintln!("SKIPPED: no /proc/self/status VmHWM");
        return;
    };
    let mut count = 0;
    let mut checksum = 0u64;
    for f in open_source(&file, &SourceOptions::default()).unwrap() {
        let f = f.unwrap();
        checksum = checksum.wrapping_add(f.image.data().iter().step_by(97).map(|&v| v as u64).sum::<u64>());
        count += 1;
    }
    assert_eq!(count, n);
    assert!(checksum > 0);
    let grown_mib = (peak_rss_kib().unwrap() - before) / 1024;
    let all_frames_mib = (w * h * 3 * n / (1024 * 1024)) as u64;
    // One or two frames (0.9 MiB each) plus allocator slack; far below all of them.
    assert!(grown_mib < 32, "peak RSS grew by {grown_mib} MiB (all frames: {all_frames_mib} MiB)");
}

//! Video sources through ffmpeg: exact pixels and counts on generated
//! testsrc videos, skip/limit, gray output, and bad videos.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use colslam_io::{SourceError, SourceKind, SourceOptions, VideoColor, VideoSource, open_source, probe_source};
use colslam_testutil::have_ffmpeg;
use common::{ffmpeg, testsrc, testsrc_raw};

/// Lossless RGB (FFV1 in Matroska, which stores no frame count in its header).
const FFV1_RGB: [&str; 4] = ["-c:v", "ffv1", "-pix_fmt", "bgr0"];
const FFV1_GRAY: [&str; 4] = ["-c:v", "ffv1", "-pix_fmt", "gray"];
/// Lossy MPEG-4 part 2 in MP4 (ffmpeg's built-in encoder), with B-frames so
/// decode order differs from display order.
const MPEG4: [&str; 6] = ["-c:v", "mpeg4", "-bf", "2", "-q:v", "3"];

#[test]
fn lossless_video_exact_pixels_and_count() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (w, h, n) = (64, 48, 7);
    let file = testsrc(dir.path(), "t.mkv", w, h, n, &FFV1_RGB);
    let reference = testsrc_raw(w, h, n, "rgb24");
    let mut src = open_source(&file, &SourceOptions::default()).unwrap();
    assert_eq!(src.kind(), SourceKind::Video);
    assert_eq!(src.len_hint(), Some(n));
    assert_eq!(src.total_source_frames(), Some(n));
    assert_eq!(src.image_size(), Some((w, h)));
    let frames: Vec<_> = src.by_ref().map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), n);
    let frame_bytes = w * h * 3;
    for (i, f) in frames.iter().enumerate() {
        assert_eq!((f.index, f.source_index), (i, i));
        assert_eq!((f.image.width(), f.image.height(), f.image.channels()), (w, h, 3));
        assert_eq!(f.image.data().len(), frame_bytes);
        assert!(f.image.data() == &reference[i * frame_bytes..(i + 1) * frame_bytes], "frame {i} differs");
        assert!((f.timestamp - i as f64 / 10.0).abs() < 1e-9, "{}", f.timestamp);
        assert_eq!(f.name, format!("frame_{i:06}"));
    }
    assert!(src.next().is_none(), "a finished source stays finished");

    // start 1, skip 3: source frames 1 and 4 -- exactly those pixels.
    let opts = SourceOptions { skip: 3, start: 1, ..Default::default() };
    let src = open_source(&file, &opts).unwrap();
    assert_eq!(src.len_hint(), Some(2));
    let frames: Vec<_> = src.map(|f| f.unwrap()).collect();
    assert_eq!(frames.iter().map(|f| f.source_index).collect::<Vec<_>>(), [1, 4]);
    for f in &frames {
        let k = f.source_index;
        assert!(f.image.data() == &reference[k * frame_bytes..(k + 1) * frame_bytes]);
        assert!((f.timestamp - k as f64 / 10.0).abs() < 1e-9);
    }
    // max_frames caps.
    let opts = SourceOptions { skip: 2, max_frames: Some(3), ..Default::default() };
    let src = open_source(&file, &opts).unwrap();
    assert_eq!(src.len_hint(), Some(3));
    assert_eq!(src.map(|f| f.unwrap().source_index).collect::<Vec<_>>(), [0, 2, 4]);
    // Start past the end.
    let e = open_source(&file, &SourceOptions { start: 7, ..Default::default() }).err().unwrap();
    assert!(matches!(e, SourceError::NoFrames { .. }), "{e}");
}

#[test]
fn gray_video_and_forced_colour() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (w, h, n) = (32, 24, 4);
    let file = testsrc(dir.path(), "g.mkv", w, h, n, &FFV1_GRAY);
    let reference = testsrc_raw(w, h, n, "gray");
    let frames: Vec<_> = open_source(&file, &SourceOptions::default()).unwrap().map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), n);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.image.channels(), 1, "gray pixel format gives gray frames");
        assert!(f.image.data() == &reference[i * w * h..(i + 1) * w * h]);
    }
    let mut opts = SourceOptions::default();
    opts.video.color = VideoColor::Rgb;
    let f = open_source(&file, &opts).unwrap().next().unwrap().unwrap();
    assert_eq!(f.image.channels(), 3);
    // Forcing gray on an RGB video.
    let rgb = testsrc(dir.path(), "c.mkv", w, h, 2, &FFV1_RGB);
    opts.video.color = VideoColor::Gray;
    let f = open_source(&rgb, &opts).unwrap().next().unwrap().unwrap();
    assert_eq!(f.image.channels(), 1);
}

#[test]
fn mp4_with_b_frames_counts_and_timestamps() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (w, h, n) = (96, 64, 12);
    let file = testsrc(dir.path(), "b.mp4", w, h, n, &MPEG4);
    std::fs::write(dir.path().join("camera.yaml"), "model: PINHOLE\n").unwrap();
    let info = probe_source(&file, &SourceOptions::default()).unwrap();
    assert_eq!(info.kind, SourceKind::Video);
    assert_eq!(info.total_source_frames, Some(n));
    assert_eq!(info.image_size, Some((w, h)));
    assert_eq!(info.camera_file, Some(dir.path().join("camera.yaml")));
    assert!(info.description.contains("b.mp4") && info.description.contains("12 frames"), "{}", info.description);
    let reference = testsrc_raw(w, h, n, "rgb24");
    let frames: Vec<_> = open_source(&file, &SourceOptions::default()).unwrap().map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), n);
    let fb = w * h * 3;
    for (i, f) in frames.iter().enumerate() {
        assert!((f.timestamp - i as f64 / 10.0).abs() < 1e-9, "frame {i}: {}", f.timestamp);
        // Lossy, but each frame must be closest to its own reference frame (display order).
        let err = |k: usize| -> u64 {
            f.image
                .data()
                .iter()
                .zip(&reference[k * fb..(k + 1) * fb])
                .map(|(&a, &b)| (a as i64 - b as i64).unsigned_abs())
                .sum()
        };
        let best = (0..n).min_by_key(|&k| err(k)).unwrap();
        assert_eq!(best, i, "frame {i} looks like reference frame {best}");
    }
}

#[test]
fn drop_early_kills_ffmpeg_quickly() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let file = testsrc(dir.path(), "long.mkv", 320, 240, 300, &FFV1_RGB);
    let mut src = VideoSource::open(&file, &SourceOptions::default()).unwrap();
    assert_eq!(src.ffmpeg_pid(), None, "ffmpeg starts lazily");
    src.next().unwrap().unwrap();
    let pid = src.ffmpeg_pid().expect("ffmpeg runs after the first frame");
    assert!(Path::new(&format!("/proc/{pid}")).exists());
    let t = Instant::now();
    drop(src);
    assert!(t.elapsed() < Duration::from_secs(2), "drop took {:?}", t.elapsed());
    // Killed and reaped: no process (not even a zombie) is left.
    assert!(!Path::new(&format!("/proc/{pid}")).exists(), "ffmpeg {pid} still exists after drop");

    // Reaching max_frames stops ffmpeg too.
    let opts = SourceOptions { max_frames: Some(2), ..Default::default() };
    let mut src = VideoSource::open(&file, &opts).unwrap();
    src.next().unwrap().unwrap();
    let pid = src.ffmpeg_pid().unwrap();
    src.next().unwrap().unwrap();
    assert!(src.next().is_none());
    assert_eq!(src.ffmpeg_pid(), None);
    assert!(!Path::new(&format!("/proc/{pid}")).exists());
}

#[test]
fn corrupt_video_names_the_file() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("random_bytes.mp4");
    let mut rng = colslam_geometry::SplitMix64::new(7);
    let bytes: Vec<u8> = (0..100_000).map(|_| rng.next_u64() as u8).collect();
    std::fs::write(&file, bytes).unwrap();
    let e = open_source(&file, &SourceOptions::default()).err().expect("random bytes must not open");
    assert!(matches!(e, SourceError::Video { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("random_bytes.mp4") && msg.contains("ffprobe"), "{msg}");

    // An unknown extension holding random bytes is tried as a video too.
    let other = dir.path().join("clip.bin");
    std::fs::write(&other, b"definitely not a video").unwrap();
    let msg = open_source(&other, &SourceOptions::default()).err().unwrap().to_string();
    assert!(msg.contains("clip.bin"), "{msg}");
}

#[test]
fn zero_frame_video() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("empty.avi");
    let f = file.to_string_lossy().into_owned();
    ffmpeg(&["-f", "lavfi", "-i", "testsrc=size=32x24:rate=10", "-frames:v", "0", "-c:v", "ffv1", &f]);
    let msg = open_source(&file, &SourceOptions::default()).err().unwrap().to_string();
    assert!(msg.contains("empty.avi") && msg.contains("no frames"), "{msg}");
}

#[test]
fn missing_ffmpeg_says_install() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("v.mp4");
    std::fs::write(&file, b"x").unwrap();
    let mut opts = SourceOptions::default();
    opts.video.ffprobe = "/nonexistent/ffprobe".into();
    let e = open_source(&file, &opts).err().unwrap();
    assert!(matches!(e, SourceError::FfmpegMissing { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("install ffmpeg") && msg.contains("v.mp4"), "{msg}");

    if !have_ffmpeg() {
        return;
    }
    // ffprobe present, ffmpeg missing: the error comes with the first frame.
    let real = testsrc(dir.path(), "ok.mkv", 16, 16, 2, &FFV1_RGB);
    let mut opts = SourceOptions::default();
    opts.video.ffmpeg = "/nonexistent/ffmpeg".into();
    let mut src = open_source(&real, &opts).unwrap();
    let msg = src.next().unwrap().unwrap_err().to_string();
    assert!(msg.contains("install ffmpeg") && msg.contains("ok.mkv"), "{msg}");
    assert!(src.next().is_none());
}

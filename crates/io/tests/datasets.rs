//! Real data from the shared datasets (skipped outside CI when absent).

mod common;

use colslam_io::{SourceError, SourceKind, SourceOptions, open_source, probe_source};

/// `timestamp path` pairs of a TUM rgb.txt, comments skipped.
fn rgb_txt(dir: &std::path::Path) -> Vec<(f64, String)> {
    std::fs::read_to_string(dir.join("rgb.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| {
            let mut t = l.split_whitespace();
            (t.next().unwrap().parse().unwrap(), t.next().unwrap().to_string())
        })
        .collect()
}

#[test]
fn tum_fr1_rpy_sub() {
    let Some(dir) = colslam_testutil::dataset("tum_fr1_rpy_sub") else { return };
    let list = rgb_txt(&dir);
    assert_eq!(list.len(), 200);
    let info = probe_source(&dir, &SourceOptions::default()).unwrap();
    assert_eq!(info.kind, SourceKind::Tum);
    assert_eq!((info.total_source_frames, info.frames), (Some(200), Some(200)));
    assert_eq!(info.image_size, Some((640, 480)));
    assert_eq!(info.camera_file, Some(dir.join("camera.yaml")));

    // skip 2 -> 100 frames, every other rgb.txt entry, timestamps equal.
    let src = open_source(&dir, &SourceOptions { skip: 2, ..Default::default() }).unwrap();
    assert_eq!(src.len_hint(), Some(100));
    let mut n = 0;
    for f in src {
        let f = f.unwrap();
        let (t, path) = &list[f.source_index];
        assert_eq!(f.source_index, 2 * f.index);
        assert_eq!(f.timestamp, *t);
        assert!(path.ends_with(&f.name));
        assert_eq!((f.image.width(), f.image.height(), f.image.channels()), (640, 480, 3));
        n += 1;
    }
    assert_eq!(n, 100);

    let src = open_source(&dir, &SourceOptions { max_frames: Some(10), ..Default::default() }).unwrap();
    assert_eq!(src.len_hint(), Some(10));
    let ts: Vec<f64> = src.map(|f| f.unwrap().timestamp).collect();
    assert_eq!(ts, list[..10].iter().map(|(t, _)| *t).collect::<Vec<_>>());
}

#[test]
fn strecha_fountain_jpegs() {
    let Some(dir) = colslam_testutil::dataset("strecha_fountain_P11") else { return };
    let src = open_source(&dir, &SourceOptions::default()).unwrap();
    assert_eq!(src.kind(), SourceKind::Tum);
    assert_eq!(src.len_hint(), Some(11));
    assert_eq!(src.image_size(), Some((1536, 1024)));
    assert!(src.camera_file().is_some());
    let frames: Vec<_> = src.map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 11);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.timestamp, i as f64);
        assert_eq!(f.name, format!("{i:04}.jpg"));
        assert_eq!((f.image.width(), f.image.height()), (1536, 1024));
    }
    assert_ne!(frames[0].image.data(), frames[1].image.data());
}

#[test]
fn kitti984_video() {
    let Some(file) = colslam_testutil::kitti_clip() else { return };
    let info = probe_source(&file, &SourceOptions::default()).unwrap();
    assert_eq!(info.kind, SourceKind::Video);
    assert_eq!(info.total_source_frames, Some(268));
    assert_eq!(info.image_size, Some((1242, 375)));

    // All frames: count, size, 30 fps timestamps, consecutive frames differ.
    let src = open_source(&file, &SourceOptions::default()).unwrap();
    assert_eq!(src.len_hint(), Some(268));
    let mut prev: Option<colslam_io::Frame> = None;
    let mut n = 0;
    for f in src {
        let f = f.unwrap();
        assert_eq!((f.image.width(), f.image.height()), (1242, 375));
        assert!((f.timestamp - f.index as f64 / 30.0).abs() < 1e-9, "frame {}: {}", f.index, f.timestamp);
        if let Some(p) = &prev {
            assert!(f.timestamp > p.timestamp);
            assert_ne!(p.image.data(), f.image.data(), "frames {} and {} are identical", p.index, f.index);
        }
        prev = Some(f);
        n += 1;
    }
    assert_eq!(n, 268);

    // skip 5 -> ceil(268 / 5) = 54 frames, 1/6 s apart.
    let src = open_source(&file, &SourceOptions { skip: 5, ..Default::default() }).unwrap();
    assert_eq!(src.len_hint(), Some(54));
    let frames: Vec<(usize, f64)> = src.map(|f| f.map(|f| (f.source_index, f.timestamp)).unwrap()).collect();
    assert_eq!(frames.len(), 54);
    for (k, (si, t)) in frames.iter().enumerate() {
        assert_eq!(*si, 5 * k);
        assert!((t - 5.0 * k as f64 / 30.0).abs() < 1e-9);
    }
    // skip 5 + max 7.
    let src = open_source(&file, &SourceOptions { skip: 5, max_frames: Some(7), ..Default::default() }).unwrap();
    assert_eq!(src.len_hint(), Some(7));
    assert_eq!(src.count(), 7);
}

#[test]
fn kitti984_truncated_copies() {
    let Some(file) = colslam_testutil::kitti_clip() else { return };
    let bytes = std::fs::read(&file).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    // The first 30 % of the file: its index (moov) is at the end, so ffprobe refuses it.
    let cut = tmp.path().join("truncated.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 10]).unwrap();
    let e = open_source(&cut, &SourceOptions::default()).err().expect("truncated video must not open");
    let msg = e.to_string();
    assert!(msg.contains("truncated.mp4") && msg.contains("moov") && msg.contains("may be truncated"), "{msg}");

    // With the index moved to the front (faststart), the same cut opens and
    // decodes some frames, then reports the damage with ffmpeg's message.
    let fast = tmp.path().join("fast.mp4");
    common::ffmpeg(&["-i", &file.to_string_lossy(), "-c", "copy", "-movflags", "+faststart", &fast.to_string_lossy()]);
    let fbytes = std::fs::read(&fast).unwrap();
    let cut = tmp.path().join("fast_truncated.mp4");
    std::fs::write(&cut, &fbytes[..fbytes.len() * 3 / 10]).unwrap();
    let src = open_source(&cut, &SourceOptions { skip: 4, ..Default::default() }).unwrap();
    assert_eq!(src.len_hint(), Some(67), "the index still announces every frame");
    let items: Vec<_> = src.collect();
    let (last, good) = items.split_last().unwrap();
    assert!(good.len() > 5 && good.len() < 67, "{} frames", good.len());
    assert!(good.iter().all(|f| f.is_ok()));
    let e = last.as_ref().unwrap_err();
    assert!(matches!(e, SourceError::VideoTruncated { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("fast_truncated.mp4") && msg.contains("truncated"), "{msg}");
}

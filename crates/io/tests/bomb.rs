//! A "decompression bomb" (a 2.5 MB PNG announcing 16000x16000 16-bit
//! pixels, 512 MB decoded) is refused from its header, as the first frame
//! (the pixel budget) and as a later frame (the size of the first frame),
//! quickly and without allocating its pixels. One test in this binary, so
//! the process's peak memory is this test's.

mod common;

use colslam_io::{SourceError, SourceOptions, open_source};
use common::{chain, png, png_bomb};

/// Peak resident memory of this process in MiB (Linux), `None` elsewhere.
fn peak_rss_mib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse::<u64>().ok().map(|kib| kib / 1024)
}

#[test]
fn decompression_bomb_is_refused_from_its_header() {
    let d = tempfile::tempdir().unwrap();
    let bomb_file = d.path().join("bomb.png");
    png_bomb(&bomb_file, 16000, 16000);
    assert!(std::fs::metadata(&bomb_file).unwrap().len() < 4 << 20, "the bomb is small on disk");

    // Alone: the first frame has nothing to compare with; the pixel budget refuses it.
    let alone = d.path().join("alone");
    std::fs::create_dir(&alone).unwrap();
    std::fs::copy(&bomb_file, alone.join("000.png")).unwrap();
    let t = std::time::Instant::now();
    let mut src = open_source(&alone, &SourceOptions::default()).unwrap();
    let err = src.next().unwrap().unwrap_err();
    let took = t.elapsed();
    let msg = chain(&err);
    assert!(matches!(&err, SourceError::Image { source: colslam_image::ImageError::TooLarge { .. }, .. }), "{msg}");
    assert!(msg.contains("000.png") && msg.contains("16000x16000"), "{msg}");
    assert!(took.as_secs_f64() < 0.5, "refused in {took:?}");

    // Third frame of an 8x6 sequence: refused as a size mismatch before decoding.
    let seq = d.path().join("seq");
    png(&seq.join("000.png"), 0);
    png(&seq.join("001.png"), 1);
    std::fs::copy(&bomb_file, seq.join("002.png")).unwrap();
    png(&seq.join("003.png"), 3);
    let src = open_source(&seq, &SourceOptions::default()).unwrap();
    let t = std::time::Instant::now();
    let frames: Vec<_> = src.collect();
    let took = t.elapsed();
    assert_eq!(frames.len(), 4);
    assert!(frames[0].is_ok() && frames[1].is_ok() && frames[3].is_ok(), "the frames around the bomb still read");
    let err = frames[2].as_ref().unwrap_err();
    let msg = chain(err);
    assert!(matches!(err, SourceError::SizeMismatch { width: 16000, height: 16000, .. }), "{msg}");
    assert!(msg.contains("002.png"), "{msg}");
    assert!(took.as_secs_f64() < 0.5, "read in {took:?}");

    if let Some(peak) = peak_rss_mib() {
        // Decoding the bomb takes gigabytes; refusing it takes nothing.
        assert!(peak < 100, "peak resident memory {peak} MiB");
    }
}

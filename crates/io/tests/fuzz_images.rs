//! Fuzzing of the image readers: the header reader (`image_size`, PNG and
//! JPEG), the EXIF focal-length parser and the decoders (`colslam_image::Image::decode`). Mutated files
//! give a size / an image or an error, never a panic, a hang or a huge
//! allocation. The decoder is fuzzed here, beside the header reader, for
//! the JPEG fixture of these tests. See `colslam_testutil::fuzz`; the long
//! run is in docs/benchmarks.md ("Fuzzing").

mod common;

use std::path::Path;

use colslam_image::Image;
use colslam_io::image_size;
use colslam_testutil::fuzz::{Corpus, Scratch, fuzz};

colslam_testutil::fuzz_allocator!();

/// Inputs per reader in the default test run.
const CI_ITERS: u64 = 4_000;

/// PNGs written by colslam_image (gray and RGB, two sizes) and the tiny
/// JPEG fixture.
fn corpus() -> Corpus {
    let mut corpus = Corpus::single("image");
    for (w, h, ch) in [(8, 6, 1), (8, 6, 3), (17, 9, 1), (3, 33, 3)] {
        let mut img = Image::new(w, h, ch);
        for (i, v) in img.data_mut().iter_mut().enumerate() {
            *v = (i * 37 % 251) as u8;
        }
        corpus = corpus.sample(img.encode_png(Path::new("seed.png")).unwrap());
    }
    corpus.sample(common::TINY_JPEG.to_vec()).words([&b"IHDR"[..], b"IDAT", b"IEND", b"\xff\xc0", b"\xff\xd9"])
}

#[test]
fn fuzz_image_header() {
    let mut scratch = Scratch::new();
    fuzz("image-header", &corpus(), CI_ITERS, |parts| image_size(&scratch.put("image", Some(&parts[0]))));
}

/// JPEG heads with EXIF blocks (35 mm equivalent, focal plane, both): each
/// gives a focal length unchanged, as the fuzzer requires of its corpus.
fn exif_corpus() -> Corpus {
    use colslam_io::exif::exif_jpeg_head;
    Corpus::single("jpeg")
        .sample(exif_jpeg_head(Some((50, 10)), Some(28), None))
        .sample(exif_jpeg_head(Some((35, 1)), None, Some((2000, 1, 3))))
        .sample(exif_jpeg_head(Some((41, 10)), Some(26), Some((5000, 3, 2))))
        .words([&b"Exif\0\0"[..], b"MM\0\x2a", b"II\x2a\0", b"\x87\x69", b"\xa4\x05", b"\x92\x0a", b"\xff\xe1"])
}

#[test]
fn fuzz_exif_focal() {
    fuzz("exif-focal", &exif_corpus(), CI_ITERS, |parts| {
        colslam_io::exif::parse_jpeg_exif_focal(&parts[0]).and_then(|e| e.focal_px(640, 480)).ok_or("no focal")
    });
}

#[test]
fn fuzz_image_decode() {
    fuzz("image-decode", &corpus(), CI_ITERS, |parts| Image::decode(&parts[0], Path::new("fuzz/image")));
}

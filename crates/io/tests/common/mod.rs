//! Fixture helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use colslam_image::Image;

/// Fixture image size.
pub const W: usize = 8;
/// Fixture image size.
pub const H: usize = 6;

/// An 8x6 gray JPEG (uniform value 77), made once with OpenCV 4.12
/// (`cv2.imencode('.jpg', np.full((6, 8), 77, np.uint8))`), since colslam_image encodes PNG only.
pub const TINY_JPEG: [u8; 333] = [
    255, 216, 255, 224, 0, 16, 74, 70, 73, 70, 0, 1, 1, 0, 0, 1, 0, 1, 0, 0, 255, 219, 0, 67, 0, 2, 1, 1, 1, 1, 1, 2,
    1, 1, 1, 2, 2, 2, 2, 2, 4, 3, 2, 2, 2, 2, 5, 4, 4, 3, 4, 6, 5, 6, 6, 6, 5, 6, 6, 6, 7, 9, 8, 6, 7, 9, 7, 6, 6, 8,
    11, 8, 9, 10, 10, 10, 10, 10, 6, 8, 11, 12, 11, 10, 12, 9, 10, 10, 10, 255, 192, 0, 11, 8, 0, 6, 0, 8, 1, 1, 17, 0,
    255, 196, 0, 31, 0, 0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 255, 196,
    0, 181, 16, 0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 125, 1, 2, 3, 0, 4, 17, 5, 18, 33, 49, 65, 6, 19, 81, 97,
    7, 34, 113, 20, 50, 129, 145, 161, 8, 35, 66, 177, 193, 21, 82, 209, 240, 36, 51, 98, 114, 130, 9, 10, 22, 23, 24,
    25, 26, 37, 38, 39, 40, 41, 42, 52, 53, 54, 55, 56, 57, 58, 67, 68, 69, 70, 71, 72, 73, 74, 83, 84, 85, 86, 87, 88,
    89, 90, 99, 100, 101, 102, 103, 104, 105, 106, 115, 116, 117, 118, 119, 120, 121, 122, 131, 132, 133, 134, 135,
    136, 137, 138, 146, 147, 148, 149, 150, 151, 152, 153, 154, 162, 163, 164, 165, 166, 167, 168, 169, 170, 178, 179,
    180, 181, 182, 183, 184, 185, 186, 194, 195, 196, 197, 198, 199, 200, 201, 202, 210, 211, 212, 213, 214, 215, 216,
    217, 218, 225, 226, 227, 228, 229, 230, 231, 232, 233, 234, 241, 242, 243, 244, 245, 246, 247, 248, 249, 250, 255,
    218, 0, 8, 1, 1, 0, 0, 63, 0, 248, 206, 191, 255, 217,
];

/// Writes an 8x6 RGB PNG whose first pixel's red value is `id` (to check order).
pub fn png(path: &Path, id: u8) {
    if let Some(p) = path.parent() {
        std::fs::create_dir_all(p).unwrap();
    }
    let mut img = Image::new(W, H, 3);
    img.set(0, 0, 0, id);
    img.write_png(path).unwrap();
}

/// Writes the tiny JPEG.
pub fn jpeg(path: &Path) {
    if let Some(p) = path.parent() {
        std::fs::create_dir_all(p).unwrap();
    }
    std::fs::write(path, TINY_JPEG).unwrap();
}

/// Runs ffmpeg with `args` (quiet, overwrite), panicking on failure.
pub fn ffmpeg(args: &[&str]) {
    let out = Command::new("ffmpeg").args(["-v", "error", "-y", "-nostdin"]).args(args).output().unwrap();
    assert!(out.status.success(), "ffmpeg {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Makes a testsrc video of `frames` frames at `w`x`h`, 10 fps, with the
/// given codec arguments, and returns its path.
pub fn testsrc(dir: &Path, name: &str, w: usize, h: usize, frames: usize, codec: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let src = format!("testsrc=size={w}x{h}:rate=10");
    let n = frames.to_string();
    let mut args = vec!["-f", "lavfi", "-i", &src, "-frames:v", &n];
    args.extend_from_slice(codec);
    let o = out.to_string_lossy().into_owned();
    args.push(&o);
    ffmpeg(&args);
    out
}

/// The same testsrc frames as raw RGB24 bytes (the exact reference).
pub fn testsrc_raw(w: usize, h: usize, frames: usize, pix_fmt: &str) -> Vec<u8> {
    let src = format!("testsrc=size={w}x{h}:rate=10");
    let n = frames.to_string();
    let out = Command::new("ffmpeg")
        .args([
            "-v",
            "error",
            "-nostdin",
            "-f",
            "lavfi",
            "-i",
            &src,
            "-frames:v",
            &n,
            "-f",
            "rawvideo",
            "-pix_fmt",
            pix_fmt,
            "-",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    out.stdout
}

/// Writes a real "decompression bomb": a `width`x`height` 16-bit gray PNG of
/// zeros (16000x16000 compresses to about 2 MB but decodes to 512 MB), rows
/// streamed through the encoder so making it needs one row of memory.
pub fn png_bomb(path: &Path, width: u32, height: u32) {
    use std::io::Write;
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = png::Encoder::new(file, width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::NoFilter);
    let mut w = enc.write_header().unwrap();
    let mut s = w.stream_writer().unwrap();
    let row = vec![0u8; 2 * width as usize];
    for _ in 0..height {
        s.write_all(&row).unwrap();
    }
    s.finish().unwrap();
}

/// An error and its causes joined by ": " (what the binary prints): a
/// cause is not repeated in its wrapper's message, so tests read the chain.
pub fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cause = c.source();
    }
    s
}

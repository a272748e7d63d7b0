//! Image size from a PNG or JPEG header, without decoding pixels (so
//! `probe_source` stays cheap).

use std::io::{BufReader, Read};
use std::path::Path;

use crate::SourceError;

/// PNG signature (8 bytes) followed by the IHDR chunk length and type.
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];
/// Bytes of a PNG up to and including the IHDR width and height fields.
const PNG_HEADER_LEN: usize = 24;
/// Upper bound of JPEG segments walked before giving up (a real file reaches
/// its SOF marker after a handful of APPn/DQT/DHT segments).
const JPEG_MAX_SEGMENTS: usize = 1024;

/// Width and height of a PNG or JPEG file, read from its header only.
pub fn image_size(path: &Path) -> Result<(usize, usize), SourceError> {
    let file = std::fs::File::open(path).map_err(|e| SourceError::io(path, e))?;
    let mut r = BufReader::new(file);
    let bad = |reason: &str| {
        SourceError::image(
            colslam_image::ImageError::Decode { path: path.to_path_buf(), reason: reason.to_string() },
            String::new(),
        )
    };
    let mut head = [0u8; 2];
    r.read_exact(&mut head).map_err(|_| bad("file too short for an image header"))?;
    if head == [0x89, b'P'] {
        let mut rest = [0u8; PNG_HEADER_LEN - 2];
        r.read_exact(&mut rest).map_err(|_| bad("truncated PNG header"))?;
        let mut h = [0u8; PNG_HEADER_LEN];
        h[..2].copy_from_slice(&head);
        h[2..].copy_from_slice(&rest);
        if h[..8] != PNG_SIGNATURE || &h[12..16] != b"IHDR" {
            return Err(bad("bad PNG signature or missing IHDR"));
        }
        let w = u32::from_be_bytes([h[16], h[17], h[18], h[19]]) as usize;
        let ht = u32::from_be_bytes([h[20], h[21], h[22], h[23]]) as usize;
        return Ok((w, ht));
    }
    if head == [0xFF, 0xD8] {
        return jpeg_size(&mut r).ok_or_else(|| bad("no JPEG frame header (SOF) found"));
    }
    Err(SourceError::image(colslam_image::ImageError::UnsupportedFormat { path: path.to_path_buf() }, String::new()))
}

/// Walks JPEG marker segments after SOI until a start-of-frame marker.
fn jpeg_size(r: &mut impl Read) -> Option<(usize, usize)> {
    let mut byte = [0u8; 1];
    for _ in 0..JPEG_MAX_SEGMENTS {
        // Find the next marker: 0xFF followed by a non-0xFF byte (fill bytes allowed).
        r.read_exact(&mut byte).ok()?;
        if byte[0] != 0xFF {
            return None;
        }
        let mut marker = 0xFF;
        while marker == 0xFF {
            r.read_exact(&mut byte).ok()?;
            marker = byte[0];
        }
        // Standalone markers carry no length.
        if marker == 0x01 || (0xD0..=0xD7).contains(&marker) {
            continue;
        }
        let mut len = [0u8; 2];
        r.read_exact(&mut len).ok()?;
        let len = u16::from_be_bytes(len) as usize;
        if len < 2 {
            return None;
        }
        // SOF0..SOF15 except DHT (C4), JPG (C8) and DAC (CC).
        let is_sof = (0xC0..=0xCF).contains(&marker) && !matches!(marker, 0xC4 | 0xC8 | 0xCC);
        if is_sof {
            let mut sof = [0u8; 5];
            r.read_exact(&mut sof).ok()?;
            let h = u16::from_be_bytes([sof[1], sof[2]]) as usize;
            let w = u16::from_be_bytes([sof[3], sof[4]]) as usize;
            return Some((w, h));
        }
        std::io::copy(&mut r.by_ref().take((len - 2) as u64), &mut std::io::sink()).ok()?;
    }
    None
}

//! The focal length a JPEG's EXIF block records, for photo folders without
//! a camera file (as COLMAP reads it when it creates a camera from an
//! image). A small bounded parser rather than a crate: the pipeline needs
//! four tags, and a hand-written walk over a length-checked byte slice can
//! be fuzzed with the other parsers (`tests/fuzz_images.rs`) and never
//! reads past [`MAX_EXIF_SCAN`] bytes of a file.
//!
//! Tags read (EXIF 2.3): FocalLength (0x920A), FocalLengthIn35mmFilm
//! (0xA405), FocalPlaneXResolution (0xA20E), FocalPlaneResolutionUnit
//! (0xA210) and PixelXDimension (0xA002), from IFD0's EXIF sub-IFD.

use std::io::Read;
use std::path::Path;

/// Bytes of a file scanned for its EXIF block: APP1 comes right after the
/// start of image and is at most 64 KiB long.
pub const MAX_EXIF_SCAN: usize = 70_000;

/// Entries read from one IFD at most (a real one holds a few dozen).
const MAX_IFD_ENTRIES: usize = 512;

/// Side of the 35 mm film frame the "35 mm equivalent" refers to, mm.
const FILM_35MM_LONG_SIDE_MM: f64 = 36.0;

/// The focal-length tags of a JPEG's EXIF block.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ExifFocal {
    /// FocalLength, millimetres.
    pub focal_mm: Option<f64>,
    /// FocalLengthIn35mmFilm, millimetres.
    pub focal_35mm: Option<f64>,
    /// FocalPlaneXResolution, pixels per [`Self::resolution_unit_mm`].
    pub plane_x_resolution: Option<f64>,
    /// FocalPlaneResolutionUnit in millimetres (inch by default).
    pub resolution_unit_mm: f64,
    /// PixelXDimension: the width the focal-plane resolution refers to.
    pub pixel_x_dimension: Option<f64>,
}

/// Which tags gave a focal length in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExifFocalKind {
    /// FocalLengthIn35mmFilm.
    Equivalent35mm,
    /// FocalLength with FocalPlaneXResolution.
    FocalPlane,
}

impl ExifFocal {
    /// The focal length in pixels of a `width` x `height` image: from the
    /// 35 mm equivalent (`f35 * max(w, h) / 36`, the film frame's long side
    /// mapped to the image's), else from FocalLength and the focal-plane
    /// resolution (scaled when the image is smaller than the sensor's
    /// PixelXDimension). `None` without usable tags or for a result outside
    /// (0.05, 50) times the larger side (a corrupt tag, not a lens).
    pub fn focal_px(&self, width: usize, height: usize) -> Option<(f64, ExifFocalKind)> {
        let side = width.max(height) as f64;
        let from_35 = self.focal_35mm.map(|f| (f * side / FILM_35MM_LONG_SIDE_MM, ExifFocalKind::Equivalent35mm));
        let from_plane = || {
            let (f, res) = (self.focal_mm?, self.plane_x_resolution?);
            let scale = self.pixel_x_dimension.filter(|d| *d > 0.0).map_or(1.0, |d| width as f64 / d);
            Some((f * res / self.resolution_unit_mm * scale, ExifFocalKind::FocalPlane))
        };
        from_35.filter(|(f, _)| plausible(*f, side)).or_else(|| from_plane().filter(|(f, _)| plausible(*f, side)))
    }
}

fn plausible(f: f64, side: f64) -> bool {
    f.is_finite() && f > 0.05 * side && f < 50.0 * side
}

/// The EXIF focal tags of the JPEG at `path`: `None` when the file is not a
/// JPEG, has no EXIF block or the block is malformed (a missing prior, not
/// an error: the caller falls back to its guess).
pub fn read_exif_focal(path: &Path) -> Option<ExifFocal> {
    let file = std::fs::File::open(path).ok()?;
    let mut head = Vec::with_capacity(4096);
    file.take(MAX_EXIF_SCAN as u64).read_to_end(&mut head).ok()?;
    parse_jpeg_exif_focal(&head)
}

/// The EXIF focal tags of a JPEG's first bytes (see [`read_exif_focal`]).
pub fn parse_jpeg_exif_focal(bytes: &[u8]) -> Option<ExifFocal> {
    let tiff = find_exif_tiff(bytes)?;
    parse_tiff_focal(tiff)
}

/// The TIFF block of the first APP1 "Exif" segment before the image data.
fn find_exif_tiff(bytes: &[u8]) -> Option<&[u8]> {
    if bytes.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut pos = 2;
    loop {
        let (&ff, &marker) = (bytes.get(pos)?, bytes.get(pos + 1)?);
        if ff != 0xFF {
            return None;
        }
        // Start of scan or of a frame: EXIF comes before both.
        if marker == 0xDA || (0xC0..=0xCF).contains(&marker) && !matches!(marker, 0xC4 | 0xC8 | 0xCC) {
            return None;
        }
        let len = usize::from(u16::from_be_bytes([*bytes.get(pos + 2)?, *bytes.get(pos + 3)?]));
        let body = bytes.get(pos + 4..(pos + 2).checked_add(len)?)?;
        if marker == 0xE1 && body.starts_with(b"Exif\0\0") {
            return body.get(6..);
        }
        pos = pos + 2 + len;
    }
}

/// Byte order of a TIFF block.
#[derive(Clone, Copy)]
struct Tiff<'a> {
    data: &'a [u8],
    little: bool,
}

impl Tiff<'_> {
    fn u16_at(&self, at: usize) -> Option<u16> {
        let b: [u8; 2] = self.data.get(at..at.checked_add(2)?)?.try_into().ok()?;
        Some(if self.little { u16::from_le_bytes(b) } else { u16::from_be_bytes(b) })
    }

    fn u32_at(&self, at: usize) -> Option<u32> {
        let b: [u8; 4] = self.data.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if self.little { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) })
    }

    /// The entries `(tag, type, count, value-or-offset position)` of the IFD at `at`.
    fn entries(&self, at: usize) -> Option<Vec<(u16, u16, u32, usize)>> {
        let n = usize::from(self.u16_at(at)?).min(MAX_IFD_ENTRIES);
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let e = at + 2 + 12 * i;
            out.push((self.u16_at(e)?, self.u16_at(e + 2)?, self.u32_at(e + 4)?, e + 8));
        }
        Some(out)
    }

    /// A single numeric value: SHORT (3), LONG (4) or RATIONAL (5, at an offset).
    fn number(&self, kind: u16, count: u32, field: usize) -> Option<f64> {
        if count == 0 {
            return None;
        }
        match kind {
            3 => Some(f64::from(self.u16_at(field)?)),
            4 => Some(f64::from(self.u32_at(field)?)),
            5 => {
                let at = usize::try_from(self.u32_at(field)?).ok()?;
                let (num, den) = (self.u32_at(at)?, self.u32_at(at.checked_add(4)?)?);
                (den != 0).then(|| f64::from(num) / f64::from(den))
            }
            _ => None,
        }
    }
}

/// The focal tags of a TIFF block (IFD0, then its EXIF sub-IFD).
fn parse_tiff_focal(data: &[u8]) -> Option<ExifFocal> {
    let little = match data.get(..2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let t = Tiff { data, little };
    if t.u16_at(2)? != 42 {
        return None;
    }
    let ifd0 = usize::try_from(t.u32_at(4)?).ok()?;
    let sub = t.entries(ifd0)?.into_iter().find(|e| e.0 == 0x8769)?;
    let sub_at = usize::try_from(t.u32_at(sub.3)?).ok()?;
    let mut out = ExifFocal { resolution_unit_mm: 25.4, ..ExifFocal::default() };
    for (tag, kind, count, field) in t.entries(sub_at)? {
        let v = t.number(kind, count, field);
        match tag {
            0x920A => out.focal_mm = v.filter(|f| *f > 0.0),
            0xA405 => out.focal_35mm = v.filter(|f| *f > 0.0),
            0xA20E => out.plane_x_resolution = v.filter(|r| *r > 0.0),
            0xA002 => out.pixel_x_dimension = v,
            0xA210 => {
                out.resolution_unit_mm = match v.map(|u| u as u32) {
                    Some(3) => 10.0,
                    Some(4) => 1.0,
                    Some(5) => 1e-3,
                    _ => 25.4,
                }
            }
            _ => {}
        }
    }
    Some(out)
}

/// A minimal JPEG head with an EXIF block holding the given focal tags
/// (big-endian TIFF), for tests and the fuzz corpus. Not a decodable image:
/// it ends after the APP1 segment.
pub fn exif_jpeg_head(
    focal_mm: Option<(u32, u32)>,
    focal_35mm: Option<u16>,
    plane: Option<(u32, u32, u16)>,
) -> Vec<u8> {
    let mut entries: Vec<(u16, u16, u32, Vec<u8>)> = Vec::new();
    if let Some((n, d)) = focal_mm {
        entries.push((0x920A, 5, 1, [n.to_be_bytes(), d.to_be_bytes()].concat()));
    }
    if let Some((n, d, unit)) = plane {
        entries.push((0xA20E, 5, 1, [n.to_be_bytes(), d.to_be_bytes()].concat()));
        entries.push((0xA210, 3, 1, unit.to_be_bytes().to_vec()));
    }
    if let Some(f) = focal_35mm {
        entries.push((0xA405, 3, 1, f.to_be_bytes().to_vec()));
    }
    // TIFF header (8) + IFD0 with one entry (2 + 12 + 4) = 26; the sub-IFD follows.
    let sub_at: u32 = 26;
    let mut tiff = b"MM\0\x2a\0\0\0\x08".to_vec();
    tiff.extend(1u16.to_be_bytes());
    tiff.extend(0x8769u16.to_be_bytes());
    tiff.extend(4u16.to_be_bytes());
    tiff.extend(1u32.to_be_bytes());
    tiff.extend(sub_at.to_be_bytes());
    tiff.extend(0u32.to_be_bytes());
    let n = entries.len() as u32;
    let mut extra_at = sub_at + 2 + 12 * n + 4;
    let mut extra = Vec::new();
    tiff.extend((n as u16).to_be_bytes());
    for (tag, kind, count, value) in &entries {
        tiff.extend(tag.to_be_bytes());
        tiff.extend(kind.to_be_bytes());
        tiff.extend(count.to_be_bytes());
        if value.len() > 4 {
            tiff.extend(extra_at.to_be_bytes());
            extra.extend(value.iter().copied());
            extra_at += value.len() as u32;
        } else {
            let mut field = value.clone();
            field.resize(4, 0);
            tiff.extend(field);
        }
    }
    tiff.extend(0u32.to_be_bytes());
    tiff.extend(extra);
    let mut out = vec![0xFF, 0xD8, 0xFF, 0xE1];
    out.extend(((tiff.len() + 8) as u16).to_be_bytes());
    out.extend(b"Exif\0\0");
    out.extend(tiff);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_35mm_equivalent_and_the_focal_plane_give_pixels() {
        let head = exif_jpeg_head(Some((50, 10)), Some(28), None);
        let exif = parse_jpeg_exif_focal(&head).expect("exif");
        assert_eq!(exif.focal_mm, Some(5.0));
        assert_eq!(exif.focal_35mm, Some(28.0));
        let (f, kind) = exif.focal_px(1536, 1024).expect("focal");
        assert_eq!(kind, ExifFocalKind::Equivalent35mm);
        assert!((f - 28.0 * 1536.0 / 36.0).abs() < 1e-9, "{f}");
        // FocalLength 35 mm on a sensor of 2000 px per cm, image as large as the sensor.
        let head = exif_jpeg_head(Some((35, 1)), None, Some((2000, 1, 3)));
        let (f, kind) = parse_jpeg_exif_focal(&head).and_then(|e| e.focal_px(3000, 2000)).expect("focal");
        assert_eq!(kind, ExifFocalKind::FocalPlane);
        assert!((f - 7000.0).abs() < 1e-9, "{f}");
        // A focal length alone says nothing in pixels.
        let head = exif_jpeg_head(Some((35, 1)), None, None);
        assert_eq!(parse_jpeg_exif_focal(&head).and_then(|e| e.focal_px(3000, 2000)), None);
    }

    #[test]
    fn malformed_blocks_give_none() {
        let head = exif_jpeg_head(Some((50, 10)), Some(28), None);
        for cut in 0..head.len() {
            let _ = parse_jpeg_exif_focal(&head[..cut]);
        }
        assert_eq!(parse_jpeg_exif_focal(b"not a jpeg"), None);
        // A zero denominator and an absurd 35 mm value are refused.
        let head = exif_jpeg_head(Some((50, 0)), Some(60000), None);
        let e = parse_jpeg_exif_focal(&head).expect("parses");
        assert_eq!(e.focal_mm, None);
        assert_eq!(e.focal_px(640, 480), None);
    }
}

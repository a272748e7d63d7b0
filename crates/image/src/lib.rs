//! Owned 8-bit image buffers for colslam, with decoding of JPEG and PNG files
//! and PNG encoding. Pixels are stored row-major, channels interleaved.

use std::path::{Path, PathBuf};

mod output;
pub use output::{OutputDir, OutputError, fault, write_atomic};

/// Errors from reading or writing images.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be read or written.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file could not be decoded.
    #[error("{path}: cannot decode image: {reason}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// The file extension / magic bytes name no supported format.
    #[error("{path}: unsupported image format (expected PNG or JPEG)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// The buffer does not match the stated size.
    #[error("buffer of {len} bytes does not hold a {width}x{height}x{channels} image")]
    BadBuffer {
        /// Buffer length.
        len: usize,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// Channels.
        channels: usize,
    },
    /// The header announces an image beyond the decoding budget
    /// ([`MAX_PIXELS`], [`MAX_DECODED_BYTES`], [`MAX_SIDE`]); refused before
    /// any pixel buffer is allocated.
    #[error("{path}: image of {width}x{height} is too large to decode ({reason})")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Width from the header.
        width: usize,
        /// Height from the header.
        height: usize,
        /// Which limit it exceeds.
        reason: String,
    },
    /// PNG encoding failed.
    #[error("{path}: cannot encode PNG: {reason}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// Most pixels an image may have to be decoded (64 Mpx, e.g. 8192x8192):
/// above any camera a SLAM input comes from (8K video is 33 Mpx), and small
/// enough that the decoder's buffers stay well under a gigabyte. A compressed
/// file announcing more (a "decompression bomb": a few megabytes of zeros
/// claiming 16000x16000) is refused from its header alone.
pub const MAX_PIXELS: usize = 1 << 26;
/// Most bytes the decoder's raw output may take (samples of up to 16 bits
/// before reduction to 8 bits): 256 MiB, so a 16-bit RGBA file within
/// [`MAX_PIXELS`] cannot make the decoder's working copies reach gigabytes.
pub const MAX_DECODED_BYTES: usize = 1 << 28;
/// Longest side accepted (also set as the decoders' own width/height limit).
pub const MAX_SIDE: usize = 1 << 15;

/// Checks a size read from a header against [`MAX_SIDE`] and [`MAX_PIXELS`];
/// `path` only names the source in the error. Callers that learn a size
/// before decoding (image headers, a video's probe) use it to refuse
/// oversized inputs before allocating anything.
pub fn check_size(width: usize, height: usize, path: &Path) -> Result<(), ImageError> {
    let too_large = |reason: String| ImageError::TooLarge { path: path.to_path_buf(), width, height, reason };
    if width > MAX_SIDE || height > MAX_SIDE {
        return Err(too_large(format!("a side is longer than {MAX_SIDE} pixels")));
    }
    match width.checked_mul(height) {
        Some(px) if px <= MAX_PIXELS => Ok(()),
        _ => Err(too_large(format!("more than the {} Mpx limit", MAX_PIXELS >> 20))),
    }
}

/// [`check_size`], plus [`MAX_DECODED_BYTES`] for `components` samples of
/// `bytes_per_sample` bytes per pixel.
fn check_decode_size(
    width: usize,
    height: usize,
    components: usize,
    bytes_per_sample: usize,
    path: &Path,
) -> Result<(), ImageError> {
    check_size(width, height, path)?;
    // check_size bounds width * height by MAX_PIXELS, and components (<= 4)
    // times bytes_per_sample (<= 2) cannot overflow it on a 64-bit usize;
    // checked anyway for 32-bit targets.
    let bytes = width.checked_mul(height).and_then(|p| p.checked_mul(components * bytes_per_sample));
    match bytes {
        Some(b) if b <= MAX_DECODED_BYTES => Ok(()),
        _ => Err(ImageError::TooLarge {
            path: path.to_path_buf(),
            width,
            height,
            reason: format!(
                "{components} channel(s) of {} bits need more than {} MiB",
                8 * bytes_per_sample,
                MAX_DECODED_BYTES >> 20
            ),
        }),
    }
}

/// An owned 8-bit image with 1 (gray) or 3 (RGB) interleaved channels.
#[derive(Clone, PartialEq, Eq)]
pub struct Image {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<u8>,
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Image({}x{}x{})", self.width, self.height, self.channels)
    }
}

impl Image {
    /// Wraps a buffer; `data.len()` must equal `width * height * channels` and
    /// `channels` must be 1 or 3.
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<u8>) -> Result<Self, ImageError> {
        if !(channels == 1 || channels == 3) || data.len() != width * height * channels {
            return Err(ImageError::BadBuffer { len: data.len(), width, height, channels });
        }
        Ok(Self { width, height, channels, data })
    }

    /// A zero-filled image.
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        let channels = if channels == 3 { 3 } else { 1 };
        Self { width, height, channels, data: vec![0; width * height * channels] }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }
    /// Channels: 1 or 3.
    pub fn channels(&self) -> usize {
        self.channels
    }
    /// Raw interleaved pixels.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// Mutable raw interleaved pixels.
    pub fn data_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }
    /// Consumes the image and returns its buffer.
    pub fn into_vec(self) -> Vec<u8> {
        self.data
    }
    /// True if the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }

    /// One channel of a pixel; `x < width`, `y < height`, `c < channels`.
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> u8 {
        self.data[(y * self.width + x) * self.channels + c]
    }

    /// Sets one channel of a pixel.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, c: usize, v: u8) {
        self.data[(y * self.width + x) * self.channels + c] = v;
    }

    /// Gray version (ITU-R BT.601 luma, as OpenCV's `COLOR_RGB2GRAY`).
    pub fn to_gray(&self) -> Image {
        if self.channels == 1 {
            return self.clone();
        }
        let data = self
            .data
            .chunks_exact(3)
            .map(|p| {
                // Fixed-point 0.299 R + 0.587 G + 0.114 B with rounding (weights sum to 2^14).
                let v = 4899 * p[0] as u32 + 9617 * p[1] as u32 + 1868 * p[2] as u32;
                ((v + (1 << 13)) >> 14) as u8
            })
            .collect();
        Image { width: self.width, height: self.height, channels: 1, data }
    }

    /// RGB version (gray replicated).
    pub fn to_rgb(&self) -> Image {
        if self.channels == 3 {
            return self.clone();
        }
        let data = self.data.iter().flat_map(|&v| [v, v, v]).collect();
        Image { width: self.width, height: self.height, channels: 3, data }
    }

    /// Decodes a PNG or JPEG file (chosen by its magic bytes).
    pub fn read(path: &Path) -> Result<Image, ImageError> {
        let bytes = std::fs::read(path).map_err(|source| ImageError::Io { path: path.to_path_buf(), source })?;
        Self::decode(&bytes, path)
    }

    /// Decodes PNG or JPEG bytes; `path` only names the source in errors.
    /// The header is read first and an image beyond [`check_size`]'s limits
    /// or [`MAX_DECODED_BYTES`] is refused before any pixel buffer exists.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
        use zune_png::zune_core::bit_depth::BitDepth;
        use zune_png::zune_core::options::DecoderOptions;
        let derr = |reason: String| ImageError::Decode { path: path.to_path_buf(), reason };
        let limits = DecoderOptions::default().set_max_width(MAX_SIDE).set_max_height(MAX_SIDE);
        if bytes.starts_with(&[0x89, b'P', b'N', b'G']) {
            let opts = limits.png_set_strip_to_8bit(true);
            let mut dec =
                zune_png::PngDecoder::new_with_options(zune_png::zune_core::bytestream::ZCursor::new(bytes), opts);
            dec.decode_headers().map_err(|e| derr(format!("{e:?}")))?;
            let (w, h) = dec.dimensions().ok_or_else(|| derr("no dimensions".into()))?;
            let cs = dec.colorspace().ok_or_else(|| derr("no colour space".into()))?;
            let sample = if dec.depth() == Some(BitDepth::Sixteen) { 2 } else { 1 };
            check_decode_size(w, h, cs.num_components(), sample, path)?;
            let px = dec.decode_raw().map_err(|e| derr(format!("{e:?}")))?;
            from_colorspace(w, h, cs.num_components(), cs.has_alpha(), px).map_err(|e| derr(e.to_string()))
        } else if bytes.starts_with(&[0xFF, 0xD8]) {
            let mut dec =
                zune_jpeg::JpegDecoder::new_with_options(zune_jpeg::zune_core::bytestream::ZCursor::new(bytes), limits);
            dec.decode_headers().map_err(|e| derr(format!("{e:?}")))?;
            let (w, h) = dec.dimensions().ok_or_else(|| derr("no header".into()))?;
            let cs = dec.output_colorspace().ok_or_else(|| derr("no colour space".into()))?;
            check_decode_size(w, h, cs.num_components(), 1, path)?;
            let px = dec.decode().map_err(|e| derr(format!("{e:?}")))?;
            from_colorspace(w, h, cs.num_components(), cs.has_alpha(), px).map_err(|e| derr(e.to_string()))
        } else {
            Err(ImageError::UnsupportedFormat { path: path.to_path_buf() })
        }
    }

    /// Writes the image as PNG, atomically (temporary file in the same
    /// folder, then rename).
    pub fn write_png(&self, path: &Path) -> Result<(), ImageError> {
        let bytes = self.encode_png(path)?;
        write_atomic(path, &bytes).map_err(|source| ImageError::Io { path: path.to_path_buf(), source })
    }

    /// Encodes as PNG bytes; `path` only names the target in errors.
    pub fn encode_png(&self, path: &Path) -> Result<Vec<u8>, ImageError> {
        let eerr = |e: png::EncodingError| ImageError::Encode { path: path.to_path_buf(), reason: e.to_string() };
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
            enc.set_color(if self.channels == 3 { png::ColorType::Rgb } else { png::ColorType::Grayscale });
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Fast);
            let mut w = enc.write_header().map_err(eerr)?;
            w.write_image_data(&self.data).map_err(eerr)?;
        }
        Ok(out)
    }
}

fn from_colorspace(w: usize, h: usize, comps: usize, alpha: bool, px: Vec<u8>) -> Result<Image, ImageError> {
    match (comps, alpha) {
        (1, false) => Image::from_vec(w, h, 1, px),
        (2, true) => Image::from_vec(w, h, 1, px.chunks_exact(2).map(|p| p[0]).collect()),
        (3, false) => Image::from_vec(w, h, 3, px),
        (4, true) => Image::from_vec(w, h, 3, px.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect()),
        _ => Err(ImageError::BadBuffer { len: px.len(), width: w, height: h, channels: comps }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_gray_and_rgb() {
        let dir = tempfile::tempdir().unwrap();
        for ch in [1, 3] {
            let mut img = Image::new(17, 9, ch);
            for (i, v) in img.data_mut().iter_mut().enumerate() {
                *v = (i * 7 % 251) as u8;
            }
            let p = dir.path().join(format!("a{ch}.png"));
            img.write_png(&p).unwrap();
            assert_eq!(Image::read(&p).unwrap(), img);
        }
    }

    /// A PNG whose header announces `w`x`h` 8-bit gray pixels, without
    /// pixel data (enough for the header check).
    fn png_header_only(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Eight);
            let _writer = enc.write_header().unwrap();
        }
        out
    }

    #[test]
    fn oversized_headers_are_refused_before_decoding() {
        let p = Path::new("big.png");
        let e = Image::decode(&png_header_only(9000, 9000), p).unwrap_err();
        assert!(matches!(e, ImageError::TooLarge { width: 9000, height: 9000, .. }), "{e}");
        assert!(e.to_string().contains("big.png") && e.to_string().contains("9000x9000"), "{e}");
        // A side beyond MAX_SIDE is the decoder's own limit.
        for (w, h) in [(40000, 10), (10, 40000)] {
            let e = Image::decode(&png_header_only(w, h), p).unwrap_err().to_string();
            assert!(e.contains("big.png") && e.contains("40000"), "{e}");
        }
        assert!(check_size(8192, 8192, p).is_ok());
        assert!(check_size(8193, 8192, p).is_err());
        assert!(check_size(usize::MAX, 2, p).is_err());
        // 16-bit RGBA within the pixel budget still exceeds the byte budget.
        assert!(check_decode_size(8192, 8192, 4, 2, p).is_err());
        assert!(check_decode_size(8192, 8192, 3, 1, p).is_ok());
    }

    #[test]
    fn gray_conversion_matches_bt601() {
        let img = Image::from_vec(2, 1, 3, vec![255, 0, 0, 10, 200, 30]).unwrap();
        let g = img.to_gray();
        assert_eq!(g.data(), &[76, 124]); // round(0.299*255), round(0.299*10+0.587*200+0.114*30)
    }

    #[test]
    fn bad_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("broken.png");
        std::fs::write(&p, [0x89, b'P', b'N', b'G', 1, 2, 3]).unwrap();
        let e = Image::read(&p).unwrap_err().to_string();
        assert!(e.contains("broken.png"), "{e}");
        let q = dir.path().join("text.jpg");
        std::fs::write(&q, b"hello").unwrap();
        assert!(matches!(Image::read(&q), Err(ImageError::UnsupportedFormat { .. })));
        let missing = dir.path().join("missing.png");
        assert!(Image::read(&missing).unwrap_err().to_string().contains("missing.png"));
        assert!(Image::from_vec(2, 2, 3, vec![0; 5]).is_err());
    }
}

//! Owned 8-bit image buffers for colslam, with decoding of JPEG and PNG files
//! and PNG encoding. Pixels are stored row-major, channels interleaved.

use std::path::{Path, PathBuf};

mod output;
pub use output::{OutputDir, OutputError, fault, write_atomic};

/// Errors from reading or writing images.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
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
    /// PNG encoding failed.
    #[error("{path}: cannot encode PNG: {reason}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
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
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
        let derr = |reason: String| ImageError::Decode { path: path.to_path_buf(), reason };
        if bytes.starts_with(&[0x89, b'P', b'N', b'G']) {
            let mut dec = zune_png::PngDecoder::new(zune_png::zune_core::bytestream::ZCursor::new(bytes));
            let opts = zune_png::zune_core::options::DecoderOptions::default().png_set_strip_to_8bit(true);
            dec.set_options(opts);
            let px = dec.decode_raw().map_err(|e| derr(format!("{e:?}")))?;
            let (w, h) = dec.dimensions().ok_or_else(|| derr("no dimensions".into()))?;
            let cs = dec.colorspace().ok_or_else(|| derr("no colour space".into()))?;
            from_colorspace(w, h, cs.num_components(), cs.has_alpha(), px).map_err(|e| derr(e.to_string()))
        } else if bytes.starts_with(&[0xFF, 0xD8]) {
            let mut dec = zune_jpeg::JpegDecoder::new(zune_jpeg::zune_core::bytestream::ZCursor::new(bytes));
            let px = dec.decode().map_err(|e| derr(format!("{e:?}")))?;
            let info = dec.info().ok_or_else(|| derr("no header".into()))?;
            let cs = dec.output_colorspace().ok_or_else(|| derr("no colour space".into()))?;
            from_colorspace(info.width as usize, info.height as usize, cs.num_components(), cs.has_alpha(), px)
                .map_err(|e| derr(e.to_string()))
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

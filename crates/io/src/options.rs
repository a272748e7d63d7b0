//! Options shared by every frame source.

use std::path::PathBuf;

use crate::SourceError;

/// Default frame step: every frame.
pub const DEFAULT_SKIP: usize = 1;
/// Default first source frame.
pub const DEFAULT_START: usize = 0;
/// Default `ffmpeg` program (found on `PATH`).
pub const DEFAULT_FFMPEG: &str = "ffmpeg";
/// Default `ffprobe` program (found on `PATH`).
pub const DEFAULT_FFPROBE: &str = "ffprobe";

/// Which frames to read from a source, and how.
///
/// Selection: source frames `start, start + skip, start + 2 skip, ...`, then
/// at most `max_frames` of them.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceOptions {
    /// Take every `skip`-th source frame; at least 1. Default 1 (every frame).
    pub skip: usize,
    /// Stop after this many frames (after skipping); `None` = all. Default `None`.
    pub max_frames: Option<usize>,
    /// First source frame to take (0-based). Default 0.
    pub start: usize,
    /// Frame rate for image folders without timestamps (plain folders): the
    /// timestamp of source frame `i` is `i / fps`. `None` (the default) gives
    /// `0, 1, 2, ...` seconds. For videos it overrides a missing or unusable
    /// frame rate in the file (timestamps still come from the frames' pts when
    /// the file has them).
    pub fps: Option<f64>,
    /// Video decoding options.
    pub video: VideoOptions,
}

impl Default for SourceOptions {
    fn default() -> Self {
        Self { skip: DEFAULT_SKIP, max_frames: None, start: DEFAULT_START, fps: None, video: VideoOptions::default() }
    }
}

impl SourceOptions {
    /// Checks the options: `skip >= 1`, `max_frames != Some(0)`, `fps` finite
    /// and positive, and the video options.
    pub fn validate(&self) -> Result<(), SourceError> {
        if self.skip == 0 {
            return Err(SourceError::InvalidOptions("skip must be at least 1 (1 = every frame), got 0".into()));
        }
        if self.max_frames == Some(0) {
            return Err(SourceError::InvalidOptions(
                "max_frames must be at least 1 (or unset for all frames), got 0".into(),
            ));
        }
        if let Some(fps) = self.fps
            && !(fps.is_finite() && fps > 0.0)
        {
            return Err(SourceError::InvalidOptions(format!("fps must be finite and positive, got {fps}")));
        }
        self.video.validate()
    }

    /// Number of frames selected from a source of `total` frames.
    pub fn selected_count(&self, total: usize) -> usize {
        let step = self.skip.max(1);
        let n = if total > self.start { (total - self.start).div_ceil(step) } else { 0 };
        match self.max_frames {
            Some(m) => n.min(m),
            None => n,
        }
    }

    /// Source index of the `k`-th selected frame.
    pub fn source_index(&self, k: usize) -> usize {
        self.start + k * self.skip.max(1)
    }
}

/// Colour of the frames decoded from a video.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VideoColor {
    /// Gray when the video's pixel format is gray (e.g. `gray`, `gray10le`,
    /// `ya8`), RGB otherwise. Default.
    #[default]
    Auto,
    /// Always 3-channel RGB.
    Rgb,
    /// Always 1-channel gray (ffmpeg converts).
    Gray,
}

/// How videos are decoded (through the `ffmpeg` and `ffprobe` programs).
#[derive(Debug, Clone, PartialEq)]
pub struct VideoOptions {
    /// Output colour. Default [`VideoColor::Auto`].
    pub color: VideoColor,
    /// The `ffmpeg` program. Default `"ffmpeg"` (on `PATH`).
    pub ffmpeg: PathBuf,
    /// The `ffprobe` program. Default `"ffprobe"` (on `PATH`).
    pub ffprobe: PathBuf,
}

impl Default for VideoOptions {
    fn default() -> Self {
        Self { color: VideoColor::Auto, ffmpeg: PathBuf::from(DEFAULT_FFMPEG), ffprobe: PathBuf::from(DEFAULT_FFPROBE) }
    }
}

impl VideoOptions {
    /// Checks that both program paths are non-empty.
    pub fn validate(&self) -> Result<(), SourceError> {
        if self.ffmpeg.as_os_str().is_empty() || self.ffprobe.as_os_str().is_empty() {
            return Err(SourceError::InvalidOptions("the ffmpeg and ffprobe program paths must not be empty".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_counts() {
        let mut o = SourceOptions::default();
        assert_eq!(o.selected_count(10), 10);
        o.skip = 3; // 0 3 6 9
        assert_eq!(o.selected_count(10), 4);
        assert_eq!(o.source_index(3), 9);
        o.start = 1; // 1 4 7
        assert_eq!(o.selected_count(10), 3);
        assert_eq!(o.source_index(2), 7);
        o.max_frames = Some(2);
        assert_eq!(o.selected_count(10), 2);
        o.start = 10;
        assert_eq!(o.selected_count(10), 0);
    }

    #[test]
    fn validation() {
        assert!(SourceOptions::default().validate().is_ok());
        let o = SourceOptions { skip: 0, ..Default::default() };
        assert!(o.validate().unwrap_err().to_string().contains("skip"));
        let o = SourceOptions { max_frames: Some(0), ..Default::default() };
        assert!(o.validate().is_err());
        let o = SourceOptions { fps: Some(f64::NAN), ..Default::default() };
        assert!(o.validate().is_err());
        let o = SourceOptions { fps: Some(-1.0), ..Default::default() };
        assert!(o.validate().is_err());
    }
}

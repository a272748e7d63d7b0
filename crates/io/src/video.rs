//! Video files decoded by the `ffmpeg` program: `ffprobe` (JSON) gives the
//! size, frame count and packet timestamps without decoding; `ffmpeg` pipes
//! raw RGB or gray frames, of which exactly one frame's bytes are read per
//! `next()`. Frame selection (start/skip) runs inside ffmpeg with its
//! `select` filter, so dropped frames never cross the pipe, and
//! `-frames:v` stops it at the limit.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStderr, ChildStdout, Command, ExitStatus, Stdio};
use std::thread::JoinHandle;

use colslam_image::Image;
use serde_json::Value;

use crate::{Frame, FrameSource, SourceError, SourceKind, SourceOptions, VideoColor, find_camera_file};

/// Frame rate assumed when neither the file nor the options give one.
pub const DEFAULT_VIDEO_FPS: f64 = 30.0;
/// Bytes of ffmpeg's stderr kept for error messages (the tail is what matters).
const STDERR_KEEP_BYTES: usize = 16 * 1024;
/// Lines of ffmpeg's stderr quoted in an error message.
const STDERR_QUOTE_LINES: usize = 6;
/// Largest frame accepted (bytes), against absurd sizes in damaged headers.
const MAX_FRAME_BYTES: usize = 1 << 30;

/// What ffprobe tells about the video stream.
#[derive(Debug, Clone)]
struct VideoInfo {
    width: usize,
    height: usize,
    pix_fmt: String,
    codec: String,
    /// Frames in the stream: the container's frame count, else its
    /// non-discarded packets (one decoded frame each).
    total: usize,
    /// Frame rate used for timestamps when pts are unusable.
    fps: f64,
    /// Presentation timestamps (s) of the frames in display order; empty when
    /// the packets have none or their count disagrees with `total`.
    pts: Vec<f64>,
    /// Stream start time (s).
    start_time: f64,
}

/// A running ffmpeg child and the thread draining its stderr (so a chatty
/// ffmpeg can never block on a full stderr pipe while we read stdout).
struct Running {
    child: Child,
    stdout: ChildStdout,
    stderr: Option<JoinHandle<String>>,
}

impl Running {
    /// Stops the child (killing it first when `kill`), reaps it and returns
    /// its exit status and the tail of its stderr.
    fn finish(&mut self, kill: bool) -> (Option<ExitStatus>, String) {
        if kill {
            // Err only if it already exited, which `wait` then reaps.
            let _ = self.child.kill();
        }
        let status = self.child.wait().ok();
        let text = self.stderr.take().and_then(|h| h.join().ok()).unwrap_or_default();
        (status, text)
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        // Never leave a running or zombie ffmpeg behind.
        if self.stderr.is_some() {
            self.finish(true);
        }
    }
}

/// A video file read through `ffmpeg`, one frame per `next()`; see the module docs.
pub struct VideoSource {
    path: PathBuf,
    opts: SourceOptions,
    info: VideoInfo,
    channels: usize,
    /// Frames to yield (after start, skip and limit).
    selected: usize,
    camera_file: Option<PathBuf>,
    running: Option<Running>,
    yielded: usize,
    finished: bool,
}

impl std::fmt::Debug for VideoSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VideoSource")
            .field("path", &self.path)
            .field("info", &self.info)
            .field("channels", &self.channels)
            .field("selected", &self.selected)
            .field("yielded", &self.yielded)
            .field("ffmpeg_pid", &self.ffmpeg_pid())
            .finish()
    }
}

impl VideoSource {
    /// Probes `path` with ffprobe; ffmpeg itself starts at the first `next()`.
    pub fn open(path: &Path, opts: &SourceOptions) -> Result<Self, SourceError> {
        opts.validate()?;
        crate::error::check_regular_file(path).map_err(|p| SourceError::not_a_file(path, p))?;
        let info = probe(path, opts)?;
        let gray = match opts.video.color {
            VideoColor::Gray => true,
            VideoColor::Rgb => false,
            VideoColor::Auto => is_gray_format(&info.pix_fmt),
        };
        let selected = opts.selected_count(info.total);
        if selected == 0 {
            return Err(SourceError::NoFrames {
                path: path.to_path_buf(),
                reason: format!(": start {} is past its {} frames", opts.start, info.total),
            });
        }
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        Ok(Self {
            path: path.to_path_buf(),
            opts: opts.clone(),
            camera_file: find_camera_file(&[&parent]),
            channels: if gray { 1 } else { 3 },
            info,
            selected,
            running: None,
            yielded: 0,
            finished: false,
        })
    }

    /// The ffmpeg child's process id while it runs (for diagnostics and tests).
    pub fn ffmpeg_pid(&self) -> Option<u32> {
        self.running.as_ref().map(|r| r.child.id())
    }

    /// Channels of the frames: 1 (gray) or 3 (RGB).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Frame rate used for timestamps without pts (from the file or options).
    pub fn fps(&self) -> f64 {
        self.info.fps
    }

    fn frame_bytes(&self) -> Result<usize, SourceError> {
        self.info
            .width
            .checked_mul(self.info.height)
            .and_then(|p| p.checked_mul(self.channels))
            .filter(|&b| b > 0 && b <= MAX_FRAME_BYTES)
            .ok_or_else(|| SourceError::Video {
                path: self.path.clone(),
                reason: format!("unusable frame size {}x{}", self.info.width, self.info.height),
            })
    }

    fn ffmpeg_args(&self) -> Vec<std::ffi::OsString> {
        let mut a: Vec<std::ffi::OsString> = Vec::new();
        let mut push = |s: &str| a.push(s.into());
        // -noautorotate: frames keep the coded size ffprobe reported.
        for s in ["-v", "error", "-nostdin", "-noautorotate", "-i"] {
            push(s);
        }
        a.push(self.path.as_os_str().to_owned());
        let mut push = |s: &str| a.push(s.into());
        for s in ["-map", "0:v:0", "-an", "-sn", "-dn"] {
            push(s);
        }
        let (start, skip) = (self.opts.start, self.opts.skip.max(1));
        if start > 0 || skip > 1 {
            // `n` is the decoded frame's index; commas escaped for the filtergraph.
            push("-vf");
            push(&format!("select=gte(n\\,{start})*not(mod(n-{start}\\,{skip}))"));
        }
        // Passthrough: without it ffmpeg re-times to constant rate and
        // duplicates frames to fill the gaps `select` leaves. `-fps_mode`
        // replaced the deprecated `-vsync` in ffmpeg 5.1.
        let sync = if supports_fps_mode(&self.opts.video.ffmpeg) { "-fps_mode" } else { "-vsync" };
        for s in [sync, "passthrough", "-frames:v"] {
            push(s);
        }
        push(&self.selected.to_string());
        let pix = if self.channels == 1 { "gray" } else { "rgb24" };
        for s in ["-f", "rawvideo", "-pix_fmt", pix, "-"] {
            push(s);
        }
        a
    }

    fn start(&mut self) -> Result<(), SourceError> {
        let program = &self.opts.video.ffmpeg;
        let mut child = Command::new(program)
            .args(self.ffmpeg_args())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| SourceError::FfmpegMissing {
                program: program.clone(),
                path: self.path.clone(),
                reason: e.to_string(),
            })?;
        let (Some(stdout), Some(stderr)) = (child.stdout.take(), child.stderr.take()) else {
            // Invariant: both were requested as pipes above.
            let _ = child.kill();
            let _ = child.wait();
            return Err(SourceError::Video { path: self.path.clone(), reason: "ffmpeg pipes unavailable".into() });
        };
        let handle = std::thread::Builder::new()
            .name("ffmpeg-stderr".into())
            .spawn(move || drain_tail(stderr))
            .map_err(|e| SourceError::io(&self.path, e));
        let handle = match handle {
            Ok(h) => h,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        self.running = Some(Running { child, stdout, stderr: Some(handle) });
        Ok(())
    }

    /// Stops ffmpeg; returns its status and stderr tail (nothing if not running).
    fn stop(&mut self, kill: bool) -> (Option<ExitStatus>, String) {
        self.finished = true;
        match self.running.take() {
            Some(mut r) => r.finish(kill),
            None => (None, String::new()),
        }
    }

    fn timestamp(&self, source_index: usize) -> f64 {
        match self.info.pts.get(source_index) {
            Some(&t) => t,
            None => self.info.start_time + source_index as f64 / self.info.fps,
        }
    }

    /// The end of ffmpeg's output: a clean end, or an error from its status/stderr.
    fn end_of_stream(&mut self) -> Option<Result<Frame, SourceError>> {
        let (status, stderr) = self.stop(false);
        let message = quote_stderr(&stderr);
        let ok = status.is_some_and(|s| s.success());
        let path = self.path.clone();
        if !ok {
            let code = status.and_then(|s| s.code()).map_or("a signal".to_string(), |c| format!("code {c}"));
            let reason =
                format!("ffmpeg exited with {code}: {}", if message.is_empty() { "no message" } else { &message });
            return Some(Err(if self.yielded == 0 {
                SourceError::Video { path, reason }
            } else {
                SourceError::VideoTruncated { path, frames_read: self.yielded, reason }
            }));
        }
        if self.yielded == 0 {
            let reason = if message.is_empty() { String::new() } else { format!(": {message}") };
            return Some(Err(SourceError::NoFrames { path, reason }));
        }
        if self.yielded < self.selected {
            if !message.is_empty() {
                return Some(Err(SourceError::VideoTruncated {
                    path,
                    frames_read: self.yielded,
                    reason: format!("expected {} frames; ffmpeg: {message}", self.selected),
                }));
            }
            tracing::warn!(
                "video {}: ffmpeg delivered {} of the {} frames its container announced",
                path.display(),
                self.yielded,
                self.selected
            );
        }
        None
    }
}

impl Iterator for VideoSource {
    type Item = Result<Frame, SourceError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.finished {
            return None;
        }
        if self.yielded >= self.selected {
            // Limit reached: no need to let ffmpeg flush the rest.
            self.stop(true);
            return None;
        }
        let bytes = match self.frame_bytes() {
            Ok(b) => b,
            Err(e) => {
                self.finished = true;
                return Some(Err(e));
            }
        };
        if self.running.is_none()
            && let Err(e) = self.start()
        {
            self.finished = true;
            return Some(Err(e));
        }
        let mut buf = vec![0u8; bytes];
        let got = match self.running.as_mut().map(|r| read_full(&mut r.stdout, &mut buf)) {
            Some(Ok(n)) => n,
            Some(Err(e)) => {
                self.stop(true);
                return Some(Err(SourceError::io(&self.path, e)));
            }
            // Invariant: started just above.
            None => return None,
        };
        if got == 0 {
            return self.end_of_stream();
        }
        if got < bytes {
            let (_, stderr) = self.stop(true);
            let msg = quote_stderr(&stderr);
            return Some(Err(SourceError::VideoTruncated {
                path: self.path.clone(),
                frames_read: self.yielded,
                reason: format!(
                    "partial final frame ({got} of {bytes} bytes){}",
                    if msg.is_empty() { String::new() } else { format!("; ffmpeg: {msg}") }
                ),
            }));
        }
        let image = match Image::from_vec(self.info.width, self.info.height, self.channels, buf) {
            Ok(img) => img,
            Err(e) => {
                self.stop(true);
                return Some(Err(SourceError::Video { path: self.path.clone(), reason: e.to_string() }));
            }
        };
        let index = self.yielded;
        self.yielded += 1;
        let source_index = self.opts.source_index(index);
        Some(Ok(Frame {
            index,
            source_index,
            timestamp: self.timestamp(source_index),
            name: format!("frame_{source_index:06}"),
            image,
        }))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (0, Some(self.selected.saturating_sub(self.yielded)))
    }
}

impl FrameSource for VideoSource {
    fn len_hint(&self) -> Option<usize> {
        Some(self.selected)
    }
    fn total_source_frames(&self) -> Option<usize> {
        Some(self.info.total)
    }
    fn image_size(&self) -> Option<(usize, usize)> {
        Some((self.info.width, self.info.height))
    }
    fn camera_file(&self) -> Option<PathBuf> {
        self.camera_file.clone()
    }
    fn kind(&self) -> SourceKind {
        SourceKind::Video
    }
    fn path(&self) -> &Path {
        &self.path
    }
    fn describe(&self) -> String {
        let mut s = format!("video {} ({} frames", self.path.display(), self.selected);
        if self.selected != self.info.total {
            s.push_str(&format!(" of {}", self.info.total));
        }
        s.push_str(&format!(
            ", {}x{}, {:.3} fps, {} {})",
            self.info.width,
            self.info.height,
            self.info.fps,
            self.info.codec,
            if self.channels == 1 { "gray" } else { "RGB" }
        ));
        s
    }
}

/// Reads until `buf` is full or the stream ends; returns the bytes read.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match r.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// Reads a child's stderr to its end, keeping the last [`STDERR_KEEP_BYTES`].
fn drain_tail(mut stderr: ChildStderr) -> String {
    let mut kept: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        match stderr.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => {
                kept.extend_from_slice(&chunk[..n]);
                if kept.len() > STDERR_KEEP_BYTES {
                    let cut = kept.len() - STDERR_KEEP_BYTES;
                    kept.drain(..cut);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
    String::from_utf8_lossy(&kept).into_owned()
}

/// The last few non-empty lines of a program's stderr, joined with " | ",
/// without ffmpeg's `[component @ 0x55...] ` prefixes (they hold addresses,
/// which would make messages differ between runs).
fn quote_stderr(text: &str) -> String {
    let lines: Vec<&str> = text.lines().map(strip_component).filter(|l| !l.is_empty()).collect();
    let from = lines.len().saturating_sub(STDERR_QUOTE_LINES);
    lines.get(from..).unwrap_or_default().join(" | ")
}

fn strip_component(line: &str) -> &str {
    let line = line.trim();
    if line.starts_with('[')
        && let Some(end) = line.find("] ")
        && line[..end].contains(" @ 0x")
    {
        return line[end + 2..].trim();
    }
    line
}

/// First ffmpeg release with `-fps_mode` (major, minor).
const FPS_MODE_SINCE: (u32, u32) = (5, 1);

/// Whether this ffmpeg takes `-fps_mode` (5.1 and later), from its
/// `-version` banner; cached per program. Unparsable versions (git builds
/// such as `N-112233-gabc`) are taken as recent.
fn supports_fps_mode(ffmpeg: &Path) -> bool {
    static CACHE: std::sync::Mutex<Vec<(PathBuf, bool)>> = std::sync::Mutex::new(Vec::new());
    if let Ok(cache) = CACHE.lock()
        && let Some((_, v)) = cache.iter().find(|(p, _)| p == ffmpeg)
    {
        return *v;
    }
    let banner = Command::new(ffmpeg)
        .args(["-hide_banner", "-version"])
        .stdin(Stdio::null())
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_default();
    let v = parse_ffmpeg_version(&banner).is_none_or(|ver| ver >= FPS_MODE_SINCE);
    if let Ok(mut cache) = CACHE.lock() {
        cache.push((ffmpeg.to_path_buf(), v));
    }
    v
}

/// `(major, minor)` from `ffmpeg version 5.1.9-0+deb12u1 ...` or `ffmpeg version n7.0 ...`.
fn parse_ffmpeg_version(banner: &str) -> Option<(u32, u32)> {
    let word = banner.lines().next()?.split_whitespace().nth(2)?;
    let word = word.strip_prefix('n').unwrap_or(word);
    let mut parts = word.split(|c: char| !c.is_ascii_digit());
    let major = parts.next()?.parse().ok()?;
    let minor = parts.next().and_then(|m| m.parse().ok()).unwrap_or(0);
    Some((major, minor))
}

fn is_gray_format(pix_fmt: &str) -> bool {
    ["gray", "ya", "monob", "monow"].iter().any(|p| pix_fmt.starts_with(p))
}

/// Parses "num/den" (or a plain number) to a positive finite value.
fn parse_rational(s: &str) -> Option<f64> {
    let v = match s.split_once('/') {
        Some((n, d)) => n.trim().parse::<f64>().ok()? / d.trim().parse::<f64>().ok()?,
        None => s.trim().parse::<f64>().ok()?,
    };
    (v.is_finite() && v > 0.0).then_some(v)
}

/// Runs ffprobe on the first video stream: stream fields and every packet's
/// pts and flags (demuxing only, no decoding).
fn probe(path: &Path, opts: &SourceOptions) -> Result<VideoInfo, SourceError> {
    let program = &opts.video.ffprobe;
    let out = Command::new(program)
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg("stream=width,height,pix_fmt,codec_name,nb_frames,avg_frame_rate,r_frame_rate,time_base,start_time:packet=pts,flags")
        .args(["-of", "json"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| SourceError::FfmpegMissing { program: program.clone(), path: path.to_path_buf(), reason: e.to_string() })?;
    let stderr = quote_stderr(&String::from_utf8_lossy(&out.stderr));
    if !out.status.success() {
        // mp4/mov keep their index (moov) at the end unless made "faststart",
        // so a cut-off download typically fails this way.
        let hint = if stderr.contains("moov atom not found") { "; the file may be truncated" } else { "" };
        let reason = format!(
            "unreadable or corrupt video (ffprobe: {}){hint}",
            if stderr.is_empty() { "failed without a message" } else { &stderr }
        );
        return Err(SourceError::Video { path: path.to_path_buf(), reason });
    }
    let bad = |reason: String| SourceError::Video { path: path.to_path_buf(), reason };
    let json: Value =
        serde_json::from_slice(&out.stdout).map_err(|e| bad(format!("cannot parse ffprobe output: {e}")))?;
    parse_probe(&json, opts).map_err(|r| bad(if stderr.is_empty() { r } else { format!("{r} (ffprobe: {stderr})") }))
}

/// Interprets ffprobe's JSON; errors are reasons (the caller adds the path).
fn parse_probe(json: &Value, opts: &SourceOptions) -> Result<VideoInfo, String> {
    let stream = json
        .get("streams")
        .and_then(|s| s.as_array())
        .and_then(|s| s.first())
        .ok_or_else(|| "no video stream found".to_string())?;
    let dim = |k: &str| stream.get(k).and_then(Value::as_u64).and_then(|v| usize::try_from(v).ok()).unwrap_or(0);
    let (width, height) = (dim("width"), dim("height"));
    if width == 0 || height == 0 {
        return Err("the video stream has no frame size".into());
    }
    // The same budget as image files: a damaged or hostile header must not
    // make every `next()` allocate a frame of gigabytes.
    colslam_image::check_size(width, height, Path::new("")).map_err(|e| match e {
        colslam_image::ImageError::TooLarge { reason, .. } => {
            format!("frame size {width}x{height} is too large to decode ({reason})")
        }
        other => other.to_string(),
    })?;
    let text = |k: &str| stream.get(k).and_then(Value::as_str).unwrap_or_default().to_string();
    let fps = parse_rational(&text("avg_frame_rate"))
        .or_else(|| parse_rational(&text("r_frame_rate")))
        .or(opts.fps)
        .unwrap_or_else(|| {
            tracing::warn!("video has no frame rate; assuming {DEFAULT_VIDEO_FPS} fps");
            DEFAULT_VIDEO_FPS
        });
    let time_base = parse_rational(&text("time_base"));
    let start_time = text("start_time").parse::<f64>().ok().filter(|t| t.is_finite()).unwrap_or(0.0);
    let packets = json.get("packets").and_then(Value::as_array).map(Vec::as_slice).unwrap_or_default();
    let mut total = 0;
    let mut pts = Vec::new();
    for p in packets {
        let discard = p.get("flags").and_then(Value::as_str).is_some_and(|f| f.contains('D'));
        if discard {
            continue;
        }
        total += 1;
        if let (Some(v), Some(tb)) = (p.get("pts").and_then(Value::as_i64), time_base) {
            pts.push(v as f64 * tb);
        }
    }
    // The container's own count wins when it has one: in a truncated file
    // the index still announces every frame while fewer packets remain, and
    // that gap is how a truncation is told from a clean end.
    if let Some(declared) = text("nb_frames").parse::<usize>().ok().filter(|&n| n > 0) {
        if declared != total {
            tracing::debug!("video stream declares {declared} frames but {total} packets were found");
        }
        total = declared;
    }
    if total == 0 {
        return Err("the video has no frames".into());
    }
    if pts.len() == total {
        // Packets come in decode order; frames leave the decoder in pts order.
        pts.sort_by(f64::total_cmp);
    } else {
        pts.clear();
    }
    Ok(VideoInfo { width, height, pix_fmt: text("pix_fmt"), codec: text("codec_name"), total, fps, pts, start_time })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rationals() {
        assert_eq!(parse_rational("30/1"), Some(30.0));
        assert_eq!(parse_rational("30000/1001").map(|v| (v * 1000.0).round()), Some(29970.0));
        assert_eq!(parse_rational("0/0"), None);
        assert_eq!(parse_rational("25"), Some(25.0));
        assert_eq!(parse_rational(""), None);
    }

    #[test]
    fn probe_json_parsing() {
        let json: Value = serde_json::from_str(
            r#"{"packets":[{"pts":0,"flags":"K_"},{"pts":1024,"flags":"__"},{"pts":512,"flags":"__"},{"pts":-512,"flags":"_D"}],
               "streams":[{"width":64,"height":48,"pix_fmt":"gray","codec_name":"ffv1","avg_frame_rate":"30/1","time_base":"1/15360"}]}"#,
        )
        .unwrap();
        let info = parse_probe(&json, &SourceOptions::default()).unwrap();
        assert_eq!((info.width, info.height, info.total), (64, 48, 3));
        assert_eq!(info.pts, vec![0.0, 512.0 / 15360.0, 1024.0 / 15360.0]);
        assert!(is_gray_format(&info.pix_fmt));
        let none: Value = serde_json::from_str(r#"{"streams":[]}"#).unwrap();
        assert!(parse_probe(&none, &SourceOptions::default()).unwrap_err().contains("no video stream"));
        let huge: Value = serde_json::from_str(
            r#"{"packets":[{"pts":0,"flags":"K_"}],"streams":[{"width":16000,"height":16000,"pix_fmt":"gray16le"}]}"#,
        )
        .unwrap();
        let e = parse_probe(&huge, &SourceOptions::default()).unwrap_err();
        assert!(e.contains("16000x16000") && e.contains("too large"), "{e}");
    }

    #[test]
    fn ffmpeg_versions() {
        assert_eq!(parse_ffmpeg_version("ffmpeg version 5.1.9-0+deb12u1 Copyright (c) 2000-2026"), Some((5, 1)));
        assert_eq!(parse_ffmpeg_version("ffmpeg version 4.4.2-0ubuntu0.22.04.1 Copyright"), Some((4, 4)));
        assert_eq!(parse_ffmpeg_version("ffmpeg version n7.0 Copyright"), Some((7, 0)));
        assert_eq!(parse_ffmpeg_version("ffmpeg version N-112233-gabcdef Copyright"), None);
        assert_eq!(parse_ffmpeg_version(""), None);
        assert!((4, 4) < FPS_MODE_SINCE && (7, 0) >= FPS_MODE_SINCE);
    }

    #[test]
    fn stderr_quote_keeps_last_lines() {
        let text = (0..20).map(|i| format!("line {i}\n")).collect::<String>();
        let q = quote_stderr(&text);
        assert!(q.starts_with("line 14") && q.ends_with("line 19"), "{q}");
        let q =
            quote_stderr("[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55a00b9c5100] moov atom not found\n/x/r.mp4: Invalid data\n");
        assert_eq!(q, "moov atom not found | /x/r.mp4: Invalid data");
        assert_eq!(strip_component("[h264] odd"), "[h264] odd");
    }
}

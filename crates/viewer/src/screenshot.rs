//! Deterministic screenshots of the page (`colslam view MODEL --screenshot`):
//! headless Chromium opens the page with `?screenshot=1`, which draws the
//! state once without the live event stream (a stream never lets virtual
//! time settle) and marks `<body data-screenshot="drawn">` when the scene,
//! the frame panel and its keypoints are drawn. Chromium runs on virtual
//! time, so timers and animations cannot make two pictures differ, and its
//! `--dump-dom` output, taken at the same moment as the picture, proves the
//! page had finished drawing.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Environment variable naming the Chromium binary.
pub const CHROMIUM_ENV: &str = "COLSLAM_CHROMIUM";
/// Programs searched on `PATH` when [`CHROMIUM_ENV`] is not set.
pub const CHROMIUM_NAMES: [&str; 3] = ["chromium", "chromium-browser", "google-chrome"];
/// Default picture size.
pub const DEFAULT_SIZE: (u32, u32) = (1280, 800);
/// Virtual time the page gets to load and draw (network waits do not count).
const VIRTUAL_TIME_BUDGET_MS: u32 = 20_000;
/// Wall-clock bound on one Chromium run.
const CHROMIUM_TIMEOUT: Duration = Duration::from_secs(120);
/// The attribute the page sets on `<body>` once everything is drawn.
const DRAWN_MARK: &str = "data-screenshot=\"drawn\"";
/// Largest side accepted for a screenshot.
const MAX_SIDE: u32 = 8192;

/// Why a screenshot was not written.
#[derive(Debug, thiserror::Error)]
pub enum ScreenshotError {
    /// No Chromium was found.
    #[error(
        "no Chromium found: set COLSLAM_CHROMIUM to its path, or put one of chromium, chromium-browser, google-chrome on PATH"
    )]
    NoChromium,
    /// `COLSLAM_CHROMIUM` names a file that does not exist.
    #[error("COLSLAM_CHROMIUM={0} does not exist")]
    ChromiumMissing(PathBuf),
    /// The size is not `WxH` within bounds.
    #[error("invalid screenshot size {0:?}: expected WIDTHxHEIGHT, each 16 to 8192 (e.g. 1280x800)")]
    Size(String),
    /// Chromium could not be started or waited for.
    #[error("cannot run {program}")]
    Spawn {
        /// The Chromium binary.
        program: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Chromium ran past its time.
    #[error("{program} did not finish within {seconds} s")]
    Timeout {
        /// The Chromium binary.
        program: PathBuf,
        /// The bound.
        seconds: u64,
    },
    /// Chromium failed or wrote no picture.
    #[error("{program} wrote no screenshot: {message}")]
    Failed {
        /// The Chromium binary.
        program: PathBuf,
        /// Its exit and last error lines.
        message: String,
    },
    /// The page never said it had drawn the scene.
    #[error(
        "the page did not finish drawing within {VIRTUAL_TIME_BUDGET_MS} ms of virtual time (no {DRAWN_MARK}; it reached {stage:?})"
    )]
    NotDrawn {
        /// The last stage the page reported.
        stage: String,
    },
    /// The picture could not be written.
    #[error("{path}: cannot write the screenshot")]
    Write {
        /// The output file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

/// Parses `WIDTHxHEIGHT` (e.g. `1280x800`).
pub fn parse_size(s: &str) -> Result<(u32, u32), ScreenshotError> {
    let bad = || ScreenshotError::Size(s.to_string());
    let (w, h) = s.trim().split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if !(16..=MAX_SIDE).contains(&w) || !(16..=MAX_SIDE).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// The Chromium to use: [`CHROMIUM_ENV`] when set (it must exist), else the
/// first of [`CHROMIUM_NAMES`] on `PATH`.
pub fn find_chromium() -> Result<PathBuf, ScreenshotError> {
    find_chromium_in(std::env::var_os(CHROMIUM_ENV), std::env::var_os("PATH"))
}

fn find_chromium_in(
    explicit: Option<std::ffi::OsString>,
    path: Option<std::ffi::OsString>,
) -> Result<PathBuf, ScreenshotError> {
    if let Some(p) = explicit.filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() { Ok(p) } else { Err(ScreenshotError::ChromiumMissing(p)) };
    }
    let dirs: Vec<PathBuf> = path.map(|p| std::env::split_paths(&p).collect()).unwrap_or_default();
    CHROMIUM_NAMES
        .iter()
        .flat_map(|name| dirs.iter().map(move |d| d.join(name)))
        .find(|p| p.is_file())
        .ok_or(ScreenshotError::NoChromium)
}

/// The page URL in screenshot mode (`url` is [`crate::Viewer::url`]).
pub fn screenshot_url(url: &str) -> String {
    let sep = if url.contains('?') { '&' } else { '?' };
    format!("{url}{sep}screenshot=1")
}

/// Opens `url` (the viewer's page) in headless `chromium` in screenshot
/// mode at `size` and writes the picture to `out` (PNG, atomically), once
/// the page says it has drawn everything.
pub fn capture(chromium: &Path, url: &str, size: (u32, u32), out: &Path) -> Result<(), ScreenshotError> {
    let work = ScratchDir::new().map_err(|source| ScreenshotError::Write { path: out.to_path_buf(), source })?;
    let shot = work.0.join("shot.png");
    let spawn = |source| ScreenshotError::Spawn { program: chromium.to_path_buf(), source };
    let mut child = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--mute-audio",
        ])
        .arg(format!("--user-data-dir={}", work.0.join("profile").display()))
        .arg(format!("--window-size={},{}", size.0, size.1))
        .arg(format!("--virtual-time-budget={VIRTUAL_TIME_BUDGET_MS}"))
        .arg(format!("--screenshot={}", shot.display()))
        .arg("--dump-dom")
        .arg(screenshot_url(url))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(spawn)?;
    // Both pipes are drained on threads so a chatty Chromium cannot block.
    let drain = |r: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(mut r) = r {
                let _ = r.read_to_string(&mut s);
            }
            s
        })
    };
    let dom = drain(child.stdout.take().map(|o| Box::new(o) as _));
    let log = drain(child.stderr.take().map(|e| Box::new(e) as _));
    let start = Instant::now();
    let status = loop {
        match child.try_wait().map_err(spawn)? {
            Some(st) => break st,
            None if start.elapsed() > CHROMIUM_TIMEOUT => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(ScreenshotError::Timeout {
                    program: chromium.to_path_buf(),
                    seconds: CHROMIUM_TIMEOUT.as_secs(),
                });
            }
            None => std::thread::sleep(Duration::from_millis(50)),
        }
    };
    let (dom, log) = (dom.join().unwrap_or_default(), log.join().unwrap_or_default());
    tracing::debug!("chromium exited with {status} after {:.1} s", start.elapsed().as_secs_f64());
    let png = match std::fs::read(&shot) {
        Ok(png) if status.success() && png.starts_with(b"\x89PNG") => png,
        _ => {
            let tail: Vec<&str> = log.lines().filter(|l| !l.contains("dbus")).rev().take(3).collect();
            let message = format!("{status}; {}", tail.into_iter().rev().collect::<Vec<_>>().join(" | "));
            return Err(ScreenshotError::Failed { program: chromium.to_path_buf(), message });
        }
    };
    if !dom.contains(DRAWN_MARK) {
        let stage = dom
            .split_once("data-screenshot-stage=\"")
            .and_then(|(_, rest)| rest.split_once('"'))
            .map_or("nothing (the page did not start)", |(stage, _)| stage);
        return Err(ScreenshotError::NotDrawn { stage: stage.to_string() });
    }
    colslam_image::write_atomic(out, &png).map_err(|source| ScreenshotError::Write { path: out.to_path_buf(), source })
}

/// A private temporary folder (Chromium's profile and picture), removed on drop.
struct ScratchDir(PathBuf);

impl ScratchDir {
    fn new() -> std::io::Result<Self> {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let dir = std::env::temp_dir().join(format!("colslam-screenshot-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        Ok(Self(dir))
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        // Best effort: a leftover temporary folder is harmless.
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_bad_ones_are_refused() {
        assert_eq!(parse_size("1280x800").ok(), Some((1280, 800)));
        assert_eq!(parse_size(" 640X480 ").ok(), Some((640, 480)));
        for bad in ["", "1280", "x800", "1280x", "0x10", "10x10", "100000x100", "-5x100", "axb"] {
            assert!(parse_size(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn chromium_is_found_from_the_variable_or_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let fake = dir.path().join("chromium-browser");
        std::fs::write(&fake, b"").expect("write");
        let path = Some(std::ffi::OsString::from(dir.path()));
        assert_eq!(find_chromium_in(None, path.clone()).ok(), Some(fake.clone()));
        assert_eq!(find_chromium_in(Some(fake.clone().into()), None).ok(), Some(fake));
        let missing = dir.path().join("nope");
        let e = find_chromium_in(Some(missing.clone().into()), path).expect_err("missing");
        assert!(e.to_string().contains(&missing.display().to_string()), "{e}");
        let e = find_chromium_in(None, Some(std::ffi::OsString::from("/nonexistent-dir"))).expect_err("none");
        assert!(e.to_string().contains("COLSLAM_CHROMIUM") && e.to_string().contains("chromium-browser"), "{e}");
    }

    #[test]
    fn the_url_gets_the_screenshot_flag() {
        assert_eq!(screenshot_url("http://127.0.0.1:1/"), "http://127.0.0.1:1/?screenshot=1");
        assert_eq!(screenshot_url("http://h:1/?token=ab"), "http://h:1/?token=ab&screenshot=1");
    }
}

//! Parsers for the image-sequence layouts: TUM `rgb.txt`, EuRoC `data.csv`,
//! KITTI `times.txt` + image folder, and plain folders. Each returns the
//! ordered list of image files with their timestamps; nothing is decoded.

use std::path::{Path, PathBuf};

use crate::{SourceError, is_image_file, is_video_file, natural_cmp};

/// Nanoseconds per second (EuRoC timestamps are integer nanoseconds).
const NANOS_PER_SECOND: u64 = 1_000_000_000;
/// Images subfolder of a EuRoC camera folder.
const EUROC_DATA_DIR: &str = "data";

/// One image of a sequence, before frame selection.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RawEntry {
    /// The image file.
    pub path: PathBuf,
    /// Its timestamp in seconds, when the layout has one.
    pub timestamp: Option<f64>,
    /// 1-based line of the list file naming it (0 when found by listing a folder).
    pub line: usize,
}

/// Non-empty, non-comment lines of a list file with their 1-based numbers.
fn content_lines(file: &Path) -> Result<Vec<(usize, String)>, SourceError> {
    let text = std::fs::read_to_string(file).map_err(|e| SourceError::io(file, e))?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect())
}

fn malformed(file: &Path, line: usize, content: &str, reason: impl Into<String>) -> SourceError {
    SourceError::MalformedLine { file: file.to_path_buf(), line, content: content.to_string(), reason: reason.into() }
}

/// Checks that `t` (on `line`) comes strictly after the previous timestamp
/// of the list, then records it. Frames of a sequence are taken in list
/// order, and a repeated or earlier stamp (a concatenated or hand-edited
/// list) would otherwise surface only later, as a degenerate evaluation.
fn check_increasing<T: PartialOrd + std::fmt::Display + Copy>(
    previous: &mut Option<(T, usize)>,
    t: T,
    file: &Path,
    line: usize,
    content: &str,
) -> Result<(), SourceError> {
    if let Some((prev, prev_line)) = *previous
        && t <= prev
    {
        let how = if t == prev { "repeats" } else { "is earlier than" };
        return Err(malformed(
            file,
            line,
            content,
            format!("timestamp {t} {how} the one on line {prev_line} ({prev}); timestamps must increase strictly"),
        ));
    }
    *previous = Some((t, line));
    Ok(())
}

fn parse_seconds(tok: &str) -> Option<f64> {
    tok.parse::<f64>().ok().filter(|t| t.is_finite())
}

/// TUM `rgb.txt`: `timestamp path` per line, `#` comments; paths relative to `dir`.
pub(crate) fn parse_tum(dir: &Path, list: &Path) -> Result<Vec<RawEntry>, SourceError> {
    let mut out = Vec::new();
    let mut previous = None;
    for (n, line) in content_lines(list)? {
        let toks: Vec<&str> = line.split_whitespace().collect();
        let [ts, rel] = toks.as_slice() else {
            return Err(malformed(list, n, &line, "expected `timestamp path`"));
        };
        let timestamp = parse_seconds(ts).ok_or_else(|| malformed(list, n, &line, format!("bad timestamp {ts:?}")))?;
        check_increasing(&mut previous, timestamp, list, n, &line)?;
        out.push(RawEntry { path: dir.join(rel), timestamp: Some(timestamp), line: n });
    }
    Ok(out)
}

/// EuRoC `data.csv`: `timestamp_ns,filename` per line, `#` header; images in `cam_dir/data/`.
pub(crate) fn parse_euroc(cam_dir: &Path, list: &Path) -> Result<Vec<RawEntry>, SourceError> {
    let data = cam_dir.join(EUROC_DATA_DIR);
    let mut out = Vec::new();
    let mut previous = None;
    for (n, line) in content_lines(list)? {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let [ns, name] = fields.as_slice() else {
            return Err(malformed(list, n, &line, "expected `timestamp_ns,filename`"));
        };
        let ns: u64 = ns.parse().map_err(|_| malformed(list, n, &line, format!("bad nanosecond timestamp {ns:?}")))?;
        if name.is_empty() {
            return Err(malformed(list, n, &line, "empty file name"));
        }
        check_increasing(&mut previous, ns, list, n, &line)?;
        // Split before converting so the fractional part keeps full precision.
        let timestamp = (ns / NANOS_PER_SECOND) as f64 + (ns % NANOS_PER_SECOND) as f64 / NANOS_PER_SECOND as f64;
        out.push(RawEntry { path: data.join(name), timestamp: Some(timestamp), line: n });
    }
    Ok(out)
}

/// KITTI: images of `image_dir` in natural order, timestamps from `times.txt`
/// (one number of seconds per line). Images with all-digit names (`000042.png`)
/// take line `42` of `times.txt`; otherwise images and lines pair by position
/// and their counts must agree.
pub(crate) fn list_kitti(image_dir: &Path, times: &Path) -> Result<Vec<RawEntry>, SourceError> {
    let mut stamps = Vec::new();
    let mut previous = None;
    for (n, line) in content_lines(times)? {
        let t = parse_seconds(&line).ok_or_else(|| malformed(times, n, &line, "expected one timestamp in seconds"))?;
        check_increasing(&mut previous, t, times, n, &line)?;
        stamps.push((n, t));
    }
    let images = list_images(image_dir)?;
    let numbered: Option<Vec<usize>> =
        images.iter().map(|p| p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<usize>().ok())).collect();
    let mut out = Vec::with_capacity(images.len());
    match numbered {
        Some(ids) => {
            for (path, id) in images.into_iter().zip(ids) {
                let &(line, t) = stamps.get(id).ok_or_else(|| SourceError::Layout {
                    path: times.to_path_buf(),
                    reason: format!(
                        "has {} timestamps but image {} needs line {}",
                        stamps.len(),
                        path.display(),
                        id + 1
                    ),
                })?;
                out.push(RawEntry { path, timestamp: Some(t), line });
            }
        }
        None => {
            if images.len() != stamps.len() {
                return Err(SourceError::Layout {
                    path: times.to_path_buf(),
                    reason: format!(
                        "has {} timestamps but {} holds {} images",
                        stamps.len(),
                        image_dir.display(),
                        images.len()
                    ),
                });
            }
            for (path, (line, t)) in images.into_iter().zip(stamps) {
                out.push(RawEntry { path, timestamp: Some(t), line });
            }
        }
    }
    Ok(out)
}

/// A plain folder: its PNG/JPEG files in natural order, no timestamps.
pub(crate) fn list_folder(dir: &Path) -> Result<Vec<RawEntry>, SourceError> {
    let images = list_images(dir)?;
    if images.is_empty() {
        return Err(SourceError::NoImages { dir: dir.to_path_buf(), hint: folder_hint(dir) });
    }
    Ok(images.into_iter().map(|path| RawEntry { path, timestamp: None, line: 0 }).collect())
}

/// Image files (by extension, hidden files excluded) of `dir`, naturally sorted by name.
pub(crate) fn list_images(dir: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let rd = std::fs::read_dir(dir).map_err(|e| SourceError::io(dir, e))?;
    let mut names = Vec::new();
    for entry in rd {
        let entry = entry.map_err(|e| SourceError::io(dir, e))?;
        let path = entry.path();
        let hidden = entry.file_name().to_string_lossy().starts_with('.');
        if !hidden && is_image_file(&path) && path.is_file() {
            names.push(path);
        }
    }
    names.sort_by(|a, b| {
        let na = a.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
        let nb = b.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
        natural_cmp(&na, &nb)
    });
    Ok(names)
}

/// A hint for an image-less folder: video files or image subfolders it holds.
fn folder_hint(dir: &Path) -> String {
    let Ok(rd) = std::fs::read_dir(dir) else { return String::new() };
    let mut videos = Vec::new();
    let mut subdirs = Vec::new();
    for e in rd.flatten() {
        let p = e.path();
        if p.is_file() && is_video_file(&p) {
            videos.push(e.file_name().to_string_lossy().into_owned());
        } else if p.is_dir() && list_images(&p).is_ok_and(|v| !v.is_empty()) {
            subdirs.push(e.file_name().to_string_lossy().into_owned());
        }
    }
    videos.sort();
    subdirs.sort();
    let mut hint = String::new();
    if !videos.is_empty() {
        hint.push_str(&format!("; it holds video file(s) {}: pass the video itself", videos.join(", ")));
    }
    if !subdirs.is_empty() {
        hint.push_str(&format!("; subfolder(s) with images: {}", subdirs.join(", ")));
    }
    hint
}

//! Image sequences (TUM, EuRoC, KITTI, plain folders): a list of image files
//! decoded one per `next()`.

use std::path::{Path, PathBuf};

use colslam_image::Image;

use crate::detect::{KITTI_CALIB, Layout};
use crate::error::{FileProblem, check_regular_file};
use crate::layouts::{RawEntry, list_folder, list_kitti, parse_euroc, parse_tum};
use crate::{Frame, FrameSource, SourceError, SourceKind, SourceOptions, detect_layout, find_camera_file, image_size};

/// EuRoC's own camera description in each camera folder.
const EUROC_SENSOR_FILE: &str = "sensor.yaml";

/// One selected image.
#[derive(Debug, Clone)]
struct Entry {
    path: PathBuf,
    timestamp: f64,
    source_index: usize,
    /// 1-based line in the list file (0 when found by listing).
    line: usize,
}

/// A sequence of image files, decoded lazily one per `next()`. Holds the
/// selected file paths only, never decoded images.
#[derive(Debug)]
pub struct ImageSequence {
    kind: SourceKind,
    path: PathBuf,
    /// The list file naming the images (rgb.txt, data.csv, times.txt).
    list: Option<PathBuf>,
    /// Selected images, in output order.
    entries: Vec<Entry>,
    total: usize,
    cursor: usize,
    /// Size from the first selected image's header, when readable.
    size: Option<(usize, usize)>,
    /// Size of the first decoded frame (the reference when no header size).
    first_decoded: Option<(usize, usize)>,
    camera_file: Option<PathBuf>,
    native_calibration: Option<PathBuf>,
}

impl ImageSequence {
    /// Opens an image sequence at `path` (any layout but video).
    pub fn open(path: &Path, opts: &SourceOptions) -> Result<Self, SourceError> {
        opts.validate()?;
        match detect_layout(path)? {
            Layout::Video { file } => Err(SourceError::Layout {
                path: file,
                reason: "is a video, not an image sequence (use VideoSource or open_source)".into(),
            }),
            layout => Self::open_layout(path, layout, opts),
        }
    }

    /// Opens the image sequence described by `layout` (found at `path`).
    /// Checks that every selected image named by a list file exists.
    pub fn open_layout(path: &Path, layout: Layout, opts: &SourceOptions) -> Result<Self, SourceError> {
        opts.validate()?;
        let (kind, raw, list, camera_file, native_calibration) = match layout {
            Layout::Video { file } => {
                return Err(SourceError::Layout { path: file, reason: "is a video, not an image sequence".into() });
            }
            Layout::Tum { dir, list } => {
                let raw = parse_tum(&dir, &list)?;
                (SourceKind::Tum, raw, Some(list), find_camera_file(&[&dir]), None)
            }
            Layout::Euroc { root, cam_dir, list } => {
                let raw = parse_euroc(&cam_dir, &list)?;
                let mav = root.join("mav0");
                let sensor = Some(cam_dir.join(EUROC_SENSOR_FILE)).filter(|p| p.is_file());
                // A camera.yaml beside the data wins; EuRoC's own sensor.yaml
                // (`intrinsics: [fu, fv, cu, cv]` lists) counts as the camera
                // file only if colslam_camera can actually read it.
                let cam = find_camera_file(&[&root, &mav, &cam_dir])
                    .or_else(|| sensor.clone().filter(|p| colslam_camera::file::read_camera_file(p).is_ok()));
                (SourceKind::Euroc, raw, Some(list), cam, sensor)
            }
            Layout::Kitti { dir, image_dir, times } => {
                let raw = list_kitti(&image_dir, &times)?;
                if raw.is_empty() {
                    return Err(SourceError::NoImages { dir: image_dir, hint: String::new() });
                }
                let calib = Some(dir.join(KITTI_CALIB)).filter(|p| p.is_file());
                (SourceKind::Kitti, raw, Some(times), find_camera_file(&[&dir]), calib)
            }
            Layout::Folder { dir } => {
                let raw = list_folder(&dir)?;
                (SourceKind::Folder, raw, None, find_camera_file(&[&dir]), None)
            }
        };
        let total = raw.len();
        let n = opts.selected_count(total);
        if n == 0 {
            let what = list.as_deref().unwrap_or(path);
            let reason = if total == 0 {
                ": it names no images".to_string()
            } else {
                format!(": start {} is past its {} frames", opts.start, total)
            };
            return Err(SourceError::NoFrames { path: what.to_path_buf(), reason });
        }
        let mut entries = Vec::with_capacity(n);
        for k in 0..n {
            let source_index = opts.source_index(k);
            // Invariant: selected_count keeps source_index(k) < total for k < n.
            let Some(RawEntry { path: img, timestamp, line }) = raw.get(source_index).cloned() else { break };
            if let Some(list) = &list
                && let Err(problem) = check_regular_file(&img)
            {
                let list = list.clone();
                return Err(match problem {
                    FileProblem::Missing => SourceError::MissingListedImage { image: img, list, line },
                    FileProblem::NotAFile(what) => SourceError::UnusableListedImage {
                        image: img,
                        list,
                        line,
                        problem: format!("is {what}, not an image file"),
                        source: None,
                    },
                    FileProblem::Unreadable(e) => SourceError::UnusableListedImage {
                        image: img,
                        list,
                        line,
                        problem: "cannot be examined".into(),
                        source: Some(e),
                    },
                });
            }
            let timestamp = timestamp.unwrap_or_else(|| match opts.fps {
                Some(fps) => source_index as f64 / fps,
                None => source_index as f64,
            });
            entries.push(Entry { path: img, timestamp, source_index, line });
        }
        let size = entries.first().and_then(|e| image_size(&e.path).ok());
        Ok(Self {
            kind,
            path: path.to_path_buf(),
            list,
            entries,
            total,
            cursor: 0,
            size,
            first_decoded: None,
            camera_file,
            native_calibration,
        })
    }

    /// Paths of the selected images, in output order (no decoding).
    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        self.entries.iter().map(|e| e.path.as_path())
    }

    /// The selected frames as the iterator will name and time them, in
    /// output order, without decoding: what a consumer needs to pair a run's
    /// outputs (image names, trajectory timestamps) with the input's files.
    pub fn listed(&self) -> impl Iterator<Item = ListedFrame<'_>> {
        self.entries.iter().map(|e| ListedFrame { name: frame_name(&e.path), path: &e.path, timestamp: e.timestamp })
    }

    /// Adds the list-file context to an image error from the header reader.
    fn in_context(&self, err: SourceError, e: &Entry) -> SourceError {
        match err {
            SourceError::Image { source, context } if context.is_empty() => SourceError::image(source, self.context(e)),
            other => other,
        }
    }

    fn context(&self, e: &Entry) -> String {
        match &self.list {
            Some(list) if e.line > 0 => format!(" (listed in {} line {})", list.display(), e.line),
            _ => String::new(),
        }
    }
}

/// One selected frame of an [`ImageSequence`], before decoding.
#[derive(Debug, Clone, PartialEq)]
pub struct ListedFrame<'a> {
    /// The frame's name ([`crate::Frame::name`]: the file name).
    pub name: String,
    /// The image file.
    pub path: &'a Path,
    /// The timestamp the frame gets ([`crate::Frame::timestamp`]).
    pub timestamp: f64,
}

/// The name a frame of an image file gets: its file name.
fn frame_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

fn size_mismatch(path: &Path, (width, height): (usize, usize), expected: (usize, usize)) -> SourceError {
    SourceError::SizeMismatch {
        path: path.to_path_buf(),
        width,
        height,
        expected_width: expected.0,
        expected_height: expected.1,
    }
}

impl Iterator for ImageSequence {
    type Item = Result<Frame, SourceError>;

    fn next(&mut self) -> Option<Self::Item> {
        let index = self.cursor;
        let e = self.entries.get(index)?.clone();
        // A failed frame is consumed too, so a caller may skip it and go on.
        self.cursor += 1;
        // The header is checked before the file is decoded: a frame of
        // another size, or one beyond the decoding budget (a few megabytes
        // of compressed zeros can announce gigabytes of pixels), is refused
        // without allocating its pixels.
        let reference = self.first_decoded.or(self.size);
        let header = match image_size(&e.path) {
            Ok(size) => size,
            Err(err) => return Some(Err(self.in_context(err, &e))),
        };
        if let Some(reference) = reference
            && header != reference
        {
            return Some(Err(size_mismatch(&e.path, header, reference)));
        }
        if let Err(err) = colslam_image::check_size(header.0, header.1, &e.path) {
            return Some(Err(SourceError::image(err, self.context(&e))));
        }
        let image = match Image::read(&e.path) {
            Ok(img) => img,
            Err(err) => return Some(Err(SourceError::image(err, self.context(&e)))),
        };
        let (w, h) = (image.width(), image.height());
        // The decoder agrees with the header parser on every valid file; a
        // file replaced between the two reads is still caught here.
        let reference = *self.first_decoded.get_or_insert(reference.unwrap_or((w, h)));
        if (w, h) != reference {
            return Some(Err(size_mismatch(&e.path, (w, h), reference)));
        }
        let name = frame_name(&e.path);
        Some(Ok(Frame { index, source_index: e.source_index, timestamp: e.timestamp, name, image }))
    }

    /// Skips `n` frames without reading their files (a second pass over
    /// the sequence reads only the frames it needs).
    fn nth(&mut self, n: usize) -> Option<Self::Item> {
        self.cursor = self.cursor.saturating_add(n).min(self.entries.len());
        self.next()
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.entries.len().saturating_sub(self.cursor);
        (left, Some(left))
    }
}

impl FrameSource for ImageSequence {
    fn len_hint(&self) -> Option<usize> {
        Some(self.entries.len())
    }
    fn total_source_frames(&self) -> Option<usize> {
        Some(self.total)
    }
    fn image_size(&self) -> Option<(usize, usize)> {
        self.first_decoded.or(self.size)
    }
    fn camera_file(&self) -> Option<PathBuf> {
        self.camera_file.clone()
    }
    fn native_calibration_file(&self) -> Option<PathBuf> {
        self.native_calibration.clone()
    }
    fn first_image(&self) -> Option<&Path> {
        self.entries.first().map(|e| e.path.as_path())
    }
    fn kind(&self) -> SourceKind {
        self.kind
    }
    fn path(&self) -> &Path {
        &self.path
    }
    fn describe(&self) -> String {
        let n = self.entries.len();
        let mut s = format!("{} {} ({n} frames", self.kind, self.path.display());
        if n != self.total {
            s.push_str(&format!(" of {}", self.total));
        }
        if let Some((w, h)) = self.size {
            s.push_str(&format!(", {w}x{h}"));
        }
        s.push(')');
        s
    }
}

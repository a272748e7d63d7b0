//! Writing a sequence in the TUM RGB-D layout:
//!
//! ```text
//! out/rgb/000000.png ...   RGB PNG frames
//! out/rgb.txt              "timestamp rgb/000000.png"
//! out/groundtruth.txt      "timestamp tx ty tz qx qy qz qw" (world_from_cam)
//! out/camera.yaml          flat key: value (model, width, height, fx, fy, cx, cy[, k1, k2, p1, p2], fps)
//! out/scene.json           room, extent, boxes, seed, options (written last)
//! ```
//!
//! Every file is written atomically. `scene.json` is the completion marker:
//! it is removed before anything is rewritten and written only after all
//! other files, so a folder with a `scene.json` whose options equal the
//! requested ones (and with every listed file present) is complete and is
//! left untouched.

use std::path::Path;
use std::time::Instant;

use colslam_image::write_atomic;
use serde::{Deserialize, Serialize};

use crate::options::{SynthError, SynthOptions, SynthReport};
use crate::scene::{Aabb, SceneBox};
use crate::{SyntheticSequence, Trajectory};

/// Version of the folder layout / `scene.json` schema; bump it when the
/// renderer's output changes so that old folders are regenerated.
pub const FORMAT_VERSION: u32 = 1;
/// Name of the completion marker.
pub const SCENE_JSON: &str = "scene.json";

/// Content of `scene.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SceneDescription {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Always "colslam-synth".
    pub generator: String,
    /// The seed (also inside `options`).
    pub seed: u64,
    /// Inner room size in metres (x, y, z).
    pub room_size: [f64; 3],
    /// Extent of the scene's bounding box in metres (the room).
    pub scene_extent: [f64; 3],
    /// Diagonal of the scene's bounding box in metres.
    pub scene_diagonal: f64,
    /// Length of the ground-truth path in metres.
    pub path_length: f64,
    /// Number of frames.
    pub frames: usize,
    /// The furniture boxes (name, min, max).
    pub boxes: Vec<BoxDescription>,
    /// The options that produced the folder.
    pub options: SynthOptions,
}

/// One box of `scene.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BoxDescription {
    /// What it stands for.
    pub name: String,
    /// Minimum corner (metres, world).
    pub min: [f64; 3],
    /// Maximum corner.
    pub max: [f64; 3],
}

impl From<&SceneBox> for BoxDescription {
    fn from(b: &SceneBox) -> Self {
        BoxDescription { name: b.name.clone(), min: b.aabb.min, max: b.aabb.max }
    }
}

/// Relative path of frame `i`'s image.
pub fn frame_name(i: usize) -> String {
    format!("rgb/{i:06}.png")
}

/// Timestamp string of frame `i` (identical in `rgb.txt` and `groundtruth.txt`).
fn timestamp(i: usize, fps: f64) -> String {
    format!("{:.6}", i as f64 / fps)
}

/// `rgb.txt` text.
fn rgb_txt(opts: &SynthOptions) -> String {
    let mut s = String::from("# color images\n# colslam-synth synthetic sequence\n# timestamp filename\n");
    for i in 0..opts.frames {
        s.push_str(&format!("{} {}\n", timestamp(i, opts.fps), frame_name(i)));
    }
    s
}

/// `groundtruth.txt` text (full precision: Rust's shortest round-trip form).
fn groundtruth_txt(seq: &SyntheticSequence) -> String {
    let mut s = String::from(
        "# ground truth trajectory\n# colslam-synth: world_from_cam (camera x right, y down, z forward; world z up)\n# timestamp tx ty tz qx qy qz qw\n",
    );
    let fps = seq.options().fps;
    for (i, p) in seq.world_from_cam().iter().enumerate() {
        let t = p.translation;
        let q = p.quat_xyzw();
        s.push_str(&format!(
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?}\n",
            timestamp(i, fps),
            t.x,
            t.y,
            t.z,
            q[0],
            q[1],
            q[2],
            q[3]
        ));
    }
    s
}

/// `camera.yaml` text, in the flat format of the datasets' `camera.yaml`.
fn camera_yaml(opts: &SynthOptions, seq: &SyntheticSequence) -> String {
    let cam = seq.camera();
    let mut s = String::from(
        "# colslam-synth synthetic camera. Pixel convention: OpenCV/TUM (pixel (i, j) centred at (i, j)),\n# so the principal point at the image centre is ((width - 1) / 2, (height - 1) / 2).\n",
    );
    s.push_str(&format!("model: {}\n", cam.model.name()));
    s.push_str(&format!("width: {}\nheight: {}\n", cam.width, cam.height));
    for (name, v) in ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"].iter().zip(&cam.params) {
        s.push_str(&format!("{name}: {v:?}\n"));
    }
    s.push_str(&format!("fps: {:?}\n", opts.fps));
    s
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    write_atomic(path, text.as_bytes()).map_err(|e| SynthError::io(path, e))
}

/// True when `out` holds a complete sequence made with `opts`.
fn is_complete(opts: &SynthOptions, out: &Path) -> bool {
    let Ok(text) = std::fs::read_to_string(out.join(SCENE_JSON)) else { return false };
    let Ok(desc) = serde_json::from_str::<SceneDescription>(&text) else { return false };
    if desc.format_version != FORMAT_VERSION || desc.options != *opts {
        return false;
    }
    ["rgb.txt", "groundtruth.txt", "camera.yaml"].iter().all(|f| out.join(f).is_file())
        && (0..opts.frames).all(|i| out.join(frame_name(i)).is_file())
}

/// Removes frames `rgb/NNNNNN.png` with `NNNNNN >= frames` left by an
/// earlier, longer sequence (other files are left alone).
fn remove_stale_frames(rgb: &Path, frames: usize) -> Result<(), SynthError> {
    let entries = std::fs::read_dir(rgb).map_err(|e| SynthError::io(rgb, e))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let Some(stem) = name.strip_suffix(".png") else { continue };
        if stem.len() == 6
            && stem.bytes().all(|b| b.is_ascii_digit())
            && stem.parse::<usize>().is_ok_and(|k| k >= frames)
        {
            let p = entry.path();
            std::fs::remove_file(&p).map_err(|e| SynthError::io(&p, e))?;
        }
    }
    Ok(())
}

/// Generates the sequence into `out` (created if needed). A folder that
/// already holds a complete sequence with the same options is left as is
/// (the report then says `up_to_date` and `frames_written = 0`); anything
/// else is (re)written. `progress(done, total)` is called after each frame.
pub fn generate(
    opts: &SynthOptions,
    out: &Path,
    progress: Option<&dyn Fn(usize, usize)>,
) -> Result<SynthReport, SynthError> {
    let start = Instant::now();
    opts.validate()?;
    let extent = {
        let r = opts.room_size;
        [r[0], r[1], r[2]]
    };
    let diagonal = (extent[0].powi(2) + extent[1].powi(2) + extent[2].powi(2)).sqrt();
    if is_complete(opts, out) {
        let tr = Trajectory::new(opts);
        let centres: Vec<_> = (0..opts.frames).map(|i| tr.center(i as f64 / opts.fps)).collect();
        let path_length = centres.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let start_end = match (centres.first(), centres.last()) {
            (Some(a), Some(b)) => (b - a).norm(),
            _ => 0.0,
        };
        return Ok(SynthReport {
            frames: opts.frames,
            frames_written: 0,
            up_to_date: true,
            scene_extent: extent,
            scene_diagonal: diagonal,
            path_length,
            start_end_distance: start_end,
            setup_seconds: 0.0,
            render_seconds: 0.0,
            write_seconds: 0.0,
            total_seconds: start.elapsed().as_secs_f64(),
        });
    }
    let rgb = out.join("rgb");
    std::fs::create_dir_all(&rgb).map_err(|e| SynthError::io(&rgb, e))?;
    let marker = out.join(SCENE_JSON);
    match std::fs::remove_file(&marker) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(SynthError::io(&marker, e)),
    }
    remove_stale_frames(&rgb, opts.frames)?;

    let t_setup = Instant::now();
    let seq = SyntheticSequence::new(opts)?;
    let setup_seconds = t_setup.elapsed().as_secs_f64();

    let mut render_seconds = 0.0;
    let mut write_seconds = 0.0;
    let n = seq.num_frames();
    // Frame i is encoded and written while frame i + 1 renders.
    let mut pending: Option<(usize, colslam_image::Image)> = None;
    for i in 0..=n {
        let t0 = Instant::now();
        let (rendered, written) = rayon::join(
            || if i < n { Some(seq.render(i)) } else { None },
            || -> Result<Option<usize>, SynthError> {
                match pending.take() {
                    Some((k, img)) => {
                        img.write_png(&out.join(frame_name(k)))?;
                        Ok(Some(k))
                    }
                    None => Ok(None),
                }
            },
        );
        let elapsed = t0.elapsed().as_secs_f64();
        if let (Some(k), Some(p)) = (written?, progress) {
            p(k + 1, n);
        }
        match rendered {
            Some(img) => {
                render_seconds += elapsed;
                pending = Some((i, img?));
            }
            None => write_seconds += elapsed,
        }
    }

    let t_write = Instant::now();
    write_text(&out.join("rgb.txt"), &rgb_txt(opts))?;
    write_text(&out.join("groundtruth.txt"), &groundtruth_txt(&seq))?;
    write_text(&out.join("camera.yaml"), &camera_yaml(opts, &seq))?;
    let centres: Vec<_> = seq.world_from_cam().iter().map(|p| p.translation).collect();
    let start_end = match (centres.first(), centres.last()) {
        (Some(a), Some(b)) => (b - a).norm(),
        _ => 0.0,
    };
    let desc = SceneDescription {
        format_version: FORMAT_VERSION,
        generator: "colslam-synth".into(),
        seed: opts.seed,
        room_size: opts.room_size,
        scene_extent: extent,
        scene_diagonal: diagonal,
        path_length: seq.path_length(),
        frames: n,
        boxes: seq.scene().boxes().iter().map(BoxDescription::from).collect(),
        options: opts.clone(),
    };
    let json =
        serde_json::to_string_pretty(&desc).map_err(|source| SynthError::Json { path: marker.clone(), source })?;
    write_text(&marker, &json)?;
    write_seconds += t_write.elapsed().as_secs_f64();

    let room: &Aabb = seq.scene().room();
    let size = room.size();
    Ok(SynthReport {
        frames: n,
        frames_written: n,
        up_to_date: false,
        scene_extent: size,
        scene_diagonal: diagonal,
        path_length: seq.path_length(),
        start_end_distance: start_end,
        setup_seconds,
        render_seconds,
        write_seconds,
        total_seconds: start.elapsed().as_secs_f64(),
    })
}

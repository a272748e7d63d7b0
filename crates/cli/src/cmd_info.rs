//! `colslam info`: describe a COLMAP model folder or an input sequence.

use crate::stdout::outln;
use anyhow::Result;
use colslam_eval::trajectory::Trajectory;
use colslam_scene::Reconstruction;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// A COLMAP model folder, a video file or an image-sequence folder.
    pub path: PathBuf,
}

/// Runs `info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    if is_model_dir(&args.path) {
        let rec = colslam_scene::read_model(&args.path)?;
        outln!("{}", describe_model(&rec));
    } else {
        outln!("{}", describe_input(&args.path)?);
    }
    Ok(())
}

fn is_model_dir(p: &Path) -> bool {
    p.join("cameras.bin").is_file() || p.join("cameras.txt").is_file()
}

/// A summary of a reconstruction.
pub fn describe_model(rec: &Reconstruction) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "cameras:            {}", rec.num_cameras());
    let _ = writeln!(s, "images:             {} ({} registered)", rec.num_images(), rec.num_registered_images());
    let _ = writeln!(s, "points3D:           {}", rec.num_points3d());
    let _ = writeln!(s, "observations:       {}", rec.num_observations());
    let _ = writeln!(s, "mean track length:  {:.3}", rec.mean_track_length());
    let _ = write!(s, "mean reproj. error: {:.4} px", rec.mean_reprojection_error());
    s
}

/// A summary of an input sequence or video, with its camera file if any.
pub fn describe_input(path: &Path) -> Result<String> {
    let info = colslam_io::probe_source(path, &colslam_io::SourceOptions::default())?;
    let mut s = info.description.clone();
    if let Some((w, h)) = info.image_size {
        let _ = write!(s, "\nimage size: {w}x{h}");
    }
    if let Some(n) = info.frames {
        let _ = write!(s, "\nframes: {n}");
    }
    if let Some(cam_path) = &info.camera_file {
        match colslam_camera::file::read_camera_file(cam_path) {
            Ok(cam) => {
                let _ = write!(s, "\ncamera: {} {}x{} {:?}", cam.model, cam.width, cam.height, cam.params);
            }
            Err(e) => {
                // The cause (an OS error) is the error's source, not in its message.
                let e = anyhow::Error::new(e);
                let _ = write!(s, "\ncamera file {} not usable: {e:#}", cam_path.display());
            }
        }
    }
    Ok(s)
}

/// The registered images' poses as a TUM trajectory (camera-to-world). The
/// timestamp is the image name's stem when it parses as a number (TUM and
/// colslam name frames by timestamp), else the image id.
pub fn trajectory_of(rec: &Reconstruction) -> Trajectory {
    let mut entries: Vec<(f64, colslam_geometry::Rigid3)> = rec
        .images()
        .filter(|img| img.registered)
        .map(|img| {
            let stem = Path::new(&img.name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let t = stem.parse::<f64>().unwrap_or(f64::from(img.id.0));
            (t, img.cam_from_world.inverse())
        })
        .collect();
    entries.sort_by(|a, b| a.0.total_cmp(&b.0));
    Trajectory { stamps: entries.iter().map(|e| e.0).collect(), poses: entries.iter().map(|e| e.1).collect() }
}

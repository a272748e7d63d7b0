//! `colslam export`: convert a COLMAP model between binary and text, export
//! its point cloud (PLY) or its registered poses (TUM trajectory), or export
//! a run for Gaussian splatting (`3dgs`) or nerfstudio (the work itself is
//! the library's [`colslam_slam::export`]; this file adds the progress bar).

use crate::stdout::outln;
use anyhow::Result;
use colslam_slam::export::{ExportProgress, FrameSelection, SceneExport, SceneFormat};
use std::path::PathBuf;

/// Output formats.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ExportFormat {
    /// COLMAP binary model (cameras.bin, images.bin, points3D.bin).
    Bin,
    /// COLMAP text model (cameras.txt, images.txt, points3D.txt).
    Txt,
    /// Coloured point cloud (binary PLY).
    Ply,
    /// TUM trajectory of the registered images (camera-to-world; timestamps
    /// parsed from the image names when they are numbers, else the image ids).
    Tum,
    /// nerfstudio (`ns-train ... --data OUT`): transforms.json, images/,
    /// sparse_pc.ply. MODEL must be a run folder.
    Nerfstudio,
    /// 3D Gaussian splatting (graphdeco train.py -s OUT, gsplat --data_dir
    /// OUT): undistorted images/ and a PINHOLE model in sparse/0. MODEL must
    /// be a run folder.
    #[value(name = "3dgs")]
    Gaussian3d,
}

/// Which frames a nerfstudio or 3dgs export holds.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum FramesArg {
    /// Every localised frame.
    All,
    /// The model's keyframes only.
    Keyframes,
}

/// Arguments of `export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// COLMAP model folder (binary or text); for nerfstudio and 3dgs, a run's
    /// output folder (model, trajectory.tum, report.json).
    pub model: PathBuf,
    /// Output: a folder for bin/txt/nerfstudio/3dgs, a file for ply/tum.
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Output format.
    #[arg(short, long, value_name = "FORMAT", value_enum)]
    pub format: ExportFormat,
    /// nerfstudio and 3dgs: every localised frame or the keyframes only.
    #[arg(long, value_name = "WHICH", value_enum, default_value = "all")]
    pub frames: FramesArg,
    /// nerfstudio and 3dgs: read the images from this input (the run's
    /// sequence folder or video, moved) instead of the one report.json names.
    #[arg(long, value_name = "PATH")]
    pub images: Option<PathBuf>,
    /// nerfstudio and 3dgs: which map of a run that ended with several (0:
    /// the largest, at the run folder's root; K: the run's maps/K).
    #[arg(long, value_name = "K", default_value_t = 0)]
    pub map: usize,
}

/// Runs `export`. A model folder is written as a whole (the folder holds
/// the previous model or the new one, never a mix), and its location is
/// checked and locked before the input model is read.
pub fn run(args: &ExportArgs, quiet: bool) -> Result<()> {
    let scene_only = args.images.is_some() || matches!(args.frames, FramesArg::Keyframes) || args.map != 0;
    if scene_only && !matches!(args.format, ExportFormat::Nerfstudio | ExportFormat::Gaussian3d) {
        anyhow::bail!("--frames, --images and --map apply to -f nerfstudio and -f 3dgs only");
    }
    let read = || colslam_scene::read_model(&args.model);
    match args.format {
        ExportFormat::Bin | ExportFormat::Txt => {
            let format = match args.format {
                ExportFormat::Bin => colslam_scene::ModelFormat::Binary,
                _ => colslam_scene::ModelFormat::Text,
            };
            let out = colslam_scene::begin_model_output(&args.output)?;
            colslam_scene::write_model_files(&read()?, out.path(), format)?;
            out.commit()?;
        }
        ExportFormat::Ply => colslam_scene::write_ply(&read()?, &args.output)?,
        ExportFormat::Tum => {
            let traj = crate::cmd_info::trajectory_of(&read()?);
            traj.write_tum(&args.output)?;
        }
        ExportFormat::Nerfstudio => return export_scene(args, SceneFormat::Nerfstudio, quiet),
        ExportFormat::Gaussian3d => return export_scene(args, SceneFormat::Gaussian3d, quiet),
    }
    outln!("wrote {}", args.output.display());
    Ok(())
}

/// A run exported for nerfstudio or Gaussian splatting, with a progress bar
/// over the written frames.
fn export_scene(args: &ExportArgs, format: SceneFormat, quiet: bool) -> Result<()> {
    let req = SceneExport {
        run: args.model.clone(),
        output: args.output.clone(),
        format,
        frames: match args.frames {
            FramesArg::All => FrameSelection::All,
            FramesArg::Keyframes => FrameSelection::Keyframes,
        },
        images: args.images.clone(),
        map: args.map,
    };
    let pb = crate::logging::progress_bar(0, quiet, "export", "frames");
    let result = colslam_slam::export::export_scene_with(&req, &mut |p: &ExportProgress<'_>| {
        pb.set_length(p.total as u64);
        pb.set_position(p.done as u64);
    });
    pb.finish_and_clear();
    let s = result?;
    outln!(
        "wrote {}: {} frames ({} keyframes, {} without a pose left out), {} points, {} camera {}x{}{}",
        args.output.display(),
        s.frames,
        s.keyframes,
        s.not_localized,
        s.points,
        s.camera_model,
        s.width,
        s.height,
        if s.undistorted { ", images undistorted" } else { "" }
    );
    Ok(())
}

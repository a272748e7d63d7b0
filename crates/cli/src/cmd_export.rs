//! `colslam export`: convert a COLMAP model between binary and text, or
//! export its point cloud (PLY) or its registered poses (TUM trajectory).

use crate::stdout::outln;
use anyhow::Result;
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
}

/// Arguments of `export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// COLMAP model folder (binary or text).
    pub model: PathBuf,
    /// Output: a folder for bin/txt, a file for ply/tum.
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Output format.
    #[arg(short, long, value_name = "FORMAT", value_enum)]
    pub format: ExportFormat,
}

/// Runs `export`. A model folder is written as a whole (the folder holds
/// the previous model or the new one, never a mix), and its location is
/// checked and locked before the input model is read.
pub fn run(args: &ExportArgs) -> Result<()> {
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
    }
    outln!("wrote {}", args.output.display());
    Ok(())
}

//! `colslam export`: convert a COLMAP model between binary and text, or
//! export its point cloud (PLY) or its registered poses (TUM trajectory).

use crate::stdout::outln;
use anyhow::{Context, Result};
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
    #[arg(short, long)]
    pub output: PathBuf,
    /// Output format.
    #[arg(short, long, value_enum)]
    pub format: ExportFormat,
}

/// Runs `export`.
pub fn run(args: &ExportArgs) -> Result<()> {
    let rec = colslam_scene::read_model(&args.model)?;
    match args.format {
        ExportFormat::Bin | ExportFormat::Txt => {
            std::fs::create_dir_all(&args.output).with_context(|| format!("creating {}", args.output.display()))?;
            let format = match args.format {
                ExportFormat::Bin => colslam_scene::ModelFormat::Binary,
                _ => colslam_scene::ModelFormat::Text,
            };
            colslam_scene::write_model(&rec, &args.output, format)?;
        }
        ExportFormat::Ply => colslam_scene::write_ply(&rec, &args.output)?,
        ExportFormat::Tum => {
            let traj = crate::cmd_info::trajectory_of(&rec);
            traj.write_tum(&args.output)?;
        }
    }
    outln!("wrote {}", args.output.display());
    Ok(())
}

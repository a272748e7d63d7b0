//! PLY export of the 3D points with colours, in the layout COLMAP's
//! `WriteBinaryPlyPoints` / `WriteTextPlyPoints` use (x, y, z as `float`,
//! red, green, blue as `uchar`), which Open3D, MeshLab and
//! `pycolmap.Reconstruction.import_PLY` read.

use crate::error::SceneError;
use crate::reconstruction::Reconstruction;
use std::fmt::Write as _;
use std::path::Path;

/// Encoding of the vertex data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlyFormat {
    /// `binary_little_endian 1.0` (default; 15 bytes per point).
    #[default]
    BinaryLittleEndian,
    /// `ascii 1.0`, one `x y z r g b` line per point.
    Ascii,
}

/// The header for `n` vertices.
fn header(format: PlyFormat, n: usize) -> String {
    let fmt = match format {
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
        PlyFormat::Ascii => "ascii",
    };
    format!(
        "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
}

/// The PLY file contents for the points of `rec` (by increasing point id).
/// Coordinates are stored as 32-bit floats, as COLMAP does.
pub fn encode_ply(rec: &Reconstruction, format: PlyFormat) -> Vec<u8> {
    let mut out = header(format, rec.num_points3d()).into_bytes();
    match format {
        PlyFormat::BinaryLittleEndian => {
            for (_, p) in rec.points3d() {
                for v in p.xyz.iter() {
                    // PLY `float` is 32-bit; the precision loss is the format's.
                    out.extend_from_slice(&(*v as f32).to_le_bytes());
                }
                out.extend_from_slice(&p.color);
            }
        }
        PlyFormat::Ascii => {
            let mut s = String::new();
            for (_, p) in rec.points3d() {
                let _ = writeln!(
                    s,
                    "{} {} {} {} {} {}",
                    p.xyz.x as f32, p.xyz.y as f32, p.xyz.z as f32, p.color[0], p.color[1], p.color[2]
                );
            }
            out.extend_from_slice(s.as_bytes());
        }
    }
    out
}

/// Writes the points of `rec` as a binary little-endian PLY, atomically.
pub fn write_ply(rec: &Reconstruction, path: &Path) -> Result<(), SceneError> {
    write_ply_with(rec, path, PlyFormat::BinaryLittleEndian)
}

/// Writes the points of `rec` as PLY in the given encoding, atomically.
pub fn write_ply_with(rec: &Reconstruction, path: &Path, format: PlyFormat) -> Result<(), SceneError> {
    colslam_image::write_atomic(path, &encode_ply(rec, format)).map_err(|e| SceneError::io(path, e))
}

//! Typed ids for cameras, images and 3D points (COLMAP's `camera_t`,
//! `image_t`, `point3D_t`).
//!
//! COLMAP marks "no id" with the largest value of the integer type
//! (`kInvalidPoint3DId = u64::MAX` in binary files, `-1` in text files). Here
//! absence is an `Option`, so an id value is always a real id; the invalid
//! constants exist only for file I/O.

use std::fmt;

/// Id of a camera (COLMAP `camera_t`, `u32`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CameraId(pub u32);

/// Id of an image (COLMAP `image_t`, `u32`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ImageId(pub u32);

/// Id of a 3D point (COLMAP `point3D_t`, `u64`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Point3DId(pub u64);

/// The value COLMAP writes in binary files for "no 3D point"
/// (`kInvalidPoint3DId`, `std::numeric_limits<uint64_t>::max()`).
pub const INVALID_POINT3D_ID: u64 = u64::MAX;

/// The value COLMAP uses for an invalid camera or image id (`u32::MAX`).
pub const INVALID_ID_U32: u32 = u32::MAX;

impl fmt::Display for CameraId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl fmt::Display for ImageId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl fmt::Display for Point3DId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl Point3DId {
    /// Decodes a point id as stored in a binary `images.bin` (`u64::MAX` = none).
    pub fn from_binary(raw: u64) -> Option<Self> {
        (raw != INVALID_POINT3D_ID).then_some(Self(raw))
    }

    /// Encodes an optional point id for a binary `images.bin`.
    pub fn to_binary(id: Option<Self>) -> u64 {
        id.map_or(INVALID_POINT3D_ID, |p| p.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_point_id_round_trip() {
        assert_eq!(Point3DId::from_binary(u64::MAX), None);
        assert_eq!(Point3DId::from_binary(7), Some(Point3DId(7)));
        assert_eq!(Point3DId::to_binary(None), u64::MAX);
        assert_eq!(Point3DId::to_binary(Some(Point3DId(3))), 3);
        assert_eq!(format!("{} {} {}", CameraId(1), ImageId(2), Point3DId(3)), "1 2 3");
        assert!(ImageId(1) < ImageId(2));
    }
}

//! The table of COLMAP camera models (src/colmap/sensor/models.h).

/// COLMAP camera model, with COLMAP's numeric id as discriminant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(i32)]
pub enum CameraModelId {
    /// f, cx, cy
    SimplePinhole = 0,
    /// fx, fy, cx, cy
    Pinhole = 1,
    /// f, cx, cy, k
    SimpleRadial = 2,
    /// f, cx, cy, k1, k2
    Radial = 3,
    /// fx, fy, cx, cy, k1, k2, p1, p2
    OpenCv = 4,
    /// fx, fy, cx, cy, k1, k2, k3, k4
    OpenCvFisheye = 5,
    /// fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6
    FullOpenCv = 6,
}

impl CameraModelId {
    /// Every supported model.
    pub const ALL: [CameraModelId; 7] = [
        Self::SimplePinhole,
        Self::Pinhole,
        Self::SimpleRadial,
        Self::Radial,
        Self::OpenCv,
        Self::OpenCvFisheye,
        Self::FullOpenCv,
    ];

    /// COLMAP's numeric id.
    pub fn id(self) -> i32 {
        self as i32
    }

    /// The model for a COLMAP numeric id.
    pub fn from_id(id: i32) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.id() == id)
    }

    /// COLMAP's name, e.g. "SIMPLE_RADIAL".
    pub fn name(self) -> &'static str {
        match self {
            Self::SimplePinhole => "SIMPLE_PINHOLE",
            Self::Pinhole => "PINHOLE",
            Self::SimpleRadial => "SIMPLE_RADIAL",
            Self::Radial => "RADIAL",
            Self::OpenCv => "OPENCV",
            Self::OpenCvFisheye => "OPENCV_FISHEYE",
            Self::FullOpenCv => "FULL_OPENCV",
        }
    }

    /// The model for a COLMAP name (case-insensitive).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name().eq_ignore_ascii_case(name.trim()))
    }

    /// Parameter names in COLMAP order, comma separated.
    pub fn param_names(self) -> &'static str {
        match self {
            Self::SimplePinhole => "f, cx, cy",
            Self::Pinhole => "fx, fy, cx, cy",
            Self::SimpleRadial => "f, cx, cy, k",
            Self::Radial => "f, cx, cy, k1, k2",
            Self::OpenCv => "fx, fy, cx, cy, k1, k2, p1, p2",
            Self::OpenCvFisheye => "fx, fy, cx, cy, k1, k2, k3, k4",
            Self::FullOpenCv => "fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6",
        }
    }

    /// Number of parameters.
    pub fn num_params(self) -> usize {
        self.param_names().split(',').count()
    }
}

impl std::fmt::Display for CameraModelId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_names_counts_round_trip() {
        let counts = [3, 4, 4, 5, 8, 8, 12];
        for (m, n) in CameraModelId::ALL.into_iter().zip(counts) {
            assert_eq!(CameraModelId::from_id(m.id()), Some(m));
            assert_eq!(CameraModelId::from_name(&m.name().to_lowercase()), Some(m));
            assert_eq!(m.num_params(), n, "{m}");
        }
        assert_eq!(CameraModelId::from_id(99), None);
    }
}

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
        match self {
            Self::SimplePinhole => 3,
            Self::Pinhole | Self::SimpleRadial => 4,
            Self::Radial => 5,
            Self::OpenCv | Self::OpenCvFisheye => 8,
            Self::FullOpenCv => 12,
        }
    }

    /// Parameter names in COLMAP order, one entry per parameter.
    pub fn param_name_list(self) -> impl Iterator<Item = &'static str> {
        self.param_names().split(',').map(str::trim)
    }

    /// Index of the parameter called `name` (e.g. "k1"), if the model has one.
    pub fn param_index(self, name: &str) -> Option<usize> {
        self.param_name_list().position(|n| n.eq_ignore_ascii_case(name.trim()))
    }

    /// Indices of the focal length parameter(s): one shared `f` or `fx, fy`
    /// (COLMAP's `focal_length_idxs`).
    pub fn focal_length_idxs(self) -> &'static [usize] {
        if self.has_single_focal() { &[0] } else { &[0, 1] }
    }

    /// Indices of the principal point `cx, cy` (COLMAP's `principal_point_idxs`).
    pub fn principal_point_idxs(self) -> &'static [usize] {
        if self.has_single_focal() { &[1, 2] } else { &[2, 3] }
    }

    /// Indices of the extra (distortion) parameters, possibly empty
    /// (COLMAP's `extra_params_idxs`).
    pub fn extra_params_idxs(self) -> &'static [usize] {
        const IDXS: [usize; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
        let start = self.num_extra_start();
        // Invariant: start <= num_params <= 12 for every model (see num_params).
        &IDXS[start..self.num_params()]
    }

    /// Index of the first extra parameter (3 for one focal, 4 for two).
    pub(crate) fn num_extra_start(self) -> usize {
        if self.has_single_focal() { 3 } else { 4 }
    }

    /// True for models with one focal length `f` shared by both axes.
    pub fn has_single_focal(self) -> bool {
        matches!(self, Self::SimplePinhole | Self::SimpleRadial | Self::Radial)
    }

    /// True for models with distortion parameters (anything but the pinholes).
    pub fn has_distortion_params(self) -> bool {
        !matches!(self, Self::SimplePinhole | Self::Pinhole)
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
            assert_eq!(m.param_name_list().count(), n, "{m}");
            let mut all: Vec<usize> = m.focal_length_idxs().to_vec();
            all.extend_from_slice(m.principal_point_idxs());
            all.extend_from_slice(m.extra_params_idxs());
            assert_eq!(all, (0..n).collect::<Vec<_>>(), "{m}");
            assert_eq!(m.param_index("cx"), Some(m.principal_point_idxs()[0]), "{m}");
        }
        assert_eq!(CameraModelId::from_id(99), None);
    }
}

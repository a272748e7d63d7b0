//! Options, errors and the report of the synthetic sequence generator.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Errors of the synthetic sequence generator.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// An option is out of its valid range.
    #[error("invalid synth option {name} = {value}: {reason}")]
    InvalidOption {
        /// Option name (field of [`SynthOptions`]).
        name: &'static str,
        /// The offending value, formatted.
        value: String,
        /// Why it is invalid.
        reason: String,
    },
    /// The camera path passes through furniture or leaves the room.
    #[error("camera path is invalid: {0} (change seed or scene/path options)")]
    BadPath(String),
    /// A frame index beyond the sequence.
    #[error("frame {index} is out of range: the sequence has {frames} frames")]
    FrameOutOfRange {
        /// Requested index.
        index: usize,
        /// Number of frames.
        frames: usize,
    },
    /// The camera could not be built or used.
    #[error("camera: {0}")]
    Camera(String),
    /// A file or folder could not be read or written.
    #[error("{path}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// An image could not be encoded or written.
    #[error(transparent)]
    Image(#[from] colslam_image::ImageError),
    /// `scene.json` could not be encoded.
    #[error("{path}: cannot encode JSON")]
    Json {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: serde_json::Error,
    },
}

impl SynthError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SynthError::Io { path: path.into(), source }
    }
}

/// Radial-tangential (OpenCV "plumb bob" without k3) distortion
/// coefficients `[k1, k2, p1, p2]`, COLMAP's `OPENCV` parameter order.
pub type Distortion = [f64; 4];

/// Largest absolute distortion coefficient accepted: beyond it the OPENCV
/// model folds over inside a 640x480 field of view and unprojection is not
/// unique any more.
pub const MAX_DISTORTION_COEFF: f64 = 2.0;

/// The shape of the camera path.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathShape {
    /// An arc of at most half a turn around the central table, looking at
    /// it (the default: never revisits its start).
    #[default]
    Arc,
    /// Laps around the central table, looking at it: `path_length /
    /// (2 pi orbit_radius)` laps, so later laps revisit mapped space (long
    /// looping sequences).
    Laps,
    /// A straight line along the room's x axis, beside the table, looking
    /// across the room at the +y wall: every stretch sees new wall (long
    /// exploring sequences in a long room).
    Line,
    /// A drive along two sides of a large room, looking where it goes:
    /// straight along +x beside the -y wall, a quarter turn to the left of
    /// radius `orbit_radius`, straight along +y beside the +x wall; the two
    /// straights share `path_length` minus the turn. Forward motion with
    /// one turn, the geometry of a car's camera (issue 20's scale test,
    /// with exact intrinsics where real drives have a calibration).
    Drive,
}

/// Options of the synthetic sequence. Every field has a documented default
/// (see [`SynthOptions::default`]); call [`SynthOptions::validate`] (done by
/// every entry point) before use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SynthOptions {
    /// Number of frames. Default 150 (5 s at 30 fps).
    pub frames: usize,
    /// Image width in pixels. Default 640.
    pub width: usize,
    /// Image height in pixels. Default 480.
    pub height: usize,
    /// Frame rate; timestamps are `i / fps`. Default 30.
    pub fps: f64,
    /// Focal length in pixels (fx = fy); the principal point is the image
    /// centre (`width / 2`, `height / 2`, COLMAP's continuous pixel
    /// coordinates where pixel `(c, r)` covers `[c, c+1) x [r, r+1)`).
    /// Default 525 (a Kinect-like 63 x 49 degree field of view at 640x480).
    pub focal: f64,
    /// Optional lens distortion `[k1, k2, p1, p2]`: the camera is then
    /// COLMAP's OPENCV model; `None` (default) gives a PINHOLE camera.
    pub distortion: Option<Distortion>,
    /// Standard deviation of the additive per-channel image noise, in gray
    /// levels. Default 2.
    pub noise_sigma: f64,
    /// Motion blur: exposure time as a fraction of the frame interval, in
    /// [0, 1]. 0 (default) renders sharp frames; above 0 each frame averages
    /// `blur_samples` renders spread over the exposure, centred on the frame
    /// time (the ground-truth pose is the one at the centre).
    pub motion_blur: f64,
    /// Sub-frame renders averaged for motion blur when `motion_blur > 0`.
    /// Default 4.
    pub blur_samples: usize,
    /// Rolling-shutter readout time in seconds, first row to last, in
    /// [0, 1 / fps]. 0 (default) renders a global shutter; above 0 pixel row
    /// `r` is seen from the pose at `t + ((r + 0.5) / height - 0.5) *
    /// readout` (the middle row at the frame time, whose pose is the ground
    /// truth), as a CMOS sensor reads its rows one after the other.
    /// Left out of `scene.json` when 0, so global-shutter folders stay as
    /// they were.
    #[serde(skip_serializing_if = "is_zero")]
    pub readout: f64,
    /// Supersampling factor per axis (`n x n` rays per pixel). Default 2.
    pub supersample: usize,
    /// Seed of every random choice (textures, furniture jitter, path, noise).
    /// Default 20_240_601.
    pub seed: u64,
    /// Inner size of the room in metres: x (length), y (width), z (height).
    /// Default 6 x 5 x 2.8.
    pub room_size: [f64; 3],
    /// Texture resolution: edge length of one texel in metres. Default 0.005
    /// (5 mm, about 1.5 pixels at 1.5 m with the default focal length).
    pub texel_size: f64,
    /// Number of extra randomly placed boxes (clutter) along the walls.
    /// Default 6.
    pub clutter_boxes: usize,
    /// Length of the base camera path in metres (the jitter adds a little).
    /// Default 1.5.
    pub path_length: f64,
    /// Shape of the camera path. Default [`PathShape::Arc`].
    pub path: PathShape,
    /// Horizontal distance of the camera from the room centre (the path is an
    /// arc around the central table). Default 1.8.
    pub orbit_radius: f64,
    /// Mean camera height above the floor in metres. Default 1.4.
    pub camera_height: f64,
    /// Amplitude of the hand-held position jitter in metres. Default 0.01.
    pub jitter_position: f64,
    /// Amplitude of the hand-held orientation jitter in degrees. Default 0.6.
    pub jitter_rotation_deg: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            frames: 150,
            width: 640,
            height: 480,
            fps: 30.0,
            focal: 525.0,
            distortion: None,
            noise_sigma: 2.0,
            motion_blur: 0.0,
            blur_samples: 4,
            readout: 0.0,
            supersample: 2,
            seed: 20_240_601,
            room_size: [6.0, 5.0, 2.8],
            texel_size: 0.005,
            clutter_boxes: 6,
            path_length: 1.5,
            path: PathShape::Arc,
            orbit_radius: 1.8,
            camera_height: 1.4,
            jitter_position: 0.01,
            jitter_rotation_deg: 0.6,
        }
    }
}

/// Smallest room edge accepted (the furniture layout needs this much).
pub const MIN_ROOM_SIZE: [f64; 3] = [4.0, 3.5, 2.2];
/// Largest image edge accepted, in pixels.
pub const MAX_IMAGE_SIZE: usize = 16_384;
/// Largest supersampling factor accepted.
pub const MAX_SUPERSAMPLE: usize = 8;
/// Largest number of motion-blur sub-frames accepted.
pub const MAX_BLUR_SAMPLES: usize = 64;
/// Smallest texel edge accepted, in metres (memory grows with its inverse square).
pub const MIN_TEXEL_SIZE: f64 = 0.001;
/// Largest texel edge accepted, in metres.
pub const MAX_TEXEL_SIZE: f64 = 0.1;
/// Largest number of clutter boxes accepted.
pub const MAX_CLUTTER_BOXES: usize = 64;
/// Largest room edge accepted, in metres (a long exploring room; the texel
/// budget bounds the memory).
pub const MAX_ROOM_SIZE: f64 = 200.0;
/// Distance the [`PathShape::Line`] keeps from each end wall, metres (the
/// shelf and the tall cabinet stand there).
pub const LINE_END_MARGIN: f64 = 1.0;
/// Largest number of rays per frame (`width * height * supersample^2`); the
/// ray table holds 16 bytes per ray.
pub const MAX_RAYS: usize = 64 << 20;
/// Largest number of texels over all surfaces (4 bytes each).
pub const MAX_TEXELS: f64 = 200e6;
/// Upper bound of the furniture's surface area in m^2, without clutter.
const FURNITURE_AREA: f64 = 60.0;
/// Upper bound of one clutter box's (and its stacked box's) surface area, m^2.
const CLUTTER_AREA: f64 = 2.5;

fn invalid(name: &'static str, value: impl std::fmt::Display, reason: &str) -> SynthError {
    SynthError::InvalidOption { name, value: value.to_string(), reason: reason.to_string() }
}

fn check_finite_positive(name: &'static str, v: f64) -> Result<(), SynthError> {
    if !v.is_finite() || v <= 0.0 {
        return Err(invalid(name, v, "must be a finite number > 0"));
    }
    Ok(())
}

fn check_finite_non_negative(name: &'static str, v: f64) -> Result<(), SynthError> {
    if !v.is_finite() || v < 0.0 {
        return Err(invalid(name, v, "must be a finite number >= 0"));
    }
    Ok(())
}

impl SynthOptions {
    /// Checks every option; the error names the option, its value and the
    /// valid range.
    pub fn validate(&self) -> Result<(), SynthError> {
        if self.frames == 0 {
            return Err(invalid("frames", self.frames, "must be at least 1"));
        }
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_IMAGE_SIZE {
                return Err(invalid(name, v, &format!("must be in 1..={MAX_IMAGE_SIZE} pixels")));
            }
        }
        check_finite_positive("fps", self.fps)?;
        check_finite_positive("focal", self.focal)?;
        if let Some(d) = &self.distortion {
            for (name, v) in
                ["distortion.k1", "distortion.k2", "distortion.p1", "distortion.p2"].into_iter().zip(d.iter().copied())
            {
                if !v.is_finite() || v.abs() > MAX_DISTORTION_COEFF {
                    return Err(invalid(name, v, &format!("must be finite with |value| <= {MAX_DISTORTION_COEFF}")));
                }
            }
        }
        check_finite_non_negative("noise_sigma", self.noise_sigma)?;
        if !self.motion_blur.is_finite() || !(0.0..=1.0).contains(&self.motion_blur) {
            return Err(invalid(
                "motion_blur",
                self.motion_blur,
                "must be an exposure fraction of the frame interval in [0, 1]",
            ));
        }
        if !self.readout.is_finite() || !(0.0..=1.0 / self.fps).contains(&self.readout) {
            return Err(invalid("readout", self.readout, "must be a readout time in seconds in [0, 1 / fps]"));
        }
        if self.blur_samples == 0 || self.blur_samples > MAX_BLUR_SAMPLES {
            return Err(invalid("blur_samples", self.blur_samples, &format!("must be in 1..={MAX_BLUR_SAMPLES}")));
        }
        if self.supersample == 0 || self.supersample > MAX_SUPERSAMPLE {
            return Err(invalid("supersample", self.supersample, &format!("must be in 1..={MAX_SUPERSAMPLE}")));
        }
        let rays = self.width * self.height * self.supersample * self.supersample;
        if rays > MAX_RAYS {
            return Err(invalid(
                "supersample",
                self.supersample,
                &format!(
                    "{}x{} pixels with {}x{} samples make {rays} rays per frame, more than {MAX_RAYS}",
                    self.width, self.height, self.supersample, self.supersample
                ),
            ));
        }
        for (i, (&v, &min)) in self.room_size.iter().zip(MIN_ROOM_SIZE.iter()).enumerate() {
            const NAMES: [&str; 3] = ["room_size[0] (x)", "room_size[1] (y)", "room_size[2] (z)"];
            if !v.is_finite() || v < min || v > MAX_ROOM_SIZE {
                return Err(SynthError::InvalidOption {
                    name: "room_size",
                    value: format!("{:?}", self.room_size),
                    reason: format!(
                        "{} = {v} must be in [{min}, {MAX_ROOM_SIZE}] metres",
                        NAMES.get(i).copied().unwrap_or("?")
                    ),
                });
            }
        }
        if !self.texel_size.is_finite() || !(MIN_TEXEL_SIZE..=MAX_TEXEL_SIZE).contains(&self.texel_size) {
            return Err(invalid(
                "texel_size",
                self.texel_size,
                &format!("must be in [{MIN_TEXEL_SIZE}, {MAX_TEXEL_SIZE}] metres"),
            ));
        }
        if self.clutter_boxes > MAX_CLUTTER_BOXES {
            return Err(invalid("clutter_boxes", self.clutter_boxes, &format!("must be at most {MAX_CLUTTER_BOXES}")));
        }
        let [x, y, z] = self.room_size;
        let area = 2.0 * (x * y + y * z + x * z) + FURNITURE_AREA + CLUTTER_AREA * self.clutter_boxes as f64;
        let texels = area / (self.texel_size * self.texel_size);
        if texels > MAX_TEXELS {
            return Err(invalid(
                "texel_size",
                self.texel_size,
                &format!(
                    "about {area:.0} m^2 of surfaces would need {texels:.3e} texels, more than {MAX_TEXELS:.0e}; use larger texels or a smaller room"
                ),
            ));
        }
        check_finite_positive("path_length", self.path_length)?;
        check_finite_positive("orbit_radius", self.orbit_radius)?;
        check_finite_positive("camera_height", self.camera_height)?;
        let half_min = 0.5 * self.room_size[0].min(self.room_size[1]);
        if self.orbit_radius > half_min - 0.3 {
            return Err(invalid(
                "orbit_radius",
                self.orbit_radius,
                &format!("must leave 0.3 m to the walls: at most {}", half_min - 0.3),
            ));
        }
        if self.orbit_radius < 1.0 {
            return Err(invalid(
                "orbit_radius",
                self.orbit_radius,
                "must be at least 1.0 m to clear the central table",
            ));
        }
        if self.camera_height < 0.3 || self.camera_height > self.room_size[2] - 0.3 {
            return Err(invalid("camera_height", self.camera_height, "must leave 0.3 m to the floor and the ceiling"));
        }
        self.validate_path_length()?;
        check_finite_non_negative("jitter_position", self.jitter_position)?;
        if self.jitter_position > 0.1 {
            return Err(invalid("jitter_position", self.jitter_position, "must be at most 0.1 m"));
        }
        check_finite_non_negative("jitter_rotation_deg", self.jitter_rotation_deg)?;
        if self.jitter_rotation_deg > 10.0 {
            return Err(invalid("jitter_rotation_deg", self.jitter_rotation_deg, "must be at most 10 degrees"));
        }
        Ok(())
    }
}

impl SynthOptions {
    /// The path length against the path's shape.
    fn validate_path_length(&self) -> Result<(), SynthError> {
        match self.path {
            // The arc must stay below a full turn so that the path never
            // revisits its start (the camera would otherwise look back at
            // the same view).
            PathShape::Arc if self.path_length / self.orbit_radius > std::f64::consts::PI => {
                Err(invalid("path_length", self.path_length, "must be at most pi * orbit_radius (half a turn)"))
            }
            PathShape::Line if self.path_length > self.room_size[0] - 2.0 * LINE_END_MARGIN => Err(invalid(
                "path_length",
                self.path_length,
                &format!(
                    "a line path must leave {LINE_END_MARGIN} m to each end wall: at most room_size[0] - {}",
                    2.0 * LINE_END_MARGIN
                ),
            )),
            PathShape::Drive => self.validate_drive(),
            _ => Ok(()),
        }
    }

    /// A drive's straights must be of non-negative length and keep
    /// [`LINE_END_MARGIN`] from the walls they drive towards.
    fn validate_drive(&self) -> Result<(), SynthError> {
        let d = drive_layout(self);
        let (hx, hy) = (self.room_size[0] / 2.0, self.room_size[1] / 2.0);
        if d.straight < 0.0 {
            return Err(invalid("path_length", self.path_length, "a drive must be at least its quarter turn long"));
        }
        if d.corner_x - d.straight < -hx + LINE_END_MARGIN || d.corner_y + d.straight > hy - LINE_END_MARGIN {
            return Err(invalid(
                "room_size",
                format!("{:?}", self.room_size),
                &format!("too small for a drive of {} m with a turn of radius {}", self.path_length, self.orbit_radius),
            ));
        }
        Ok(())
    }
}

/// Distance of a [`PathShape::Drive`] from the walls beside it, metres
/// (the lane's distance from the buildings).
pub const DRIVE_INSET: f64 = 3.0;

/// Where a [`PathShape::Drive`] runs (room coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveLayout {
    /// Length of each straight, metres.
    pub straight: f64,
    /// Radius of the turn.
    pub radius: f64,
    /// x of the first straight's end (the turn's start).
    pub corner_x: f64,
    /// y of the first straight.
    pub first_y: f64,
    /// y of the second straight's start (the turn's end).
    pub corner_y: f64,
}

/// The drive of `opts` (its straights may be negative when the options are
/// invalid; [`SynthOptions::validate`] refuses those).
pub fn drive_layout(opts: &SynthOptions) -> DriveLayout {
    let radius = opts.orbit_radius;
    let (hx, hy) = (opts.room_size[0] / 2.0, opts.room_size[1] / 2.0);
    let turn = std::f64::consts::FRAC_PI_2 * radius;
    DriveLayout {
        straight: (opts.path_length - turn) / 2.0,
        radius,
        corner_x: hx - DRIVE_INSET - radius,
        first_y: -hy + DRIVE_INSET,
        corner_y: -hy + DRIVE_INSET + radius,
    }
}

/// What [`crate::generate`] did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthReport {
    /// Frames in the sequence.
    pub frames: usize,
    /// Frames rendered and written by this call (0 when the folder already
    /// held the complete sequence).
    pub frames_written: usize,
    /// True when the folder already held a complete sequence with the same
    /// options and nothing was written.
    pub up_to_date: bool,
    /// Size of the scene's bounding box (the room) in metres.
    pub scene_extent: [f64; 3],
    /// Diagonal of the scene's bounding box in metres.
    pub scene_diagonal: f64,
    /// Length of the ground-truth camera path in metres.
    pub path_length: f64,
    /// Distance between the first and last camera centre in metres.
    pub start_end_distance: f64,
    /// Seconds spent building the scene (texture baking, ray table).
    pub setup_seconds: f64,
    /// Seconds spent rendering frames (PNG encoding and writing of the
    /// previous frame runs alongside and is included).
    pub render_seconds: f64,
    /// Seconds spent writing what did not overlap rendering (the last frame,
    /// the text files).
    pub write_seconds: f64,
    /// Total seconds.
    pub total_seconds: f64,
}

impl std::fmt::Display for SynthReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.up_to_date {
            write!(f, "{} frames already present (up to date)", self.frames)?;
        } else {
            let per_frame =
                if self.frames_written > 0 { 1e3 * self.render_seconds / self.frames_written as f64 } else { 0.0 };
            write!(
                f,
                "{} frames written in {:.1} s (setup {:.1} s, {:.0} ms per frame)",
                self.frames_written, self.total_seconds, self.setup_seconds, per_frame
            )?;
        }
        write!(
            f,
            "; scene {:.1} x {:.1} x {:.1} m (diagonal {:.2} m); path {:.2} m, first-to-last {:.2} m",
            self.scene_extent[0],
            self.scene_extent[1],
            self.scene_extent[2],
            self.scene_diagonal,
            self.path_length,
            self.start_end_distance
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        SynthOptions::default().validate().unwrap();
    }

    #[test]
    fn errors_name_the_option() {
        let cases: Vec<(SynthOptions, &str)> = vec![
            (SynthOptions { frames: 0, ..Default::default() }, "frames"),
            (SynthOptions { width: 0, ..Default::default() }, "width"),
            (SynthOptions { height: 0, ..Default::default() }, "height"),
            (SynthOptions { noise_sigma: -1.0, ..Default::default() }, "noise_sigma"),
            (SynthOptions { fps: f64::NAN, ..Default::default() }, "fps"),
            (SynthOptions { motion_blur: 1.5, ..Default::default() }, "motion_blur"),
            (SynthOptions { supersample: 0, ..Default::default() }, "supersample"),
            (SynthOptions { room_size: [1.0, 5.0, 2.8], ..Default::default() }, "room_size"),
            (SynthOptions { texel_size: 0.0, ..Default::default() }, "texel_size"),
            (SynthOptions { texel_size: 0.001, room_size: [50.0, 50.0, 10.0], ..Default::default() }, "texel_size"),
            (SynthOptions { width: 8000, height: 8000, ..Default::default() }, "rays per frame"),
            (SynthOptions { orbit_radius: 5.0, ..Default::default() }, "orbit_radius"),
            (SynthOptions { distortion: Some([f64::INFINITY, 0.0, 0.0, 0.0]), ..Default::default() }, "distortion.k1"),
        ];
        for (opts, name) in cases {
            let e = opts.validate().unwrap_err().to_string();
            assert!(e.contains(name), "{e} should name {name}");
        }
        let e = SynthOptions { noise_sigma: -1.0, ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("-1") && e.contains(">= 0"), "{e}");
    }
}

//! COLMAP text model files, after COLMAP 4's `reconstruction_io_text.cc`:
//! `#` comment headers, one record per line (images take two lines: the
//! pose line and the keypoint line, which may be empty), numbers written
//! like `%.17g`, `-1` for a keypoint without 3D point.

use super::fmt::push_g17;
use super::{Loc, RawCamera, RawData, RawFrame, RawImage, RawPoint, RawRig, RawSensor, SENSOR_CAMERA};
use crate::error::SceneError;
use crate::ids::INVALID_POINT3D_ID;
use crate::reconstruction::Reconstruction;
use colslam_camera::CameraModelId;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use std::fmt::Write as _;
use std::path::Path;
use std::str::FromStr;

/// COLMAP's sensor type names (`SensorType` enum: INVALID = -1, CAMERA = 0,
/// IMU = 1).
const SENSOR_TYPES: [(&str, i32); 3] = [("INVALID", -1), ("CAMERA", SENSOR_CAMERA), ("IMU", 1)];

fn sensor_name(kind: i32) -> &'static str {
    SENSOR_TYPES.iter().find(|(_, k)| *k == kind).map_or("INVALID", |(n, _)| n)
}

/// Tokens of one line with its file and number, for error messages.
struct Line<'a> {
    path: &'a Path,
    number: usize,
    tokens: std::str::SplitWhitespace<'a>,
}

impl<'a> Line<'a> {
    fn new(path: &'a Path, number: usize, text: &'a str) -> Self {
        Self { path, number, tokens: text.split_whitespace() }
    }

    fn err(&self, what: String) -> SceneError {
        SceneError::BadLine { path: self.path.to_path_buf(), line: self.number, what }
    }

    fn next_str(&mut self, what: &str) -> Result<&'a str, SceneError> {
        self.tokens.next().ok_or_else(|| self.err(format!("missing {what}")))
    }

    fn next<T: FromStr>(&mut self, what: &str) -> Result<T, SceneError> {
        let t = self.next_str(what)?;
        t.parse().map_err(|_| self.err(format!("{what} {t:?} is not a valid {}", std::any::type_name::<T>())))
    }

    fn pose(&mut self, what: &str) -> Result<Rigid3, SceneError> {
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = self.next(what)?;
        }
        super::pose_from_parts([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]])
            .map_err(|e| self.err(format!("{what}: {e}")))
    }

    fn sensor_type(&mut self) -> Result<i32, SceneError> {
        let t = self.next_str("sensor type")?;
        SENSOR_TYPES
            .iter()
            .find(|(n, _)| *n == t)
            .map(|(_, k)| *k)
            .ok_or_else(|| self.err(format!("unknown sensor type {t:?}")))
    }

    fn rest(&mut self) -> Vec<&'a str> {
        self.tokens.by_ref().collect()
    }

    fn end(&mut self) -> Result<(), SceneError> {
        match self.tokens.next() {
            None => Ok(()),
            Some(t) => Err(self.err(format!("unexpected extra value {t:?}"))),
        }
    }
}

/// Data lines (not empty, not comments) with 1-based numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

pub(super) fn parse_cameras(path: &Path, text: &str) -> Result<Vec<RawCamera>, SceneError> {
    let mut out = Vec::new();
    for (number, l) in data_lines(text) {
        let mut line = Line::new(path, number, l);
        let id: u32 = line.next("camera id")?;
        let name = line.next_str("camera model")?;
        let model = CameraModelId::from_name(name).ok_or_else(|| SceneError::UnknownCameraModel {
            path: path.to_path_buf(),
            camera: id,
            model: format!("{name:?} (line {number})"),
        })?;
        let width: u64 = line.next("width")?;
        let height: u64 = line.next("height")?;
        let params = line
            .rest()
            .into_iter()
            .map(|t| t.parse::<f64>().map_err(|_| line.err(format!("camera parameter {t:?} is not a number"))))
            .collect::<Result<Vec<_>, _>>()?;
        let camera = super::make_camera(path, Loc::Line(number), id, model, width, height, params)?;
        out.push(RawCamera { loc: Loc::Line(number), id, camera });
    }
    Ok(out)
}

pub(super) fn parse_images(path: &Path, text: &str) -> Result<Vec<RawImage>, SceneError> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    while let Some((number, raw)) = lines.next() {
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut line = Line::new(path, number, l);
        let id: u32 = line.next("image id")?;
        let cam_from_world = line.pose("image pose")?;
        let camera_id: u32 = line.next("camera id")?;
        let name = line.next_str("image name")?.to_string();
        line.end().map_err(|_| line.err("image name must not contain whitespace".into()))?;
        // The keypoint line follows directly, even when empty.
        let Some((pnum, praw)) = lines.next() else {
            return Err(line.err(format!("image {id} has no POINTS2D line")));
        };
        let mut pline = Line::new(path, pnum, praw.trim());
        let toks = pline.rest();
        if !toks.len().is_multiple_of(3) {
            return Err(
                pline.err(format!("POINTS2D has {} values, not a multiple of 3 (X, Y, POINT3D_ID)", toks.len()))
            );
        }
        let mut points2d = Vec::with_capacity(toks.len() / 3);
        for c in toks.chunks_exact(3) {
            let num =
                |t: &str, what: &str| t.parse::<f64>().map_err(|_| pline.err(format!("{what} {t:?} is not a number")));
            let (x, y) = (num(c[0], "point2D x")?, num(c[1], "point2D y")?);
            let pid = if c[2] == "-1" {
                None
            } else {
                let v: u64 =
                    c[2].parse().map_err(|_| pline.err(format!("point3D id {:?} is not -1 or an id", c[2])))?;
                (v != INVALID_POINT3D_ID).then_some(v)
            };
            points2d.push((Vec2::new(x, y), pid));
        }
        out.push(RawImage { loc: Loc::Line(number), id, cam_from_world, camera_id, name, points2d });
    }
    Ok(out)
}

pub(super) fn parse_points(path: &Path, text: &str) -> Result<Vec<RawPoint>, SceneError> {
    let mut out = Vec::new();
    for (number, l) in data_lines(text) {
        let mut line = Line::new(path, number, l);
        let id: u64 = line.next("point3D id")?;
        if id == INVALID_POINT3D_ID {
            return Err(line.err("point3D id is the invalid id".into()));
        }
        let xyz = Vec3::new(line.next("x")?, line.next("y")?, line.next("z")?);
        let color = [line.next("red")?, line.next("green")?, line.next("blue")?];
        let error: f64 = line.next("error")?;
        let toks = line.rest();
        if !toks.len().is_multiple_of(2) {
            return Err(line.err(format!("TRACK has {} values, not pairs (IMAGE_ID, POINT2D_IDX)", toks.len())));
        }
        let mut track = Vec::with_capacity(toks.len() / 2);
        for c in toks.chunks_exact(2) {
            let img: u32 = c[0].parse().map_err(|_| line.err(format!("track image id {:?} is invalid", c[0])))?;
            let idx: u32 = c[1].parse().map_err(|_| line.err(format!("track point2D index {:?} is invalid", c[1])))?;
            track.push((img, idx));
        }
        out.push(RawPoint { loc: Loc::Line(number), id, xyz, color, error, track });
    }
    Ok(out)
}

pub(super) fn parse_rigs(path: &Path, text: &str) -> Result<Vec<RawRig>, SceneError> {
    let mut out = Vec::new();
    for (number, l) in data_lines(text) {
        let mut line = Line::new(path, number, l);
        let id: u32 = line.next("rig id")?;
        let n: u32 = line.next("number of sensors")?;
        let mut sensors = Vec::new();
        if n > 0 {
            let kind = line.sensor_type()?;
            let sid: u32 = line.next("reference sensor id")?;
            sensors.push(RawSensor { kind, id: sid, pose: None });
        }
        for _ in 1..n {
            let kind = line.sensor_type()?;
            let sid: u32 = line.next("sensor id")?;
            let has_pose: u8 = line.next("has_pose")?;
            let pose = match has_pose {
                0 => None,
                1 => Some(line.pose("sensor_from_rig")?),
                v => return Err(line.err(format!("has_pose is {v}, not 0 or 1"))),
            };
            sensors.push(RawSensor { kind, id: sid, pose });
        }
        line.end()?;
        out.push(RawRig { loc: Loc::Line(number), id, sensors });
    }
    Ok(out)
}

pub(super) fn parse_frames(path: &Path, text: &str) -> Result<Vec<RawFrame>, SceneError> {
    let mut out = Vec::new();
    for (number, l) in data_lines(text) {
        let mut line = Line::new(path, number, l);
        let id: u32 = line.next("frame id")?;
        let rig_id: u32 = line.next("rig id")?;
        let rig_from_world = line.pose("rig_from_world")?;
        let n: u32 = line.next("number of data ids")?;
        let mut data = Vec::new();
        for _ in 0..n {
            let kind = line.sensor_type()?;
            let sensor_id: u32 = line.next("sensor id")?;
            let data_id: u64 = line.next("data id")?;
            data.push(RawData { kind, sensor_id, data_id });
        }
        line.end()?;
        out.push(RawFrame { loc: Loc::Line(number), id, rig_id, rig_from_world, data });
    }
    Ok(out)
}

// ----- writing -------------------------------------------------------------

fn push_pose(s: &mut String, p: &Rigid3) {
    for v in p.quat_wxyz().iter().chain(p.translation.iter()) {
        push_g17(s, *v);
        s.push(' ');
    }
}

pub(super) fn write_rigs(rec: &Reconstruction) -> String {
    let mut s = String::new();
    s.push_str("# Rig calib list with one line of data per calib:\n");
    s.push_str(
        "#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n",
    );
    let _ = writeln!(s, "# Number of rigs: {}", rec.num_cameras());
    for cam in rec.cameras() {
        let _ = writeln!(s, "{} 1 {} {}", cam.id, sensor_name(SENSOR_CAMERA), cam.id);
    }
    s
}

pub(super) fn write_cameras(rec: &Reconstruction) -> String {
    let mut s = String::new();
    s.push_str("# Camera list with one line of data per camera:\n");
    s.push_str("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    let _ = writeln!(s, "# Number of cameras: {}", rec.num_cameras());
    for cam in rec.cameras() {
        let c = &cam.camera;
        let _ = write!(s, "{} {} {} {}", cam.id, c.model.name(), c.width, c.height);
        for p in &c.params {
            s.push(' ');
            push_g17(&mut s, *p);
        }
        s.push('\n');
    }
    s
}

pub(super) fn write_frames(rec: &Reconstruction) -> String {
    let mut s = String::new();
    s.push_str("# Frame list with one line of data per frame:\n");
    s.push_str(
        "#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS, DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)\n",
    );
    let _ = writeln!(s, "# Number of frames: {}", rec.num_registered_images());
    for img in rec.images().filter(|i| i.registered) {
        let _ = write!(s, "{} {} ", img.id, img.camera_id);
        push_pose(&mut s, &img.cam_from_world);
        let _ = writeln!(s, "1 {} {} {}", sensor_name(SENSOR_CAMERA), img.camera_id, img.id);
    }
    s
}

pub(super) fn write_images(rec: &Reconstruction, path: &Path) -> Result<String, SceneError> {
    let mut s = String::new();
    s.push_str("# Image list with two lines of data per image:\n");
    s.push_str("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n");
    s.push_str("#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
    let _ = write!(s, "# Number of images: {}, mean observations per image: ", rec.num_registered_images());
    push_g17(&mut s, rec.mean_observations_per_registered_image());
    s.push('\n');
    for img in rec.registered_image_ids().iter().filter_map(|id| rec.image(*id)) {
        if img.name.is_empty() || img.name.chars().any(char::is_whitespace) {
            return Err(SceneError::Unwritable {
                path: path.to_path_buf(),
                what: format!("image {} name {:?} is empty or has whitespace (text format)", img.id, img.name),
            });
        }
        let _ = write!(s, "{} ", img.id);
        push_pose(&mut s, &img.cam_from_world);
        let _ = writeln!(s, "{} {}", img.camera_id, img.name);
        // COLMAP leaves a space after the last keypoint.
        for p in &img.points2d {
            push_g17(&mut s, p.xy.x);
            s.push(' ');
            push_g17(&mut s, p.xy.y);
            s.push(' ');
            match p.point3d_id {
                Some(id) => {
                    let _ = write!(s, "{id} ");
                }
                None => s.push_str("-1 "),
            }
        }
        s.push('\n');
    }
    Ok(s)
}

pub(super) fn write_points(rec: &Reconstruction) -> String {
    let mut s = String::new();
    s.push_str("# 3D point list with one line of data per point:\n");
    s.push_str("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    let _ = write!(s, "# Number of points: {}, mean track length: ", rec.num_points3d());
    push_g17(&mut s, rec.mean_track_length());
    s.push('\n');
    for (id, p) in rec.points3d() {
        let _ = write!(s, "{id} ");
        for v in p.xyz.iter() {
            push_g17(&mut s, *v);
            s.push(' ');
        }
        let _ = write!(s, "{} {} {} ", p.color[0], p.color[1], p.color[2]);
        push_g17(&mut s, p.error);
        s.push(' ');
        let mut first = true;
        for el in &p.track {
            if !first {
                s.push(' ');
            }
            first = false;
            let _ = write!(s, "{} {}", el.image_id, el.point2d_idx);
        }
        s.push('\n');
    }
    s
}

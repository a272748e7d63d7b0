//! COLMAP binary model files (little-endian), after COLMAP 4's
//! `reconstruction_io_binary.cc`.
//!
//! Layouts (counts are u64 unless noted):
//! * cameras: count; per camera: id u32, model i32, width u64, height u64,
//!   params f64 x model's count.
//! * images: count; per image: id u32, qw qx qy qz tx ty tz f64, camera u32,
//!   name bytes + NUL, num points2D u64, per point x y f64 + point3D id u64
//!   (`u64::MAX` = none).
//! * points3D: count; per point: id u64, x y z f64, r g b u8, error f64,
//!   track length u64, per element image u32 + point2D index u32.
//! * rigs: count; per rig: id u32, num sensors u32, if > 0 the reference
//!   sensor (type i32, id u32), then per other sensor type i32, id u32,
//!   has_pose u8, pose (qw qx qy qz tx ty tz f64) when has_pose.
//! * frames: count; per frame: id u32, rig id u32, rig_from_world (7 f64),
//!   num data ids u32, per data id sensor type i32, sensor id u32, id u64.
//!
//! Every count is checked against the bytes left before anything is
//! allocated, so a corrupt count fails cleanly.

use super::{Loc, RawCamera, RawData, RawFrame, RawImage, RawPoint, RawRig, RawSensor, SENSOR_CAMERA};
use crate::error::SceneError;
use crate::ids::{INVALID_POINT3D_ID, Point3DId};
use crate::reconstruction::Reconstruction;
use colslam_camera::CameraModelId;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use std::path::Path;

/// Bytes of a pose: 7 f64.
const POSE_BYTES: usize = 7 * 8;
/// Smallest camera record: id, model, width, height, no parameters.
const MIN_CAMERA_BYTES: usize = 4 + 4 + 8 + 8;
/// Smallest image record: id, pose, camera, empty name (NUL), point count.
const MIN_IMAGE_BYTES: usize = 4 + POSE_BYTES + 4 + 1 + 8;
/// One keypoint: x, y, point3D id.
const POINT2D_BYTES: usize = 8 + 8 + 8;
/// Smallest 3D point record: id, xyz, rgb, error, track length.
const MIN_POINT3D_BYTES: usize = 8 + 3 * 8 + 3 + 8 + 8;
/// One track element: image id, point2D index.
const TRACK_ELEMENT_BYTES: usize = 4 + 4;
/// Smallest rig record: id, sensor count.
const MIN_RIG_BYTES: usize = 4 + 4;
/// Smallest non-reference sensor: type, id, has_pose.
const MIN_SENSOR_BYTES: usize = 4 + 4 + 1;
/// Smallest frame record: id, rig id, pose, data id count.
const MIN_FRAME_BYTES: usize = 4 + 4 + POSE_BYTES + 4;
/// One frame data id: sensor type, sensor id, data id.
const DATA_ID_BYTES: usize = 4 + 4 + 8;

/// A bounds-checked little-endian cursor over a file's bytes.
struct Reader<'a> {
    path: &'a Path,
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path, buf: &'a [u8]) -> Self {
        Self { path, buf, pos: 0 }
    }

    fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], SceneError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        match end.and_then(|e| self.buf.get(self.pos..e)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => Err(SceneError::Truncated {
                path: self.path.to_path_buf(),
                offset: self.pos,
                what: format!("{what}: need {n} bytes, {} left", self.remaining()),
            }),
        }
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], SceneError> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    fn u8(&mut self, what: &str) -> Result<u8, SceneError> {
        Ok(self.array::<1>(what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, SceneError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    fn i32(&mut self, what: &str) -> Result<i32, SceneError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    fn u64(&mut self, what: &str) -> Result<u64, SceneError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }
    fn f64(&mut self, what: &str) -> Result<f64, SceneError> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    fn pose(&mut self, what: &str) -> Result<Rigid3, SceneError> {
        let at = self.pos;
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = self.f64(what)?;
        }
        super::pose_from_parts([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]])
            .map_err(|e| self.corrupt(at, format!("{what}: {e}")))
    }

    /// Reads a count of records of at least `min_bytes` each and checks that
    /// the file can hold them before anyone allocates for them.
    fn count(&mut self, min_bytes: usize, what: &str) -> Result<usize, SceneError> {
        let at = self.pos;
        let n = self.u64(what)?;
        self.check_count(at, n, min_bytes, what)
    }

    fn count_u32(&mut self, min_bytes: usize, what: &str) -> Result<usize, SceneError> {
        let at = self.pos;
        let n = u64::from(self.u32(what)?);
        self.check_count(at, n, min_bytes, what)
    }

    fn check_count(&self, at: usize, n: u64, min_bytes: usize, what: &str) -> Result<usize, SceneError> {
        let need = usize::try_from(n).ok().and_then(|n| n.checked_mul(min_bytes));
        match need {
            Some(need) if need <= self.remaining() => Ok(n as usize),
            _ => Err(SceneError::Truncated {
                path: self.path.to_path_buf(),
                offset: at,
                what: format!(
                    "{what} = {n} needs at least {} bytes, only {} left",
                    need.map_or("more than 2^64".to_string(), |b| b.to_string()),
                    self.remaining()
                ),
            }),
        }
    }

    fn cstring(&mut self, what: &str) -> Result<String, SceneError> {
        let at = self.pos;
        let rest = self.buf.get(self.pos..).unwrap_or(&[]);
        let Some(len) = rest.iter().position(|&b| b == 0) else {
            return Err(SceneError::Truncated {
                path: self.path.to_path_buf(),
                offset: at,
                what: format!("{what}: no terminating NUL"),
            });
        };
        let bytes = self.take(len, what)?;
        self.pos += 1; // the NUL found above
        String::from_utf8(bytes.to_vec()).map_err(|_| self.corrupt(at, format!("{what} is not UTF-8")))
    }

    fn corrupt(&self, offset: usize, what: String) -> SceneError {
        SceneError::Corrupt { path: self.path.to_path_buf(), offset, what }
    }

    fn finish(&self) -> Result<(), SceneError> {
        if self.remaining() == 0 {
            Ok(())
        } else {
            Err(self.corrupt(self.pos, format!("{} unexpected trailing bytes", self.remaining())))
        }
    }
}

pub(super) fn parse_cameras(path: &Path, buf: &[u8]) -> Result<Vec<RawCamera>, SceneError> {
    let mut r = Reader::new(path, buf);
    let n = r.count(MIN_CAMERA_BYTES, "number of cameras")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let at = r.pos;
        let id = r.u32("camera id")?;
        let model_id = r.i32("camera model")?;
        let model = CameraModelId::from_id(model_id).ok_or_else(|| SceneError::UnknownCameraModel {
            path: path.to_path_buf(),
            camera: id,
            model: format!("id {model_id} (at byte {})", at + 4),
        })?;
        let width = r.u64("camera width")?;
        let height = r.u64("camera height")?;
        let mut params = Vec::with_capacity(model.num_params());
        for _ in 0..model.num_params() {
            params.push(r.f64("camera parameter")?);
        }
        let camera = super::make_camera(path, Loc::Byte(at), id, model, width, height, params)?;
        out.push(RawCamera { loc: Loc::Byte(at), id, camera });
    }
    r.finish()?;
    Ok(out)
}

pub(super) fn parse_images(path: &Path, buf: &[u8]) -> Result<Vec<RawImage>, SceneError> {
    let mut r = Reader::new(path, buf);
    let n = r.count(MIN_IMAGE_BYTES, "number of images")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let at = r.pos;
        let id = r.u32("image id")?;
        let cam_from_world = r.pose("image pose")?;
        let camera_id = r.u32("image camera id")?;
        let name = r.cstring("image name")?;
        let np = r.count(POINT2D_BYTES, "number of points2D")?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            let x = r.f64("point2D x")?;
            let y = r.f64("point2D y")?;
            let pid = r.u64("point2D point3D id")?;
            points2d.push((Vec2::new(x, y), (pid != INVALID_POINT3D_ID).then_some(pid)));
        }
        out.push(RawImage { loc: Loc::Byte(at), id, cam_from_world, camera_id, name, points2d });
    }
    r.finish()?;
    Ok(out)
}

pub(super) fn parse_points(path: &Path, buf: &[u8]) -> Result<Vec<RawPoint>, SceneError> {
    let mut r = Reader::new(path, buf);
    let n = r.count(MIN_POINT3D_BYTES, "number of points3D")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let at = r.pos;
        let id = r.u64("point3D id")?;
        if id == INVALID_POINT3D_ID {
            return Err(r.corrupt(at, "point3D id is the invalid id u64::MAX".into()));
        }
        let xyz = Vec3::new(r.f64("point3D x")?, r.f64("point3D y")?, r.f64("point3D z")?);
        let color = [r.u8("point3D red")?, r.u8("point3D green")?, r.u8("point3D blue")?];
        let error = r.f64("point3D error")?;
        let len = r.count(TRACK_ELEMENT_BYTES, "track length")?;
        let mut track = Vec::with_capacity(len);
        for _ in 0..len {
            track.push((r.u32("track image id")?, r.u32("track point2D index")?));
        }
        out.push(RawPoint { loc: Loc::Byte(at), id, xyz, color, error, track });
    }
    r.finish()?;
    Ok(out)
}

pub(super) fn parse_rigs(path: &Path, buf: &[u8]) -> Result<Vec<RawRig>, SceneError> {
    let mut r = Reader::new(path, buf);
    let n = r.count(MIN_RIG_BYTES, "number of rigs")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let at = r.pos;
        let id = r.u32("rig id")?;
        let ns = r.count_u32(MIN_SENSOR_BYTES - 1, "number of sensors")?;
        let mut sensors = Vec::with_capacity(ns);
        if ns > 0 {
            let kind = r.i32("reference sensor type")?;
            let sid = r.u32("reference sensor id")?;
            sensors.push(RawSensor { kind, id: sid, pose: None });
        }
        for _ in 1..ns {
            let kind = r.i32("sensor type")?;
            let sid = r.u32("sensor id")?;
            let has_pose = r.u8("sensor has_pose")?;
            let pose = match has_pose {
                0 => None,
                1 => Some(r.pose("sensor_from_rig")?),
                v => return Err(r.corrupt(r.pos - 1, format!("sensor has_pose is {v}, not 0 or 1"))),
            };
            sensors.push(RawSensor { kind, id: sid, pose });
        }
        out.push(RawRig { loc: Loc::Byte(at), id, sensors });
    }
    r.finish()?;
    Ok(out)
}

pub(super) fn parse_frames(path: &Path, buf: &[u8]) -> Result<Vec<RawFrame>, SceneError> {
    let mut r = Reader::new(path, buf);
    let n = r.count(MIN_FRAME_BYTES, "number of frames")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let at = r.pos;
        let id = r.u32("frame id")?;
        let rig_id = r.u32("frame rig id")?;
        let rig_from_world = r.pose("rig_from_world")?;
        let nd = r.count_u32(DATA_ID_BYTES, "number of data ids")?;
        let mut data = Vec::with_capacity(nd);
        for _ in 0..nd {
            let kind = r.i32("data sensor type")?;
            let sensor_id = r.u32("data sensor id")?;
            let data_id = r.u64("data id")?;
            data.push(RawData { kind, sensor_id, data_id });
        }
        out.push(RawFrame { loc: Loc::Byte(at), id, rig_id, rig_from_world, data });
    }
    r.finish()?;
    Ok(out)
}

// ----- writing -------------------------------------------------------------

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_i32(b: &mut Vec<u8>, v: i32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f64(b: &mut Vec<u8>, v: f64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_pose(b: &mut Vec<u8>, p: &Rigid3) {
    for v in p.quat_wxyz() {
        put_f64(b, v);
    }
    for v in p.translation.iter() {
        put_f64(b, *v);
    }
}

/// One single-sensor rig per camera, `rig_id = camera_id`.
pub(super) fn write_rigs(rec: &Reconstruction) -> Vec<u8> {
    let mut b = Vec::new();
    put_u64(&mut b, rec.num_cameras() as u64);
    for cam in rec.cameras() {
        put_u32(&mut b, cam.id.0);
        put_u32(&mut b, 1);
        put_i32(&mut b, SENSOR_CAMERA);
        put_u32(&mut b, cam.id.0);
    }
    b
}

pub(super) fn write_cameras(rec: &Reconstruction) -> Vec<u8> {
    let mut b = Vec::new();
    put_u64(&mut b, rec.num_cameras() as u64);
    for cam in rec.cameras() {
        put_u32(&mut b, cam.id.0);
        put_i32(&mut b, cam.camera.model.id());
        put_u64(&mut b, cam.camera.width);
        put_u64(&mut b, cam.camera.height);
        for p in &cam.camera.params {
            put_f64(&mut b, *p);
        }
    }
    b
}

/// One frame per registered image (`frame_id = image_id`, rig = camera), by
/// increasing id as COLMAP writes them.
pub(super) fn write_frames(rec: &Reconstruction) -> Vec<u8> {
    let mut b = Vec::new();
    let reg: Vec<_> = rec.images().filter(|i| i.registered).collect();
    put_u64(&mut b, reg.len() as u64);
    for img in reg {
        put_u32(&mut b, img.id.0);
        put_u32(&mut b, img.camera_id.0);
        put_pose(&mut b, &img.cam_from_world);
        put_u32(&mut b, 1);
        put_i32(&mut b, SENSOR_CAMERA);
        put_u32(&mut b, img.camera_id.0);
        put_u64(&mut b, u64::from(img.id.0));
    }
    b
}

/// Registered images in registration order.
pub(super) fn write_images(rec: &Reconstruction, path: &Path) -> Result<Vec<u8>, SceneError> {
    let mut b = Vec::new();
    put_u64(&mut b, rec.num_registered_images() as u64);
    for img in rec.registered_image_ids().iter().filter_map(|id| rec.image(*id)) {
        if img.name.as_bytes().contains(&0) {
            return Err(SceneError::Unwritable {
                path: path.to_path_buf(),
                what: format!("image {} name {:?} contains a NUL byte", img.id, img.name),
            });
        }
        put_u32(&mut b, img.id.0);
        put_pose(&mut b, &img.cam_from_world);
        put_u32(&mut b, img.camera_id.0);
        b.extend_from_slice(img.name.as_bytes());
        b.push(0);
        put_u64(&mut b, img.points2d.len() as u64);
        for p in &img.points2d {
            put_f64(&mut b, p.xy.x);
            put_f64(&mut b, p.xy.y);
            put_u64(&mut b, Point3DId::to_binary(p.point3d_id));
        }
    }
    Ok(b)
}

pub(super) fn write_points(rec: &Reconstruction) -> Vec<u8> {
    let mut b = Vec::new();
    put_u64(&mut b, rec.num_points3d() as u64);
    for (id, p) in rec.points3d() {
        put_u64(&mut b, id.0);
        for v in p.xyz.iter() {
            put_f64(&mut b, *v);
        }
        b.extend_from_slice(&p.color);
        put_f64(&mut b, p.error);
        put_u64(&mut b, p.track.len() as u64);
        for el in &p.track {
            put_u32(&mut b, el.image_id.0);
            put_u32(&mut b, el.point2d_idx);
        }
    }
    b
}

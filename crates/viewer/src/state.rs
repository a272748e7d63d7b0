//! The viewer's shared state: the map with a version stamp on every entity,
//! so a client that has seen version `v` can be sent only what changed since.
//!
//! Invariants:
//! * `version` only grows within an epoch; every change stamps the changed
//!   entity (or tombstone) with the new `version`.
//! * `epoch` changes when the whole map is replaced (a loaded model, a reset);
//!   a client on an older epoch gets a full snapshot, never a delta.

use crate::frames::ImageSource;
use crate::gt::GroundTruthLayer;
use crate::types::{FrameUpdate, KeyframeUpdate, MapDelta, RunState, Summary, ViewerCamera, ViewerPoint, ViewerUpdate};
use colslam_image::Image;
use colslam_scene::Reconstruction;
use serde_json::{Value, json};
use std::collections::HashMap;
use std::sync::Arc;

/// Relative position change below which a synced point counts as unchanged
/// (avoids resending points that bundle adjustment moved by rounding noise).
const SYNC_POSITION_TOLERANCE: f64 = 1e-9;

/// Tombstones (removed ids) kept before they are dropped; a client older
/// than the drop then gets a full state instead of a delta.
const MAX_TOMBSTONES: usize = 200_000;

#[derive(Debug, Clone, Default)]
struct Stamped<T> {
    value: T,
    version: u64,
}

/// A frame or keyframe picture, shared with the HTTP threads that serve it.
#[derive(Debug, Clone)]
pub(crate) struct Picture {
    pub image: Arc<Image>,
    /// Version at which it was set: the page asks `/api/frame.png?v=N`.
    pub version: u64,
}

/// Everything the page shows.
#[derive(Debug, Default)]
pub(crate) struct State {
    pub epoch: u64,
    pub version: u64,
    /// Version of the last point/camera change (lets a delta skip the scan).
    map_version: u64,
    points: HashMap<u64, Stamped<ViewerPoint>>,
    cameras: HashMap<u32, Stamped<ViewerCamera>>,
    removed_points: Vec<(u64, u64)>,
    removed_cameras: Vec<(u32, u64)>,
    /// Tombstones stamped up to this version were dropped: a delta from an
    /// older version cannot be built and a full state is sent instead.
    tombstone_floor: u64,
    /// Next registration order handed to a camera first seen by `sync`.
    next_order: u32,
    frame: Option<Stamped<FrameUpdate>>,
    pub frame_picture: Option<Picture>,
    keyframe: Option<Stamped<KeyframeUpdate>>,
    pub keyframe_picture: Option<Picture>,
    summary: Stamped<Summary>,
    status: Stamped<String>,
    run: Stamped<RunState>,
    /// Where the shown model came from ("live", a folder path, or empty).
    source: Stamped<String>,
    /// The last full reconstruction given (for export, the frame panel's
    /// keypoints and pictures).
    pub model: Option<Arc<Reconstruction>>,
    /// Where the loaded model's images are (`None`: none looked for, e.g. a
    /// live map).
    images: Stamped<Option<Arc<ImageSource>>>,
    /// The loaded model compared with a ground truth.
    ground_truth: Stamped<Option<GroundTruthLayer>>,
    /// Whether a run controller is attached (Run enabled in the page).
    pub has_controller: bool,
    /// Set when the server shuts down; wakes and ends the event streams.
    pub shutdown: bool,
}

impl State {
    fn bump(&mut self) -> u64 {
        self.version += 1;
        self.version
    }

    /// Clears everything map-related and starts a new epoch.
    fn new_epoch(&mut self) {
        self.epoch += 1;
        self.version = 0;
        self.map_version = 0;
        self.points.clear();
        self.cameras.clear();
        self.removed_points.clear();
        self.removed_cameras.clear();
        self.tombstone_floor = 0;
        self.next_order = 0;
        let v = self.bump();
        // Re-stamp the non-map parts so a delta from 0 would include them.
        self.summary.version = v;
        self.status.version = v;
        self.run.version = v;
        self.source.version = v;
        self.images.version = v;
        self.ground_truth.version = v;
        if let Some(f) = &mut self.frame {
            f.version = v;
        }
        if let Some(k) = &mut self.keyframe {
            k.version = v;
        }
    }

    /// The current run state.
    pub fn run_state(&self) -> &RunState {
        &self.run.value
    }

    /// Number of points and cameras held.
    pub fn counts(&self) -> (usize, usize) {
        (self.points.len(), self.cameras.len())
    }

    /// Replaces the map by `rec` (new epoch); cameras are ordered by
    /// registration order.
    pub fn set_reconstruction(&mut self, rec: &Reconstruction, source: &str) {
        self.new_epoch();
        let v = self.version;
        for (order, id) in rec.registered_image_ids().iter().enumerate() {
            let order = u32::try_from(order).unwrap_or(u32::MAX);
            if let Some(cam) = rec.image(*id).and_then(|img| ViewerCamera::from_image(rec, img, order)) {
                self.cameras.insert(cam.image_id, Stamped { value: cam, version: v });
            }
        }
        self.next_order = u32::try_from(rec.num_registered_images()).unwrap_or(u32::MAX);
        for (id, p) in rec.points3d() {
            self.points.insert(id.0, Stamped { value: ViewerPoint::from_point(id, p), version: v });
        }
        self.map_version = v;
        self.summary = Stamped { value: Summary::of(rec), version: v };
        self.source = Stamped { value: source.to_string(), version: v };
        self.model = Some(Arc::new(rec.clone()));
        // A new model's images and ground truth are given after it, if any.
        self.images = Stamped { value: None, version: v };
        self.ground_truth = Stamped { value: None, version: v };
    }

    /// Sets where the shown model's images are.
    pub fn set_images(&mut self, images: ImageSource) {
        let v = self.bump();
        self.images = Stamped { value: Some(Arc::new(images)), version: v };
    }

    /// Sets (or clears) the ground-truth layer of the shown model.
    pub fn set_ground_truth(&mut self, layer: Option<GroundTruthLayer>) {
        let v = self.bump();
        self.ground_truth = Stamped { value: layer, version: v };
    }

    /// The shown model and where its images are, for the frame panel.
    pub fn model_and_images(&self) -> (Option<Arc<Reconstruction>>, Option<Arc<ImageSource>>) {
        (self.model.clone(), self.images.value.clone())
    }

    /// Brings the map in line with `rec` by a diff: changed or new points and
    /// cameras are upserted, vanished ones removed, all in the current epoch
    /// (clients receive only the difference). Cameras keep the order they
    /// were first seen with; new ones get the next order.
    pub fn sync_reconstruction(&mut self, rec: &Reconstruction) {
        let mut delta = MapDelta::default();
        let mut seen_cams = std::collections::HashSet::new();
        for id in rec.registered_image_ids() {
            seen_cams.insert(id.0);
            let order = self.cameras.get(&id.0).map(|c| c.value.order).unwrap_or_else(|| {
                let o = self.next_order;
                self.next_order = self.next_order.saturating_add(1);
                o
            });
            if let Some(cam) = rec.image(*id).and_then(|img| ViewerCamera::from_image(rec, img, order))
                && self.cameras.get(&id.0).is_none_or(|c| c.value != cam)
            {
                delta.cameras.push(cam);
            }
        }
        delta.removed_cameras = self.cameras.keys().filter(|k| !seen_cams.contains(k)).copied().collect();
        for (id, p) in rec.points3d() {
            let changed = match self.points.get(&id.0) {
                None => true,
                Some(old) => {
                    let o = &old.value;
                    let d = (0..3).map(|i| (o.xyz[i] - p.xyz[i]).abs()).fold(0.0, f64::max);
                    let scale = p.xyz.norm().max(1.0);
                    d > SYNC_POSITION_TOLERANCE * scale
                        || o.color != p.color
                        || o.observers != ViewerPoint::from_point(id, p).observers
                }
            };
            if changed {
                delta.points.push(ViewerPoint::from_point(id, p));
            }
        }
        delta.removed_points =
            self.points.keys().filter(|k| rec.point3d(colslam_scene::Point3DId(**k)).is_none()).copied().collect();
        self.apply_map_delta(delta);
        let v = self.bump();
        // The run's numbers (rate, progress) stay: the model is what it made.
        let run = self.summary.value;
        let summary = Summary { fps: run.fps, frames: run.frames, total_frames: run.total_frames, ..Summary::of(rec) };
        self.summary = Stamped { value: summary, version: v };
        // No copy of `rec` is kept for export here: cloning the whole model at
        // every keyframe would slow the pipeline. Export during a run asks
        // the controller's snapshot(); a vanished model must not be exported.
        self.model = None;
    }

    fn apply_map_delta(&mut self, d: MapDelta) {
        if d.points.is_empty() && d.cameras.is_empty() && d.removed_points.is_empty() && d.removed_cameras.is_empty() {
            return;
        }
        let v = self.bump();
        self.map_version = v;
        for c in d.cameras {
            self.next_order = self.next_order.max(c.order.saturating_add(1));
            self.cameras.insert(c.image_id, Stamped { value: c, version: v });
        }
        for id in d.removed_cameras {
            if self.cameras.remove(&id).is_some() {
                self.removed_cameras.push((id, v));
            }
        }
        for p in d.points {
            self.points.insert(p.id, Stamped { value: p, version: v });
        }
        for id in d.removed_points {
            if self.points.remove(&id).is_some() {
                self.removed_points.push((id, v));
            }
        }
        // A tombstone older than a re-added entity is harmless: the client
        // applies removals before upserts.
        if self.removed_points.len() + self.removed_cameras.len() > MAX_TOMBSTONES {
            self.removed_points.clear();
            self.removed_cameras.clear();
            self.tombstone_floor = v;
        }
        if self.source.value.is_empty() {
            self.source = Stamped { value: "live".into(), version: v };
        }
    }

    /// Applies one update.
    pub fn apply(&mut self, update: ViewerUpdate) {
        match update {
            ViewerUpdate::Reset => {
                self.new_epoch();
                let v = self.version;
                self.frame = None;
                self.frame_picture = None;
                self.keyframe = None;
                self.keyframe_picture = None;
                self.summary = Stamped { value: Summary::default(), version: v };
                self.source = Stamped { value: String::new(), version: v };
                self.model = None;
                self.images = Stamped { value: None, version: v };
                self.ground_truth = Stamped { value: None, version: v };
            }
            ViewerUpdate::Frame(mut f) => {
                let v = self.bump();
                self.frame_picture = f.image.take().map(|img| Picture { image: Arc::new(img), version: v });
                self.frame = Some(Stamped { value: f, version: v });
            }
            ViewerUpdate::Keyframe(mut k) => {
                let v = self.bump();
                self.keyframe_picture = k.image.take().map(|img| Picture { image: Arc::new(img), version: v });
                self.keyframe = Some(Stamped { value: k, version: v });
            }
            ViewerUpdate::MapDelta(d) => self.apply_map_delta(d),
            ViewerUpdate::Summary(s) => {
                let v = self.bump();
                self.summary = Stamped { value: s, version: v };
            }
            ViewerUpdate::Status(s) => {
                let v = self.bump();
                self.status = Stamped { value: s, version: v };
            }
            ViewerUpdate::RunState(r) => {
                let v = self.bump();
                self.run = Stamped { value: r, version: v };
            }
        }
    }

    /// The full state as JSON (`"full": true`).
    pub fn snapshot_json(&self) -> Value {
        self.json_since(0, true)
    }

    /// What changed after version `since` in this epoch (`"full": false`),
    /// or the full state when tombstones that delta needs were dropped.
    pub fn delta_json(&self, since: u64) -> Value {
        self.json_since(since, since < self.tombstone_floor)
    }

    fn json_since(&self, since: u64, full: bool) -> Value {
        let newer = |v: u64| full || v > since;
        let mut out = serde_json::Map::new();
        out.insert("full".into(), json!(full));
        out.insert("epoch".into(), json!(self.epoch));
        out.insert("version".into(), json!(self.version));
        if full || self.map_version > since {
            let mut pts: Vec<&ViewerPoint> =
                self.points.values().filter(|p| newer(p.version)).map(|p| &p.value).collect();
            pts.sort_unstable_by_key(|p| p.id);
            out.insert("points".into(), points_json(&pts));
            let mut cams: Vec<&ViewerCamera> =
                self.cameras.values().filter(|c| newer(c.version)).map(|c| &c.value).collect();
            cams.sort_unstable_by_key(|c| (c.order, c.image_id));
            out.insert("cameras".into(), Value::Array(cams.into_iter().map(camera_json).collect()));
            if !full {
                let rp: Vec<u64> = self.removed_points.iter().filter(|(_, v)| *v > since).map(|(id, _)| *id).collect();
                let rc: Vec<u32> = self.removed_cameras.iter().filter(|(_, v)| *v > since).map(|(id, _)| *id).collect();
                out.insert("removed_points".into(), json!(rp));
                out.insert("removed_cameras".into(), json!(rc));
            }
        }
        if let Some(f) = self.frame.as_ref().filter(|f| newer(f.version)) {
            let pic = self.frame_picture.as_ref();
            out.insert("frame".into(), frame_json(&f.value, pic));
        }
        if let Some(k) = self.keyframe.as_ref().filter(|k| newer(k.version)) {
            let pic = self.keyframe_picture.as_ref();
            out.insert(
                "keyframe".into(),
                json!({
                    "image_id": k.value.image_id,
                    "frame_index": k.value.frame_index,
                    "name": k.value.name,
                    "picture": pic.map(|p| p.version),
                }),
            );
        }
        if newer(self.summary.version) {
            out.insert("summary".into(), json!(self.summary.value));
        }
        if newer(self.status.version) {
            out.insert("status".into(), json!(self.status.value));
        }
        if newer(self.run.version) {
            out.insert("run".into(), json!({"state": self.run.value.name(), "message": self.run.value.message()}));
        }
        if newer(self.source.version) {
            out.insert("source".into(), json!(self.source.value));
        }
        if newer(self.images.version) {
            let images = self.images.value.as_ref().map(|i| json!({"available": i.available(), "note": i.describe()}));
            out.insert("images".into(), images.unwrap_or(Value::Null));
        }
        if newer(self.ground_truth.version) {
            out.insert("gt".into(), self.ground_truth.value.as_ref().map_or(Value::Null, GroundTruthLayer::to_json));
        }
        if full {
            out.insert("has_controller".into(), json!(self.has_controller));
        }
        Value::Object(out)
    }
}

/// Points as flat arrays (parsed straight into typed arrays by the page):
/// `ids`, `xyz` (3 per point), `rgb` (3 per point), `tlen` (observers per
/// point) and `track` (all observers, concatenated).
fn points_json(pts: &[&ViewerPoint]) -> Value {
    let mut ids = Vec::with_capacity(pts.len());
    let mut xyz = Vec::with_capacity(3 * pts.len());
    let mut rgb = Vec::with_capacity(3 * pts.len());
    let mut tlen = Vec::with_capacity(pts.len());
    let mut track: Vec<u32> = Vec::new();
    for p in pts {
        ids.push(p.id);
        // f32 is ample for display and halves the JSON size.
        xyz.extend(p.xyz.iter().map(|&c| c as f32));
        rgb.extend(p.color);
        tlen.push(p.observers.len());
        track.extend_from_slice(&p.observers);
    }
    json!({"ids": ids, "xyz": xyz, "rgb": rgb, "tlen": tlen, "track": track})
}

/// A camera: centre `c`, world-from-camera rotation `r` (row-major 3x3, so
/// its columns are the camera axes in world coordinates) and intrinsics.
fn camera_json(c: &ViewerCamera) -> Value {
    let world_from_cam = c.cam_from_world.inverse();
    let r = world_from_cam.rotation_matrix();
    let center = world_from_cam.translation;
    // i, j < 3 index a fixed 3x3 matrix: always in bounds.
    let rows: Vec<f32> = (0..3).flat_map(|i| (0..3).map(move |j| (i, j))).map(|(i, j)| r[(i, j)] as f32).collect();
    json!({
        "id": c.image_id, "name": c.name, "order": c.order,
        "c": [center.x as f32, center.y as f32, center.z as f32], "r": rows,
        "w": c.width, "h": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
    })
}

fn frame_json(f: &FrameUpdate, pic: Option<&Picture>) -> Value {
    let flat = |lines: &[[f32; 4]]| -> Vec<f32> { lines.iter().flatten().copied().collect() };
    json!({
        "index": f.index,
        "picture": pic.map(|p| p.version),
        "width": pic.map(|p| p.image.width()),
        "height": pic.map(|p| p.image.height()),
        "lines": flat(&f.flow_lines),
        "outlier_lines": flat(&f.outlier_lines),
        "flow_score": f.flow_score, "num_matches": f.num_matches, "num_inliers": f.num_inliers,
        "flow_threshold": f.flow_threshold, "min_matches": f.min_matches,
        "is_keyframe": f.is_keyframe,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(id: u64) -> ViewerPoint {
        ViewerPoint { id, xyz: [0.0; 3], color: [0; 3], observers: vec![] }
    }

    #[test]
    fn dropped_tombstones_force_a_full_state() {
        let mut st = State::default();
        let points: Vec<ViewerPoint> = (0..MAX_TOMBSTONES as u64 + 10).map(pt).collect();
        st.apply(ViewerUpdate::MapDelta(MapDelta { points, ..Default::default() }));
        let before = st.version;
        st.apply(ViewerUpdate::MapDelta(MapDelta { removed_points: (0..100).collect(), ..Default::default() }));
        let d = st.delta_json(before);
        assert_eq!(d["full"], false);
        assert_eq!(d["removed_points"].as_array().map(Vec::len), Some(100));
        let mid = st.version;
        // Pushing the tombstones over the limit drops them all.
        st.apply(ViewerUpdate::MapDelta(MapDelta {
            removed_points: (100..MAX_TOMBSTONES as u64 + 5).collect(),
            ..Default::default()
        }));
        assert_eq!(st.delta_json(mid)["full"], true, "a client older than the drop gets everything");
        let now = st.version;
        st.apply(ViewerUpdate::MapDelta(MapDelta {
            removed_points: vec![MAX_TOMBSTONES as u64 + 6],
            ..Default::default()
        }));
        let d = st.delta_json(now);
        assert_eq!(d["full"], false);
        assert_eq!(d["removed_points"], serde_json::json!([MAX_TOMBSTONES as u64 + 6]));
        assert_eq!(st.counts().0, 4, "ids MAX+5, MAX+7, MAX+8, MAX+9 remain");
    }
}

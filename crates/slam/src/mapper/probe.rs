//! Scale diagnostics for forward motion (issue 20), debug log only. At each
//! stage of a keyframe's registration (after PnP, after triangulation, after
//! its local BA) a `scale probe` line gives the centres of the new keyframe
//! and the keyframes before it with statistics of the stage's points; around
//! every local BA and global refinement a `scale snapshot` line gives the
//! keyframe centres. Against ground truth, `scripts/kitti-stage-scale.py`
//! and `scripts/kitti-lba-scale.py` tell which stage changes the scale
//! between consecutive keyframes. Nothing here changes the map, and without
//! debug logging nothing is computed.

use super::state::Mapper;
use colslam_geometry::Vec3;
use colslam_geometry::stats::median_finite;
use colslam_scene::reconstruction::triangulation_angle;
use colslam_scene::{Image, ImageId, Point3DId};
use std::collections::HashSet;

/// Keyframes before the new one whose centres a probe line lists: the
/// script's scale ratio needs two.
const PROBE_PREVIOUS: usize = 4;

/// The newest keyframes listed around a local BA: its bundle is the new
/// keyframe's most connected ones, on a sequence the last few, so the
/// change of scale it makes is seen without an O(keyframes) line per BA.
const LOCAL_BA_SNAPSHOT: usize = 12;

/// One probe: the new keyframe's frame and centre, the previous keyframes'
/// (newest first), and the stage's points' statistics.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ScaleProbe {
    /// Frame index and centre of the new keyframe, then of up to
    /// [`PROBE_PREVIOUS`] keyframes before it in registration order.
    pub(crate) centres: Vec<(usize, Vec3)>,
    /// Points measured (those that still exist).
    pub(crate) points: usize,
    /// Median over the points of their largest triangulation angle, degrees.
    pub(crate) median_angle_deg: f64,
    /// Median depth in the new camera over the distance to the previous
    /// keyframe (scale-free).
    pub(crate) median_depth_over_baseline: f64,
}

impl ScaleProbe {
    fn line(&self, stage: &str) -> String {
        let frame = self.centres.first().map_or(0, |c| c.0);
        format!(
            "scale probe {stage} frame {frame}: points {} angle {:.3} depth/baseline {:.2} centres {}",
            self.points,
            self.median_angle_deg,
            self.median_depth_over_baseline,
            centres_text(&self.centres)
        )
    }
}

/// `frame:x,y,z` for each centre, space-separated.
fn centres_text(centres: &[(usize, Vec3)]) -> String {
    let list: Vec<String> = centres.iter().map(|(f, c)| format!("{f}:{:.6},{:.6},{:.6}", c.x, c.y, c.z)).collect();
    list.join(" ")
}

/// The largest triangulation angle of a point over its track's centres, radians.
fn largest_angle(rec: &colslam_scene::Reconstruction, id: Point3DId) -> Option<f64> {
    let p = rec.point3d(id)?;
    let centres: Vec<Vec3> =
        p.track.iter().filter_map(|e| rec.image(e.image_id)).map(Image::projection_center).collect();
    let mut best = 0.0f64;
    for (i, a) in centres.iter().enumerate() {
        for b in &centres[i + 1..] {
            best = best.max(triangulation_angle(a, b, &p.xyz));
        }
    }
    Some(best)
}

impl Mapper {
    /// True when probes are logged (debug level).
    pub(super) fn probing() -> bool {
        tracing::enabled!(tracing::Level::DEBUG)
    }

    /// The 3D points image `image_id` observes.
    fn observed_points(&self, image_id: ImageId) -> HashSet<Point3DId> {
        self.rec
            .image(image_id)
            .map_or_else(HashSet::new, |img| img.points2d.iter().filter_map(|p| p.point3d_id).collect())
    }

    /// The probe of the new keyframe `image_id` (frame `frame`, not yet
    /// among the keyframes) over `points`; `None` when it is not in the map.
    pub(crate) fn scale_probe(&self, image_id: ImageId, frame: usize, points: &[Point3DId]) -> Option<ScaleProbe> {
        let img = self.rec.image(image_id)?;
        let centre = img.cam_from_world.center();
        let mut centres = vec![(frame, centre)];
        centres.extend(
            self.keyframes
                .iter()
                .rev()
                .filter(|k| k.image_id != image_id)
                .take(PROBE_PREVIOUS)
                .filter_map(|k| self.rec.image(k.image_id).map(|i| (k.data.index(), i.cam_from_world.center()))),
        );
        let baseline = centres.get(1).map_or(f64::NAN, |(_, c)| (c - centre).norm());
        let (mut angles, mut depths) = (Vec::new(), Vec::new());
        for pid in points {
            let (Some(p), Some(angle)) = (self.rec.point3d(*pid), largest_angle(&self.rec, *pid)) else { continue };
            angles.push(angle.to_degrees());
            depths.push(img.cam_from_world.transform_point(&p.xyz).z / baseline);
        }
        Some(ScaleProbe {
            centres,
            points: angles.len(),
            median_angle_deg: median_finite(&angles).unwrap_or(f64::NAN),
            median_depth_over_baseline: median_finite(&depths).unwrap_or(f64::NAN),
        })
    }

    fn log_probe(&self, stage: &str, image_id: ImageId, frame: usize, points: &[Point3DId]) {
        if let Some(probe) = self.scale_probe(image_id, frame, points) {
            tracing::debug!("{}", probe.line(stage));
        }
    }

    /// After PnP and track continuation: probes the PnP inliers; returns
    /// the points the new keyframe observes then (when probing).
    pub(super) fn probe_registered(&self, image_id: ImageId, frame: usize) -> Option<HashSet<Point3DId>> {
        if !Self::probing() {
            return None;
        }
        let points = self.observed_points(image_id);
        let mut inliers: Vec<Point3DId> = points.iter().copied().collect();
        inliers.sort();
        self.log_probe("pnp", image_id, frame, &inliers);
        Some(points)
    }

    /// After triangulation: probes the points the new keyframe gained
    /// (`before`: what it observed after PnP); returns them.
    pub(super) fn probe_triangulated(
        &self,
        image_id: ImageId,
        frame: usize,
        before: &HashSet<Point3DId>,
    ) -> Vec<Point3DId> {
        let mut new: Vec<Point3DId> = self.observed_points(image_id).difference(before).copied().collect();
        new.sort();
        self.log_probe("tri", image_id, frame, &new);
        new
    }

    /// After the local refinement: probes the new points that survived it.
    pub(super) fn probe_refined(&self, image_id: ImageId, frame: usize, new: Vec<Point3DId>) {
        let alive: Vec<Point3DId> = new.into_iter().filter(|p| self.rec.point3d(*p).is_some()).collect();
        self.log_probe("lba", image_id, frame, &alive);
    }

    /// Frame index and centre of the registered keyframes, the last `max`
    /// in order.
    fn keyframe_centres(&self, max: usize) -> Vec<(usize, Vec3)> {
        let skip = self.keyframes.len().saturating_sub(max);
        self.keyframes
            .iter()
            .skip(skip)
            .filter_map(|k| {
                let img = self.rec.image(k.image_id).filter(|i| i.registered)?;
                Some((k.data.index(), img.cam_from_world.center()))
            })
            .collect()
    }

    /// Before and after a global refinement: every keyframe's centre.
    pub(super) fn log_global_probe(&self, when: &str) {
        if Self::probing() {
            tracing::debug!("scale snapshot {when}-global: {}", centres_text(&self.keyframe_centres(usize::MAX)));
        }
    }

    /// Before and after the local BA of frame `frame`'s keyframe: the newest
    /// keyframes' centres, and (after) the frames of the bundle.
    pub(super) fn log_local_ba_probe(&self, when: &str, frame: usize, bundle: &[ImageId]) {
        if !Self::probing() {
            return;
        }
        tracing::debug!(
            "scale snapshot {when}-lba-{frame}: {}",
            centres_text(&self.keyframe_centres(LOCAL_BA_SNAPSHOT))
        );
        if when == "after" {
            let frames: Vec<String> = bundle
                .iter()
                .map(|id| self.keyframe_position(*id).map_or(frame, |k| self.keyframes[k].data.index()).to_string())
                .collect();
            tracing::debug!("scale bundle {frame}: {}", frames.join(" "));
        }
    }
}

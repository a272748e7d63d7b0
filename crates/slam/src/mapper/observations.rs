//! Refinement of the keyframes' observations by patch alignment, after
//! mapping (issue 14, item 3; `--refine-observations`).
//!
//! Each keypoint was detected independently in its image, so the
//! observations of one track disagree by the detector's noise (integer
//! positions at their pyramid level: about 0.8 px median on the synthetic
//! sequence, docs/benchmarks.md). Here every track takes one reference
//! observation (the middle one in frame order), and each other observation
//! is moved to where the reference's neighbourhood appears in its image:
//! the template is the reference patch, warped by the homography of the
//! plane through the point facing the reference camera (an affine map at
//! the point), aligned by Gauss-Newton on the smoothed intensities
//! ([`crate::patch`]). Then the map is bundle adjusted again.
//!
//! What an observation is aligned to: the warp is anchored at the point's
//! projection, not at the reference keypoint, so every other observation
//! moves to the surface point at the point's projection in the reference
//! image (the map's consensus from all observations), while the reference
//! keeps its own keypoint. Anchoring at the reference keypoint, or moving
//! the reference to the projection too, both came out less accurate on the
//! synthetic sequence and Strecha (docs/history.md).
//!
//! The images are read again from the source ([`FrameImages`]), one at a
//! time, in two passes (the templates, then the alignments), so a long
//! video is never held in memory; a frame that cannot be read again is
//! skipped with a warning and its observations keep their keypoints.

use super::localize::{FrameInliers, Localization};
use super::state::{Mapper, level_scale};
use crate::error::SlamError;
use crate::frame::{FrameData, undistort};
use crate::options::{OVERLAP_MAX_VIEW_ANGLE_DEG, SlamOptions};
use crate::patch::{Alignment, GradientImage, PATCH_HALF, SmoothImage, Template};
use crate::timing::{Stage, StageTimings};
use colslam_camera::Camera;
use colslam_estimators::refine_absolute_pose;
use colslam_geometry::nalgebra::Matrix2;
use colslam_geometry::{Rigid3, Vec2, Vec3};
use colslam_image::Image;
use colslam_scene::{ImageId, Point3DId, TrackElement};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet, HashMap};

/// Reads frames of the input again after mapping, for the refinements that
/// look at the pixels.
pub trait FrameImages {
    /// Calls `visit` once for each frame of `frames` (indices after skip,
    /// ascending) with its image, or the reason it could not be read. An
    /// error means no frame could be read at all (the source cannot be
    /// opened again).
    fn read(&mut self, frames: &[usize], visit: &mut dyn FnMut(usize, Result<Image, String>)) -> Result<(), SlamError>;
}

/// Farthest an observation may move, pixels: the keypoint's own error is
/// under a pixel at the levels that carry most tracks; a larger move is
/// another structure, or an alignment that slid along an edge.
pub const MAX_SHIFT_PX: f64 = 2.0;
/// Least normalised cross-correlation of an aligned patch with its
/// template: below it the appearance changed too much (occlusion, a
/// specular surface, a plane far from the fronto-parallel guess) for the
/// position to be trusted. 0.7, 0.8 and 0.9 gave the same Strecha and
/// synthetic-room figures; the synthetic drive was best at 0.7
/// (docs/benchmarks.md).
pub const MIN_ZNCC: f64 = 0.7;

/// Bytes of gray images the first pass keeps for the second: a sequence of
/// up to about 400 keyframes at 640x480 is read once, a longer one reads
/// the rest again.
const KEPT_IMAGE_BYTES: usize = 128 << 20;

/// What [`Mapper::refine_observations`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObservationRefinement {
    /// Tracks whose reference patch could serve as a template.
    pub tracks: usize,
    /// Observations aligned against their track's template.
    pub tried: usize,
    /// Observations moved.
    pub moved: usize,
    /// Median distance moved, pixels.
    pub median_shift_px: f64,
    /// Frames that could not be read again.
    pub unread: usize,
    /// The first of them, its name and why.
    pub first_unread: Option<String>,
}

/// One observation to align: its image, keypoint index, position and its
/// track's reference.
struct Target {
    point: Point3DId,
    point2d: u32,
    xy: Vec2,
}

/// The reference patches of a map's tracks, cut once for the keyframes'
/// alignment and kept for the non-keyframes' ([`Mapper::refine_frame_observations`]).
/// About 1 KB per track: the pipeline drops them once the map's frames are
/// localised.
#[derive(Default)]
pub struct TrackTemplates {
    /// Each track's template and the reference keypoint it was cut at.
    templates: HashMap<Point3DId, (Template, Vec2)>,
    /// Each track's reference keyframe.
    reference_of: HashMap<Point3DId, ImageId>,
}

/// Frames that could not be read again: each named once in a warning, the
/// first kept for the run's report.
struct Unread {
    map: usize,
    names: HashMap<usize, String>,
    frames: BTreeSet<usize>,
    first: Option<String>,
}

impl Unread {
    fn note(&mut self, index: usize, why: &str) {
        self.frames.insert(index);
        let frame = format!("frame {index} ({})", self.names.get(&index).map_or("?", String::as_str));
        tracing::warn!(
            "map {}: {frame} could not be read again for the observation refinement: {why}; its observations keep their keypoints",
            self.map
        );
        self.first.get_or_insert_with(|| format!("{frame}: {why}"));
    }
}

/// The median of the moves and the log line, shared by both passes.
fn summary(
    map: usize,
    what: &str,
    tracks: usize,
    tried: usize,
    mut shifts: Vec<f64>,
    unread: Unread,
) -> ObservationRefinement {
    let moved = shifts.len();
    let median_shift_px = colslam_geometry::stats::median_in_place(&mut shifts).unwrap_or(0.0);
    let report = ObservationRefinement {
        tracks,
        tried,
        moved,
        median_shift_px,
        unread: unread.frames.len(),
        first_unread: unread.first,
    };
    tracing::info!(
        "map {map}: {what} observations refined: {} of {} moved (median {:.2} px) over {} tracks{}",
        report.moved,
        report.tried,
        report.median_shift_px,
        report.tracks,
        if report.unread > 0 { format!(", {} frames unread", report.unread) } else { String::new() }
    );
    report
}

impl Mapper {
    /// Refines the keyframes' observations by patch alignment (the module
    /// documentation), then bundle adjusts the map again (converged, or to
    /// the periodic tolerance when a rolling-shutter compensation follows).
    /// Returns the tracks' templates for [`Self::refine_frame_observations`].
    pub fn refine_observations(
        &mut self,
        images: &mut dyn FrameImages,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(ObservationRefinement, TrackTemplates), SlamError> {
        let (report, templates) =
            timings.time(Stage::ObservationRefinement, || self.align_observations(images, opts))?;
        if report.moved == 0 {
            return Ok((report, templates));
        }
        self.global_refine(opts.final_ba_tolerance(), opts, timings)?;
        self.rec.update_point_errors()?;
        Ok((report, templates))
    }

    /// Aligns observations `(tag, point, pixel)` in one image taken from
    /// `pose` to their tracks' templates, each search bounded by
    /// `max_shift` pixels: the aligned pixel and the alignment for each that
    /// was found and passed the checks.
    fn align_in_image<T: Copy + Send + Sync>(
        &self,
        camera: &Camera,
        tracks: &TrackTemplates,
        image: &SmoothImage,
        pose: &Rigid3,
        list: &[(T, Point3DId, Vec2)],
        max_shift: f64,
    ) -> Vec<Option<(T, Vec2, Alignment)>> {
        let rec = &self.rec;
        list.par_iter()
            .map(|(tag, pid, xy)| {
                let (template, ref_xy) = tracks.templates.get(pid)?;
                let ref_pose = rec.image(*tracks.reference_of.get(pid)?)?.cam_from_world;
                let (anchor, warp) = plane_warp(camera, &ref_pose, ref_xy, pose, &rec.point3d(*pid)?.xyz)?;
                let a = image.align(template, &(xy + anchor), &warp, max_shift)?;
                (a.zncc >= MIN_ZNCC).then(|| (*tag, xy + a.shift, a))
            })
            .collect()
    }

    /// The alignment itself: moves observations, no bundle adjustment.
    fn align_observations(
        &mut self,
        images: &mut dyn FrameImages,
        opts: &SlamOptions,
    ) -> Result<(ObservationRefinement, TrackTemplates), SlamError> {
        let camera = self.camera()?.clone();
        // Registered keyframes: image id -> (slot, frame index).
        let slot: HashMap<ImageId, (usize, usize)> = self
            .keyframes
            .iter()
            .enumerate()
            .filter(|(_, k)| self.rec.image(k.image_id).is_some_and(|i| i.registered))
            .map(|(s, k)| (k.image_id, (s, k.data.index())))
            .collect();
        let frame_of = |id: &ImageId| slot.get(id).map(|s| s.1);
        // Each track's reference: the middle observation in frame order.
        let mut references: BTreeMap<usize, Vec<(Point3DId, Vec2)>> = BTreeMap::new();
        let mut tracks = TrackTemplates::default();
        for (pid, p) in self.rec.points3d() {
            let mut els: Vec<_> = p.track.iter().filter_map(|e| frame_of(&e.image_id).map(|f| (f, e))).collect();
            if els.len() < 2 {
                continue;
            }
            els.sort_by_key(|(f, e)| (*f, e.point2d_idx));
            let (frame, el) = els[els.len() / 2];
            let Some(xy) = self.rec.image(el.image_id).and_then(|i| i.points2d.get(el.point2d_idx as usize)) else {
                continue;
            };
            references.entry(frame).or_default().push((pid, xy.xy));
            tracks.reference_of.insert(pid, el.image_id);
        }
        // Every other observation of a track with a reference, by frame.
        let mut targets: BTreeMap<usize, (ImageId, Vec<Target>)> = BTreeMap::new();
        for (pid, p) in self.rec.points3d() {
            let Some(reference) = tracks.reference_of.get(&pid) else { continue };
            for el in p.track.iter().filter(|el| el.image_id != *reference) {
                let Some(frame) = frame_of(&el.image_id) else { continue };
                let Some(xy) = self.rec.image(el.image_id).and_then(|i| i.points2d.get(el.point2d_idx as usize)) else {
                    continue;
                };
                let entry = targets.entry(frame).or_insert_with(|| (el.image_id, Vec::new()));
                entry.1.push(Target { point: pid, point2d: el.point2d_idx, xy: xy.xy });
            }
        }
        let names = self.keyframes.iter().map(|k| (k.data.index(), k.data.id.name.clone())).collect();
        let mut unread = Unread { map: self.index, names, frames: BTreeSet::new(), first: None };
        // Pass 1: the templates, at the reference keypoints. The gray
        // images the second pass needs stay in memory within a budget, so a
        // short sequence is read once.
        let mut kept: BTreeMap<usize, Image> = BTreeMap::new();
        let mut kept_bytes = 0usize;
        let frames: Vec<usize> = references.keys().copied().collect();
        images.read(&frames, &mut |index, image| match image {
            Err(why) => unread.note(index, &why),
            Ok(image) => {
                let gray = image.to_gray();
                let g = GradientImage::new(&gray);
                for (pid, xy) in references.get(&index).into_iter().flatten() {
                    if let Some(t) = g.template(xy) {
                        tracks.templates.insert(*pid, (t, *xy));
                    }
                }
                if targets.contains_key(&index) && kept_bytes + gray.data().len() <= KEPT_IMAGE_BYTES {
                    kept_bytes += gray.data().len();
                    kept.insert(index, gray);
                }
            }
        })?;
        // Pass 2: the alignments; with `--search-local-map`, also the tracks
        // of each keyframe's local map that it does not observe.
        let mut moves: Vec<(ImageId, u32, Vec2, f64)> = Vec::new();
        let mut found_new: Vec<(ImageId, Point3DId, Vec2, f64)> = Vec::new();
        let mut tried = 0usize;
        let local = LocalTemplates::new(self, &tracks);
        let mut align_in = |index: usize, image: &Image| {
            let Some((image_id, list)) = targets.get(&index) else { return };
            let Some(img) = self.rec.image(*image_id) else { return };
            let pose = img.cam_from_world;
            let list: Vec<KeyframeTarget> = list
                .iter()
                .filter(|t| tracks.templates.contains_key(&t.point))
                .map(|t| (t.point2d, t.point, t.xy))
                .collect();
            let smooth = SmoothImage::new(image);
            let mut found = self.align_in_image(&camera, &tracks, &smooth, &pose, &list, MAX_SHIFT_PX);
            if let Some(&(s, _)) = slot.get(image_id).filter(|_| opts.refine.realign_coarse) {
                for (octave, (places, items)) in coarse_failures(&list, &found, &self.keyframes[s].data) {
                    let radius = MAX_SHIFT_PX * level_scale(octave);
                    let again = self.align_in_image(&camera, &tracks, &smooth, &pose, &items, radius);
                    for (i, a) in places.into_iter().zip(again) {
                        found[i] = a.filter(|(_, _, a)| a.sigma_px <= MAX_FOUND_SIGMA_PX);
                    }
                }
            }
            if opts.refine.search_local_map.keyframes() {
                let observed: Vec<Point3DId> = img.points2d.iter().filter_map(|p| p.point3d_id).collect();
                let new = local.search(&camera, &smooth, &pose, &observed, &found);
                tried += new.len();
                found_new.extend(new.into_iter().flatten().map(|(pid, xy, a)| (*image_id, pid, xy, a.shift.norm())));
            }
            tried += found.len();
            moves.extend(found.into_iter().flatten().map(|(k, xy, a)| (*image_id, k, xy, a.shift.norm())));
        };
        let kept_frames: BTreeSet<usize> = kept.keys().copied().collect();
        for (index, image) in std::mem::take(&mut kept) {
            align_in(index, &image);
        }
        let frames: Vec<usize> =
            targets.keys().filter(|f| !kept_frames.contains(f) && !unread.frames.contains(f)).copied().collect();
        images.read(&frames, &mut |index, image| match image {
            Err(why) => unread.note(index, &why),
            Ok(image) => align_in(index, &image),
        })?;
        let mut shifts = Vec::with_capacity(moves.len());
        for (image_id, k, xy, d) in moves {
            let Some(n) = undistort(&camera, &xy) else { continue };
            let Some(&(s, _)) = slot.get(&image_id) else { continue };
            let kf = &mut self.keyframes[s];
            if let (Some(px), Some(nm)) = (kf.data.pixels.get_mut(k as usize), kf.data.normalized.get_mut(k as usize)) {
                *px = xy;
                *nm = n;
                self.rec.set_point2d_xy(image_id, k, xy)?;
                shifts.push(d);
            }
        }
        let mut added = 0usize;
        for (image_id, pid, xy, d) in found_new {
            // The search skipped the keyframe's own tracks; a track is
            // observed once per image.
            if self.rec.point3d(pid).is_none_or(|p| p.track.iter().any(|e| e.image_id == image_id)) {
                continue;
            }
            let idx = self.rec.push_point2d(image_id, xy)?;
            self.rec.add_observation(pid, TrackElement::new(image_id, idx))?;
            shifts.push(d);
            added += 1;
        }
        if opts.refine.search_local_map.keyframes() {
            tracing::debug!("map {}: local maps searched in the keyframes: {added} observations added", self.index);
        }
        let report = summary(self.index, "keyframe", tracks.templates.len(), tried, shifts, unread);
        Ok((report, tracks))
    }

    /// Aligns the localised non-keyframes' PnP inliers to their tracks'
    /// templates; with `--search-local-map`, where at least
    /// [`MIN_ALIGNED_SHARE`] of them aligned, also the templates of the
    /// frame's local map ([`LocalTemplates`]) where their points project,
    /// which join the frame's inliers. Each such frame's pose is refined on
    /// the aligned observations (with `--refine-all-frames`, these
    /// observations enter the final bundle adjustment). The frames are read
    /// again one at a time.
    pub fn refine_frame_observations(
        &self,
        loc: &mut Localization,
        tracks: &TrackTemplates,
        images: &mut dyn FrameImages,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<ObservationRefinement, SlamError> {
        timings.time(Stage::ObservationRefinement, || {
            let camera = self.camera()?;
            // The pose refinement PnP ended with.
            let refine = opts.mapper.absolute_pose(self.focal()?, opts.seed).refine_options;
            let slot: HashMap<usize, usize> =
                loc.poses.iter().enumerate().filter(|(_, p)| !p.keyframe).map(|(s, p)| (p.frame.index, s)).collect();
            // The frames with an observation of a track with a template.
            let frames: BTreeSet<usize> = loc
                .inliers
                .iter()
                .filter(|(f, inl)| {
                    slot.contains_key(f) && inl.iter().any(|(_, pid)| tracks.templates.contains_key(pid))
                })
                .map(|(f, _)| *f)
                .collect();
            let frames: Vec<usize> = frames.into_iter().collect();
            let names = loc.poses.iter().map(|p| (p.frame.index, p.frame.name.clone())).collect();
            let mut unread = Unread { map: self.index, names, frames: BTreeSet::new(), first: None };
            let mut shifts = Vec::new();
            let mut tried = 0usize;
            let mut refined: Vec<(usize, Rigid3, FrameInliers)> = Vec::new();
            let local = LocalTemplates::new(self, tracks);
            let (mut searched, mut added) = (0usize, 0usize);
            images.read(&frames, &mut |index, image| {
                let image = match image {
                    Err(why) => return unread.note(index, &why),
                    Ok(image) => image,
                };
                let (Some(&s), Some(inliers)) = (slot.get(&index), loc.inliers.get(&index)) else { return };
                let pose = loc.poses[s].cam_from_world;
                let list: Vec<(usize, Point3DId, Vec2)> = inliers
                    .iter()
                    .enumerate()
                    .filter(|(_, (_, pid))| tracks.templates.contains_key(pid))
                    .map(|(k, (n, pid))| (k, *pid, camera.img_from_normalized(n)))
                    .collect();
                let smooth = SmoothImage::new(&image.to_gray());
                let found = self.align_in_image(camera, tracks, &smooth, &pose, &list, MAX_SHIFT_PX);
                let new = if opts.refine.search_local_map.frames() {
                    let observed: Vec<Point3DId> = inliers.iter().map(|(_, pid)| *pid).collect();
                    local.search(camera, &smooth, &pose, &observed, &found)
                } else {
                    Vec::new()
                };
                searched += new.len();
                tried += found.len() + new.len();
                let mut aligned = inliers.clone();
                let before = shifts.len();
                for (k, xy, a) in found.into_iter().flatten() {
                    if let Some(n) = undistort(camera, &xy) {
                        aligned[k].0 = n;
                        shifts.push(a.shift.norm());
                    }
                }
                for (pid, xy, a) in new.into_iter().flatten() {
                    if let Some(n) = undistort(camera, &xy) {
                        aligned.push((n, pid));
                        added += 1;
                        shifts.push(a.shift.norm());
                    }
                }
                if shifts.len() == before {
                    return;
                }
                let p3: Vec<Vec3> =
                    aligned.iter().filter_map(|(_, pid)| self.rec.point3d(*pid).map(|p| p.xyz)).collect();
                if p3.len() != aligned.len() {
                    return;
                }
                let p2: Vec<Vec2> = aligned.iter().map(|(n, _)| *n).collect();
                if let Ok((pose, _)) = refine_absolute_pose(&pose, &p2, &p3, &refine) {
                    // The tracks found by projection stay only where the
                    // all-frame BA will see them: kept for every frame of a
                    // long video, they would triple its inliers' memory.
                    if !opts.refine.refine_all_frames {
                        aligned.truncate(inliers.len());
                    }
                    refined.push((index, pose, aligned));
                }
            })?;
            for (index, pose, aligned) in refined {
                if let Some(&s) = slot.get(&index) {
                    loc.poses[s].cam_from_world = pose;
                }
                loc.inliers.insert(index, aligned);
            }
            if opts.refine.search_local_map.frames() {
                tracing::debug!(
                    "map {}: local maps searched in {} non-keyframes: {added} of {searched} projected tracks found",
                    self.index,
                    frames.len()
                );
            }
            Ok(summary(self.index, "non-keyframe", tracks.templates.len(), tried, shifts, unread))
        })
    }
}

/// The tracks with a template that a frame may see: those of the keyframes
/// that share its observations (ORB-SLAM's local map), each with its point
/// and its reference camera's centre.
struct LocalTemplates<'m> {
    /// The map searched, and its tracks' templates.
    map: &'m Mapper,
    tracks: &'m TrackTemplates,
    /// Each track's point and reference camera centre.
    points: HashMap<Point3DId, (Vec3, Vec3)>,
    /// Each keyframe's tracks with a template, ascending.
    of_keyframe: HashMap<ImageId, Vec<Point3DId>>,
}

impl<'m> LocalTemplates<'m> {
    fn new(map: &'m Mapper, tracks: &'m TrackTemplates) -> Self {
        let rec = &map.rec;
        let points: HashMap<Point3DId, (Vec3, Vec3)> = tracks
            .reference_of
            .iter()
            .filter(|(pid, _)| tracks.templates.contains_key(pid))
            .filter_map(|(pid, r)| Some((*pid, (rec.point3d(*pid)?.xyz, rec.image(*r)?.cam_from_world.center()))))
            .collect();
        let mut of_keyframe: HashMap<ImageId, Vec<Point3DId>> = HashMap::new();
        for kf in &map.keyframes {
            let Some(img) = rec.image(kf.image_id) else { continue };
            let mut ids: Vec<Point3DId> =
                img.points2d.iter().filter_map(|p| p.point3d_id).filter(|id| points.contains_key(id)).collect();
            ids.sort_unstable();
            ids.dedup();
            of_keyframe.insert(kf.image_id, ids);
        }
        Self { map, tracks, points, of_keyframe }
    }

    /// `--search-local-map` in one image taken from `pose` whose own
    /// observations of `observed` aligned as `own`: where at least
    /// [`MIN_ALIGNED_SHARE`] of them did, the tracks [`Self::visible`] gives
    /// aligned from their projection, each found within
    /// [`MAX_FOUND_SIGMA_PX`] with its pixel and alignment; none elsewhere.
    fn search<T>(
        &self,
        camera: &Camera,
        image: &SmoothImage,
        pose: &Rigid3,
        observed: &[Point3DId],
        own: &[Option<T>],
    ) -> Vec<Option<(Point3DId, Vec2, Alignment)>> {
        let aligned_share = own.iter().flatten().count() as f64 / own.len().max(1) as f64;
        if aligned_share < MIN_ALIGNED_SHARE {
            return Vec::new();
        }
        let list: Vec<(Point3DId, Point3DId, Vec2)> =
            self.visible(camera, pose, observed).into_iter().map(|(pid, xy)| (pid, pid, xy)).collect();
        let mut found = self.map.align_in_image(camera, self.tracks, image, pose, &list, MAX_SHIFT_PX);
        for f in &mut found {
            if f.as_ref().is_some_and(|(_, _, a)| a.sigma_px > MAX_FOUND_SIGMA_PX) {
                *f = None;
            }
        }
        found
    }

    /// The tracks not among `observed` of the [`LOCAL_KEYFRAMES`] keyframes
    /// that observe the most of `observed` (ties: lower id) whose point
    /// projects inside an image taken from `pose`, far enough from the
    /// border for a patch to be aligned, in front of it at a distance within
    /// [`MAX_SCALE_CHANGE`] of the reference camera's and within
    /// [`OVERLAP_MAX_VIEW_ANGLE_DEG`] of the reference view: each with its
    /// projection, by point id.
    fn visible(&self, camera: &Camera, pose: &Rigid3, observed: &[Point3DId]) -> Vec<(Point3DId, Vec2)> {
        let mut votes: BTreeMap<ImageId, usize> = BTreeMap::new();
        for pid in observed {
            for e in self.map.rec.point3d(*pid).map(|p| p.track.as_slice()).unwrap_or_default() {
                if self.of_keyframe.contains_key(&e.image_id) {
                    *votes.entry(e.image_id).or_default() += 1;
                }
            }
        }
        let mut keyframes: Vec<(usize, ImageId)> = votes.into_iter().map(|(id, n)| (n, id)).collect();
        keyframes.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        keyframes.truncate(LOCAL_KEYFRAMES);
        let have: std::collections::HashSet<Point3DId> = observed.iter().copied().collect();
        let mut ids: Vec<Point3DId> = keyframes
            .iter()
            .filter_map(|(_, id)| self.of_keyframe.get(id))
            .flatten()
            .copied()
            .filter(|id| !have.contains(id))
            .collect();
        ids.sort_unstable();
        ids.dedup();
        let centre = pose.center();
        let cos_max = OVERLAP_MAX_VIEW_ANGLE_DEG.to_radians().cos();
        let margin = f64::from(PATCH_HALF) + MAX_SHIFT_PX + 1.0;
        let (w, h) = (camera.width as f64, camera.height as f64);
        ids.into_iter()
            .filter_map(|pid| {
                let (x, ref_centre) = self.points.get(&pid)?;
                let (r1, r2) = (x - ref_centre, x - centre);
                let (d1, d2) = (r1.norm(), r2.norm());
                if r1.dot(&r2) < cos_max * d1 * d2 || d2 > d1 * MAX_SCALE_CHANGE || d1 > d2 * MAX_SCALE_CHANGE {
                    return None;
                }
                let xy = camera.img_from_cam(&pose.transform_point(x))?;
                (xy.x >= margin && xy.y >= margin && xy.x <= w - margin && xy.y <= h - margin).then_some((pid, xy))
            })
            .collect()
    }
}

/// A keyframe observation to align: its index among the keyframe's
/// observations, its track and its pixel.
type KeyframeTarget = (u32, Point3DId, Vec2);

/// The observations of `list` whose alignment failed (`None` in `found`)
/// and whose keypoint (in `data`) was detected above the pyramid's finest
/// level, by octave, each with its place in `list`: `--realign-coarse`
/// searches them again within [`MAX_SHIFT_PX`] times the octave's scale
/// ([`level_scale`]) and keeps those whose alignment
/// predicts at most [`MAX_FOUND_SIGMA_PX`]. A keypoint detected at a
/// coarse level sits on that level's pixel grid, so the surface point its
/// track's template shows can lie beyond the search; a wider search can
/// also slide onto another structure, which the precision gate keeps out
/// (as for the tracks found by projection).
fn coarse_failures<A>(
    list: &[KeyframeTarget],
    found: &[Option<A>],
    data: &FrameData,
) -> BTreeMap<u8, (Vec<usize>, Vec<KeyframeTarget>)> {
    let mut by_octave: BTreeMap<u8, (Vec<usize>, Vec<KeyframeTarget>)> = BTreeMap::new();
    for (i, (item, f)) in list.iter().zip(found).enumerate() {
        let Some(kp) = data.features.keypoints.get(item.0 as usize) else { continue };
        if f.is_none() && kp.octave > 0 {
            let entry = by_octave.entry(kp.octave).or_default();
            entry.0.push(i);
            entry.1.push(*item);
        }
    }
    by_octave
}

/// Share of a frame's own observations (a non-keyframe's PnP inliers) that
/// must align for its local map to be searched: where most of them fail
/// (motion blur, an uncompensated rolling shutter: TUM fr1's frames align a
/// third of theirs, the synthetic room's four in five), the templates found
/// by projection would mostly fail too, at the cost of their search.
const MIN_ALIGNED_SHARE: f64 = 0.5;

/// Largest standard deviation an alignment may predict for a track found
/// by projection ([`Alignment::sigma_px`]), pixels. Such an observation has
/// no detection behind it: it is where the patch settled from the map's
/// own projection. With every one of them kept, KITTI odometry's drive was
/// 22-40 % less accurate over three seeds; kept where the alignment
/// predicts a quarter pixel or better (about half of them there, most on
/// the synthetic room), the drive is level and the rooms and the Strecha
/// sets keep their gain. What the gate tells apart is the prediction, not
/// the number: a third of the found tracks kept at random left most of
/// KITTI's loss where a third kept by a tighter gate did not, and so did
/// keeping only those whose patch is not an edge
/// (docs/benchmarks.md, "Found tracks gated by their alignment's
/// precision"). The observations a frame detected itself are not gated:
/// their position is the detector's, whatever the alignment does.
pub const MAX_FOUND_SIGMA_PX: f64 = 0.25;

/// Keyframes whose tracks a frame is searched for: those sharing the most
/// of its observations (ORB-SLAM's local map is its covisible keyframes and
/// theirs; 10 of them hold the points a frame between two keyframes sees).
const LOCAL_KEYFRAMES: usize = 10;

/// Largest ratio of a point's distances from a frame and from its track's
/// reference camera for its template to be searched there: beyond
/// it the 9x9 template covers a patch of another size than the image.
const MAX_SCALE_CHANGE: f64 = 1.5;

/// Where the reference patch around `ref_xy` lands in a target view, as an
/// affine map at the point: the patch is taken to lie on the plane through
/// `x` facing the reference camera (the fronto-parallel guess of patch-based
/// multi-view stereo). Returns the offset of the reference keypoint's image
/// from the point's projection in the target (the start of the search is
/// the target observation plus this offset) and the 2x2 Jacobian of the
/// map; `None` where a ray misses the plane or a point leaves the camera.
fn plane_warp(
    camera: &Camera,
    ref_pose: &Rigid3,
    ref_xy: &Vec2,
    target_pose: &Rigid3,
    x: &Vec3,
) -> Option<(Vec2, Matrix2<f64>)> {
    let centre = ref_pose.center();
    let normal = (centre - x).try_normalize(1e-12)?;
    let world_from_ref = ref_pose.inverse();
    let on_plane = |px: &Vec2| -> Option<Vec2> {
        let n = camera.cam_from_img(px)?;
        let dir = world_from_ref.rotation * Vec3::new(n.x, n.y, 1.0);
        let denom = dir.dot(&normal);
        let lambda = (x - centre).dot(&normal) / denom;
        if !(lambda.is_finite() && lambda > 0.0) {
            return None;
        }
        camera.img_from_cam(&target_pose.transform_point(&(centre + lambda * dir)))
    };
    let projected = camera.img_from_cam(&target_pose.transform_point(x))?;
    let h = f64::from(PATCH_HALF);
    let c = on_plane(ref_xy)?;
    let dx = (on_plane(&(ref_xy + Vec2::new(h, 0.0)))? - c) / h;
    let dy = (on_plane(&(ref_xy + Vec2::new(0.0, h)))? - c) / h;
    Some((c - projected, Matrix2::new(dx.x, dy.x, dx.y, dy.y)))
}

//! Rolling-shutter compensation (beyond the paper).
//!
//! A rolling-shutter camera exposes its rows one after the other: with a
//! readout time `tau` (first row to last), row `v` of an `h`-row image is
//! taken `(v / h - 0.5) * tau` after the middle row. While the camera turns at
//! angular velocity `w` (camera frame), a keypoint seen on row `v` is a ray of
//! the camera as it was at that moment, not at the frame's timestamp; on TUM
//! fr1/rpy (a Kinect v1 turning at up to ~30 deg/s) that is several pixels
//! and was the largest error left: with the ground truth's angular velocity
//! the ATE fell from 2.2 to 0.9 cm (docs/history.md).
//!
//! The pipeline corrects offline, after mapping, when every frame has a pose:
//! each frame's angular velocity comes from its neighbours' poses (central
//! difference), each observation's bearing is rotated back to the middle
//! row's time (rotation only: at the speeds of hand-held video the rotation
//! dominates the motion during one readout), and the map is bundle adjusted
//! again and every frame localised again with the corrected observations.
//! The same first-order rotational model underlies rolling-shutter bundle
//! adjustment in the literature (e.g. Hedborg et al., "Rolling shutter bundle
//! adjustment", CVPR 2012); ours keeps the velocities fixed from the first
//! solution instead of estimating them in BA.
//!
//! `--rolling-shutter auto` estimates the readout the same way: with the
//! velocities of the first solution fixed, the bundle-adjustment cost of the
//! keyframes as a function of the readout is a one-dimensional problem
//! (observations move linearly with it, so the cost is close to a parabola
//! near its minimum), minimised over a grid and by successive parabolic
//! interpolation over a few bundle adjustments from the same start. A global
//! shutter gives its minimum at 0. The map scored was built, completed and
//! filtered under some readout, and keeps the observations that agree with
//! it, so the minimum leans towards that readout; `auto` therefore
//! alternates estimation and compensation until they agree (a fixed point,
//! found by the secant method), which is the self-consistency that
//! rolling-shutter bundle adjustment reaches by estimating the motion and the
//! structure together (Hedborg et al., CVPR 2012).

use super::localize::Localization;
use super::state::Mapper;
use crate::error::SlamError;
use crate::frame::{FramePose, FrameRecord};
use crate::options::{GlobalBaTolerance, RollingShutter, SlamOptions};
use crate::timing::{Stage, StageTimings};
use colslam_camera::Camera;
use colslam_geometry::{Quat, Rigid3, Sim3, Vec2, Vec3, umeyama};
use colslam_sfm::SfmError;
use colslam_sfm::bundle::adjust_global;
use std::collections::{HashMap, HashSet};

/// A frame's angular velocity is taken from its neighbours only when they
/// are at most this far apart in time (seconds).
pub const MAX_GAP_S: f64 = 1.0;

/// Upper end of the readout search of `--rolling-shutter auto`, seconds. A
/// readout cannot exceed the frame period; 1/24 s (the slowest common video
/// rate) with a margin bounds it.
pub const AUTO_MAX_READOUT_S: f64 = 0.05;

/// Readouts the first search of `auto` scores before refining (seconds):
/// a grid over the range rather than its ends and middle, because far from
/// the map's readout the scoring BA converges poorly and its cost is no
/// parabola (on TUM fr1 the ends and middle put the vertex at half the
/// grid's minimum, docs/history.md).
pub const AUTO_FIRST_GRID_S: [f64; 5] = [0.0, 0.01, 0.02, 0.03, 0.04];

/// Half-width of the later rounds' search around the readout the map was
/// compensated with (seconds): three samples, then the vertex.
pub const AUTO_LOCAL_STEP_S: f64 = 0.005;

/// Bundle adjustments the first search may run (the grid, then vertices).
pub const AUTO_EVALUATIONS: usize = 6;

/// Bundle adjustments each later round's search may run.
pub const AUTO_LOCAL_EVALUATIONS: usize = 4;

/// The search stops when its next readout is this close (seconds) to one
/// already scored: well under what the compensation can tell apart.
pub const AUTO_READOUT_TOLERANCE_S: f64 = 0.5e-3;

/// Rounds of `--rolling-shutter auto`: estimate, compensate, estimate again
/// on the compensated map. One round finds about half of TUM fr1's readout:
/// the map scored was built, completed and filtered at readout 0 and keeps
/// the observations that agree with 0, while the same search on a map
/// compensated at the frame period finds most of it (docs/history.md). Each
/// round moves the readout towards where the estimate agrees with the map
/// it was made on; the third moved it by under 0.5 ms on TUM and synthetic.
pub const AUTO_ROUNDS: usize = 3;

/// Least relative decrease of the scoring cost, from readout 0 to the best
/// readout, for `auto` to report a rolling shutter: a global-shutter camera
/// still gains a little from a small readout that absorbs noise (the
/// synthetic default 0.06 %, Strecha 0), a rolling shutter much more (TUM
/// fr1 about 5 %; docs/benchmarks.md).
pub const AUTO_MIN_GAIN: f64 = 0.01;

/// The readout `auto` reports from the search's samples `(readout, cost)`:
/// the one of least cost, or 0 when it lowers the cost at readout 0 by less
/// than [`AUTO_MIN_GAIN`] (or no sample is at 0).
pub fn chosen_readout(samples: &[(f64, f64)]) -> f64 {
    let Some(&(_, at_zero)) = samples.iter().find(|s| s.0 == 0.0) else { return 0.0 };
    let Some(&(best, cost)) = samples.iter().min_by(|a, b| a.1.total_cmp(&b.1)) else { return 0.0 };
    if at_zero > 0.0 && (at_zero - cost) / at_zero >= AUTO_MIN_GAIN { best } else { 0.0 }
}

/// The readout to compensate with next, from the rounds so far: each
/// `(compensated, estimated)` is the readout a map was compensated with and
/// the readout the search found on it. The readout wanted is a fixed point
/// of that map (estimate = compensation); from one round it is the
/// estimate, from two or more the secant through the last two rounds
/// (the estimate moves by less than the compensation, so plain iteration
/// would creep towards it), clamped to `[0, hi]`, and the last estimate when
/// the secant does not cross (no fixed point between or beyond them).
pub fn next_readout(rounds: &[(f64, f64)], hi: f64) -> f64 {
    let Some(&(c1, e1)) = rounds.last() else { return 0.0 };
    let Some(&(c0, e0)) = rounds.len().checked_sub(2).and_then(|i| rounds.get(i)) else { return e1.clamp(0.0, hi) };
    let (h0, h1) = (e0 - c0, e1 - c1);
    // h(c) = estimate - compensation, zero at the fixed point; it falls
    // with c when the estimate follows the compensation by less than 1:1.
    let slope = (h1 - h0) / (c1 - c0);
    if !(slope < 0.0 && slope.is_finite()) {
        return e1.clamp(0.0, hi);
    }
    (c1 - h1 / slope).clamp(0.0, hi)
}

/// Function tolerance of the bundle adjustments that score a readout: the
/// periodic tolerance stops the ones far from the start (large readouts)
/// too early and biases the search towards 0; full convergence costs twice
/// the iterations for the same estimate (docs/history.md).
pub const AUTO_BA_FUNCTION_TOLERANCE: f64 = 1e-5;

/// The bundle adjustment that scores a readout: the global one with a
/// soft-L1 loss of 1 px, so that the observations the map's filter kept at
/// readout 0 and that a readout moves away do not dominate the score
/// (with the squared loss the search found 0 on TUM fr1, docs/history.md).
fn auto_readout_ba(opts: &SlamOptions) -> colslam_sfm::bundle::BundleOptions {
    let mut ba = opts.mapper.global_ba(GlobalBaTolerance::Periodic);
    ba.ba.function_tolerance = AUTO_BA_FUNCTION_TOLERANCE;
    ba.ba.loss = colslam_optim::LossFunction::SoftL1(1.0);
    ba.intrinsics = opts.refined_intrinsics();
    ba
}

/// Minimises `cost` over `[0, hi]` by successive parabolic interpolation:
/// scores the `start` points, then the vertex of the parabola through the
/// best sample and its two nearest neighbours (clamped to the range; the
/// best sample when the three are not convex), until `evaluations` scores or
/// the next point is within `tol` of a scored one. Returns the best scored
/// point and every sample `(x, cost)` in the order scored.
pub fn parabolic_search<E>(
    start: &[f64],
    hi: f64,
    evaluations: usize,
    tol: f64,
    mut cost: impl FnMut(f64) -> Result<f64, E>,
) -> Result<(f64, Vec<(f64, f64)>), E> {
    let mut samples: Vec<(f64, f64)> = Vec::new();
    for &x in start.iter().take(evaluations.max(1)) {
        samples.push((x, cost(x)?));
    }
    while samples.len() < evaluations {
        let mut sorted = samples.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let best = (0..sorted.len()).min_by(|&a, &b| sorted[a].1.total_cmp(&sorted[b].1)).unwrap_or(0);
        // The best sample and its neighbours (the three at the end when it is one).
        let mid = best.clamp(1, sorted.len().saturating_sub(2).max(1));
        let Some(&[a, b, c]) =
            sorted.get(mid.saturating_sub(1)..mid + 2).and_then(|s| <&[(f64, f64); 3]>::try_from(s).ok())
        else {
            break;
        };
        let next = parabola_vertex(a, b, c).unwrap_or(sorted[best].0).clamp(0.0, hi);
        if samples.iter().any(|s| (s.0 - next).abs() < tol) {
            break;
        }
        samples.push((next, cost(next)?));
    }
    let best = samples.iter().min_by(|a, b| a.1.total_cmp(&b.1)).map_or(0.0, |s| s.0);
    Ok((best, samples))
}

/// The abscissa of the minimum of the parabola through three points, `None`
/// when they are not convex (or collinear).
fn parabola_vertex((x0, y0): (f64, f64), (x1, y1): (f64, f64), (x2, y2): (f64, f64)) -> Option<f64> {
    let d01 = (y1 - y0) / (x1 - x0);
    let d12 = (y2 - y1) / (x2 - x1);
    let curvature = (d12 - d01) / (x2 - x0);
    let v = 0.5 * (x0 + x1) - d01 / (2.0 * curvature);
    (curvature > 0.0 && v.is_finite()).then_some(v)
}

/// Camera-frame angular velocity (rad/s) of each posed frame, by frame
/// index: the rotation from the previous to the next posed frame over their
/// time difference (one-sided at the ends), in the convention of
/// `cam_from_world` rotations, `R(t + dt) = exp([w] dt) R(t)`. Frames whose
/// neighbours are more than `max_gap` seconds apart get none.
pub fn angular_velocities(poses: &[FramePose], max_gap: f64) -> HashMap<usize, Vec3> {
    let mut by_time: Vec<&FramePose> = poses.iter().collect();
    by_time.sort_by(|a, b| a.frame.timestamp.total_cmp(&b.frame.timestamp).then(a.frame.index.cmp(&b.frame.index)));
    let mut out = HashMap::new();
    for i in 0..by_time.len() {
        let prev = if i > 0 { by_time[i - 1] } else { by_time[i] };
        let next = by_time.get(i + 1).copied().unwrap_or(by_time[i]);
        let dt = next.frame.timestamp - prev.frame.timestamp;
        if !(dt > 0.0 && dt <= max_gap) {
            continue;
        }
        let rel: Quat = next.cam_from_world.rotation * prev.cam_from_world.rotation.inverse();
        let w = rel.scaled_axis() / dt;
        if w.iter().all(|v| v.is_finite()) {
            out.insert(by_time[i].frame.index, w);
        }
    }
    out
}

/// The pixel and normalised coordinates an observation at `px` would have
/// had at the frame's middle-row time, for a camera turning at `w` with
/// readout time `readout` (seconds). `None` when the pixel cannot be
/// undistorted or the corrected ray does not project.
pub fn compensate(camera: &Camera, px: &Vec2, w: &Vec3, readout: f64) -> Option<(Vec2, Vec2)> {
    let h = camera.height as f64;
    if h <= 0.0 {
        return None;
    }
    // COLMAP pixel convention: rows span 0..h, the middle row is at h/2.
    let dt = (px.y / h - 0.5) * readout;
    let n = camera.cam_from_img(px)?;
    // The ray seen at time t + dt, in the camera at t: x(t) = R(t) R(t + dt)^T
    // x(t + dt) = exp(-[w] dt) x(t + dt).
    let b = Quat::from_scaled_axis(-w * dt) * Vec3::new(n.x, n.y, 1.0);
    if b.z <= 0.0 {
        return None;
    }
    let n2 = Vec2::new(b.x / b.z, b.y / b.z);
    let px2 = camera.img_from_normalized(&n2);
    (px2.iter().chain(n2.iter()).all(|v| v.is_finite())).then_some((px2, n2))
}

/// A rolling-shutter compensation of the records: the camera, the frames'
/// angular velocities and the readout it was made with. Records spilled to
/// disk are compensated with it when they are read back
/// ([`crate::records::RecordStore::compensate`]).
#[derive(Debug, Clone)]
pub struct Compensation {
    /// The map's camera when the compensation ran.
    pub camera: Camera,
    /// Angular velocity of each frame that has one, by frame index.
    pub velocities: HashMap<usize, Vec3>,
    /// Readout time, seconds.
    pub readout: f64,
}

impl Compensation {
    /// Sets the record's compensated coordinates from its measured pixels.
    pub fn apply(&self, r: &mut FrameRecord) {
        let camera = &self.camera;
        let w = self.velocities.get(&r.frame.index);
        r.compensated = r
            .obs
            .iter()
            .map(|o| {
                // NaN: not undistortable, skipped by localisation.
                let Some(measured) = crate::frame::undistort(camera, &o.pixel()) else {
                    return Vec2::repeat(f64::NAN);
                };
                let px = camera.img_from_normalized(&measured);
                w.and_then(|w| compensate(camera, &px, w, self.readout)).map_or(measured, |(_, n)| n)
            })
            .collect();
    }
}

impl Mapper {
    /// Estimates the readout time (seconds) of a finished map from its first
    /// localisation (`--rolling-shutter auto`): for each readout tried, the
    /// keyframe observations are moved with the frames' angular velocities
    /// and the keyframes bundle adjusted from the same start; the readout of
    /// least cost wins ([`parabolic_search`] over `[0, AUTO_MAX_READOUT_S]`).
    /// The map is left as it was. 0 for a map too small to tell.
    pub fn estimate_readout(
        &mut self,
        first: &Localization,
        around: Option<f64>,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<f64, SfmError> {
        let w = angular_velocities(&first.poses, MAX_GAP_S);
        if self.rec.num_registered_images() < 3 || w.is_empty() {
            return Ok(0.0);
        }
        let start = self.rec.clone();
        let ba = auto_readout_ba(opts);
        let refine = opts.refine.refine_intrinsics;
        let (grid, evaluations) = match around {
            None => (AUTO_FIRST_GRID_S.to_vec(), AUTO_EVALUATIONS),
            Some(c) => {
                let mut g = vec![(c - AUTO_LOCAL_STEP_S).max(0.0), c, (c + AUTO_LOCAL_STEP_S).min(AUTO_MAX_READOUT_S)];
                g.dedup();
                (g, AUTO_LOCAL_EVALUATIONS)
            }
        };
        let searched = parabolic_search(&grid, AUTO_MAX_READOUT_S, evaluations, AUTO_READOUT_TOLERANCE_S, |readout| {
            self.rec = start.clone();
            self.move_keyframe_observations(&w, readout)?;
            let report = timings.time(Stage::GlobalBa, || adjust_global(&mut self.rec, refine, &ba))?;
            tracing::debug!("map {}: readout {:.2} ms: BA cost {:.6e}", self.index, 1e3 * readout, report.final_cost);
            Ok::<f64, SfmError>(report.final_cost)
        });
        self.rec = start;
        let (best, samples) = searched?;
        // The gain rule tells a global shutter on the first search only.
        let readout = if around.is_some() { best } else { chosen_readout(&samples) };
        if readout == 0.0 && best > 0.0 {
            tracing::info!(
                "map {}: rolling-shutter readout estimated at 0 (a global shutter: {:.1} ms explains too little)",
                self.index,
                1e3 * best
            );
        } else {
            tracing::info!(
                "map {}: rolling-shutter readout estimated at {:.1} ms ({} bundle adjustments)",
                self.index,
                1e3 * readout,
                samples.len()
            );
        }
        Ok(readout)
    }

    /// The rolling-shutter step of a finished map, as `--rolling-shutter`
    /// asks: nothing for a given 0, a compensation with a given readout, or
    /// [`Self::compensate_auto`]. Returns the localisation and the readout
    /// the map was compensated with.
    pub fn rolling_shutter(
        &mut self,
        first: Localization,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(Localization, f64), SlamError> {
        match opts.refine.rolling_shutter {
            RollingShutter::Seconds(s) if s > 0.0 => {
                // Each round's velocities come from the poses the last one
                // compensated (`--rolling-shutter-rounds`).
                let mut loc = first;
                for _ in 0..opts.refine.rolling_shutter_rounds {
                    loc = self.compensate_rolling_shutter(loc, s, opts, timings)?;
                }
                Ok((loc, s))
            }
            RollingShutter::Seconds(_) => Ok((first, 0.0)),
            RollingShutter::Auto => self.compensate_auto(first, opts, timings),
        }
    }

    /// `--rolling-shutter auto`: estimates the readout ([`Self::estimate_readout`])
    /// and compensates with it, then estimates again on the compensated map
    /// (its velocities from the compensated poses) and compensates with the
    /// readout [`next_readout`] gives, for at most [`AUTO_ROUNDS`] rounds or
    /// until the readout moves by less than [`AUTO_READOUT_TOLERANCE_S`].
    /// Returns the final localisation and the readout it was compensated
    /// with (0, and the map converged uncompensated, for a global shutter).
    pub fn compensate_auto(
        &mut self,
        first: Localization,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<(Localization, f64), SlamError> {
        let mut rounds: Vec<(f64, f64)> = Vec::new();
        let (mut loc, mut compensated) = (first, 0.0);
        for _ in 0..AUTO_ROUNDS {
            let around = (compensated > 0.0).then_some(compensated);
            let estimate = self.estimate_readout(&loc, around, opts, timings)?;
            rounds.push((compensated, estimate));
            let next = next_readout(&rounds, AUTO_MAX_READOUT_S);
            if compensated == 0.0 && next == 0.0 {
                return Ok((self.converge_uncompensated(opts, timings)?, 0.0));
            }
            // A later round that finds no readout keeps the last compensation
            // (compensating with 0 would not undo it).
            if next == 0.0 || (next - compensated).abs() < AUTO_READOUT_TOLERANCE_S {
                break;
            }
            tracing::info!("map {}: compensating with a readout of {:.1} ms", self.index, 1e3 * next);
            loc = self.compensate_rolling_shutter(loc, next, opts, timings)?;
            compensated = next;
        }
        Ok((loc, compensated))
    }

    /// One round of rolling-shutter compensation of a finished map, from
    /// its first localisation: every keyframe observation and every
    /// non-keyframe record is moved, from its measured position, to its
    /// frame's middle-row time with the frames' angular velocities; the map
    /// is refined globally (track completion, merging and filtering matter:
    /// corrected observations join tracks they did not fit before), then to
    /// [`crate::options::ROLLING_SHUTTER_FINAL_BA_TOLERANCE`], and every frame is localised again.
    /// Called again with the localisation it returned, it takes the
    /// velocities from the compensated poses (`--rolling-shutter-rounds`).
    /// Returns the new localisation, or `first` when nothing moved.
    pub fn compensate_rolling_shutter(
        &mut self,
        first: Localization,
        readout: f64,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Localization, SlamError> {
        let w = angular_velocities(&first.poses, MAX_GAP_S);
        let Some(moved) = self.move_observations(&w, readout)? else { return Ok(first) };
        self.global_refine(GlobalBaTolerance::Periodic, opts, timings)?;
        if moved == 0 {
            return Ok(first);
        }
        self.global_refine(GlobalBaTolerance::RollingShutter, opts, timings)?;
        self.rec.update_point_errors()?;
        let mut loc = self.localize_all(opts, timings)?;
        let carried = carry_lost_frames(&first, &mut loc);
        if carried > 0 {
            tracing::info!(
                "map {}: {carried} frames whose support the compensation removed keep their pose relative to their nearest keyframe",
                self.index
            );
        }
        Ok(loc)
    }

    /// Converges the map's bundle adjustment and localises every frame again:
    /// what is left to do when the final BA stopped at the periodic tolerance
    /// for a compensation and the estimated readout was 0.
    pub fn converge_uncompensated(
        &mut self,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<Localization, SlamError> {
        self.global_refine(GlobalBaTolerance::Converged, opts, timings)?;
        self.rec.update_point_errors()?;
        self.localize_all(opts, timings)
    }

    /// Moves every keyframe observation and record of a frame with a
    /// velocity to the middle-row time, from its measured position (so a
    /// second call does not compound corrections). Returns the number of
    /// keyframe observations moved; `None` without a readout or a map.
    fn move_observations(
        &mut self,
        velocities: &HashMap<usize, Vec3>,
        readout: f64,
    ) -> Result<Option<usize>, SfmError> {
        if readout == 0.0 || self.rec.num_registered_images() < 2 {
            return Ok(None);
        }
        let moved = self.move_keyframe_observations(velocities, readout)?;
        let camera = self.camera()?.clone();
        // Every record keeps its coordinates from here on, measured where it
        // has no velocity: the global refinements below may change the
        // camera, and the records must stay as compensated now.
        self.records.compensate(Compensation { camera, velocities: velocities.clone(), readout });
        tracing::debug!(
            "map {}: rolling shutter ({:.1} ms readout): {moved} keyframe observations moved, {} frames with a velocity",
            self.index,
            1e3 * readout,
            velocities.len()
        );
        Ok(Some(moved))
    }

    /// Moves the observations of every registered keyframe with a velocity
    /// to the middle-row time, from their measured pixels. Returns how many
    /// moved.
    fn move_keyframe_observations(
        &mut self,
        velocities: &HashMap<usize, Vec3>,
        readout: f64,
    ) -> Result<usize, SfmError> {
        let camera = self.camera()?.clone();
        let mut moved = 0;
        for kf in &self.keyframes {
            let Some(w) = velocities.get(&kf.data.index()) else { continue };
            if !self.rec.image(kf.image_id).is_some_and(|i| i.registered) {
                continue;
            }
            for (k, px) in kf.data.pixels.iter().enumerate() {
                if let Some((fixed, _)) = compensate(&camera, px, w, readout) {
                    self.rec.set_point2d_xy(kf.image_id, k as u32, fixed)?;
                    moved += 1;
                }
            }
        }
        Ok(moved)
    }
}

/// Gives the frames that `first` localised and `after` (the localisation of
/// the compensated map) lost a pose: the one `first` gave them relative to
/// their nearest keyframe in frame order, moved with that keyframe and scaled
/// by the change of scale of the keyframe centres (the refinement normalises
/// the map). A refinement of the finished map must not lose a frame it had
/// localised: a record in a fast turn that leans on few keyframes can lose
/// most of its map points to the compensated BA's filter (docs/history.md,
/// issue 15) although its pose relative to its keyframe was sound. ORB-SLAM
/// keeps every frame's pose relative to its reference keyframe for the same
/// reason (its trajectory is written through the optimised keyframes).
/// Refining the carried pose on what is left of the frame's support does
/// not help: too few of those correspondences agree with it (docs/history.md).
/// Returns how many frames were carried.
pub(crate) fn carry_lost_frames(first: &Localization, after: &mut Localization) -> usize {
    let keyframes = |loc: &Localization| -> HashMap<usize, Rigid3> {
        loc.poses.iter().filter(|p| p.keyframe).map(|p| (p.frame.index, p.cam_from_world.inverse())).collect()
    };
    let (before, now) = (keyframes(first), keyframes(after));
    let mut shared: Vec<usize> = before.keys().filter(|k| now.contains_key(k)).copied().collect();
    shared.sort_unstable();
    // Indexing below: `shared` holds only keys of both maps.
    let centres = |m: &HashMap<usize, Rigid3>| -> Vec<Vec3> { shared.iter().map(|k| m[k].translation).collect() };
    // Fewer than three keyframes or a degenerate layout: no scale change.
    let scale = umeyama(&centres(&before), &centres(&now), true).map_or(1.0, |s| s.scale);
    let lost: HashSet<usize> = after.failed.iter().map(|f| f.index).collect();
    let mut carried = Vec::new();
    for p in first.poses.iter().filter(|p| !p.keyframe && lost.contains(&p.frame.index)) {
        let Some(&k) = shared.iter().min_by_key(|k| k.abs_diff(p.frame.index)) else { break };
        let (kf0, kf1) = (&before[&k], &now[&k]);
        // world_after_from_world_before at the keyframe, with the map's scale change.
        let rotation = kf1.rotation * kf0.rotation.inverse();
        let sim = Sim3 { scale, rotation, translation: kf1.translation - scale * (rotation * kf0.translation) };
        let world_from_cam = sim.transform_world_from_cam(&p.cam_from_world.inverse());
        tracing::debug!("frame {}: pose carried through the keyframe of frame {k}", p.frame.index);
        carried.push(FramePose { cam_from_world: world_from_cam.inverse(), ..p.clone() });
    }
    let indices: HashSet<usize> = carried.iter().map(|p| p.frame.index).collect();
    after.failed.retain(|f| !indices.contains(&f.index));
    after.poses.extend(carried);
    after.poses.sort_by_key(|p| p.frame.index);
    indices.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(index: usize, t: f64, w: &Vec3) -> FramePose {
        FramePose {
            frame: crate::frame::FrameId { index, timestamp: t, name: format!("{index}") },
            cam_from_world: Rigid3::new(Quat::from_scaled_axis(w * t), Vec3::zeros()),
            keyframe: false,
        }
    }

    #[test]
    fn a_frame_the_compensation_lost_moves_with_its_nearest_keyframe() {
        // Keyframes at frames 0, 10 and 20; frame 12 localised first, lost
        // after a refinement that moved the whole map by a similarity (the
        // normalisation's scale included): it keeps its place in the map.
        let at = |index: usize, keyframe: bool, angle: f64, c: Vec3| FramePose {
            frame: crate::frame::FrameId { index, timestamp: index as f64, name: format!("{index}") },
            cam_from_world: Rigid3::new(Quat::from_scaled_axis(Vec3::new(0.1, angle, 0.0)), c).inverse(),
            keyframe,
        };
        let kf = [
            (0, 0.0, Vec3::new(0.0, 0.0, 0.0)),
            (10, 0.2, Vec3::new(1.0, 0.1, 0.0)),
            (20, 0.4, Vec3::new(2.0, 0.0, 0.3)),
        ];
        let mut poses: Vec<FramePose> = kf.iter().map(|&(i, a, c)| at(i, true, a, c)).collect();
        poses.push(at(12, false, 0.25, Vec3::new(1.2, 0.1, 0.05)));
        let first = Localization { poses, ..Default::default() };
        let sim = Sim3 {
            scale: 2.5,
            rotation: Quat::from_scaled_axis(Vec3::new(0.0, 0.3, -0.2)),
            translation: Vec3::new(4.0, -1.0, 2.0),
        };
        let moved = |p: &FramePose| FramePose {
            cam_from_world: sim.transform_world_from_cam(&p.cam_from_world.inverse()).inverse(),
            ..p.clone()
        };
        let lost = first.poses[3].frame.clone();
        let mut after = Localization {
            poses: first.poses[..3].iter().map(moved).collect(),
            failed: vec![lost.clone(), crate::frame::FrameId { index: 15, ..lost }],
            ..Default::default()
        };
        assert_eq!(carry_lost_frames(&first, &mut after), 1);
        assert_eq!(after.poses.iter().map(|p| p.frame.index).collect::<Vec<_>>(), [0, 10, 12, 20]);
        // Frame 15 was never localised: still failed.
        assert_eq!(after.failed.iter().map(|f| f.index).collect::<Vec<_>>(), [15]);
        let (got, want) = (after.poses[2].cam_from_world, moved(&first.poses[3]).cam_from_world);
        assert!((got.center() - want.center()).norm() < 1e-9, "{:?} {:?}", got.center(), want.center());
        assert!(got.rotation.angle_to(&want.rotation) < 1e-9);
        assert!(!after.poses[2].keyframe);
    }

    #[test]
    fn velocities_of_a_steady_turn() {
        let w = Vec3::new(0.3, -0.5, 0.2);
        let poses: Vec<FramePose> = (0..10).map(|i| pose(i, i as f64 / 15.0, &w)).collect();
        let v = angular_velocities(&poses, 0.5);
        assert_eq!(v.len(), 10);
        for i in 0..10 {
            assert!((v[&i] - w).norm() < 1e-9, "frame {i}: {}", v[&i]);
        }
        // A gap longer than allowed (between frames 4 and 5) leaves the
        // frames beside it out; the others keep their velocity.
        let mut gappy = poses.clone();
        for p in &mut gappy[5..] {
            p.frame.timestamp += 2.0;
        }
        let v = angular_velocities(&gappy, 0.5);
        assert!(!v.contains_key(&4) && !v.contains_key(&5), "{:?}", v.keys());
        for i in [0, 3, 6, 9] {
            assert!((v[&i] - w).norm() < 1e-9, "frame {i}");
        }
    }

    #[test]
    fn the_search_finds_a_parabola_minimum_and_stays_at_zero_when_cost_rises() {
        let mut calls = 0;
        let (x, samples) = parabolic_search(&[0.0, 0.025, 0.05], 0.05, 5, 1e-4, |t| {
            calls += 1;
            Ok::<f64, ()>(100.0 + 1e4 * (t - 0.0137) * (t - 0.0137))
        })
        .unwrap();
        assert!((x - 0.0137).abs() < 1e-6, "{x} after {samples:?}");
        assert!(calls <= 5);
        // A cost that only rises: 0, after the three bracketing samples.
        let (x, samples) = parabolic_search(&[0.0, 0.025, 0.05], 0.05, 5, 1e-4, |t| Ok::<f64, ()>(1.0 + t)).unwrap();
        assert_eq!((x, samples.len()), (0.0, 3));
        // A minimum beyond the range: the upper end.
        let (x, _) =
            parabolic_search(&[0.0, 0.025, 0.05], 0.05, 5, 1e-4, |t| Ok::<f64, ()>((t - 0.2) * (t - 0.2))).unwrap();
        assert!((x - 0.05).abs() < 1e-12, "{x}");
    }

    #[test]
    fn the_next_readout_is_the_fixed_point_of_estimate_and_compensation() {
        // One round: the estimate.
        assert_eq!(next_readout(&[(0.0, 0.015)], 0.05), 0.015);
        // An estimate that follows the compensation at 0.3:1 (estimate =
        // 0.015 + 0.3 c, TUM fr1-like): the secant lands on its fixed point
        // 0.015 / 0.7, where plain iteration would be at 0.0195.
        let g = |c: f64| 0.015 + 0.3 * c;
        let r = next_readout(&[(0.0, g(0.0)), (0.015, g(0.015))], 0.05);
        assert!((r - 0.015 / 0.7).abs() < 1e-12, "{r}");
        // Clamped to the search range.
        assert_eq!(next_readout(&[(0.0, 0.04), (0.04, 0.07)], 0.05), 0.05);
        // No crossing (the estimate runs ahead of the compensation): the last estimate.
        assert_eq!(next_readout(&[(0.0, 0.01), (0.01, 0.03)], 0.05), 0.03);
        assert_eq!(next_readout(&[], 0.05), 0.0);
    }

    #[test]
    fn a_readout_must_explain_enough_of_the_cost() {
        // TUM fr1-like: 5 % less cost at 12 ms.
        assert_eq!(chosen_readout(&[(0.0, 100.0), (0.025, 104.0), (0.012, 95.0)]), 0.012);
        // Synthetic-like: 0.06 % is noise, a global shutter.
        assert_eq!(chosen_readout(&[(0.0, 1190.3), (0.025, 1198.0), (0.0054, 1189.6)]), 0.0);
        assert_eq!(chosen_readout(&[]), 0.0);
    }

    #[test]
    fn compensation_undoes_a_simulated_rolling_shutter() {
        // A camera turning at w sees world point X on row v at time dt(v):
        // project with the pose of that moment, then compensate, and the
        // result must be the projection at the middle-row time.
        let camera = Camera {
            model: colslam_camera::CameraModelId::OpenCv,
            width: 640,
            height: 480,
            params: vec![517.3, 516.5, 318.6, 255.3, 0.26, -0.95, -0.005, 0.0026],
        };
        let (w, readout) = (Vec3::new(0.4, -0.6, 0.3), 0.03);
        // Far below the middle row (about row 410), where the shutter shifts most.
        let x = Vec3::new(0.3, 0.6, 2.0);
        let at = |dt: f64| camera.img_from_cam(&(Quat::from_scaled_axis(w * dt) * x)).expect("projects");
        // Fixed point of v = project(pose(dt(v))).y.
        let mut px = at(0.0);
        for _ in 0..50 {
            px = at((px.y / 480.0 - 0.5) * readout);
        }
        let mid = at(0.0);
        assert!((px - mid).norm() > 1.0, "the shutter should move the point: {px} vs {mid}");
        let (fixed, n) = compensate(&camera, &px, &w, readout).expect("compensates");
        assert!((fixed - mid).norm() < 1e-6, "{fixed} vs {mid}");
        assert!((camera.img_from_normalized(&n) - fixed).norm() < 1e-9);
        // No readout, no change.
        let (same, _) = compensate(&camera, &px, &w, 0.0).expect("compensates");
        assert!((same - px).norm() < 1e-6);
    }
}

//! The focal length of an uncalibrated camera, estimated from the first
//! frames before the run maps them (issue 16).
//!
//! Two-view self-calibration (the focal length that makes `K^T F K` an
//! essential matrix) is degenerate for object-centred photo sets and a
//! car's planar motion (Sturm's critical motions; docs/history.md), so the
//! estimate is a one-dimensional search over a multi-view map of the first
//! frames: the pipeline maps them at a starting focal length, and each
//! candidate is scored by the cost of a bundle adjustment of that map's
//! poses and points with the focal length fixed at it. Scoring each
//! candidate by its own map instead is biased: the mapper's
//! triangulation-angle threshold is in degrees, so a short focal length
//! turns the same pixels into wider angles and keeps more points. The
//! curvature of the cost says whether the frames constrain the focal
//! length at all (forward motion does not). The run's global refinements
//! then refine the focal length from the estimate, as COLMAP's
//! self-calibration refines its prior.

use crate::error::SlamError;
use crate::events::EventSink;
use crate::frame::FrameData;
use crate::options::{RollingShutter, SlamOptions};
use crate::pipeline::Slam;
use colslam_camera::Camera;
use colslam_geometry::Vec2;
use colslam_optim::LossFunction;
use colslam_scene::Reconstruction;
use colslam_sfm::SfmError;
use colslam_sfm::bundle::{BundleOptions, adjust_global};
use serde::Serialize;

/// The bundle-adjustment cost of the first frames' map with the focal
/// length fixed at one value.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FocalCandidate {
    /// The focal length tried, pixels.
    pub focal_px: f64,
    /// The cost after a bundle adjustment of poses and points (soft-L1 loss
    /// of 1 px) from the map made at the starting focal length.
    pub cost: f64,
}

/// The estimate and every candidate the search scored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FocalEstimate {
    /// The estimated focal length, pixels.
    pub focal_px: f64,
    /// The focal length the map of the first frames was made with, pixels.
    pub start_px: f64,
    /// Frames the search used.
    pub frames: usize,
    /// Keyframes and observations of the map scored.
    pub keyframes: usize,
    /// Observations of the map scored.
    pub observations: usize,
    /// How much the cost rises 10 % away from the estimate, relative to
    /// its value there: near 0 when the first
    /// frames do not constrain the focal length (a critical motion).
    pub sharpness: f64,
    /// The candidates, in the order they were tried.
    pub candidates: Vec<FocalCandidate>,
}

/// A pinhole camera of `w` x `h` pixels with focal length `f` and the
/// principal point at the image centre, in OpenCV's pixel convention (the
/// centre of a w-pixel row is at (w - 1) / 2).
pub fn centred_camera(w: u32, h: u32, f: f64) -> Camera {
    Camera::simple_pinhole(w as u64, h as u64, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0)
}

/// Points sampled on each segment from the principal point to a corner by
/// [`distortion_shift`] and [`term_shift`]: a two-term lens (RADIAL) can
/// move the corners less than the image's middle (TUM fr1's fit k1 0.10,
/// k2 -0.20 moves them under 1 px and three quarters of the way out 4 px).
const SHIFT_SAMPLES: usize = 32;

/// How far `camera`'s distortion terms move image points, pixels: the
/// largest move over the segments from the principal point to the four
/// corners, each point's ray through the pinhole part (focal lengths and
/// principal point) projected with and without the distortion. At the
/// farthest corner for a one-term radial lens.
pub fn distortion_shift(camera: &Camera) -> f64 {
    term_shift(camera, camera.model.extra_params_idxs())
}

/// How far some distortion terms of `camera` (parameter indices `terms`)
/// move image points, pixels: [`distortion_shift`] against the camera with
/// those terms at 0.
pub fn term_shift(camera: &Camera, terms: &[usize]) -> f64 {
    let mut without = camera.clone();
    for &i in terms {
        if let Some(v) = without.params.get_mut(i) {
            *v = 0.0;
        }
    }
    largest_move(camera, &without)
}

/// The largest distance between `camera`'s and `other`'s projections of the
/// same rays: `camera`'s pinhole rays through the points of the segments
/// from its principal point to the image's corners.
fn largest_move(camera: &Camera, other: &Camera) -> f64 {
    let (w, h) = (camera.width as f64, camera.height as f64);
    let (f, c) = (Vec2::new(camera.focal_x(), camera.focal_y()), camera.principal_point());
    let mut largest = 0.0f64;
    for (x, y) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
        let corner = Vec2::new((x - c.x) / f.x, (y - c.y) / f.y);
        for i in 1..=SHIFT_SAMPLES {
            let ray = corner * (i as f64 / SHIFT_SAMPLES as f64);
            largest = largest.max((camera.img_from_normalized(&ray) - other.img_from_normalized(&ray)).norm());
        }
    }
    largest
}

/// The largest map the pipeline makes of `frames` with the focal length
/// fixed at `f` (no rolling-shutter compensation).
fn prefix_map(
    frames: &[FrameData],
    w: u32,
    h: u32,
    f: f64,
    opts: &SlamOptions,
) -> Result<Option<Reconstruction>, SlamError> {
    let mut opts = opts.clone();
    // Only the focal length varies between the candidates' maps.
    opts.refine.refine_intrinsics = false;
    opts.refine.refine_distortion = false;
    opts.refine.rolling_shutter = RollingShutter::Seconds(0.0);
    let mut slam = Slam::new(opts, &centred_camera(w, h, f), EventSink::none())?;
    for frame in frames {
        let mut data = frame.clone();
        data.normalize_with(slam.camera());
        slam.process_features(data)?;
    }
    let result = slam.finish()?;
    Ok(result.maps.first().map(|m| m.map.reconstruction().clone()))
}

/// The cost of `rec` after a bundle adjustment of its poses and points
/// with every camera's focal length set to `f` (COLMAP pixel convention:
/// the principal point is not moved).
fn cost_at(rec: &Reconstruction, f: f64) -> Result<f64, SfmError> {
    let mut rec = rec.clone();
    let ids: Vec<_> = rec.cameras().map(|c| c.id).collect();
    for id in ids {
        if let Some(cam) = rec.camera_mut(id) {
            for &i in cam.model.focal_length_idxs() {
                cam.params[i] = f;
            }
        }
    }
    let mut ba = BundleOptions::global();
    ba.ba.loss = LossFunction::SoftL1(1.0);
    let report = adjust_global(&mut rec, false, &ba)?;
    tracing::debug!("focal search: f {f:.1} px: cost {:.5e} in {} iterations", report.final_cost, report.iterations);
    Ok(report.final_cost)
}

/// How much the bundle-adjustment cost of `rec` ([`cost_at`]) rises, on
/// average, with the focal length fixed 10 % either side of `f` instead of
/// at it, relative to the cost at `f`: the [`FocalEstimate::sharpness`] of
/// a map whose BA refined the focal length to `f`, so near 0 when its
/// views do not constrain it (three bundle adjustments of a copy).
pub(crate) fn focal_sharpness(rec: &Reconstruction, f: f64) -> Result<f64, SfmError> {
    let [below, at, above] = costs_around(rec, f)?;
    Ok((0.5 * (below + above) - at) / at.max(f64::MIN_POSITIVE))
}

/// [`cost_at`] 10 % below `f`, at it and 10 % above: what
/// [`focal_sharpness`] and [`focal_profile`] read.
fn costs_around(rec: &Reconstruction, f: f64) -> Result<[f64; 3], SfmError> {
    Ok([cost_at(rec, f / 1.1)?, cost_at(rec, f)?, cost_at(rec, f * 1.1)?])
}

/// What the views of a map say about its focal length near `f`
/// ([`focal_profile`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FocalProfile {
    /// The focal length's relative standard deviation (infinite when the
    /// cost does not curve up around `f`).
    pub spread: f64,
    /// How much better, in chi-square, the better of the focal lengths 10 %
    /// either side fits than `f` (0 when neither does): the evidence that
    /// `f` is wrong, however flat the cost is.
    pub drop: f64,
}

/// The profile of a map's cost over its focal length: the cost with the
/// focal length fixed at `f` and 10 % either side ([`cost_at`], each
/// re-fitting the poses and points, so the marginal, not the conditional,
/// uncertainty), a parabola in log f. The best fit's cost is the
/// residuals' variance times half the degrees of freedom (two per
/// observation, less three per point and six per pose, plus the seven of
/// the gauge), which turns costs into chi-square: one standard deviation
/// is where the parabola has risen by one. `f` need not be the minimum: a
/// focal length held at a guess is judged by the same three costs.
pub(crate) fn focal_profile(rec: &Reconstruction, f: f64) -> Result<FocalProfile, SfmError> {
    let step = 1.1_f64.ln();
    let [below, at, above] = costs_around(rec, f)?;
    let dof =
        2 * rec.num_observations() as i64 - 3 * rec.num_points3d() as i64 - 6 * rec.num_registered_images() as i64 + 7;
    if dof <= 0 {
        return Ok(FocalProfile { spread: f64::INFINITY, drop: 0.0 });
    }
    // cost(t) = a t^2 + b t + at, t in steps of `step`.
    let a = 0.5 * (below + above) - at;
    let b = 0.5 * (above - below);
    let least = below.min(at).min(above);
    // The best fit: the parabola's vertex where it curves up (never above
    // the costs tried), else the least cost tried.
    let best = if a > 0.0 { (at - b * b / (4.0 * a)).clamp(0.0, least) } else { least };
    // Half the residuals' variance: one unit of chi-square in cost.
    let unit = best / dof as f64;
    let chi2 = |cost: f64| {
        if cost <= 0.0 {
            0.0
        } else if unit > 0.0 {
            cost / unit
        } else {
            // Exact observations: any change is decisive.
            f64::INFINITY
        }
    };
    let spread = if a > 0.0 { step / chi2(a).sqrt() } else { f64::INFINITY };
    Ok(FocalProfile { spread, drop: chi2(at - least) })
}

/// The coarse grid of the search, as factors of the starting focal length:
/// 0.35 to 2 in steps of 2^(1/4).
const COARSE_GRID: [f64; 11] = [0.354, 0.420, 0.5, 0.595, 0.707, 0.841, 1.0, 1.189, 1.414, 1.682, 2.0];

/// The fine grid around the coarse estimate, in steps of 2^(1/8).
const FINE_GRID: [f64; 5] = [0.841, 0.917, 1.0, 1.091, 1.189];

/// The search stops once a round moves the focal length by less than this
/// ratio; else the frames are mapped again with the new value, since a map
/// made with a wrong focal length keeps observations that favour it (each
/// round removes most of the remaining error).
const CONVERGED_RATIO: f64 = 1.02;

/// Rounds of the search at most (the coarse one included).
const MAX_ROUNDS: usize = 4;

/// Below this [`FocalEstimate::sharpness`] the first frames do not
/// constrain the focal length: a forward-moving car's camera lies far
/// below it, hand-held and object-centred sets far above
/// (docs/benchmarks.md, "The focal length searched from the first frames").
pub const MIN_SHARPNESS: f64 = 0.01;

/// A map of the first frames with fewer keyframes is too small to judge
/// whether they constrain the focal length: a slow start makes a few
/// keyframes whose cost is flat although the whole run constrains it.
pub const MIN_JUDGED_KEYFRAMES: usize = 5;

impl FocalEstimate {
    /// The first frames constrain the focal length: the estimate is used
    /// and refined.
    pub fn constrained(&self) -> bool {
        self.sharpness >= MIN_SHARPNESS
    }

    /// A map large enough to judge found the focal length unconstrained (a
    /// forward or planar motion): bundle adjustment would let it run away,
    /// so the run keeps its guess fixed.
    pub fn unconstrained(&self) -> bool {
        !self.constrained() && self.keyframes >= MIN_JUDGED_KEYFRAMES
    }
}

/// Estimates the focal length of a `w` x `h` camera from `frames` (the
/// first frames of the run, features extracted), starting from the guess
/// `start`: [`search`] on a coarse grid from a map made with `start`,
/// then on a fine grid from a map made with the last estimate, until a
/// round moves it by less than [`CONVERGED_RATIO`]. `None` when the frames
/// make no map.
pub fn estimate_focal(
    frames: &[FrameData],
    w: u32,
    h: u32,
    start: f64,
    opts: &SlamOptions,
) -> Result<Option<FocalEstimate>, SlamError> {
    let Some(mut estimate) = search(frames, w, h, start, &COARSE_GRID, opts)? else { return Ok(None) };
    tracing::info!("focal search: {:.1} px from a map made at {start:.1} px", estimate.focal_px);
    for _ in 1..MAX_ROUNDS {
        let moved = (estimate.focal_px / estimate.start_px).ln().abs();
        if moved < CONVERGED_RATIO.ln() || estimate.sharpness < MIN_SHARPNESS {
            break;
        }
        let Some(mut next) = search(frames, w, h, estimate.focal_px, &FINE_GRID, opts)? else { break };
        tracing::info!("focal search: {:.1} px from a map made at {:.1} px", next.focal_px, estimate.focal_px);
        let mut candidates = std::mem::take(&mut estimate.candidates);
        candidates.append(&mut next.candidates);
        next.candidates = candidates;
        estimate = next;
    }
    Ok(Some(estimate))
}

/// One round of the search: the pipeline maps `frames` with the focal
/// length fixed at `start`, then the focal length is searched on a log grid
/// of `grid` factors of `start` by the cost of a bundle adjustment of that
/// map's poses and points (one set of observations for every candidate, so
/// that the mapper's thresholds, which depend on the focal length, do not
/// bias the comparison), and the minimum is refined by a parabola through
/// its neighbours in log f.
fn search(
    frames: &[FrameData],
    w: u32,
    h: u32,
    start: f64,
    grid: &[f64],
    opts: &SlamOptions,
) -> Result<Option<FocalEstimate>, SlamError> {
    let Some(rec) = prefix_map(frames, w, h, start, opts)? else { return Ok(None) };
    if rec.num_registered_images() < 3 {
        return Ok(None);
    }
    let mut candidates = Vec::new();
    for factor in grid {
        let f = factor * start;
        candidates.push(FocalCandidate { focal_px: f, cost: cost_at(&rec, f)? });
    }
    let Some(best) = (0..candidates.len()).min_by(|&a, &b| candidates[a].cost.total_cmp(&candidates[b].cost)) else {
        return Ok(None);
    };
    let (focal_px, sharpness) = if best == 0 || best + 1 == candidates.len() {
        // At the grid's edge: no bracket, so no sharpness either.
        (candidates[best].focal_px, 0.0)
    } else {
        let [a, b, c] = [&candidates[best - 1], &candidates[best], &candidates[best + 1]];
        parabola_min(a, b, c)
    };
    let estimate = FocalEstimate {
        focal_px,
        start_px: start,
        frames: frames.len(),
        keyframes: rec.num_registered_images(),
        observations: rec.num_observations(),
        sharpness,
        candidates,
    };
    Ok(Some(estimate))
}

/// The vertex of the parabola through three candidates in log f (equal
/// steps), and the cost's relative rise 10 % away from it.
fn parabola_min(a: &FocalCandidate, b: &FocalCandidate, c: &FocalCandidate) -> (f64, f64) {
    let step = (c.focal_px / b.focal_px).ln();
    let curvature = a.cost - 2.0 * b.cost + c.cost;
    if curvature <= 0.0 || b.cost <= 0.0 || step <= 0.0 {
        return (b.focal_px, 0.0);
    }
    // Offset of the vertex from b in steps, within the bracket.
    let t = (0.5 * (a.cost - c.cost) / curvature).clamp(-0.5, 0.5);
    let vertex = b.cost - 0.25 * (a.cost - c.cost) * t;
    // cost(t) = vertex + curvature / 2 * (t - t_vertex)^2, t in steps.
    let ten_percent = 1.1_f64.ln() / step;
    let rise = 0.5 * curvature * ten_percent * ten_percent;
    ((b.focal_px.ln() + t * step).exp(), rise / vertex.max(f64::MIN_POSITIVE))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frontend::Frontend;
    use colslam_synth::{SynthOptions, SyntheticSequence};

    /// The first `n` frames of a small synthetic room (320 x 240, true
    /// focal length 262.5 px), features extracted with a camera of focal
    /// length `f`.
    fn synthetic_frames(n: usize, f: f64) -> Vec<FrameData> {
        let opts =
            SynthOptions { frames: n, width: 320, height: 240, focal: 262.5, seed: 12, ..SynthOptions::default() };
        frames_of(&opts, n, f)
    }

    /// The first `n` frames of `opts`'s sequence (320 x 240), features
    /// extracted with a camera of focal length `f`.
    fn frames_of(opts: &SynthOptions, n: usize, f: f64) -> Vec<FrameData> {
        let seq = SyntheticSequence::new(opts).unwrap_or_else(|e| panic!("sequence: {e}"));
        let frontend = Frontend::new(&SlamOptions::default().frontend, &centred_camera(320, 240, f))
            .unwrap_or_else(|e| panic!("frontend: {e}"));
        (0..n)
            .map(|i| {
                let image = seq.render(i).unwrap_or_else(|e| panic!("render: {e}"));
                let frame = colslam_io::Frame {
                    index: i,
                    source_index: i,
                    timestamp: i as f64 / opts.fps,
                    name: format!("{i:06}.png"),
                    image,
                };
                frontend.process(&frame).unwrap_or_else(|e| panic!("features: {e}"))
            })
            .collect()
    }

    #[test]
    fn a_radial_term_moves_the_farthest_corner_by_k_r_cubed_focal_lengths() {
        // SIMPLE_RADIAL maps the normalised radius r to r (1 + k r^2): at a
        // corner r is (half the diagonal) / f, and the shift k r^3 f. A
        // principal point off the centre makes its farthest corner count.
        let pinhole = Camera::simple_pinhole(640, 480, 500.0, 300.0, 240.0);
        let radial = Camera { params: vec![500.0, 300.0, 240.0, 0.02], ..pinhole.with_radial_term() };
        let r = (340.0_f64.powi(2) + 240.0_f64.powi(2)).sqrt() / 500.0;
        let expected = 0.02 * r.powi(3) * 500.0;
        let shift = distortion_shift(&radial);
        assert!((shift - expected).abs() < 1e-9, "shift {shift} px, expected {expected}");
        assert_eq!(distortion_shift(&pinhole), 0.0);
    }

    #[test]
    fn a_two_term_lens_that_spares_the_corners_still_moves_the_image() {
        // RADIAL's radial move is f r (k1 r^2 + k2 r^4): with k2 = -k1 / r_c^2
        // it vanishes at the corner's radius r_c and peaks at r_c / sqrt(5/3),
        // where it is f k1 r^3 (1 - 3/5) = 0.4 f k1 r^3.
        let pinhole = Camera::simple_pinhole(640, 480, 500.0, 320.0, 240.0);
        let rc = 400.0 / 500.0;
        let (k1, k2) = (0.1, -0.1 / (rc * rc));
        let lens = Camera {
            params: vec![500.0, 320.0, 240.0, k1, k2],
            ..pinhole.with_radial_term().with_second_radial_term()
        };
        let r = rc / (5.0_f64 / 3.0).sqrt();
        let peak = 500.0 * k1 * r.powi(3) * 0.4;
        let shift = distortion_shift(&lens);
        assert!(shift > 0.98 * peak && shift <= peak + 1e-9, "shift {shift} px, peak {peak} px");
        let corner = lens.img_from_normalized(&Vec2::new(0.64, 0.48)) - Vec2::new(640.0, 480.0);
        assert!(corner.norm() < 1e-9, "the corner does not move: {corner:?}");
        // k2's own move is largest at the corner: f |k2| r_c^5.
        let k2_move = 500.0 * k2.abs() * rc.powi(5);
        assert!((term_shift(&lens, &[4]) - k2_move).abs() < 1e-9, "{} against {k2_move}", term_shift(&lens, &[4]));
    }

    #[test]
    fn a_map_orbiting_the_room_constrains_its_focal_length_far_more_than_a_straight_drive() {
        // The remap's test of a stable focal length
        // (`pipeline::REMAP_MIN_SHARPNESS`): a map whose views turn about
        // the scene fixes the focal length; one moving straight ahead fits
        // as well with it 10 % off either way (a critical motion). Measured:
        // the room's arc 0.012 (14 keyframes), the drive's first 60 frames
        // 6e-5.
        let truth = 262.5;
        let room =
            SynthOptions { frames: 150, width: 320, height: 240, focal: truth, seed: 12, ..SynthOptions::default() };
        let drive = SynthOptions {
            path: colslam_synth::options::PathShape::Drive,
            path_length: 60.0,
            orbit_radius: 6.0,
            room_size: [40.0, 40.0, 6.0],
            frames: 300,
            ..room.clone()
        };
        let sharpness = |opts: &SynthOptions, n: usize| {
            let frames = frames_of(opts, n, truth);
            let rec = prefix_map(&frames, 320, 240, truth, &SlamOptions::default())
                .unwrap_or_else(|e| panic!("map: {e}"))
                .unwrap_or_else(|| panic!("no map"));
            focal_sharpness(&rec, truth).unwrap_or_else(|e| panic!("sharpness: {e}"))
        };
        let (orbit, straight) = (sharpness(&room, 150), sharpness(&drive, 60));
        assert!(straight < 0.1 * crate::pipeline::REMAP_MIN_SHARPNESS, "straight drive: {straight}");
        assert!(orbit > 20.0 * straight, "orbit {orbit} against the straight drive's {straight}");
    }

    #[test]
    fn the_focal_search_finds_the_synthetic_focal_length_from_a_far_guess() {
        // COLMAP's prior for photos (1.2 x the larger side, 384 px) is 46 %
        // off; the estimate must land within 5 % (the search settles 3 %
        // long on these 60 frames: the minimum of their bundle adjustment's
        // cost, not a bias of the search).
        let start = 1.2 * 320.0;
        let frames = synthetic_frames(60, start);
        let e = estimate_focal(&frames, 320, 240, start, &SlamOptions::default())
            .unwrap_or_else(|e| panic!("search: {e}"))
            .unwrap_or_else(|| panic!("no map of the first frames"));
        let truth = 262.5;
        assert!(
            (e.focal_px / truth - 1.0).abs() < 0.05,
            "estimate {:.1} px vs {truth}: {:?}",
            e.focal_px,
            e.candidates
        );
        assert!(e.sharpness > 0.0, "a bracketed minimum: {e:?}");
    }
}

//! ORB features with the ORB-SLAM recipe.
//!
//! References: Rublee, Rabaud, Konolige & Bradski, "ORB: an efficient
//! alternative to SIFT or SURF" (ICCV 2011); Mur-Artal, Montiel & Tardós,
//! "ORB-SLAM" (T-RO 2015) and ORB-SLAM2's `ORBextractor` (grid FAST with a
//! fallback threshold, quadtree distribution).
//!
//! Per pyramid level (levels run in parallel with rayon), with the default
//! [`Selection::Strongest`] (OpenCV's ORB, `modules/features2d/src/orb.cpp`):
//! 1. FAST-9 at `ini_fast_threshold` over the level, 3x3 non-maximum
//!    suppression on the FAST score. A level with fewer corners than its
//!    quota is searched again at the threshold halfway down to
//!    `min_fast_threshold`, then at `min_fast_threshold` itself.
//! 2. The twice-quota best by FAST score are scored ([`ScoreType`], Harris by
//!    default) and the quota best kept, wherever they lie.
//!
//! With [`Selection::Quadtree`] (ORB-SLAM):
//! 1. FAST-9 at `ini_fast_threshold` over the whole level, 3x3 non-maximum
//!    suppression on the FAST score. If the level has fewer corners than its
//!    quota (or always, with [`FallbackMode::Always`] as ORB-SLAM), every
//!    grid cell (~`cell_size` px) where nothing was found is searched again
//!    at `min_fast_threshold`.
//! 2. Each corner is scored ([`ScoreType`], Harris by default).
//! 3. A quadtree splits the level into nodes until there are as many nodes as
//!    the level's quota, and keeps the best-scored corner of each node, so the
//!    keypoints spread over the image instead of clustering on texture. With
//!    [`FallbackMode::WhenShort`] every strong corner is kept and the weak
//!    (fallback) corners are spread over the remaining slots.
//!
//! Then, in both cases:
//! 4. Orientation by the intensity centroid over a disc of radius 15.
//! 5. Steered rBRIEF (256 learned pairs) on the level smoothed by a 7x7
//!    Gaussian (sigma 2).
//!
//! 6. With `subpixel` (an option, off by default), the position is refined
//!    at the level to sub-pixel accuracy by gradient-based corner
//!    refinement (`subpixel`).
//!
//! Keypoints are mapped back to level-0 pixels with pixel centres aligned
//! (`x0 = (x + 0.5) * s - 0.5`, `s = width0 / width_level`, the sampling of
//! the pyramid's resize), which removes the up-to-1.3 px bias at the
//! coarsest level of OpenCV's `x * s`.

use crate::FeatureError;
use crate::fast::FastMap;
use crate::orb_pattern::{ORB_BITS, ORB_PATTERN};
use crate::pyramid::{Plane, gaussian_blur7, resize_bilinear};
use crate::subpixel;
use crate::types::{Descriptors, FeatureExtractor, Features, Keypoint};
use colslam_image::Image;
use rayon::prelude::*;
use std::borrow::Cow;
use std::time::Instant;

/// Milliseconds elapsed since `t`.
fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Radius of the orientation disc (half of the 31-pixel ORB patch).
pub const ORIENTATION_RADIUS: usize = 15;
/// Lanes of one orientation row: the disc's 31 pixels, padded to 32.
const DISC_LANES: usize = 32;
/// Diameter of the described patch at level 0 (ORB's 31x31 patch).
pub const PATCH_SIZE: f32 = 31.0;
/// Smallest allowed `edge_threshold`: rotated pattern samples reach 18 px,
/// plus one so that the check is strict.
pub const MIN_EDGE_THRESHOLD: usize = PATTERN_REACH + 1;
/// Half-size of the Harris window (7x7, as OpenCV's ORB).
const HARRIS_HALF_BLOCK: isize = 3;
/// Largest |x| or |y| of a rotated, rounded pattern sample (13 * sqrt(2) < 18.4).
const PATTERN_REACH: usize = 18;
/// Size of the descriptor's patch buffer: a power of two at least
/// `(2 * PATTERN_REACH + 1)^2 = 1369`.
const PATCH_BUF: usize = 2048;
/// Fractional bits of the fixed-point pattern rotation.
const ROT_BITS: u32 = 12;
/// 1.0 in fixed-point rotation units.
const ROT_ONE: i32 = 1 << ROT_BITS;
/// With [`Selection::Strongest`], the candidates kept by FAST score before
/// the Harris ranking, per keypoint wanted (OpenCV's ORB keeps 2).
const PRESELECT_FACTOR: usize = 2;
/// Most pyramid levels accepted by `validate()`.
const MAX_LEVELS: usize = 32;

/// How corners are ranked inside the quadtree nodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScoreType {
    /// Harris corner measure on a 7x7 window (OpenCV's ORB default).
    /// Chosen as the default because FAST's score is high along strong edges
    /// too, while Harris prefers points well localised in both directions
    /// (Rublee et al. 2011, section 3.1), which is what two-view geometry and
    /// PnP need. It costs about a microsecond per candidate.
    Harris,
    /// The FAST score (ORB-SLAM's choice): cheaper, slightly less stable.
    Fast,
}

/// How the keypoints of a level are chosen among its FAST corners.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// The strongest corners of the level by [`ScoreType`], wherever they
    /// are (OpenCV's ORB; default). On the TUM fr1/rpy frames of
    /// `colslam bench features` (1000 keypoints, mutual nearest neighbours)
    /// this gives about 315 matches per consecutive pair within 1 px
    /// (Sampson) of the ground-truth geometry, 58 % of the matches, against
    /// 254 and 53 % with [`Selection::Quadtree`]: the quadtree fills weakly
    /// textured regions with low-contrast corners that repeat and match
    /// worse, at every pyramid level.
    Strongest,
    /// ORB-SLAM's quadtree distribution: keypoints spread evenly over the
    /// level, the best-scored corner of each node.
    Quadtree,
}

/// When the lower thresholds are used. With [`Selection::Strongest`]:
/// `WhenShort` searches a level again (at the threshold halfway down, then
/// at `min_fast_threshold`) only while it has fewer corners than its quota,
/// `Always` searches every level once at `min_fast_threshold`. With
/// [`Selection::Quadtree`], as described below (empty grid cells).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FallbackMode {
    /// Only on levels that have fewer corners at `ini_fast_threshold` than
    /// their quota, and then the fallback corners (spread by the quadtree)
    /// only fill the slots left: every strong corner is kept (default).
    /// Measured on a TUM fr1 frame warped by known similarities, `Always`
    /// filled most slots with weak, blur-sensitive corners: correct matches
    /// fell from 93 % to 83 % (30 degree rotation) and their number from 492
    /// to 308. This mode keeps ORB-SLAM's coverage of weakly textured levels
    /// without displacing strong corners.
    WhenShort,
    /// Every cell without a corner at the initial threshold (ORB-SLAM2).
    Always,
}

/// Options of [`OrbExtractor`].
#[derive(Debug, Clone, PartialEq)]
pub struct OrbOptions {
    /// Keypoints wanted over all levels (default 1000). Fewer are returned on
    /// weakly textured images.
    pub n_features: usize,
    /// Scale ratio between consecutive pyramid levels (default 1.2).
    pub scale_factor: f32,
    /// Pyramid levels (default 8). Levels smaller than the border leave are
    /// skipped.
    pub n_levels: usize,
    /// FAST threshold tried first in every grid cell (default 20).
    pub ini_fast_threshold: u8,
    /// Lowest FAST threshold, for levels (with [`Selection::Strongest`]) or
    /// grid cells (with [`Selection::Quadtree`]) where the first found too
    /// little (default 7).
    pub min_fast_threshold: u8,
    /// When the fallback threshold is used (default [`FallbackMode::WhenShort`]).
    pub fallback: FallbackMode,
    /// Approximate grid cell size in pixels for the fallback search of
    /// [`Selection::Quadtree`] (default 30).
    pub cell_size: usize,
    /// Distance in level pixels from the border inside which no keypoint is
    /// kept (default 19, also the minimum: descriptor samples reach 18 px).
    pub edge_threshold: usize,
    /// Corner ranking (default Harris).
    pub score: ScoreType,
    /// How keypoints are chosen (default [`Selection::Strongest`]).
    pub selection: Selection,
    /// Harris `k` (default 0.04).
    pub harris_k: f32,
    /// Refine each keypoint to sub-pixel accuracy at its level (gradient-based
    /// corner refinement around the detected pixel, see `subpixel`) before
    /// mapping it to full resolution; descriptors and orientation stay
    /// computed at the detected pixel. Without it (default) a keypoint of
    /// level `l` is quantised to `scale_factor^l` pixels. Off by default:
    /// it sharpens keypoints on the synthetic sequence but made the runs on
    /// the real sequences less accurate (docs/benchmarks.md).
    pub subpixel: bool,
}

impl Default for OrbOptions {
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_fast_threshold: 20,
            min_fast_threshold: 7,
            fallback: FallbackMode::WhenShort,
            cell_size: 30,
            edge_threshold: MIN_EDGE_THRESHOLD,
            score: ScoreType::Harris,
            selection: Selection::Strongest,
            harris_k: 0.04,
            subpixel: false,
        }
    }
}

impl OrbOptions {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FeatureError> {
        let bad = |reason: String| Err(FeatureError::InvalidOptions { what: "ORB", reason });
        if self.n_features == 0 {
            return bad("n_features must be at least 1".into());
        }
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0 && self.scale_factor <= 4.0) {
            return bad(format!("scale_factor {} must be in (1, 4]", self.scale_factor));
        }
        if self.n_levels == 0 || self.n_levels > MAX_LEVELS {
            return bad(format!("n_levels {} must be in 1..={MAX_LEVELS}", self.n_levels));
        }
        if self.min_fast_threshold == 0 || self.min_fast_threshold > self.ini_fast_threshold {
            return bad(format!(
                "need 1 <= min_fast_threshold ({}) <= ini_fast_threshold ({})",
                self.min_fast_threshold, self.ini_fast_threshold
            ));
        }
        if self.cell_size < 8 {
            return bad(format!("cell_size {} must be at least 8", self.cell_size));
        }
        if self.edge_threshold < MIN_EDGE_THRESHOLD {
            return bad(format!("edge_threshold {} must be at least {MIN_EDGE_THRESHOLD}", self.edge_threshold));
        }
        if !self.harris_k.is_finite() || self.harris_k < 0.0 || self.harris_k > 0.25 {
            return bad(format!("harris_k {} must be in [0, 0.25]", self.harris_k));
        }
        Ok(())
    }
}

/// Per-level counts of one extraction.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OrbLevelReport {
    /// Level size in pixels.
    pub width: usize,
    /// Level size in pixels.
    pub height: usize,
    /// Keypoints the level was asked for.
    pub quota: usize,
    /// FAST corners after non-maximum suppression.
    pub candidates: usize,
    /// FAST corners at the initial threshold after non-maximum suppression.
    pub strong_candidates: usize,
    /// Grid cells searched again at the lower threshold.
    pub fallback_cells: usize,
    /// Keypoints kept.
    pub kept: usize,
    /// Time in FAST detection, both thresholds, and suppression (ms).
    pub detect_ms: f64,
    /// Time scoring the candidates (Harris or FAST) (ms).
    pub score_ms: f64,
    /// Time in the quadtree distribution (ms).
    pub distribute_ms: f64,
    /// Time smoothing the level, orienting and describing the keypoints (ms).
    pub describe_ms: f64,
}

/// What an extraction did, level by level.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OrbReport {
    /// One entry per pyramid level that was built.
    pub levels: Vec<OrbLevelReport>,
    /// Time building the pyramid (ms).
    pub pyramid_ms: f64,
    /// Wall time of the whole extraction (ms).
    pub total_ms: f64,
}

/// ORB extractor; cheap to clone, shareable between threads.
#[derive(Debug, Clone)]
pub struct OrbExtractor {
    opts: OrbOptions,
    /// Per row offset `v`: the weight `u` of lane `i` (`u = i - radius`)
    /// inside the disc, 0 outside.
    disc_u: Vec<[i16; DISC_LANES]>,
    /// Per row offset `v`: `v` inside the disc, 0 outside.
    disc_v: Vec<[i16; DISC_LANES]>,
}

impl OrbExtractor {
    /// Makes an extractor after validating the options.
    pub fn new(opts: OrbOptions) -> Result<Self, FeatureError> {
        opts.validate()?;
        let umax = disc_half_widths();
        let r = ORIENTATION_RADIUS as isize;
        let lane_u = |i: usize| i as isize - r;
        let disc_u = umax
            .iter()
            .map(|&um| std::array::from_fn(|i| if lane_u(i).abs() <= um { lane_u(i) as i16 } else { 0 }))
            .collect();
        let disc_v = umax
            .iter()
            .enumerate()
            .map(|(v, &um)| std::array::from_fn(|i| if lane_u(i).abs() <= um { v as i16 } else { 0 }))
            .collect();
        Ok(Self { opts, disc_u, disc_v })
    }

    /// The options in use.
    pub fn options(&self) -> &OrbOptions {
        &self.opts
    }

    /// Extracts features (RGB input is converted to gray first) and reports
    /// per-level counts and timings. The keypoint quota is split over the
    /// levels that could be built, so a small image still gets up to
    /// `n_features` keypoints.
    pub fn extract_with_report(&self, image: &Image) -> Result<(Features, OrbReport), FeatureError> {
        if image.is_empty() {
            return Err(FeatureError::EmptyImage { width: image.width(), height: image.height() });
        }
        let gray: Cow<'_, Image> =
            if image.channels() == 1 { Cow::Borrowed(image) } else { Cow::Owned(image.to_gray()) };
        let start = Instant::now();
        let levels = self.build_pyramid(&gray);
        let pyramid_ms = ms_since(start);
        let quotas = level_quotas(self.opts.n_features, self.opts.scale_factor, levels.len().max(1));
        let (w0, h0) = (gray.width() as f32, gray.height() as f32);
        let results: Vec<(Vec<Keypoint>, Vec<[u64; 4]>, OrbLevelReport)> = levels
            .par_iter()
            .enumerate()
            .map(|(level, plane)| {
                let quota = quotas.get(level).copied().unwrap_or(0);
                let sx = w0 / plane.width as f32;
                let sy = h0 / plane.height as f32;
                self.process_level(plane, level, quota, sx, sy)
            })
            .collect();
        let mut keypoints = Vec::new();
        let mut descriptors = Vec::new();
        let mut report = OrbReport { pyramid_ms, ..Default::default() };
        for (k, d, r) in results {
            keypoints.extend(k);
            descriptors.extend(d);
            report.levels.push(r);
        }
        report.total_ms = ms_since(start);
        Ok((Features { keypoints, descriptors: Descriptors::Binary(descriptors) }, report))
    }

    /// Level 0 is the input; level l is the bilinear down-sampling of level
    /// l - 1 to `round(size0 / scale_factor^l)`. Stops at the first level too
    /// small to hold a keypoint.
    fn build_pyramid(&self, gray: &Image) -> Vec<Plane> {
        let min_side = 2 * self.opts.edge_threshold + 1;
        let (w0, h0) = (gray.width(), gray.height());
        let mut levels: Vec<Plane> = Vec::with_capacity(self.opts.n_levels);
        if w0 < min_side || h0 < min_side {
            return levels;
        }
        levels.push(Plane { width: w0, height: h0, data: gray.data().to_vec() });
        let mut scale = 1.0f64;
        for _ in 1..self.opts.n_levels {
            scale *= self.opts.scale_factor as f64;
            let w = (w0 as f64 / scale).round() as usize;
            let h = (h0 as f64 / scale).round() as usize;
            if w < min_side || h < min_side {
                break;
            }
            let Some(prev) = levels.last() else { break };
            let next = resize_bilinear(prev, w, h);
            levels.push(next);
        }
        levels
    }

    fn process_level(
        &self,
        plane: &Plane,
        level: usize,
        quota: usize,
        sx: f32,
        sy: f32,
    ) -> (Vec<Keypoint>, Vec<[u64; 4]>, OrbLevelReport) {
        let mut report = OrbLevelReport { width: plane.width, height: plane.height, quota, ..Default::default() };
        let e = self.opts.edge_threshold;
        if quota == 0 || plane.width <= 2 * e || plane.height <= 2 * e {
            return (Vec::new(), Vec::new(), report);
        }
        // Keypoint area [e, w - e) x [e, h - e): every read below (FAST 3 px,
        // Harris 4 px, orientation 15 px, descriptor 18 px) stays in bounds.
        let (x0, x1, y0, y1) = (e, plane.width - e, e, plane.height - e);
        let t0 = Instant::now();
        if self.opts.selection == Selection::Strongest {
            let chosen = self.select_strongest(plane, (x0, x1, y0, y1), quota, &mut report);
            return self.describe_level(plane, level, chosen, sx, sy, report);
        }
        let mut fast = FastMap::new(plane);
        fast.detect(plane, (x0, x1, y0, y1), self.opts.ini_fast_threshold);

        // Grid cells (ORB-SLAM: about cell_size px, evenly dividing the area).
        let (aw, ah) = (x1 - x0, y1 - y0);
        let ncols = (aw / self.opts.cell_size).max(1);
        let nrows = (ah / self.opts.cell_size).max(1);
        let cw = aw.div_ceil(ncols);
        let ch = ah.div_ceil(nrows);
        let mut occupied = vec![false; ncols * nrows];
        for &ci in &fast.corners {
            let (x, y) = (ci as usize % plane.width, ci as usize / plane.width);
            let cell = ((y - y0) / ch).min(nrows - 1) * ncols + ((x - x0) / cw).min(ncols - 1);
            if let Some(o) = occupied.get_mut(cell) {
                *o = true;
            }
        }
        let strong = fast.suppress(plane.width);
        report.strong_candidates = strong.len();
        let use_fallback = self.opts.min_fast_threshold < self.opts.ini_fast_threshold
            && match self.opts.fallback {
                FallbackMode::Always => true,
                FallbackMode::WhenShort => strong.len() < quota,
            };
        if use_fallback {
            // One band of grid rows at a time, over the full width, testing
            // only the columns of empty cells.
            for (cr, band) in occupied.chunks(ncols).enumerate() {
                let empty = band.iter().filter(|&&o| !o).count();
                if empty == 0 {
                    continue;
                }
                report.fallback_cells += empty;
                let cy0 = y0 + cr * ch;
                let rect = (x0, x1, cy0, (cy0 + ch).min(y1));
                let keep = |x: usize| band.get(((x - x0) / cw).min(ncols - 1)).is_some_and(|&o| !o);
                fast.detect_where(plane, rect, self.opts.min_fast_threshold, keep);
            }
        }
        report.detect_ms = ms_since(t0);
        let t1 = Instant::now();
        let corners = if report.fallback_cells > 0 { fast.suppress(plane.width) } else { strong };
        report.candidates = corners.len();

        let w = plane.width;
        let ini = self.opts.ini_fast_threshold;
        let mut strong_cands = Vec::new();
        let mut weak_cands = Vec::new();
        for &ci in &corners {
            let (x, y) = (ci as usize % w, ci as usize / w);
            let fast_score = fast.score.get(ci as usize).copied().unwrap_or(0);
            let response = match self.opts.score {
                ScoreType::Harris => harris_response(plane, x, y, self.opts.harris_k),
                ScoreType::Fast => fast_score as f32,
            };
            let c = Candidate { x: x as u32, y: y as u32, response };
            // A corner at threshold t has a FAST score above t.
            if fast_score > ini { strong_cands.push(c) } else { weak_cands.push(c) }
        }
        report.score_ms = ms_since(t1);
        let t2 = Instant::now();
        let area = (x0 as f32, x1 as f32, y0 as f32, y1 as f32);
        let chosen = match self.opts.fallback {
            FallbackMode::Always => {
                strong_cands.extend(weak_cands);
                distribute_quadtree(&strong_cands, area, quota)
            }
            FallbackMode::WhenShort if strong_cands.len() >= quota => distribute_quadtree(&strong_cands, area, quota),
            FallbackMode::WhenShort => {
                // Keep every strong corner; weak ones only fill the rest.
                let fill = distribute_quadtree(&weak_cands, area, quota - strong_cands.len());
                strong_cands.extend(fill);
                strong_cands
            }
        };
        report.kept = chosen.len();
        if chosen.is_empty() {
            return (Vec::new(), Vec::new(), report);
        }
        report.distribute_ms = ms_since(t2);
        self.describe_level(plane, level, chosen, sx, sy, report)
    }

    /// [`Selection::Strongest`]: FAST at `ini_fast_threshold` over the level
    /// (again at `min_fast_threshold` when the fallback applies), 3x3
    /// non-maximum suppression, the [`PRESELECT_FACTOR`] x quota best by FAST
    /// score, then the quota best by the chosen [`ScoreType`]. This is the
    /// selection of OpenCV's ORB (`modules/features2d/src/orb.cpp`), which
    /// Rublee et al. (2011, section 3.1) describe.
    fn select_strongest(
        &self,
        plane: &Plane,
        rect: (usize, usize, usize, usize),
        quota: usize,
        report: &mut OrbLevelReport,
    ) -> Vec<Candidate> {
        let t0 = Instant::now();
        let mut fast = FastMap::new(plane);
        let (ini, min) = (self.opts.ini_fast_threshold, self.opts.min_fast_threshold);
        // `Always`: one pass at the lower threshold (it finds the corners of
        // the initial one too, with the same scores).
        let first = if self.opts.fallback == FallbackMode::Always { min } else { ini };
        fast.detect(plane, rect, first);
        let mut corners = fast.suppress(plane.width);
        report.strong_candidates =
            corners.iter().filter(|&&ci| fast.score.get(ci as usize).is_some_and(|&s| s > ini)).count();
        // Short of the quota: the whole level again, first at the threshold
        // halfway down (usually enough, and a pass at the lowest threshold
        // costs about three times one at the initial threshold on these
        // frames), then at the lowest.
        let mid = ((ini as u16 + min as u16) / 2) as u8;
        let mut last = first;
        for t in [mid, min] {
            if t < last && corners.len() < quota {
                fast.reset();
                fast.detect(plane, rect, t);
                corners = fast.suppress(plane.width);
                last = t;
            }
        }
        if last < ini {
            let (ncols, nrows) = self.grid(rect);
            report.fallback_cells = ncols * nrows;
        }
        report.detect_ms = ms_since(t0);
        report.candidates = corners.len();
        let t1 = Instant::now();
        let w = plane.width;
        let mut cands: Vec<Candidate> = corners
            .iter()
            .map(|&ci| Candidate {
                x: (ci as usize % w) as u32,
                y: (ci as usize / w) as u32,
                response: fast.score.get(ci as usize).copied().unwrap_or(0) as f32,
            })
            .collect();
        keep_best(&mut cands, PRESELECT_FACTOR * quota);
        if self.opts.score == ScoreType::Harris {
            for c in cands.iter_mut() {
                c.response = harris_response(plane, c.x as usize, c.y as usize, self.opts.harris_k);
            }
        }
        keep_best(&mut cands, quota);
        // Raster order, as the other selection returns them.
        cands.sort_unstable_by_key(|c| (c.y, c.x));
        report.score_ms = ms_since(t1);
        cands
    }

    /// Fallback grid over the keypoint area: (columns, rows) of cells of
    /// about `cell_size` pixels.
    fn grid(&self, rect: (usize, usize, usize, usize)) -> (usize, usize) {
        let (x0, x1, y0, y1) = rect;
        (((x1 - x0) / self.opts.cell_size).max(1), ((y1 - y0) / self.opts.cell_size).max(1))
    }

    fn describe_level(
        &self,
        plane: &Plane,
        level: usize,
        chosen: Vec<Candidate>,
        sx: f32,
        sy: f32,
        mut report: OrbLevelReport,
    ) -> (Vec<Keypoint>, Vec<[u64; 4]>, OrbLevelReport) {
        report.kept = chosen.len();
        let t3 = Instant::now();
        let blurred = gaussian_blur7(plane);
        let mut kps = Vec::with_capacity(chosen.len());
        let mut descs = Vec::with_capacity(chosen.len());
        let scale = (sx * sy).sqrt();
        for c in chosen {
            let (x, y) = (c.x as usize, c.y as usize);
            let angle = self.orientation(plane, x, y);
            descs.push(describe(&blurred, x, y, angle));
            // The integer path keeps its f32 arithmetic, so default keypoints
            // stay bit for bit what they were before the option existed.
            let (kx, ky) = if self.opts.subpixel {
                let (rx, ry) = subpixel::refine(plane, x, y);
                (((rx + 0.5) * sx as f64 - 0.5) as f32, ((ry + 0.5) * sy as f64 - 0.5) as f32)
            } else {
                ((c.x as f32 + 0.5) * sx - 0.5, (c.y as f32 + 0.5) * sy - 0.5)
            };
            kps.push(Keypoint {
                x: kx,
                y: ky,
                octave: level as u8,
                angle,
                response: c.response,
                size: PATCH_SIZE * scale,
            });
        }
        report.describe_ms = ms_since(t3);
        (kps, descs, report)
    }

    /// Intensity-centroid orientation in degrees `[0, 360)` over the disc of
    /// radius [`ORIENTATION_RADIUS`] (Rosin 1999; Rublee et al. 2011 eq. 2-3).
    /// `(x, y)` must lie at least that radius inside the plane.
    fn orientation(&self, plane: &Plane, x: usize, y: usize) -> f32 {
        orientation(plane, x, y, &self.disc_u, &self.disc_v)
    }
}

impl FeatureExtractor for OrbExtractor {
    fn name(&self) -> &str {
        "orb"
    }

    fn extract(&self, gray: &Image) -> Result<Features, FeatureError> {
        self.extract_with_report(gray).map(|(f, _)| f)
    }
}

/// Half-width of the orientation disc per row offset `v = 0..=radius`.
/// Disc of radius r: `|u|^2 + v^2 <= r^2 + r`, i.e. distance rounded to r.
/// The set is symmetric under swapping u and v, so the moments do not
/// favour an axis.
fn disc_half_widths() -> Vec<isize> {
    let r = ORIENTATION_RADIUS as isize;
    (0..=r)
        .map(|v| {
            let mut u = 0;
            while (u + 1) * (u + 1) + v * v <= r * r + r {
                u += 1;
            }
            u
        })
        .collect()
}

/// Keypoints per level in geometric proportion (ORB-SLAM): level l gets
/// `n (1 - 1/s) / (1 - (1/s)^L) * (1/s)^l`, rounded, and the last level the
/// remainder, so the quotas sum to `n`.
pub(crate) fn level_quotas(n: usize, scale_factor: f32, n_levels: usize) -> Vec<usize> {
    let f = 1.0 / scale_factor as f64;
    let mut per = n as f64 * (1.0 - f) / (1.0 - f.powi(n_levels as i32));
    let mut out = Vec::with_capacity(n_levels);
    let mut sum = 0usize;
    for _ in 0..n_levels.saturating_sub(1) {
        let q = (per.round() as usize).min(n - sum);
        out.push(q);
        sum += q;
        per *= f;
    }
    out.push(n - sum);
    out
}

/// Keeps the `n` candidates of highest response (ties: the earlier in
/// raster order wins), in no particular order.
fn keep_best(cands: &mut Vec<Candidate>, n: usize) {
    if cands.len() <= n {
        return;
    }
    let stronger_first =
        |a: &Candidate, b: &Candidate| b.response.total_cmp(&a.response).then((a.y, a.x).cmp(&(b.y, b.x)));
    if n > 0 {
        cands.select_nth_unstable_by(n - 1, stronger_first);
    }
    cands.truncate(n);
}

#[derive(Debug, Clone, Copy)]
struct Candidate {
    x: u32,
    y: u32,
    response: f32,
}

/// Harris response on a 7x7 window with 3x3 Sobel gradients, gradients
/// normalised to [-1, 1] and the structure tensor averaged over the window,
/// so the value does not depend on the window size. `(x, y)` must lie at
/// least 4 px inside the plane (guaranteed by the edge threshold).
#[inline(always)]
fn harris_kernel(p: &Plane, x: usize, y: usize, k: f32) -> f32 {
    let w = p.width;
    let r = HARRIS_HALF_BLOCK as usize;
    // Rows y - r - 1 ..= y + r + 1 and columns x - r - 1 ..= x + r + 1.
    let span = 2 * r + 3;
    let (Some(top), Some(left)) = ((y + 1).checked_sub(r + 2), (x + 1).checked_sub(r + 2)) else { return 0.0 };
    let row = |yy: usize| p.data.get((top + yy) * w + left..(top + yy) * w + left + span);
    let (mut a, mut b, mut c) = (0i64, 0i64, 0i64);
    for dy in 0..2 * r + 1 {
        let (Some(r0), Some(r1), Some(r2)) = (row(dy), row(dy + 1), row(dy + 2)) else { return 0.0 };
        for i in 0..2 * r + 1 {
            // Window of columns i..i+3 around centre column i + 1.
            let (Some(u), Some(m), Some(d)) = (r0.get(i..i + 3), r1.get(i..i + 3), r2.get(i..i + 3)) else {
                return 0.0;
            };
            let (u0, u1, u2) = (u[0] as i32, u[1] as i32, u[2] as i32);
            let (m0, m2) = (m[0] as i32, m[2] as i32);
            let (d0, d1, d2) = (d[0] as i32, d[1] as i32, d[2] as i32);
            let ix = (m2 - m0) * 2 + (u2 - u0) + (d2 - d0);
            let iy = (d1 - u1) * 2 + (d0 - u0) + (d2 - u2);
            a += (ix * ix) as i64;
            b += (iy * iy) as i64;
            c += (ix * iy) as i64;
        }
    }
    let side = (2 * HARRIS_HALF_BLOCK + 1) as f64;
    // Sobel's largest response is 4 * 255.
    let norm = 1.0 / (side * side * (4.0 * 255.0) * (4.0 * 255.0));
    let (a, b, c) = (a as f64 * norm, b as f64 * norm, c as f64 * norm);
    (a * b - c * c - k as f64 * (a + b) * (a + b)) as f32
}

crate::simd::multiversion!(harris_response, harris_kernel, (p: &Plane, x: usize, y: usize, k: f32) -> f32);

/// A quadtree node over `[x0, x1) x [y0, y1)` owning `idx[start..end]`.
#[derive(Debug, Clone, Copy)]
struct Node {
    x0: f32,
    x1: f32,
    y0: f32,
    y1: f32,
    start: usize,
    end: usize,
    alive: bool,
}

/// ORB-SLAM's `DistributeOctTree`, reformulated: start from `round(w / h)`
/// side-by-side nodes, then repeatedly split the node holding the most
/// candidates into four (dropping empty children) until there are at least
/// `target` nodes or no node can be split; keep the best-scored candidate of
/// each node, then the `target` best overall. Splitting the fullest node
/// first spreads keypoints like ORB-SLAM's breadth-first rounds do, and is
/// deterministic (ties broken by node creation order).
fn distribute_quadtree(cands: &[Candidate], area: (f32, f32, f32, f32), target: usize) -> Vec<Candidate> {
    use std::collections::BinaryHeap;
    if cands.is_empty() || target == 0 {
        return Vec::new();
    }
    let (ax0, ax1, ay0, ay1) = area;
    let n_ini = (((ax1 - ax0) / (ay1 - ay0)).round() as usize).clamp(1, cands.len().max(1));
    let hx = (ax1 - ax0) / n_ini as f32;
    let mut idx: Vec<u32> = (0..cands.len() as u32).collect();
    let col = |c: &Candidate| (((c.x as f32 - ax0) / hx) as usize).min(n_ini - 1);
    idx.sort_by_key(|&i| cands.get(i as usize).map(col).unwrap_or(0));
    let mut nodes: Vec<Node> = Vec::new();
    let mut start = 0;
    for k in 0..n_ini {
        let mut end = start;
        while end < idx.len() && idx.get(end).and_then(|&i| cands.get(i as usize)).map(col) == Some(k) {
            end += 1;
        }
        if end > start {
            let x0 = ax0 + hx * k as f32;
            nodes.push(Node { x0, x1: x0 + hx, y0: ay0, y1: ay1, start, end, alive: true });
        }
        start = end;
    }
    // Max-heap on (count, -id): the fullest node first, oldest among equals.
    let mut heap: BinaryHeap<(usize, std::cmp::Reverse<usize>)> = BinaryHeap::new();
    let splittable = |n: &Node| n.end - n.start > 1 && n.x1 - n.x0 >= 1.0 && n.y1 - n.y0 >= 1.0;
    for (id, n) in nodes.iter().enumerate() {
        if splittable(n) {
            heap.push((n.end - n.start, std::cmp::Reverse(id)));
        }
    }
    let mut alive = nodes.len();
    // First node id created by the latest split.
    let mut last_split = usize::MAX;
    while alive < target {
        let Some((_, std::cmp::Reverse(id))) = heap.pop() else { break };
        let Some(&parent) = nodes.get(id) else { break };
        let mx = 0.5 * (parent.x0 + parent.x1);
        let my = 0.5 * (parent.y0 + parent.y1);
        let quadrant = |i: u32| {
            cands.get(i as usize).map(|c| (c.x as f32 >= mx) as usize + 2 * (c.y as f32 >= my) as usize).unwrap_or(0)
        };
        let Some(slice) = idx.get_mut(parent.start..parent.end) else { break };
        slice.sort_by_key(|&i| quadrant(i));
        let mut counts = [0usize; 4];
        for &i in slice.iter() {
            counts[quadrant(i)] += 1;
        }
        if let Some(p) = nodes.get_mut(id) {
            p.alive = false;
        }
        alive -= 1;
        last_split = nodes.len();
        let mut s = parent.start;
        for (q, &cnt) in counts.iter().enumerate() {
            if cnt == 0 {
                continue;
            }
            let (x0, x1) = if q & 1 == 0 { (parent.x0, mx) } else { (mx, parent.x1) };
            let (y0, y1) = if q & 2 == 0 { (parent.y0, my) } else { (my, parent.y1) };
            let child = Node { x0, x1, y0, y1, start: s, end: s + cnt, alive: true };
            s += cnt;
            let cid = nodes.len();
            if splittable(&child) {
                heap.push((cnt, std::cmp::Reverse(cid)));
            }
            nodes.push(child);
            alive += 1;
        }
    }
    // Best candidate of every alive node, with its node id.
    let mut best: Vec<(Candidate, u32, usize)> = nodes
        .iter()
        .enumerate()
        .filter(|(_, n)| n.alive)
        .filter_map(|(id, n)| {
            idx.get(n.start..n.end)?
                .iter()
                .filter_map(|&i| cands.get(i as usize).map(|c| (*c, i, id)))
                .max_by(|a, b| a.0.response.total_cmp(&b.0.response).then(b.1.cmp(&a.1)))
        })
        .collect();
    let weaker_first = |a: &(Candidate, u32, usize), b: &(Candidate, u32, usize)| {
        a.0.response.total_cmp(&b.0.response).then(b.1.cmp(&a.1))
    };
    // The last split may overshoot the target by up to 3 nodes: drop the
    // weakest of its children, which sit in the densest region, so the
    // spread elsewhere is kept (ORB-SLAM keeps the overshoot instead).
    while best.len() > target {
        let victim = best
            .iter()
            .enumerate()
            .filter(|(_, b)| b.2 >= last_split)
            .min_by(|a, b| weaker_first(a.1, b.1))
            .map(|(k, _)| k);
        match victim {
            Some(k) if best.iter().filter(|b| b.2 >= last_split).count() > 1 => {
                best.remove(k);
            }
            _ => break,
        }
    }
    if best.len() > target {
        best.sort_by(|a, b| weaker_first(b, a));
        best.truncate(target);
    }
    best.into_iter().map(|(c, _, _)| c).collect()
}

/// Intensity-centroid orientation in degrees `[0, 360)` over the disc of
/// radius [`ORIENTATION_RADIUS`] (Rosin 1999; Rublee et al. 2011 eq. 2-3),
/// with the per-row weight tables of [`OrbExtractor`]. `(x, y)` must lie at
/// least that radius (plus one column) inside the plane; 0 otherwise.
#[inline(always)]
fn orientation_kernel(
    plane: &Plane,
    x: usize,
    y: usize,
    disc_u: &[[i16; DISC_LANES]],
    disc_v: &[[i16; DISC_LANES]],
) -> f32 {
    const R: usize = ORIENTATION_RADIUS;
    let w = plane.width;
    let d = &plane.data;
    // Fixed-width rows of DISC_LANES pixels starting at x - R, weighted by
    // the per-row tables (zero outside the disc): no loop tails, so the
    // whole sum vectorises.
    let row = |yy: usize| -> Option<&[u8; DISC_LANES]> {
        let start = yy * w + x.checked_sub(R)?;
        d.get(start..start + DISC_LANES)?.try_into().ok()
    };
    let (mut acc10, mut acc01) = ([0i32; DISC_LANES], [0i32; DISC_LANES]);
    let zeros = [0u8; DISC_LANES];
    for (v, (wu, wv)) in disc_u.iter().zip(disc_v).enumerate() {
        let (Some(up), Some(down)) = (y.checked_sub(v).and_then(row), row(y + v)) else { return 0.0 };
        // The centre row (v = 0) is counted once.
        let down = if v == 0 { &zeros } else { down };
        for i in 0..DISC_LANES {
            let (a, b) = (up[i] as i32, down[i] as i32);
            // |u| <= 15, v <= 15, 16 rows: at most 15 * 510 * 16 per lane.
            acc10[i] += wu[i] as i32 * (a + b);
            acc01[i] += wv[i] as i32 * (b - a);
        }
    }
    let m10: i64 = acc10.iter().map(|&s| s as i64).sum();
    let m01: i64 = acc01.iter().map(|&s| s as i64).sum();
    let a = (m01 as f32).atan2(m10 as f32).to_degrees();
    let a = if a < 0.0 { a + 360.0 } else { a };
    // atan2 of a tiny negative y can round to exactly 360.
    if a >= 360.0 { 0.0 } else { a }
}

crate::simd::multiversion!(orientation, orientation_kernel, (plane: &Plane, x: usize, y: usize, disc_u: &[[i16; DISC_LANES]], disc_v: &[[i16; DISC_LANES]]) -> f32);

/// Steered BRIEF: the pattern rotated by `angle_deg`, samples rounded to the
/// nearest pixel of the smoothed level; bit i is set when the first sample of
/// pair i is darker than the second. `(x, y)` must lie at least 19 px inside
/// the plane (samples reach 18 px); out-of-range reads return 0 instead of
/// panicking.
#[inline(always)]
fn describe_kernel(blurred: &Plane, x: usize, y: usize, angle_deg: f32) -> [u64; 4] {
    let (s, c) = angle_deg.to_radians().sin_cos();
    // Fixed-point rotation (12 fractional bits; error < 0.01 px at the
    // pattern's 18 px reach), rounding half up with a shift.
    let cs = (c * ROT_ONE as f32).round() as i32;
    let sn = (s * ROT_ONE as f32).round() as i32;
    // Copy the (2 * PATTERN_REACH + 1)^2 patch around the keypoint into a
    // fixed buffer: sample indices then need no bounds check (masked to the
    // buffer size, which they never exceed).
    const SIDE: usize = 2 * PATTERN_REACH + 1;
    let mut patch = [0u8; PATCH_BUF];
    let (Some(x0), Some(y0)) = (x.checked_sub(PATTERN_REACH), y.checked_sub(PATTERN_REACH)) else {
        return [0; 4];
    };
    for (r, dst) in patch.chunks_exact_mut(SIDE).take(SIDE).enumerate() {
        let start = (y0 + r) * blurred.width + x0;
        let Some(src) = blurred.data.get(start..start + SIDE) else { return [0; 4] };
        dst.copy_from_slice(src);
    }
    let centre = (PATTERN_REACH * SIDE + PATTERN_REACH) as i32;
    // Offsets of the first and second samples of every pair, rotated (a
    // vectorisable loop).
    let mut off1 = [0i32; ORB_BITS];
    let mut off2 = [0i32; ORB_BITS];
    for ((o1, o2), p) in off1.iter_mut().zip(off2.iter_mut()).zip(ORB_PATTERN.iter()) {
        let [x1, y1, x2, y2] = p.map(|v| v as i32);
        let rot = |px: i32, py: i32| {
            let rx = (px * cs - py * sn + ROT_ONE / 2) >> ROT_BITS;
            let ry = (px * sn + py * cs + ROT_ONE / 2) >> ROT_BITS;
            centre + ry * SIDE as i32 + rx
        };
        *o1 = rot(x1, y1);
        *o2 = rot(x2, y2);
    }
    // Rotated samples lie within PATTERN_REACH of the centre in x and y, so
    // every index is inside the copied patch; the mask only lets the
    // compiler drop the bounds check.
    let at = |o: i32| patch[o as usize & (PATCH_BUF - 1)];
    // Gather the samples, then compare them in bulk (vectorised).
    let first = off1.map(at);
    let second = off2.map(at);
    let mut out = [0u64; 4];
    for (word, (a, b)) in out.iter_mut().zip(first.chunks_exact(64).zip(second.chunks_exact(64))) {
        let mut bits = 0u64;
        for (bit, (&a, &b)) in a.iter().zip(b).enumerate() {
            bits |= ((a < b) as u64) << bit;
        }
        *word = bits;
    }
    out
}

crate::simd::multiversion!(describe, describe_kernel, (blurred: &Plane, x: usize, y: usize, angle_deg: f32) -> [u64; 4]);

#[cfg(test)]
mod tests {
    use super::*;

    /// Gaussian blobs at known sub-pixel centres, of sizes seen at every
    /// pyramid level: (image, centres).
    fn blob_image(w: usize, h: usize) -> (Image, Vec<(f64, f64)>) {
        let mut rng = colslam_geometry::SplitMix64::new(14);
        let sigmas = [1.6, 2.3, 3.2, 4.5];
        let spacing = 48;
        let mut blobs = Vec::new();
        for (j, cy) in (spacing..h - spacing / 2).step_by(spacing).enumerate() {
            for (i, cx) in (spacing..w - spacing / 2).step_by(spacing).enumerate() {
                let (dx, dy) = (rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5));
                blobs.push((cx as f64 + dx, cy as f64 + dy, sigmas[(i + 2 * j) % sigmas.len()]));
            }
        }
        let mut data = vec![0u8; w * h];
        for (k, v) in data.iter_mut().enumerate() {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            let mut f = 40.0;
            for &(bx, by, s) in &blobs {
                let d2 = (x - bx).powi(2) + (y - by).powi(2);
                if d2 < 36.0 * s * s {
                    f += 180.0 * (-d2 / (2.0 * s * s)).exp();
                }
            }
            *v = f.round().clamp(0.0, 255.0) as u8;
        }
        (Image::from_vec(w, h, 1, data).unwrap(), blobs.iter().map(|&(x, y, _)| (x, y)).collect())
    }

    /// Per level: (keypoints near a blob, median distance to its centre in
    /// level pixels).
    fn blob_errors(subpixel: bool) -> Vec<(usize, f64)> {
        let (img, centres) = blob_image(640, 480);
        let opts = OrbOptions { subpixel, n_features: 2000, ..Default::default() };
        let (f, _) = OrbExtractor::new(opts).unwrap().extract_with_report(&img).unwrap();
        let mut per = vec![Vec::new(); 8];
        for kp in &f.keypoints {
            let scale = 1.2f64.powi(kp.octave as i32);
            let d = centres
                .iter()
                .map(|&(x, y)| ((kp.x as f64 - x).powi(2) + (kp.y as f64 - y).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            // Within one level pixel: the blob's own detection.
            if d < scale {
                per[kp.octave as usize].push(d / scale);
            }
        }
        per.iter().map(|v| (v.len(), colslam_geometry::stats::median_finite(v).unwrap_or(f64::NAN))).collect()
    }

    /// A blob centred between pixels is found there at every level: the
    /// sub-pixel refinement and the pixel-centre mapping to full resolution
    /// put the median keypoint within 0.3 level pixels of the true centre
    /// (0.06-0.27 measured, the most at level 0 where the largest blobs
    /// exceed the refinement's window; integer positions 0.3-0.6, and a
    /// wrong mapping such as OpenCV's `x * s` is off by up to `(s - 1) / 2`
    /// px).
    #[test]
    fn subpixel_keypoints_find_blob_centres_at_every_level() {
        let refined = blob_errors(true);
        let integer = blob_errors(false);
        for (level, (&(n, e), &(n0, e0))) in refined.iter().zip(&integer).enumerate() {
            assert!(n >= 5 && n0 >= 5, "level {level}: {n} / {n0} blob keypoints");
            assert!(e < 0.3 && e < 0.6 * e0, "level {level}: median error {e:.3} level px (integer {e0:.3})");
            assert!(e0 > 0.25, "level {level}: integer positions {e0:.3} level px");
        }
    }

    #[test]
    fn quotas_sum_and_decrease() {
        let q = level_quotas(1000, 1.2, 8);
        assert_eq!(q.len(), 8);
        assert_eq!(q.iter().sum::<usize>(), 1000);
        assert_eq!(q[0], 217); // 1000 * (1 - 1/1.2) / (1 - 1.2^-8) = 217.2
        assert!(q.windows(2).take(6).all(|w| w[0] > w[1]));
        assert_eq!(level_quotas(1, 1.2, 8).iter().sum::<usize>(), 1);
        assert_eq!(level_quotas(5, 1.2, 1), vec![5]);
    }

    #[test]
    fn options_validation() {
        assert!(OrbOptions::default().validate().is_ok());
        let bad = [
            OrbOptions { n_features: 0, ..Default::default() },
            OrbOptions { scale_factor: 1.0, ..Default::default() },
            OrbOptions { scale_factor: f32::NAN, ..Default::default() },
            OrbOptions { n_levels: 0, ..Default::default() },
            OrbOptions { min_fast_threshold: 30, ..Default::default() },
            OrbOptions { edge_threshold: 10, ..Default::default() },
            OrbOptions { cell_size: 2, ..Default::default() },
            OrbOptions { harris_k: -1.0, ..Default::default() },
        ];
        for o in bad {
            let e = OrbExtractor::new(o.clone()).unwrap_err();
            assert!(e.to_string().contains("ORB"), "{o:?}: {e}");
        }
    }

    #[test]
    fn orientation_disc_is_round() {
        let umax = disc_half_widths();
        assert_eq!(umax[0], 15);
        assert_eq!(umax[15], 3); // 3^2 + 15^2 = 234 <= 240 < 4^2 + 15^2
        // Symmetric: the number of rows reaching |u| >= k equals umax[k] + 1
        // style transposition property: (u, v) in disc <=> (v, u) in disc.
        for v in 0..=15usize {
            for u in 0..=15usize {
                let inside = u as isize <= umax[v];
                let transposed = v as isize <= umax[u];
                assert_eq!(inside, transposed, "u={u} v={v}");
            }
        }
    }

    /// A textured plane from a seeded generator (smooth blobs plus noise).
    fn random_plane(w: usize, h: usize, seed: u64) -> Plane {
        let mut state = seed;
        let data = (0..w * h)
            .map(|i| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let smooth = 100.0 + 60.0 * (x / 7.0).sin() * (y / 5.0).cos();
                (smooth + (state >> 58) as f64) as u8
            })
            .collect();
        Plane { width: w, height: h, data }
    }

    #[test]
    fn orientation_equals_the_disc_moments() {
        let e = OrbExtractor::new(OrbOptions::default()).unwrap();
        let p = random_plane(80, 70, 7);
        let umax = disc_half_widths();
        for (x, y) in [(19, 19), (40, 35), (60, 50), (33, 21)] {
            let (mut m10, mut m01) = (0i64, 0i64);
            for (v, &um) in umax.iter().enumerate() {
                let v = v as isize;
                for u in -um..=um {
                    for (vv, counted) in [(v, true), (-v, v != 0)] {
                        if counted {
                            let val = p.data[(y as isize + vv) as usize * p.width + (x as isize + u) as usize] as i64;
                            m10 += u as i64 * val;
                            m01 += vv as i64 * val;
                        }
                    }
                }
            }
            let want = (m01 as f32).atan2(m10 as f32).to_degrees().rem_euclid(360.0);
            let got = e.orientation(&p, x, y);
            let d = (got - want).abs();
            assert!(d.min(360.0 - d) < 1e-3, "({x},{y}): {got} vs {want}");
        }
    }

    #[test]
    fn descriptor_equals_the_rotated_pattern() {
        let p = random_plane(90, 80, 11);
        for (x, y, angle) in [(19usize, 19usize, 0.0f32), (45, 40, 33.0), (70, 60, 181.5), (30, 50, 359.0)] {
            let (s, c) = angle.to_radians().sin_cos();
            let (cs, sn) = ((c * ROT_ONE as f32).round() as i32, (s * ROT_ONE as f32).round() as i32);
            let sample = |px: i8, py: i8| {
                let (px, py) = (px as i32, py as i32);
                let rx = (px * cs - py * sn + ROT_ONE / 2) >> ROT_BITS;
                let ry = (px * sn + py * cs + ROT_ONE / 2) >> ROT_BITS;
                p.data[(y as i32 + ry) as usize * p.width + (x as i32 + rx) as usize]
            };
            let mut want = [0u64; 4];
            for (i, &[x1, y1, x2, y2]) in ORB_PATTERN.iter().enumerate() {
                if sample(x1, y1) < sample(x2, y2) {
                    want[i / 64] |= 1 << (i % 64);
                }
            }
            assert_eq!(describe(&p, x, y, angle), want, "({x},{y}) at {angle}");
        }
    }

    #[test]
    fn orientation_points_to_the_bright_side() {
        let e = OrbExtractor::new(OrbOptions::default()).unwrap();
        let (w, h) = (61usize, 61usize);
        // Bright half-plane x > 30: angle 0. Bright y > 30: angle 90.
        let px = Plane { width: w, height: h, data: (0..w * h).map(|i| if i % w > 30 { 200 } else { 10 }).collect() };
        let a = e.orientation(&px, 30, 30);
        assert!(!(1.0..=359.0).contains(&a), "{a}");
        let py = Plane { width: w, height: h, data: (0..w * h).map(|i| if i / w > 30 { 200 } else { 10 }).collect() };
        assert!((e.orientation(&py, 30, 30) - 90.0).abs() < 1.0);
    }

    #[test]
    fn quadtree_spreads_and_respects_target() {
        // A dense cluster in one corner and a few isolated points elsewhere.
        let mut cands = Vec::new();
        for y in 0..20u32 {
            for x in 0..20u32 {
                cands.push(Candidate { x: 20 + x, y: 20 + y, response: 10.0 + (x + y) as f32 });
            }
        }
        for (x, y) in [(300, 50), (500, 400), (100, 400), (600, 30)] {
            cands.push(Candidate { x, y, response: 1.0 });
        }
        let got = distribute_quadtree(&cands, (19.0, 621.0, 19.0, 461.0), 10);
        assert_eq!(got.len(), 10);
        // All four isolated points survive despite their low response.
        for (x, y) in [(300, 50), (500, 400), (100, 400), (600, 30)] {
            assert!(got.iter().any(|c| c.x == x && c.y == y), "({x},{y}) lost");
        }
        assert!(distribute_quadtree(&[], (0.0, 1.0, 0.0, 1.0), 5).is_empty());
        // Fewer candidates than the target: all are kept.
        assert_eq!(distribute_quadtree(&cands[..3], (19.0, 621.0, 19.0, 461.0), 10).len(), 3);
    }
}

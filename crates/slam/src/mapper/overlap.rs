//! Matching of overlapping keyframe pairs at the end of mapping
//! (`--match-overlapping`): a sequential pipeline matches each keyframe to a
//! few recent ones and to older ones looking the same way, so two keyframes
//! that see the same surface from different places and times (a path that
//! comes back to its start, photos taken around a building) are never
//! matched and their tracks stay apart. With the poses known, the map itself
//! says which pairs overlap: the points of one keyframe that project into the
//! other, in front of it and seen from a similar direction. Those pairs are
//! matched, the matches that agree with the poses go into the correspondence
//! graph, and the triangulator creates, continues and merges tracks through
//! them (COLMAP's retriangulation and track merging after an exhaustive or
//! vocabulary-tree matching; here the pose graph chooses the pairs).

use super::state::Mapper;
use crate::error::SlamError;
use crate::frontend::Frontend;
use crate::options::{
    GlobalBaTolerance, OVERLAP_MAX_ERROR_PX, OVERLAP_MAX_VIEW_ANGLE_DEG, OVERLAP_MIN_POINTS, SlamOptions,
};
use crate::timing::{Stage, StageTimings};
use colslam_scene::ImageId;
use colslam_scene::projection::project;
use colslam_sfm::triangulator::{complete_and_merge_all, retriangulate, triangulate_image};

/// What [`Mapper::match_overlapping_pairs`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OverlapReport {
    /// Keyframe pairs matched.
    pub pairs: usize,
    /// Correspondences they added to the graph.
    pub correspondences: usize,
    /// 3D points before and after triangulating through them.
    pub points: (usize, usize),
}

impl Mapper {
    /// Matches each keyframe with up to `opts.refine.match_overlapping`
    /// keyframes it was never matched with whose views overlap its own
    /// (most shared projections first), adds the verified matches to the
    /// correspondence graph and triangulates through them. The caller's
    /// global refinement then completes and merges tracks and adjusts.
    pub fn match_overlapping_pairs(
        &mut self,
        frontend: &Frontend,
        opts: &SlamOptions,
        timings: &mut StageTimings,
    ) -> Result<OverlapReport, SlamError> {
        let mut report = OverlapReport { points: (self.rec.num_points3d(), 0), ..OverlapReport::default() };
        let pairs = self.overlapping_pairs(opts.refine.match_overlapping)?;
        let focal = self.focal()?;
        let mut touched: Vec<ImageId> = Vec::new();
        for (a, b) in pairs {
            let (ka, kb) = (&self.keyframes[a], &self.keyframes[b]);
            let matches = timings.time(Stage::Matching, || frontend.match_frames(&kb.data, &ka.data))?;
            let image_id = kb.image_id;
            let Some(pose) = self.rec.image(image_id).map(|i| i.cam_from_world) else { continue };
            let verified = self.verified_matches(&kb.data, &pose, &vec![(a, matches)], focal, OVERLAP_MAX_ERROR_PX);
            let before = self.graph.num_correspondences_for_image(image_id);
            self.add_correspondences(image_id, &verified)?;
            report.correspondences += self.graph.num_correspondences_for_image(image_id) - before;
            report.pairs += 1;
            touched.extend([self.keyframes[a].image_id, image_id]);
        }
        touched.sort_unstable();
        touched.dedup();
        let tri = opts.mapper.triangulator();
        timings.time(Stage::Triangulation, || -> Result<(), SlamError> {
            for &id in &touched {
                triangulate_image(&mut self.rec, &self.graph, id, &tri)?;
            }
            retriangulate(&mut self.rec, &self.graph, Some(&touched), &tri)?;
            complete_and_merge_all(&mut self.rec, &self.graph, &tri)?;
            Ok(())
        })?;
        // New tracks through wide-baseline matches hold outliers that the
        // filter only finds after a bundle adjustment: adjust and filter
        // once here, so the caller's converged adjustment starts from the
        // filtered tracks (COLMAP iterates global refinement the same way).
        self.global_refine(GlobalBaTolerance::Periodic, opts, timings)?;
        report.points.1 = self.rec.num_points3d();
        tracing::debug!(
            "map {}: matched {} overlapping keyframe pairs, {} new correspondences, points {} -> {}",
            self.index,
            report.pairs,
            report.correspondences,
            report.points.0,
            report.points.1
        );
        Ok(report)
    }

    /// Keyframe pairs `(a, b)` (positions, `a < b`) without correspondences
    /// whose views overlap by at least [`OVERLAP_MIN_POINTS`] projections
    /// ([`Self::shared_projections`]), at most `per_keyframe` for each
    /// keyframe, most overlapping first (ties: lower positions).
    fn overlapping_pairs(&self, per_keyframe: usize) -> Result<Vec<(usize, usize)>, SlamError> {
        let n = self.keyframes.len();
        let mut candidates: Vec<(usize, usize, usize)> = Vec::new();
        for a in 0..n {
            for b in a + 1..n {
                let (ia, ib) = (self.keyframes[a].image_id, self.keyframes[b].image_id);
                if self.graph.num_correspondences_between(ia, ib) > 0 {
                    continue;
                }
                let shared = self.shared_projections(ia, ib)?.min(self.shared_projections(ib, ia)?);
                if shared >= OVERLAP_MIN_POINTS {
                    candidates.push((shared, a, b));
                }
            }
        }
        candidates.sort_by(|x, y| y.0.cmp(&x.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
        let mut taken = vec![0usize; n];
        let mut pairs = Vec::new();
        for (_, a, b) in candidates {
            if taken[a] < per_keyframe && taken[b] < per_keyframe {
                taken[a] += 1;
                taken[b] += 1;
                pairs.push((a, b));
            }
        }
        Ok(pairs)
    }

    /// How many 3D points observed in image `from` project inside image
    /// `into`, in front of it, seen from directions within
    /// [`OVERLAP_MAX_VIEW_ANGLE_DEG`] (beyond it ORB descriptors no longer
    /// match: they are not invariant to strong perspective change).
    fn shared_projections(&self, from: ImageId, into: ImageId) -> Result<usize, SlamError> {
        let camera = self.camera()?;
        let (Some(src), Some(dst)) = (self.rec.image(from), self.rec.image(into)) else { return Ok(0) };
        let (c_from, c_into) = (src.cam_from_world.center(), dst.cam_from_world.center());
        let cos_max = OVERLAP_MAX_VIEW_ANGLE_DEG.to_radians().cos();
        let (w, h) = (camera.width as f64, camera.height as f64);
        let count = src
            .points2d
            .iter()
            .filter_map(|p| p.point3d_id.and_then(|id| self.rec.point3d(id)))
            .filter(|p| {
                let Some(px) = project(camera, &dst.cam_from_world, &p.xyz) else { return false };
                let (r1, r2) = (p.xyz - c_from, p.xyz - c_into);
                let cos = r1.dot(&r2) / (r1.norm() * r2.norm());
                px.x >= 0.0 && px.y >= 0.0 && px.x < w && px.y < h && cos >= cos_max
            })
            .count();
        Ok(count)
    }
}

//! The correspondence graph: which keypoint of which image matches which
//! keypoint of another (after COLMAP's `src/colmap/scene/correspondence_graph.h`).
//!
//! COLMAP builds it once from a database of all matches; the sequential
//! pipeline grows it one keyframe at a time (the new keyframe's matches to
//! previous keyframes), so every operation here is incremental. Iteration
//! orders are deterministic.

use crate::SfmError;
use colslam_scene::ImageId;
use std::collections::BTreeMap;

/// One end of a correspondence: a keypoint of an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Correspondence {
    /// The image.
    pub image_id: ImageId,
    /// Index of the keypoint in that image.
    pub point2d_idx: u32,
}

impl Correspondence {
    /// Builds a correspondence end.
    pub fn new(image_id: ImageId, point2d_idx: u32) -> Self {
        Self { image_id, point2d_idx }
    }
}

#[derive(Debug, Clone, Default)]
struct ImageNode {
    /// Correspondences of each keypoint.
    corrs: Vec<Vec<Correspondence>>,
    /// Keypoints with at least one correspondence.
    num_observations: usize,
    /// Total correspondences of all keypoints.
    num_correspondences: usize,
}

/// Key of an unordered image pair: the smaller id first.
fn pair_key(a: ImageId, b: ImageId) -> (ImageId, ImageId) {
    if a <= b { (a, b) } else { (b, a) }
}

/// The 2D-2D correspondences between images.
#[derive(Debug, Clone, Default)]
pub struct CorrespondenceGraph {
    images: BTreeMap<ImageId, ImageNode>,
    /// Number of correspondences of each image pair that has any.
    pairs: BTreeMap<(ImageId, ImageId), usize>,
}

impl CorrespondenceGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds an image with `num_points2d` keypoints and no correspondences.
    pub fn add_image(&mut self, image_id: ImageId, num_points2d: usize) -> Result<(), SfmError> {
        if self.images.contains_key(&image_id) {
            return Err(SfmError::DuplicateImage(image_id));
        }
        self.images.insert(image_id, ImageNode { corrs: vec![Vec::new(); num_points2d], ..ImageNode::default() });
        Ok(())
    }

    /// True when the image is in the graph.
    pub fn exists_image(&self, image_id: ImageId) -> bool {
        self.images.contains_key(&image_id)
    }

    /// Number of images.
    pub fn num_images(&self) -> usize {
        self.images.len()
    }

    /// Number of image pairs with at least one correspondence.
    pub fn num_image_pairs(&self) -> usize {
        self.pairs.len()
    }

    fn node(&self, image_id: ImageId) -> Result<&ImageNode, SfmError> {
        self.images.get(&image_id).ok_or(SfmError::UnknownImage(image_id))
    }

    /// Adds the matches `(idx1, idx2)` between keypoints of `image1` and
    /// `image2`. Matches already present are skipped, as are repeated uses
    /// of a keypoint within this call (the first wins, as COLMAP does for
    /// duplicate matches). Returns how many correspondences were added.
    pub fn add_correspondences(
        &mut self,
        image1: ImageId,
        image2: ImageId,
        matches: &[(u32, u32)],
    ) -> Result<usize, SfmError> {
        if image1 == image2 {
            return Err(SfmError::SelfMatch(image1));
        }
        let len1 = self.node(image1)?.corrs.len();
        let len2 = self.node(image2)?.corrs.len();
        for &(i1, i2) in matches {
            if i1 as usize >= len1 {
                return Err(SfmError::KeypointOutOfRange { image: image1, idx: i1, len: len1 });
            }
            if i2 as usize >= len2 {
                return Err(SfmError::KeypointOutOfRange { image: image2, idx: i2, len: len2 });
            }
        }
        let mut added = Vec::with_capacity(matches.len());
        {
            let node1 = self.images.get(&image1).ok_or(SfmError::UnknownImage(image1))?;
            let mut used1 = std::collections::HashSet::new();
            let mut used2 = std::collections::HashSet::new();
            for &(i1, i2) in matches {
                // Bounds were checked above.
                let exists = node1.corrs[i1 as usize].iter().any(|c| c.image_id == image2);
                if exists || !used1.insert(i1) || !used2.insert(i2) {
                    continue;
                }
                added.push((i1, i2));
            }
        }
        if added.is_empty() {
            return Ok(0);
        }
        // A keypoint of image2 may already correspond to another keypoint of
        // image1 from an earlier call; COLMAP keeps both ends symmetric, and
        // so do we: skip such matches.
        let node2 = self.images.get(&image2).ok_or(SfmError::UnknownImage(image2))?;
        added.retain(|&(_, i2)| !node2.corrs[i2 as usize].iter().any(|c| c.image_id == image1));
        for (this, other, idx_this, idx_other) in [(image1, image2, 0usize, 1usize), (image2, image1, 1, 0)] {
            let node = self.images.get_mut(&this).ok_or(SfmError::UnknownImage(this))?;
            for m in &added {
                let (a, b) = ([m.0, m.1][idx_this], [m.0, m.1][idx_other]);
                let list = &mut node.corrs[a as usize];
                if list.is_empty() {
                    node.num_observations += 1;
                }
                list.push(Correspondence::new(other, b));
                node.num_correspondences += 1;
            }
        }
        *self.pairs.entry(pair_key(image1, image2)).or_insert(0) += added.len();
        Ok(added.len())
    }

    /// Removes an image and every correspondence that involves it, from
    /// both ends (keyframe culling; COLMAP's graph is never edited, as it is
    /// built once from a database). Returns how many correspondences of the
    /// image were removed.
    pub fn delete_image(&mut self, image_id: ImageId) -> Result<usize, SfmError> {
        let node = self.images.remove(&image_id).ok_or(SfmError::UnknownImage(image_id))?;
        for (idx, list) in node.corrs.iter().enumerate() {
            for c in list {
                let Some(other) = self.images.get_mut(&c.image_id) else { continue };
                let Some(back) = other.corrs.get_mut(c.point2d_idx as usize) else { continue };
                let before = back.len();
                back.retain(|b| !(b.image_id == image_id && b.point2d_idx as usize == idx));
                other.num_correspondences -= before - back.len();
                if before > 0 && back.is_empty() {
                    other.num_observations -= 1;
                }
            }
        }
        self.pairs.retain(|&(a, b), _| a != image_id && b != image_id);
        Ok(node.num_correspondences)
    }

    /// The correspondences of one keypoint (empty for an unknown image or index).
    pub fn correspondences(&self, image_id: ImageId, point2d_idx: u32) -> &[Correspondence] {
        self.images.get(&image_id).and_then(|n| n.corrs.get(point2d_idx as usize)).map_or(&[], Vec::as_slice)
    }

    /// True when the keypoint has at least one correspondence.
    pub fn has_correspondences(&self, image_id: ImageId, point2d_idx: u32) -> bool {
        !self.correspondences(image_id, point2d_idx).is_empty()
    }

    /// Number of keypoints of the image that have a correspondence.
    pub fn num_observations_for_image(&self, image_id: ImageId) -> usize {
        self.images.get(&image_id).map_or(0, |n| n.num_observations)
    }

    /// Number of correspondences of all keypoints of the image.
    pub fn num_correspondences_for_image(&self, image_id: ImageId) -> usize {
        self.images.get(&image_id).map_or(0, |n| n.num_correspondences)
    }

    /// Number of correspondences between two images.
    pub fn num_correspondences_between(&self, image1: ImageId, image2: ImageId) -> usize {
        self.pairs.get(&pair_key(image1, image2)).copied().unwrap_or(0)
    }

    /// All image pairs with their correspondence counts, smaller id first.
    pub fn image_pairs(&self) -> impl Iterator<Item = (ImageId, ImageId, usize)> + '_ {
        self.pairs.iter().map(|(&(a, b), &n)| (a, b, n))
    }

    /// The images that share correspondences with `image_id`, with counts,
    /// most connected first (ties by id).
    pub fn connected_images(&self, image_id: ImageId) -> Vec<(ImageId, usize)> {
        let mut out: BTreeMap<ImageId, usize> = BTreeMap::new();
        if let Some(node) = self.images.get(&image_id) {
            for list in &node.corrs {
                for c in list {
                    *out.entry(c.image_id).or_insert(0) += 1;
                }
            }
        }
        let mut v: Vec<(ImageId, usize)> = out.into_iter().collect();
        v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        v
    }

    /// The matches between two images as `(idx in image1, idx in image2)`,
    /// sorted by the first index.
    pub fn matches_between(&self, image1: ImageId, image2: ImageId) -> Vec<(u32, u32)> {
        let Some(node) = self.images.get(&image1) else { return Vec::new() };
        let mut out = Vec::new();
        for (i, list) in node.corrs.iter().enumerate() {
            for c in list {
                if c.image_id == image2 {
                    out.push((i as u32, c.point2d_idx));
                }
            }
        }
        out
    }

    /// Keypoints reachable from `(image_id, point2d_idx)` within
    /// `transitivity` hops of the graph, excluding the start (COLMAP's
    /// `ExtractTransitiveCorrespondences`). Breadth-first, so the order is
    /// deterministic: nearer hops first, then insertion order.
    pub fn transitive_correspondences(
        &self,
        image_id: ImageId,
        point2d_idx: u32,
        transitivity: usize,
    ) -> Vec<Correspondence> {
        let start = Correspondence::new(image_id, point2d_idx);
        if transitivity == 0 {
            return Vec::new();
        }
        if transitivity == 1 {
            return self.correspondences(image_id, point2d_idx).to_vec();
        }
        let mut seen = std::collections::HashSet::new();
        seen.insert(start);
        let mut out = Vec::new();
        let mut frontier = vec![start];
        for _ in 0..transitivity {
            let mut next = Vec::new();
            for c in &frontier {
                for &n in self.correspondences(c.image_id, c.point2d_idx) {
                    if seen.insert(n) {
                        out.push(n);
                        next.push(n);
                    }
                }
            }
            if next.is_empty() {
                break;
            }
            frontier = next;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph() -> CorrespondenceGraph {
        let mut g = CorrespondenceGraph::new();
        for i in 1..=3 {
            g.add_image(ImageId(i), 5).unwrap();
        }
        g
    }

    #[test]
    fn symmetric_counts() {
        let mut g = graph();
        assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(0, 1), (2, 3), (4, 4)]).unwrap(), 3);
        assert_eq!(g.num_correspondences_between(ImageId(1), ImageId(2)), 3);
        assert_eq!(g.num_correspondences_between(ImageId(2), ImageId(1)), 3);
        assert_eq!(g.correspondences(ImageId(2), 3), &[Correspondence::new(ImageId(1), 2)]);
        assert_eq!(g.num_observations_for_image(ImageId(1)), 3);
        assert_eq!(g.num_correspondences_for_image(ImageId(2)), 3);
        assert_eq!(g.matches_between(ImageId(2), ImageId(1)), vec![(1, 0), (3, 2), (4, 4)]);
        // Duplicates (same pair again, or a keypoint reused) are skipped.
        assert_eq!(g.add_correspondences(ImageId(2), ImageId(1), &[(1, 0), (0, 0)]).unwrap(), 0);
        assert_eq!(g.add_correspondences(ImageId(1), ImageId(3), &[(0, 0), (0, 1), (1, 0)]).unwrap(), 1);
        assert_eq!(g.num_correspondences_for_image(ImageId(1)), 4);
        assert_eq!(g.num_observations_for_image(ImageId(1)), 3);
        assert_eq!(g.num_image_pairs(), 2);
        assert_eq!(g.connected_images(ImageId(1)), vec![(ImageId(2), 3), (ImageId(3), 1)]);
    }

    #[test]
    fn transitive() {
        let mut g = graph();
        g.add_correspondences(ImageId(1), ImageId(2), &[(0, 0)]).unwrap();
        g.add_correspondences(ImageId(2), ImageId(3), &[(0, 0)]).unwrap();
        assert_eq!(g.transitive_correspondences(ImageId(1), 0, 1), vec![Correspondence::new(ImageId(2), 0)]);
        assert_eq!(
            g.transitive_correspondences(ImageId(1), 0, 2),
            vec![Correspondence::new(ImageId(2), 0), Correspondence::new(ImageId(3), 0)]
        );
        assert!(g.transitive_correspondences(ImageId(1), 1, 3).is_empty());
    }

    #[test]
    fn deleting_an_image_removes_its_correspondences_from_both_ends() {
        let mut g = graph();
        g.add_correspondences(ImageId(1), ImageId(2), &[(0, 0), (1, 1)]).unwrap();
        g.add_correspondences(ImageId(2), ImageId(3), &[(0, 0), (2, 2)]).unwrap();
        g.add_correspondences(ImageId(1), ImageId(3), &[(1, 4)]).unwrap();
        assert_eq!(g.delete_image(ImageId(2)).unwrap(), 4);
        assert!(!g.exists_image(ImageId(2)));
        assert_eq!(g.num_image_pairs(), 1);
        assert_eq!(g.num_correspondences_between(ImageId(1), ImageId(2)), 0);
        assert!(g.correspondences(ImageId(1), 0).is_empty());
        assert_eq!(g.correspondences(ImageId(1), 1), &[Correspondence::new(ImageId(3), 4)]);
        assert!(g.correspondences(ImageId(3), 0).is_empty() && g.correspondences(ImageId(3), 2).is_empty());
        assert_eq!((g.num_observations_for_image(ImageId(1)), g.num_correspondences_for_image(ImageId(1))), (1, 1));
        assert_eq!((g.num_observations_for_image(ImageId(3)), g.num_correspondences_for_image(ImageId(3))), (1, 1));
        assert_eq!(g.connected_images(ImageId(3)), vec![(ImageId(1), 1)]);
        assert!(matches!(g.delete_image(ImageId(2)), Err(SfmError::UnknownImage(_))));
        // The id can be added again, with no correspondences.
        g.add_image(ImageId(2), 5).unwrap();
        assert_eq!(g.num_correspondences_for_image(ImageId(2)), 0);
    }

    #[test]
    fn errors() {
        let mut g = graph();
        assert!(matches!(g.add_image(ImageId(1), 3), Err(SfmError::DuplicateImage(_))));
        assert!(matches!(g.add_correspondences(ImageId(1), ImageId(1), &[]), Err(SfmError::SelfMatch(_))));
        assert!(matches!(g.add_correspondences(ImageId(1), ImageId(9), &[]), Err(SfmError::UnknownImage(_))));
        assert!(matches!(
            g.add_correspondences(ImageId(1), ImageId(2), &[(5, 0)]),
            Err(SfmError::KeypointOutOfRange { idx: 5, .. })
        ));
        assert!(g.correspondences(ImageId(9), 0).is_empty());
        assert!(g.correspondences(ImageId(1), 99).is_empty());
    }
}

//! The correspondence graph's public API (after COLMAP's
//! `correspondence_graph_test.cc`).

use colslam_scene::ImageId;
use colslam_sfm::{Correspondence, CorrespondenceGraph, SfmError};

fn c(image: u32, idx: u32) -> Correspondence {
    Correspondence::new(ImageId(image), idx)
}

/// A graph with images `1..=sizes.len()` holding `sizes[i]` keypoints.
fn graph(sizes: &[usize]) -> CorrespondenceGraph {
    let mut g = CorrespondenceGraph::new();
    for (i, &n) in sizes.iter().enumerate() {
        g.add_image(ImageId(i as u32 + 1), n).unwrap();
    }
    g
}

#[test]
fn empty_graph_has_nothing() {
    let g = CorrespondenceGraph::new();
    assert_eq!(g.num_images(), 0);
    assert_eq!(g.num_image_pairs(), 0);
    assert_eq!(g.image_pairs().count(), 0);
    assert!(!g.exists_image(ImageId(1)));
    assert!(g.connected_images(ImageId(1)).is_empty());
    assert!(g.transitive_correspondences(ImageId(1), 0, 3).is_empty());
}

#[test]
fn added_images_exist_without_correspondences() {
    let g = graph(&[10, 4]);
    assert_eq!(g.num_images(), 2);
    assert!(g.exists_image(ImageId(1)) && g.exists_image(ImageId(2)) && !g.exists_image(ImageId(3)));
    assert_eq!(g.num_image_pairs(), 0);
    for i in 0..10 {
        assert!(!g.has_correspondences(ImageId(1), i));
    }
    assert_eq!(g.num_observations_for_image(ImageId(1)), 0);
    assert_eq!(g.num_correspondences_for_image(ImageId(2)), 0);
}

#[test]
fn two_view_lookup_is_symmetric() {
    let mut g = graph(&[10, 10]);
    let matches = [(0, 0), (1, 2), (3, 7), (4, 8)];
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &matches).unwrap(), 4);
    for &(i, j) in &matches {
        assert_eq!(g.correspondences(ImageId(1), i), &[c(2, j)]);
        assert_eq!(g.correspondences(ImageId(2), j), &[c(1, i)]);
        assert!(g.has_correspondences(ImageId(1), i) && g.has_correspondences(ImageId(2), j));
    }
    // Keypoints outside the matches have none (2 is matched in image 2 only).
    assert!(!g.has_correspondences(ImageId(1), 2));
    assert!(g.has_correspondences(ImageId(2), 2));
    assert!(!g.has_correspondences(ImageId(2), 1));
    assert_eq!(g.matches_between(ImageId(1), ImageId(2)), matches.to_vec());
    assert_eq!(g.matches_between(ImageId(2), ImageId(1)), vec![(0, 0), (2, 1), (7, 3), (8, 4)]);
    for (a, b) in [(1, 2), (2, 1)] {
        assert_eq!(g.num_correspondences_between(ImageId(a), ImageId(b)), 4);
    }
    for i in [1, 2] {
        assert_eq!(g.num_observations_for_image(ImageId(i)), 4);
        assert_eq!(g.num_correspondences_for_image(ImageId(i)), 4);
    }
    assert_eq!(g.image_pairs().collect::<Vec<_>>(), vec![(ImageId(1), ImageId(2), 4)]);
}

#[test]
fn three_view_counts_observations_and_correspondences() {
    // COLMAP's ThreeView case: keypoint 0 seen in all three images, keypoint 5 in 2 and 3.
    let mut g = graph(&[10, 10, 10]);
    g.add_correspondences(ImageId(1), ImageId(2), &[(0, 0)]).unwrap();
    g.add_correspondences(ImageId(1), ImageId(3), &[(0, 0)]).unwrap();
    g.add_correspondences(ImageId(2), ImageId(3), &[(0, 0), (5, 5)]).unwrap();
    let obs: Vec<usize> = (1..=3).map(|i| g.num_observations_for_image(ImageId(i))).collect();
    let corrs: Vec<usize> = (1..=3).map(|i| g.num_correspondences_for_image(ImageId(i))).collect();
    assert_eq!(obs, [1, 2, 2]);
    assert_eq!(corrs, [2, 3, 3]);
    assert_eq!(g.num_image_pairs(), 3);
    assert_eq!(g.num_correspondences_between(ImageId(3), ImageId(2)), 2);
    // Insertion order of a keypoint's correspondences is kept.
    assert_eq!(g.correspondences(ImageId(1), 0), &[c(2, 0), c(3, 0)]);
    assert_eq!(g.correspondences(ImageId(2), 0), &[c(1, 0), c(3, 0)]);
    assert_eq!(g.correspondences(ImageId(3), 0), &[c(1, 0), c(2, 0)]);
    assert_eq!(g.correspondences(ImageId(3), 5), &[c(2, 5)]);
}

#[test]
fn duplicate_image_is_refused_with_typed_error() {
    let mut g = graph(&[5, 5]);
    g.add_correspondences(ImageId(1), ImageId(2), &[(1, 1)]).unwrap();
    match g.add_image(ImageId(2), 99) {
        Err(SfmError::DuplicateImage(id)) => assert_eq!(id, ImageId(2)),
        other => panic!("expected DuplicateImage, got {other:?}"),
    }
    // The existing image keeps its keypoints and correspondences.
    assert_eq!(g.num_images(), 2);
    assert_eq!(g.correspondences(ImageId(2), 1), &[c(1, 1)]);
    assert!(matches!(
        g.add_correspondences(ImageId(1), ImageId(2), &[(0, 5)]),
        Err(SfmError::KeypointOutOfRange { .. })
    ));
}

#[test]
fn out_of_range_keypoint_is_refused_and_nothing_is_added() {
    // COLMAP's OutOfBounds case, where image 2 has only 4 keypoints.
    let mut g = graph(&[10, 4]);
    match g.add_correspondences(ImageId(1), ImageId(2), &[(9, 3), (10, 3), (9, 4)]) {
        Err(SfmError::KeypointOutOfRange { image, idx, len }) => assert_eq!((image, idx, len), (ImageId(1), 10, 10)),
        other => panic!("expected KeypointOutOfRange, got {other:?}"),
    }
    match g.add_correspondences(ImageId(1), ImageId(2), &[(9, 3), (8, 4)]) {
        Err(SfmError::KeypointOutOfRange { image, idx, len }) => assert_eq!((image, idx, len), (ImageId(2), 4, 4)),
        other => panic!("expected KeypointOutOfRange, got {other:?}"),
    }
    // A refused call adds none of its valid matches either.
    assert_eq!(g.num_image_pairs(), 0);
    assert_eq!(g.num_correspondences_for_image(ImageId(1)), 0);
    assert!(!g.has_correspondences(ImageId(1), 9));
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(9, 3)]).unwrap(), 1);
}

#[test]
fn unknown_and_self_matches_are_refused_with_typed_errors() {
    let mut g = graph(&[3, 3]);
    assert!(matches!(
        g.add_correspondences(ImageId(7), ImageId(1), &[(0, 0)]),
        Err(SfmError::UnknownImage(ImageId(7)))
    ));
    assert!(matches!(
        g.add_correspondences(ImageId(1), ImageId(8), &[(0, 0)]),
        Err(SfmError::UnknownImage(ImageId(8)))
    ));
    assert!(matches!(g.add_correspondences(ImageId(2), ImageId(2), &[(0, 1)]), Err(SfmError::SelfMatch(ImageId(2)))));
    assert_eq!(g.num_image_pairs(), 0);
    // Queries on unknown images or keypoints are empty, not errors.
    assert!(g.correspondences(ImageId(7), 0).is_empty());
    assert!(g.correspondences(ImageId(1), 3).is_empty());
    assert!(g.matches_between(ImageId(7), ImageId(1)).is_empty());
    assert_eq!(g.num_observations_for_image(ImageId(7)), 0);
    assert_eq!(g.num_correspondences_between(ImageId(1), ImageId(7)), 0);
}

#[test]
fn duplicate_matches_within_a_call_are_skipped() {
    // COLMAP's Duplicate case: (1, 1) twice and keypoint 3 of image 1 matched
    // twice. The repeated match is dropped; of the two uses of keypoint 3 the
    // first wins (COLMAP would keep both (3, 3) and (3, 4)).
    let mut g = graph(&[10, 10]);
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(0, 0), (1, 1), (1, 1), (3, 3), (3, 4)]).unwrap(), 3);
    assert_eq!(g.matches_between(ImageId(1), ImageId(2)), vec![(0, 0), (1, 1), (3, 3)]);
    assert_eq!(g.num_correspondences_for_image(ImageId(1)), 3);
    assert_eq!(g.num_correspondences_for_image(ImageId(2)), 3);
    assert_eq!(g.num_correspondences_between(ImageId(1), ImageId(2)), 3);
    assert!(!g.has_correspondences(ImageId(2), 4));
    // Two keypoints of image 1 on one keypoint of image 2: also first wins.
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(5, 6), (7, 6)]).unwrap(), 1);
    assert_eq!(g.correspondences(ImageId(2), 6), &[c(1, 5)]);
}

#[test]
fn matches_already_present_are_skipped_in_either_order() {
    let mut g = graph(&[6, 6]);
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(0, 1), (2, 3)]).unwrap(), 2);
    // The same matches given from the other side, plus one new one.
    assert_eq!(g.add_correspondences(ImageId(2), ImageId(1), &[(1, 0), (3, 2), (5, 4)]).unwrap(), 1);
    // Keypoints already matched to the other image cannot take a second
    // partner there, from either end.
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[(0, 5), (1, 3)]).unwrap(), 0);
    assert_eq!(g.matches_between(ImageId(1), ImageId(2)), vec![(0, 1), (2, 3), (4, 5)]);
    assert_eq!(g.matches_between(ImageId(2), ImageId(1)), vec![(1, 0), (3, 2), (5, 4)]);
    assert_eq!(g.num_correspondences_between(ImageId(1), ImageId(2)), 3);
    assert_eq!(g.num_correspondences_for_image(ImageId(1)), 3);
    assert_eq!(g.num_correspondences_for_image(ImageId(2)), 3);
    // An empty call is fine and changes nothing.
    assert_eq!(g.add_correspondences(ImageId(1), ImageId(2), &[]).unwrap(), 0);
    assert_eq!(g.num_image_pairs(), 1);
}

#[test]
fn image_pairs_are_smaller_id_first_in_ascending_order() {
    let mut g = graph(&[4, 4, 4, 4, 4]);
    g.add_correspondences(ImageId(5), ImageId(2), &[(0, 0), (1, 1)]).unwrap();
    g.add_correspondences(ImageId(3), ImageId(1), &[(0, 0)]).unwrap();
    g.add_correspondences(ImageId(2), ImageId(1), &[(2, 2), (3, 3), (1, 1)]).unwrap();
    g.add_correspondences(ImageId(4), ImageId(3), &[(3, 0)]).unwrap();
    let pairs: Vec<(u32, u32, usize)> = g.image_pairs().map(|(a, b, n)| (a.0, b.0, n)).collect();
    assert_eq!(pairs, vec![(1, 2, 3), (1, 3, 1), (2, 5, 2), (3, 4, 1)]);
    assert_eq!(g.num_image_pairs(), 4);
    // A refused or empty addition creates no pair.
    g.add_correspondences(ImageId(4), ImageId(5), &[]).unwrap();
    assert_eq!(g.num_image_pairs(), 4);
}

#[test]
fn connected_images_are_ranked_by_count_then_id() {
    let mut g = graph(&[6, 6, 6, 6, 6]);
    g.add_correspondences(ImageId(3), ImageId(5), &[(0, 0), (1, 1)]).unwrap();
    g.add_correspondences(ImageId(3), ImageId(1), &[(2, 2), (3, 3)]).unwrap();
    g.add_correspondences(ImageId(3), ImageId(4), &[(0, 0), (1, 1), (4, 4)]).unwrap();
    g.add_correspondences(ImageId(3), ImageId(2), &[(5, 5)]).unwrap();
    let ranked: Vec<(u32, usize)> = g.connected_images(ImageId(3)).into_iter().map(|(i, n)| (i.0, n)).collect();
    assert_eq!(ranked, vec![(4, 3), (1, 2), (5, 2), (2, 1)]);
    assert_eq!(g.connected_images(ImageId(2)), vec![(ImageId(3), 1)]);
    // Keypoints 0 and 1 of image 3 each have two correspondences.
    assert_eq!(g.num_observations_for_image(ImageId(3)), 6);
    assert_eq!(g.num_correspondences_for_image(ImageId(3)), 8);
}

#[test]
fn transitive_correspondences_follow_hops_breadth_first() {
    // A chain 1-2-3-4-5 through keypoint 0, with a shortcut 1-3 through the
    // same keypoints (a cycle) and an unrelated match on keypoint 1.
    let mut g = graph(&[3, 3, 3, 3, 3]);
    for (a, b) in [(1, 2), (2, 3), (3, 4), (4, 5), (1, 3)] {
        g.add_correspondences(ImageId(a), ImageId(b), &[(0, 0)]).unwrap();
    }
    g.add_correspondences(ImageId(1), ImageId(2), &[(1, 2)]).unwrap();
    let hops = |t| g.transitive_correspondences(ImageId(1), 0, t);
    assert!(hops(0).is_empty());
    assert_eq!(hops(1), vec![c(2, 0), c(3, 0)]);
    assert_eq!(hops(2), vec![c(2, 0), c(3, 0), c(4, 0)]);
    assert_eq!(hops(3), vec![c(2, 0), c(3, 0), c(4, 0), c(5, 0)]);
    // More hops than the component needs: every node once, never the start.
    assert_eq!(hops(10), hops(3));
    assert_eq!(g.transitive_correspondences(ImageId(5), 0, 2), vec![c(4, 0), c(3, 0)]);
    assert_eq!(g.transitive_correspondences(ImageId(2), 2, 5), vec![c(1, 1)]);
    assert!(g.transitive_correspondences(ImageId(1), 2, 5).is_empty());
    // Hop 1 equals the direct correspondences for every keypoint.
    for i in 1..=5 {
        for k in 0..3 {
            assert_eq!(g.transitive_correspondences(ImageId(i), k, 1), g.correspondences(ImageId(i), k));
        }
    }
}

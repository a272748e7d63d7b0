//! Keyframe culling (`--cull-keyframes`, `mapper/cull.rs`) on the exact
//! synthetic maps of the mapper's tests.

use super::*;

fn cull_opts() -> SlamOptions {
    let mut o = opts();
    o.mapper.cull_keyframes = true;
    o
}

/// Frames that are keyframes of the map, in order.
fn frames_of(map: &Mapper) -> Vec<usize> {
    keyframe_frames(map)
}

/// Checks that the map no longer knows image `id` anywhere: model, tracks,
/// graph, records.
fn assert_gone(map: &Mapper, id: ImageId) {
    assert!(map.rec.image(id).is_none(), "image {id:?} still in the model");
    assert!(!map.graph.exists_image(id), "image {id:?} still in the graph");
    assert!(map.rec.points3d().all(|(_, p)| p.track.iter().all(|e| e.image_id != id)));
    assert!(
        map.records().unwrap().iter().all(|r| r.obs.iter().all(|o| o.keyframe != id)),
        "a record still refers to it"
    );
}

/// The model is valid as COLMAP defines it and every point keeps two
/// observations by registered keyframes.
fn assert_consistent(map: &Mapper) {
    map.rec.check_consistency().unwrap();
    assert!(map.rec.points3d().all(|(_, p)| p.track.len() >= 2));
    assert_eq!(map.rec.num_images(), map.keyframes.len());
    assert_eq!(map.rec.num_registered_images(), map.keyframes.len());
    assert_eq!(map.graph.num_images(), map.keyframes.len());
}

#[test]
fn redundant_keyframes_leave_the_map_and_their_frames_are_still_localised() {
    let scene = Scene::translating(9);
    let mut map = scene.exact_map(0, &[0, 1, 2, 3, 4, 5, 6]);
    map.initial_frames = (0, 1);
    // Frame 7 matched keyframes 5 and 6 only, frame 8 keyframe 5 only.
    map.add_record(record(&scene, &map, 7, &[5, 6])).unwrap();
    map.add_record(record(&scene, &map, 8, &[5])).unwrap();
    let ids: HashMap<usize, ImageId> = (0..7).map(|f| (f, image_of(&map, f))).collect();
    let culled = map.cull_keyframes(ids[&6], &cull_opts()).unwrap();
    let kept = frames_of(&map);
    assert!(culled >= 2, "culled {culled}: {kept:?} left");
    assert_eq!(map.culled_keyframes(), culled);
    assert_eq!(kept.len(), 7 - culled);
    for f in [0, 1, 6] {
        assert!(kept.contains(&f), "frame {f} is the initial pair's or the newest: kept");
    }
    assert_consistent(&map);
    let gone: Vec<usize> = (2..6).filter(|f| !kept.contains(f)).collect();
    for f in &gone {
        assert_gone(&map, ids[f]);
    }
    // Every frame keeps a pose: kept keyframes as keyframes, culled ones
    // and the records that matched them localised at their true poses.
    let loc = map.localize_all(&opts(), &mut StageTimings::default()).unwrap();
    let got: Vec<(usize, bool)> = loc.poses.iter().map(|p| (p.frame.index, p.keyframe)).collect();
    let expected: Vec<(usize, bool)> = (0..9).map(|f| (f, kept.contains(&f))).collect();
    assert_eq!(got, expected, "failed: {:?}", loc.failed);
    for p in &loc.poses {
        let err = pose_error(&Sim3::identity(), &p.cam_from_world, &scene.poses[p.frame.index]);
        assert!(err < RECORD_ROUNDING_TOL, "frame {} is {err:e} off", p.frame.index);
    }
}

#[test]
fn only_points_seen_by_three_other_keyframes_at_the_same_scale_make_a_keyframe_redundant() {
    let scene = Scene::translating(4);
    // Two other keyframes are never enough.
    let mut map = scene.exact_map(0, &[0, 1, 2]);
    assert!(!map.is_redundant(image_of(&map, 1)));
    assert_eq!(map.cull_keyframes(image_of(&map, 2), &cull_opts()).unwrap(), 0);
    let mut map = scene.exact_map(0, &[0, 1, 2, 3]);
    let id = image_of(&map, 1);
    assert!(map.is_redundant(id));
    // The others see its points two pyramid levels coarser: not redundant;
    // one level coarser is within ORB-SLAM's slack.
    let set_levels = |map: &mut Mapper, octave: u8| {
        for kf in map.keyframes.iter_mut().filter(|k| k.image_id != id) {
            kf.data.features.keypoints.iter_mut().for_each(|k| k.octave = octave);
        }
    };
    set_levels(&mut map, 2);
    assert!(!map.is_redundant(id));
    set_levels(&mut map, 1);
    assert!(map.is_redundant(id));
}

#[test]
fn a_promoted_frame_that_is_culled_is_localised_again() {
    let scene = Scene::translating(6);
    let mut map = scene.exact_map(0, &[0, 1, 2, 3, 4, 5]);
    map.initial_frames = (0, 1);
    let mut promoted = record(&scene, &map, 3, &[2]);
    promoted.promoted = true;
    map.add_record(promoted).unwrap();
    map.cull_keyframes(image_of(&map, 5), &cull_opts()).unwrap();
    assert!(!frames_of(&map).contains(&3), "frame 3 is redundant: {:?}", frames_of(&map));
    assert!(map.records().unwrap().iter().all(|r| !r.promoted));
    let loc = map.localize_all(&opts(), &mut StageTimings::default()).unwrap();
    assert!(loc.poses.iter().any(|p| p.frame.index == 3 && !p.keyframe));
}

#[test]
fn registration_with_culling_keeps_fewer_keyframes_and_every_frame() {
    let scene = Scene::translating(12);
    let frontend = scene.frontend();
    let run = |o: &SlamOptions| {
        let mut map = initial_map(&scene);
        for f in 5..12 {
            registered(&mut map, &scene, f, &frontend, o);
        }
        map
    };
    let all = run(&opts());
    let culled = run(&cull_opts());
    assert_eq!(all.culled_keyframes(), 0);
    assert!(culled.culled_keyframes() > 0);
    assert_eq!(culled.keyframes.len() + culled.culled_keyframes(), all.keyframes.len());
    assert_consistent(&culled);
    let g = scene.assert_exact(&culled);
    let loc = culled.localize_all(&opts(), &mut StageTimings::default()).unwrap();
    let frames: Vec<usize> = loc.poses.iter().map(|p| p.frame.index).collect();
    assert_eq!(frames, vec![0, 4, 5, 6, 7, 8, 9, 10, 11]);
    for p in &loc.poses {
        let err = pose_error(&g, &p.cam_from_world, &scene.poses[p.frame.index]);
        assert!(err < RECORD_ROUNDING_TOL, "frame {} is {err:e} off", p.frame.index);
    }
}

#[test]
fn culling_at_the_end_checks_every_keyframe_the_newest_included() {
    // Culling after a registration checks the newest keyframe's local bundle
    // only and never the newest itself; the pass at the end of tracking
    // checks every keyframe, and every frame keeps its pose.
    let scene = Scene::translating(12);
    let build = || {
        let mut map = scene.exact_map(0, &(0..12).collect::<Vec<_>>());
        map.initial_frames = (0, 1);
        map
    };
    let mut bundle = build();
    let newest = image_of(&bundle, 11);
    let in_bundle = bundle.cull_keyframes(newest, &cull_opts()).unwrap();
    assert!(frames_of(&bundle).contains(&11));
    let mut map = build();
    let culled = map.cull_all_keyframes().unwrap();
    let kept = frames_of(&map);
    assert!(culled > in_bundle, "culled {culled} at the end, {in_bundle} in the bundle: {kept:?} left");
    assert!(kept.contains(&0) && kept.contains(&1), "the initial pair stays: {kept:?}");
    assert_eq!(map.culled_keyframes(), culled);
    assert_consistent(&map);
    let loc = map.localize_all(&opts(), &mut StageTimings::default()).unwrap();
    let got: Vec<(usize, bool)> = loc.poses.iter().map(|p| (p.frame.index, p.keyframe)).collect();
    let expected: Vec<(usize, bool)> = (0..12).map(|f| (f, kept.contains(&f))).collect();
    assert_eq!(got, expected, "failed: {:?}", loc.failed);
    for p in &loc.poses {
        let err = pose_error(&Sim3::identity(), &p.cam_from_world, &scene.poses[p.frame.index]);
        assert!(err < RECORD_ROUNDING_TOL, "frame {} is {err:e} off", p.frame.index);
    }
}

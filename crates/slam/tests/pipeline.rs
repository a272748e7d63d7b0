//! End-to-end tests of the pipeline on synthetic sequences with exact ground
//! truth, and on degenerate inputs (they must finish with a report, never
//! panic).

use colslam_eval::trajectory::Trajectory;
use colslam_eval::{EvalOptions, EvalReport, evaluate};
use colslam_image::Image;
use colslam_io::Frame;
use colslam_slam::{EventSink, LocalMapSearch, Slam, SlamEvent, SlamOptions, SlamResult};
use colslam_synth::{SynthOptions, SyntheticSequence};

fn small_synth(frames: usize, seed: u64) -> SynthOptions {
    SynthOptions { frames, width: 320, height: 240, focal: 262.5, seed, ..SynthOptions::default() }
}

/// The default synthetic room with `frames` frames, and its frames.
fn room(frames: usize) -> (SyntheticSequence, Vec<Frame>) {
    let opts = SynthOptions { frames, ..SynthOptions::default() };
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    (seq, frames)
}

fn frames_of(seq: &SyntheticSequence, n: usize, fps: f64) -> Vec<Frame> {
    (0..n)
        .map(|i| Frame {
            index: i,
            source_index: i,
            timestamp: i as f64 / fps,
            name: format!("{i:06}.png"),
            image: seq.render(i).expect("render"),
        })
        .collect()
}

fn run(frames: &[Frame], camera: &colslam_camera::Camera, opts: SlamOptions, events: EventSink) -> SlamResult {
    let mut slam = Slam::new(opts, camera, events).expect("options");
    for f in frames {
        slam.process(f).expect("process");
    }
    slam.finish().expect("finish")
}

/// The run's ATE against the synthetic ground truth, and the room's
/// diagonal (m) that the synthetic tests scale their bounds by.
fn ate_and_room_diagonal(seq: &SyntheticSequence, opts: &SynthOptions, r: &SlamResult) -> (EvalReport, f64) {
    let ate = evaluate(&gt_trajectory(seq, opts.frames, opts.fps), &est_trajectory(r), &EvalOptions::default())
        .expect("evaluate");
    let size = seq.scene().room().size();
    (ate, (size[0].powi(2) + size[1].powi(2) + size[2].powi(2)).sqrt())
}

/// A dataset of `$COLSLAM_DATA` in TUM layout: its folder, its camera
/// (`camera.yaml`) and every frame; `None` (the test skips) when absent.
fn dataset_frames(name: &str) -> Option<(std::path::PathBuf, colslam_camera::Camera, Vec<Frame>)> {
    let dir = colslam_testutil::dataset(name)?;
    let camera = colslam_camera::file::read_camera_file(&dir.join("camera.yaml")).expect("camera file");
    let source = colslam_io::open_source(&dir, &colslam_io::SourceOptions::default()).expect("source");
    let frames: Vec<Frame> = source.map(|f| f.expect("frame")).collect();
    Some((dir, camera, frames))
}

fn gt_trajectory(seq: &SyntheticSequence, n: usize, fps: f64) -> Trajectory {
    let poses: Vec<_> = (0..n).map(|i| seq.cam_from_world(i).expect("pose")).collect();
    Trajectory::from_cam_from_world((0..n).map(|i| i as f64 / fps).collect(), &poses)
}

fn est_trajectory(r: &SlamResult) -> Trajectory {
    let m = &r.maps[0];
    Trajectory::from_cam_from_world(
        m.poses.iter().map(|p| p.frame.timestamp).collect(),
        &m.poses.iter().map(|p| p.cam_from_world).collect::<Vec<_>>(),
    )
}

#[test]
fn synthetic_sequence_is_fully_localised_and_accurate() {
    // The default camera and scene, fewer frames.
    let opts = SynthOptions { frames: 100, ..SynthOptions::default() };
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let (events, rx) = EventSink::channel();
    let r = run(&frames, seq.camera(), SlamOptions::default(), events);
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    assert!(r.not_localized.is_empty(), "not localised: {:?}", r.not_localized);
    assert_eq!(r.maps[0].poses.len(), opts.frames);
    let (ate, diagonal) = ate_and_room_diagonal(&seq, &opts, &r);
    assert!(ate.ate_rmse < 5e-4 * diagonal, "ATE {} m vs scene diagonal {} m", ate.ate_rmse, diagonal);
    // Events arrived, keyframes among them, and the run finished.
    let events: Vec<SlamEvent> = rx.try_iter().collect();
    let keyframes = events.iter().filter(|e| matches!(e, SlamEvent::KeyframeAdded { .. })).count();
    assert!(keyframes >= 3, "{keyframes} keyframe events");
    assert!(events.iter().any(|e| matches!(e, SlamEvent::MapUpdated { .. })));
    assert!(matches!(events.last(), Some(SlamEvent::Finished)));
    let rec = r.maps[0].map.reconstruction();
    rec.check_consistency().expect("consistent model");
    assert!(rec.mean_reprojection_error() < 1.0, "{}", rec.mean_reprojection_error());
}

#[test]
fn same_seed_gives_identical_models() {
    let opts = small_synth(40, 2);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let a = run(&frames, seq.camera(), SlamOptions::default(), EventSink::none());
    let b = run(&frames, seq.camera(), SlamOptions::default(), EventSink::none());
    let dir = tempfile::tempdir().expect("tempdir");
    let (pa, pb) = (dir.path().join("a"), dir.path().join("b"));
    for (r, p) in [(&a, &pa), (&b, &pb)] {
        std::fs::create_dir_all(p).expect("mkdir");
        colslam_scene::write_model(r.maps[0].map.reconstruction(), p, colslam_scene::ModelFormat::Binary)
            .expect("write");
    }
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        assert_eq!(std::fs::read(pa.join(f)).expect("read"), std::fs::read(pb.join(f)).expect("read"), "{f} differs");
    }
    assert!(a.maps[0].map.reconstruction().num_points3d() > 100);
}

fn synthetic_camera() -> colslam_camera::Camera {
    colslam_camera::Camera::pinhole(320, 240, 262.5, 262.5, 159.5, 119.5)
}

fn frame(i: usize, image: Image) -> Frame {
    Frame { index: i, source_index: i, timestamp: i as f64 / 30.0, name: format!("{i:06}.png"), image }
}

#[test]
fn static_camera_finishes_with_a_report() {
    let seq = SyntheticSequence::new(&small_synth(2, 3)).expect("sequence");
    let img = seq.render(0).expect("render");
    let frames: Vec<Frame> = (0..30).map(|i| frame(i, img.clone())).collect();
    let r = run(&frames, &synthetic_camera(), SlamOptions::default(), EventSink::none());
    // No motion, no map: every frame is reported as not localised.
    assert_eq!(r.frames.len(), 30);
    assert!(r.maps.is_empty());
    assert_eq!(r.not_localized.len(), 30);
    assert!(!r.stats.notes.is_empty());
}

#[test]
fn black_frames_and_two_frames_finish() {
    let frames: Vec<Frame> = (0..10).map(|i| frame(i, Image::new(320, 240, 3))).collect();
    let r = run(&frames, &synthetic_camera(), SlamOptions::default(), EventSink::none());
    assert!(r.maps.is_empty());
    assert_eq!(r.not_localized.len(), 10);

    let seq = SyntheticSequence::new(&small_synth(40, 4)).expect("sequence");
    let two = vec![frame(0, seq.render(0).expect("render")), frame(1, seq.render(39).expect("render"))];
    let r = run(&two, seq.camera(), SlamOptions::default(), EventSink::none());
    assert_eq!(r.frames.len(), 2);
    assert!(r.maps.len() <= 1);
}

#[test]
fn a_cut_to_another_scene_starts_a_new_map() {
    let a = SyntheticSequence::new(&small_synth(40, 5)).expect("sequence");
    let b = SyntheticSequence::new(&small_synth(40, 6)).expect("sequence");
    let mut frames = frames_of(&a, 40, 30.0);
    for (k, f) in frames_of(&b, 40, 30.0).into_iter().enumerate() {
        frames.push(frame(40 + k, f.image));
    }
    let r = run(&frames, a.camera(), SlamOptions::default(), EventSink::none());
    assert!(r.maps.len() >= 2, "maps: {}, notes: {:?}", r.maps.len(), r.stats.notes);
    let localized: usize = r.maps.iter().map(|m| m.poses.len()).sum();
    assert!(localized >= 60, "only {localized} of 80 frames localised");
}

#[test]
fn wrong_frame_size_is_an_error_not_a_panic() {
    let mut slam = Slam::new(SlamOptions::default(), &synthetic_camera(), EventSink::none()).expect("options");
    let e = slam.process(&frame(0, Image::new(100, 50, 1))).unwrap_err().to_string();
    assert!(e.contains("100x50") && e.contains("320x240"), "{e}");
    assert!(
        Slam::new(
            {
                let mut o = SlamOptions::default();
                o.keyframes.min_matches = 0;
                o
            },
            &synthetic_camera(),
            EventSink::none()
        )
        .is_err()
    );
}

#[test]
fn refine_all_frames_puts_every_localised_frame_in_the_model() {
    let opts = small_synth(40, 8);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let mut slam_opts = SlamOptions::default();
    slam_opts.refine.refine_all_frames = true;
    slam_opts.mapper.weight_by_level = true;
    let r = run(&frames, seq.camera(), slam_opts, EventSink::none());
    let m = &r.maps[0];
    assert_eq!(
        m.map.reconstruction().num_registered_images(),
        m.poses.len(),
        "every localised frame is an image of the model"
    );
    m.map.reconstruction().check_consistency().expect("consistent model");
    let (ate, diagonal) = ate_and_room_diagonal(&seq, &opts, &r);
    assert!(ate.ate_rmse < 1e-3 * diagonal, "ATE {} m", ate.ate_rmse);
}

#[test]
fn frames_before_the_initial_pair_are_tracked_backwards() {
    let opts = small_synth(60, 9);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let r = run(&frames, seq.camera(), SlamOptions::default(), EventSink::none());
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    let m = &r.maps[0].map;
    let (first, _) = m.initial_frames();
    // The fixture's initial pair does not start at frame 0 (the first image
    // is the one with the most matches in the window), so frames precede it.
    assert!(first >= 2, "initial pair starts at frame {first}");
    let earlier: Vec<usize> = m.keyframes().iter().map(|k| k.data.index()).filter(|&i| i < first).collect();
    assert!(!earlier.is_empty(), "no keyframe before the initial pair (frame {first})");
    // Keyframes stay in frame order after the backward pass.
    assert!(m.keyframes().windows(2).all(|w| w[0].data.index() < w[1].data.index()));
    assert!(r.not_localized.is_empty(), "not localised: {:?}", r.not_localized);
}

/// A synthetic sequence played out along its path and back again.
fn out_and_back() -> (SyntheticSequence, Vec<Frame>) {
    let opts = small_synth(45, 10);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let mut frames = frames_of(&seq, opts.frames, opts.fps);
    for k in 0..opts.frames {
        frames.push(frame(opts.frames + k, seq.render(opts.frames - 1 - k).expect("render")));
    }
    (seq, frames)
}

#[test]
fn a_camera_coming_back_matches_the_keyframes_it_saw_before() {
    // Out along the path and back again: on the way back the camera sees
    // what it mapped on the way out, 30 and more frames earlier.
    let (seq, frames) = out_and_back();
    // Pairs of keyframes in the correspondence graph further apart in the
    // keyframe list than the `match_keyframes` most recent ones.
    let far_pairs = |revisited: usize| {
        let mut opts = SlamOptions::default();
        opts.mapper.match_revisited = revisited;
        // Map reuse (which registers against old keyframes) and culling off:
        // the revisit matching alone.
        opts.keyframes.reuse_keyframes = 0;
        opts.mapper.cull_keyframes = false;
        let recent = opts.mapper.match_keyframes;
        let r = run(&frames, seq.camera(), opts, EventSink::none());
        assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
        let m = &r.maps[0].map;
        let position: std::collections::HashMap<_, _> =
            m.keyframes().iter().enumerate().map(|(p, k)| (k.image_id, p)).collect();
        m.graph().image_pairs().filter(|(a, b, n)| *n > 0 && position[a].abs_diff(position[b]) > recent).count()
    };
    let (with, without) = (far_pairs(5), far_pairs(0));
    assert_eq!(without, 0, "only recent keyframes are matched when revisits are off");
    assert!(with > 0, "no keyframe matched one it saw 30 frames before");
}

#[test]
fn a_camera_coming_back_tracks_the_old_keyframes_and_adds_few() {
    // Out along the path and back again over the same views: with map reuse
    // each frame on the way back is tracked against the old keyframe that
    // covers it best, whose flow is small, so few keyframes are added.
    let (seq, frames) = out_and_back();
    let keyframes = |reuse: usize| {
        let mut o = SlamOptions::default();
        o.keyframes.reuse_keyframes = reuse;
        o.mapper.cull_keyframes = false;
        let r = run(&frames, seq.camera(), o, EventSink::none());
        assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
        assert!(r.not_localized.is_empty(), "not localised: {:?}", r.not_localized);
        let m = &r.maps[0].map;
        let back = m.keyframes().iter().filter(|k| k.data.index() >= frames.len() / 2).count();
        (m.keyframes().len() - back, back)
    };
    let (out_without, back_without) = keyframes(0);
    let (out_with, back_with) = keyframes(8);
    assert!(back_without * 2 > out_without, "{back_without} keyframes back, {out_without} out: the fixture revisits");
    assert!(back_with * 4 <= out_with, "{back_with} keyframes back with reuse, {out_with} out");
}

#[test]
fn culled_keyframes_are_counted_in_the_report() {
    // Without map reuse the way back re-maps the same views densely; the
    // culling removes redundant keyframes and report.json says how many.
    let (seq, frames) = out_and_back();
    let mut o = SlamOptions::default();
    o.keyframes.reuse_keyframes = 0;
    let r = run(&frames, seq.camera(), o.clone(), EventSink::none());
    assert!(r.not_localized.is_empty(), "not localised: {:?}", r.not_localized);
    let culled: usize = r.maps.iter().map(|m| m.map.culled_keyframes()).sum();
    assert!(culled > 0, "nothing culled");
    let dir = tempfile::tempdir().expect("tempdir");
    let report = colslam_slam::output::write_outputs(&r, &dir.path().join("out"), "synthetic", &o, Default::default())
        .expect("outputs");
    assert_eq!(report.culled_keyframes, culled);
    assert_eq!(report.localized, frames.len());
}

#[test]
fn a_live_view_drops_culled_keyframes() {
    // Map increments only add and move keyframes: after a cull the next
    // update must be a full snapshot, or a viewer keeps the culled one.
    let (seq, frames) = out_and_back();
    let mut o = SlamOptions::default();
    o.keyframes.reuse_keyframes = 0;
    let (sink, rx) = EventSink::channel();
    let r = run(&frames, seq.camera(), o, sink);
    assert!(r.maps[0].map.culled_keyframes() > 0, "nothing culled");
    // The viewer's copy: a full update replaces it, an increment adds to it.
    let mut shown = std::collections::BTreeSet::new();
    for e in rx.try_iter() {
        if let SlamEvent::MapUpdated { full, poses, keyframes, .. } = e {
            if full {
                shown.clear();
            }
            shown.extend(poses.iter().map(|(id, _, _)| *id));
            assert_eq!(shown.len(), keyframes, "the viewer shows {} keyframes of {keyframes}", shown.len());
        }
    }
}

/// The small room's default path over `n` frames (seed 11), run with the
/// default options: one map, `min_localized` frames or more, and an ATE
/// under 0.1 % of the room's diagonal. 0.1 %, not the 0.05 % of the VGA
/// default: at 320x240 and a slow camera (9 keyframes over 300 frames) the
/// map's scale drifts from keyframe to keyframe (integer ORB corners at a
/// quarter of the pixels); measured 6.6 mm (0.08 %) over 300 frames with
/// the default keypoint count, and 7 mm to 10 cm over keypoint counts
/// 800-2000 in `colslam demo --frames 300 --width 320 --height 240
/// --scene-seed 11`, while the same path at 640x480 stays at 1.1-1.9 mm
/// (docs/history.md).
fn slow_room_run(n: usize, min_localized: usize) -> SlamResult {
    let opts = small_synth(n, 11);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let r = run(&frames, seq.camera(), SlamOptions::default(), EventSink::none());
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    let localized = r.maps[0].poses.len();
    assert!(localized >= min_localized, "only {localized} of {n} frames localised; notes: {:?}", r.stats.notes);
    let (ate, diagonal) = ate_and_room_diagonal(&seq, &opts, &r);
    assert!(ate.ate_rmse < 1e-3 * diagonal, "ATE {} m vs scene diagonal {} m", ate.ate_rmse, diagonal);
    r
}

#[test]
fn a_slow_camera_widens_the_initialisation_window() {
    // The default path over 300 frames: too little motion within the first
    // 20 frames for an initial pair, so the window must span more time.
    let r = slow_room_run(300, 297);
    assert!(
        r.stats.notes.iter().any(|n| n.contains("initialisation failed on frames 0..=19")),
        "notes: {:?}",
        r.stats.notes
    );
}

#[test]
fn a_very_slow_camera_initialises_from_a_window_taking_every_few_frames() {
    // The default path over 1000 frames: thinning the failed window while
    // new frames came in at the full rate kept it under 45 frames, too
    // little motion, and no window ever initialised. Taking every other new
    // frame after each thinning doubles the time it spans.
    slow_room_run(1000, 990);
}

#[test]
fn wide_baseline_photos_initialise_from_overlapping_pairs() {
    // Strecha castle-P19: 19 photos around a courtyard; the frames far from
    // the first image share no view with it, so the initial pair must be
    // found among the nearer ones (all 8 farthest candidates fail).
    let Some((_, camera, frames)) = dataset_frames("strecha_castle_P19") else { return };
    assert_eq!(frames.len(), 19);
    let r = run(&frames, &camera, SlamOptions::default(), EventSink::none());
    assert!(!r.maps.is_empty(), "no map; notes: {:?}", r.stats.notes);
    let localized = r.maps[0].poses.len();
    assert!(localized >= 18, "only {localized} of 19 photos localised; notes: {:?}", r.stats.notes);
}

/// COLMAP's focal length prior for photos, 1.2 x the larger side: 33-46 %
/// long on the shared sequences with 4:3 and 3:2 frames and twice the
/// focal length of a car's 3.3:1 rectified camera, so the runs that start
/// from it exercise the remap (the run's own guess, `run::guessed_focal`,
/// starts within 10 % there).
fn colmap_prior(w: u32, h: u32) -> f64 {
    1.2 * w.max(h) as f64
}

/// A shared sequence run without its calibration, from a far guess: the
/// focal length at [`colmap_prior`], principal point at the centre, and
/// refined. The folder, the hidden calibration and the result; `None` when
/// the data are absent.
fn run_without_calibration(name: &str) -> Option<(std::path::PathBuf, colslam_camera::Camera, SlamResult)> {
    let (dir, calibrated, frames) = dataset_frames(name)?;
    let (w, h) = (calibrated.width as u32, calibrated.height as u32);
    let guess = colslam_slam::calibrate::centred_camera(w, h, colmap_prior(w, h));
    let mut opts = SlamOptions::default();
    opts.refine.refine_intrinsics = true;
    let r = run(&frames, &guess, opts, EventSink::none());
    Some((dir, calibrated, r))
}

#[test]
fn castle_without_calibration_is_mapped_again_with_the_settled_focal_length() {
    // The same photos with the focal length started at COLMAP's prior
    // (33 % long) and refined: the first map's focal length settles near the
    // calibration's by its eighth keyframe, but the map made under the
    // guess fails every photo after the tenth (11 of 19 localised). Mapped
    // again from the settled focal length, every photo is localised.
    let Some((dir, calibrated, r)) = run_without_calibration("strecha_castle_P19") else { return };
    assert!(r.stats.notes.iter().any(|n| n.contains("mapped again")), "notes: {:?}", r.stats.notes);
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    assert!(r.maps[0].poses.len() >= 18, "only {} of 19 photos localised", r.maps[0].poses.len());
    let focal = r.maps[0].map.camera().expect("camera").focal_x();
    assert!((focal / calibrated.focal_x() - 1.0).abs() < 0.01, "focal length {focal} px");
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
    let ate = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate");
    // Calibrated: 10.2-13.2 cm over seeds (docs/benchmarks.md).
    assert!(ate.ate_rmse < 0.15, "ATE {} m", ate.ate_rmse);
}

#[test]
fn kitti_without_calibration_is_mapped_again_once_a_map_constrains_its_focal_length() {
    // A car driving straight, focal length started at COLMAP's prior, 1489
    // px (twice the calibration's). Held in two-view homography maps and
    // refined from the third view on, it ends within 3 % of the
    // calibration's, but the map made under the guess keeps its error (ATE
    // 14-20 m against 0.24 calibrated). So the frames so far are mapped
    // again as soon as a map's focal length stays put while the map grows
    // and its views constrain it: on every seed measured, the first map at
    // 13 keyframes, 701-703 px (sharpness 0.14-0.16), at frame 51, before
    // it fails.
    let Some((dir, calibrated, frames)) = dataset_frames("kitti_odom00_first300") else { return };
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
    let (w, h) = (calibrated.width as u32, calibrated.height as u32);
    let guess = colslam_slam::calibrate::centred_camera(w, h, colmap_prior(w, h));
    for seed in [0, 2] {
        let mut opts = SlamOptions::default();
        opts.refine.refine_intrinsics = true;
        opts.seed = seed;
        let r = run(&frames, &guess, opts, EventSink::none());
        let notes = &r.stats.notes;
        assert!(
            notes.iter().any(|n| n.contains("kept its focal length while it grew") && n.contains("mapped again")),
            "seed {seed}: notes: {notes:?}"
        );
        assert_eq!(r.maps.len(), 1, "seed {seed}: notes: {notes:?}");
        let localized = r.maps[0].poses.len();
        assert!(localized >= 290, "seed {seed}: only {localized} of 300 frames localised");
        let focal = r.maps[0].map.camera().expect("camera").focal_x();
        assert!((focal / calibrated.focal_x() - 1.0).abs() < 0.05, "seed {seed}: focal length {focal} px");
        let ate = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate");
        // `colslam run` (with the observation refinement this test's
        // pipeline lacks) measured 0.45-0.71 m over seeds 0-4; here seeds
        // 0-5 give 0.45-1.01 m. Without any remap: 14-20 m.
        assert!(ate.ate_rmse < 1.5, "seed {seed}: ATE {} m", ate.ate_rmse);
    }
}

#[test]
fn the_kitti_clip_without_calibration_is_one_map_from_the_guessed_focal_length() {
    // A car's 1242 x 375 video (KITTI's raw camera: pycolmap refines its
    // frames to 707-718 px; twitchslam runs it at 984). Started from
    // COLMAP's prior (1490 px) the run broke into 2 maps holding 175 of 268
    // frames and ended at 582 px; the guess from the image area, 682 px,
    // maps every frame in one map.
    let Some(file) = colslam_testutil::kitti_clip() else { return };
    let source = colslam_io::open_source(&file, &colslam_io::SourceOptions::default()).expect("source");
    let frames: Vec<Frame> = source.map(|f| f.expect("frame")).collect();
    assert_eq!(frames.len(), 268);
    let r = one_map_from_the_guess("clip", &frames, SlamOptions::default().seed, 265);
    let focal = r.maps[0].map.camera().expect("camera").focal_x();
    assert!((650.0..=800.0).contains(&focal), "focal length {focal:.1} px");
}

/// `frames` run without calibration from the run's own guess
/// (`run::guessed_focal`, principal point at the centre, refined), which
/// must make one map of at least `min_frames` frames.
fn one_map_from_the_guess(name: &str, frames: &[Frame], seed: u64, min_frames: usize) -> SlamResult {
    let (w, h) = (frames[0].image.width(), frames[0].image.height());
    let start = colslam_slam::run::guessed_focal(w as f64, h as f64);
    let guess = colslam_slam::calibrate::centred_camera(w as u32, h as u32, start);
    let mut opts = SlamOptions::default();
    opts.refine.refine_intrinsics = true;
    opts.seed = seed;
    let r = run(frames, &guess, opts, EventSink::none());
    let notes = &r.stats.notes;
    assert_eq!(r.maps.len(), 1, "{name}: notes: {notes:?}");
    let localized = r.maps[0].poses.len();
    let n = frames.len();
    assert!(localized >= min_frames, "{name}: only {localized} of {n} frames localised; notes: {notes:?}");
    let camera = r.maps[0].map.camera().expect("camera");
    eprintln!("{name}: {localized} frames, {:?} {:?} from {start:.1} px", camera.model, camera.params);
    r
}

#[test]
fn kitti_without_calibration_is_one_map_from_the_guessed_focal_length() {
    // The run's own guess, 683 px (5 % short of the calibration's 718.9).
    // An initial pair moving straight ahead fits any focal length: its
    // two-view BA took the guess to 504 px in 50 iterations on this seed,
    // and the map broke at frame 34 (273 of 300 frames in 2 maps). Held
    // where the two views leave it freer than the guess is, one map.
    let Some((_, calibrated, frames)) = dataset_frames("kitti_odom00_first300") else { return };
    let r = one_map_from_the_guess("kitti", &frames, 1, 295);
    let focal = r.maps[0].map.camera().expect("camera").focal_x();
    assert!((focal / calibrated.focal_x() - 1.0).abs() < 0.05, "focal length {focal:.1} px");
}

#[test]
fn undistorted_photos_without_calibration_keep_a_pinhole_camera() {
    // Strecha's photos were undistorted with their calibration. Over 10^5
    // residuals a radial term's cost gain is still significant on
    // herzjesu (chi-square 108 with `colslam run`), but it moves the
    // image's corners by under a pixel (k -0.0023, 0.96 px) and kept it
    // costs the trajectory 7 %: the term needs `MIN_RADIAL_SHIFT_PX` too.
    // Castle's seed 1 asks for k -0.009 (3.8 px) with the principal point
    // held at the centre, and for -0.001 once it is refined: the term stood
    // in for the principal point's offset and is dropped (kept, castle's
    // trajectory was 5 % worse).
    for (name, seed, max_ate) in [("strecha_herzjesu_P25", 0, 0.011), ("strecha_castle_P19", 1, 0.045)] {
        let Some((dir, calibrated, frames)) = dataset_frames(name) else { return };
        let r = one_map_from_the_guess(name, &frames, seed, frames.len());
        let camera = r.maps[0].map.camera().expect("camera");
        assert_eq!(camera.model, colslam_camera::CameraModelId::SimplePinhole, "{name}: params {:?}", camera.params);
        let focal = camera.focal_x();
        assert!((focal / calibrated.focal_x() - 1.0).abs() < 0.01, "{name}: focal length {focal:.1} px");
        let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
        let ate = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate");
        eprintln!("{name} without calibration: ATE {} m", ate.ate_rmse);
        // herzjesu 0.90 cm here (this pipeline does not refine the
        // observations; `colslam run` 0.64 cm, calibrated 0.64 cm).
        assert!(ate.ate_rmse < max_ate, "{name}: ATE {} m", ate.ate_rmse);
    }
}

#[test]
fn rolling_shutter_compensation_brings_tum_rpy_under_1_5_cm() {
    // TUM fr1/rpy: a Kinect v1 (rolling shutter, 30 Hz) turning fast. The
    // issue's bar is 1.5 cm with ORB; without compensation the run is at
    // 2.2 cm, like COLMAP's and GLOMAP's (docs/benchmarks.md).
    let Some((dir, camera, frames)) = dataset_frames("tum_fr1_rpy_sub") else { return };
    assert_eq!(frames.len(), 200);
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
    let mut opts = SlamOptions::default();
    opts.refine.rolling_shutter = colslam_slam::RollingShutter::Seconds(1.0 / 30.0);
    let r = run(&frames, &camera, opts, EventSink::none());
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    let localized = r.maps[0].poses.len();
    assert!(localized >= 198, "only {localized} of 200 frames localised");
    let ate = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate");
    assert!(ate.ate_rmse < 0.015, "ATE {} m", ate.ate_rmse);
    r.maps[0].map.reconstruction().check_consistency().expect("consistent model");
}

#[test]
fn rolling_shutter_with_culling_and_reuse_keeps_every_tum_rpy_frame() {
    // With culling and map reuse, frames 22-24 (the end of a fast turn) lean
    // on one keyframe, and the compensated BA's filter deletes most of their
    // map points; they keep their pose relative to their keyframe instead
    // of being lost (197 of 200 without that).
    let Some((dir, camera, frames)) = dataset_frames("tum_fr1_rpy_sub") else { return };
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
    let mut opts = SlamOptions::default();
    opts.refine.rolling_shutter = colslam_slam::RollingShutter::Seconds(1.0 / 30.0);
    opts.mapper.cull_keyframes = true;
    opts.keyframes.reuse_keyframes = 8;
    let r = run(&frames, &camera, opts, EventSink::none());
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    assert_eq!(r.maps[0].poses.len(), 200, "every frame localised");
    let ate = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate");
    assert!(ate.ate_rmse < 0.015, "ATE {} m", ate.ate_rmse);
}

/// Keyframes of a culling, map-reusing run (`--reuse-keyframes reuse`) over
/// the first `n` frames of `frames` played forward, back and forward again
/// (0..199, 198..1, 0..), each frame a new one with increasing timestamps;
/// every frame must be localised in one map.
fn forward_back_keyframes(frames: &[Frame], camera: &colslam_camera::Camera, n: usize, reuse: usize) -> usize {
    let mut opts = SlamOptions::default();
    opts.mapper.cull_keyframes = true;
    opts.keyframes.reuse_keyframes = reuse;
    let mut slam = Slam::new(opts, camera, EventSink::none()).expect("options");
    let period = 2 * frames.len() - 2;
    let dt = (frames[frames.len() - 1].timestamp - frames[0].timestamp) / (frames.len() - 1) as f64;
    for i in 0..n {
        let p = i % period;
        let mut f = frames[if p < frames.len() { p } else { period - p }].clone();
        (f.index, f.timestamp) = (i, i as f64 * dt);
        slam.process(&f).expect("process");
    }
    let r = slam.finish().expect("finish");
    assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
    assert!(r.not_localized.is_empty(), "{} frames not localised", r.not_localized.len());
    r.maps[0].map.keyframes().len()
}

#[test]
fn revisiting_tum_rpy_forward_and_back_adds_few_keyframes() {
    // TUM fr1/rpy played forward, back and forward again: with culling and
    // map reuse searching 40 covisible keyframes (in batches of 8) the two
    // passes over mapped space add at most a tenth of the first pass's
    // keyframes (measured 73 -> 75); searching only the first batch of 8,
    // frames between keyframes that culling thinned out find no covering
    // view and become keyframes again (84).
    let Some((_, camera, frames)) = dataset_frames("tum_fr1_rpy_sub") else { return };
    let first = forward_back_keyframes(&frames, &camera, frames.len(), 40);
    let wide = forward_back_keyframes(&frames, &camera, 3 * frames.len(), 40);
    let narrow = forward_back_keyframes(&frames, &camera, 3 * frames.len(), 8);
    assert!(wide * 10 <= first * 11, "{wide} keyframes after three passes, {first} after the first");
    assert!(narrow * 10 > first * 11, "{narrow} keyframes with a search of 8: the fixture no longer tells");
}

#[test]
fn a_refined_camera_is_the_one_every_step_sees() {
    // The synthetic camera given 8 % too long a focal length, refined by
    // bundle adjustment: the map's reconstruction owns the camera, the
    // pipeline normalises new frames with it, and at the end every
    // keyframe's normalised coordinates come from the refined camera.
    let opts = small_synth(60, 12);
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let wrong = colslam_camera::Camera::pinhole(320, 240, 283.5, 283.5, 159.5, 119.5);
    let mut slam_opts = SlamOptions::default();
    slam_opts.refine.refine_intrinsics = true;
    let mut slam = Slam::new(slam_opts, &wrong, EventSink::none()).expect("options");
    for f in &frames {
        slam.process(f).expect("process");
    }
    let map_camera = slam.current_map().expect("a map").camera().expect("camera").clone();
    assert_eq!(slam.camera(), &map_camera, "the pipeline uses the map's camera");
    assert!((map_camera.focal_x() - 283.5).abs() > 1.0, "refined: {}", map_camera.focal_x());
    let r = slam.finish().expect("finish");
    let m = &r.maps[0].map;
    let camera = m.camera().expect("camera");
    let (f, truth) = (camera.focal_x(), 262.5);
    assert!((f - truth).abs() < 0.02 * truth, "refined focal {f} vs {truth}");
    for kf in m.keyframes() {
        for (n, px) in kf.data.normalized.iter().zip(&kf.data.pixels) {
            assert_eq!(
                Some(*n),
                camera.cam_from_img(px),
                "keyframe {} normalised with another camera",
                kf.data.index()
            );
        }
    }
    assert!(r.maps[0].poses.len() >= 55, "{} of 60 frames localised", r.maps[0].poses.len());
}

#[test]
fn a_guessed_focal_length_is_refined_to_the_synthetic_one() {
    // No calibration: the focal length started at COLMAP's prior (46 %
    // long) and refined by the global bundle adjustments. Exact
    // projection, so a converged refinement must land on
    // the true focal length: with a squared loss the few mismatches the map
    // keeps pulled it along its weak direction, and a lens with barrel
    // distortion (k1 -0.1) needs the radial term found at the end.
    // The whole default room for the pinhole (its 90 first frames end
    // within 1 % either way), 90 frames for the distorted lens; at 320 x 240
    // the refinement stays 1-4 % off whatever the loss. The pinhole also
    // from half its focal length: a telephoto, whose `run::guessed_focal`
    // is short (the room ends at 525.5 px from 262 with `colslam run`).
    // The run reads its frames again, as `colslam run` does: from COLMAP's
    // prior the room's first two views barely tell the focal length
    // (chi-square 1.9 better at 691 px) and hold it, and without the
    // observations' refinement the pinhole then ends 1.37 % long (+0.24 %
    // with it; docs/benchmarks.md).
    let half = Some(0.5 * SynthOptions::default().focal);
    for (frames, distortion, start) in [(150, None, None), (150, None, half), (90, Some([-0.1, 0.02, 0.0, 0.0]), None)]
    {
        let synth = SynthOptions { frames, distortion, ..SynthOptions::default() };
        let (w, h) = (synth.width, synth.height);
        let seq = SyntheticSequence::new(&synth).expect("sequence");
        let frames = frames_of(&seq, synth.frames, synth.fps);
        let f0 = start.unwrap_or_else(|| colmap_prior(w as u32, h as u32));
        let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let guess = colslam_camera::Camera::simple_pinhole(w as u64, h as u64, f0, cx, cy);
        let mut opts = SlamOptions::default();
        opts.refine.refine_intrinsics = true;
        opts.refine.robust_intrinsics = true;
        let r = run_reading_again(&frames, &guess, opts, Vec::new());
        assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
        let camera = r.maps[0].map.camera().expect("camera").clone();
        let (f, truth) = (camera.focal_x(), synth.focal);
        eprintln!(
            "{} frames, distortion {distortion:?}, from {f0:.1} px: {:?}, f {f:.2} px ({:+.2} %)",
            synth.frames,
            camera.model,
            100.0 * (f / truth - 1.0)
        );
        // Without the robust loss (`--robust-intrinsics`) the pinhole ended
        // 1.75 % long; without the radial term the distorted lens 9 % long.
        assert!(
            (f / truth - 1.0).abs() < 0.01,
            "{distortion:?}, from {f0:.1} px: refined focal length {f:.2} px against {truth}"
        );
    }
}

#[test]
fn a_lens_one_radial_term_does_not_describe_gets_a_second() {
    // The room through a pincushion lens (k1 0.1, k2 -0.1), run as a user
    // would without its camera file (`colslam run`: the focal length
    // estimated from the first frames, then refined). One radial term fits
    // the lens with the focal length 0.8 % long and the trajectory at 2.4x
    // the calibrated run's; the second term (RADIAL, removing 0.9 % of the
    // cost where `SECOND_RADIAL_MIN_GAIN` asks 0.5 %) brings both back
    // (measured: +0.11 % and 0.29 mm, against 0.74 mm with one term;
    // docs/benchmarks.md).
    let synth = SynthOptions { distortion: Some([0.1, -0.1, 0.0, 0.0]), ..SynthOptions::default() };
    let root = tempfile::tempdir().expect("tempdir");
    let input = root.path().join("pincushion");
    colslam_synth::generate(&synth, &input, None).expect("generate");
    std::fs::remove_file(input.join("camera.yaml")).expect("hide the calibration");
    let mut config = colslam_slam::RunConfig::new(&input, root.path().join("out"));
    config.gt = Some(input.join("groundtruth.txt"));
    let out = colslam_slam::run::run(&config, EventSink::none(), colslam_slam::RunHooks::default()).expect("run");
    assert_eq!(out.result.maps.len(), 1, "notes: {:?}", out.result.stats.notes);
    let camera = out.result.maps[0].map.camera().expect("camera").clone();
    let f = camera.focal_x();
    let ate = out.report.eval.as_ref().expect("evaluated").ate_rmse;
    let size = SyntheticSequence::new(&synth).expect("sequence").scene().room().size();
    let diagonal = (size[0].powi(2) + size[1].powi(2) + size[2].powi(2)).sqrt();
    eprintln!(
        "pincushion lens: {:?} {:?}, f {f:.2} px ({:+.2} %), ATE {:.3} mm",
        camera.model,
        camera.params,
        100.0 * (f / synth.focal - 1.0),
        1e3 * ate
    );
    assert_eq!(camera.model, colslam_camera::CameraModelId::Radial, "{camera:?}");
    assert!((f / synth.focal - 1.0).abs() < 0.004, "focal length {f:.2} px against {}", synth.focal);
    assert!(ate < 6e-5 * diagonal, "ATE {ate} m, room diagonal {diagonal} m");
}

#[test]
fn rolling_shutter_auto_finds_the_readout_of_a_synthetic_camera() {
    // A camera turning fast (5 degrees of hand-held jitter, up to ~0.5 rad/s)
    // whose rows are read over 30 ms: `auto` must find the readout (one
    // round of estimation from the uncompensated map alone gave 2-3 ms too
    // little at 640x480) and compensating must not cost accuracy; the same
    // path through a global shutter must come out under 5 ms.
    let rs = SynthOptions { readout: 0.03, jitter_rotation_deg: 5.0, ..small_synth(60, 3) };
    let mut opts = SlamOptions::default();
    opts.refine.rolling_shutter = colslam_slam::RollingShutter::Auto;
    for (synth, lo, hi) in [(rs.clone(), 0.026, 0.034), (SynthOptions { readout: 0.0, ..rs }, 0.0, 0.005)] {
        let seq = SyntheticSequence::new(&synth).expect("sequence");
        let frames = frames_of(&seq, synth.frames, synth.fps);
        let r = run(&frames, seq.camera(), opts.clone(), EventSink::none());
        assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
        let readout = r.maps[0].readout_s;
        eprintln!("synthetic readout {} s: estimated {readout} s", synth.readout);
        assert!((lo..=hi).contains(&readout), "readout {} estimated as {readout}", synth.readout);
    }
}

#[test]
fn a_second_round_of_compensation_makes_a_rolling_shutter_room_more_accurate() {
    // The synthetic camera of the test above, its 30 ms readout given: the
    // first round's angular velocities come from poses the rolling shutter
    // bent, the second's from the poses the first compensated.
    let synth = SynthOptions { readout: 0.03, jitter_rotation_deg: 5.0, ..small_synth(60, 3) };
    let seq = SyntheticSequence::new(&synth).expect("sequence");
    let frames = frames_of(&seq, synth.frames, synth.fps);
    let gt = gt_trajectory(&seq, synth.frames, synth.fps);
    let ate = |rounds: usize| {
        let mut opts = SlamOptions::default();
        opts.refine.rolling_shutter = colslam_slam::RollingShutter::Seconds(0.03);
        opts.refine.rolling_shutter_rounds = rounds;
        let r = run(&frames, seq.camera(), opts, EventSink::none());
        assert_eq!(r.maps.len(), 1, "notes: {:?}", r.stats.notes);
        assert_eq!(r.maps[0].poses.len(), synth.frames);
        evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate").ate_rmse
    };
    let (one, two) = (ate(1), ate(2));
    eprintln!("rolling-shutter room, readout given: one round {one:.6} m, two {two:.6} m");
    // Measured: 5.21 -> 4.68 mm.
    assert!(two < 0.95 * one, "one round {one} m, two {two} m");
}

/// The frames kept in memory, read again by index for the refinements that
/// look at the pixels; the `unreadable` ones fail as a lost file would.
struct KeptFrames {
    frames: Vec<Frame>,
    unreadable: Vec<usize>,
}

impl colslam_slam::FrameImages for KeptFrames {
    fn read(
        &mut self,
        frames: &[usize],
        visit: &mut dyn FnMut(usize, Result<Image, String>),
    ) -> Result<(), colslam_slam::SlamError> {
        for &i in frames {
            match self.frames.get(i) {
                Some(f) if !self.unreadable.contains(&i) => visit(i, Ok(f.image.clone())),
                _ => visit(i, Err("the file is gone".into())),
            }
        }
        Ok(())
    }
}

/// A run that can read its frames again, but not the `unreadable` ones.
fn run_reading_again(
    frames: &[Frame],
    camera: &colslam_camera::Camera,
    opts: SlamOptions,
    unreadable: Vec<usize>,
) -> SlamResult {
    let images = KeptFrames { frames: frames.to_vec(), unreadable };
    let mut slam = Slam::new(opts, camera, EventSink::none()).expect("options").with_frame_images(Box::new(images));
    for f in frames {
        slam.process(f).expect("process");
    }
    slam.finish().expect("finish")
}

/// A synthetic run that can read its frames again, and its ATE over every
/// frame and over the keyframes alone (metres).
fn run_with_images(
    seq: &SyntheticSequence,
    frames: &[Frame],
    opts: SlamOptions,
    unreadable: Vec<usize>,
) -> (SlamResult, f64, f64) {
    let r = run_reading_again(frames, seq.camera(), opts, unreadable);
    let n = frames.len();
    let fps = 30.0;
    let gt = gt_trajectory(seq, n, fps);
    let all = evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate").ate_rmse;
    let kf: Vec<_> = r.maps[0].poses.iter().filter(|p| p.keyframe).collect();
    let est = Trajectory::from_cam_from_world(
        kf.iter().map(|p| p.frame.timestamp).collect(),
        &kf.iter().map(|p| p.cam_from_world).collect::<Vec<_>>(),
    );
    let keyframes = evaluate(&gt, &est, &EvalOptions::default()).expect("evaluate").ate_rmse;
    (r, all, keyframes)
}

/// Each final refinement stage earns its place on the synthetic room: the
/// two-view tracks out of the final BAs' pose estimate, the refined
/// observations, then the robust final BA on them.
#[test]
fn each_final_refinement_stage_makes_the_synthetic_map_more_accurate() {
    let (seq, frames) = room(100);
    // The camera as given: an estimated radial term brings the robust loss
    // of refined intrinsics into the global BAs, which would hide the
    // stages' own effect.
    let mut every_track = SlamOptions::default();
    every_track.refine.refine_distortion = false;
    every_track.refine.refine_observations = false;
    // Measured before the failed alignments were searched again (the test
    // below).
    every_track.refine.realign_coarse = false;
    every_track.refine.final_ba_min_track = 2;
    let mut long_tracks = every_track.clone();
    long_tracks.refine.final_ba_min_track = SlamOptions::default().refine.final_ba_min_track;
    let mut refined = long_tracks.clone();
    refined.refine.refine_observations = true;
    refined.refine.search_local_map = LocalMapSearch::Off;
    let mut searched = refined.clone();
    searched.refine.search_local_map = LocalMapSearch::Frames;
    let mut robust = searched.clone();
    robust.refine.robust_final_ba = true;
    let mut everywhere = searched.clone();
    everywhere.refine.search_local_map = LocalMapSearch::All;
    let (_, all0, kf0) = run_with_images(&seq, &frames, every_track, Vec::new());
    let (r1, all1, kf1) = run_with_images(&seq, &frames, long_tracks, Vec::new());
    let (r2, all2, kf2) = run_with_images(&seq, &frames, refined, Vec::new());
    let (r3, all3, kf3) = run_with_images(&seq, &frames, searched, Vec::new());
    let (_, all4, kf4) = run_with_images(&seq, &frames, robust, Vec::new());
    let (_, all5, kf5) = run_with_images(&seq, &frames, everywhere, Vec::new());
    eprintln!(
        "ATE all frames {all0:.6} -> {all1:.6} -> {all2:.6} -> {all3:.6} -> {all4:.6} m, keyframes {kf0:.6} -> {kf1:.6} -> {kf2:.6} -> {kf3:.6} -> {kf4:.6} m; keyframes searched too: {all5:.6} / {kf5:.6} m"
    );
    // Measured: keyframes 2.12 -> 1.31 -> 0.80 -> 0.80 -> 0.59 mm, every
    // frame 1.81 -> 1.50 -> 0.75 -> 0.56 -> 0.50 mm (the non-keyframes'
    // observations aligned too, then their local maps searched: 0.75x).
    // Alone, the robust final BA no longer helps once the two-view
    // tracks are out (1.31 -> 1.44 mm): the mismatches it held down were
    // theirs.
    assert!(kf1 < 0.8 * kf0, "two-view tracks out: keyframes {kf0} -> {kf1}");
    assert_eq!(r1.stats.refined_observations, 0);
    assert!(r2.stats.refined_observations > 1000, "{}", r2.stats.refined_observations);
    assert!(kf2 < 0.7 * kf1, "refined observations: keyframes {kf1} -> {kf2}");
    assert!(all2 < 0.6 * all1, "refined observations: every frame {all1} -> {all2}");
    // The local map searched in every non-keyframe moves no keyframe.
    assert_eq!(kf3, kf2);
    assert!(r3.stats.refined_observations > r2.stats.refined_observations);
    assert!(all3 < 0.8 * all2, "local map searched: every frame {all2} -> {all3}");
    assert!(kf4 < 0.85 * kf3, "robust final BA: keyframes {kf3} -> {kf4}");
    // Searched in the keyframes too (`all`), their tracks grow before the
    // final BA: keyframes 0.80 -> 0.42 mm, every frame 0.57 -> 0.35 mm
    // (the tracks found kept within a quarter pixel).
    assert!(kf5 < 0.6 * kf3, "local map searched in the keyframes: keyframes {kf3} -> {kf5}");
    assert!(all5 < 0.75 * all3, "local map searched in the keyframes: every frame {all3} -> {all5}");
}

/// The keyframe observations whose alignment failed, searched again
/// within their keypoint's pyramid scale (`--realign-coarse`), make the
/// synthetic room more accurate with the default options.
#[test]
fn failed_alignments_of_coarse_keypoints_searched_again_make_the_room_more_accurate() {
    let (seq, frames) = room(100);
    let mut kept = SlamOptions::default();
    kept.refine.realign_coarse = false;
    let (_, all_kept, kf_kept) = run_with_images(&seq, &frames, kept, Vec::new());
    let (_, all, kf) = run_with_images(&seq, &frames, SlamOptions::default(), Vec::new());
    eprintln!("ATE all frames {all_kept:.6} -> {all:.6} m, keyframes {kf_kept:.6} -> {kf:.6} m");
    // Measured: every frame 0.268 -> 0.250 mm, keyframes 0.287 -> 0.258 mm.
    assert!(all < 0.97 * all_kept, "every frame: {all_kept} -> {all} m");
    assert!(kf < 0.95 * kf_kept, "keyframes: {kf_kept} -> {kf} m");
}

#[test]
fn the_tracks_found_in_the_keyframes_keep_the_drive_as_accurate() {
    // KITTI odometry: searching the keyframes' local maps too (`all`)
    // made the drive 22-40 % less accurate than searching the frames
    // between them (`frames`) while every track found was kept; kept where
    // the alignment predicts a quarter pixel or better, the two are level
    // (docs/benchmarks.md, "Found tracks gated by their alignment's
    // precision").
    let Some((dir, camera, frames)) = dataset_frames("kitti_odom00_first300") else { return };
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).expect("ground truth");
    let ate = |search: LocalMapSearch| {
        let mut opts = SlamOptions::default();
        opts.refine.search_local_map = search;
        let r = run_reading_again(&frames, &camera, opts, Vec::new());
        assert_eq!(r.maps.len(), 1);
        evaluate(&gt, &est_trajectory(&r), &EvalOptions::default()).expect("evaluate").ate_rmse
    };
    let (frames_only, all) = (ate(LocalMapSearch::Frames), ate(LocalMapSearch::All));
    eprintln!("KITTI odometry ATE: frames {frames_only:.4} m, all {all:.4} m");
    assert!(all < 1.15 * frames_only, "the keyframes searched too: {frames_only} -> {all} m");
}

#[test]
fn a_frame_that_cannot_be_read_again_keeps_its_keypoints_and_the_run_finishes() {
    let (seq, frames) = room(60);
    // Every frame unreadable but the first few: the keyframes among them
    // keep their keypoints, the rest are refined.
    let mut on = SlamOptions::default();
    on.refine.refine_observations = true;
    let (r, _, _) = run_with_images(&seq, &frames, on.clone(), (10..60).collect());
    assert_eq!(r.maps.len(), 1);
    assert_eq!(r.maps[0].poses.len(), 60);
    let unread_note = |r: &colslam_slam::SlamResult, what: &str| {
        r.stats.notes.iter().find(|n| n.contains(&format!(" {what} could not be read again"))).cloned()
    };
    let note = unread_note(&r, "keyframes").expect("a note names the keyframes");
    assert!(note.contains(".png): the file is gone"), "{note}");
    // Every non-keyframe unreadable: the keyframes are refined, each
    // non-keyframe keeps its PnP pose, and a note says so.
    let all = run_with_images(&seq, &frames, on.clone(), Vec::new()).0;
    let keyframes: Vec<usize> = all.maps[0].poses.iter().filter(|p| p.keyframe).map(|p| p.frame.index).collect();
    let (r, _, _) = run_with_images(&seq, &frames, on.clone(), (0..60).filter(|i| !keyframes.contains(i)).collect());
    assert_eq!(r.maps[0].poses.len(), 60);
    assert!(r.stats.refined_observations > 0 && r.stats.refined_observations < all.stats.refined_observations);
    assert_eq!(unread_note(&r, "keyframes"), None);
    let note = unread_note(&r, "non-keyframes").expect("a note names the non-keyframes");
    assert!(note.contains(".png): the file is gone"), "{note}");
    // Nothing readable: nothing moves, and the run still ends with its map.
    let (r, _, _) = run_with_images(&seq, &frames, on.clone(), (0..60).collect());
    assert_eq!(r.stats.refined_observations, 0);
    assert_eq!(r.maps[0].poses.len(), 60);
    // Under a rolling-shutter compensation the refinement is skipped, and said so.
    on.refine.rolling_shutter = colslam_slam::RollingShutter::Seconds(0.03);
    let (r, _, _) = run_with_images(&seq, &frames, on, Vec::new());
    assert_eq!(r.stats.refined_observations, 0);
    assert!(r.stats.notes.iter().any(|n| n.contains("observation refinement skipped")), "{:?}", r.stats.notes);
}

/// A calibration that left a small radial distortion out: the room is
/// rendered with k1 = 0.03 and the run is told the same camera without it.
/// `refine_distortion` recovers k1 from the data, and the trajectory with it.
#[test]
fn a_principal_point_given_off_centre_is_moved_back_by_the_final_ba() {
    // The room's principal point is the image centre; the camera says it is
    // 16 px right and 12 px up of it and lets the intrinsics be refined.
    // Held, the map bends around the wrong centre; freed once mapping ends
    // (`--refine-principal-point`), the final BA moves it back part of the
    // way (the room's arc of views constrains it weakly) and the trajectory
    // with it.
    let synth = SynthOptions::default();
    let seq = SyntheticSequence::new(&synth).expect("sequence");
    let frames = frames_of(&seq, synth.frames, synth.fps);
    let truth = seq.camera().clone();
    let (tx, ty) = (truth.params[2], truth.params[3]);
    let off = colslam_camera::Camera::simple_pinhole(truth.width, truth.height, synth.focal, tx + 16.0, ty - 12.0);
    let gt = gt_trajectory(&seq, synth.frames, synth.fps);
    let ate = |r: &SlamResult| evaluate(&gt, &est_trajectory(r), &EvalOptions::default()).expect("evaluate").ate_rmse;
    let mut opts = SlamOptions::default();
    opts.refine.refine_intrinsics = true;
    assert!(opts.refine.refine_principal_point, "on by default");
    let freed = run(&frames, &off, opts.clone(), EventSink::none());
    opts.refine.refine_principal_point = false;
    let held = run(&frames, &off, opts, EventSink::none());
    let centre = |r: &SlamResult| r.maps[0].map.camera().expect("camera").principal_point();
    let start = ((16.0f64).powi(2) + (12.0f64).powi(2)).sqrt();
    // The run's camera is in COLMAP's convention, the synthetic one in
    // OpenCV's: half a pixel apart.
    let dist = |c: colslam_geometry::Vec2| ((c.x - 0.5 - tx).powi(2) + (c.y - 0.5 - ty).powi(2)).sqrt();
    eprintln!(
        "principal point off by {start:.1} px: held {:.1} px, ATE {:.6} m; freed {:.1} px, ATE {:.6} m",
        dist(centre(&held)),
        ate(&held),
        dist(centre(&freed)),
        ate(&freed)
    );
    assert!((dist(centre(&held)) - start).abs() < 1e-9, "held where given");
    // Measured: 20.0 -> 12.6 px, ATE 3.41 -> 2.73 mm.
    assert!(dist(centre(&freed)) < 0.75 * start, "principal point {:?}", centre(&freed));
    assert!(ate(&freed) < 0.9 * ate(&held), "ATE {} -> {}", ate(&held), ate(&freed));
}

#[test]
fn a_residual_radial_distortion_is_recovered_from_the_data() {
    let true_k1 = 0.03;
    let opts = SynthOptions { frames: 80, distortion: Some([true_k1, 0.0, 0.0, 0.0]), ..SynthOptions::default() };
    let seq = SyntheticSequence::new(&opts).expect("sequence");
    let frames = frames_of(&seq, opts.frames, opts.fps);
    let lens = seq.camera();
    // The same calibration without its distortion.
    let pinhole = colslam_camera::Camera::new(
        colslam_camera::CameraModelId::Pinhole,
        lens.width,
        lens.height,
        lens.params[..4].to_vec(),
    )
    .expect("camera");
    let gt = gt_trajectory(&seq, opts.frames, opts.fps);
    let ate = |r: &SlamResult| evaluate(&gt, &est_trajectory(r), &EvalOptions::default()).expect("evaluate").ate_rmse;
    let mut off = SlamOptions::default();
    off.refine.refine_distortion = false;
    let held = run(&frames, &pinhole, off, EventSink::none());
    let on = SlamOptions::default();
    assert!(on.refine.refine_distortion, "on by default");
    let refined = run(&frames, &pinhole, on, EventSink::none());
    let camera = refined.maps[0].map.reconstruction().cameras().next().expect("camera").camera.clone();
    let k1 = camera.params[4];
    eprintln!("k1 {k1:.5} (true {true_k1}); ATE held {:.6} m, refined {:.6} m", ate(&held), ate(&refined));
    assert_eq!(camera.model, colslam_camera::CameraModelId::OpenCv);
    // The focal length stays as given.
    assert_eq!(camera.params[..2], lens.params[..2]);
    // Measured: k1 0.0284, ATE 2.63 -> 1.61 mm.
    assert!((k1 - true_k1).abs() < 0.005, "k1 {k1}");
    assert!(ate(&refined) < 0.8 * ate(&held), "ATE {} -> {}", ate(&held), ate(&refined));
}

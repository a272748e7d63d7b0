//! End-to-end browser tests: the viewer runs in this process on an ephemeral
//! port, and `e2e/test.mjs` drives headless Chromium through playwright-core
//! against it (load a model, track selector, clip range, picking, export and
//! reload, invalid settings, a simulated live run, a 100,000-point map, a
//! server restart). Screenshots go to a temporary folder, so tests never
//! touch the tracked files; the documentation's pictures are made on
//! request with `COLSLAM_SCREENSHOT_DIR=docs/screenshots` (a relative path
//! is taken from the workspace root; they are the same from run to run).
//!
//! Needs `node`, Chromium (`/usr/bin/chromium` or `COLSLAM_CHROMIUM`) and
//! `npm ci` in `crates/viewer/e2e` (scripts/setup-browser.sh does all).
//! Skips with a message when any is missing, except in CI (`CI=true`) where
//! it fails: a CI run that could not drive a browser must not look green.

use colslam_viewer::{
    ControlError, FrameUpdate, KeyframeUpdate, MapDelta, RunController, RunSettings, RunState, Summary, Viewer,
    ViewerCamera, ViewerOptions, ViewerPoint, ViewerUpdate, demo_reconstruction,
};
use serde_json::json;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The whole browser run must end within this (a hung browser fails the test).
const BROWSER_TIMEOUT: Duration = Duration::from_secs(240);

/// What to do when a prerequisite is missing: `Err` (the test fails) in CI,
/// `Ok` with the skip notice elsewhere.
fn missing_prerequisite(what: &str, ci: bool) -> Result<String, String> {
    if ci {
        Err(format!("CI=true but {what} (run scripts/setup-browser.sh)"))
    } else {
        Ok(format!("SKIPPED: {what} (run scripts/setup-browser.sh)"))
    }
}

fn skip_or_fail(what: &str) {
    match missing_prerequisite(what, colslam_testutil::in_ci()) {
        Ok(notice) => eprintln!("{notice}"),
        Err(failure) => panic!("{failure}"),
    }
}

#[test]
fn a_missing_browser_fails_in_ci() {
    assert!(missing_prerequisite("chromium not found", true).is_err());
    let notice = missing_prerequisite("chromium not found", false).expect("skipped outside CI");
    assert!(notice.starts_with("SKIPPED") && notice.contains("chromium not found"), "{notice}");
}

/// Where the screenshots go: `COLSLAM_SCREENSHOT_DIR` (relative to the
/// workspace root) when set, else `scratch`.
fn screenshot_dir(requested: Option<std::ffi::OsString>, root: &Path, scratch: &Path) -> PathBuf {
    match requested {
        Some(d) if !d.is_empty() => root.join(d),
        _ => scratch.to_path_buf(),
    }
}

#[test]
fn screenshots_stay_out_of_the_tree_unless_asked() {
    let (root, scratch) = (Path::new("/ws"), Path::new("/tmp/t"));
    assert_eq!(screenshot_dir(None, root, scratch), scratch);
    assert_eq!(screenshot_dir(Some("".into()), root, scratch), scratch);
    assert_eq!(screenshot_dir(Some("docs/screenshots".into()), root, scratch), root.join("docs/screenshots"));
    assert_eq!(screenshot_dir(Some("/abs/dir".into()), root, scratch), Path::new("/abs/dir"));
}

/// What the frame panel of the loaded model must show, and the ground truth
/// the "gt" step gives it.
struct FramePanel {
    config: serde_json::Value,
    gt: colslam_viewer::GroundTruthLayer,
}

/// Prepares the browser test's model for the frame panel: moves one
/// observation of the latest camera 10 px off (an outlier), writes every
/// image to `images` (blue channel = 20 x registration rank), and works out
/// what the page must show: keypoint counts from the model's structure,
/// observations of the clicked camera, the timeline's camera, and the ATE of
/// `colslam eval` (the library) on the model's TUM export against a ground
/// truth made from the cameras.
fn frame_panel_expectations(rec: &mut colslam_scene::Reconstruction, images: &Path) -> FramePanel {
    use colslam_scene::ImageId;
    let ids: Vec<ImageId> = rec.registered_image_ids().to_vec();
    let latest = *ids.last().expect("cameras");
    let slot = rec.image(latest).expect("latest").points2d.iter().position(|p| p.point3d_id.is_some()).expect("obs");
    let xy = rec.image(latest).expect("latest").points2d[slot].xy + colslam_geometry::Vec2::new(10.0, 0.0);
    rec.set_point2d_xy(latest, slot as u32, xy).expect("move keypoint");
    std::fs::create_dir_all(images).expect("images dir");
    for (rank, id) in ids.iter().enumerate() {
        let mut img = colslam_image::Image::new(96, 72, 3);
        for y in 0..72 {
            for x in 0..96 {
                img.set(x, y, 0, (x * 2) as u8);
                img.set(x, y, 1, (y * 3) as u8);
                img.set(x, y, 2, (20 * rank) as u8);
            }
        }
        img.write_png(&images.join(&rec.image(*id).expect("image").name)).expect("write image");
    }
    let observations =
        |id: ImageId| rec.image(id).expect("image").points2d.iter().filter(|p| p.point3d_id.is_some()).count();
    let kps = rec.image(latest).expect("latest").points2d.len();
    let click = ids[2];
    let timeline_rank = 4;
    // Ground truth: the camera centres in another frame and scale, two moved.
    let (stamps, centres): (Vec<f64>, Vec<colslam_geometry::Rigid3>) = ids
        .iter()
        .enumerate()
        .map(|(rank, id)| {
            let world_from_cam = rec.image(*id).expect("image").cam_from_world.inverse();
            let mut p = world_from_cam;
            p.translation = p.translation * 3.0 + colslam_geometry::Vec3::new(5.0, -1.0, 2.0);
            if rank % 3 == 1 {
                p.translation.z += 0.2;
            }
            (rank as f64, p)
        })
        .unzip();
    let gt = colslam_eval::Trajectory::new(stamps, centres);
    let dir = tempfile::tempdir().expect("tempdir");
    gt.write_tum(&dir.path().join("gt.tum")).expect("gt");
    std::fs::write(dir.path().join("est.tum"), colslam_viewer::tum_trajectory(rec)).expect("est");
    let report =
        colslam_eval::evaluate_files(&dir.path().join("gt.tum"), &dir.path().join("est.tum"), &Default::default())
            .expect("colslam eval");
    let layer = colslam_viewer::GroundTruthLayer::compute(rec, &gt, "gt.tum").expect("layer");
    let config = json!({
        "latest": {"id": latest.0, "blue": 20 * (ids.len() - 1),
                   "counts": {"triangulated": observations(latest) - 1, "outlier": 1, "unmatched": kps - observations(latest)}},
        "click": {"id": click.0, "observations": observations(click)},
        "timeline": {"rank": timeline_rank, "id": ids[timeline_rank].0},
        "gt": {"ate": report.ate_rmse, "segments": ids.len() - 1},
    });
    FramePanel { config, gt: layer }
}

fn chromium() -> Option<PathBuf> {
    let p =
        std::env::var_os("COLSLAM_CHROMIUM").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    p.exists().then_some(p)
}

#[derive(Default)]
struct MockController {
    started: Mutex<Vec<RunSettings>>,
}

impl RunController for MockController {
    fn start(&self, settings: RunSettings) -> Result<(), ControlError> {
        self.started.lock().unwrap_or_else(|e| e.into_inner()).push(settings);
        Ok(())
    }
    fn stop(&self) {}
    fn max_frames_for(&self, _input: &Path, skip: usize) -> Result<usize, ControlError> {
        Ok(100usize.div_ceil(skip))
    }
}

/// A synthetic camera picture: a checkerboard drifting with the frame index.
fn picture(frame: usize) -> colslam_image::Image {
    let (w, h) = (320, 240);
    let mut img = colslam_image::Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let cell = ((x + 4 * frame) / 24 + y / 24) % 2;
            let base = if cell == 0 { 60 } else { 170 };
            img.set(x, y, 0, (base + x / 8) as u8);
            img.set(x, y, 1, (base + y / 8) as u8);
            img.set(x, y, 2, base as u8);
        }
    }
    img
}

const LIVE_KEYFRAMES: usize = 10;
const LIVE_POINTS: usize = 400;
const FRAMES_PER_KEYFRAME: usize = 3;
/// Verified matches of each simulated frame (one flow line each) and the
/// rejected ones (drawn only on request).
const FLOW_LINES: usize = 40;
const OUTLIER_LINES: usize = 12;
/// The line the simulated run ends with.
const LIVE_FINISHED: &str = "30 of 30 frames localised, 10 keyframes, 400 points, 1 map; outputs in /data/out";
/// The message of the simulated failed run.
const LIVE_FAILED: &str = "no images in /data/empty";

/// Feeds a simulated run: frames with flow lines, and at every third frame a
/// keyframe with its camera and the points it introduces (map deltas).
fn feed_live_run(viewer: &Viewer) {
    let rec = demo_reconstruction(LIVE_KEYFRAMES, LIVE_POINTS, 11).expect("demo");
    viewer.apply(ViewerUpdate::Reset);
    let mut frame = 0;
    let (mut points, mut observations) = (0, 0);
    for (kf, image_id) in rec.registered_image_ids().iter().enumerate() {
        for j in 0..FRAMES_PER_KEYFRAME {
            frame += 1;
            let lines = (0..FLOW_LINES)
                .map(|l| {
                    let (x, y) = ((l * 37 % 300) as f32 + 10.0, (l * 53 % 220) as f32 + 10.0);
                    [x, y, x + 4.0 * (j + 1) as f32, y + 2.0]
                })
                .collect();
            let outlier_lines = (0..OUTLIER_LINES).map(|l| [5.0, 5.0 + l as f32, 300.0, 200.0]).collect();
            viewer.apply(ViewerUpdate::Frame(FrameUpdate {
                index: frame,
                image: Some(picture(frame)),
                flow_lines: lines,
                outlier_lines,
                flow_score: 0.02 * (j + 1) as f64,
                num_matches: 300 - 20 * j,
                num_inliers: FLOW_LINES,
                flow_threshold: 0.05,
                min_matches: 50,
                is_keyframe: j + 1 == FRAMES_PER_KEYFRAME,
            }));
            std::thread::sleep(Duration::from_millis(30));
        }
        let img = rec.image(*image_id).expect("image");
        viewer.apply(ViewerUpdate::Keyframe(KeyframeUpdate {
            image_id: image_id.0,
            frame_index: frame,
            name: img.name.clone(),
            image: Some(picture(frame)),
        }));
        let cam = ViewerCamera::from_image(&rec, img, u32::try_from(kf).expect("order")).expect("camera");
        let new_points: Vec<ViewerPoint> = rec
            .points3d()
            .filter(|(_, p)| p.track.iter().map(|t| t.image_id).min() == Some(*image_id))
            .map(|(id, p)| ViewerPoint::from_point(id, p))
            .collect();
        points += new_points.len();
        observations += new_points.iter().map(|p| p.observers.len()).sum::<usize>();
        viewer.apply(ViewerUpdate::MapDelta(MapDelta { points: new_points, cameras: vec![cam], ..Default::default() }));
        viewer.apply(ViewerUpdate::Summary(Summary {
            keyframes: kf + 1,
            points,
            observations,
            mean_reproj_error: 0.42,
            fps: 11.5,
            frames: frame,
            total_frames: Some(LIVE_KEYFRAMES * FRAMES_PER_KEYFRAME),
        }));
        viewer.apply(ViewerUpdate::Status(format!("registered keyframe {}", image_id.0)));
        std::thread::sleep(Duration::from_millis(80));
    }
    viewer.apply(ViewerUpdate::RunState(RunState::Finished(LIVE_FINISHED.into())));
}

const RESTART_CAMERAS: usize = 3;
const RESTART_POINTS: usize = 50;
const LARGE_POINTS: usize = 100_000;
const LARGE_CAMERAS: usize = 2_000;
/// Generous bound on the page's rebuild of the large map (JavaScript work:
/// clip, colours, frustums); a typical machine takes far less.
const LARGE_MAX_REBUILD_MS: u32 = 3000;
/// Generous bound on picking a camera by click on the large map (one pass
/// over the 2,000 cameras, none over the points).
const LARGE_MAX_PICK_MS: u32 = 100;

/// 2,000 cameras on a helix and 100,000 points around it, each observed by
/// 3 consecutive cameras.
fn large_map() -> MapDelta {
    let mut rng = colslam_geometry::SplitMix64::new(5);
    let cameras = (0..LARGE_CAMERAS)
        .map(|i| {
            let a = i as f64 * 0.01;
            let center = colslam_geometry::Vec3::new(10.0 * a.cos(), 0.02 * i as f64, 10.0 * a.sin());
            let rot = colslam_geometry::Quat::from_euler_angles(0.0, -a, 0.0);
            let world_from_cam = colslam_geometry::Rigid3::new(rot, center);
            ViewerCamera {
                image_id: i as u32 + 1,
                name: format!("{i:06}.png"),
                order: i as u32,
                cam_from_world: world_from_cam.inverse(),
                width: 640,
                height: 480,
                fx: 500.0,
                fy: 500.0,
                cx: 320.0,
                cy: 240.0,
            }
        })
        .collect();
    let points = (0..LARGE_POINTS)
        .map(|j| {
            let first = rng.below(LARGE_CAMERAS - 2) as u32 + 1;
            let a = f64::from(first) * 0.01;
            let r = rng.uniform(12.0, 16.0);
            let y = 0.02 * f64::from(first) + rng.uniform(-3.0, 3.0);
            ViewerPoint {
                id: j as u64 + 1,
                xyz: [r * a.cos(), y, r * a.sin()],
                color: [(rng.below(256)) as u8, 128, (255.0 * f64::from(first) / LARGE_CAMERAS as f64) as u8],
                observers: vec![first, first + 1, first + 2],
            }
        })
        .collect();
    MapDelta { points, cameras, ..Default::default() }
}

#[test]
fn browser_end_to_end() {
    let root = colslam_testutil::workspace_root();
    let e2e = root.join("crates/viewer/e2e");
    let node_ok = Command::new("node").arg("--version").output().map(|o| o.status.success()).unwrap_or(false);
    if !node_ok {
        return skip_or_fail("node is not installed");
    }
    let Some(chromium) = chromium() else {
        return skip_or_fail("chromium not found at /usr/bin/chromium (or COLSLAM_CHROMIUM)");
    };
    if !e2e.join("node_modules/playwright-core/package.json").is_file() {
        return skip_or_fail("playwright-core is not installed in crates/viewer/e2e (npm ci)");
    }

    let work = tempfile::tempdir().expect("tempdir");
    let model_dir = work.path().join("model");
    let mut rec = demo_reconstruction(8, 600, 7).expect("demo");
    let frames = frame_panel_expectations(&mut rec, &work.path().join("images"));
    colslam_scene::write_model(&rec, &model_dir, colslam_scene::ModelFormat::Binary).expect("write model");
    // Expected counts: camera order = image id - 1 (registered in id order);
    // a point is introduced at its smallest observer's order.
    let intro = |p: &colslam_scene::Point3D| p.track.iter().map(|t| t.image_id.0 - 1).min().expect("track");
    let (clip_start, clip_end) = (2u32, 4u32);
    let clip_points = rec.points3d().filter(|(_, p)| (clip_start..=clip_end).contains(&intro(p))).count();
    let (track_id, track_point) = rec.points3d().find(|(_, p)| intro(p) == 3).expect("a point introduced at 3");
    let track_lines = track_point.track.len();
    let clip_track_lines =
        track_point.track.iter().filter(|t| (clip_start..=clip_end).contains(&(t.image_id.0 - 1))).count();
    assert!(clip_track_lines < track_lines, "the clip must cut the chosen track");

    let shots = screenshot_dir(std::env::var_os("COLSLAM_SCREENSHOT_DIR"), &root, &work.path().join("screenshots"));
    std::fs::create_dir_all(&shots).expect("screenshot dir");
    let mut viewer = Viewer::start(ViewerOptions { port: 0, ..Default::default() }).expect("viewer");
    let controller = Arc::new(MockController::default());
    viewer.set_controller(controller.clone());

    let config = json!({
        "url": viewer.url(),
        "chromium": chromium,
        "shots": shots,
        "model_dir": model_dir,
        "bad_model_dir": work.path().join("not-a-model"),
        "work_dir": work.path(),
        "run_input": "/data/sequence",
        "run_bound_skip2": 50,
        "model": {
            "points": rec.num_points3d(), "cameras": rec.num_registered_images(),
            "track": {"id": track_id.0, "lines": track_lines},
            "clip": {"start": clip_start, "end": clip_end, "points": clip_points, "cameras": clip_end - clip_start + 1,
                     "track_lines": clip_track_lines},
        },
        "restart": {"points": RESTART_POINTS, "cameras": RESTART_CAMERAS},
        "frames": frames.config,
        "large": {"points": LARGE_POINTS, "cameras": LARGE_CAMERAS, "max_rebuild_ms": LARGE_MAX_REBUILD_MS,
                  "max_pick_ms": LARGE_MAX_PICK_MS},
        "live": {
            "cameras": LIVE_KEYFRAMES, "points": LIVE_POINTS, "last_keyframe_id": LIVE_KEYFRAMES,
            "last_frame": LIVE_KEYFRAMES * FRAMES_PER_KEYFRAME, "flow_lines": FLOW_LINES,
            "outlier_lines": OUTLIER_LINES, "finished": LIVE_FINISHED, "failed": LIVE_FAILED,
        },
    });
    let config_path = work.path().join("config.json");
    std::fs::write(&config_path, config.to_string()).expect("config");

    let mut child = Command::new("node")
        .arg(e2e.join("test.mjs"))
        .arg(&config_path)
        .current_dir(&e2e)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn node");
    let pid = child.id();
    // Watchdog: a hung browser must fail the test, not hang it.
    let finished = Arc::new(std::sync::atomic::AtomicBool::new(false));
    {
        let finished = Arc::clone(&finished);
        std::thread::spawn(move || {
            let start = std::time::Instant::now();
            while start.elapsed() < BROWSER_TIMEOUT {
                if finished.load(std::sync::atomic::Ordering::SeqCst) {
                    return;
                }
                std::thread::sleep(Duration::from_millis(200));
            }
            eprintln!("browser test timed out; killing node (pid {pid})");
            let _ = Command::new("kill").arg(pid.to_string()).status();
        });
    }
    let mut stderr = child.stderr.take().expect("stderr");
    let log = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stderr.read_to_string(&mut s);
        s
    });
    let mut stdin = child.stdin.take().expect("stdin");
    let stdout = BufReader::new(child.stdout.take().expect("stdout"));
    let mut result = String::new();
    for line in stdout.lines() {
        let line = line.expect("stdout line");
        match line.strip_prefix("STEP ") {
            Some("run-started") => {
                let started = controller.started.lock().expect("lock").clone();
                assert_eq!(started.len(), 1, "exactly one run started (invalid settings were refused)");
                let s = &started[0];
                assert_eq!((s.skip, s.init_frames, s.max_frames), (2, 20, None));
                assert_eq!(s.input, PathBuf::from("/data/sequence"));
                assert_eq!(
                    (s.extractor, s.matcher),
                    (colslam_viewer::Extractor::Xfeat, colslam_viewer::Matcher::Lighterglue)
                );
                writeln!(stdin, "DONE run-started").expect("ack");
            }
            Some("large") => {
                let t = std::time::Instant::now();
                viewer.apply(ViewerUpdate::Reset);
                viewer.apply(ViewerUpdate::MapDelta(large_map()));
                eprintln!("PERF large map built and applied in {:?}", t.elapsed());
                writeln!(stdin, "DONE large").expect("ack");
            }
            Some("large-delta") => {
                let p = ViewerPoint {
                    id: LARGE_POINTS as u64 + 1,
                    xyz: [0.0, 0.0, 0.0],
                    color: [255, 0, 0],
                    observers: vec![1],
                };
                viewer.apply(ViewerUpdate::MapDelta(MapDelta { points: vec![p], ..Default::default() }));
                writeln!(stdin, "DONE large-delta").expect("ack");
            }
            Some("restart") => {
                // The server goes away and comes back on the same port (a
                // restarted `colslam view`): the page must reconnect by
                // itself and show the new server's whole state.
                let port = viewer.local_addr().port();
                viewer.shutdown();
                viewer = Viewer::start(ViewerOptions { port, ..Default::default() }).expect("restart on the same port");
                viewer.set_reconstruction(&demo_reconstruction(RESTART_CAMERAS, RESTART_POINTS, 3).expect("demo"));
                writeln!(stdin, "DONE restart").expect("ack");
            }
            Some("gt") => {
                viewer.set_ground_truth(Some(frames.gt.clone()));
                writeln!(stdin, "DONE gt").expect("ack");
            }
            Some("live") => {
                feed_live_run(&viewer);
                writeln!(stdin, "DONE live").expect("ack");
            }
            Some("live-failed") => {
                viewer.apply(ViewerUpdate::RunState(RunState::Running));
                viewer.apply(ViewerUpdate::RunState(RunState::Failed(LIVE_FAILED.into())));
                writeln!(stdin, "DONE live-failed").expect("ack");
            }
            Some(other) => panic!("unknown step {other}"),
            None => result = line,
        }
    }
    let status = child.wait().expect("wait node");
    finished.store(true, std::sync::atomic::Ordering::SeqCst);
    let log = log.join().unwrap_or_default();
    eprintln!("{log}");
    assert!(status.success() && result == "ALL OK", "browser scenarios failed ({result}):\n{log}");
    for name in [
        "viewer-camera-panel.png",
        "viewer-ground-truth.png",
        "viewer-reconstruction.png",
        "viewer-frame-view.png",
        "viewer-overview.png",
        "viewer-track.png",
    ] {
        let png = std::fs::read(shots.join(name)).expect("screenshot written");
        assert!(png.starts_with(b"\x89PNG"), "{name} is a PNG");
    }
}

/// `colslam view MODEL --screenshot`'s library side: headless Chromium draws
/// the page in screenshot mode (no event stream) and the picture is written
/// once the page says the scene and the camera panel are drawn; the same
/// input gives the same bytes.
#[test]
fn screenshot_mode_writes_the_drawn_page() {
    let Some(chromium) = chromium() else {
        return skip_or_fail("chromium not found at /usr/bin/chromium (or COLSLAM_CHROMIUM)");
    };
    let work = tempfile::tempdir().expect("tempdir");
    let model_dir = work.path().join("model");
    let mut rec = demo_reconstruction(8, 600, 7).expect("demo");
    frame_panel_expectations(&mut rec, &work.path().join("images"));
    colslam_scene::write_model(&rec, &model_dir, colslam_scene::ModelFormat::Binary).expect("write model");
    let viewer = Viewer::start(ViewerOptions { port: 0, ..Default::default() }).expect("viewer");
    viewer.set_reconstruction_from(&rec, "model");
    viewer.set_images(colslam_viewer::ImageSource::discover(&model_dir, &rec));
    let size = (640, 400);
    let shots: Vec<Vec<u8>> = ["a.png", "b.png"]
        .iter()
        .map(|name| {
            let out = work.path().join(name);
            colslam_viewer::screenshot::capture(&chromium, &viewer.url(), size, &out).expect("screenshot");
            std::fs::read(&out).expect("read screenshot")
        })
        .collect();
    assert!(shots[0] == shots[1], "the same model gave two different pictures");
    let img = colslam_image::Image::decode(&shots[0], Path::new("a.png")).expect("a PNG");
    assert_eq!((img.width(), img.height()), (640, 400));
    let colours: std::collections::HashSet<Vec<u8>> = img.data().chunks(img.channels()).map(<[u8]>::to_vec).collect();
    assert!(colours.len() > 50, "a near-uniform picture ({} colours)", colours.len());
}

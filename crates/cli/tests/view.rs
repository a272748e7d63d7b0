//! `colslam view` and `colslam run --view` end to end: the real binary as a
//! subprocess on an ephemeral port, read through its HTTP API and event
//! stream; and (when node, playwright-core and Chromium are installed) a run
//! started from the page's settings panel in headless Chromium.

use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_colslam");

/// A run on the small synthetic sequence takes a few seconds; this bounds a hang.
const RUN_TIMEOUT: Duration = Duration::from_secs(120);

/// Kills the child when the test ends, however it ends.
struct Guard(Child);

impl Drop for Guard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Spawns the binary and reads the viewer URL from its first stdout line.
fn spawn_viewer(args: &[&std::ffi::OsStr]) -> (Guard, String, BufReader<ChildStdout>) {
    let mut child = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn colslam");
    let mut out = BufReader::new(child.stdout.take().expect("stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("first line");
    let url = line.trim().strip_prefix("viewer: ").unwrap_or_else(|| panic!("first line names the URL: {line:?}"));
    (Guard(child), url.trim_end_matches('/').to_string(), out)
}

fn host_of(url: &str) -> &str {
    url.strip_prefix("http://").expect("http URL")
}

/// One HTTP request; returns status and body.
fn request(url: &str, method: &str, path: &str, body: Option<&Value>) -> (u16, String) {
    let host = host_of(url);
    let mut s = TcpStream::connect(host).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(30))).expect("timeout");
    let body = body.map(|b| b.to_string()).unwrap_or_default();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .expect("send");
    let mut resp = String::new();
    s.read_to_string(&mut resp).expect("read response");
    let status = resp.split(' ').nth(1).and_then(|c| c.parse().ok()).expect("status code");
    let body = resp.split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or_default();
    (status, body)
}

fn get_json(url: &str, path: &str) -> Value {
    let (status, body) = request(url, "GET", path, None);
    assert_eq!(status, 200, "GET {path}: {body}");
    serde_json::from_str(&body).expect("JSON")
}

/// The small synthetic sequence (40 frames, 320 x 240) in `dir/seq`.
fn synthetic(dir: &Path) -> PathBuf {
    synthetic_frames(dir, 40)
}

/// A synthetic sequence of `frames` frames at 320x240.
fn synthetic_frames(dir: &Path, frames: usize) -> PathBuf {
    let seq = dir.join("seq");
    let status = Command::new(BIN)
        .args(["-q", "demo", "--generate-only", "--frames", &frames.to_string(), "--width", "320", "--height", "240"])
        .arg("-o")
        .arg(&seq)
        .status()
        .expect("run demo");
    assert!(status.success(), "demo --generate-only failed");
    seq
}

/// Frames of the browser scenario: enough that the run lasts long enough
/// (a few seconds) for the page's 30 ms polling to see keyframes change
/// while it goes on; 40 frames took under a second once the pipeline got
/// faster, and the page saw at most one keyframe.
const BROWSER_RUN_FRAMES: usize = 200;

#[test]
fn view_serves_a_model_and_refuses_a_bad_folder() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = dir.path().join("model");
    let rec = colslam_viewer::demo_reconstruction(6, 300, 5).expect("demo model");
    colslam_scene::write_model(&rec, &model, colslam_scene::ModelFormat::Binary).expect("write model");

    let (_child, url, _out) = spawn_viewer(&["view".as_ref(), model.as_os_str(), "--port".as_ref(), "0".as_ref()]);
    let state = get_json(&url, "/api/state");
    assert_eq!(state["full"], true);
    assert_eq!(state["points"]["ids"].as_array().map(Vec::len), Some(rec.num_points3d()));
    assert_eq!(state["cameras"].as_array().map(Vec::len), Some(rec.num_registered_images()));
    assert_eq!(state["summary"]["points"], rec.num_points3d());
    assert_eq!(state["has_controller"], true, "the page's Run button is enabled");
    assert_eq!(state["run"]["state"], "idle");

    let bad = dir.path().join("no-model-here");
    std::fs::create_dir_all(&bad).expect("mkdir");
    let out = Command::new(BIN).args(["view", "--port", "0"]).arg(&bad).output().expect("run view");
    assert!(!out.status.success(), "a folder without a model must fail");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no-model-here") && err.contains("no COLMAP model"), "clear error: {err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("viewer:"), "no server started");
}

/// Reads `update` events until the stream ends or `deadline`.
fn read_events(url: &str, deadline: Instant) -> Vec<Value> {
    let host = host_of(url);
    let mut s = TcpStream::connect(host).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    write!(s, "GET /events HTTP/1.1\r\nHost: {host}\r\n\r\n").expect("send");
    let mut r = BufReader::new(s);
    let mut events = Vec::new();
    let mut line = String::new();
    while Instant::now() < deadline {
        line.clear();
        match r.read_line(&mut line) {
            Ok(0) => break,
            Ok(_) => {
                if let Some(data) = line.trim_end().strip_prefix("data: ") {
                    events.push(serde_json::from_str(data).expect("event JSON"));
                }
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => panic!("event stream: {e}"),
        }
    }
    events
}

/// `colslam -q run INPUT -o OUT [extra] --view --port 0 --view-exit`: its
/// exit status and every event the page was sent (the stream ends when the
/// process exits after the run).
fn run_followed(input: &Path, out: &Path, extra: &[&std::ffi::OsStr]) -> (std::process::ExitStatus, Vec<Value>) {
    let mut args: Vec<&std::ffi::OsStr> =
        vec!["-q".as_ref(), "run".as_ref(), input.as_os_str(), "-o".as_ref(), out.as_os_str()];
    args.extend_from_slice(extra);
    args.extend(["--view", "--port", "0", "--view-exit"].map(std::ffi::OsStr::new));
    let (mut child, url, _stdout) = spawn_viewer(&args);
    let events = read_events(&url, Instant::now() + RUN_TIMEOUT);
    (child.0.wait().expect("wait"), events)
}

#[test]
fn run_with_view_streams_keyframes_live() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic(dir.path());
    let out = dir.path().join("out");
    let gt = seq.join("groundtruth.txt");
    let (status, events) = run_followed(&seq, &out, &["--gt".as_ref(), gt.as_os_str()]);
    assert!(status.success(), "run --view failed");
    assert!(out.join("cameras.bin").is_file(), "outputs written");

    let live_keyframes: std::collections::BTreeSet<u64> =
        events.iter().filter(|e| e["full"] == false).filter_map(|e| e["keyframe"]["image_id"].as_u64()).collect();
    assert!(live_keyframes.len() >= 2, "keyframes arrive as increments while the run goes on: {live_keyframes:?}");
    let with_lines = events.iter().filter(|e| e["frame"]["lines"].as_array().is_some_and(|a| !a.is_empty())).count();
    assert!(with_lines > 0, "frames come with flow lines");
    // One flow line per verified match, and verification rejected some.
    let frames: Vec<&Value> =
        events.iter().filter_map(|e| e.get("frame")).filter(|f| f["num_matches"].as_u64() > Some(0)).collect();
    for f in &frames {
        let lines = f["lines"].as_array().map_or(0, Vec::len) / 4;
        assert_eq!(Some(lines as u64), f["num_inliers"].as_u64(), "frame {}", f["index"]);
    }
    assert!(frames.iter().any(|f| f["num_inliers"].as_u64() < f["num_matches"].as_u64()), "some matches were rejected");
    assert!(events.iter().any(|e| e["frame"]["picture"].is_u64()), "frames come with their picture");
    let live_points = events
        .iter()
        .filter(|e| e["full"] == false)
        .any(|e| e["points"]["ids"].as_array().is_some_and(|a| !a.is_empty()));
    assert!(live_points, "map increments arrive during the run");
    let states: Vec<&str> = events.iter().filter_map(|e| e["run"]["state"].as_str()).collect();
    assert!(states.contains(&"running"), "states: {states:?}");
    assert_eq!(states.last(), Some(&"finished"), "the run ends finished: {states:?}");
    let last_summary = events.iter().rev().find_map(|e| e.get("summary")).expect("a summary");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report")).expect("json");
    assert_eq!(last_summary["points"], report["points"], "the final model is shown");
    // With --gt the final model comes with the comparison layer: the
    // model's cameras (the keyframes) against the ground truth, each one
    // matched. The report's ATE is over every localised frame, so the two
    // figures differ.
    let layer = events.iter().rev().find_map(|e| e.get("gt").filter(|g| !g.is_null())).expect("a ground-truth layer");
    let (layer_ate, run_ate) = (layer["ate_rmse"].as_f64(), report["eval"]["ate_rmse"].as_f64());
    assert!(layer_ate.is_some_and(|a| a.is_finite() && a >= 0.0), "{layer}");
    assert!(run_ate.is_some(), "the run evaluated: {}", report["eval"]);
    assert_eq!(layer["matched"].as_u64(), report["keyframes"].as_u64(), "one pose per keyframe of the model");
}

#[test]
fn view_runs_the_pipeline_from_the_page_api() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic(dir.path());
    let out = dir.path().join("out");
    let (_child, url, _stdout) = spawn_viewer(&["-q".as_ref(), "view".as_ref(), "--port".as_ref(), "0".as_ref()]);
    let (status, body) = request(&url, "POST", "/api/max_frames", Some(&serde_json::json!({"input": seq, "skip": 3})));
    assert_eq!(status, 200, "{body}");
    let bound: Value = serde_json::from_str(&body).expect("JSON");
    assert_eq!(bound["max_frames"], 14, "40 frames with skip 3");
    let (status, body) = request(
        &url,
        "POST",
        "/api/run",
        Some(&serde_json::json!({"input": dir.path().join("missing"), "output": out})),
    );
    assert_eq!(status, 400, "a missing input is refused at once: {body}");
    let (status, body) = request(&url, "POST", "/api/run", Some(&serde_json::json!({"input": seq, "output": out})));
    assert_eq!(status, 200, "run started: {body}");
    let deadline = Instant::now() + RUN_TIMEOUT;
    let state = loop {
        let st = get_json(&url, "/api/state");
        if st["run"]["state"] == "finished" || st["run"]["state"] == "failed" {
            break st;
        }
        assert!(Instant::now() < deadline, "run did not end: {}", st["run"]);
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(state["run"]["state"], "finished", "{}", state["run"]);
    let kf = state["summary"]["keyframes"].as_u64().unwrap_or(0);
    assert!(kf >= 2, "keyframes: {}", state["summary"]);
    assert_eq!(state["cameras"].as_array().map(Vec::len), Some(kf as usize));
    assert!(out.join("cameras.bin").is_file(), "outputs written");
    // Export of the final model from the page.
    let ply = dir.path().join("cloud.ply");
    let (status, body) = request(&url, "POST", "/api/export", Some(&serde_json::json!({"path": ply, "format": "ply"})));
    assert_eq!(status, 200, "{body}");
    assert!(std::fs::read(&ply).expect("ply").starts_with(b"ply"));
    // A second run, stopped right after it starts: it ends early, still
    // writes its outputs, and says so in the report.
    // (A longer sequence, so that the stop cannot come after its last frame.)
    let long_dir = dir.path().join("long");
    std::fs::create_dir_all(&long_dir).expect("mkdir");
    let long = synthetic_frames(&long_dir, BROWSER_RUN_FRAMES);
    let out2 = dir.path().join("out2");
    let (status, body) = request(&url, "POST", "/api/run", Some(&serde_json::json!({"input": long, "output": out2})));
    assert_eq!(status, 200, "second run started: {body}");
    let (status, body) = request(&url, "POST", "/api/stop", Some(&serde_json::json!({})));
    assert_eq!(status, 200, "{body}");
    let deadline = Instant::now() + RUN_TIMEOUT;
    while !out2.join("report.json").is_file() || get_json(&url, "/api/state")["run"]["state"] != "stopped" {
        assert!(Instant::now() < deadline, "stopped run did not end");
        std::thread::sleep(Duration::from_millis(100));
    }
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out2.join("report.json")).expect("report")).expect("json");
    assert!(
        report["frames"].as_u64().is_some_and(|n| n < BROWSER_RUN_FRAMES as u64),
        "stopped early: {} frames",
        report["frames"]
    );
    assert!(report["notes"].to_string().contains("stopped on request"), "notes: {}", report["notes"]);
    let run = &get_json(&url, "/api/state")["run"];
    let line = format!("of {} frames localised", report["frames"]);
    assert!(run["message"].as_str().is_some_and(|m| m.contains(&line) && m.contains("out2")), "{run}");
}

/// A folder of frames whose headers are valid (so a run starts) but whose
/// pixel data is cut off: every frame fails to decode and the run fails.
fn broken_frames(dir: &Path) -> PathBuf {
    let seq = dir.join("broken");
    std::fs::create_dir_all(&seq).expect("mkdir");
    for i in 0..3 {
        let p = seq.join(format!("{i:03}.png"));
        colslam_image::Image::new(32, 24, 1).write_png(&p).expect("png");
        let bytes = std::fs::read(&p).expect("read");
        std::fs::write(&p, &bytes[..40]).expect("truncate");
    }
    seq
}

#[test]
fn run_with_view_shows_a_failed_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let empty = dir.path().join("no-images-here");
    std::fs::create_dir_all(&empty).expect("mkdir");
    let out = dir.path().join("out");
    let (status, events) = run_followed(&empty, &out, &[]);
    assert!(!status.success(), "a failed run fails the command");
    let run = events.iter().rev().find_map(|e| e.get("run")).expect("a run state");
    assert_eq!(run["state"], "failed", "{run}");
    let msg = run["message"].as_str().unwrap_or("");
    assert!(msg.contains("no-images-here"), "the message names the input: {msg}");
}

fn skip_or_fail(what: &str) {
    if colslam_testutil::in_ci() {
        panic!("CI=true but {what} (run scripts/setup-browser.sh)");
    }
    eprintln!("SKIPPED: {what} (run scripts/setup-browser.sh)");
}

/// The acceptance scenario in a real browser: start a run on the
/// synthetic default from the settings panel and see keyframes arrive live.
#[test]
fn browser_run_from_the_settings_panel() {
    let root = colslam_testutil::workspace_root();
    let playwright = root.join("crates/viewer/e2e/node_modules/playwright-core/index.mjs");
    let chromium =
        std::env::var_os("COLSLAM_CHROMIUM").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    let node_ok = Command::new("node").arg("--version").output().map(|o| o.status.success()).unwrap_or(false);
    if !node_ok {
        return skip_or_fail("node is not installed");
    }
    if !chromium.exists() {
        return skip_or_fail("chromium not found at /usr/bin/chromium (or COLSLAM_CHROMIUM)");
    }
    if !playwright.is_file() {
        return skip_or_fail("playwright-core is not installed in crates/viewer/e2e (npm ci)");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic_frames(dir.path(), BROWSER_RUN_FRAMES);
    let out = dir.path().join("out");
    let (_child, url, _stdout) = spawn_viewer(&["-q".as_ref(), "view".as_ref(), "--port".as_ref(), "0".as_ref()]);
    let config = serde_json::json!({
        "url": format!("{url}/"),
        "frames": BROWSER_RUN_FRAMES,
        "chromium": chromium,
        "playwright": format!("file://{}", playwright.display()),
        "input": seq,
        "output": out,
        "broken_input": broken_frames(dir.path()),
        "broken_output": dir.path().join("broken-out"),
        // Only on request: the picture shows timings, so it changes from run to run.
        // (A relative folder is taken from the workspace root, as in the viewer's browser test.)
        "shot": std::env::var_os("COLSLAM_SCREENSHOT_DIR").map(|d| root.join(d).join("viewer-live-run.png")),
    });
    let config_path = dir.path().join("config.json");
    std::fs::write(&config_path, config.to_string()).expect("config");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/e2e_run.mjs");
    let mut node = Command::new("node")
        .arg(&script)
        .arg(&config_path)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn node");
    // Watchdog: a hung browser fails the test instead of hanging it.
    let deadline = Instant::now() + RUN_TIMEOUT;
    let status = loop {
        if let Some(s) = node.try_wait().expect("wait node") {
            break Some(s);
        }
        if Instant::now() > deadline {
            let _ = node.kill();
            let _ = node.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut log = String::new();
    if let Some(mut e) = node.stderr.take() {
        let _ = e.read_to_string(&mut log);
    }
    let mut result = String::new();
    if let Some(mut o) = node.stdout.take() {
        let _ = o.read_to_string(&mut result);
    }
    eprintln!("{log}");
    assert!(status.is_some_and(|s| s.success()) && result.trim() == "ALL OK", "browser run failed ({result}):\n{log}");
    assert!(out.join("cameras.bin").is_file(), "the run wrote its outputs");
}

//! Server tests with a raw `TcpStream` client: static files, state snapshot
//! and increments, event streams with reconnects, bad requests, abrupt
//! disconnects, run control, load and export.

use super::*;
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Ipv4Addr, TcpStream};
use std::sync::Mutex;
use std::time::{Duration, Instant};

pub(crate) fn start() -> Viewer {
    Viewer::start(ViewerOptions { bind: IpAddr::V4(Ipv4Addr::LOCALHOST), port: 0, ..Default::default() })
        .expect("start viewer")
}

/// Sends raw bytes, returns (status, body).
pub(crate) fn raw(v: &Viewer, request: &[u8]) -> (u16, Vec<u8>) {
    let (status, _, body) = raw_to(v.local_addr(), request);
    (status, body)
}

pub(crate) fn get(v: &Viewer, path: &str) -> (u16, Vec<u8>) {
    raw(v, format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").as_bytes())
}

pub(crate) fn get_json(v: &Viewer, path: &str) -> (u16, Value) {
    let (code, body) = get(v, path);
    (code, serde_json::from_slice(&body).expect("json body"))
}

pub(crate) fn post(v: &Viewer, path: &str, body: &str) -> (u16, Value) {
    let req = format!(
        "POST {path} HTTP/1.1\r\nHost: localhost:1\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    let (code, body) = raw(v, req.as_bytes());
    (code, serde_json::from_slice(&body).expect("json body"))
}

/// An open event stream.
struct Events {
    reader: BufReader<TcpStream>,
}

impl Events {
    fn open(v: &Viewer) -> Events {
        let mut s = TcpStream::connect(v.local_addr()).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
        s.write_all(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: text/event-stream\r\n\r\n").expect("write");
        let mut reader = BufReader::new(s);
        let mut line = String::new();
        reader.read_line(&mut line).expect("status line");
        assert!(line.starts_with("HTTP/1.1 200"), "{line}");
        let mut ctype = false;
        loop {
            line.clear();
            reader.read_line(&mut line).expect("header");
            if line == "\r\n" {
                break;
            }
            ctype |= line.to_ascii_lowercase().starts_with("content-type: text/event-stream");
        }
        assert!(ctype, "event stream content type");
        Events { reader }
    }

    /// The next `update` event's JSON.
    fn next(&mut self) -> Value {
        let mut line = String::new();
        loop {
            line.clear();
            let n = self.reader.read_line(&mut line).expect("event line");
            assert!(n > 0, "stream ended");
            if let Some(data) = line.strip_prefix("data: ") {
                return serde_json::from_str(data.trim_end()).expect("event json");
            }
        }
    }
}

fn ids(v: &Value) -> Vec<u64> {
    v["points"]["ids"].as_array().map(|a| a.iter().filter_map(Value::as_u64).collect()).unwrap_or_default()
}

fn point(id: u64, x: f64, observers: Vec<u32>) -> ViewerPoint {
    ViewerPoint { id, xyz: [x, 0.0, 1.0], color: [10, 20, 30], observers }
}

#[test]
fn serves_the_embedded_page() {
    let v = start();
    let (code, body) = get(&v, "/");
    assert_eq!(code, 200);
    assert!(String::from_utf8_lossy(&body).contains("<canvas id=\"gl\">"));
    let (code, body) = get(&v, "/app.js");
    assert_eq!(code, 200);
    assert!(String::from_utf8_lossy(&body).contains("EventSource"));
    assert_eq!(get(&v, "/style.css").0, 200);
    assert!(v.url().starts_with("http://127.0.0.1:"));
    assert_ne!(v.local_addr().port(), 0, "ephemeral port reported");
}

#[test]
fn bad_requests_get_4xx() {
    let v = start();
    assert_eq!(get(&v, "/nope").0, 404);
    assert_eq!(raw(&v, b"DELETE /api/state HTTP/1.1\r\n\r\n").0, 405);
    assert_eq!(raw(&v, b"GET /api/run HTTP/1.1\r\n\r\n").0, 405);
    assert_eq!(raw(&v, b"garbage\r\n\r\n").0, 400);
    assert_eq!(raw(&v, b"GET / SPDY/9\r\n\r\n").0, 505);
    assert_eq!(raw(&v, b"POST /api/load HTTP/1.1\r\nContent-Length: nine\r\n\r\n").0, 400);
    // Other sites may not drive the viewer through the user's browser.
    let port = v.local_addr().port();
    let evil_host = format!("GET /api/state HTTP/1.1\r\nHost: evil.example:{port}\r\n\r\n");
    assert_eq!(raw(&v, evil_host.as_bytes()).0, 403);
    let evil_origin =
        format!("GET /api/state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://evil.example\r\n\r\n");
    assert_eq!(raw(&v, evil_origin.as_bytes()).0, 403);
    let same_origin =
        format!("GET /api/state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://127.0.0.1:{port}\r\n\r\n");
    assert_eq!(raw(&v, same_origin.as_bytes()).0, 200);
    let form = "POST /api/export HTTP/1.1\r\nContent-Type: text/plain\r\nContent-Length: 2\r\n\r\n{}";
    assert_eq!(raw(&v, form.as_bytes()).0, 415);
    assert_eq!(raw(&v, b"POST /api/load HTTP/1.1\r\nContent-Length: 99999999999\r\n\r\n").0, 413);
    let huge = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(20_000));
    assert_eq!(raw(&v, huge.as_bytes()).0, 431);
    assert_eq!(post(&v, "/api/load", "{not json").0, 400);
    assert_eq!(post(&v, "/api/load", "{}").0, 400);
    assert_eq!(get(&v, "/api/state?epoch=x&since=1").0, 400);
    assert_eq!(post(&v, "/api/export", r#"{"path":"/tmp/x","format":"jpeg"}"#).0, 400);
    // No picture yet.
    assert_eq!(get(&v, "/api/frame.png").0, 404);
    // Still serving after all that.
    assert_eq!(get(&v, "/").0, 200);
}

#[test]
fn snapshot_and_increments() {
    let v = start();
    let rec = demo_reconstruction(4, 50, 1).expect("demo");
    v.set_reconstruction(&rec);
    let (code, full) = get_json(&v, "/api/state");
    assert_eq!(code, 200);
    assert_eq!(full["full"], true);
    assert_eq!(ids(&full).len(), 50);
    assert_eq!(full["cameras"].as_array().map(Vec::len), Some(4));
    assert_eq!(full["summary"]["points"], 50);
    // Tracks: three observers per point, flattened.
    assert_eq!(full["points"]["track"].as_array().map(Vec::len), Some(150));
    // Orders are the registration order.
    let orders: Vec<u64> =
        full["cameras"].as_array().into_iter().flatten().filter_map(|c| c["order"].as_u64()).collect();
    assert_eq!(orders, vec![0, 1, 2, 3]);
    let (epoch, version) = (full["epoch"].as_u64().unwrap_or(0), full["version"].as_u64().unwrap_or(0));

    v.apply(ViewerUpdate::MapDelta(MapDelta {
        points: vec![point(1000, 0.5, vec![1])],
        removed_points: vec![1, 2],
        ..Default::default()
    }));
    let (_, delta) = get_json(&v, &format!("/api/state?epoch={epoch}&since={version}"));
    assert_eq!(delta["full"], false);
    assert_eq!(ids(&delta), vec![1000], "only the new point");
    assert_eq!(delta["removed_points"], serde_json::json!([1, 2]));
    assert_eq!(delta["cameras"].as_array().map(Vec::len), Some(0));
    assert!(delta.get("summary").is_none(), "unchanged parts are left out");
    // A stale epoch gets the full state.
    let (_, stale) = get_json(&v, &format!("/api/state?epoch={}&since={version}", epoch + 7));
    assert_eq!(stale["full"], true);
    assert_eq!(ids(&stale).len(), 49);
    // Non-map updates do not resend the map.
    let v2 = delta["version"].as_u64().unwrap_or(0);
    v.apply(ViewerUpdate::Status("hello".into()));
    let (_, d2) = get_json(&v, &format!("/api/state?epoch={epoch}&since={v2}"));
    assert!(d2.get("points").is_none());
    assert_eq!(d2["status"], "hello");
}

#[test]
fn sync_sends_only_the_difference() {
    let v = start();
    let mut rec = demo_reconstruction(3, 20, 2).expect("demo");
    v.sync_reconstruction(&rec);
    let (_, s0) = get_json(&v, "/api/state");
    assert_eq!(ids(&s0).len(), 20);
    let (epoch, version) = (s0["epoch"].as_u64().unwrap_or(0), s0["version"].as_u64().unwrap_or(0));
    let moved = colslam_scene::Point3DId(5);
    if let Some(p) = rec.point3d_xyz_mut(moved) {
        p.x += 1.0;
    }
    rec.delete_point3d(colslam_scene::Point3DId(7)).expect("delete");
    v.sync_reconstruction(&rec);
    let (_, d) = get_json(&v, &format!("/api/state?epoch={epoch}&since={version}"));
    assert_eq!(d["full"], false);
    assert_eq!(ids(&d), vec![5]);
    assert_eq!(d["removed_points"], serde_json::json!([7]));
    assert_eq!(d["cameras"].as_array().map(Vec::len), Some(0), "unchanged cameras are not resent");
    assert_eq!(d["summary"]["points"], 19);
    assert_eq!(v.handle().counts(), (19, 3));
}

#[test]
fn event_stream_snapshot_increments_and_reconnect() {
    let v = start();
    v.set_reconstruction(&demo_reconstruction(3, 30, 3).expect("demo"));
    let mut ev = Events::open(&v);
    let first = ev.next();
    assert_eq!(first["full"], true);
    assert_eq!(ids(&first).len(), 30);

    v.apply(ViewerUpdate::MapDelta(MapDelta { points: vec![point(500, 1.0, vec![1, 2])], ..Default::default() }));
    let d = ev.next();
    assert_eq!(d["full"], false);
    assert_eq!(ids(&d), vec![500]);

    v.apply(ViewerUpdate::Frame(FrameUpdate {
        index: 12,
        image: Some(colslam_image::Image::new(8, 6, 3)),
        flow_lines: vec![[0.0, 0.0, 1.0, 1.0]],
        outlier_lines: vec![[2.0, 2.0, 3.0, 3.0], [4.0, 4.0, 5.0, 5.0]],
        flow_score: 0.07,
        num_matches: 99,
        num_inliers: 97,
        flow_threshold: 0.05,
        min_matches: 50,
        is_keyframe: true,
    }));
    let f = ev.next();
    assert_eq!(f["frame"]["index"], 12);
    assert_eq!(f["frame"]["lines"].as_array().map(Vec::len), Some(4));
    assert_eq!(f["frame"]["outlier_lines"].as_array().map(Vec::len), Some(8));
    assert_eq!((&f["frame"]["num_matches"], &f["frame"]["num_inliers"]), (&99.into(), &97.into()));
    assert!(f.get("points").is_none(), "a frame does not resend the map");
    let (code, png) = get(&v, &format!("/api/frame.png?v={}", f["frame"]["picture"]));
    assert_eq!(code, 200);
    assert_eq!(&png[1..4], b"PNG");

    // Reconnect: the full current state once, then increments again.
    drop(ev);
    let mut ev = Events::open(&v);
    let again = ev.next();
    assert_eq!(again["full"], true);
    assert_eq!(ids(&again).len(), 31);
    assert_eq!(again["frame"]["index"], 12);
    v.apply(ViewerUpdate::MapDelta(MapDelta { removed_points: vec![500], ..Default::default() }));
    let d = ev.next();
    assert_eq!(d["removed_points"], serde_json::json!([500]));
    assert_eq!(ids(&d), Vec::<u64>::new());

    // A new model is a new epoch: sent in full.
    v.set_reconstruction(&demo_reconstruction(2, 5, 4).expect("demo"));
    let e = ev.next();
    assert_eq!(e["full"], true);
    assert_eq!(ids(&e).len(), 5);
}

#[test]
fn survives_abrupt_disconnects() {
    let v = start();
    v.set_reconstruction(&demo_reconstruction(3, 2000, 5).expect("demo"));
    for _ in 0..5 {
        // Half a request, then gone.
        let mut s = TcpStream::connect(v.local_addr()).expect("connect");
        let _ = s.write_all(b"GET /eve");
        drop(s);
        // An event stream closed before reading its (large) first event.
        let mut s = TcpStream::connect(v.local_addr()).expect("connect");
        let _ = s.write_all(b"GET /events HTTP/1.1\r\n\r\n");
        drop(s);
    }
    // Updates after the clients left must not fail; their threads must end.
    for i in 0..20 {
        v.apply(ViewerUpdate::Status(format!("tick {i}")));
        std::thread::sleep(Duration::from_millis(5));
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while v.handle.shared.slots().count(None) > 0 {
        assert!(Instant::now() < deadline, "connection threads did not end");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(get(&v, "/").0, 200);
    let mut ev = Events::open(&v);
    assert_eq!(ids(&ev.next()).len(), 2000);
}

#[derive(Default)]
struct MockController {
    started: Mutex<Vec<RunSettings>>,
    stopped: Mutex<usize>,
    /// Calls of `max_frames_for` (each would open the input: ffprobe).
    probes: std::sync::atomic::AtomicUsize,
}

impl RunController for MockController {
    fn start(&self, settings: RunSettings) -> Result<(), ControlError> {
        if settings.input.to_string_lossy().contains("missing") {
            return Err(ControlError::Input(colslam_io::SourceError::NotFound { path: settings.input }));
        }
        self.started.lock().unwrap_or_else(|e| e.into_inner()).push(settings);
        Ok(())
    }
    fn stop(&self) {
        if let Ok(mut s) = self.stopped.lock() {
            *s += 1;
        }
    }
    fn max_frames_for(&self, input: &std::path::Path, skip: usize) -> Result<usize, ControlError> {
        self.probes.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        if input.to_string_lossy().contains("missing") {
            return Err(ControlError::Input(colslam_io::SourceError::NotFound { path: input.to_path_buf() }));
        }
        Ok(100usize.div_ceil(skip))
    }
}

#[test]
fn run_control() {
    let v = start();
    let settings = r#"{"input":"/data/seq","output":"/tmp/out","skip":2,"max_frames":null,"init_frames":20,
        "flow_threshold":0.05,"extractor":"orb","matcher":"nn"}"#;
    // No controller: Run is off in the page and refused by the server.
    assert_eq!(get_json(&v, "/api/state").1["has_controller"], false);
    let (code, j) = post(&v, "/api/run", settings);
    assert_eq!(code, 503);
    assert!(j["error"].as_str().unwrap_or("").contains("no pipeline"));
    assert_eq!(post(&v, "/api/max_frames", r#"{"input":"x","skip":1}"#).0, 503);

    let ctl = Arc::new(MockController::default());
    v.set_controller(ctl.clone());
    let (code, j) = post(&v, "/api/max_frames", r#"{"input":"/data/seq","skip":3}"#);
    assert_eq!((code, j["max_frames"].as_u64()), (200, Some(34)));
    // The page sends the field's text as it is.
    assert_eq!(post(&v, "/api/max_frames", r#"{"input":"/data/seq","skip":"3"}"#).1["max_frames"], 34);
    assert_eq!(post(&v, "/api/max_frames", r#"{"input":"/data/seq","skip":-1}"#).0, 400);
    assert_eq!(post(&v, "/api/max_frames", r#"{"input":"/data/seq","skip":"x"}"#).0, 400);
    assert_eq!(post(&v, "/api/max_frames", r#"{"skip":1}"#).0, 400);
    assert_eq!(post(&v, "/api/max_frames", r#"{"input":"/missing","skip":1}"#).0, 400);

    for (bad, why) in [
        (settings.replace("\"skip\":2", "\"skip\":-1"), "skip"),
        (settings.replace("/data/seq", ""), "input"),
        (settings.replace("0.05", "1.5"), "threshold"),
        (settings.replace("\"init_frames\":20", "\"init_frames\":1"), "init-frames"),
        (settings.replace("\"orb\"", "\"sift\""), "sift"),
    ] {
        let (code, j) = post(&v, "/api/run", &bad);
        assert_eq!(code, 400, "{bad}");
        assert!(j["error"].as_str().unwrap_or("").contains(why), "{j}");
    }
    assert_eq!(post(&v, "/api/run", &settings.replace("/data/seq", "/missing")).0, 400);
    assert!(ctl.started.lock().map(|s| s.is_empty()).unwrap_or(false));

    let (code, _) = post(&v, "/api/run", settings);
    assert_eq!(code, 200);
    let got = ctl.started.lock().map(|s| s.clone()).unwrap_or_default();
    assert_eq!(got.len(), 1);
    assert_eq!((got[0].skip, got[0].extractor, got[0].max_frames), (2, Extractor::Orb, None));
    assert_eq!(post(&v, "/api/run", settings).0, 409, "second run while running");
    let (_, s) = get_json(&v, "/api/state");
    assert_eq!(s["run"]["state"], "running");
    assert_eq!(s["has_controller"], true);
    assert_eq!(post(&v, "/api/stop", "{}").0, 200);
    assert_eq!(*ctl.stopped.lock().expect("lock"), 1);
    v.apply(ViewerUpdate::RunState(RunState::Stopped("3 of 9 frames localised; outputs in /o".into())));
    let (_, s) = get_json(&v, "/api/state");
    assert_eq!(
        (&s["run"]["state"], &s["run"]["message"]),
        (&"stopped".into(), &"3 of 9 frames localised; outputs in /o".into())
    );
    assert_eq!(post(&v, "/api/run", settings).0, 200, "a new run after the last ended");
}

#[test]
fn load_and_export() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = dir.path().join("model");
    let rec = demo_reconstruction(5, 80, 6).expect("demo");
    colslam_scene::write_model(&rec, &model, colslam_scene::ModelFormat::Binary).expect("write");
    let v = start();
    // A bad folder: a clear error naming it.
    let bad = dir.path().join("nothing-here");
    let (code, j) = post(&v, "/api/load", &serde_json::json!({ "path": bad }).to_string());
    assert_eq!(code, 400);
    let msg = j["error"].as_str().unwrap_or("");
    assert!(msg.contains("nothing-here") && msg.contains("cameras"), "{msg}");
    // Export with nothing loaded.
    assert_eq!(post(&v, "/api/export", r#"{"path":"/tmp/x.ply","format":"ply"}"#).0, 400);

    let (code, j) = post(&v, "/api/load", &serde_json::json!({ "path": model }).to_string());
    assert_eq!((code, j["points"].as_u64(), j["cameras"].as_u64()), (200, Some(80), Some(5)));
    let (_, s) = get_json(&v, "/api/state");
    assert_eq!(ids(&s).len(), 80);
    assert!(s["source"].as_str().unwrap_or("").ends_with("model"));

    for (name, fmt) in [("bin", "colmap-bin"), ("txt", "colmap-txt"), ("cloud.ply", "ply"), ("traj.txt", "tum")] {
        let out = dir.path().join("out").join(name);
        if let Some(p) = out.parent() {
            std::fs::create_dir_all(p).expect("mkdir");
        }
        let (code, j) = post(&v, "/api/export", &serde_json::json!({ "path": out, "format": fmt }).to_string());
        assert_eq!(code, 200, "{fmt}: {j}");
    }
    let back = colslam_scene::read_model(&dir.path().join("out/txt")).expect("read back");
    assert_eq!((back.num_points3d(), back.num_registered_images()), (80, 5));
    let back = colslam_scene::read_model(&dir.path().join("out/bin")).expect("read back");
    assert_eq!(back.num_observations(), rec.num_observations());
    let tum = std::fs::read_to_string(dir.path().join("out/traj.txt")).expect("tum");
    let lines: Vec<&str> = tum.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(lines.len(), 5);
    // Camera 3 sits at x = 0.5 (demo cameras move 0.25 per image).
    let fields: Vec<f64> = lines[2].split_whitespace().filter_map(|f| f.parse().ok()).collect();
    assert_eq!(fields.len(), 8);
    assert!((fields[1] - 0.5).abs() < 1e-9, "{}", lines[2]);
    let ply = std::fs::read(dir.path().join("out/cloud.ply")).expect("ply");
    assert!(ply.starts_with(b"ply"));
}

#[test]
fn percent_decoding() {
    assert_eq!(http::percent_decode("a%20b+c%2Fd"), "a b c/d");
    assert_eq!(http::percent_decode("100%"), "100%");
    assert_eq!(http::percent_decode("%zz%4"), "%zz%4");
}

#[test]
fn downscale_keeps_aspect_and_averages() {
    let mut img = colslam_image::Image::new(1280, 720, 3);
    img.set(0, 0, 0, 255);
    let (small, f) = downscale_for_view(&img, 640);
    assert_eq!((small.width(), small.height(), small.channels()), (640, 360, 3));
    assert_eq!(f, 0.5);
    assert_eq!(small.get(0, 0, 0), 63, "box average of 255 and three zeros");
    let (same, f) = downscale_for_view(&small, 640);
    assert_eq!((same.width(), f), (640, 1.0));
}

#[test]
fn settings_validation() {
    let mut s = RunSettings { input: "/a".into(), output: "/b".into(), ..Default::default() };
    assert!(s.validate().is_ok());
    s.max_frames = Some(0);
    assert!(s.validate().is_err());
    s.max_frames = Some(5);
    s.flow_threshold = f64::NAN;
    assert!(s.validate().is_err());
}

#[test]
fn handles_are_thread_safe() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<ViewerHandle>();
    send_sync::<Viewer>();
}

/// Sends raw bytes on a new connection, returns (status, head, body).
fn raw_to(addr: std::net::SocketAddr, request: &[u8]) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
    s.write_all(request).expect("write");
    let mut out = Vec::new();
    s.read_to_end(&mut out).expect("read");
    let split = out.windows(4).position(|w| w == b"\r\n\r\n").expect("response head");
    let head = String::from_utf8_lossy(&out[..split]).into_owned();
    let status = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).expect("status code");
    (status, head, out[split + 4..].to_vec())
}

/// Waits (up to `limit`) until no connection is registered.
fn wait_idle(v: &Viewer, limit: Duration) -> Duration {
    let t = Instant::now();
    while v.handle.shared.slots().count(None) > 0 {
        assert!(t.elapsed() < limit, "{} connections still held after {limit:?}", v.handle.shared.slots().count(None));
        std::thread::sleep(Duration::from_millis(10));
    }
    t.elapsed()
}

#[test]
fn slow_clients_do_not_lock_the_server() {
    let v = start();
    // 70 clients that send a request head one byte at a time, slower than
    // any read timeout notices: more than every serving slot.
    let mut slow: Vec<TcpStream> = (0..70)
        .map(|_| {
            let mut s = TcpStream::connect(v.local_addr()).expect("connect");
            let _ = s.write_all(b"GET / HTTP/1.1\r\nX-Slow: ");
            s
        })
        .collect();
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let drip = std::thread::spawn({
        let stop = Arc::clone(&stop);
        let mut conns: Vec<TcpStream> = slow.iter().filter_map(|s| s.try_clone().ok()).collect();
        move || {
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                for s in &mut conns {
                    // Clients closed to make room fail here: that is expected.
                    let _ = s.write_all(b"a");
                }
                std::thread::sleep(Duration::from_millis(300));
            }
        }
    });
    std::thread::sleep(Duration::from_millis(100));
    for _ in 0..3 {
        let t = Instant::now();
        let (code, _) = get(&v, "/api/state");
        assert_eq!(code, 200, "a normal client is served while 70 slow ones are connected");
        assert!(t.elapsed() < Duration::from_secs(2), "served in {:?}", t.elapsed());
    }
    let mut ev = Events::open(&v);
    assert_eq!(ev.next()["full"], true);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    let _ = drip.join();
    slow.clear();
    drop(ev);
    wait_idle(&v, Duration::from_secs(3));
}

#[test]
fn a_request_must_arrive_within_the_deadline() {
    let deadline = Duration::from_millis(600);
    let v = Viewer::start(ViewerOptions { port: 0, request_deadline: deadline, ..Default::default() }).expect("start");
    let mut s = TcpStream::connect(v.local_addr()).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
    s.write_all(b"GET / HTTP/1.1\r\nX-Slow: ").expect("write");
    // One byte every 100 ms: each read is quick, the request never ends.
    let mut w = s.try_clone().expect("clone");
    let drip = std::thread::spawn(move || {
        for _ in 0..50 {
            if w.write_all(b"a").is_err() {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    let t = Instant::now();
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let took = t.elapsed();
    assert!(String::from_utf8_lossy(&out).starts_with("HTTP/1.1 408"), "{}", String::from_utf8_lossy(&out));
    assert!(took >= deadline - Duration::from_millis(100) && took < Duration::from_secs(3), "closed after {took:?}");
    drop(s);
    let _ = drip.join();
    wait_idle(&v, Duration::from_secs(2));
    assert_eq!(get(&v, "/").0, 200);
}

#[test]
fn event_streams_release_their_slots_when_clients_leave() {
    let v = start();
    for _ in 0..200 {
        let mut s = TcpStream::connect(v.local_addr()).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
        s.write_all(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").expect("write");
        let mut line = String::new();
        BufReader::new(&s).read_line(&mut line).expect("status line");
        assert!(line.starts_with("HTTP/1.1 200"), "{line}");
    }
    // Streams open at once are capped; each notices its client left within
    // a poll interval, not at the next keepalive.
    assert!(v.handle.shared.slots().count(Some(http::Phase::Events)) <= http::MAX_EVENT_STREAMS);
    let took = wait_idle(&v, Duration::from_secs(2));
    eprintln!("200 event streams released {took:?} after their clients left");
    assert_eq!(get(&v, "/").0, 200);
    let mut ev = Events::open(&v);
    assert_eq!(ev.next()["full"], true);
}

#[test]
fn off_loopback_requests_need_the_token() {
    let v =
        match Viewer::start(ViewerOptions { bind: IpAddr::V4(Ipv4Addr::UNSPECIFIED), port: 0, ..Default::default() }) {
            Ok(v) => v,
            Err(e) => {
                // Machines without IPv4 sockets: the checks are tested below.
                eprintln!("SKIPPED: cannot bind 0.0.0.0: {e}");
                return;
            }
        };
    let token = v.access_token().expect("a token off loopback").to_string();
    assert_eq!(token.len(), 32);
    assert!(v.url().ends_with(&format!("/?token={token}")), "{}", v.url());
    let port = v.local_addr().port();
    let addr = std::net::SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    let req = |target: &str, extra: &str| {
        raw_to(addr, format!("GET {target} HTTP/1.1\r\nHost: 192.0.2.7:{port}\r\n{extra}\r\n").as_bytes())
    };
    assert_eq!(req("/api/state", "").0, 401, "no token");
    assert_eq!(req("/", "").0, 401, "not even the page");
    assert_eq!(req("/api/state?token=0123", "").0, 401, "wrong token");
    assert_eq!(req(&format!("/api/state?token={}", token.replace(&token[..1], "x")), "").0, 401);
    assert_eq!(req("/api/state", &format!("Cookie: colslam_token_{port}=nope\r\n")).0, 401);
    assert_eq!(req(&format!("/api/state?token={token}"), "").0, 200);
    // The index opened with the token sets it as a cookie for the page's requests.
    let (code, head, _) = req(&format!("/?token={token}"), "");
    assert_eq!(code, 200);
    let cookie = head.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).expect("cookie set");
    assert!(cookie.contains(&format!("colslam_token_{port}={token}")), "{cookie}");
    assert!(cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"), "{cookie}");
    assert_eq!(req("/api/state", &format!("Cookie: a=b; colslam_token_{port}={token}\r\n")).0, 200);
    assert_eq!(req("/api/state", &format!("Authorization: Bearer {token}\r\n")).0, 200);
    // A page of another site (DNS rebinding makes Host and Origin agree)
    // is refused even with the token; the bound address's own origin is not.
    let post = |origin: &str| {
        let body = "{}";
        raw_to(
            addr,
            format!(
                "POST /api/load?token={token} HTTP/1.1\r\nHost: evil.example:{port}\r\nOrigin: {origin}\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
                body.len()
            )
            .as_bytes(),
        )
        .0
    };
    assert_eq!(post(&format!("http://evil.example:{port}")), 403);
    assert_eq!(post("http://192.0.2.7:1"), 403, "wrong port");
    assert_eq!(post(&format!("http://192.0.2.7:{port}")), 400, "passes the checks (the body lacks a path)");
}

#[test]
fn origin_must_name_the_bound_address() {
    let ip = |s: &str| s.parse::<IpAddr>().expect("ip");
    let lan = ip("192.168.1.5");
    assert!(http::origin_allowed("http://192.168.1.5:8765", lan, 8765));
    assert!(!http::origin_allowed("http://192.168.1.6:8765", lan, 8765));
    assert!(!http::origin_allowed("http://192.168.1.5:8766", lan, 8765));
    assert!(!http::origin_allowed("https://192.168.1.5:8765", lan, 8765));
    assert!(!http::origin_allowed("http://attacker.example:8765", lan, 8765));
    assert!(!http::origin_allowed("http://192.168.1.5", lan, 8765));
    assert!(http::origin_allowed("http://192.168.1.5", lan, 80));
    assert!(!http::origin_allowed("null", lan, 8765));
    let any = ip("0.0.0.0");
    assert!(http::origin_allowed("http://10.0.0.2:8765", any, 8765));
    assert!(http::origin_allowed("http://[fe80::1]:8765", ip("::"), 8765));
    assert!(http::origin_allowed("http://localhost:8765", any, 8765));
    assert!(!http::origin_allowed("http://rebind.attacker.example:8765", any, 8765));
    assert!(!http::origin_allowed("http://[fe80::1]:8765", lan, 8765));
}

#[test]
fn max_frames_is_not_a_get() {
    let v = start();
    let ctl = Arc::new(MockController::default());
    v.set_controller(ctl.clone());
    // An <img> on another site sends GETs: they must not open files.
    assert_eq!(get(&v, "/api/max_frames?input=%2Fetc%2Fpasswd&skip=1").0, 405);
    let port = v.local_addr().port();
    let body = r#"{"input":"/etc/passwd","skip":1}"#;
    let cross = format!(
        "POST /api/max_frames HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://evil.example\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    assert_eq!(raw(&v, cross.as_bytes()).0, 403);
    let form = format!(
        "POST /api/max_frames HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: text/plain\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    assert_eq!(raw(&v, form.as_bytes()).0, 415);
    assert_eq!(ctl.probes.load(std::sync::atomic::Ordering::SeqCst), 0, "the controller was never asked");
    assert_eq!(post(&v, "/api/max_frames", body).0, 200);
    assert_eq!(ctl.probes.load(std::sync::atomic::Ordering::SeqCst), 1);
}

#[test]
fn request_head_parser_is_a_pure_function() {
    let r =
        parse_request_head(b"POST /a%20b?x=1&y=%2F HTTP/1.1\r\nHost: h\r\nContent-Length: 12\r\n\r\n").expect("parses");
    assert_eq!((r.method.as_str(), r.path.as_str(), r.content_length), ("POST", "/a b", 12));
    assert_eq!(r.query, vec![("x".to_string(), "1".to_string()), ("y".to_string(), "/".to_string())]);
    assert_eq!(r.headers[0], ("host".to_string(), "h".to_string()));
    let status = |b: &[u8]| parse_request_head(b).map(|_| 0).unwrap_or_else(|e| e.status);
    assert_eq!(status(b"GET / HTTP/1.0\n\n"), 0);
    assert_eq!(status(b""), 400);
    assert_eq!(status(b"GET /\r\n\r\n"), 400);
    assert_eq!(status(b"GET / SPDY/9\r\n\r\n"), 505);
    assert_eq!(status(b"GET / HTTP/1.1\r\n\xff\r\n\r\n"), 400);
    assert_eq!(status(b"GET / HTTP/1.1\r\nContent-Length: -1\r\n\r\n"), 400);
    assert_eq!(status(b"GET / HTTP/1.1\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n"), 400);
    assert_eq!(status(b"GET / HTTP/1.1\r\nContent-Length: 99999999\r\n\r\n"), 413);
    assert_eq!(status(format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(20_000)).as_bytes()), 431);
    // Arbitrary bytes never panic.
    let mut rng = colslam_geometry::SplitMix64::new(17);
    for len in 0..300 {
        let bytes: Vec<u8> = (0..len).map(|_| rng.below(256) as u8).collect();
        let _ = parse_request_head(&bytes);
    }
}

#[test]
fn run_settings_parse_as_a_pure_function() {
    let s = RunSettings::from_json(br#"{"input":"/a","output":"/b","skip":2}"#).expect("valid");
    assert_eq!((s.skip, s.init_frames), (2, RunSettings::default().init_frames));
    assert!(matches!(RunSettings::from_json(b"{"), Err(SettingsError::Json(_))));
    assert!(matches!(RunSettings::from_json(br#"{"input":"/a","output":"/b","x":1}"#), Err(SettingsError::Json(_))));
    // Out of the pipeline's range: its own check says why.
    assert!(matches!(
        RunSettings::from_json(br#"{"input":"/a","output":"/b","skip":0}"#),
        Err(SettingsError::Options(_))
    ));
    assert!(matches!(
        RunSettings::from_json(br#"{"input":"/a","output":"/b","skip":-1}"#),
        Err(SettingsError::Invalid(_))
    ));
    assert!(matches!(RunSettings::from_json(br#"{"input":"","output":"/b"}"#), Err(SettingsError::Invalid(_))));
}

//! A minimal HTTP/1.1 server on `std::net`: one thread per connection, one
//! request per connection (`Connection: close`), Server-Sent Events for live
//! updates. Only what the embedded page needs; it binds to loopback by
//! default.

use crate::export::{ExportFormat, export_reconstruction};
use crate::state::State;
use crate::types::{RunController, RunSettings, RunState, ViewerUpdate};
use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Duration;

/// Longest accepted request head (request line + headers).
const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Longest accepted request body.
const MAX_BODY_BYTES: usize = 1024 * 1024;
/// Connections served at once; more get 503 (each holds a thread).
pub(crate) const MAX_CONNECTIONS: usize = 64;
/// A client that sends its request slower than this is dropped.
const READ_TIMEOUT: Duration = Duration::from_secs(10);
/// A client that does not take data for this long is dropped.
const WRITE_TIMEOUT: Duration = Duration::from_secs(30);
/// Event streams send a comment this often so dead clients are noticed.
const KEEPALIVE: Duration = Duration::from_secs(10);
/// Pause after each event so bursts of updates coalesce into one message.
const MIN_EVENT_INTERVAL: Duration = Duration::from_millis(25);
/// Milliseconds the browser waits before reconnecting a dropped stream.
const SSE_RETRY_MS: u32 = 500;

const INDEX_HTML: &str = include_str!("../web/index.html");
const APP_JS: &str = include_str!("../web/app.js");
const STYLE_CSS: &str = include_str!("../web/style.css");

/// State shared by the server threads and the [`crate::Viewer`] handles.
pub(crate) struct Shared {
    pub state: Mutex<State>,
    pub changed: Condvar,
    pub controller: Mutex<Option<Arc<dyn RunController>>>,
    pub connections: AtomicUsize,
    pub stop: AtomicBool,
}

impl Shared {
    pub fn new() -> Self {
        Self {
            state: Mutex::new(State::default()),
            changed: Condvar::new(),
            controller: Mutex::new(None),
            connections: AtomicUsize::new(0),
            stop: AtomicBool::new(false),
        }
    }

    /// Locks the state. A panic while holding the lock (a bug) must not take
    /// the viewer down with it, so a poisoned lock is recovered: every State
    /// method leaves it consistent between statements that bump versions.
    pub fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Applies `f` to the state and wakes the event streams.
    pub fn update(&self, f: impl FnOnce(&mut State)) {
        f(&mut self.lock());
        self.changed.notify_all();
    }

    fn controller(&self) -> Option<Arc<dyn RunController>> {
        self.controller.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Accepts connections until `shared.stop` is set.
pub(crate) fn serve(listener: TcpListener, shared: Arc<Shared>) {
    for conn in listener.incoming() {
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(stream) = conn else { continue };
        let shared = Arc::clone(&shared);
        if shared.connections.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
            shared.connections.fetch_sub(1, Ordering::SeqCst);
            let mut s = stream;
            let _ = respond(&mut s, 503, "text/plain", b"too many connections");
            continue;
        }
        let spawned = std::thread::Builder::new().name("colslam-viewer-conn".into()).spawn({
            let shared = Arc::clone(&shared);
            move || {
                // Errors here are a client going away: nothing to report.
                let _ = handle(stream, &shared);
                shared.connections.fetch_sub(1, Ordering::SeqCst);
            }
        });
        if spawned.is_err() {
            shared.connections.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

/// A parsed request.
#[derive(Debug)]
pub(crate) struct Request {
    pub method: String,
    pub path: String,
    pub query: Vec<(String, String)>,
    /// Headers with lower-case names.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Request {
    fn param(&self, key: &str) -> Option<&str> {
        self.query.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }

    /// A header by lower-case name.
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
}

/// Why a request could not be parsed: the status to answer with.
#[derive(Debug)]
pub(crate) struct BadRequest {
    pub status: u16,
    pub message: String,
}

fn bad(status: u16, message: impl Into<String>) -> BadRequest {
    BadRequest { status, message: message.into() }
}

/// Reads one request from `r`.
pub(crate) fn read_request(r: &mut impl BufRead) -> Result<Request, BadRequest> {
    let mut head = Vec::new();
    loop {
        let mut line = Vec::new();
        let n =
            r.by_ref().take((MAX_HEAD_BYTES + 1 - head.len().min(MAX_HEAD_BYTES)) as u64).read_until(b'\n', &mut line);
        let n = n.map_err(|e| bad(400, format!("cannot read request: {e}")))?;
        if n == 0 {
            return Err(bad(400, "connection closed before the request ended"));
        }
        head.extend_from_slice(&line);
        if head.len() > MAX_HEAD_BYTES {
            return Err(bad(431, "request head too large"));
        }
        if line == b"\r\n" || line == b"\n" {
            break;
        }
    }
    let head = String::from_utf8(head).map_err(|_| bad(400, "request head is not UTF-8"))?;
    let mut lines = head.lines();
    let request_line = lines.next().unwrap_or_default();
    let mut parts = request_line.split_whitespace();
    let (Some(method), Some(target), Some(version)) = (parts.next(), parts.next(), parts.next()) else {
        return Err(bad(400, format!("malformed request line {request_line:?}")));
    };
    if !version.starts_with("HTTP/1.") {
        return Err(bad(505, format!("unsupported protocol {version}")));
    }
    let mut content_length = 0usize;
    let mut headers = Vec::new();
    for h in lines {
        if let Some((k, v)) = h.split_once(':') {
            let (k, v) = (k.trim().to_ascii_lowercase(), v.trim());
            if k == "content-length" {
                content_length = v.parse().map_err(|_| bad(400, format!("bad Content-Length {v:?}")))?;
            }
            headers.push((k, v.to_string()));
        }
    }
    if content_length > MAX_BODY_BYTES {
        return Err(bad(413, format!("body of {content_length} bytes exceeds {MAX_BODY_BYTES}")));
    }
    let mut body = vec![0u8; content_length];
    r.read_exact(&mut body).map_err(|e| bad(400, format!("body shorter than Content-Length: {e}")))?;
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    let query = query
        .split('&')
        .filter(|s| !s.is_empty())
        .map(|kv| {
            let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
            (percent_decode(k), percent_decode(v))
        })
        .collect();
    Ok(Request { method: method.to_string(), path: percent_decode(path), query, headers, body })
}

/// Decodes `%XX` escapes and `+` (as space); invalid escapes stay as they are.
pub(crate) fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        // `i < b.len()` is the loop condition, so this index is in bounds.
        match b[i] {
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            b'%' => {
                let hex = b
                    .get(i + 1..i + 3)
                    .and_then(|h| std::str::from_utf8(h).ok())
                    .and_then(|h| u8::from_str_radix(h, 16).ok());
                match hex {
                    Some(v) => {
                        out.push(v);
                        i += 3;
                    }
                    None => {
                        out.push(b'%');
                        i += 1;
                    }
                }
            }
            c => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        204 => "No Content",
        400 => "Bad Request",
        404 => "Not Found",
        405 => "Method Not Allowed",
        409 => "Conflict",
        403 => "Forbidden",
        413 => "Payload Too Large",
        415 => "Unsupported Media Type",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        _ => "Status",
    }
}

fn respond(s: &mut TcpStream, status: u16, content_type: &str, body: &[u8]) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status} {}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        reason(status),
        body.len()
    );
    s.write_all(head.as_bytes())?;
    s.write_all(body)?;
    s.flush()
}

fn respond_json(s: &mut TcpStream, status: u16, v: &Value) -> std::io::Result<()> {
    respond(s, status, "application/json", v.to_string().as_bytes())
}

fn respond_error(s: &mut TcpStream, status: u16, message: &str) -> std::io::Result<()> {
    respond_json(s, status, &json!({ "error": message }))
}

fn handle(mut stream: TcpStream, shared: &Shared) -> std::io::Result<()> {
    stream.set_read_timeout(Some(READ_TIMEOUT))?;
    stream.set_write_timeout(Some(WRITE_TIMEOUT))?;
    let req = {
        let mut reader = BufReader::new(stream.try_clone()?);
        read_request(&mut reader)
    };
    let req = match req {
        Ok(r) => r,
        Err(e) => return respond_error(&mut stream, e.status, &e.message),
    };
    let loopback = stream.local_addr().map(|a| a.ip().is_loopback()).unwrap_or(false);
    if let Err(e) = check_origin(&req, loopback) {
        return respond_error(&mut stream, e.status, &e.message);
    }
    route(&mut stream, &req, shared)
}

/// Host names a loopback-bound viewer answers to. Anything else in `Host` is
/// a DNS-rebinding attempt: another site's page whose name resolves here.
const LOOPBACK_HOSTS: [&str; 3] = ["127.0.0.1", "localhost", "[::1]"];

/// Guards against other web sites driving the viewer through the user's
/// browser (it reads and writes files on request): a loopback-bound server
/// accepts only loopback `Host` names; a request carrying an `Origin` must
/// come from the page's own origin; POST bodies must be
/// `application/json`, which a cross-site form cannot send without a CORS
/// preflight (answered 405 here, so the browser refuses).
fn check_origin(req: &Request, loopback: bool) -> Result<(), BadRequest> {
    let host = req.header("host");
    if loopback && let Some(h) = host {
        let name = match h.rsplit_once(':') {
            Some((n, port)) if port.bytes().all(|b| b.is_ascii_digit()) => n,
            _ => h,
        };
        if !LOOPBACK_HOSTS.iter().any(|l| l.eq_ignore_ascii_case(name)) {
            return Err(bad(403, format!("host {h:?} is not served (the viewer answers on loopback only)")));
        }
    }
    if let Some(origin) = req.header("origin") {
        let same = host.is_some_and(|h| origin.strip_prefix("http://").is_some_and(|o| o.eq_ignore_ascii_case(h)));
        if !same {
            return Err(bad(403, format!("cross-origin request from {origin:?} refused")));
        }
    }
    if req.method == "POST" {
        let ctype = req.header("content-type").unwrap_or("");
        if !ctype.to_ascii_lowercase().starts_with("application/json") {
            return Err(bad(415, "POST bodies must be application/json"));
        }
    }
    Ok(())
}

fn route(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let get = req.method == "GET";
    let post = req.method == "POST";
    match req.path.as_str() {
        "/" | "/index.html" if get => respond(s, 200, "text/html; charset=utf-8", INDEX_HTML.as_bytes()),
        "/app.js" if get => respond(s, 200, "text/javascript; charset=utf-8", APP_JS.as_bytes()),
        "/style.css" if get => respond(s, 200, "text/css; charset=utf-8", STYLE_CSS.as_bytes()),
        "/favicon.ico" if get => respond(s, 204, "image/x-icon", b""),
        "/events" if get => event_stream(s, shared),
        "/api/state" if get => api_state(s, req, shared),
        "/api/frame.png" if get => picture(s, shared, false),
        "/api/keyframe.png" if get => picture(s, shared, true),
        "/api/max_frames" if get => api_max_frames(s, req, shared),
        "/api/run" if post => api_run(s, req, shared),
        "/api/stop" if post => api_stop(s, shared),
        "/api/load" if post => api_load(s, req, shared),
        "/api/export" if post => api_export(s, req, shared),
        "/" | "/index.html" | "/app.js" | "/style.css" | "/favicon.ico" | "/events" | "/api/state"
        | "/api/frame.png" | "/api/keyframe.png" | "/api/max_frames" | "/api/run" | "/api/stop" | "/api/load"
        | "/api/export" => respond_error(s, 405, &format!("{} not allowed on {}", req.method, req.path)),
        _ => respond_error(s, 404, &format!("no such resource {}", req.path)),
    }
}

/// `GET /api/state`: the full state, or with `?epoch=E&since=V` what changed
/// after version V (a full state when E is not the current epoch).
fn api_state(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let parse =
        |k: &str| req.param(k).map(|v| v.parse::<u64>().map_err(|_| format!("{k} must be a number, got {v:?}")));
    let (epoch, since) = match (parse("epoch").transpose(), parse("since").transpose()) {
        (Ok(e), Ok(v)) => (e, v),
        (Err(e), _) | (_, Err(e)) => return respond_error(s, 400, &e),
    };
    let body = {
        let st = shared.lock();
        match (epoch, since) {
            (Some(e), Some(v)) if e == st.epoch => st.delta_json(v),
            _ => st.snapshot_json(),
        }
    };
    respond_json(s, 200, &body)
}

fn event_stream(s: &mut TcpStream, shared: &Shared) -> std::io::Result<()> {
    s.write_all(
        b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nConnection: close\r\nX-Accel-Buffering: no\r\n\r\n",
    )?;
    s.write_all(format!("retry: {SSE_RETRY_MS}\n\n").as_bytes())?;
    // Every connection, new or reconnecting, starts from the full state.
    let (mut epoch, mut version, first) = {
        let st = shared.lock();
        (st.epoch, st.version, st.snapshot_json())
    };
    send_event(s, epoch, version, &first)?;
    loop {
        let msg = {
            let st = shared.lock();
            let (st, _) = shared
                .changed
                .wait_timeout_while(st, KEEPALIVE, |st| !st.shutdown && st.epoch == epoch && st.version == version)
                .unwrap_or_else(|e| e.into_inner());
            if st.shutdown || shared.stop.load(Ordering::SeqCst) {
                return Ok(());
            }
            if st.epoch != epoch {
                Some((st.epoch, st.version, st.snapshot_json()))
            } else if st.version != version {
                Some((st.epoch, st.version, st.delta_json(version)))
            } else {
                None
            }
        };
        match msg {
            Some((e, v, body)) => {
                send_event(s, e, v, &body)?;
                epoch = e;
                version = v;
                std::thread::sleep(MIN_EVENT_INTERVAL);
            }
            None => s.write_all(b": keepalive\n\n")?,
        }
        s.flush()?;
    }
}

fn send_event(s: &mut TcpStream, epoch: u64, version: u64, body: &Value) -> std::io::Result<()> {
    // serde_json's compact output has no newlines, so one data line suffices.
    let text = format!("id: {epoch}:{version}\nevent: update\ndata: {body}\n\n");
    s.write_all(text.as_bytes())?;
    s.flush()
}

fn picture(s: &mut TcpStream, shared: &Shared, keyframe: bool) -> std::io::Result<()> {
    let pic = {
        let st = shared.lock();
        if keyframe { st.keyframe_picture.clone() } else { st.frame_picture.clone() }
    };
    let Some(pic) = pic else {
        return respond_error(s, 404, "no picture yet");
    };
    // Encoding happens here, on the client's thread, not the pipeline's.
    let name = if keyframe { "keyframe.png" } else { "frame.png" };
    match pic.image.encode_png(std::path::Path::new(name)) {
        Ok(png) => respond(s, 200, "image/png", &png),
        Err(e) => respond_error(s, 500, &e.to_string()),
    }
}

fn json_body(req: &Request) -> Result<Value, String> {
    serde_json::from_slice(&req.body).map_err(|e| format!("request body is not valid JSON: {e}"))
}

fn path_field(v: &Value, key: &str) -> Result<PathBuf, String> {
    match v.get(key).and_then(Value::as_str).map(str::trim) {
        Some(p) if !p.is_empty() => Ok(PathBuf::from(p)),
        _ => Err(format!("{key} path is missing")),
    }
}

fn api_max_frames(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let Some(ctl) = shared.controller() else {
        return respond_error(s, 503, "no pipeline attached (started with `colslam view`)");
    };
    let input = req.param("input").map(str::trim).unwrap_or("");
    if input.is_empty() {
        return respond_error(s, 400, "input path is missing");
    }
    let skip = match req.param("skip").unwrap_or("1").parse::<i64>() {
        Ok(k) if k >= 1 => usize::try_from(k).unwrap_or(usize::MAX),
        _ => return respond_error(s, 400, "frame skip must be an integer of at least 1"),
    };
    match ctl.max_frames_for(std::path::Path::new(input), skip) {
        Ok(n) => respond_json(s, 200, &json!({ "max_frames": n })),
        Err(e) => respond_error(s, 400, &e),
    }
}

fn api_run(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let Some(ctl) = shared.controller() else {
        return respond_error(s, 503, "no pipeline attached: start the viewer with `colslam run ... --view` to run");
    };
    let settings: RunSettings = match serde_json::from_slice(&req.body) {
        Ok(v) => v,
        Err(e) => return respond_error(s, 400, &format!("invalid settings: {e}")),
    };
    if let Err(e) = settings.validate() {
        return respond_error(s, 400, &format!("invalid settings: {e}"));
    }
    {
        let st = shared.lock();
        if st_running(&st) {
            drop(st);
            return respond_error(s, 409, "a run is already in progress; stop it first");
        }
    }
    match ctl.start(settings) {
        Ok(()) => {
            shared.update(|st| st.apply(ViewerUpdate::RunState(RunState::Running)));
            respond_json(s, 200, &json!({ "ok": true }))
        }
        Err(e) => respond_error(s, 400, &e),
    }
}

fn st_running(st: &State) -> bool {
    matches!(st.run_state(), RunState::Running | RunState::Stopping)
}

fn api_stop(s: &mut TcpStream, shared: &Shared) -> std::io::Result<()> {
    let Some(ctl) = shared.controller() else {
        return respond_error(s, 503, "no pipeline attached");
    };
    ctl.stop();
    shared.update(|st| {
        if st_running(st) {
            st.apply(ViewerUpdate::RunState(RunState::Stopping));
        }
    });
    respond_json(s, 200, &json!({ "ok": true }))
}

fn api_load(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let path = match json_body(req).and_then(|v| path_field(&v, "path")) {
        Ok(p) => p,
        Err(e) => return respond_error(s, 400, &e),
    };
    if st_running(&shared.lock()) {
        return respond_error(s, 409, "a run is in progress; stop it before loading a model");
    }
    match colslam_scene::read_model(&path) {
        Ok(rec) => {
            let (points, cameras) = (rec.num_points3d(), rec.num_registered_images());
            shared.update(|st| st.set_reconstruction(&rec, &path.display().to_string()));
            respond_json(s, 200, &json!({ "ok": true, "points": points, "cameras": cameras }))
        }
        Err(e) => respond_error(s, 400, &format!("cannot load model: {e}")),
    }
}

fn api_export(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let parsed = json_body(req).and_then(|v| {
        let path = path_field(&v, "path")?;
        let fmt = v.get("format").and_then(Value::as_str).unwrap_or("");
        let fmt = ExportFormat::from_name(fmt)
            .ok_or_else(|| format!("unknown export format {fmt:?} (expected colmap-bin, colmap-txt, ply or tum)"))?;
        Ok((path, fmt))
    });
    let (path, format) = match parsed {
        Ok(p) => p,
        Err(e) => return respond_error(s, 400, &e),
    };
    let live = shared.controller().and_then(|c| c.snapshot()).map(Arc::new);
    let Some(rec) = live.or_else(|| shared.lock().model.clone()) else {
        return respond_error(s, 400, "no reconstruction to export yet");
    };
    match export_reconstruction(&rec, &path, format) {
        Ok(()) => respond_json(s, 200, &json!({ "ok": true, "path": path.display().to_string() })),
        Err(e) => respond_error(s, 400, &format!("export failed: {e}")),
    }
}

//! A minimal HTTP/1.1 server on `std::net`: one thread per connection, one
//! request per connection (`Connection: close`), Server-Sent Events for live
//! updates. Only what the embedded page needs; it binds to loopback by
//! default.
//!
//! Slow or abandoned clients cannot lock it: every connection is registered
//! in [`Slots`]; one still sending its request must finish it (head and
//! body) within the request deadline, whatever its pace, and is the first to
//! be closed when its client (peer address) or the server as a whole holds
//! too many; event streams notice a closed socket within [`SSE_POLL`].
//!
//! Bound anywhere but loopback, the server asks for an access token (see
//! [`Access`]).

use crate::export::{ExportFormat, export_reconstruction};
use crate::state::State;
use crate::types::{RunController, RunSettings, RunState, ViewerUpdate};
use serde_json::{Value, json};
use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, Shutdown, TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Longest accepted request head (request line + headers).
const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Longest accepted request body.
const MAX_BODY_BYTES: usize = 1024 * 1024;
/// Requests served at once (head read, answer or event stream under way);
/// more get 503. Each holds a thread.
pub(crate) const MAX_CONNECTIONS: usize = 64;
/// Connections still sending their request. When full, the one that has
/// been sending longest is closed, so a crowd of slow clients delays new
/// ones by nothing.
pub(crate) const MAX_READING: usize = 128;
/// Connections one peer address may hold in any phase (a half of the
/// serving slots, so one client never holds them all). A new connection
/// over the cap closes that peer's oldest one still sending its request,
/// else its oldest event stream, else it gets 503. The page needs a few:
/// its event stream, a request or two, the pictures.
pub(crate) const MAX_PER_CLIENT: usize = MAX_CONNECTIONS / 2;
/// Event streams at once; a new one closes the oldest (a browser's
/// EventSource reconnects by itself).
pub(crate) const MAX_EVENT_STREAMS: usize = 32;
/// Default whole-request deadline: the request line, headers and body must
/// all arrive within this, however they are paced.
pub const REQUEST_DEADLINE: Duration = Duration::from_secs(10);
/// A client that does not take data for this long is dropped.
const WRITE_TIMEOUT: Duration = Duration::from_secs(30);
/// Event streams check this often whether their client went away.
const SSE_POLL: Duration = Duration::from_millis(250);
/// Event streams send a comment this often when nothing changes (proxies
/// and browsers drop silent streams).
const KEEPALIVE: Duration = Duration::from_secs(10);
/// Pause after each event so bursts of updates coalesce into one message.
const MIN_EVENT_INTERVAL: Duration = Duration::from_millis(25);
/// Milliseconds the browser waits before reconnecting a dropped stream.
const SSE_RETRY_MS: u32 = 500;

const INDEX_HTML: &str = include_str!("../web/index.html");
const APP_JS: &str = include_str!("../web/app.js");
const STYLE_CSS: &str = include_str!("../web/style.css");

/// Who may use the server.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Access {
    /// Bound to loopback: only this machine connects, and other web sites
    /// are kept out by the `Host` and `Origin` checks ([`check_origin`]).
    Loopback,
    /// Bound elsewhere: every request must carry `token` (query parameter
    /// `token`, the cookie the page's index sets, or `Authorization: Bearer`),
    /// and an `Origin`, when sent, must name the bound address and port.
    Token {
        /// The secret (hex), made at start from the OS's random source.
        token: String,
        /// The configured address (unspecified: any IP literal).
        bind: IpAddr,
        /// The bound port.
        port: u16,
    },
}

/// How the server treats its clients.
#[derive(Debug, Clone)]
pub(crate) struct ServerConfig {
    pub access: Access,
    pub request_deadline: Duration,
}

/// State shared by the server threads and the [`crate::Viewer`] handles.
pub(crate) struct Shared {
    pub state: Mutex<State>,
    pub changed: Condvar,
    pub controller: Mutex<Option<Arc<dyn RunController>>>,
    pub slots: Mutex<Slots>,
    pub stop: AtomicBool,
}

impl Shared {
    pub fn new() -> Self {
        Self {
            state: Mutex::new(State::default()),
            changed: Condvar::new(),
            controller: Mutex::new(None),
            slots: Mutex::new(Slots::default()),
            stop: AtomicBool::new(false),
        }
    }

    /// Locks the state. A panic while holding the lock (a bug) must not take
    /// the viewer down with it, so a poisoned lock is recovered: every State
    /// method leaves it consistent between statements that bump versions.
    pub fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Locks the connection registry (recovered when poisoned: each
    /// [`Slots`] method leaves it consistent).
    pub fn slots(&self) -> MutexGuard<'_, Slots> {
        self.slots.lock().unwrap_or_else(|e| e.into_inner())
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

/// What a connection is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// Its request has not fully arrived.
    Reading,
    /// Its request is being answered.
    Serving,
    /// It follows the event stream.
    Events,
}

struct Slot {
    id: u64,
    peer: IpAddr,
    phase: Phase,
    since: Instant,
    /// A handle on the socket to close it from another thread.
    stream: TcpStream,
}

/// The open connections. Closing one (eviction) removes it here and shuts
/// its socket down, which ends its thread's blocking read or write.
#[derive(Default)]
pub(crate) struct Slots {
    next_id: u64,
    open: Vec<Slot>,
}

impl Slots {
    /// Open connections in `phase` (all when `None`).
    pub fn count(&self, phase: Option<Phase>) -> usize {
        self.open.iter().filter(|s| phase.is_none_or(|p| s.phase == p)).count()
    }

    fn serving(&self) -> usize {
        self.open.iter().filter(|s| s.phase != Phase::Reading).count()
    }

    /// Closes the oldest connection matching `pick`; false when none does.
    fn evict_oldest(&mut self, pick: impl Fn(&Slot) -> bool) -> bool {
        let oldest = self.open.iter().enumerate().filter(|(_, s)| pick(s)).min_by_key(|(_, s)| s.since).map(|(i, _)| i);
        match oldest {
            Some(i) => {
                let slot = self.open.swap_remove(i);
                // An error means the socket is already closed: the goal.
                let _ = slot.stream.shutdown(Shutdown::Both);
                true
            }
            None => false,
        }
    }

    /// Registers a new connection from `peer` (in [`Phase::Reading`]),
    /// making room as the caps above say; `None`: refuse it.
    fn admit(&mut self, peer: IpAddr, stream: TcpStream) -> Option<u64> {
        if self.open.iter().filter(|s| s.peer == peer).count() >= MAX_PER_CLIENT
            && !self.evict_oldest(|s| s.peer == peer && s.phase == Phase::Reading)
            && !self.evict_oldest(|s| s.peer == peer && s.phase == Phase::Events)
        {
            return None;
        }
        if self.count(Some(Phase::Reading)) >= MAX_READING {
            self.evict_oldest(|s| s.phase == Phase::Reading);
        }
        self.next_id += 1;
        let id = self.next_id;
        self.open.push(Slot { id, peer, phase: Phase::Reading, since: Instant::now(), stream });
        Some(id)
    }

    /// Moves connection `id` to `phase`. False when it was closed meanwhile,
    /// or (to [`Phase::Serving`]) when every serving slot is taken. A new
    /// event stream over [`MAX_EVENT_STREAMS`] closes the oldest one.
    fn promote(&mut self, id: u64, phase: Phase) -> bool {
        if !self.is_open(id) {
            return false;
        }
        match phase {
            Phase::Serving if self.serving() >= MAX_CONNECTIONS => return false,
            Phase::Events if self.count(Some(Phase::Events)) >= MAX_EVENT_STREAMS => {
                // `id` is serving, not streaming yet, so this closes another.
                self.evict_oldest(|s| s.phase == Phase::Events);
            }
            _ => {}
        }
        let slot = self.open.iter_mut().find(|s| s.id == id);
        slot.map(|slot| {
            slot.phase = phase;
            slot.since = Instant::now();
        })
        .is_some()
    }

    fn is_open(&self, id: u64) -> bool {
        self.open.iter().any(|s| s.id == id)
    }

    fn release(&mut self, id: u64) {
        self.open.retain(|s| s.id != id);
    }
}

/// Accepts connections until `shared.stop` is set.
pub(crate) fn serve(listener: TcpListener, shared: Arc<Shared>, config: Arc<ServerConfig>) {
    for conn in listener.incoming() {
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(mut stream) = conn else { continue };
        // A refusal must not stall the accept loop on a client that reads nothing.
        if stream.set_write_timeout(Some(WRITE_TIMEOUT)).is_err() {
            continue;
        }
        let peer = match stream.peer_addr() {
            Ok(a) => a.ip(),
            Err(_) => continue,
        };
        let admitted = stream.try_clone().ok().and_then(|handle| shared.slots().admit(peer, handle));
        let Some(id) = admitted else {
            let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
            let _ = respond(&mut stream, 503, "text/plain", b"too many connections");
            continue;
        };
        let spawned = std::thread::Builder::new().name("colslam-viewer-conn".into()).spawn({
            let shared = Arc::clone(&shared);
            let config = Arc::clone(&config);
            move || {
                // Errors here are a client going away: nothing to report.
                let _ = handle(stream, id, &shared, &config);
                shared.slots().release(id);
            }
        });
        if spawned.is_err() {
            shared.slots().release(id);
        }
    }
}

/// A parsed request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Request {
    /// `GET`, `POST`, ...
    pub method: String,
    /// The target's path, percent-decoded.
    pub path: String,
    /// The target's query, decoded, in order.
    pub query: Vec<(String, String)>,
    /// Headers with lower-case names.
    pub headers: Vec<(String, String)>,
    /// The body's announced length (`Content-Length`, 0 without one).
    pub content_length: usize,
    /// The body ([`parse_request_head`] leaves it empty).
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

/// Why a request could not be parsed or is refused: the status to answer with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{status}: {message}")]
pub struct BadRequest {
    /// The HTTP status.
    pub status: u16,
    /// The reason, sent as `{"error": message}`.
    pub message: String,
}

fn bad(status: u16, message: impl Into<String>) -> BadRequest {
    BadRequest { status, message: message.into() }
}

/// Where the head ends in `buf` (just past the blank line), searching from
/// `from` (so a head arriving byte by byte is scanned once).
fn head_end(buf: &[u8], from: usize) -> Option<usize> {
    (from..buf.len()).find_map(|i| {
        let rest = buf.get(i..)?;
        if rest.starts_with(b"\n\n") {
            Some(i + 2)
        } else if rest.starts_with(b"\r\n\r\n") {
            Some(i + 4)
        } else {
            None
        }
    })
}

/// Parses a request head: the bytes up to and including the blank line that
/// ends it (a missing blank line is accepted). Pure, for tests and fuzzing;
/// [`read_request`] reads the head and then the body it announces.
pub fn parse_request_head(head: &[u8]) -> Result<Request, BadRequest> {
    if head.len() > MAX_HEAD_BYTES {
        return Err(bad(431, "request head too large"));
    }
    let head = std::str::from_utf8(head).map_err(|_| bad(400, "request head is not UTF-8"))?;
    let mut lines = head.lines();
    let request_line = lines.next().unwrap_or_default();
    let mut parts = request_line.split_whitespace();
    let (Some(method), Some(target), Some(version)) = (parts.next(), parts.next(), parts.next()) else {
        return Err(bad(400, format!("malformed request line {request_line:?}")));
    };
    if !version.starts_with("HTTP/1.") {
        return Err(bad(505, format!("unsupported protocol {version}")));
    }
    let mut content_length: Option<usize> = None;
    let mut headers = Vec::new();
    for h in lines {
        if let Some((k, v)) = h.split_once(':') {
            let (k, v) = (k.trim().to_ascii_lowercase(), v.trim());
            if k == "content-length" {
                let n = v.parse().map_err(|_| bad(400, format!("bad Content-Length {v:?}")))?;
                if content_length.is_some_and(|c| c != n) {
                    return Err(bad(400, "conflicting Content-Length headers"));
                }
                content_length = Some(n);
            }
            headers.push((k, v.to_string()));
        }
    }
    let content_length = content_length.unwrap_or(0);
    if content_length > MAX_BODY_BYTES {
        return Err(bad(413, format!("body of {content_length} bytes exceeds {MAX_BODY_BYTES}")));
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    let query = query
        .split('&')
        .filter(|s| !s.is_empty())
        .map(|kv| {
            let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
            (percent_decode(k), percent_decode(v))
        })
        .collect();
    Ok(Request {
        method: method.to_string(),
        path: percent_decode(path),
        query,
        headers,
        content_length,
        body: Vec::new(),
    })
}

fn read_failed(e: &std::io::Error) -> BadRequest {
    match e.kind() {
        ErrorKind::TimedOut | ErrorKind::WouldBlock => bad(408, "the request did not arrive in time"),
        _ => bad(400, format!("cannot read request: {e}")),
    }
}

/// Reads one request from `r`: the head, then the body it announces.
pub(crate) fn read_request(r: &mut impl Read) -> Result<Request, BadRequest> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 4096];
    let end = loop {
        // The terminator may straddle two reads: rescan the last 3 bytes.
        if let Some(end) = head_end(&buf, buf.len().saturating_sub(chunk.len() + 3)) {
            break end;
        }
        if buf.len() > MAX_HEAD_BYTES {
            return Err(bad(431, "request head too large"));
        }
        let n = r.read(&mut chunk).map_err(|e| read_failed(&e))?;
        if n == 0 {
            return Err(bad(400, "connection closed before the request ended"));
        }
        buf.extend_from_slice(chunk.get(..n).unwrap_or_default());
    };
    let (head, rest) = buf.split_at(end.min(buf.len()));
    let mut req = parse_request_head(head)?;
    let mut body = rest.to_vec();
    body.truncate(req.content_length);
    while body.len() < req.content_length {
        let want = (req.content_length - body.len()).min(chunk.len());
        let n = r.read(chunk.get_mut(..want).unwrap_or_default()).map_err(|e| read_failed(&e))?;
        if n == 0 {
            return Err(bad(400, "body shorter than Content-Length"));
        }
        body.extend_from_slice(chunk.get(..n).unwrap_or_default());
    }
    req.body = body;
    Ok(req)
}

/// A socket reader that fails once `deadline` passes: each read waits at
/// most until then, so a client dripping bytes cannot stretch its request.
struct DeadlineReader<'a> {
    stream: &'a TcpStream,
    deadline: Instant,
}

impl Read for DeadlineReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::new(ErrorKind::TimedOut, "request deadline passed"));
        }
        self.stream.set_read_timeout(Some(left))?;
        let mut s = self.stream;
        s.read(buf)
    }
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
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        409 => "Conflict",
        413 => "Payload Too Large",
        415 => "Unsupported Media Type",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        _ => "Status",
    }
}

/// Writes a whole response; `extra` holds further header lines, each ending
/// in `\r\n`.
fn respond_with(s: &mut TcpStream, status: u16, content_type: &str, extra: &str, body: &[u8]) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status} {}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n{extra}\r\n",
        reason(status),
        body.len()
    );
    s.write_all(head.as_bytes())?;
    s.write_all(body)?;
    s.flush()
}

fn respond(s: &mut TcpStream, status: u16, content_type: &str, body: &[u8]) -> std::io::Result<()> {
    respond_with(s, status, content_type, "", body)
}

fn respond_json(s: &mut TcpStream, status: u16, v: &Value) -> std::io::Result<()> {
    respond(s, status, "application/json", v.to_string().as_bytes())
}

fn respond_error(s: &mut TcpStream, status: u16, message: &str) -> std::io::Result<()> {
    respond_json(s, status, &json!({ "error": message }))
}

/// One connection being served.
struct Conn<'a> {
    shared: &'a Shared,
    config: &'a ServerConfig,
    id: u64,
}

fn handle(mut stream: TcpStream, id: u64, shared: &Shared, config: &ServerConfig) -> std::io::Result<()> {
    stream.set_write_timeout(Some(WRITE_TIMEOUT))?;
    let deadline = Instant::now() + config.request_deadline;
    let req = read_request(&mut DeadlineReader { stream: &stream, deadline });
    let req = match req {
        Ok(r) => r,
        Err(e) => return respond_error(&mut stream, e.status, &e.message),
    };
    if !shared.slots().promote(id, Phase::Serving) {
        return respond_error(&mut stream, 503, "too many connections");
    }
    if let Err(e) = check_access(&req, &config.access) {
        return respond_error(&mut stream, e.status, &e.message);
    }
    route(&mut stream, &req, &Conn { shared, config, id })
}

/// Host names a loopback-bound viewer answers to. Anything else in `Host` is
/// a DNS-rebinding attempt: another site's page whose name resolves here.
const LOOPBACK_HOSTS: [&str; 3] = ["127.0.0.1", "localhost", "[::1]"];

/// Guards against other web sites driving the viewer through the user's
/// browser (it reads and writes files and starts runs on request).
///
/// Loopback-bound, the server accepts only loopback `Host` names, and a
/// request carrying an `Origin` must come from the page's own origin.
/// Bound elsewhere, a `Host` proves nothing (DNS rebinding makes any name
/// point here), so every request needs the access token (401 without), and
/// an `Origin` must name the bound address and port (403 otherwise).
///
/// In both cases POST bodies must be `application/json`, which a cross-site
/// form cannot send without a CORS preflight (answered 405 here, so the
/// browser refuses). Every request with an effect is a POST.
pub(crate) fn check_access(req: &Request, access: &Access) -> Result<(), BadRequest> {
    match access {
        Access::Loopback => {
            let host = req.header("host");
            if let Some(h) = host {
                let name = match h.rsplit_once(':') {
                    Some((n, port)) if port.bytes().all(|b| b.is_ascii_digit()) => n,
                    _ => h,
                };
                if !LOOPBACK_HOSTS.iter().any(|l| l.eq_ignore_ascii_case(name)) {
                    return Err(bad(403, format!("host {h:?} is not served (the viewer answers on loopback only)")));
                }
            }
            if let Some(origin) = req.header("origin") {
                let same =
                    host.is_some_and(|h| origin.strip_prefix("http://").is_some_and(|o| o.eq_ignore_ascii_case(h)));
                if !same {
                    return Err(bad(403, format!("cross-origin request from {origin:?} refused")));
                }
            }
        }
        Access::Token { token, bind, port } => {
            if !carries_token(req, token, *port) {
                return Err(bad(
                    401,
                    "access token missing or wrong: open the URL the viewer printed (it ends in ?token=...)",
                ));
            }
            if let Some(origin) = req.header("origin")
                && !origin_allowed(origin, *bind, *port)
            {
                return Err(bad(403, format!("cross-origin request from {origin:?} refused")));
            }
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

/// The cookie that carries the token once the index was opened with it.
/// Named by port: browsers share a host's cookies across its ports.
fn token_cookie(port: u16) -> String {
    format!("colslam_token_{port}")
}

/// Equality of two secrets in time independent of where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && std::hint::black_box(a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y))) == 0
}

/// Whether the request carries `token`: in its query, its cookie or an
/// `Authorization: Bearer` header.
fn carries_token(req: &Request, token: &str, port: u16) -> bool {
    let name = token_cookie(port);
    let from_cookie = req
        .headers
        .iter()
        .filter(|(k, _)| k == "cookie")
        .flat_map(|(_, v)| v.split(';'))
        .filter_map(|c| c.trim().split_once('='))
        .filter(|(k, _)| *k == name)
        .map(|(_, v)| v);
    let from_bearer = req.header("authorization").and_then(|a| a.strip_prefix("Bearer ")).map(str::trim);
    let from_query = req.param("token");
    // Every candidate is compared (no early exit on the first match).
    from_query
        .into_iter()
        .chain(from_bearer)
        .chain(from_cookie)
        .fold(false, |ok, c| ok | same_secret(c.as_bytes(), token.as_bytes()))
}

/// Whether `origin` (e.g. `http://192.168.1.5:8765`) is the page's own
/// origin for a server bound to `bind`:`port`. For an unspecified bind
/// (0.0.0.0, ::) any IP literal with the right port is; host names never
/// are except `localhost` (a DNS name can be pointed here by anyone).
pub(crate) fn origin_allowed(origin: &str, bind: IpAddr, port: u16) -> bool {
    let Some(authority) = origin.strip_prefix("http://") else { return false };
    let (host, origin_port) = match authority.rsplit_once(':') {
        Some((h, p)) if !h.is_empty() && !p.contains(']') => (h, p.parse::<u16>().ok()),
        _ => (authority, Some(80)),
    };
    if origin_port != Some(port) {
        return false;
    }
    let literal = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')).unwrap_or(host);
    match literal.parse::<IpAddr>() {
        Ok(ip) => ip == bind || bind.is_unspecified(),
        Err(_) => bind.is_unspecified() && host.eq_ignore_ascii_case("localhost"),
    }
}

/// The `Set-Cookie` line for the index when it was opened with a valid
/// token in its URL: the page's later requests (fetch, EventSource,
/// pictures) then carry it without knowing it. HttpOnly: scripts cannot
/// read it; SameSite=Strict: other sites' requests do not carry it.
fn index_cookie(req: &Request, access: &Access) -> String {
    match access {
        Access::Token { token, port, .. }
            if req.param("token").is_some_and(|t| same_secret(t.as_bytes(), token.as_bytes())) =>
        {
            format!("Set-Cookie: {}={token}; Path=/; HttpOnly; SameSite=Strict\r\n", token_cookie(*port))
        }
        _ => String::new(),
    }
}

fn route(s: &mut TcpStream, req: &Request, conn: &Conn) -> std::io::Result<()> {
    let shared = conn.shared;
    let get = req.method == "GET";
    let post = req.method == "POST";
    match req.path.as_str() {
        "/" | "/index.html" if get => {
            let cookie = index_cookie(req, &conn.config.access);
            respond_with(s, 200, "text/html; charset=utf-8", &cookie, INDEX_HTML.as_bytes())
        }
        "/app.js" if get => respond(s, 200, "text/javascript; charset=utf-8", APP_JS.as_bytes()),
        "/style.css" if get => respond(s, 200, "text/css; charset=utf-8", STYLE_CSS.as_bytes()),
        "/favicon.ico" if get => respond(s, 204, "image/x-icon", b""),
        "/events" if get => event_stream(s, conn),
        "/api/state" if get => api_state(s, req, shared),
        "/api/frame.png" if get => picture(s, shared, false),
        "/api/keyframe.png" if get => picture(s, shared, true),
        "/api/camera" if get => api_camera(s, req, shared),
        "/api/image" if post => api_image(s, req, shared),
        "/api/max_frames" if post => api_max_frames(s, req, shared),
        "/api/run" if post => api_run(s, req, shared),
        "/api/stop" if post => api_stop(s, shared),
        "/api/load" if post => api_load(s, req, shared),
        "/api/export" if post => api_export(s, req, shared),
        "/" | "/index.html" | "/app.js" | "/style.css" | "/favicon.ico" | "/events" | "/api/state"
        | "/api/frame.png" | "/api/keyframe.png" | "/api/camera" | "/api/image" | "/api/max_frames" | "/api/run"
        | "/api/stop" | "/api/load" | "/api/export" => {
            respond_error(s, 405, &format!("{} not allowed on {}", req.method, req.path))
        }
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

/// Whether the client closed its end: a non-blocking peek sees end of file
/// (or an error) at once, where a write would succeed into the socket's
/// buffer and fail only later.
fn peer_gone(s: &TcpStream) -> bool {
    if s.set_nonblocking(true).is_err() {
        return true;
    }
    let peeked = s.peek(&mut [0u8; 1]);
    if s.set_nonblocking(false).is_err() {
        return true;
    }
    match peeked {
        Ok(0) => true,
        Ok(_) => false,
        Err(e) => e.kind() != ErrorKind::WouldBlock,
    }
}

fn event_stream(s: &mut TcpStream, conn: &Conn) -> std::io::Result<()> {
    let shared = conn.shared;
    if !shared.slots().promote(conn.id, Phase::Events) {
        return Ok(());
    }
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
    let mut last_write = Instant::now();
    loop {
        let msg = {
            let st = shared.lock();
            let (st, _) = shared
                .changed
                .wait_timeout_while(st, SSE_POLL, |st| !st.shutdown && st.epoch == epoch && st.version == version)
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
        // A client that left, or a stream closed to make room, ends here.
        if peer_gone(s) || !shared.slots().is_open(conn.id) {
            return Ok(());
        }
        match msg {
            Some((e, v, body)) => {
                send_event(s, e, v, &body)?;
                epoch = e;
                version = v;
                last_write = Instant::now();
                std::thread::sleep(MIN_EVENT_INTERVAL);
            }
            None if last_write.elapsed() >= KEEPALIVE => {
                s.write_all(b": keepalive\n\n")?;
                s.flush()?;
                last_write = Instant::now();
            }
            None => {}
        }
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
        Err(e) => respond_error(s, 500, &colslam_slam::error_chain(&e)),
    }
}

/// The reprojection error (pixels) beyond which the frame panel draws a
/// keypoint with a 3D point as an outlier: the pipeline's own filter bound.
fn outlier_threshold() -> f64 {
    colslam_slam::options::MapperOptions::default().max_reproj_error
}

/// An image id from a query or body value.
fn image_id(v: Option<&Value>) -> Result<u32, String> {
    let id = match v {
        Some(Value::Number(n)) => n.as_u64(),
        Some(Value::String(t)) => t.trim().parse::<u64>().ok(),
        _ => None,
    };
    id.and_then(|i| u32::try_from(i).ok()).ok_or_else(|| "id must be an image id (a whole number)".to_string())
}

/// `GET /api/camera?id=N`: camera N of the loaded model with its keypoints
/// by state (see [`crate::camera_detail`]). Reads the model in memory only.
fn api_camera(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let id = match image_id(req.param("id").map(|v| Value::String(v.to_string())).as_ref()) {
        Ok(id) => id,
        Err(e) => return respond_error(s, 400, &e),
    };
    let (Some(rec), images) = shared.lock().model_and_images() else {
        return respond_error(s, 404, "no loaded model (a live map has no keypoints to show)");
    };
    match crate::frames::camera_detail(&rec, id, outlier_threshold()) {
        Some(mut v) => {
            // The frame's time as the run read it, when the images' source
            // knows it (a list's stamps rather than the image name).
            let listed = rec.image(colslam_scene::ImageId(id)).and_then(|img| images?.timestamp(&img.name));
            if let Some(t) = listed {
                v["timestamp"] = Value::from(t);
            }
            respond_json(s, 200, &v)
        }
        None => respond_error(s, 404, &format!("the model has no image {id}")),
    }
}

/// `POST /api/image {id}`: the picture of image `id` of the loaded model, as
/// PNG at most [`crate::VIEW_MAX_WIDTH`] wide. A POST because it opens a file
/// (or starts ffmpeg for a video frame): only the page's own requests may.
/// Only images the model names are read (see [`crate::frames`]).
fn api_image(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let id = match json_body(req).and_then(|v| image_id(v.get("id"))) {
        Ok(id) => id,
        Err(e) => return respond_error(s, 400, &e),
    };
    let (Some(rec), Some(images)) = shared.lock().model_and_images() else {
        return respond_error(s, 404, "no images: no model was loaded from a folder");
    };
    // Decoding happens on this client's thread, outside the state lock.
    let picture = crate::frames::load_picture(&rec, &images, id, crate::VIEW_MAX_WIDTH);
    match picture {
        Ok(img) => match img.encode_png(std::path::Path::new("image.png")) {
            Ok(png) => respond(s, 200, "image/png", &png),
            Err(e) => respond_error(s, 500, &colslam_slam::error_chain(&e)),
        },
        Err(e) => {
            tracing::debug!("image {id} not served: {}", colslam_slam::error_chain(&e));
            respond_error(s, e.status(), &colslam_slam::error_chain(&e))
        }
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

/// `POST /api/max_frames {input, skip}`: the bound of the max-frames
/// slider. A POST because it opens the input (and may start ffprobe):
/// requests with effects outside the server pass the POST checks.
fn api_max_frames(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let Some(ctl) = shared.controller() else {
        return respond_error(s, 503, "no pipeline attached (started with `colslam view`)");
    };
    let parsed = json_body(req).and_then(|v| {
        let input = path_field(&v, "input")?;
        let skip = match v.get("skip") {
            None | Some(Value::Null) => Some(1),
            Some(Value::Number(n)) => n.as_u64().filter(|k| *k >= 1),
            Some(Value::String(t)) => t.trim().parse::<u64>().ok().filter(|k| *k >= 1),
            Some(_) => None,
        };
        let skip = skip.ok_or("frame skip must be an integer of at least 1")?;
        Ok((input, usize::try_from(skip).unwrap_or(usize::MAX)))
    });
    let (input, skip) = match parsed {
        Ok(p) => p,
        Err(e) => return respond_error(s, 400, &e),
    };
    match ctl.max_frames_for(&input, skip) {
        Ok(n) => respond_json(s, 200, &json!({ "max_frames": n })),
        Err(e) => respond_error(s, e.status(), &colslam_slam::error_chain(&e)),
    }
}

fn api_run(s: &mut TcpStream, req: &Request, shared: &Shared) -> std::io::Result<()> {
    let Some(ctl) = shared.controller() else {
        return respond_error(s, 503, "no pipeline attached: start the viewer with `colslam run ... --view` to run");
    };
    let settings = match RunSettings::from_json(&req.body) {
        Ok(v) => v,
        Err(e) => return respond_error(s, 400, &colslam_slam::error_chain(&e)),
    };
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
        Err(e) => respond_error(s, e.status(), &colslam_slam::error_chain(&e)),
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
            let images = crate::frames::ImageSource::discover(&path, &rec);
            shared.update(|st| {
                st.set_reconstruction(&rec, &path.display().to_string());
                st.set_images(images);
            });
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
        Err(e) => respond_error(s, 400, &format!("export failed: {}", colslam_slam::error_chain(&e))),
    }
}

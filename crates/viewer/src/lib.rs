//! The colslam viewer (paper section 3.7) as a local web application.
//!
//! [`Viewer::start`] binds a small HTTP/1.1 server (std only, loopback by
//! default) that serves an embedded WebGL page and streams the state through
//! Server-Sent Events. Producers feed it with
//! [`Viewer::set_reconstruction`] (a whole model), [`Viewer::sync_reconstruction`]
//! (a live model: only the difference is sent) and [`Viewer::apply`]
//! ([`ViewerUpdate`]: frames, keyframes, map deltas, summary, status). A
//! [`RunController`] attached with [`Viewer::set_controller`] lets the page
//! start and stop the pipeline.
//!
//! Live runs of the pipeline ([`colslam_slam::run::run`]): [`run_live`] runs
//! one with the page following it (a bridge thread turns the pipeline's
//! events into updates), and [`ViewController`] is the controller behind the
//! page's Run/Stop/Export buttons.
//!
//! Protocol (see `web/app.js`): `GET /events` streams `update` events whose
//! data is JSON; the first event of every connection is the full state
//! (`"full": true`), later ones hold only what changed since the previous
//! event: points and cameras stamped with a newer version, removed ids, and
//! the frame/keyframe/summary/status/run parts when they changed. A new
//! epoch (a loaded model, a reset) is sent as a full state again.
//! `GET /api/state[?epoch=E&since=V]` returns the same JSON once.
//!
//! ```no_run
//! use colslam_viewer::{Viewer, ViewerOptions, ViewerUpdate};
//! let viewer = Viewer::start(ViewerOptions::default()).unwrap();
//! println!("open {}", viewer.url());
//! viewer.apply(ViewerUpdate::Status("waiting".into()));
//! ```

mod demo;
mod export;
mod frames;
mod gt;
mod http;
mod live;
pub mod screenshot;
mod state;
mod types;

pub use demo::demo_reconstruction;
pub use export::{ExportError, ExportFormat, export_reconstruction, tum_trajectory};
pub use frames::{
    ImageSource, ImagesOptionError, KEYPOINT_OUTLIER, KEYPOINT_TRIANGULATED, KEYPOINT_UNMATCHED, PictureError,
    camera_detail, load_picture,
};
pub use gt::GroundTruthLayer;
pub use http::REQUEST_DEADLINE;
/// The server's request parser, as a pure function on bytes (for fuzzing).
#[doc(hidden)]
pub use http::{BadRequest, Request, parse_request_head};
pub use live::{MAX_IMAGES_IN_FLIGHT, RunShared, ViewController, run_args_from_settings, run_live};
pub use types::{
    ControlError, Extractor, FrameUpdate, KeyframeUpdate, MapDelta, Matcher, RunController, RunSettings, RunState,
    SettingsError, Summary, ViewerCamera, ViewerPoint, ViewerUpdate,
};

use colslam_image::Image;
use colslam_scene::Reconstruction;
use http::{Access, ServerConfig, Shared};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;

/// How long shutdown waits to connect to its own listener.
const WAKE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

/// Default port (0 would pick a free one).
pub const DEFAULT_PORT: u16 = 8765;

/// Where the server listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewerOptions {
    /// Address to bind. Default 127.0.0.1 (only this machine can connect).
    /// Any other address makes the server require an access token, made at
    /// start and part of [`Viewer::url`].
    pub bind: IpAddr,
    /// Port; 0 picks a free one. Default [`DEFAULT_PORT`].
    pub port: u16,
    /// Time a client has to send its whole request (head and body), however
    /// it paces it; a slower one is answered 408 and dropped. Default
    /// [`REQUEST_DEADLINE`].
    pub request_deadline: std::time::Duration,
}

impl Default for ViewerOptions {
    fn default() -> Self {
        Self { bind: IpAddr::V4(Ipv4Addr::LOCALHOST), port: DEFAULT_PORT, request_deadline: REQUEST_DEADLINE }
    }
}

impl ViewerOptions {
    /// The request deadline must be positive.
    pub fn validate(&self) -> Result<(), ViewerError> {
        if self.request_deadline.is_zero() {
            return Err(ViewerError::Options("the request deadline must be positive".into()));
        }
        Ok(())
    }
}

/// Why the viewer could not start.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// Binding the address failed (port in use, no permission).
    #[error("cannot listen on {addr}")]
    Bind {
        /// The address asked for.
        addr: SocketAddr,
        /// The cause.
        source: std::io::Error,
    },
    /// The server thread could not be spawned.
    #[error("cannot start the viewer thread: {0}")]
    Thread(std::io::Error),
    /// The options are out of range.
    #[error("invalid viewer options: {0}")]
    Options(String),
    /// No access token could be made (the OS's random source failed).
    #[error("cannot make the viewer's access token: {0}")]
    Token(String),
}

/// A random access token: 128 bits from the OS, in hex.
fn random_token() -> Result<String, ViewerError> {
    let mut bytes = [0u8; 16];
    getrandom::fill(&mut bytes).map_err(|e| ViewerError::Token(e.to_string()))?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// A cheap, cloneable handle that feeds the viewer from any thread.
#[derive(Clone)]
pub struct ViewerHandle {
    shared: Arc<Shared>,
}

impl ViewerHandle {
    /// Replaces the shown model by `rec` (clients receive it in full).
    pub fn set_reconstruction(&self, rec: &Reconstruction) {
        self.shared.update(|st| st.set_reconstruction(rec, "model"));
    }

    /// Like [`Self::set_reconstruction`], naming where the model came from.
    pub fn set_reconstruction_from(&self, rec: &Reconstruction, source: &str) {
        self.shared.update(|st| st.set_reconstruction(rec, source));
    }

    /// Brings the shown map in line with `rec` by a diff (clients receive
    /// only new, changed and removed points and cameras) and updates the
    /// summary's counts. Cost: one pass over `rec`'s points. No copy of
    /// `rec` is kept, so the page's Export uses [`RunController::snapshot`]
    /// (or a later [`Self::set_reconstruction`], e.g. when the run ends).
    pub fn sync_reconstruction(&self, rec: &Reconstruction) {
        self.shared.update(|st| st.sync_reconstruction(rec));
    }

    /// Applies one update.
    pub fn apply(&self, update: ViewerUpdate) {
        self.shared.update(|st| st.apply(update));
    }

    /// Says where the shown model's images are (the frame panel's
    /// pictures); call after the model was set.
    pub fn set_images(&self, images: ImageSource) {
        self.shared.update(|st| st.set_images(images));
    }

    /// Shows the comparison of the shown model with a ground truth (`None`
    /// removes it); call after the model was set.
    pub fn set_ground_truth(&self, layer: Option<GroundTruthLayer>) {
        self.shared.update(|st| st.set_ground_truth(layer));
    }

    /// Number of points and cameras currently held.
    pub fn counts(&self) -> (usize, usize) {
        self.shared.lock().counts()
    }
}

/// The running viewer server; dropping it stops the server.
pub struct Viewer {
    handle: ViewerHandle,
    addr: SocketAddr,
    token: Option<String>,
    thread: Option<JoinHandle<()>>,
}

impl Viewer {
    /// Binds and starts serving on a background thread.
    pub fn start(options: ViewerOptions) -> Result<Viewer, ViewerError> {
        options.validate()?;
        let want = SocketAddr::new(options.bind, options.port);
        let listener = TcpListener::bind(want).map_err(|source| ViewerError::Bind { addr: want, source })?;
        let addr = listener.local_addr().map_err(|source| ViewerError::Bind { addr: want, source })?;
        // Off loopback, other machines and (through DNS rebinding) any web
        // page the user opens can reach the server: only holders of the
        // printed URL may use it.
        let (access, token) = if options.bind.is_loopback() {
            (Access::Loopback, None)
        } else {
            let token = random_token()?;
            (Access::Token { token: token.clone(), bind: options.bind, port: addr.port() }, Some(token))
        };
        let config = Arc::new(ServerConfig { access, request_deadline: options.request_deadline });
        let shared = Arc::new(Shared::new());
        let thread = std::thread::Builder::new()
            .name("colslam-viewer".into())
            .spawn({
                let shared = Arc::clone(&shared);
                move || http::serve(listener, shared, config)
            })
            .map_err(ViewerError::Thread)?;
        Ok(Viewer { handle: ViewerHandle { shared }, addr, token, thread: Some(thread) })
    }

    /// The bound address (the real port when 0 was asked for).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's URL, e.g. `http://127.0.0.1:8765/`; off loopback with the
    /// access token, `http://192.168.1.5:8765/?token=...`.
    pub fn url(&self) -> String {
        match &self.token {
            Some(t) => format!("http://{}/?token={t}", self.addr),
            None => format!("http://{}/", self.addr),
        }
    }

    /// The access token requests need (`None` on loopback, where none is asked).
    pub fn access_token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// A handle for other threads.
    pub fn handle(&self) -> ViewerHandle {
        self.handle.clone()
    }

    /// Attaches the pipeline controller (enables Run/Stop in the page).
    pub fn set_controller(&self, controller: Arc<dyn RunController>) {
        *self.handle.shared.controller.lock().unwrap_or_else(|e| e.into_inner()) = Some(controller);
        self.handle.shared.update(|st| {
            st.has_controller = true;
            st.epoch += 1; // clients reload the full state, now with Run enabled
        });
    }

    /// See [`ViewerHandle::set_reconstruction`].
    pub fn set_reconstruction(&self, rec: &Reconstruction) {
        self.handle.set_reconstruction(rec);
    }

    /// See [`ViewerHandle::set_reconstruction_from`].
    pub fn set_reconstruction_from(&self, rec: &Reconstruction, source: &str) {
        self.handle.set_reconstruction_from(rec, source);
    }

    /// See [`ViewerHandle::set_images`].
    pub fn set_images(&self, images: ImageSource) {
        self.handle.set_images(images);
    }

    /// See [`ViewerHandle::set_ground_truth`].
    pub fn set_ground_truth(&self, layer: Option<GroundTruthLayer>) {
        self.handle.set_ground_truth(layer);
    }

    /// See [`ViewerHandle::sync_reconstruction`].
    pub fn sync_reconstruction(&self, rec: &Reconstruction) {
        self.handle.sync_reconstruction(rec);
    }

    /// See [`ViewerHandle::apply`].
    pub fn apply(&self, update: ViewerUpdate) {
        self.handle.apply(update);
    }

    /// Blocks until the server thread ends (for `colslam view`, which serves
    /// until interrupted).
    pub fn wait(mut self) {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }

    /// Stops the server: ends the event streams and the accept loop.
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        let shared = &self.handle.shared;
        shared.stop.store(true, Ordering::SeqCst);
        shared.update(|st| st.shutdown = true);
        // Wake the blocking accept with a connection of our own. Join only
        // when that worked: otherwise the accept could block forever, and
        // the thread ends at the next connection anyway.
        let woke = TcpStream::connect_timeout(&wake_addr(self.addr), WAKE_TIMEOUT).is_ok();
        if let Some(t) = self.thread.take()
            && woke
        {
            let _ = t.join();
        }
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.stop();
        }
    }
}

/// The address to connect to for waking the listener (an unspecified bind
/// address is reached through loopback).
fn wake_addr(addr: SocketAddr) -> SocketAddr {
    match addr.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), addr.port()),
        IpAddr::V6(ip) if ip.is_unspecified() => {
            SocketAddr::new(IpAddr::V6(std::net::Ipv6Addr::LOCALHOST), addr.port())
        }
        _ => addr,
    }
}

/// Largest width of the pictures sent to the page by default.
pub const VIEW_MAX_WIDTH: usize = 640;

/// A copy of `image` at most `max_width` wide (box-averaged, RGB or gray
/// kept), and the factor its coordinates were multiplied by (scale flow lines
/// with it). Images already narrow enough are copied unchanged (factor 1).
pub fn downscale_for_view(image: &Image, max_width: usize) -> (Image, f32) {
    let (w, h, c) = (image.width(), image.height(), image.channels());
    if w <= max_width || max_width == 0 {
        return (image.clone(), 1.0);
    }
    let step = w.div_ceil(max_width);
    let (nw, nh) = (w / step, (h / step).max(1));
    let mut out = Image::new(nw, nh, c);
    let data = image.data();
    let area = (step * step.min(h)) as u32;
    for y in 0..nh {
        for x in 0..nw {
            for ch in 0..c {
                let mut sum = 0u32;
                for dy in 0..step.min(h) {
                    for dx in 0..step {
                        // x*step+dx < nw*step <= w and y*step+dy < h (nh*step <= h
                        // or nh = 1 with dy < min(step, h)), so the index is in range.
                        let idx = ((y * step + dy) * w + x * step + dx) * c + ch;
                        sum += u32::from(data.get(idx).copied().unwrap_or(0));
                    }
                }
                out.set(x, y, ch, u8::try_from(sum / area.max(1)).unwrap_or(u8::MAX));
            }
        }
    }
    (out, 1.0 / step as f32)
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_frames;

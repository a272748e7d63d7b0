//! `colslam view` (the browser viewer, paper section 3.7) and
//! `colslam run ... --view` (the same page following a command-line run).
//!
//! Both print the page's URL as the first line on stdout (flushed; with
//! `--port 0` it names the port picked), then serve until Ctrl-C. With
//! `run --view --view-exit` the process exits when the run ends instead (for
//! scripts and tests).

use crate::stdout::outln;
use anyhow::{Context, Result};
use colslam_slam::run::{RunConfig, RunOptions};
use colslam_viewer::{
    DEFAULT_PORT, GroundTruthLayer, ImageSource, RunShared, ViewController, Viewer, ViewerOptions, run_live,
};
use std::io::Write;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// With `--view-exit`, how long the server stays up after the run so that
/// connected pages receive the final state.
const VIEW_EXIT_LINGER: Duration = Duration::from_millis(500);

/// Where the viewer listens.
#[derive(Debug, Clone, clap::Args)]
pub struct ServerArgs {
    /// Port of the viewer (0: any free one; the printed URL names it).
    #[arg(long, value_name = "PORT", default_value_t = DEFAULT_PORT)]
    pub port: u16,
    /// Address to listen on; the default serves this machine only.
    ///
    /// Any other address (e.g. 0.0.0.0) lets other machines connect: the
    /// viewer then makes a random access token, prints it in the URL
    /// (`http://HOST:PORT/?token=...`) and refuses requests without it
    /// (401). Whoever holds that URL can run the pipeline and read and write
    /// files as you: share it only with people you trust. The traffic is
    /// plain HTTP.
    #[arg(long, value_name = "ADDRESS", default_value = "127.0.0.1")]
    pub bind: IpAddr,
}

impl ServerArgs {
    fn options(&self) -> ViewerOptions {
        ViewerOptions { bind: self.bind, port: self.port, ..Default::default() }
    }
}

/// Arguments of `view`.
#[derive(Debug, clap::Args)]
pub struct ViewArgs {
    /// COLMAP model folder to show (binary or text). Without it the page
    /// starts empty: load a model or start a run from the page.
    pub model: Option<PathBuf>,
    /// Folder of the model's images (COLMAP's image_path), or the video the
    /// model was made from; the frame panel shows them with their
    /// keypoints. Default: the input named by a colslam run's report.json
    /// beside the model, else the first of MODEL/images, the folder above
    /// the model, its rgb/ and its images/ that holds the images.
    #[arg(long, requires = "model")]
    pub images: Option<PathBuf>,
    /// Ground-truth trajectory (TUM format) to compare the model's cameras
    /// with: drawn aligned to the model (Sim(3), as `colslam eval`), the
    /// path coloured by the error, the ATE shown.
    #[arg(long, requires = "model")]
    pub gt: Option<PathBuf>,
    /// Write a picture of the page to this PNG file and exit instead of
    /// serving (headless Chromium: COLSLAM_CHROMIUM, else chromium,
    /// chromium-browser or google-chrome on PATH). Same input, same picture.
    #[arg(long, requires = "model")]
    pub screenshot: Option<PathBuf>,
    /// Size of the screenshot, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x800", requires = "screenshot", value_parser = parse_size)]
    pub size: (u32, u32),
    #[command(flatten)]
    pub server: ServerArgs,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    colslam_viewer::screenshot::parse_size(s).map_err(|e| e.to_string())
}

/// Viewer flags of `run`.
#[derive(Debug, Clone, clap::Args)]
#[command(next_help_heading = "Viewer")]
pub struct RunViewArgs {
    /// Follow the run in the browser viewer, then serve the final model until Ctrl-C.
    #[arg(long)]
    pub view: bool,
    /// Port of the viewer (0: any free one; the printed URL names it).
    #[arg(long, value_name = "PORT", default_value_t = DEFAULT_PORT, requires = "view")]
    pub port: u16,
    /// Address the viewer listens on (elsewhere than loopback a token is required; see `colslam view --help`).
    #[arg(long, value_name = "ADDRESS", default_value = "127.0.0.1", requires = "view")]
    pub bind: IpAddr,
    /// With --view: exit when the run ends instead of serving on.
    #[arg(long, requires = "view")]
    pub view_exit: bool,
}

/// Prints the URL as the first stdout line, flushed (scripts read it).
fn announce(viewer: &Viewer) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "viewer: {}", viewer.url())?;
    out.flush()?;
    Ok(())
}

/// Runs `view`; the page's runs use `threads` (0: all cores).
pub fn run(args: &ViewArgs, threads: usize) -> Result<()> {
    // A bad folder is reported before anything starts.
    let model = match &args.model {
        Some(dir) => Some(
            colslam_scene::read_model(dir).with_context(|| format!("cannot load the model in {}", dir.display()))?,
        ),
        None => None,
    };
    let images = match (&args.images, &model, &args.model) {
        (Some(dir), _, _) => Some(ImageSource::given(dir).context("--images")?),
        (None, Some(rec), Some(dir)) => Some(ImageSource::discover(dir, rec)),
        _ => None,
    };
    let gt = match (&args.gt, &model) {
        (Some(file), Some(rec)) => {
            // The frames' times as the run read them (a list's stamps), else
            // those in the image names.
            let stamp_of = |image: &str| images.as_ref().and_then(|i| i.timestamp(image));
            let layer = GroundTruthLayer::read(rec, file, &stamp_of)
                .with_context(|| format!("comparing with {}", file.display()))?;
            Some(layer)
        }
        _ => None,
    };
    let chromium = match &args.screenshot {
        Some(_) => Some(colslam_viewer::screenshot::find_chromium()?),
        None => None,
    };
    // A screenshot needs no fixed port.
    let options =
        ViewerOptions { port: if chromium.is_some() { 0 } else { args.server.port }, ..args.server.options() };
    let viewer = Viewer::start(options)?;
    if chromium.is_none() {
        let shared = Arc::new(RunShared::default());
        let base = RunOptions { threads, ..RunOptions::default() };
        viewer.set_controller(Arc::new(ViewController::new(viewer.handle(), shared, base)));
    }
    if let (Some(rec), Some(dir)) = (&model, &args.model) {
        viewer.set_reconstruction_from(rec, &dir.display().to_string());
        if let Some(images) = images {
            viewer.set_images(images);
        }
        if let Some(layer) = gt {
            outln!("ground truth: ATE {:.6} m over {} poses (Sim(3))", layer.ate_rmse, layer.matched);
            viewer.set_ground_truth(Some(layer));
        }
    }
    if let (Some(chromium), Some(out)) = (chromium, &args.screenshot) {
        colslam_viewer::screenshot::capture(&chromium, &viewer.url(), args.size, out)?;
        outln!("screenshot written to {}", out.display());
        viewer.shutdown();
        return Ok(());
    }
    announce(&viewer)?;
    if let Some(rec) = &model {
        outln!("showing {} cameras and {} points", rec.num_registered_images(), rec.num_points3d());
    }
    outln!("serving until Ctrl-C");
    std::io::stdout().flush()?;
    viewer.wait();
    Ok(())
}

/// Runs `config` with the viewer following it (`run --view`).
pub fn run_followed(config: &RunConfig, v: &RunViewArgs, quiet: bool) -> Result<()> {
    let viewer = Viewer::start(ViewerOptions { bind: v.bind, port: v.port, ..Default::default() })?;
    let shared = Arc::new(RunShared::default());
    let base = config.options.clone();
    viewer.set_controller(Arc::new(ViewController::new(viewer.handle(), Arc::clone(&shared), base)));
    announce(&viewer)?;
    // The page's Run button is refused while this run goes on (the flag of
    // a fresh `shared` is free; run_live releases it).
    shared.try_begin();
    let outcome = crate::cmd_run::with_progress(quiet, |bar| {
        run_live(config, bar, &viewer.handle(), &shared, std::time::Instant::now())
    });
    // The page shows the end either way (finished, stopped or failed with
    // the message); the terminal gets the summary or the error.
    let failed = match outcome {
        Ok(o) => {
            crate::cmd_run::print_outcome(config, &o, quiet);
            None
        }
        Err(e) => Some(e),
    };
    if v.view_exit {
        std::io::stdout().flush()?;
        std::thread::sleep(VIEW_EXIT_LINGER);
        viewer.shutdown();
        return failed.map_or(Ok(()), |e| Err(e.into()));
    }
    let ended = match failed {
        Some(e) => {
            eprintln!("error: {}", colslam_slam::error_chain(&e));
            "run failed"
        }
        None => "run finished",
    };
    outln!("{ended}; the viewer keeps serving at {} until Ctrl-C", viewer.url());
    std::io::stdout().flush()?;
    viewer.wait();
    Ok(())
}

//! `colslam demo`: the embedded default. Generates the bundled synthetic
//! sequence (a textured room along a hand-held-like path, exact ground truth)
//! in TUM layout, ready for `colslam run` and `colslam eval`.

use crate::stdout::outln;
use anyhow::{Context, Result};
use colslam_synth::{SynthOptions, generate};
use std::path::PathBuf;

/// Default output folder of `colslam demo`.
pub const DEFAULT_DEMO_DIR: &str = "colslam-demo";

/// Arguments of `demo`.
#[derive(Debug, clap::Args)]
#[command(next_help_heading = "Synthetic sequence")]
pub struct DemoArgs {
    /// Folder of the sequence, its ground truth and the run's output/ (a complete sequence with the same options is reused).
    #[arg(short, long, value_name = "DIR", default_value = DEFAULT_DEMO_DIR)]
    pub output: PathBuf,
    /// Number of frames.
    #[arg(long, value_name = "N", default_value_t = SynthOptions::default().frames)]
    pub frames: usize,
    /// Image width in pixels.
    #[arg(long, value_name = "PIXELS", default_value_t = SynthOptions::default().width)]
    pub width: usize,
    /// Image height in pixels.
    #[arg(long, value_name = "PIXELS", default_value_t = SynthOptions::default().height)]
    pub height: usize,
    /// Gaussian image noise, standard deviation in gray levels.
    #[arg(long, value_name = "SIGMA", default_value_t = SynthOptions::default().noise_sigma)]
    pub noise: f64,
    /// Motion blur: exposure as a fraction of the frame interval (0: none).
    #[arg(long, value_name = "FRACTION", default_value_t = SynthOptions::default().motion_blur)]
    pub blur: f64,
    /// Rolling-shutter readout time in seconds, first row to last (0: a global shutter).
    #[arg(long, value_name = "SECONDS", default_value_t = SynthOptions::default().readout)]
    pub readout: f64,
    /// Amplitude of the hand-held orientation jitter in degrees (a faster-turning camera).
    #[arg(long, value_name = "DEG", default_value_t = SynthOptions::default().jitter_rotation_deg)]
    pub rotation_jitter: f64,
    /// Render with lens distortion (OPENCV model k1, k2, p1, p2). Default: none.
    #[arg(long, num_args = 4, value_names = ["K1", "K2", "P1", "P2"], allow_hyphen_values = true)]
    pub distortion: Option<Vec<f64>>,
    /// Random seed of the scene, textures and path.
    #[arg(long, value_name = "N", default_value_t = SynthOptions::default().seed)]
    pub scene_seed: u64,
    /// Only generate the sequence; do not run the pipeline on it.
    #[arg(long)]
    pub generate_only: bool,
    #[command(flatten)]
    pub options: colslam_slam::run::RunOptions,
}

impl DemoArgs {
    fn options(&self) -> SynthOptions {
        SynthOptions {
            frames: self.frames,
            width: self.width,
            height: self.height,
            noise_sigma: self.noise,
            motion_blur: self.blur,
            readout: self.readout,
            jitter_rotation_deg: self.rotation_jitter,
            distortion: self.distortion.as_ref().map(|d| [d[0], d[1], d[2], d[3]]),
            seed: self.scene_seed,
            ..SynthOptions::default()
        }
    }
}

/// Runs `demo`: generate the sequence, run the pipeline on it, evaluate
/// against the exact ground truth.
pub fn run(args: &DemoArgs, quiet: bool) -> Result<()> {
    // Options are checked before the sequence is rendered.
    args.options.validate()?;
    let opts = args.options();
    let pb = crate::logging::progress_bar(opts.frames as u64, quiet, "rendering", "frames");
    let progress = |done: usize, _total: usize| pb.set_position(done as u64);
    let synth = generate(&opts, &args.output, Some(&progress))
        .with_context(|| format!("generating the synthetic sequence in {}", args.output.display()))?;
    pb.finish_and_clear();
    outln!("synthetic sequence: {} ({synth})", args.output.display());
    if args.generate_only {
        return Ok(());
    }
    let run_args = colslam_slam::run::RunConfig {
        gt: Some(args.output.join("groundtruth.txt")),
        options: args.options.clone(),
        ..colslam_slam::run::RunConfig::new(&args.output, args.output.join("output"))
    };
    let outcome =
        crate::cmd_run::run_with_progress(&run_args, quiet, colslam_slam::EventSink::none(), Default::default())?;
    crate::cmd_run::print_outcome(&run_args, &outcome, quiet);
    if let Some(e) = &outcome.report.eval {
        outln!(
            "ATE RMSE {:.4} m over {} frames = {:.4} % of the scene diagonal ({:.2} m); plot: {}",
            e.ate_rmse,
            e.matched,
            100.0 * e.ate_rmse / synth.scene_diagonal,
            synth.scene_diagonal,
            run_args.output.join("trajectory.eval.png").display()
        );
    }
    Ok(())
}

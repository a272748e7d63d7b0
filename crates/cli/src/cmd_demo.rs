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
pub struct DemoArgs {
    /// Output folder (created; a complete sequence with the same options is reused).
    #[arg(short, long, default_value = DEFAULT_DEMO_DIR)]
    pub output: PathBuf,
    /// Number of frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Image width in pixels.
    #[arg(long)]
    pub width: Option<usize>,
    /// Image height in pixels.
    #[arg(long)]
    pub height: Option<usize>,
    /// Gaussian image noise, standard deviation in gray levels.
    #[arg(long)]
    pub noise: Option<f64>,
    /// Motion blur: exposure as a fraction of the frame interval (0 = none).
    #[arg(long)]
    pub blur: Option<f64>,
    /// Render with lens distortion (OPENCV model k1, k2, p1, p2).
    #[arg(long, num_args = 4, value_names = ["K1", "K2", "P1", "P2"], allow_hyphen_values = true)]
    pub distortion: Option<Vec<f64>>,
    /// Random seed of the scene, textures and path.
    #[arg(long)]
    pub scene_seed: Option<u64>,
    /// Only generate the sequence; do not run the pipeline on it.
    #[arg(long)]
    pub generate_only: bool,
    #[command(flatten)]
    pub options: colslam_slam::run::RunOptions,
}

impl DemoArgs {
    fn options(&self) -> SynthOptions {
        let mut o = SynthOptions::default();
        if let Some(v) = self.frames {
            o.frames = v;
        }
        if let Some(v) = self.width {
            o.width = v;
        }
        if let Some(v) = self.height {
            o.height = v;
        }
        if let Some(v) = self.noise {
            o.noise_sigma = v;
        }
        if let Some(v) = self.blur {
            o.motion_blur = v;
        }
        if let Some(d) = &self.distortion {
            o.distortion = Some([d[0], d[1], d[2], d[3]]);
        }
        if let Some(v) = self.scene_seed {
            o.seed = v;
        }
        o
    }
}

/// Runs `demo`: generate the sequence, run the pipeline on it, evaluate
/// against the exact ground truth.
pub fn run(args: &DemoArgs, quiet: bool) -> Result<()> {
    // Options are checked before the sequence is rendered.
    args.options.validate()?;
    let opts = args.options();
    let pb = crate::logging::progress_bar(opts.frames as u64, quiet, "rendering");
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
    crate::cmd_run::print_outcome(&run_args, &outcome);
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

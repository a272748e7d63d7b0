//! `colslam eval`: ATE and RPE of an estimated trajectory against ground
//! truth, with the numbers of `evo_ape tum -as` / `evo_rpe tum -as`, and a plot.

use crate::stdout::outln;
use anyhow::{Context, Result};
use colslam_eval::{Alignment, EvalOptions, evaluate_files, plot::plot_evaluation};
use std::path::PathBuf;

/// Arguments of `eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory (TUM format).
    #[arg(long, value_name = "FILE")]
    pub gt: PathBuf,
    /// Estimated trajectory (TUM format), e.g. a run's trajectory.tum.
    #[arg(long, value_name = "FILE")]
    pub est: PathBuf,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Where to write the PNG plot (default: beside the estimate, `<name>.eval.png`).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
    /// Do not write a plot.
    #[arg(long, conflicts_with = "plot")]
    pub no_plot: bool,
    /// Maximum timestamp difference for association, seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = EvalOptions::default().max_diff)]
    pub max_diff: f64,
    /// Time offset added to the estimate's timestamps, seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = EvalOptions::default().offset, allow_hyphen_values = true)]
    pub offset: f64,
    /// Alignment of the estimate onto the ground truth.
    #[arg(long, value_name = "KIND", value_enum, default_value = "sim3")]
    pub align: Alignment,
    /// Frame distance of the relative pose error (RPE).
    #[arg(long, value_name = "FRAMES", default_value_t = EvalOptions::default().rpe_delta)]
    pub delta: usize,
}

/// Runs `eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    let opts = EvalOptions {
        max_diff: args.max_diff,
        offset: args.offset,
        align: args.align,
        rpe_delta: args.delta,
        ..EvalOptions::default()
    };
    let report = evaluate_files(&args.gt, &args.est, &opts)?;
    if !args.no_plot {
        let path = args.plot.clone().unwrap_or_else(|| {
            let stem = args.est.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            args.est.with_file_name(format!("{stem}.eval.png"))
        });
        plot_evaluation(&report, &path).with_context(|| format!("writing the plot {}", path.display()))?;
        tracing::info!("plot written to {}", path.display());
    }
    if args.json {
        outln!("{}", serde_json::to_string(&report)?);
    } else {
        outln!("{report}");
    }
    Ok(())
}

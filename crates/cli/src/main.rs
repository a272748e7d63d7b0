//! `colslam`: offline monocular SLAM built from COLMAP's incremental SfM parts.
//!
//! Subcommands: `demo` (the embedded default: a synthetic sequence), `run`,
//! `eval`, `bench`, `view`, `export`, `info`. Only this binary uses anyhow;
//! the library crates return typed errors.

mod cmd_demo;
mod cmd_eval;
mod cmd_export;
mod cmd_info;
mod cmd_run;
mod cmd_view;
mod logging;
/// Printing to stdout that ends quietly on a closed pipe: the bench lab's helper.
mod stdout {
    pub(crate) use colslam_bench::outln;
}

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Offline monocular SLAM: video or image sequence in, camera trajectory and
/// sparse 3D map (a COLMAP model) out.
#[derive(Debug, Parser)]
#[command(name = "colslam", version, about, propagate_version = true)]
struct Cli {
    /// Less output (errors only). Overrides -v.
    #[arg(short, long, global = true)]
    quiet: bool,
    /// More output (-v: debug, -vv: trace).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Generate the bundled synthetic sequence (textured room, exact ground
    /// truth) and run on it.
    Demo(cmd_demo::DemoArgs),
    /// Run the SLAM pipeline on a video or an image sequence.
    Run(cmd_run::RunCommand),
    /// Evaluate an estimated trajectory against ground truth (ATE, RPE, plot).
    Eval(cmd_eval::EvalArgs),
    /// Benchmarks (features, estimators, BA, whole sequences).
    Bench(colslam_bench::BenchArgs),
    /// Browser viewer for a reconstruction or a live run.
    View(cmd_view::ViewArgs),
    /// Convert or export a COLMAP model (binary, text, PLY, TUM trajectory).
    Export(cmd_export::ExportArgs),
    /// Describe a COLMAP model folder or an input sequence/video.
    Info(cmd_info::InfoArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    logging::init(cli.quiet, cli.verbose);
    match dispatch(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn dispatch(cli: Cli) -> Result<()> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Demo(a) => cmd_demo::run(&a, quiet),
        Command::Eval(a) => cmd_eval::run(&a),
        Command::Export(a) => cmd_export::run(&a),
        Command::Info(a) => cmd_info::run(&a),
        Command::Run(a) => cmd_run::run(&a, quiet),
        Command::Bench(a) => colslam_bench::run(&a, quiet),
        Command::View(a) => cmd_view::run(&a),
    }
}

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
mod interrupt;
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
    #[command(flatten)]
    global: GlobalArgs,
    #[command(subcommand)]
    command: Command,
}

/// Flags of every subcommand, declared once here and shown once, under
/// their own heading at the end of each help.
#[derive(Debug, Clone, clap::Args)]
pub struct GlobalArgs {
    /// Errors only: no logs, no progress bar, only what a script needs on stdout. Overrides -v.
    #[arg(short, long, global = true, help_heading = GLOBAL_HEADING)]
    pub quiet: bool,
    /// More log output (-v: debug, -vv: trace).
    #[arg(short, long, global = true, action = clap::ArgAction::Count, help_heading = GLOBAL_HEADING)]
    pub verbose: u8,
    /// Worker threads (0: all cores).
    #[arg(long, value_name = "N", default_value_t = 0, global = true, help_heading = GLOBAL_HEADING)]
    pub threads: usize,
}

/// The help heading of [`GlobalArgs`].
const GLOBAL_HEADING: &str = "Global options";

impl GlobalArgs {
    /// `--threads` as the bench lab takes it (`None`: all cores).
    fn thread_count(&self) -> Option<usize> {
        (self.threads > 0).then_some(self.threads)
    }
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
    /// Convert or export a COLMAP model (binary, text, PLY, TUM trajectory) or a run (nerfstudio, 3D Gaussian splatting).
    Export(cmd_export::ExportArgs),
    /// Describe a COLMAP model folder or an input sequence/video.
    Info(cmd_info::InfoArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    logging::init(cli.global.quiet, cli.global.verbose);
    match dispatch(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            if let Some(frame) = interrupted_at(&e) {
                eprintln!("colslam: interrupted at frame {frame}; nothing was written");
                return std::process::ExitCode::from(interrupt::EXIT_INTERRUPTED);
            }
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The frame a run stopped at when `e` is an interruption (Ctrl-C).
fn interrupted_at(e: &anyhow::Error) -> Option<usize> {
    e.chain().find_map(|c| match c.downcast_ref::<colslam_slam::SlamError>() {
        Some(colslam_slam::SlamError::Cancelled { frame }) => Some(*frame),
        _ => None,
    })
}

fn dispatch(cli: Cli) -> Result<()> {
    let g = cli.global;
    if g.threads > 0 {
        // One pool for every command (the run driver asks for the same
        // size; the first pool built wins).
        let _ = rayon::ThreadPoolBuilder::new().num_threads(g.threads).build_global();
    }
    match cli.command {
        Command::Demo(mut a) => {
            a.options.threads = g.threads;
            cmd_demo::run(&a, g.quiet)
        }
        Command::Eval(a) => cmd_eval::run(&a),
        Command::Export(a) => cmd_export::run(&a, g.quiet),
        Command::Info(a) => cmd_info::run(&a),
        Command::Run(mut a) => {
            a.config.options.threads = g.threads;
            cmd_run::run(&a, g.quiet)
        }
        Command::Bench(a) => colslam_bench::run(&a, g.quiet, g.thread_count()),
        Command::View(a) => cmd_view::run(&a, g.threads),
    }
}

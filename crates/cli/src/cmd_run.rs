//! `colslam run`: the SLAM pipeline on a video or an image sequence, through
//! the library's driver ([`colslam_slam::run::run`]); this file only adds
//! the progress bar and the printed summary.

use crate::stdout::outln;
use anyhow::Result;
use colslam_slam::run::{RunConfig, RunHooks, RunOutput, RunStart};
use colslam_slam::{EventSink, RunReport};

/// Calls `f` with the hooks of a progress bar over a run's frames (hidden
/// with `quiet`), cleared when `f` returns.
pub fn with_progress<R>(quiet: bool, f: impl FnOnce(RunHooks<'_>) -> R) -> R {
    let pb = crate::logging::progress_bar(0, quiet, "frames");
    let out = f(RunHooks {
        on_start: Some(Box::new(|s: &RunStart| pb.set_length(s.frames.unwrap_or(0) as u64))),
        after_frame: Some(Box::new(|slam: &colslam_slam::Slam| {
            pb.inc(1);
            pb.set_message(format!("{} kf", slam.num_keyframes()));
        })),
        ..RunHooks::default()
    });
    pb.finish_and_clear();
    out
}

/// Runs the pipeline with `hooks` and a progress bar (hidden with `quiet`).
pub fn run_with_progress(config: &RunConfig, quiet: bool, events: EventSink, hooks: RunHooks<'_>) -> Result<RunOutput> {
    Ok(with_progress(quiet, |bar| colslam_slam::run::run(config, events, hooks.then(bar)))?)
}

/// A short summary table of a run.
pub fn summary(r: &RunReport) -> String {
    let t = &r.timings_s;
    let mut s = String::new();
    s.push_str(&format!("frames            {:>8}\n", r.frames));
    s.push_str(&format!("localized         {:>8}  ({:.1} %)\n", r.localized, 100.0 * r.localized_ratio));
    s.push_str(&format!("keyframes         {:>8}\n", r.keyframes));
    s.push_str(&format!("maps              {:>8}\n", r.maps.len()));
    s.push_str(&format!("3D points         {:>8}\n", r.points));
    s.push_str(&format!("observations      {:>8}\n", r.observations));
    s.push_str(&format!("mean track length {:>8.2}\n", r.mean_track_length));
    s.push_str(&format!("mean reproj. err  {:>8.3} px\n", r.mean_reprojection_error));
    s.push_str(&format!("points per image  {:>8.1}\n", r.points_per_image));
    s.push_str(&format!("wall time         {:>8.2} s  ({:.1} ms/frame)\n", r.wall_time_s, r.ms_per_frame));
    s.push_str(&format!(
        "stages (s)        decode {:.2}, features {:.2}, matching {:.2}, keyframe test {:.2}, init {:.2},\n                  registration {:.2}, triangulation {:.2}, local BA {:.2}, global BA {:.2}, localisation {:.2}, output {:.2}",
        t.decode, t.features, t.matching, t.keyframe_test, t.initialization, t.registration, t.triangulation, t.local_ba,
        t.global_ba, t.localization, t.output
    ));
    for n in &r.notes {
        s.push_str(&format!("\nnote: {n}"));
    }
    if let Some(e) = &r.eval {
        s.push_str(&format!("\n{e}"));
    }
    s
}

/// Prints a finished run's summary and where its outputs are.
pub fn print_outcome(config: &RunConfig, out: &RunOutput) {
    outln!("{}", summary(&out.report));
    outln!("outputs in {}", config.output.display());
}

/// Arguments of `run`: the run and the viewer flags.
#[derive(Debug, clap::Args)]
pub struct RunCommand {
    #[command(flatten)]
    pub config: RunConfig,
    #[command(flatten)]
    pub view: crate::cmd_view::RunViewArgs,
}

/// Runs `run`, with the viewer following when `--view` is given.
pub fn run(args: &RunCommand, quiet: bool) -> Result<()> {
    if args.view.view {
        return crate::cmd_view::run_followed(&args.config, &args.view, quiet);
    }
    let out = run_with_progress(&args.config, quiet, EventSink::none(), RunHooks::default())?;
    print_outcome(&args.config, &out);
    Ok(())
}

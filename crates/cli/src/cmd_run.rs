//! `colslam run`: the SLAM pipeline on a video or an image sequence, through
//! the library's driver ([`colslam_slam::run::run`]); this file only adds
//! the progress bar and the printed summary (the numbers, the output folder
//! and its files, the commands to view, evaluate and export it).

use crate::stdout::outln;
use anyhow::Result;
use colslam_slam::run::{RunConfig, RunHooks, RunOutput, RunStart};
use colslam_slam::{EventSink, RunReport};
use std::path::Path;

/// Calls `f` with the hooks of a progress bar over a run's frames (hidden
/// with `quiet`), cleared when `f` returns.
pub fn with_progress<R>(quiet: bool, f: impl FnOnce(RunHooks<'_>) -> R) -> R {
    let pb = crate::logging::progress_bar(0, quiet, "frames", "frames");
    let out = f(RunHooks {
        // Ctrl-C during a run stops it cleanly (`interrupt.rs`).
        interrupt: Some(crate::interrupt::install()),
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
        "stages (s)        decode {:.2}, features {:.2}, matching {:.2}, keyframe test {:.2}, init {:.2},\n                  registration {:.2}, triangulation {:.2}, local BA {:.2}, global BA {:.2},\n                  loop closure {:.2}, observation refinement {:.2}, localisation {:.2}, output {:.2}",
        t.decode, t.features, t.matching, t.keyframe_test, t.initialization, t.registration, t.triangulation, t.local_ba,
        t.global_ba, t.loop_closure, t.observation_refinement, t.localization, t.output
    ));
    for n in &r.notes {
        s.push_str(&format!("\nnote: {n}"));
    }
    if let Some(e) = &r.eval {
        s.push_str(&format!("\n{e}"));
    }
    s
}

/// The main files of a run's output folder and what each holds, in the
/// order the summary lists them.
const OUTPUT_FILES: [(&str, &str); 6] = [
    ("trajectory.tum", "every localised frame (TUM: time x y z qx qy qz qw, camera to world)"),
    ("keyframes.tum", "the keyframes only, same format"),
    ("cameras, images, points3D", "the COLMAP model of the largest map (.bin; .txt with --text; others in maps/)"),
    ("points.ply", "its coloured point cloud"),
    ("camera.yaml", "the camera the run ended with (--camera reads it)"),
    ("report.json", "everything printed above, the options and the evaluation"),
];

/// Where a finished run's outputs are and what to do next: the output
/// folder, its main files, and the exact commands to view, evaluate and
/// export it (`gt`: the ground truth, when the run was given one).
pub fn next_steps(out: &Path, gt: Option<&Path>) -> String {
    let o = shell_word(out);
    // The run already wrote the point cloud and the trajectory; the exports
    // a reader most likely wants are the model as COLMAP text and the
    // layout splatting trainers read, beside it.
    let sibling = |suffix: &str| {
        let name = out.file_name().map_or_else(|| "model".into(), |n| n.to_string_lossy().into_owned());
        shell_word(&out.with_file_name(name + suffix))
    };
    let text = sibling("-text");
    let gt = gt.map_or_else(|| "GT.txt".to_string(), shell_word);
    let est = shell_word(&out.join("trajectory.tum"));
    let mut s = format!("Output folder: {}\n", out.display());
    for (name, what) in OUTPUT_FILES {
        s.push_str(&format!("  {name:<26} {what}\n"));
    }
    s.push_str("Next steps:\n");
    s.push_str(&format!("  view      colslam view {o}\n"));
    s.push_str(&format!("  evaluate  colslam eval --gt {gt} --est {est}\n"));
    s.push_str(&format!(
        "  export    colslam export {o} -o {text} -f txt   (-f ply: point cloud, -f tum: keyframe poses)\n"
    ));
    let splat = sibling("-3dgs");
    s.push_str(&format!("  splat     colslam export {o} -o {splat} -f 3dgs  (-f nerfstudio: transforms.json)"));
    s
}

/// `p` as one word a shell reads back: quoted when it holds anything but
/// letters, digits and `/._-+,:@=`.
fn shell_word(p: &Path) -> String {
    let s = p.display().to_string();
    let plain = |c: char| c.is_ascii_alphanumeric() || "/._-+,:@=".contains(c);
    if !s.is_empty() && s.chars().all(plain) { s } else { format!("'{}'", s.replace('\'', "'\\''")) }
}

/// Prints a finished run's summary on stdout: the numbers, the output folder
/// with its main files and the next steps. With `quiet` only the one line a
/// script needs: the run's headline and its output folder.
pub fn print_outcome(config: &RunConfig, out: &RunOutput, quiet: bool) {
    let r = &out.report;
    if quiet {
        outln!("{}", r.outcome(&config.output));
        return;
    }
    outln!("{}\n", summary(r).trim_end());
    outln!("Finished in {:.1} s: {}", r.wall_time_s, r.headline());
    outln!("{}", next_steps(&config.output, config.gt.as_deref()));
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
    print_outcome(&args.config, &out, quiet);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_steps_name_the_exact_commands() {
        let s = next_steps(Path::new("runs/desk"), Some(Path::new("data/gt.txt")));
        assert!(s.starts_with("Output folder: runs/desk\n"), "{s}");
        assert!(s.contains("colslam view runs/desk\n"), "{s}");
        assert!(s.contains("colslam eval --gt data/gt.txt --est runs/desk/trajectory.tum\n"), "{s}");
        assert!(s.contains("colslam export runs/desk -o runs/desk-text -f txt"), "{s}");
        let s = next_steps(Path::new("my run"), None);
        assert!(
            s.contains("colslam view 'my run'\n") && s.contains("--gt GT.txt --est 'my run/trajectory.tum'"),
            "{s}"
        );
        assert_eq!(shell_word(Path::new("it's")), "'it'\\''s'");
    }
}

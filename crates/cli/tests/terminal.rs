//! What the terminal shows, through the binary: no escape codes in piped or
//! redirected output (colour only on a terminal, and not with `NO_COLOR`),
//! rates with three significant digits, the global flags once at the end of
//! every help, and the summary after a run with its output files and the
//! exact commands to view, evaluate and export it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_colslam");

fn colslam(args: &[&str]) -> Output {
    Command::new(BIN).args(args).env_remove("NO_COLOR").output().expect("run colslam")
}

fn ok(args: &[&str]) -> (String, String) {
    let out = colslam(args);
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    assert!(out.status.success(), "colslam {args:?} failed:\n{stderr}");
    (stdout, stderr)
}

/// A synthetic sequence of `frames` frames at 320x240 in `dir/seq`.
fn synthetic(dir: &Path, frames: usize) -> PathBuf {
    let seq = dir.join("seq");
    let s = seq.to_str().expect("utf-8");
    ok(&[
        "-q",
        "demo",
        "--generate-only",
        "-o",
        s,
        "--frames",
        &frames.to_string(),
        "--width",
        "320",
        "--height",
        "240",
    ]);
    seq
}

const ESC: &str = "\x1b[";

#[test]
fn a_piped_run_prints_no_escape_codes_and_ends_with_next_steps() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic(dir.path(), 30);
    let out = dir.path().join("out");
    let (seq_s, out_s) = (seq.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    let gt = seq.join("groundtruth.txt");
    let gt_s = gt.to_str().expect("utf-8");
    let (stdout, stderr) = ok(&["run", seq_s, "-o", out_s, "--gt", gt_s]);
    // The info logs went to the pipe, without colour.
    assert!(stderr.contains("INFO"), "logs on stderr: {stderr}");
    assert!(!stderr.contains(ESC) && !stdout.contains(ESC), "escape codes in piped output:\n{stderr}\n{stdout}");
    // The summary: numbers, output folder, files, and the exact commands.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report")).expect("json");
    let headline = format!("{} of 30 frames localised, {} keyframes", report["localized"], report["keyframes"]);
    assert!(stdout.contains(&headline), "{headline:?} in:\n{stdout}");
    assert!(stdout.contains(&format!("Output folder: {out_s}\n")), "{stdout}");
    for file in ["trajectory.tum", "keyframes.tum", "points.ply", "camera.yaml", "report.json"] {
        assert!(stdout.contains(&format!("  {file} ")), "{file} listed:\n{stdout}");
        assert!(out.join(file).is_file(), "{file} exists");
    }
    let view = format!("colslam view {out_s}\n");
    let eval = format!("colslam eval --gt {gt_s} --est {out_s}/trajectory.tum\n");
    let export = format!("colslam export {out_s} -o {out_s}-text -f txt");
    let splat = format!("colslam export {out_s} -o {out_s}-3dgs -f 3dgs");
    for cmd in [&view, &eval, &export, &splat] {
        assert!(stdout.contains(cmd.as_str()), "{cmd:?} in:\n{stdout}");
    }
    // The printed commands work as printed.
    let (evaluated, _) = ok(&["-q", "eval", "--gt", gt_s, "--est", &format!("{out_s}/trajectory.tum"), "--no-plot"]);
    assert!(evaluated.contains("ATE"), "{evaluated}");
    ok(&["-q", "export", out_s, "-o", &format!("{out_s}-text"), "-f", "txt"]);
    assert!(dir.path().join("out-text/images.txt").is_file(), "the export wrote the text model");
    ok(&["-q", "export", out_s, "-o", &format!("{out_s}-3dgs"), "-f", "3dgs"]);
    assert!(dir.path().join("out-3dgs/sparse/0/images.bin").is_file(), "the splatting export wrote its model");

    // -q: nothing on stderr, one line on stdout (what a script needs).
    let again = dir.path().join("again");
    let (stdout, stderr) = ok(&["-q", "run", seq_s, "-o", again.to_str().expect("utf-8")]);
    assert!(stderr.is_empty(), "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "{stdout}");
    assert!(lines[0].starts_with(&headline) && lines[0].ends_with(&format!("; outputs in {}", again.display())));
}

/// Runs `args` on a pseudo-terminal (`script`), `NO_COLOR` set to
/// `no_color` or removed; `None` when `script` is not available.
fn on_a_terminal(args: &str, no_color: Option<&str>) -> Option<String> {
    let mut cmd = Command::new("script");
    cmd.args(["-qec", &format!("{BIN} {args}"), "/dev/null"]);
    match no_color {
        Some(v) => cmd.env("NO_COLOR", v),
        None => cmd.env_remove("NO_COLOR"),
    };
    let out = cmd.output().ok()?;
    assert!(out.status.success(), "{args} on a terminal failed: {}", String::from_utf8_lossy(&out.stdout));
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn colour_and_rates_on_a_terminal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic(dir.path(), 24);
    let run = |name: &str| format!("run {} -o {}", seq.display(), dir.path().join(name).display());
    let Some(tty) = on_a_terminal(&run("a"), None) else {
        return eprintln!("SKIPPED: `script` (util-linux) is not installed");
    };
    assert!(has_colour(&tty), "a terminal gets colour: {tty:?}");
    // The progress bar's rate: three significant digits and the unit.
    let rate = rate_before_unit(&tty);
    assert!(rate.is_some(), "a rate like `12.3 frames/s` on the terminal: {tty:?}");
    let no_color = on_a_terminal(&run("b"), Some("1")).expect("script ran before");
    assert!(no_color.contains("INFO") && !has_colour(&no_color), "NO_COLOR=1: no colour: {no_color:?}");
    let empty = on_a_terminal(&run("c"), Some("")).expect("script ran before");
    assert!(has_colour(&empty), "an empty NO_COLOR does not count: {empty:?}");
}

/// Whether `s` holds an SGR escape sequence (`ESC [ digits;... m`: colour or
/// style). The progress bar's cursor movements are other sequences.
fn has_colour(s: &str) -> bool {
    s.split(ESC).skip(1).any(|rest| {
        let params = rest.trim_start_matches(|c: char| c.is_ascii_digit() || c == ';');
        params.starts_with('m')
    })
}

#[test]
fn colour_is_told_from_cursor_movements() {
    assert!(has_colour("\x1b[2m\x1b[32m INFO\x1b[0m x"));
    assert!(!has_colour("\x1b[2K\r\x1b[1A frames [==>  ]"));
}

/// The first `<number> frames/s` in `s` whose number has at most three
/// significant digits (`30.6`, `4.26`, `123`), if any; a number with more
/// (`30.6228`) makes it `None`.
fn rate_before_unit(s: &str) -> Option<String> {
    let at = s.find(" frames/s")?;
    let number: String = s[..at]
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    let digits = number.trim_start_matches(['0', '.']).chars().filter(char::is_ascii_digit).count();
    (digits <= 3 || !number.contains('.')).then_some(number)
}

#[test]
fn rate_parser_tells_precision() {
    assert_eq!(rate_before_unit("[===] 4/9 (30.6 frames/s, eta 1s)").as_deref(), Some("30.6"));
    assert_eq!(rate_before_unit("(0.512 frames/s"), Some("0.512".to_string()));
    assert_eq!(rate_before_unit("(30.6228 frames/s"), None);
    assert_eq!(rate_before_unit("(30.6228/s"), None);
}

/// The help headings of `help`, in order.
fn headings(help: &str) -> Vec<&str> {
    help.lines().filter(|l| !l.starts_with(' ') && l.ends_with(':') && !l.starts_with("Usage")).collect()
}

#[test]
fn global_flags_are_shown_once_at_the_end_of_every_help() {
    for sub in ["demo", "run", "eval", "bench", "view", "export", "info"] {
        for flag in ["-h", "--help"] {
            let (help, _) = ok(&[sub, flag]);
            let h = headings(&help);
            assert_eq!(h.last(), Some(&"Global options:"), "colslam {sub} {flag}: {h:?}");
            for (name, n) in [("--quiet", 1), ("--verbose", 1), ("--threads", 1)] {
                assert_eq!(help.matches(name).count(), n, "colslam {sub} {flag}: {name} once:\n{help}");
            }
            assert!(!help.contains(ESC), "no colour in piped help");
        }
    }
    let (help, _) = ok(&["run", "--help"]);
    let expected = [
        "Arguments:",
        "Options:",
        "Input and output:",
        "Camera:",
        "Features:",
        "Initialisation:",
        "Keyframes:",
        "Mapper:",
        "Refinement:",
        "Viewer:",
        "Global options:",
    ];
    assert_eq!(headings(&help), expected, "colslam run --help reads top to bottom");
    // Defaults and units are shown; the short help keeps one line per flag.
    assert!(help.contains("--flow-threshold <SCORE>") && help.contains("[default: 0.05]"), "{help}");
    let (short, _) = ok(&["run", "-h"]);
    let flags = short.lines().filter(|l| l.trim_start().starts_with('-')).count();
    let long_lines = short.lines().filter(|l| l.len() > 160).count();
    assert!(flags > 40 && long_lines == 0, "one line per flag, none over 160 columns:\n{short}");
    // --threads is taken before and after the subcommand.
    let dir = tempfile::tempdir().expect("tempdir");
    let seq = synthetic(dir.path(), 3);
    let seq_s = seq.to_str().expect("utf-8");
    ok(&["--threads", "1", "info", seq_s]);
    ok(&["info", seq_s, "--threads", "1"]);
}

//! Logging setup: `tracing` to stderr; `-q` errors only, default info,
//! `-v` debug, `-vv` trace. Colour only where a person reads it: on a
//! terminal, and not when `NO_COLOR` is set (<https://no-color.org>), so
//! piped and redirected logs hold no escape codes.

use std::ffi::OsStr;
use std::io::IsTerminal;
use tracing::Level;

/// Whether output to a stream may be coloured: it is a terminal and
/// `NO_COLOR` is unset or empty (no-color.org: any non-empty value turns
/// colour off).
pub fn colour_wanted(is_terminal: bool, no_color: Option<&OsStr>) -> bool {
    is_terminal && no_color.is_none_or(OsStr::is_empty)
}

/// Whether stderr (the logs, the progress bar) may be coloured.
pub fn stderr_colour() -> bool {
    colour_wanted(std::io::stderr().is_terminal(), std::env::var_os("NO_COLOR").as_deref())
}

/// Installs the global subscriber.
pub fn init(quiet: bool, verbose: u8) {
    let level = if quiet {
        Level::ERROR
    } else {
        match verbose {
            0 => Level::INFO,
            1 => Level::DEBUG,
            _ => Level::TRACE,
        }
    };
    let _ = tracing_subscriber::fmt()
        .with_max_level(level)
        .with_target(verbose > 0)
        .with_writer(std::io::stderr)
        .with_ansi(stderr_colour())
        .without_time()
        .try_init();
}

/// A rate with three significant digits and its unit, e.g. `30.6 frames/s`.
pub fn rate(per_sec: f64, unit: &str) -> String {
    format!("{} {unit}/s", colslam_eval::plot::format_significant(per_sec, 3))
}

/// A progress bar on stderr over `unit`s (its rate reads `30.6 frames/s`),
/// hidden when quiet or when stderr is not a terminal.
pub fn progress_bar(len: u64, quiet: bool, what: &str, unit: &'static str) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len);
    let style = indicatif::ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} ({rate}, eta {eta})")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .with_key("rate", move |s: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = w.write_str(&rate(s.per_sec(), unit));
        })
        .progress_chars("=> ");
    pb.set_style(style);
    pb.set_message(what.to_string());
    pb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        assert!(colour_wanted(true, None));
        assert!(colour_wanted(true, Some(OsStr::new(""))), "an empty NO_COLOR does not count");
        assert!(!colour_wanted(true, Some(OsStr::new("1"))));
        assert!(!colour_wanted(true, Some(OsStr::new("false"))), "any non-empty value");
        assert!(!colour_wanted(false, None), "piped or redirected");
    }

    #[test]
    fn rates_have_three_significant_digits() {
        assert_eq!(rate(30.6228, "frames"), "30.6 frames/s");
        assert_eq!(rate(4.25731, "frames"), "4.26 frames/s");
        assert_eq!(rate(1234.5, "frames"), "1234 frames/s");
        assert_eq!(rate(0.0, "frames"), "0 frames/s");
    }
}

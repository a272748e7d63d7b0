//! Keyword options to a [`RunConfig`] through the CLI's own parser: every
//! keyword is the snake_case of a `colslam run` flag (`num_features` is
//! `--num-features`), so names, defaults, validation and messages come from
//! the one clap declaration of the options tree and are never repeated here.

use clap::{Arg, ArgAction, CommandFactory, FromArgMatches, Parser};
use colslam_slam::RunConfig;
use std::ffi::OsString;
use std::path::Path;

/// The parser: `colslam run`'s arguments, nothing else.
#[derive(Debug, Parser)]
#[command(name = "colslam run", disable_help_flag = true, disable_version_flag = true)]
struct RunArgs {
    #[command(flatten)]
    config: RunConfig,
}

/// A keyword's value, as Python gave it.
#[derive(Debug, Clone, PartialEq)]
pub enum OptionValue {
    /// `True`/`False`: a bare flag, or `true`/`false` for a flag taking a boolean.
    Flag(bool),
    /// One value, as its text.
    Value(String),
    /// Several values (a list or a tuple): the values of a flag taking many,
    /// else the flag repeated.
    List(Vec<String>),
}

/// Why keyword options were refused.
#[derive(Debug, thiserror::Error)]
pub enum OptionsError {
    /// No flag has this name.
    #[error("{0}")]
    Unknown(String),
    /// The value is refused by the parser (type, range, possible values, conflicts).
    #[error("{0}")]
    Invalid(String),
}

/// The parameters of `run` itself, which are no keyword options.
const RESERVED: [&str; 2] = ["input", "output"];

/// The flags a keyword may name, in help order (positionals and the
/// reserved ones left out).
pub fn option_args() -> Vec<Arg> {
    RunArgs::command()
        .get_arguments()
        .filter(|a| a.get_long().is_some_and(|l| !RESERVED.contains(&l)))
        .cloned()
        .collect()
}

/// The keyword of a flag: its long name in snake_case.
pub fn keyword(long: &str) -> String {
    long.replace('-', "_")
}

/// Parses `input`, `output` and the keywords into a run configuration.
pub fn run_config(input: &Path, output: &Path, options: &[(String, OptionValue)]) -> Result<RunConfig, OptionsError> {
    let args = option_args();
    let mut argv: Vec<OsString> = vec!["colslam run".into(), input.into(), "--output".into(), output.into()];
    for (name, value) in options {
        let long = name.replace('_', "-");
        let Some(arg) = args.iter().find(|a| a.get_long() == Some(long.as_str())) else {
            // Unknown: clap names it and suggests the nearest flag.
            if RESERVED.contains(&long.as_str()) || long == "help" || long == "version" {
                return Err(OptionsError::Unknown(format!("unexpected keyword argument '{name}'")));
            }
            argv.push(format!("--{long}").into());
            continue;
        };
        push_value(&mut argv, arg, &long, value);
    }
    let cmd = RunArgs::command();
    let matches = cmd.try_get_matches_from(argv).map_err(|e| clap_error(&e, &args))?;
    let parsed = RunArgs::from_arg_matches(&matches).map_err(|e| clap_error(&e, &args))?;
    Ok(parsed.config)
}

/// Appends the flag `--long` with `value` as the CLI spells it.
fn push_value(argv: &mut Vec<OsString>, arg: &Arg, long: &str, value: &OptionValue) {
    let takes_value = arg.get_action().takes_values();
    match value {
        OptionValue::Flag(true) if !takes_value => argv.push(format!("--{long}").into()),
        OptionValue::Flag(false) if !takes_value => {}
        OptionValue::Flag(b) => argv.push(format!("--{long}={b}").into()),
        // `--flag=value` keeps a negative number a value.
        OptionValue::Value(v) => argv.push(format!("--{long}={v}").into()),
        OptionValue::List(vs) if arg.get_num_args().is_some_and(|n| n.max_values() > 1) => {
            argv.push(format!("--{long}").into());
            argv.extend(vs.iter().map(OsString::from));
        }
        OptionValue::List(vs) => argv.extend(vs.iter().map(|v| OsString::from(format!("--{long}={v}")))),
    }
}

/// clap's message for `e`, with each flag named as its keyword
/// (`'--num-feature'` becomes `'num_feature'`) and without the usage lines.
fn clap_error(e: &clap::Error, args: &[Arg]) -> OptionsError {
    let text = e.render().to_string();
    let mut lines: Vec<&str> = text
        .lines()
        .map(str::trim_end)
        .filter(|l| !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .collect();
    if let Some(first) = lines.first_mut() {
        *first = first.strip_prefix("error: ").unwrap_or(first);
    }
    let mut msg = lines.join("\n");
    // Longest first, so `--max-frames-x` is not half rewritten by `--max-frames`.
    let mut longs: Vec<String> = msg
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '-'))
        .filter_map(|w| w.strip_prefix("--"))
        .filter(|w| !w.is_empty())
        .map(str::to_string)
        .collect();
    longs.extend(args.iter().filter_map(|a| a.get_long().map(str::to_string)));
    longs.sort_by_key(|l| std::cmp::Reverse(l.len()));
    longs.dedup();
    for long in longs {
        msg = msg.replace(&format!("--{long}"), &keyword(&long));
    }
    match e.kind() {
        clap::error::ErrorKind::UnknownArgument => OptionsError::Unknown(msg),
        _ => OptionsError::Invalid(msg),
    }
}

/// The options part of `help(colslam.run)`: every flag as a keyword, with
/// clap's help text, possible values and default, under clap's headings.
pub fn options_help() -> String {
    let mut out = String::new();
    let mut heading: Option<&str> = None;
    let args = option_args();
    for arg in &args {
        if arg.get_help_heading() != heading || out.is_empty() {
            heading = arg.get_help_heading();
            out.push_str(&format!(
                "\n{}\n{}\n",
                heading.unwrap_or("Options"),
                "-".repeat(heading.unwrap_or("Options").len())
            ));
        }
        out.push_str(&describe(arg));
    }
    out
}

/// One keyword of [`options_help`].
fn describe(arg: &Arg) -> String {
    let name = keyword(arg.get_long().unwrap_or_default());
    let takes_value = arg.get_action().takes_values();
    let kind = if !takes_value || matches!(arg.get_action(), ArgAction::SetTrue | ArgAction::SetFalse) {
        "bool".to_string()
    } else {
        let names: Vec<String> = arg.get_value_names().unwrap_or_default().iter().map(|n| n.to_string()).collect();
        if names.is_empty() { "value".to_string() } else { names.join(" ") }
    };
    let mut s = format!("{name} : {kind}");
    let defaults: Vec<String> = arg.get_default_values().iter().map(|v| v.to_string_lossy().into_owned()).collect();
    if !defaults.is_empty() {
        s.push_str(&format!(" = {}", defaults.join(" ")));
    } else if !takes_value {
        s.push_str(" = False");
    }
    s.push('\n');
    let help = arg.get_long_help().or(arg.get_help()).map(|h| h.to_string()).unwrap_or_default();
    for line in help.lines() {
        s.push_str(if line.is_empty() { "" } else { "    " });
        s.push_str(line);
        s.push('\n');
    }
    let values: Vec<String> =
        arg.get_possible_values().iter().filter(|v| !v.is_hide_set()).map(|v| format!("'{}'", v.get_name())).collect();
    if !values.is_empty() && kind != "bool" {
        s.push_str(&format!("    One of {}.\n", values.join(", ")));
    }
    s
}

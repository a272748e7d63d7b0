//! `colslam._colslam`, the native module of the Python package `colslam`
//! (see docs/python.md): the pipeline's driver (`run`), a run's result as
//! numpy arrays, model reading and the evaluation of `colslam eval`. Every
//! piece is a call into the library crates; this crate only converts.
//!
//! It is an extension module: it never links libpython (the workspace's
//! `.cargo/config.toml` sets `PYO3_BUILD_EXTENSION_MODULE`, as maturin does),
//! so the workspace builds on machines without Python.

mod errors;
mod options;
mod result;

use crate::errors::{Kind, raise, slam_error};
use crate::options::{OptionValue, OptionsError};
use crate::result::{PyCamera, RunResult};
use colslam_slam::run::{RunHooks, RunStart};
use colslam_slam::{EventSink, Slam};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyList, PyTuple};
use std::cell::{Cell, RefCell};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A keyword's Python value as the text the CLI reads: `True`/`False` for
/// flags, `str(value)` (Python's shortest round-trip text for floats) or
/// `os.fspath(value)` otherwise, lists and tuples value by value.
fn option_value(value: &Bound<'_, PyAny>) -> PyResult<Option<OptionValue>> {
    if value.is_none() {
        return Ok(None);
    }
    if let Ok(b) = value.cast::<PyBool>() {
        return Ok(Some(OptionValue::Flag(b.is_true())));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items: PyResult<Vec<String>> = value.try_iter()?.map(|v| text(&v?)).collect();
        return Ok(Some(OptionValue::List(items?)));
    }
    Ok(Some(OptionValue::Value(text(value)?)))
}

/// `os.fspath(value)` for paths, `str(value)` for anything else.
fn text(value: &Bound<'_, PyAny>) -> PyResult<String> {
    if let Ok(p) = value.extract::<PathBuf>() {
        return Ok(p.to_string_lossy().into_owned());
    }
    Ok(value.str()?.to_string())
}

/// The keyword options as (name, value) pairs in the caller's order.
fn collect_options(options: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<(String, OptionValue)>> {
    let mut out = Vec::new();
    for (k, v) in options.into_iter().flat_map(|d| d.iter()) {
        let name: String = k.extract()?;
        if let Some(value) = option_value(&v)? {
            out.push((name, value));
        }
    }
    Ok(out)
}

/// Runs the pipeline; `colslam.run` (python/colslam/__init__.py) documents it.
#[pyfunction]
#[pyo3(signature = (input, output=None, camera=None, *, progress=None, threads=0, options=None))]
fn run(
    py: Python<'_>,
    input: PathBuf,
    output: Option<PathBuf>,
    camera: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    threads: usize,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<RunResult> {
    if let Some(cb) = &progress
        && !cb.bind(py).is_callable()
    {
        return Err(PyTypeError::new_err("progress must be a callable progress(done, total) or None"));
    }
    let mut opts = collect_options(options)?;
    if let Some(camera) = &camera {
        opts.insert(0, ("camera".into(), OptionValue::Value(camera.to_string_lossy().into_owned())));
    }
    // The CLI requires an output: a placeholder until the options are
    // accepted, then the temporary folder.
    let placeholder = output.clone().unwrap_or_else(|| PathBuf::from("colslam-output"));
    let mut config = options::run_config(&input, &placeholder, &opts).map_err(|e| match e {
        OptionsError::Unknown(m) => raise(py, Kind::UnknownOption, m),
        OptionsError::Invalid(m) => raise(py, Kind::Options, m),
    })?;
    config.options.threads = threads;
    let tmp = match output {
        Some(_) => None,
        None => {
            let dir = tempfile::Builder::new()
                .prefix("colslam-run-")
                .tempdir()
                .map_err(|e| raise(py, Kind::Output, format!("creating a temporary output folder: {e}")))?;
            config.output = dir.path().join("run");
            Some(dir)
        }
    };
    // Every option and the output are checked before the GIL is released.
    config.validate().map_err(|e| slam_error(py, &e, &config.output))?;
    let stop = Arc::new(AtomicBool::new(false));
    let (outcome, pending) = py.detach(|| run_detached(&config, progress.as_ref(), &stop));
    if let Some(e) = pending {
        return Err(e);
    }
    let out = outcome.map_err(|e| slam_error(py, &e, &config.output))?;
    let readout = out.report.camera.readout_s;
    Ok(RunResult::from_run(&out, config.output.clone(), readout, tmp))
}

/// The run without the GIL. After every frame the GIL is taken for a
/// moment to run Python's signal handlers (Ctrl-C) and the progress
/// callback; an exception of either sets the stop flag (the run writes what
/// it has and returns) and is returned to be raised.
fn run_detached(
    config: &colslam_slam::RunConfig,
    progress: Option<&Py<PyAny>>,
    stop: &Arc<AtomicBool>,
) -> (Result<colslam_slam::RunOutput, colslam_slam::SlamError>, Option<PyErr>) {
    let pending: RefCell<Option<PyErr>> = RefCell::new(None);
    let total: Cell<Option<usize>> = Cell::new(None);
    let done = Cell::new(0usize);
    let hooks = RunHooks {
        cancel: vec![stop.clone()],
        on_start: Some(Box::new(|s: &RunStart| total.set(s.frames))),
        after_frame: Some(Box::new(|_: &Slam| {
            done.set(done.get() + 1);
            Python::attach(|py| {
                let r = py.check_signals().and_then(|()| match progress {
                    Some(cb) => cb.bind(py).call1((done.get(), total.get())).map(drop),
                    None => Ok(()),
                });
                if let Err(e) = r {
                    stop.store(true, Ordering::SeqCst);
                    pending.borrow_mut().get_or_insert(e);
                }
            });
        })),
        ..RunHooks::default()
    };
    let out = colslam_slam::run::run(config, EventSink::none(), hooks);
    (out, pending.into_inner())
}

/// Reads a run's output folder or a COLMAP model folder.
#[pyfunction]
fn read_model(py: Python<'_>, path: PathBuf) -> PyResult<RunResult> {
    RunResult::read(&path).map_err(|e| raise(py, Kind::Input, e))
}

/// `colslam eval`'s numbers for two TUM trajectories.
#[pyfunction]
#[pyo3(signature = (gt, est, *, max_diff=None, offset=None, align=None, delta=None))]
fn evaluate<'py>(
    py: Python<'py>,
    gt: PathBuf,
    est: PathBuf,
    max_diff: Option<f64>,
    offset: Option<f64>,
    align: Option<String>,
    delta: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    use clap::ValueEnum;
    use colslam_eval::{Alignment, EvalError, EvalOptions};
    let mut opts = EvalOptions::default();
    opts.max_diff = max_diff.unwrap_or(opts.max_diff);
    opts.offset = offset.unwrap_or(opts.offset);
    opts.rpe_delta = delta.unwrap_or(opts.rpe_delta);
    if let Some(a) = align {
        // The value names of `colslam eval --align`, from the same declaration.
        opts.align = <Alignment as clap::ValueEnum>::from_str(&a, false).map_err(|_| {
            let names: Vec<String> = Alignment::value_variants()
                .iter()
                .filter_map(|v| v.to_possible_value().map(|p| format!("'{}'", p.get_name())))
                .collect();
            raise(py, Kind::Options, format!("invalid value '{a}' for 'align': one of {}", names.join(", ")))
        })?;
    }
    let report = py.detach(|| colslam_eval::evaluate_files(&gt, &est, &opts)).map_err(|e| {
        let kind = if matches!(e, EvalError::InvalidOptions(_)) { Kind::Options } else { Kind::Input };
        raise(py, kind, colslam_slam::error_chain(&e))
    })?;
    let text = serde_json::to_string(&report).map_err(|e| raise(py, Kind::Base, e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// The options part of `help(colslam.run)`, from clap's declaration.
#[pyfunction]
fn options_help() -> String {
    options::options_help()
}

/// The keyword of every option `run` takes (the flags of `colslam run`).
#[pyfunction]
fn option_names() -> Vec<String> {
    options::option_args().iter().filter_map(|a| a.get_long().map(options::keyword)).collect()
}

/// Where a path is shown in messages.
pub(crate) fn shown(p: &Path) -> String {
    p.display().to_string()
}

#[pymodule]
fn _colslam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(read_model, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(options_help, m)?)?;
    m.add_function(wrap_pyfunction!(option_names, m)?)?;
    m.add_class::<RunResult>()?;
    m.add_class::<PyCamera>()?;
    Ok(())
}

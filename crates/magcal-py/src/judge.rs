//! `evaluate` and `next`: a calibration judged against a log's reference attitudes, and the
//! attitudes that add most to a log, as `magcal evaluate --json` and `magcal next --json` give
//! them.

use std::path::PathBuf;

use clap::Parser;
use magcal_logs::calibration::{CalibrationJson, read_calibration};
use magcal_runner::commands::evaluate::{self as evaluate_command, EvaluateArgs};
use magcal_runner::commands::next::{self as next_command, NextArgs};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyList, PyTuple};

use crate::{Calibration, Flags, InputError, parsed_after, quietly, raised};

#[derive(Parser)]
struct EvaluateCommand {
    #[command(flatten)]
    args: EvaluateArgs,
}

#[derive(Parser)]
struct NextCommand {
    #[command(flatten)]
    args: NextArgs,
}

/// Keywords as the flags of `T`'s command line: `snake_case` is `--kebab-case`, `start` and `end`
/// are `--from` and `--to` (Python keeps `from` for itself). A switch takes `True` or `False`; a
/// flag that may be repeated takes a list or tuple (one flag each) or one value; any other flag
/// takes one value, a list or tuple being its comma-separated form (`roll=(-10, 10)` is
/// `--roll=-10,10`). `None` is the flag not given. A float is its shortest text that reads back
/// to the same value, a path its `os.fspath`, anything else its `str()`. A keyword that is no
/// flag of the command is the `TypeError` of any Python function.
fn flags_of<T: clap::CommandFactory>(function: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<Flags> {
    let mut flags = Flags::default();
    let Some(options) = options else {
        return Ok(flags);
    };
    let command = T::command();
    for (key, value) in options.iter() {
        let key: String = key.extract()?;
        let name = match key.as_str() {
            "start" => "from".to_string(),
            "end" => "to".to_string(),
            k => k.replace('_', "-"),
        };
        let arg = command
            .get_arguments()
            .find(|a| a.get_long() == Some(name.as_str()) && !matches!(name.as_str(), "help" | "version"))
            .ok_or_else(|| PyTypeError::new_err(format!("{function}() got an unexpected keyword argument '{key}'")))?;
        if value.is_none() {
            continue;
        }
        let sequence = value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>();
        match arg.get_action() {
            clap::ArgAction::SetTrue => {
                if !value.is_instance_of::<PyBool>() {
                    return Err(InputError::new_err(format!(
                        "{key}=: True or False, not {}",
                        value.repr()?
                    )));
                }
                flags.flag(&name, value.extract::<bool>()?);
            }
            _ if value.is_instance_of::<PyBool>() => {
                return Err(InputError::new_err(format!(
                    "{key}=: takes a value ({}), not {}",
                    arg.get_value_names().map_or("VALUE".to_string(), |v| v.join(" ")),
                    value.repr()?
                )));
            }
            clap::ArgAction::Append if sequence => {
                for v in value.try_iter()? {
                    flags.value(&name, Some(text(&v?)?));
                }
            }
            _ if sequence => {
                let parts: Vec<String> = value.try_iter()?.map(|v| text(&v?)).collect::<PyResult<_>>()?;
                flags.value(&name, Some(parts.join(",")));
            }
            _ => {
                flags.value(&name, Some(text(&value)?));
            }
        }
    }
    Ok(flags)
}

/// A keyword's value as the command line's text.
fn text(v: &Bound<'_, PyAny>) -> PyResult<String> {
    if v.is_instance_of::<PyFloat>() {
        Ok(format!("{:?}", v.extract::<f64>()?))
    } else if !v.is_instance_of::<pyo3::types::PyString>()
        && let Ok(path) = v.extract::<PathBuf>()
    {
        Ok(path.display().to_string())
    } else {
        Ok(v.str()?.to_string())
    }
}

/// The calibration given as a `Calibration` or a path to its file: its estimates and the name
/// messages and the report call it by.
fn given(calibration: &Bound<'_, PyAny>) -> PyResult<(CalibrationJson, String)> {
    if let Ok(c) = calibration.extract::<PyRef<'_, Calibration>>() {
        return Ok((c.estimates()?.clone(), c.name.clone()));
    }
    let path: PathBuf = calibration
        .extract()
        .map_err(|_| InputError::new_err("calibration: a Calibration or the path of a calibration.json"))?;
    let cal = read_calibration(&path).map_err(|e| raised(e.into()))?;
    Ok((cal, path.display().to_string()))
}

/// The command line's output flags have no meaning here: the result is returned, not printed or
/// written; refused rather than ignored.
fn refuse_outputs(options: Option<&Bound<'_, PyDict>>, names: &[&str]) -> PyResult<()> {
    for name in names {
        if let Some(options) = options
            && options.contains(*name)?
        {
            return Err(InputError::new_err(if *name == "raw" {
                "raw=: give None as the calibration to evaluate the log's raw readings".to_string()
            } else {
                format!("{name}=: the result is returned as a dict; the command line writes files and prints")
            }));
        }
    }
    Ok(())
}

/// The JSON text as Python's objects (`json.loads`).
fn loaded<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

/// How good `calibration` is as a compass against the attitudes `log` carries, as `magcal
/// evaluate CAL LOG --json` prints it (a dict of the same keys and numbers); with `calibration`
/// `None`, the log's raw readings (`magcal evaluate --raw LOG`). `calibration` is a
/// `Calibration` or a calibration file; the other keywords are the flags of the same name
/// (`quaternion="qw,qx,qy,qz"`, `attitude_frame="enu"`, `where=["movement=1"]`, ...).
#[pyfunction]
#[pyo3(signature = (calibration, log, **options))]
pub fn evaluate<'py>(
    py: Python<'py>,
    calibration: &Bound<'py, PyAny>,
    log: PathBuf,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let log_shown = log.display().to_string();
    refuse_outputs(options, &["report", "errors", "json", "raw"])?;
    let mut flags = flags_of::<EvaluateCommand>("evaluate", options)?;
    let text = if calibration.is_none() {
        flags.flag("raw", true);
        let command: EvaluateCommand = parsed_after("evaluate", &[&log_shown], &flags)?;
        let args = &command.args;
        quietly(py, || evaluate_command::evaluated(args, &args.calibration, None))?
    } else {
        let (cal, name) = given(calibration)?;
        let command: EvaluateCommand = parsed_after("evaluate", &[&name, &log_shown], &flags)?;
        let args = &command.args;
        quietly(py, || evaluate_command::evaluated(args, &log, Some((&cal, &name))))?
    }
    .map_err(|e| raised(e.into()))
    .and_then(|e| {
        serde_json::to_string_pretty(&e.json).map_err(|e| pyo3::exceptions::PyException::new_err(e.to_string()))
    })?;
    loaded(py, &text)
}

/// The attitudes that add most to `log` for `calibration` (a `Calibration` or its file), as
/// `magcal next CAL LOG --json` prints them (a dict of the same keys and numbers): D-optimal
/// in the box of `scenario` (or of `site`, `date`, `roll`, `pitch`, `yaw`), or without a box
/// a vector calibration's own manoeuvres. The keywords are the flags of the same name.
#[pyfunction]
#[pyo3(signature = (calibration, log, **options))]
pub fn next<'py>(
    py: Python<'py>,
    calibration: &Bound<'py, PyAny>,
    log: PathBuf,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    refuse_outputs(options, &["report", "json"])?;
    let (cal, name) = given(calibration)?;
    let flags = flags_of::<NextCommand>("next", options)?;
    let command: NextCommand = parsed_after("next", &[&name, &log.display().to_string()], &flags)?;
    let args = &command.args;
    let text = quietly(py, || next_command::json(args, &cal))?.map_err(|e| raised(e.into()))?;
    loaded(py, &text)
}

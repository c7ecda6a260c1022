//! `pymagcal`: magcal from Python. The attitudes a vehicle should visit planned as `magcal design`
//! plans them (`design`, in `design.rs`); a log read into numpy arrays (`read_log`), calibrated as
//! `magcal calibrate` calibrates it (`calibrate`: the same function, the same numbers, the same
//! JSON), applied to readings and exported to an autopilot or a tool (`export`); judged against
//! the log's attitudes and augmented (`evaluate` and `next`, in `judge.rs`).
//!
//! Every option is handed to the command line's own parser, so that a value is checked, and
//! refused with the same one-line message, exactly as the flag of the same name would be. Errors
//! are Python exceptions: `InputError` (a `ValueError`: the command line's exit 2) and
//! `UnusableError` (exit 3: an export of a calibration not marked usable).

mod design;
mod judge;

use std::path::PathBuf;

use clap::Parser;
use magcal_logs::calibration::CalibrationJson;
use magcal_logs::source::{self, LogArgs};
use magcal_runner::commands::Failure;
use magcal_runner::commands::calibrate::{self as calibrate_command, CalibrateArgs, Calibrated};
use magcal_runner::commands::export::{self as export_command, ExportArgs};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2};
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;

pyo3::create_exception!(
    pymagcal,
    InputError,
    PyValueError,
    "Bad input: a log, calibration or option refused, with the command line's message (its exit 2)."
);
pyo3::create_exception!(
    pymagcal,
    UnusableError,
    PyException,
    "Not a calibration to use: an export of a calibration not marked usable, without force (the command line's exit 3)."
);

/// The command line's failure as the Python exception of its exit code.
fn raised(failure: Failure) -> PyErr {
    match failure {
        Failure::Input(e) => InputError::new_err(format!("{e:#}").replace('\n', " ")),
        Failure::Unusable(why) => UnusableError::new_err(why),
        Failure::Regression(table) => PyException::new_err(table),
    }
}

/// Options as the command line's flags: `--name=value` for each given value, `--name` for each
/// flag set.
#[derive(Default)]
struct Flags(Vec<String>);

impl Flags {
    fn value(&mut self, name: &str, value: Option<impl ToString>) -> &mut Self {
        if let Some(v) = value {
            self.0.push(format!("--{name}={}", v.to_string()));
        }
        self
    }

    /// A number exactly as given (Rust's shortest text that reads back to the same `f64`).
    fn number(&mut self, name: &str, value: Option<f64>) -> &mut Self {
        self.value(name, value.map(|v| format!("{v:?}")))
    }

    fn list(&mut self, name: &str, values: Option<Vec<String>>) -> &mut Self {
        for v in values.unwrap_or_default() {
            self.0.push(format!("--{name}={v}"));
        }
        self
    }

    fn flag(&mut self, name: &str, set: bool) -> &mut Self {
        if set {
            self.0.push(format!("--{name}"));
        }
        self
    }
}

/// Parses `flags` after the positional `first` as the command line would, into `T`.
fn parsed<T: Parser>(command: &str, first: &str, flags: &Flags) -> PyResult<T> {
    parsed_after(command, &[first], flags)
}

/// Parses `flags` and the positionals `first` as the command line would, into `T`. The
/// positionals come after `--`, so that a path beginning with `-` is a path.
fn parsed_after<T: Parser>(command: &str, first: &[&str], flags: &Flags) -> PyResult<T> {
    let argv = std::iter::once(command.to_string())
        .chain(flags.0.iter().cloned())
        .chain(std::iter::once("--".to_string()))
        .chain(first.iter().map(|f| f.to_string()));
    T::try_parse_from(argv).map_err(|e| InputError::new_err(magcal_runner::cli::one_line(&e)))
}

#[derive(Parser)]
struct ReadCommand {
    log: PathBuf,
    #[command(flatten)]
    input: LogArgs,
}

#[derive(Parser)]
struct CalibrateCommand {
    #[command(flatten)]
    args: CalibrateArgs,
}

#[derive(Parser)]
struct ExportCommand {
    #[command(flatten)]
    args: ExportArgs,
}

/// A log's readings and what was logged beside them, as `magcal` reads it.
#[pyclass(module = "pymagcal", frozen)]
struct Log {
    log: source::Log,
    path: String,
}

#[pymethods]
impl Log {
    /// The path the log was read from (or the name of readings handed over as an array).
    #[getter]
    fn path(&self) -> &str {
        &self.path
    }

    /// The readings, `(n, 3)`, in the log's units, before any calibration.
    #[getter]
    fn readings<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows(py, &self.log.readings)
    }

    /// Each reading's position: its 1-based line in a CSV file, its message's byte offset in a
    /// flight log.
    #[getter]
    fn lines<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        self.log
            .lines
            .iter()
            .map(|&l| l as u64)
            .collect::<Vec<_>>()
            .into_pyarray(py)
    }

    /// Each reading's time, seconds on the log's clock, or `None` where the log has no times.
    #[getter]
    fn times<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.log.times.as_ref().map(|t| t.clone().into_pyarray(py))
    }

    /// Each reading's attitude, `(n, 3, 3)`, the matrix taking body vectors into north, east,
    /// down (NaN for a reading without one); `None` where the log has no attitudes.
    #[getter]
    fn attitudes<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray3<f64>>> {
        let a = self.log.attitudes.as_ref()?;
        let flat: Vec<f64> = a
            .iter()
            .flat_map(|c| c.map_or([[f64::NAN; 3]; 3], |m| m).into_iter().flatten())
            .collect();
        let array = numpy::ndarray::Array3::from_shape_vec((a.len(), 3, 3), flat).expect("nine values a reading");
        Some(array.into_pyarray(py))
    }

    /// The names of the three columns read (`x, y, z` for a flight log).
    #[getter]
    fn columns(&self) -> Vec<String> {
        self.log.columns.to_vec()
    }

    /// The log's format: `csv`, `dataflash`, `tlog` or `ulog`.
    #[getter]
    fn format(&self) -> String {
        format!("{:?}", self.log.origin.format).to_lowercase()
    }

    /// The readings' units where the format fixes them, as the flag `units` names them (`mG` for
    /// ArduPilot, `G` for PX4), else `None`.
    #[getter]
    fn units(&self) -> Option<String> {
        use clap::ValueEnum;
        let name = |u: magcal_logs::site::Units| u.to_possible_value().map(|v| v.get_name().to_string());
        self.log.origin.unit.and_then(name)
    }

    /// What the reader and the cut noted, one sentence each.
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.log.origin.notes.clone()
    }

    /// SHA-256 of the file's bytes as read (lower-case hex).
    #[getter]
    fn sha256(&self) -> &str {
        &self.log.sha256
    }

    /// Rows skipped for a missing or non-finite value (`skip_bad`), as `(line, reason)`.
    #[getter]
    fn skipped(&self) -> Vec<(usize, String)> {
        self.log.skipped.clone()
    }

    fn __len__(&self) -> usize {
        self.log.readings.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Log({:?}: {} readings, columns {}, {} log)",
            self.path,
            self.log.readings.len(),
            self.log.columns.join(", "),
            self.format()
        )
    }
}

/// Readings as an `(n, 3)` array.
fn rows<'py>(py: Python<'py>, v: &[[f64; 3]]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = v.iter().flatten().copied().collect();
    Array2::from_shape_vec((v.len(), 3), flat)
        .expect("three values a reading")
        .into_pyarray(py)
}

/// An `(n, 3)` array as readings.
fn readings_of(array: &PyReadonlyArray2<'_, f64>, name: &str) -> PyResult<Vec<[f64; 3]>> {
    let a = array.as_array();
    if a.ncols() != 3 {
        return Err(InputError::new_err(format!(
            "{name}: an array of shape {:?}; readings are an (n, 3) array",
            a.shape()
        )));
    }
    Ok(a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// Reads a log as `magcal calibrate LOG` reads it: a CSV file (one reading per row), an ArduPilot
/// DataFlash log, a MAVLink telemetry log or a PX4 ULog, its format told by its first bytes.
/// Each keyword is the flag of the same name (`where` is `--where`, repeated for a list).
#[pyfunction]
#[pyo3(signature = (
    path, *, format=None, columns=None, skip_bad=false, r#where=None, compass=None, start=None,
    end=None, rate=None, time=None, time_unit=None, euler=None, quaternion=None, attitude_frame=None,
    current=None, throttle=None, position=None, utc=None, heading_from=None
))]
#[allow(clippy::too_many_arguments)]
fn read_log(
    py: Python<'_>,
    path: PathBuf,
    format: Option<String>,
    columns: Option<String>,
    skip_bad: bool,
    r#where: Option<Vec<String>>,
    compass: Option<u8>,
    start: Option<f64>,
    end: Option<f64>,
    rate: Option<f64>,
    time: Option<String>,
    time_unit: Option<String>,
    euler: Option<String>,
    quaternion: Option<String>,
    attitude_frame: Option<String>,
    current: Option<String>,
    throttle: Option<String>,
    position: Option<String>,
    utc: Option<String>,
    heading_from: Option<String>,
) -> PyResult<Log> {
    let mut flags = Flags::default();
    flags
        .value("format", format)
        .value("columns", columns)
        .flag("skip-bad", skip_bad)
        .list("where", r#where)
        .value("compass", compass)
        .number("from", start)
        .number("to", end)
        .number("rate", rate)
        .value("time", time)
        .value("time-unit", time_unit)
        .value("euler", euler)
        .value("quaternion", quaternion)
        .value("attitude-frame", attitude_frame)
        .value("current", current)
        .value("throttle", throttle)
        .value("position", position)
        .value("utc", utc)
        .value("heading-from", heading_from);
    let command: ReadCommand = parsed("read_log", &path.display().to_string(), &flags)?;
    open(py, command.log, &command.input)
}

/// Runs `f` without the interpreter's lock and with what the command prints kept: its
/// warnings and notes (the command line's standard error, one line each) become Python
/// warnings (`UserWarning`) once it is done.
fn quietly<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    let (value, captured) = py.detach(|| magcal_runner::output::capture::capturing(f));
    let warnings = py.import("warnings")?;
    for line in String::from_utf8_lossy(&captured.stderr).lines() {
        let line = line.strip_prefix("magcal: ").unwrap_or(line);
        // Level 1: the Python line that called the function (no Python frame lies between).
        warnings.call_method1("warn", (line, py.get_type::<pyo3::exceptions::PyUserWarning>(), 1))?;
    }
    Ok(value)
}

/// The log at `path` read as `input` says, without the interpreter's lock.
fn open(py: Python<'_>, path: PathBuf, input: &LogArgs) -> PyResult<Log> {
    let held = magcal_logs::read::HELD_BYTES_PER_READING;
    let log = quietly(py, || source::open(&path, input, held))?.map_err(|e| raised(e.into()))?;
    Ok(Log {
        log,
        path: path.display().to_string(),
    })
}

/// A calibration as `magcal calibrate` makes it: its estimates, standard errors and verdict.
#[pyclass(module = "pymagcal", frozen)]
struct Calibration {
    /// `None` when no model fits the log.
    cal: Option<CalibrationJson>,
    /// What messages call it: its file, or the log it was fitted to.
    name: String,
    usable: bool,
    reasons: Vec<String>,
    json: String,
}

fn array3<'py>(py: Python<'py>, v: [f64; 3]) -> Bound<'py, PyArray1<f64>> {
    v.to_vec().into_pyarray(py)
}

fn matrix<'py>(py: Python<'py>, m: [[f64; 3]; 3]) -> Bound<'py, PyArray2<f64>> {
    rows(py, &m)
}

impl Calibration {
    fn heading(&self) -> Option<&magcal_runner::log::calibration::HeadingBudgetJson> {
        self.cal.as_ref().and_then(|c| c.heading_budget.as_ref())
    }

    fn estimates(&self) -> PyResult<&CalibrationJson> {
        self.cal
            .as_ref()
            .ok_or_else(|| UnusableError::new_err(format!("no calibration: {}", self.reasons.join("; "))))
    }
}

#[pymethods]
impl Calibration {
    /// Whether the calibration is one to use (the command line's exit 0).
    #[getter]
    fn usable(&self) -> bool {
        self.usable
    }

    /// Why it is not, one reason each (empty when it is).
    #[getter]
    fn reasons(&self) -> Vec<String> {
        self.reasons.clone()
    }

    /// The JSON `magcal calibrate --json` prints, byte for byte (`calibration.json` of `--out`).
    #[getter]
    fn json(&self) -> &str {
        &self.json
    }

    /// The model fitted: `full`, `diagonal`, `offset` or a vector model (`None`: no fit).
    #[getter]
    fn fit(&self) -> Option<String> {
        self.cal.as_ref().map(|c| c.fit.clone())
    }

    /// The verdict in words.
    #[getter]
    fn verdict(&self) -> Option<String> {
        self.cal.as_ref().map(|c| c.verdict.clone())
    }

    /// The heading budget the calibration was judged against, degrees (`None`: not judged).
    #[getter]
    fn heading_budget_deg(&self) -> Option<f64> {
        self.heading().map(|b| b.verdict.budget_deg)
    }

    /// The heading error it is predicted to leave: the 95th percentile over the vehicle's
    /// attitudes at every heading, the larger of the trials' and the standard errors', degrees.
    #[getter]
    fn heading_deg(&self) -> Option<f64> {
        self.heading().map(|b| b.predicted_deg)
    }

    /// The heading budget's verdict in words: both figures, the field and the axes.
    #[getter]
    fn heading_words(&self) -> Option<String> {
        self.heading()
            .map(|b| format!("{}; inclination from {}; level is {}", b.words, b.field, b.axes))
    }

    /// The field magnitude the readings are calibrated to, in the log's units.
    #[getter]
    fn magnitude(&self) -> PyResult<f64> {
        Ok(self.estimates()?.magnitude)
    }

    /// The bias (hard iron), in the log's units.
    #[getter]
    fn bias<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(array3(py, self.estimates()?.bias))
    }

    /// The non-orthogonality angles psi, degrees ([P1] eq. (6)).
    #[getter]
    fn psi_deg<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(array3(py, self.estimates()?.psi_deg))
    }

    /// The scale factors.
    #[getter]
    fn scale<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(array3(py, self.estimates()?.scale))
    }

    /// `K`, the sensor's matrix: raw = K b + bias.
    #[getter]
    fn k<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        Ok(matrix(py, self.estimates()?.k))
    }

    /// The soft-iron inverse: calibrated = soft_iron_inverse (raw - bias).
    #[getter]
    fn soft_iron_inverse<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        Ok(matrix(py, self.estimates()?.soft_iron_inverse))
    }

    /// Standard errors `{"psi_deg": ..., "scale": ..., "bias": ...}` (`None` where the
    /// information is singular).
    #[getter]
    fn std_error(&self) -> PyResult<std::collections::BTreeMap<&'static str, Option<[f64; 3]>>> {
        let s = &self.estimates()?.std_error;
        Ok([("psi_deg", s.psi_deg), ("scale", s.scale), ("bias", s.bias)].into())
    }

    /// The readings' noise per component the standard errors rest on, in the log's units.
    #[getter]
    fn noise(&self) -> Option<f64> {
        self.cal.as_ref().and_then(|c| c.noise)
    }

    /// The readings calibrated: each row `soft_iron_inverse (raw - bias)`.
    fn apply<'py>(&self, py: Python<'py>, readings: PyReadonlyArray2<'py, f64>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let cal = self.estimates()?;
        cal.check()
            .map_err(|why| InputError::new_err(format!("the calibration fails its checks: {why}")))?;
        let raw = readings_of(&readings, "apply")?;
        let out: Vec<[f64; 3]> = raw.iter().map(|&r| cal.apply(r)).collect();
        Ok(rows(py, &out))
    }

    fn __repr__(&self) -> String {
        match &self.cal {
            Some(c) => format!(
                "Calibration({} fit, {}: bias {:?}, scale {:?})",
                c.fit,
                if self.usable { "usable" } else { "not usable" },
                c.bias,
                c.scale
            ),
            None => format!("Calibration(none: {})", self.reasons.join("; ")),
        }
    }
}

/// Calibrates `log` (a `Log` from `read_log`, a path read with the defaults, or an `(n, 3)`
/// array of readings) as `magcal calibrate` does: each keyword is the flag of the same name. The
/// result's `json` is what `magcal calibrate --json` prints for the same log and options.
#[pyfunction]
#[pyo3(signature = (
    log, *, fit=None, magnitude=None, units=None, site=None, date=None, wmm=None, noise=None,
    reject=None, residual=None, trials=None, seed=None, scenario=None, heading_budget=None
))]
#[allow(clippy::too_many_arguments)]
fn calibrate(
    py: Python<'_>,
    log: &Bound<'_, PyAny>,
    fit: Option<String>,
    magnitude: Option<f64>,
    units: Option<String>,
    site: Option<String>,
    date: Option<String>,
    wmm: Option<String>,
    noise: Option<f64>,
    reject: Option<f64>,
    residual: Option<String>,
    trials: Option<u64>,
    seed: Option<u64>,
    scenario: Option<PathBuf>,
    heading_budget: Option<f64>,
) -> PyResult<Calibration> {
    let (mut readings, shown) = if let Ok(l) = log.extract::<PyRef<'_, Log>>() {
        (l.log.clone(), l.path.clone())
    } else if let Ok(path) = log.extract::<PathBuf>() {
        // The command line's defaults (`LogArgs`'s `Default` is theirs).
        let l = open(py, path, &LogArgs::default())?;
        (l.log, l.path)
    } else {
        let array: PyReadonlyArray2<'_, f64> = log
            .extract()
            .map_err(|_| InputError::new_err("calibrate: log is a Log, a path or an (n, 3) array of readings"))?;
        let shown = "<array>".to_string();
        (source::Log::of_readings(readings_of(&array, &shown)?, &shown), shown)
    };
    let mut flags = Flags::default();
    flags
        .value("fit", fit)
        .number("magnitude", magnitude)
        .value("units", units)
        .value("site", site)
        .value("date", date)
        .value("wmm", wmm)
        .number("noise", noise)
        .number("reject", reject)
        .value("residual", residual)
        .value("trials", trials)
        .value("seed", seed)
        .value("scenario", scenario.map(|p| p.display().to_string()))
        .number("heading-budget", heading_budget);
    let command: CalibrateCommand = parsed("calibrate", &shown, &flags)?;
    let calibrated = quietly(py, || calibrate_command::calibrate(&command.args, &mut readings))?.map_err(raised)?;
    let (usable, reasons) = (calibrated.usable(), calibrated.reasons().to_vec());
    let (cal, mut json) = match calibrated {
        Calibrated::Fit { json, .. } => {
            let text = serde_json::to_string_pretty(&json).map_err(|e| PyException::new_err(e.to_string()))?;
            (Some(*json), text)
        }
        Calibrated::NoFit(json) => (
            None,
            serde_json::to_string_pretty(&json).map_err(|e| PyException::new_err(e.to_string()))?,
        ),
    };
    json.push('\n');
    Ok(Calibration {
        cal,
        name: format!("the calibration of {shown}"),
        usable,
        reasons,
        json,
    })
}

/// Reads a `calibration.json` written by `magcal calibrate --out` (or its `--json` output).
#[pyfunction]
fn read_calibration(path: PathBuf) -> PyResult<Calibration> {
    let text = std::fs::read(&path).map_err(|e| InputError::new_err(format!("{}: {e}", path.display())))?;
    let cal = magcal_logs::calibration::parse_calibration(&text, &path.display().to_string())
        .map_err(|e| InputError::new_err(format!("{e:#}")))?;
    Ok(Calibration {
        name: path.display().to_string(),
        usable: cal.usable,
        reasons: cal.reasons.clone(),
        json: String::from_utf8_lossy(&text).into_owned(),
        cal: Some(cal),
    })
}

/// The calibration as `magcal export --to TO` writes it (ArduPilot `.param` lines, PX4 `param
/// set` lines, MotionCal, Magneto or a C header), as text; each keyword is the flag of the same
/// name. A calibration not marked usable raises `UnusableError` unless `force`.
#[pyfunction]
#[pyo3(signature = (calibration, to, *, compass=None, units=None, offs_max=None, strict=false, force=false))]
fn export(
    calibration: &Calibration,
    to: String,
    compass: Option<u8>,
    units: Option<String>,
    offs_max: Option<u16>,
    strict: bool,
    force: bool,
) -> PyResult<String> {
    let cal = calibration.estimates()?;
    let shown = format!("the calibration of {}", cal.log);
    let mut flags = Flags::default();
    flags
        .value("to", Some(to))
        .value("compass", compass)
        .value("units", units)
        .value("offs-max", offs_max)
        .flag("strict", strict)
        .flag("force", force);
    let command: ExportCommand = parsed("export", &shown, &flags)?;
    let made = export_command::made(&command.args, cal, &shown, "").map_err(raised)?;
    String::from_utf8(made.text).map_err(|e| PyException::new_err(e.to_string()))
}

/// magcal from Python: plan the attitudes, read a magnetometer log, calibrate it, judge it, apply
/// and export the calibration.
#[pymodule]
fn pymagcal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("InputError", m.py().get_type::<InputError>())?;
    m.add("UnusableError", m.py().get_type::<UnusableError>())?;
    m.add_class::<Log>()?;
    m.add_class::<Calibration>()?;
    m.add_class::<design::Plan>()?;
    m.add_class::<design::Design>()?;
    m.add_function(wrap_pyfunction!(read_log, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(read_calibration, m)?)?;
    m.add_function(wrap_pyfunction!(export, m)?)?;
    m.add_function(wrap_pyfunction!(design::design, m)?)?;
    m.add_function(wrap_pyfunction!(judge::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(judge::next, m)?)?;
    Ok(())
}

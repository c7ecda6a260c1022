//! `design`: the designs of a scenario with their certificate and verdicts, as `magcal design`
//! makes them, and the tables its result set holds.

use std::path::{Path, PathBuf};

use clap::Parser;
use magcal_runner::commands::{self, Common};
use magcal_runner::output::print;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::{Flags, InputError, parsed, quietly, raised};

#[derive(Parser)]
struct DesignCommand {
    #[command(flatten)]
    common: Common,
}

/// The columns of the design tables that count (attitudes, readings, trials, rounds): `int`s.
/// Every other number is a measure, a `float` even where it happens to be whole.
const COUNTS: [&str; 12] = [
    "visit",
    "point",
    "readings",
    "m",
    "check_trials",
    "check_ok",
    "check_logs",
    "check_logs_usable",
    "rounds",
    "candidates",
    "support_points",
    "attitudes",
];

/// One cell of a table as Python has it: empty is `None`; a count ([`COUNTS`]) is an `int`; a
/// column whose every cell is a number holds `float`s (the files' shortest text that reads back
/// to the same `f64`, so the same bits); else `true`/`false` are `bool`s; else text.
#[derive(Clone, Copy, PartialEq)]
enum Column {
    Int,
    Float,
    Bool,
    Text,
}

fn column_of<'a>(name: &str, cells: impl Iterator<Item = &'a str>) -> Column {
    let mut kind = if COUNTS.contains(&name) {
        Column::Int
    } else {
        Column::Float
    };
    for c in cells.filter(|c| !c.is_empty()) {
        let int = c.parse::<i64>().is_ok();
        let float = c.parse::<f64>().is_ok();
        let boolean = c == "true" || c == "false";
        kind = match kind {
            Column::Int if int => Column::Int,
            Column::Float if float => Column::Float,
            Column::Float if boolean => Column::Bool,
            Column::Bool if boolean => Column::Bool,
            _ => return Column::Text,
        };
    }
    kind
}

/// A CSV table as a list of dicts, one per row, keyed by its header.
fn table<'py>(py: Python<'py>, name: &str, bytes: &[u8]) -> PyResult<Bound<'py, PyList>> {
    let failed = |e: csv::Error| PyException::new_err(format!("{name}: {e}"));
    let mut reader = csv::Reader::from_reader(bytes);
    let header: Vec<String> = reader.headers().map_err(failed)?.iter().map(str::to_string).collect();
    let records: Vec<csv::StringRecord> = reader.records().collect::<Result<_, _>>().map_err(failed)?;
    let kinds: Vec<Column> = (0..header.len())
        .map(|j| column_of(&header[j], records.iter().filter_map(|r| r.get(j))))
        .collect();
    let list = PyList::empty(py);
    for r in &records {
        let row = PyDict::new(py);
        for ((key, kind), cell) in header.iter().zip(&kinds).zip(r.iter()) {
            let value = match kind {
                _ if cell.is_empty() => py.None(),
                Column::Int => cell
                    .parse::<i64>()
                    .expect("checked")
                    .into_pyobject(py)?
                    .into_any()
                    .unbind(),
                Column::Float => cell
                    .parse::<f64>()
                    .expect("checked")
                    .into_pyobject(py)?
                    .into_any()
                    .unbind(),
                Column::Bool => (cell == "true").into_pyobject(py)?.to_owned().into_any().unbind(),
                Column::Text => cell.into_pyobject(py)?.into_any().unbind(),
            };
            row.set_item(key, value)?;
        }
        list.append(row)?;
    }
    Ok(list)
}

/// One design of a plan: its attitudes in the order to fly them, its metrics and its verdict.
#[pyclass(module = "pymagcal", frozen)]
pub struct Design {
    name: String,
    /// Its row of `design_metrics.csv`.
    metrics: Py<PyDict>,
    /// Its rows of `designs.csv`, in visiting order.
    points: Py<PyList>,
    /// roll, pitch, yaw, magnetic heading (degrees) and readings of each point, visiting order.
    columns: [Vec<f64>; 5],
    quaternions: Vec<[f64; 4]>,
}

fn column<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    v.to_vec().into_pyarray(py)
}

impl Design {
    fn metric<'py, T: FromPyObjectOwned<'py>>(&self, py: Python<'py>, key: &str) -> PyResult<T> {
        self.metrics
            .bind(py)
            .get_item(key)?
            .ok_or_else(|| PyException::new_err(format!("design_metrics.csv has no column {key}")))?
            .extract()
            .map_err(Into::into)
    }
}

#[pymethods]
impl Design {
    /// The design's name in the scenario.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// How it was made: `optimum`, `pso`, `plan`, `grid`, `random` or `explicit` (listed in the
    /// scenario).
    #[getter]
    fn kind(&self, py: Python<'_>) -> PyResult<String> {
        self.metric(py, "kind")
    }

    /// Readings in all, `m`.
    #[getter]
    fn m(&self, py: Python<'_>) -> PyResult<u64> {
        self.metric(py, "m")
    }

    /// Roll of each attitude, degrees, in the order to fly them.
    #[getter]
    fn roll_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        column(py, &self.columns[0])
    }

    /// Pitch of each attitude, degrees.
    #[getter]
    fn pitch_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        column(py, &self.columns[1])
    }

    /// Yaw of each attitude from the field's horizontal direction, degrees ([P1]'s angle).
    #[getter]
    fn yaw_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        column(py, &self.columns[2])
    }

    /// Magnetic heading of each attitude, degrees: what a pilot steers by.
    #[getter]
    fn magnetic_heading_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        column(py, &self.columns[3])
    }

    /// Readings to log at each attitude.
    #[getter]
    fn readings<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        self.columns[4]
            .iter()
            .map(|&r| r as u64)
            .collect::<Vec<_>>()
            .into_pyarray(py)
    }

    /// Each attitude as the quaternion `(w, x, y, z)` taking body vectors into north, east, down.
    #[getter]
    fn quaternions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let flat: Vec<f64> = self.quaternions.iter().flatten().copied().collect();
        numpy::ndarray::Array2::from_shape_vec((self.quaternions.len(), 4), flat)
            .expect("four values an attitude")
            .into_pyarray(py)
    }

    /// D-efficiency per reading against the best design of the plan.
    #[getter]
    fn d_efficiency(&self, py: Python<'_>) -> PyResult<Option<f64>> {
        self.metric(py, "d_efficiency")
    }

    /// The certified lower bound of its D-efficiency against every design of as many readings in
    /// the box (`None` without a certificate).
    #[getter]
    fn certified_efficiency(&self, py: Python<'_>) -> PyResult<Option<f64>> {
        self.metric(py, "d_efficiency_bound")
    }

    /// Whether its Cramer-Rao bound identifies every parameter.
    #[getter]
    fn identifiable(&self, py: Python<'_>) -> PyResult<bool> {
        self.metric(py, "identifiable")
    }

    /// The verdict: whether it calibrates in at least 95 % of the scenario's check trials and
    /// keeps the heading within the budget.
    #[getter]
    fn works(&self, py: Python<'_>) -> PyResult<bool> {
        self.metric(py, "works")
    }

    /// Median heading error of the check's calibrated trials, degrees (`None`: none calibrated).
    #[getter]
    fn heading_median_deg(&self, py: Python<'_>) -> PyResult<Option<f64>> {
        self.metric(py, "check_heading_median_deg")
    }

    /// The heading error its check's calibrations leave over the box at every heading, degrees:
    /// the 95th percentile over them of each one's 95th percentile over the attitudes (`works`
    /// needs it within the budget; `None`: none calibrated).
    #[getter]
    fn heading_p95_deg(&self, py: Python<'_>) -> PyResult<Option<f64>> {
        self.metric(py, "check_budget_p95_deg")
    }

    /// Of the logs of it design flew and judged as `calibrate` judges a log (20, where its
    /// heading is above half the budget), how many are usable; `works` needs 18. `None` where
    /// none were flown.
    #[getter]
    fn logs_usable(&self, py: Python<'_>) -> PyResult<Option<usize>> {
        self.metric(py, "check_logs_usable")
    }

    /// Its row of `design_metrics.csv`, every column (a copy).
    #[getter]
    fn metrics<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.metrics.bind(py).copy()
    }

    /// Its rows of `designs.csv`, in the order to fly them (copies).
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        copies(self.points.bind(py))
    }

    fn __len__(&self) -> usize {
        self.quaternions.len()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let m: u64 = self.metric(py, "m").unwrap_or(0);
        let works: bool = self.metric(py, "works").unwrap_or(false);
        format!(
            "Design({:?}: {} attitudes, {m} readings, {})",
            self.name,
            self.quaternions.len(),
            if works { "works" } else { "does not work" }
        )
    }
}

/// The designs of a scenario, as `magcal design` makes them.
#[pyclass(module = "pymagcal", frozen)]
pub struct Plan {
    name: String,
    designs: Vec<Py<Design>>,
    recommended: Option<usize>,
    recommendation: String,
    tables: Py<PyDict>,
}

#[pymethods]
impl Plan {
    /// The scenario's name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// The designs, in the scenario's order.
    #[getter]
    fn designs(&self, py: Python<'_>) -> Vec<Py<Design>> {
        self.designs.iter().map(|d| d.clone_ref(py)).collect()
    }

    /// The design to fly: among those that work, the smallest median heading error of its
    /// check, then the fewest readings; `None` when none works (`tables["advice.csv"]` says what
    /// does instead).
    #[getter]
    fn recommended(&self, py: Python<'_>) -> Option<Py<Design>> {
        self.recommended.map(|i| self.designs[i].clone_ref(py))
    }

    /// The recommendation as `magcal design` prints it.
    #[getter]
    fn recommendation(&self) -> &str {
        &self.recommendation
    }

    /// The result set's tables by file name (`designs.csv`, `design_metrics.csv`,
    /// `approximate.csv`, `certificate.csv`, and `advice.csv` when no design works), each a list
    /// of rows as dicts with the files' numbers (copies).
    #[getter]
    fn tables<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (name, rows) in self.tables.bind(py).iter() {
            out.set_item(name, copies(rows.cast::<PyList>()?)?)?;
        }
        Ok(out)
    }

    /// A design by name, or by its place in the scenario's order.
    fn __getitem__(&self, py: Python<'_>, key: &Bound<'_, PyAny>) -> PyResult<Py<Design>> {
        if let Ok(i) = key.extract::<isize>() {
            let n = self.designs.len() as isize;
            let at = if i < 0 { i + n } else { i };
            return (0..n)
                .contains(&at)
                .then(|| self.designs[at as usize].clone_ref(py))
                .ok_or_else(|| pyo3::exceptions::PyIndexError::new_err(format!("design {i} of {n}")));
        }
        let name: String = key.extract()?;
        self.designs
            .iter()
            .find(|d| d.get().name == name)
            .map(|d| d.clone_ref(py))
            .ok_or_else(|| pyo3::exceptions::PyKeyError::new_err(name))
    }

    /// Whether a design of that name is in the plan.
    fn __contains__(&self, name: &Bound<'_, PyAny>) -> bool {
        name.extract::<String>()
            .is_ok_and(|n| self.designs.iter().any(|d| d.get().name == n))
    }

    /// The designs, in the scenario's order.
    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyIterator>> {
        let list = PyList::new(py, self.designs.iter().map(|d| d.clone_ref(py)))?;
        list.try_iter()
    }

    fn __len__(&self) -> usize {
        self.designs.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Plan({:?}: {} designs, recommended {})",
            self.name,
            self.designs.len(),
            self.recommended
                .map_or("none".to_string(), |i| format!("{:?}", self.designs[i].get().name))
        )
    }
}

/// The designs of a scenario as `magcal design SCENARIO` makes them: each design's attitudes in
/// the order to fly them, its certified D-efficiency and its verdict from the scenario's check
/// trials, and the design to fly. `scenario` is a scenario file, or `toml` the scenario's text
/// itself (named `<scenario>` in messages). Each keyword is the flag of the same name. The
/// interpreter's Ctrl-C is seen when the designs are done.
#[pyfunction]
#[pyo3(signature = (scenario=None, *, toml=None, seed=None, threads=None, allow_long=false))]
pub fn design(
    py: Python<'_>,
    scenario: Option<PathBuf>,
    toml: Option<String>,
    seed: Option<i128>,
    threads: Option<i128>,
    allow_long: bool,
) -> PyResult<Plan> {
    let path = match (&scenario, &toml) {
        (Some(p), Some(_)) => {
            return Err(InputError::new_err(format!(
                "design: give the scenario file {} or its text as toml=, not both",
                p.display()
            )));
        }
        (Some(p), _) => p.clone(),
        (None, Some(_)) => PathBuf::from("<scenario>"),
        (None, None) => {
            return Err(InputError::new_err(
                "design: give a scenario file, or its text as toml=",
            ));
        }
    };
    let mut flags = Flags::default();
    flags
        .value("seed", seed)
        .value("threads", threads)
        .flag("quiet", true)
        .flag("allow-long", allow_long);
    let command: DesignCommand = parsed("design", &path.display().to_string(), &flags)?;
    let common = &command.common;
    let made = quietly(py, || -> anyhow::Result<_> {
        let loaded = match &toml {
            Some(text) => magcal_runner::scenario::parse(text.as_bytes(), Path::new(&path))?,
            None => magcal_runner::scenario::load(&common.scenario)?,
        };
        let setup = commands::setup_with(common, loaded, common.seed, None, false)?;
        let (run, advice) = commands::run::planned(&setup, true)?;
        let tables = commands::run::design_tables(&setup.scenario, &run, advice.as_ref())?;
        let mut recommendation = Vec::new();
        print::recommendation(&mut recommendation, &run, advice.as_ref())?;
        Ok((setup.scenario.name.clone(), run.recommended(), tables, recommendation))
    })?;
    let (name, recommended, tables, recommendation) = made.map_err(|e| raised(e.into()))?;
    let dict = PyDict::new(py);
    for (file, bytes) in &tables {
        dict.set_item(*file, table(py, file, bytes)?)?;
    }
    let metrics = dict.get_item("design_metrics.csv")?.expect("always written");
    let points = dict.get_item("designs.csv")?.expect("always written");
    let mut designs = Vec::new();
    for row in metrics.cast::<PyList>()?.iter() {
        let row = row.cast_into::<PyDict>()?;
        let name: String = row.get_item("design")?.expect("a design column").extract()?;
        designs.push(Py::new(py, of_rows(py, name, row, points.cast::<PyList>()?)?)?);
    }
    Ok(Plan {
        name,
        designs,
        recommended,
        recommendation: String::from_utf8_lossy(&recommendation).into_owned(),
        tables: dict.unbind(),
    })
}

/// A list of dicts, each copied.
fn copies<'py>(rows: &Bound<'py, PyList>) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(rows.py());
    for row in rows.iter() {
        out.append(row.cast::<PyDict>()?.copy()?)?;
    }
    Ok(out)
}

/// A design from its row of `design_metrics.csv` and its rows of `designs.csv`.
fn of_rows(py: Python<'_>, name: String, metrics: Bound<'_, PyDict>, all: &Bound<'_, PyList>) -> PyResult<Design> {
    let points = PyList::empty(py);
    let mut columns: [Vec<f64>; 5] = Default::default();
    let mut quaternions = Vec::new();
    let keys = ["roll_deg", "pitch_deg", "yaw_deg", "magnetic_heading_deg", "readings"];
    let number = |row: &Bound<'_, PyDict>, key: &str| -> PyResult<f64> {
        row.get_item(key)?
            .ok_or_else(|| PyException::new_err(format!("designs.csv has no column {key}")))?
            .extract()
    };
    for row in all.iter() {
        let row = row.cast_into::<PyDict>()?;
        let design: String = row.get_item("design")?.expect("a design column").extract()?;
        if design != name {
            continue;
        }
        for (c, key) in columns.iter_mut().zip(keys) {
            c.push(number(&row, key)?);
        }
        quaternions.push([
            number(&row, "qw")?,
            number(&row, "qx")?,
            number(&row, "qy")?,
            number(&row, "qz")?,
        ]);
        points.append(row)?;
    }
    Ok(Design {
        name,
        metrics: metrics.unbind(),
        points: points.unbind(),
        columns,
        quaternions,
    })
}

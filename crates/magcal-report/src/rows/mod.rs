//! The result set's files: one typed row per CSV file, shared by the writer and by every reader
//! (`check`, `plot`, `report`, the tests), so that a column is added in one place.
//!
//! Numbers are written with Rust's shortest round-trip formatting ([`Real`]): exact, and the same
//! bytes for the same value on every platform and thread count. A statistic that is undefined (no
//! successful trial, or a standard deviation of one value) is an empty cell, never `NaN`.

pub mod cells;
pub mod log_rows;
pub mod replay_rows;

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

pub use cells::{Derived, Real, Status, compass_text};

/// `summary.csv`: one row per design, noise level and metric. The trials' outcome counts
/// (`ok + not_converged + not_identifiable + failed = trials`); statistics over the `ok` trials that produced the
/// metric; `rms` of those values; `crb_rms`, the Cramer-Rao prediction of that rms. Empty where
/// undefined.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
    pub design: String,
    pub sigma_nt: Real,
    /// Execution error of the attitudes, degrees (`attitude_sigma_deg` of the scenario).
    pub attitude_sigma_deg: Real,
    pub trials: usize,
    pub ok: usize,
    pub not_converged: usize,
    pub not_identifiable: usize,
    pub failed: usize,
    pub metric: Metric,
    pub mean: Option<Real>,
    pub std: Option<Real>,
    pub median: Option<Real>,
    pub p05: Option<Real>,
    pub p95: Option<Real>,
    pub se_mean: Option<Real>,
    pub rms: Option<Real>,
    pub crb_rms: Option<Real>,
}

/// `crb.csv`: the predicted standard deviation of each parameter (Cramer-Rao bound), per design
/// and noise level; empty where the information is singular.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CrbRow {
    pub design: String,
    pub sigma_nt: Real,
    pub parameter: String,
    pub std: Option<Real>,
    pub unit: String,
    /// The root mean square of the estimate's error over the cell's `ok` trials, and its ratio to
    /// `std`: how near the estimator comes to the floor (1 at the floor; empty without `ok` trials).
    pub mc_rms: Option<Real>,
    pub mc_over_crb: Option<Real>,
}

/// `trials.csv`: one row per trial, its status, errors and estimates (empty when it has none).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TrialRow {
    pub design: String,
    pub sigma_nt: Real,
    pub attitude_sigma_deg: Real,
    pub trial: usize,
    pub status: Status,
    pub eta_psi: Option<Real>,
    pub eta_s: Option<Real>,
    pub eta_o: Option<Real>,
    pub psi1_deg: Option<Real>,
    pub psi2_deg: Option<Real>,
    pub psi3_deg: Option<Real>,
    pub s1: Option<Real>,
    pub s2: Option<Real>,
    pub s3: Option<Real>,
    pub o1_nt: Option<Real>,
    pub o2_nt: Option<Real>,
    pub o3_nt: Option<Real>,
    pub step2_iterations: Option<usize>,
    pub rms_residual_nt: Option<Real>,
    pub abs_psi_deg: Option<Real>,
    pub abs_s: Option<Real>,
    pub abs_o_nt: Option<Real>,
    pub heading_rms_deg: Option<Real>,
    pub heading_max_deg: Option<Real>,
}

impl TrialRow {
    /// The value of `metric` in this row.
    pub fn value(&self, metric: Metric) -> Option<f64> {
        match metric {
            Metric::EtaPsi => self.eta_psi,
            Metric::EtaS => self.eta_s,
            Metric::EtaO => self.eta_o,
            Metric::AbsPsiDeg => self.abs_psi_deg,
            Metric::AbsS => self.abs_s,
            Metric::AbsONt => self.abs_o_nt,
            Metric::HeadingRmsDeg => self.heading_rms_deg,
            Metric::HeadingMaxDeg => self.heading_max_deg,
        }
        .map(|r| r.0)
    }
}

/// `designs.csv`: one row per attitude, degrees (to 1e-9 degree); the true heading of the nose,
/// `-(yaw + yaw_offset_deg)` mod 360, and its magnetic heading, the true heading minus the
/// field's declination mod 360, what a compass reads (docs/conventions.md "Sense of the angles");
/// and the attitude as the unit quaternion `(qw, qx, qy, qz)` (Hamilton, `qw >= 0`) of `C_b^n`, the
/// rotation from the body frame (nose, up, right) to North-Up-East, yaw offset included.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DesignPointRow {
    pub design: String,
    /// 1-based position in the visiting order (rows are written in this order).
    pub visit: usize,
    /// 1-based index of the attitude in the design as built (scenario or optimiser order; the
    /// trials simulate the readings in this order).
    pub point: usize,
    pub roll_deg: Real,
    pub yaw_deg: Real,
    pub pitch_deg: Real,
    /// Degrees clockwise from true north.
    pub true_heading_deg: Real,
    /// Degrees clockwise from magnetic north; empty when the field has no horizontal component.
    pub magnetic_heading_deg: Option<Real>,
    pub qw: Real,
    pub qx: Real,
    pub qy: Real,
    pub qz: Real,
    /// Readings planned at this attitude (1 but for a plan).
    #[serde(default = "one")]
    pub readings: usize,
    /// The rotation from the previous attitude in the visiting order, degrees (empty for the
    /// first).
    pub turn_deg: Option<Real>,
}

fn one() -> usize {
    1
}

/// `design_metrics.csv`: information and conditioning of a design; D-efficiency against the best
/// design of the run; the \[P1\] Table III ratios against the design named `uniform` (empty when
/// there is none). A value that is undefined (the efficiency or a ratio of two singular designs)
/// is empty.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DesignMetricsRow {
    pub design: String,
    pub m: usize,
    pub ln_det_mf: Real,
    pub d_efficiency: Option<Real>,
    pub cond_h: Option<Real>,
    pub cond_mf: Option<Real>,
    pub det_inv_ratio_vs_uniform: Option<Real>,
    pub cond_h_ratio_vs_uniform: Option<Real>,
    pub cond_mf_ratio_vs_uniform: Option<Real>,
    pub kind: DesignKind,
    pub a_criterion: Option<Real>,
    pub e_criterion: Option<Real>,
    pub best_in_run: bool,
    pub identifiable: bool,
    pub weakest: String,
    /// Certified lower bound of the D-efficiency against every design of `m` readings in the
    /// box (`approximate.csv`, `certificate.csv`); empty without a certificate.
    pub d_efficiency_bound: Option<Real>,
    /// The criterion the design's optimiser minimised (`d`, `a`, `e`; empty when not optimised).
    pub criterion: Option<String>,
    /// The verdict's own Monte Carlo (`magcal_runner::pipeline::Check`): noise, trials, `ok` trials.
    pub check_sigma_nt: Real,
    pub check_trials: usize,
    pub check_ok: usize,
    /// At least 95 % of the check's trials ok.
    pub works: bool,
    /// Median and 95th percentile over the check's `ok` trials of the rms heading error over
    /// level headings, degrees.
    pub check_heading_median_deg: Option<Real>,
    pub check_heading_p95_deg: Option<Real>,
    /// The design `design` recommends flying.
    pub recommended: bool,
    /// The heading budget, degrees, and the 95/95 tolerance of the heading error the check's
    /// `ok` trials leave over the box at every heading (docs/conventions.md "Heading budget");
    /// `works` needs it within the budget. Empty in a set written before they existed.
    #[serde(default)]
    pub heading_budget_deg: Option<Real>,
    #[serde(default)]
    pub check_budget_p95_deg: Option<Real>,
    /// Logs of the design flown (simulated) at the check's noise and judged as `calibrate`
    /// judges a log, and how many of them are usable; `works` needs 90 % of them. Empty where
    /// none are flown: the check misses the budget or meets it by more than half of it.
    #[serde(default)]
    pub check_logs: Option<usize>,
    #[serde(default)]
    pub check_logs_usable: Option<usize>,
}

/// `approximate.csv`: the approximate D-optimal design of the box, support points by decreasing
/// weight (docs/conventions.md "Certified D-efficiency").
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ApproximatePointRow {
    /// 1-based.
    pub point: usize,
    pub roll_deg: Real,
    pub yaw_deg: Real,
    pub pitch_deg: Real,
    /// As in `designs.csv`.
    pub true_heading_deg: Real,
    /// As in `designs.csv`.
    pub magnetic_heading_deg: Option<Real>,
    pub weight: Real,
}

/// `certificate.csv`: one row, the certificate of the approximate design.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CertificateRow {
    /// `ln det M(xi)` of the approximate design's normalised information, `H` in nT.
    pub ln_det_per_reading: Real,
    /// The largest variance `h^T M(xi)^-1 h` found over the box (9 at the optimum).
    pub d_max: Real,
    pub d_max_roll_deg: Real,
    pub d_max_yaw_deg: Real,
    pub d_max_pitch_deg: Real,
    /// Upper bound on `ln det M*` per reading: `ln_det_per_reading + 9 ln(d_max / 9)`.
    pub ln_det_bound_per_reading: Real,
    /// The tolerance asked, and whether `d_max <= 9 (1 + tolerance)` was reached.
    pub tolerance: Real,
    pub converged: bool,
    pub rounds: usize,
    pub candidates: usize,
    pub support_points: usize,
}

/// `pso_runs.csv`: the final `ln det M_F` of each repeated PSO run (\[P1\] Fig. 4).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PsoRunRow {
    pub run: usize,
    /// Attitudes per design.
    pub m: usize,
    pub final_ln_det: Real,
    pub evaluations: usize,
}

/// The header of a row type: its field names, in order, taken from serialising a default row (so
/// that the struct is the only place that lists them).
pub fn header<T: Serialize + Default>() -> Result<csv::StringRecord> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.serialize(T::default())?;
    let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut r = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(bytes.as_slice());
    Ok(r.records().next().context("no header")??)
}

/// Writes `rows` as CSV with their header (also when there are none).
pub fn write_csv<T: Serialize + Default>(rows: impl IntoIterator<Item = T>, w: impl Write) -> Result<()> {
    let mut csv = csv::WriterBuilder::new().has_headers(false).from_writer(w);
    csv.write_record(&header::<T>()?)?;
    for row in rows {
        csv.serialize(row)?;
    }
    csv.flush()?;
    Ok(())
}

/// Rows formatted per block by one task of [`write_csv_indexed`].
const CSV_BLOCK: usize = 16_384;

/// [`write_csv`] of the `n` rows `row(0)`, ..., `row(n - 1)`, formatted in blocks of
/// `CSV_BLOCK` (16,384) rows on every thread and written in their order: the same bytes on one thread
/// or many (a CSV record's text does not depend on the records before it), with a few blocks per
/// thread in memory at a time. A calibration's ten million residual rows take 16-22 s to format
/// on one thread.
pub fn write_csv_indexed<T, F>(n: usize, row: F, mut w: impl Write) -> Result<()>
where
    T: Serialize + Default,
    F: Fn(usize) -> T + Sync,
{
    use rayon::prelude::*;
    w.write_all(&csv_bytes(std::iter::empty::<T>())?)?;
    let batch = CSV_BLOCK * 2 * rayon::current_num_threads().max(1);
    for start in (0..n).step_by(batch) {
        let end = (start + batch).min(n);
        let starts: Vec<usize> = (start..end).step_by(CSV_BLOCK).collect();
        let blocks: Vec<Result<Vec<u8>>> = starts
            .into_par_iter()
            .map(|b| {
                let mut csv = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
                for i in b..(b + CSV_BLOCK).min(end) {
                    csv.serialize(row(i))?;
                }
                csv.into_inner().map_err(|e| anyhow::anyhow!("{}", e.error()))
            })
            .collect();
        for block in blocks {
            w.write_all(&block?)?;
        }
    }
    w.flush()?;
    Ok(())
}

/// Formats rows into memory.
pub fn csv_bytes<T: Serialize + Default>(rows: impl IntoIterator<Item = T>) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    write_csv(rows, &mut buf)?;
    Ok(buf)
}

/// `text` for a message: quoted and cut to 80 characters, control characters escaped.
fn quoted_text(text: &str) -> String {
    format!(
        "\"{}\"",
        magcal_logs::limits::printable(&magcal_logs::limits::excerpt(text, 80))
    )
}

/// Reads a CSV file of `T` rows; an error names the file, the line, the column and the value.
pub fn read_csv<T: DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    let bytes = magcal_logs::limits::read_bounded(path, magcal_logs::limits::max_result_file_bytes())?;
    parse_csv(&bytes, &path.display().to_string())
}

/// Parses CSV bytes of `T` rows; errors are prefixed with `what` (a file name).
pub fn parse_csv<T: DeserializeOwned>(bytes: &[u8], what: &str) -> Result<Vec<T>> {
    let mut rows = Vec::new();
    for_each_csv_row(bytes, what, |row| {
        rows.push(row);
        Ok(())
    })?;
    Ok(rows)
}

/// Reads CSV rows of `T` from `input` one at a time, handing each to `each` (whose error ends the
/// reading), and returns how many there were: a file of any length in the memory of one row.
/// Errors are those of [`parse_csv`].
pub fn for_each_csv_row<T: DeserializeOwned, R: std::io::Read>(
    input: R,
    what: &str,
    mut each: impl FnMut(T) -> Result<()>,
) -> Result<usize> {
    let mut reader = csv::ReaderBuilder::new().buffer_capacity(1 << 16).from_reader(input);
    let headers = reader.headers().with_context(|| format!("{what}: no header"))?.clone();
    if headers.is_empty() {
        bail!("{what}: empty file");
    }
    let mut record = csv::StringRecord::new();
    let mut count = 0;
    while reader
        .read_record(&mut record)
        .map_err(|e| anyhow::anyhow!("{what}: {}", magcal_logs::limits::printable(&e.to_string())))?
    {
        let line = record.position().map_or(0, |p| p.line());
        let row = record.deserialize::<T>(Some(&headers)).map_err(|e| {
            let (column, message) = match e.kind() {
                csv::ErrorKind::Deserialize { err, .. } => {
                    let column = err.field().map_or(String::new(), |f| {
                        let name = magcal_logs::limits::printable(&magcal_logs::limits::excerpt(
                            headers.get(f as usize).unwrap_or("?"),
                            80,
                        ));
                        let value = quoted_text(record.get(f as usize).unwrap_or(""));
                        format!("{name} = {value}: ")
                    });
                    let message = match err.kind() {
                        // With a header, a missing field is a column the header does not have.
                        csv::DeserializeErrorKind::Message(m) if m.starts_with("missing field") => {
                            format!("{m}: the header has no such column (a file of another magcal version?)")
                        }
                        csv::DeserializeErrorKind::Message(m) => {
                            magcal_logs::limits::printable(&magcal_logs::limits::excerpt(m, 200))
                        }
                        csv::DeserializeErrorKind::ParseFloat(_) => "not a number".into(),
                        other => other.to_string(),
                    };
                    (column, message)
                }
                _ => (String::new(), e.to_string()),
            };
            anyhow::anyhow!("{what}: line {line}: {column}{message}")
        })?;
        each(row)?;
        count += 1;
    }
    Ok(count)
}

/// `advice.csv`: when no design works, what does instead (`magcal_runner::pipeline::advice::Advice`), one row
/// per option tried.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AdviceRow {
    /// `reduced`, `quieter` or `wider`.
    pub option: String,
    /// `full`, or the reduced model: `diagonal`, `axisN_held`, `offsets_only`.
    pub model: String,
    /// The design the option starts from.
    pub design: String,
    /// Noise of the option's check, nT.
    pub sigma_nt: Real,
    /// Its box, degrees.
    pub roll_min_deg: Real,
    pub roll_max_deg: Real,
    pub pitch_min_deg: Real,
    pub pitch_max_deg: Real,
    /// Attitudes and readings in all.
    pub attitudes: usize,
    pub readings: usize,
    pub check_trials: usize,
    pub check_ok: usize,
    pub works: bool,
    pub check_heading_median_deg: Option<Real>,
    pub check_heading_p95_deg: Option<Real>,
    /// As in `designs.csv`.
    #[serde(default)]
    pub heading_budget_deg: Option<Real>,
    #[serde(default)]
    pub check_budget_p95_deg: Option<Real>,
    #[serde(default)]
    pub check_logs: Option<usize>,
    #[serde(default)]
    pub check_logs_usable: Option<usize>,
}

/// The kind of a design source, as `design_metrics.csv` names it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DesignKind {
    /// Attitudes listed in the scenario.
    #[default]
    Explicit,
    /// A uniform grid.
    Grid,
    /// Uniform random attitudes.
    Random,
    /// The paper's PSO.
    Pso,
    /// The multi-start optimum optimiser.
    Optimum,
    /// The approximate D-optimal design rounded to a number of readings.
    Plan,
}

impl DesignKind {
    /// Whether an optimiser chose the attitudes. Many designs share the optimal `ln det M_F` with
    /// different attitudes and conditioning, so `check` compares only `ln det` for these.
    pub fn is_optimised(self) -> bool {
        matches!(self, Self::Pso | Self::Optimum | Self::Plan)
    }

    /// The name used in files.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Explicit => "explicit",
            Self::Grid => "grid",
            Self::Random => "random",
            Self::Pso => "pso",
            Self::Optimum => "optimum",
            Self::Plan => "plan",
        }
    }
}

/// The Monte Carlo metrics of `summary.csv`: the relative errors of \[P1\] eq. (21)-(23)
/// (percent), the absolute errors, and the heading error (docs/conventions.md).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// `eta_psi`, \[P1\] eq. (21), percent.
    #[default]
    EtaPsi,
    /// `eta_S`, \[P1\] eq. (22), percent.
    EtaS,
    /// `eta_O`, \[P1\] eq. (23), percent.
    EtaO,
    /// `|psi_hat - psi|`, degrees.
    AbsPsiDeg,
    /// `|S_hat - S|`.
    AbsS,
    /// `|O_hat - O|`, nT.
    AbsONt,
    /// Rms heading error over the level yaws, degrees.
    HeadingRmsDeg,
    /// Largest heading error over the level yaws, degrees.
    HeadingMaxDeg,
}

impl Metric {
    /// In file order.
    pub const ALL: [Self; 8] = [
        Self::EtaPsi,
        Self::EtaS,
        Self::EtaO,
        Self::AbsPsiDeg,
        Self::AbsS,
        Self::AbsONt,
        Self::HeadingRmsDeg,
        Self::HeadingMaxDeg,
    ];

    /// The name in files.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::EtaPsi => "eta_psi",
            Self::EtaS => "eta_s",
            Self::EtaO => "eta_o",
            Self::AbsPsiDeg => "abs_psi_deg",
            Self::AbsS => "abs_s",
            Self::AbsONt => "abs_o_nt",
            Self::HeadingRmsDeg => "heading_rms_deg",
            Self::HeadingMaxDeg => "heading_max_deg",
        }
    }

    /// An axis label.
    pub fn label(self) -> &'static str {
        match self {
            Self::EtaPsi => "eta_psi, non-orthogonality error (%)",
            Self::EtaS => "eta_S, scale factor error (%)",
            Self::EtaO => "eta_O, bias error (%)",
            Self::AbsPsiDeg => "|psi_hat - psi| (deg)",
            Self::AbsS => "|S_hat - S|",
            Self::AbsONt => "|O_hat - O| (nT)",
            Self::HeadingRmsDeg => "rms heading error over level yaws (deg)",
            Self::HeadingMaxDeg => "largest heading error over level yaws (deg)",
        }
    }

    /// The metric of one trial, if it has it.
    pub fn of(self, t: &magcal_core::monte_carlo::TrialOutcome) -> Option<f64> {
        match self {
            Self::EtaPsi => t.eta.and_then(|e| e.psi),
            Self::EtaS => t.eta.and_then(|e| e.scale),
            Self::EtaO => t.eta.and_then(|e| e.bias),
            Self::AbsPsiDeg => t.abs.map(|a| a.psi_deg),
            Self::AbsS => t.abs.map(|a| a.scale),
            Self::AbsONt => t.abs.map(|a| a.bias_nt),
            Self::HeadingRmsDeg => t.heading.map(|h| h.rms_deg),
            Self::HeadingMaxDeg => t.heading.map(|h| h.max_deg),
        }
    }

    /// The Cramer-Rao prediction of the metric's rms, where the bound defines one.
    pub fn predicted_rms(self, bound: &magcal_core::CramerRao) -> Option<f64> {
        match self {
            Self::EtaPsi | Self::EtaS | Self::EtaO => bound.rms_eta()[self as usize],
            Self::AbsPsiDeg | Self::AbsS | Self::AbsONt => bound.rms_abs()[self as usize - 3],
            Self::HeadingRmsDeg | Self::HeadingMaxDeg => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows formatted in blocks on every thread are the bytes of one writer, on one thread or
    /// two, for no rows, a part of a block, and several batches of blocks with a part left over.
    #[test]
    fn rows_formatted_in_parallel_blocks_are_the_bytes_of_one_writer() {
        #[derive(Serialize, Default)]
        struct Row {
            i: usize,
            x: Derived,
            note: Option<String>,
        }
        let row = |i: usize| Row {
            i,
            x: Derived((i as f64).sqrt() * -1.234_567_89e3),
            note: i.is_multiple_of(7).then(|| format!("a \"quoted\", {i}")),
        };
        for n in [0, 5, CSV_BLOCK * 4 * 3 + 17] {
            let one = csv_bytes((0..n).map(row)).unwrap();
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut many = Vec::new();
                pool.install(|| write_csv_indexed(n, row, &mut many)).unwrap();
                assert!(one == many, "{n} rows on {threads} threads");
            }
        }
    }

    /// 7 significant digits, no exponent, within half a unit of the 7th digit, read back.
    #[test]
    fn a_derived_number_has_seven_significant_digits() {
        let cell = |x: f64| {
            let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(vec![]);
            w.serialize([Derived(x)]).unwrap();
            String::from_utf8(w.into_inner().unwrap())
                .unwrap()
                .trim_end()
                .to_string()
        };
        for (x, text) in [
            (-0.26596902743458667, "-0.265969"),
            (46447.416666, "46447.42"),
            (0.0027673883544501177, "0.002767388"),
            (1.0, "1"),
            (9999999.5, "10000000"),
            (-123456789.0, "-123456789"),
            (0.0, "0"),
            (f64::NAN, "NaN"),
        ] {
            assert_eq!(cell(x), text, "{x}");
        }
        for k in 0..2000 {
            let x = (k as f64 * 0.37).sin() * 10f64.powi(k % 17 - 8);
            let back: f64 = cell(x).parse().unwrap();
            assert!((back - x).abs() <= 5e-7 * x.abs() * (1.0 + 1e-9), "{x} {back}");
            assert!(!cell(x).contains('e'), "{}", cell(x));
        }
    }

    #[test]
    fn a_heading_that_rounds_up_to_360_reads_0() {
        assert_eq!(compass_text(359.995, 1), "0.0");
        assert_eq!(compass_text(359.94, 1), "359.9");
        assert_eq!(compass_text(359.996, 2), "0.00");
        assert_eq!(compass_text(0.04, 1), "0.0");
        assert_eq!(compass_text(180.26, 1), "180.3");
    }

    #[test]
    fn headers_come_from_the_row_types() {
        let h = header::<SummaryRow>().unwrap();
        assert_eq!(
            h.iter().collect::<Vec<_>>(),
            [
                "design",
                "sigma_nt",
                "attitude_sigma_deg",
                "trials",
                "ok",
                "not_converged",
                "not_identifiable",
                "failed",
                "metric",
                "mean",
                "std",
                "median",
                "p05",
                "p95",
                "se_mean",
                "rms",
                "crb_rms"
            ]
        );
        // A file with no rows still has its header.
        assert_eq!(
            csv_bytes(Vec::<PsoRunRow>::new()).unwrap(),
            b"run,m,final_ln_det,evaluations\n"
        );
    }

    #[test]
    fn rows_round_trip_with_exact_numbers() {
        let row = SummaryRow {
            design: "u".into(),
            sigma_nt: Real(30.0),
            attitude_sigma_deg: Real(0.5),
            trials: 10,
            failed: 1,
            ok: 9,
            not_converged: 0,
            not_identifiable: 0,
            metric: Metric::EtaO,
            mean: Some(Real(0.1 + 0.2)),
            std: None,
            median: Some(Real(f64::INFINITY)),
            p05: Some(Real(-0.0)),
            p95: Some(Real(2.5)),
            se_mean: None,
            rms: None,
            crb_rms: Some(Real(1.0)),
        };
        let bytes = csv_bytes([row.clone()]).unwrap();
        let text = String::from_utf8(bytes.clone()).unwrap();
        assert_eq!(
            text.lines().nth(1),
            Some("u,30,0.5,10,9,0,0,1,eta_o,0.30000000000000004,,inf,-0,2.5,,,1")
        );
        let back: Vec<SummaryRow> = parse_csv(&bytes, "x").unwrap();
        assert_eq!(back, [row]);
    }

    #[test]
    fn a_bad_cell_is_named_by_line_column_and_value() {
        let text = "run,m,final_ln_det,evaluations\n0,9,1.5,3\n1,9,twelve,3\n";
        let e = parse_csv::<PsoRunRow>(text.as_bytes(), "pso_runs.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pso_runs.csv") && e.contains("line 3") && e.contains("final_ln_det = \"twelve\": not a number"),
            "{e}"
        );
        let e = parse_csv::<PsoRunRow>(b"run,m,evaluations\n0,9,3\n", "p")
            .unwrap_err()
            .to_string();
        assert!(e.contains("final_ln_det"), "{e}");
    }
}

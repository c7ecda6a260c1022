//! `magcal apply CAL.json LOG`: calibrate every reading of a log.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;

use super::Failure;
use crate::log::calibration::{CalibrationJson, MotorJson};
use crate::log::calibration::{RadiusMedian, columns_for, read_calibration};
use crate::log::flight::Format;
use crate::log::read::{self as log_file, HELD_BYTES_PER_READING};
use crate::log::source::{self, Log, LogArgs, format_of};
use crate::output::file::Output;
use crate::output::log_rows::AppliedRow;
use crate::output::stderr::to_stderr;
use crate::output::{self, Real};

/// `magcal apply`.
#[derive(Debug, Args)]
pub struct ApplyArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log to calibrate (`-`: standard input).
    #[arg(value_parser = crate::log::path_parser())]
    pub log: PathBuf,
    /// How to read the log, as for `calibrate` (default columns: those the calibration was made
    /// from; rows dropped by `--skip-bad` are named on stderr).
    #[command(flatten)]
    pub input: LogArgs,
    /// The matrix to calibrate with: `triangular`, the paper's `P` (`b = P (raw - bias)`, turned
    /// into the body frame by the alignment of a vector calibration), or `symmetric`, `A^-1`
    /// (`b = A^-1 (raw - bias)`, as `export` writes it for the autopilots). The two give the
    /// same `|b|` and differ by a rotation.
    #[arg(long, value_enum, default_value_t = Matrix::Triangular)]
    pub matrix: Matrix,
    /// Write the calibrated readings to this file, replaced whole (default, or `-`: standard
    /// output). Only a regular file or a missing path is replaced, and never an input.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// `apply --matrix`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Matrix {
    /// `p`, upper triangular (eq. (6) of the paper), then `alignment.rotation` where the calibration
    /// carries one.
    #[default]
    Triangular,
    /// `soft_iron_inverse`, symmetric.
    Symmetric,
}

/// Runs `apply`: the calibration is checked ([`crate::log::calibration::CalibrationJson::check`]),
/// the log read with the calibration's columns unless `--columns` says otherwise, every
/// calibrated reading checked finite before anything is written, and a warning given when the
/// log's median calibrated radius is far from the calibration's magnitude (other units, another
/// log or another field).
///
/// # Errors
/// A bad calibration file or log, or a reading whose calibrated value is not finite (exit 2;
/// with `--skip-bad` that reading is dropped and shown, as a non-finite one is).
pub fn run(args: &ApplyArgs) -> Result<(), Failure> {
    Ok(apply_inner(args)?)
}

fn apply_inner(args: &ApplyArgs) -> Result<()> {
    let out = Output::from_flag(args.out.as_deref());
    let inputs = [args.calibration.as_path(), args.log.as_path()];
    out.check(&inputs)?;
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    let mut input = args.input.clone();
    input.columns = columns_for(&cal, &shown, &args.log, &input)?;
    // A CSV log without times is streamed: each reading is calibrated and written as it is read,
    // and nothing of it is held. A flight log, or a CSV log cut by time, is read whole first. An
    // error part way (a bad row, a reading whose calibrated value is not finite) leaves the
    // output as it was: the rows went to a temporary file that is then removed (on standard
    // output, the rows before it have been written, as with any filter).
    // A calibration with motor interference needs each reading's input: the log is read whole.
    let streamable = cal.motor.is_none() && format_of(&args.log, input.format)? == Format::Csv && input.time.is_none();
    // A log read whole is read before anything is written: its errors replace nothing.
    let held = match streamable {
        true => None,
        false => Some(read_held(&cal, &shown, &args.log, &input, HELD_BYTES_PER_READING)?),
    };
    let mut radius = RadiusMedian::new(cal.magnitude);
    let mut skipped = Vec::new();
    let mut filtered = 0;
    let mut overflowed = Vec::new();
    out.write(&inputs, |w| {
        let mut csv = csv::WriterBuilder::new().has_headers(false).from_writer(w);
        csv.write_record(&output::header::<AppliedRow>()?)?;
        let mut row = |line: usize, raw: magcal_core::Vec3| -> Result<()> {
            let b = match args.matrix {
                Matrix::Triangular => cal.apply_body(raw),
                Matrix::Symmetric => magcal_core::small::mat_vec(&cal.soft_iron_inverse, magcal_core::small::sub(raw, cal.bias)),
            };
            // |b| through hypot: its squares overflow for components above 1e154, whose length
            // is still finite.
            let norm = b[0].hypot(b[1]).hypot(b[2]);
            if !(b.iter().all(|v| v.is_finite()) && norm.is_finite()) {
                // With --skip-bad, a reading whose calibrated value overflows is a bad row like a
                // non-finite one: dropped, counted and shown.
                if input.skip_bad {
                    overflowed.push((line, format!("the reading {raw:?} calibrated is {b:?}, not finite (--skip-bad)")));
                    return Ok(());
                }
                bail!(
                    "{}: line {line}: the reading {raw:?} calibrated by {shown} is {b:?}, not finite (is the calibration for this sensor and units?)",
                    args.log.display()
                );
            }
            radius.push(b);
            csv.serialize(AppliedRow {
                line,
                x: Real(b[0]),
                y: Real(b[1]),
                z: Real(b[2]),
                norm: Real(norm),
            })?;
            Ok(())
        };
        match &held {
            None => {
                let s = log_file::stream_with(
                    &args.log,
                    input.columns.as_deref(),
                    &[],
                    &input.filter,
                    input.skip_bad,
                    0,
                    |line, raw, _| row(line, raw),
                )?;
                (skipped, filtered) = (s.skipped, s.filtered);
            }
            Some(log) => {
                for (&line, &raw) in log.lines.iter().zip(&log.readings) {
                    row(line, raw)?;
                }
                skipped.clone_from(&log.skipped);
                filtered = log.filtered;
            }
        }
        csv.flush()?;
        Ok(())
    })?;
    skipped.extend(overflowed);
    skipped.sort_by_key(|(line, _)| *line);
    for (line, reason) in &skipped {
        to_stderr!("magcal: skipped line {line}: {reason}");
    }
    if let Some(note) = source::filter_note(&input.filter, filtered) {
        to_stderr!("magcal: {}: {note}", args.log.display());
    }
    notes(args, &cal, &shown, radius.ratio());
    Ok(())
}

/// What a reader of `apply`'s output should know of the calibration `cal` (named `shown`): the
/// frame of a vector calibration's readings, a fit marked not identifiable, and a log whose median
/// calibrated radius is `ratio` times the calibration's magnitude far from 1.
fn notes(args: &ApplyArgs, cal: &CalibrationJson, shown: &str, ratio: f64) {
    if let Some(a) = &cal.alignment {
        to_stderr!(
            "magcal: note: {shown} carries an alignment (a vector calibration, misalignment {:.3} deg): {}",
            a.misalignment_deg,
            match args.matrix {
                Matrix::Triangular =>
                    "x, y, z are the body-frame field, the alignment times P (raw - bias), body forward, right, down",
                Matrix::Symmetric =>
                    "--matrix symmetric leaves it out: x, y, z are A^-1 (raw - bias), not the body frame",
            }
        );
    }
    if !cal.identifiable {
        to_stderr!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
    if let Some(why) = cal.radius_mismatch(ratio) {
        to_stderr!("magcal: warning: {}: {why}", args.log.display());
    }
}

/// The log at `path` read whole with `input` (its columns those of the calibration `cal`, as
/// [`columns_for`] gives them), holding `held_bytes_per_reading` per reading, with the motor
/// interference `cal` carries removed from its readings. `cal_shown` names the calibration in
/// errors.
///
/// # Errors
/// A bad log, or one without the input the motor interference needs.
pub fn read_held(
    cal: &CalibrationJson,
    cal_shown: &str,
    path: &Path,
    input: &LogArgs,
    held_bytes_per_reading: u64,
) -> Result<Log> {
    // A calibration with motor interference reads the log's current or throttle.
    let input = LogArgs {
        motor: cal.motor.is_some(),
        ..input.clone()
    };
    let mut log = source::open(path, &input, held_bytes_per_reading)?;
    if let Some(m) = &cal.motor {
        without_interference(&mut log, m).with_context(|| format!("{}: {cal_shown}", path.display()))?;
    }
    Ok(log)
}

/// Removes the motor interference `m` from the readings of `log`: `raw - d u` with `u` each
/// reading's current or throttle, as `calibrate --motor` fitted the calibration.
///
/// # Errors
/// A log without that input, or a reading without one.
fn without_interference(log: &mut Log, m: &MotorJson) -> Result<()> {
    let (series, flag) = match m.input.as_str() {
        "current" => (&log.currents, "--current"),
        "throttle" => (&log.throttles, "--throttle"),
        other => bail!("motor.input {other:?}: not current or throttle"),
    };
    let Some(series) = series else {
        bail!(
            "the calibration removes motor interference per unit {}, and the log has none (a CSV log names its column with {flag})",
            m.input
        );
    };
    let u: Vec<f64> = series.iter().flatten().copied().collect();
    if u.len() != series.len() {
        bail!(
            "{} of {} readings have no {} near them in time; cut the log to where it has one (--from, --to)",
            series.len() - u.len(),
            series.len(),
            m.input
        );
    }
    for (r, u) in log.readings.iter_mut().zip(u) {
        *r = std::array::from_fn(|i| r[i] - m.per_unit[i] * u);
    }
    Ok(())
}

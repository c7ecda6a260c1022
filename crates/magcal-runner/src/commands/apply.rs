//! `magcal apply CAL.json LOG`: calibrate every reading of a log.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use crate::cli::Failure;
use crate::log::calibration::{RadiusMedian, columns_for, read_calibration};
use crate::log::read as log_file;
use crate::output::file::replace_with;

/// `magcal apply`.
#[derive(Debug, Args)]
pub struct ApplyArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log to calibrate.
    pub log: PathBuf,
    /// As for `calibrate` (default: the columns the calibration was made from).
    #[arg(long)]
    pub columns: Option<String>,
    /// As for `calibrate`: rows with a non-finite or missing value are dropped, and each is named
    /// on stderr.
    #[arg(long)]
    pub skip_bad: bool,
    /// Write the calibrated readings here (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `apply`: the calibration is checked ([`crate::log::calibration::CalibrationJson::check`]),
/// the log read with the calibration's columns unless `--columns` says otherwise, every
/// calibrated reading checked finite before anything is written, and a warning given when the
/// log's median calibrated radius is far from the calibration's magnitude (other units, another
/// log or another field).
///
/// # Errors
/// A bad calibration file or log, or a reading whose calibrated value is not finite (exit 2).
pub fn run(args: &ApplyArgs) -> Result<(), Failure> {
    Ok(apply_inner(args)?)
}

fn apply_inner(args: &ApplyArgs) -> Result<()> {
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    let columns = columns_for(&cal, &shown, &args.log, args.columns.as_deref())?;
    let log = log_file::read(&args.log, columns.as_deref(), args.skip_bad)?;
    // Every calibrated reading before anything is written: a non-finite one is refused whole.
    let mut radius = RadiusMedian::new(cal.magnitude);
    for (raw, line) in log.readings.iter().zip(&log.lines) {
        let b = cal.apply(*raw);
        if !(b.iter().all(|v| v.is_finite()) && magcal_core::small::norm(b).is_finite()) {
            bail!(
                "{}: line {line}: the reading {raw:?} calibrated by {shown} is {b:?}, not finite (is the calibration for this sensor and units?)",
                args.log.display()
            );
        }
        radius.push(b);
    }
    for (line, reason) in &log.skipped {
        eprintln!("magcal: skipped line {line}: {reason}");
    }
    if !cal.identifiable {
        eprintln!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
    if let Some(why) = cal.radius_mismatch(radius.ratio()) {
        eprintln!("magcal: warning: {}: {why}", args.log.display());
    }
    let rows = |out: &mut dyn Write| -> Result<()> {
        writeln!(out, "line,x,y,z,norm")?;
        for (raw, line) in log.readings.iter().zip(&log.lines) {
            let b = cal.apply(*raw);
            writeln!(out, "{line},{},{},{},{}", b[0], b[1], b[2], magcal_core::small::norm(b))?;
        }
        Ok(())
    };
    match &args.out {
        Some(path) => replace_with(path, rows),
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            rows(&mut w)?;
            w.flush().context("stdout")
        }
    }
}

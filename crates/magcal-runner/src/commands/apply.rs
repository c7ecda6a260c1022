//! `magcal apply CAL.json LOG`: calibrate every reading of a log.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::cli::Failure;
use crate::log::calibration::read_calibration;
use crate::log::read as log_file;
use crate::output::file::Output;
use crate::output::log_rows::AppliedRow;
use crate::output::{self, Real};

/// `magcal apply`.
#[derive(Debug, Args)]
pub struct ApplyArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log to calibrate.
    pub log: PathBuf,
    /// As for `calibrate`.
    #[arg(long)]
    pub columns: Option<String>,
    /// As for `calibrate`: rows with a non-finite or missing value are dropped, and each is named
    /// on stderr.
    #[arg(long)]
    pub skip_bad: bool,
    /// Write the calibrated readings to this file, replaced whole (default, or `-`: standard
    /// output). Only a regular file or a missing path is replaced, and never an input.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `apply`.
///
/// # Errors
/// A bad calibration file or log (exit 2).
pub fn run(args: &ApplyArgs) -> Result<(), Failure> {
    Ok(apply_inner(args)?)
}

fn apply_inner(args: &ApplyArgs) -> Result<()> {
    let out = Output::from_flag(args.out.as_deref());
    let inputs = [args.calibration.as_path(), args.log.as_path()];
    out.check(&inputs)?;
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    if !cal.identifiable {
        eprintln!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
    let log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    for (line, reason) in &log.skipped {
        eprintln!("magcal: skipped line {line}: {reason}");
    }
    let rows = log.readings.iter().zip(&log.lines).map(|(raw, &line)| {
        let b = cal.apply(*raw);
        AppliedRow {
            line,
            x: Real(b[0]),
            y: Real(b[1]),
            z: Real(b[2]),
            norm: Real(magcal_core::small::norm(b)),
        }
    });
    out.write(&inputs, |w| output::write_csv(rows, w))
}

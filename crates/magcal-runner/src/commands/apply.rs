//! `magcal apply CAL.json LOG`: calibrate every reading of a log.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::cli::Failure;
use crate::log::calibration::read_calibration;
use crate::log::read as log_file;
use crate::output::file::replace_with;

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
    /// Write the calibrated readings here (default: stdout).
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
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    if !cal.identifiable {
        eprintln!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
    let log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    for (line, reason) in &log.skipped {
        eprintln!("magcal: skipped line {line}: {reason}");
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

//! What `calibrate` says of a log that no model fits (too few readings, readings all alike): a
//! property of the data, not bad input, so exit 3 with the report, as for any calibration not to
//! use; `--out` replaces the set with the report (`no_calibration.json`), so that no earlier
//! calibration stays behind as if it were this log's.

use std::collections::BTreeMap;

use anyhow::Context;
use serde::Serialize;

use super::{CalibrateArgs, Failure};
use crate::digest::sha256_hex;
use crate::log::calibration::NO_CALIBRATION_FORMAT;
use crate::log::flown::{Flown, flown};
use crate::log::source::Log;
use crate::output::file::to_stdout;
use crate::output::staging::ResultSet;

/// The report of a log without a calibration (`no_calibration.json`).
#[derive(Debug, Serialize)]
pub struct NoCalibrationJson {
    pub log: String,
    pub format: &'static str,
    pub magcal_version: &'static str,
    pub log_sha256: String,
    pub columns: [String; 3],
    pub samples: usize,
    pub skipped: usize,
    pub rejected: usize,
    /// The model asked for (`--fit`).
    pub fit: &'static str,
    /// Always false: there is no calibration.
    pub usable: bool,
    /// Why there is none: under which model, and what the fit met.
    pub reasons: Vec<String>,
    /// The time span of the readings, seconds on the log's clock, where it has times.
    pub time_span_s: Option<[f64; 2]>,
    /// What the log's attitudes visited, where it has them.
    pub flown: Option<Flown>,
    /// What the reader noted of the log (messages it skipped, and why).
    pub log_notes: Vec<String>,
}

/// The report that `log` has no calibration, `why`, after `rejected` readings were dropped.
pub fn json(args: &CalibrateArgs, log: &Log, rejected: usize, why: String) -> NoCalibrationJson {
    // Readings a flight log's reader skipped (times going back, values not finite) are often
    // why too few are left: the reason says so rather than leave a count that looks like the log's.
    let skipped_notes: Vec<String> = log
        .origin
        .notes
        .iter()
        .filter_map(|n| n.strip_prefix("Skipped "))
        .map(|n| format!("skipped {}", n.trim_end_matches('.')))
        .collect();
    let why = if skipped_notes.is_empty() {
        why
    } else {
        format!("{why} ({})", skipped_notes.join("; "))
    };
    NoCalibrationJson {
        log: args.log.display().to_string(),
        format: NO_CALIBRATION_FORMAT,
        magcal_version: env!("CARGO_PKG_VERSION"),
        log_sha256: log.sha256.clone(),
        columns: log.columns.clone(),
        samples: log.readings.len(),
        skipped: log.skipped.len(),
        rejected,
        fit: args.fit.name(),
        usable: false,
        reasons: vec![why],
        time_span_s: log.times.as_ref().and_then(|t| Some([*t.first()?, *t.last()?])),
        flown: log.attitudes.as_ref().and_then(|a| flown(a, None)),
        log_notes: log.origin.notes.clone(),
    }
}

/// Prints (and with `--out` writes) `json`, the report that `log` (`rows` rows) has no
/// calibration; exit 3.
pub fn report(
    args: &CalibrateArgs,
    set: Option<ResultSet>,
    log: &Log,
    rows: usize,
    json: &NoCalibrationJson,
) -> Result<(), Failure> {
    if let Some(mut set) = set {
        let mut text = serde_json::to_vec_pretty(&json).context("JSON")?;
        text.push(b'\n');
        set.put("no_calibration.json", &text)?;
        let files = BTreeMap::from([("no_calibration.json".to_string(), sha256_hex(&text))]);
        let manifest = crate::output::manifest::calibration(&args.log, log.sha256.clone(), log.bytes, rows, files);
        set.put("manifest.json", &manifest.to_bytes()?)?;
        set.commit()?;
    }
    to_stdout(|w| {
        if args.json {
            serde_json::to_writer_pretty(&mut *w, &json).context("JSON")?;
            writeln!(w)?;
        } else {
            writeln!(
                w,
                "{}: {} readings (columns {}), {} skipped, {} rejected",
                json.log,
                json.samples,
                json.columns.join(", "),
                json.skipped,
                json.rejected
            )?;
            for note in &json.log_notes {
                writeln!(w, "  note: {note}")?;
            }
            writeln!(w, "NO CALIBRATION under {}", json.reasons.join("; "))?;
            if let Some(f) = &json.flown {
                super::print::print_flown(w, f, json.samples, None)?;
            }
        }
        Ok(())
    })?;
    Err(Failure::Unusable(format!(
        "{}: no calibration under {}",
        args.log.display(),
        json.reasons.join("; ")
    )))
}

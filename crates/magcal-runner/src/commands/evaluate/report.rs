//! What `evaluate` reports, made from its fits: one JSON object ([`EvaluationJson`], `--json`),
//! the text report made from it, and the per-reading rows of `--errors` ([`ErrorRow`]); the
//! types, and the page of `--report`, are in [`crate::report::evaluate`].

use std::io::Write;

use magcal_core::aviation::NavFrame;
use magcal_core::reference::{Alignment, ErrorSummary, axis_angle, cell_summaries};
use magcal_core::small::norm;

use super::{Fits, SECTOR_DEG, TILT_BANDS_DEG, Used};
use crate::commands::calibrate::heading::against;
use crate::log::calibration::CalibrationJson;
use crate::log::source::Log;
use crate::output::Real;
pub use crate::report::evaluate::{CellJson, ErrorRow, EvaluationJson, FiguresJson, RowsJson};

/// What was evaluated, for the report's header.
pub struct Source<'a> {
    pub log: &'a Log,
    pub log_shown: &'a str,
    pub cal: Option<&'a CalibrationJson>,
    pub cal_shown: Option<&'a str>,
}

/// The report of the fits of the readings `used`.
pub fn evaluation_json(source: Source, used: &Used, fits: &Fits) -> EvaluationJson {
    let log = source.log;
    let units = source.cal.and_then(|c| c.units.clone()).or_else(|| {
        log.origin
            .unit
            .and_then(|u| clap::ValueEnum::to_possible_value(&u))
            .map(|v| v.get_name().to_string())
    });
    let body = match used.frame {
        NavFrame::Ned => "forward, right, down",
        NavFrame::Enu => "forward, left, up",
    };
    EvaluationJson {
        log: source.log_shown.to_string(),
        log_sha256: log.sha256.clone(),
        calibration: source.cal_shown.map(str::to_string),
        units,
        against: against(&log.origin),
        frames: format!(
            "Q turns the calibrated frame into the body frame ({body}); F is in the reference frame with z up (east, north, up for NED attitudes)"
        ),
        rows: RowsJson {
            readings: log.readings.len(),
            used: used.raw.len(),
            without_attitude: used.without,
            skipped: log.skipped.len(),
            left_out_by_where: log.filtered,
            notes: log.origin.notes.clone(),
        },
        sector_deg: SECTOR_DEG,
        tilt_bands_deg: TILT_BANDS_DEG.to_vec(),
        calibrated: fits.calibrated.as_ref().map(|a| figures(a, used)),
        calibrated_aligned: fits.aligned.as_ref().map(|a| figures(a, used)),
        uncalibrated: figures(&fits.raw, used),
    }
}

/// The figures of one fit.
fn figures(a: &Alignment, used: &Used) -> FiguresJson {
    let (axis, angle) = axis_angle(&a.rotation);
    let f = a.field;
    let sectors = cell_summaries(a, &used.sectors(), (360.0 / SECTOR_DEG) as usize);
    let bands = cell_summaries(a, &used.bands(), TILT_BANDS_DEG.len() - 1);
    FiguresJson {
        heading_rms_deg: a.summary.heading_rms_deg,
        heading_p95_deg: a.summary.heading_p95_deg,
        heading_max_deg: a.summary.heading_max_deg,
        direction_rms_deg: a.summary.direction_rms_deg,
        rotation: a.rotation,
        rotation_angle_deg: angle.to_degrees(),
        rotation_axis: axis,
        field: f,
        field_magnitude: norm(f),
        field_dip_deg: (-f[2]).atan2(f[0].hypot(f[1])).to_degrees(),
        by_heading: sectors
            .into_iter()
            .enumerate()
            .map(|(i, c)| cell(i as f64 * SECTOR_DEG, (i + 1) as f64 * SECTOR_DEG, c))
            .collect(),
        by_tilt: bands
            .into_iter()
            .enumerate()
            .map(|(i, c)| cell(TILT_BANDS_DEG[i], TILT_BANDS_DEG[i + 1], c))
            .collect(),
    }
}

fn cell(from_deg: f64, to_deg: f64, (readings, s): (usize, Option<ErrorSummary>)) -> CellJson {
    CellJson {
        from_deg,
        to_deg,
        readings,
        heading_rms_deg: s.map(|s| s.heading_rms_deg),
        heading_max_deg: s.map(|s| s.heading_max_deg),
        direction_rms_deg: s.map(|s| s.direction_rms_deg),
    }
}

/// The rows of `--errors`: `judged`'s errors (the calibrated readings', or the raw ones' with
/// `--raw`) beside `raw`'s.
pub fn error_rows<'a>(
    used: &'a Used,
    judged: &'a Alignment,
    raw: &'a Alignment,
) -> impl Iterator<Item = ErrorRow> + 'a {
    (0..used.raw.len()).map(move |t| error_row(used, judged, raw, t))
}

/// The row of `--errors` of reading `t` of `used`.
pub fn error_row(used: &Used, judged: &Alignment, raw: &Alignment, t: usize) -> ErrorRow {
    let [roll, pitch, heading] = used.roll_pitch_heading[t];
    ErrorRow {
        line: used.lines[t],
        time_s: used.times.as_ref().map(|v| Real(v[t])),
        roll_deg: Real(roll),
        pitch_deg: Real(pitch),
        heading_deg: Real(heading),
        tilt_deg: Real(used.tilt[t]),
        heading_error_deg: Real(judged.heading_deg[t]),
        direction_error_deg: Real(judged.direction_deg[t]),
        raw_heading_error_deg: Real(raw.heading_deg[t]),
        raw_direction_error_deg: Real(raw.direction_deg[t]),
    }
}

/// A figure to 4 decimals, `-` for none.
fn fig(x: Option<f64>) -> String {
    x.map_or_else(|| "-".to_string(), |v| format!("{v:.4}"))
}

/// The text report of `j`.
///
/// # Errors
/// A failed write.
pub fn print(w: &mut dyn Write, j: &EvaluationJson) -> std::io::Result<()> {
    let r = &j.rows;
    match &j.calibration {
        Some(c) => writeln!(w, "{} evaluated with {c}", j.log)?,
        None => writeln!(w, "{}: raw readings, uncalibrated", j.log)?,
    }
    writeln!(
        w,
        "  {} readings with an attitude used, {} without one; {} rows skipped, {} left out by --where",
        r.used, r.without_attitude, r.skipped, r.left_out_by_where
    )?;
    for note in &r.notes {
        writeln!(w, "  note: {note}")?;
    }
    writeln!(w, "  attitudes: {}", j.against)?;
    writeln!(w, "  {}", j.frames)?;
    writeln!(
        w,
        "{:<16}{:>13}{:>13}{:>13}{:>15}   (degrees)",
        "", "heading rms", "heading p95", "heading max", "direction rms"
    )?;
    let sets = j.sets();
    for (name, f) in &sets {
        writeln!(
            w,
            "{name:<16}{:>13.4}{:>13.4}{:>13.4}{:>15.4}",
            f.heading_rms_deg, f.heading_p95_deg, f.heading_max_deg, f.direction_rms_deg
        )?;
    }
    if j.calibrated_aligned.is_some() {
        writeln!(
            w,
            "aligned: the calibrated readings with Q held at the calibration's alignment, only F fitted"
        )?;
    }
    let units = j.units.as_deref().unwrap_or("the log's units");
    for (name, f) in &sets {
        let a = f.rotation_axis;
        writeln!(
            w,
            "{name}: Q {:.4} deg about ({:.4}, {:.4}, {:.4}); F ({:.4}, {:.4}, {:.4}) {units}, |F| {:.4}, dip {:.4} deg",
            f.rotation_angle_deg,
            a[0],
            a[1],
            a[2],
            f.field[0],
            f.field[1],
            f.field[2],
            f.field_magnitude,
            f.field_dip_deg
        )?;
    }
    let main = sets[0].1;
    let raw = j.calibrated.as_ref().map(|_| &j.uncalibrated);
    writeln!(
        w,
        "by heading of the body (clockwise from the reference frame's north), {}:",
        sets[0].0
    )?;
    cells(w, &main.by_heading, raw.map(|r| &r.by_heading[..]))?;
    writeln!(w, "by tilt (angle between body up and up), {}:", sets[0].0)?;
    cells(w, &main.by_tilt, raw.map(|r| &r.by_tilt[..]))
}

/// A table of cells, with the raw readings' heading rms beside where given.
fn cells(w: &mut dyn Write, cells: &[CellJson], raw: Option<&[CellJson]>) -> std::io::Result<()> {
    write!(
        w,
        "  {:<10}{:>10}{:>13}{:>13}{:>15}",
        "degrees", "readings", "heading rms", "heading max", "direction rms"
    )?;
    if raw.is_some() {
        write!(w, "{:>17}", "raw heading rms")?;
    }
    writeln!(w)?;
    for (i, c) in cells.iter().enumerate() {
        let range = format!("{}-{}", c.from_deg, c.to_deg);
        write!(
            w,
            "  {range:<10}{:>10}{:>13}{:>13}{:>15}",
            c.readings,
            fig(c.heading_rms_deg),
            fig(c.heading_max_deg),
            fig(c.direction_rms_deg)
        )?;
        if let Some(raw) = raw {
            write!(w, "{:>17}", fig(raw[i].heading_rms_deg))?;
        }
        writeln!(w)?;
    }
    Ok(())
}

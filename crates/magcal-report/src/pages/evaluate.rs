//! What `evaluate` reports: its JSON object ([`EvaluationJson`], `evaluate --json`), its rows per
//! reading ([`ErrorRow`], `evaluate --errors`) and its page (`evaluate --report`): heading error
//! against time, against heading and against tilt, its histogram, the errors per heading sector
//! and tilt band, and the JSON's figures in tables.

use anyhow::{Context, Result};
use magcal_core::Vec3;
use magcal_core::small::Mat3;
use plotly::common::{Marker, Mode, Title};
use plotly::layout::{Axis, BarMode};
use plotly::{Bar, Layout, Plot, Scatter};
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::{Block, Cell, Page, Table, drawn, thinned_note};
use crate::rows::Real;

/// Readings drawn in each figure against a reading's time, heading or tilt at most.
pub const MAX_DRAWN: usize = 4000;

/// `evaluate --json`: every figure the text report prints.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvaluationJson {
    pub log: String,
    /// SHA-256 of the log's bytes as read.
    pub log_sha256: String,
    /// The calibration file; `null` with `--raw`.
    pub calibration: Option<String>,
    /// The readings' unit where known (the calibration's `--units`, a flight log's own).
    pub units: Option<String>,
    /// What the attitudes are, in words.
    pub against: String,
    /// The frames of `rotation` and `field`, in words.
    pub frames: String,
    pub rows: RowsJson,
    /// Width of the heading sectors of `by_heading`, degrees.
    pub sector_deg: f64,
    /// Bounds of the tilt bands of `by_tilt`, degrees.
    pub tilt_bands_deg: Vec<f64>,
    /// The calibrated readings `P (raw - bias)`; `null` with `--raw`.
    pub calibrated: Option<FiguresJson>,
    /// The calibrated readings with `Q` held at the calibration's alignment (a vector
    /// calibration's) and only `F` fitted; `null` without one.
    pub calibrated_aligned: Option<FiguresJson>,
    /// The raw readings taken as calibrated.
    pub uncalibrated: FiguresJson,
}

/// What was read and what was used.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RowsJson {
    /// Readings read (after `--where`, `--skip-bad`, `--from`, `--to` and `--rate`).
    pub readings: usize,
    /// Readings with an attitude: those evaluated.
    pub used: usize,
    /// Readings without an attitude (an empty or non-finite attitude cell, no attitude sample
    /// near them in time).
    pub without_attitude: usize,
    /// Rows skipped for a bad value (`--skip-bad`).
    pub skipped: usize,
    /// Rows left out by `--where`.
    pub left_out_by_where: usize,
    /// What the reader and the cut say about the log, one sentence each.
    pub notes: Vec<String>,
}

/// The figures of one set of readings, degrees unless said.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FiguresJson {
    pub heading_rms_deg: f64,
    pub heading_p95_deg: f64,
    pub heading_max_deg: f64,
    pub direction_rms_deg: f64,
    /// `Q`, calibrated frame into body frame (rows).
    pub rotation: Mat3,
    /// `Q`'s angle and axis (a unit vector in the body frame).
    pub rotation_angle_deg: f64,
    pub rotation_axis: Vec3,
    /// `F` in the reference frame, the readings' units; its magnitude and dip (positive where
    /// the field points below the horizontal).
    pub field: Vec3,
    pub field_magnitude: f64,
    pub field_dip_deg: f64,
    /// The errors per heading sector of the body, from 0 in steps of `sector_deg`.
    pub by_heading: Vec<CellJson>,
    /// The errors per tilt band.
    pub by_tilt: Vec<CellJson>,
}

/// The errors of the readings in one cell; the figures are `null` in an empty cell.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CellJson {
    pub from_deg: f64,
    pub to_deg: f64,
    pub readings: usize,
    pub heading_rms_deg: Option<f64>,
    pub heading_max_deg: Option<f64>,
    pub direction_rms_deg: Option<f64>,
}

/// `evaluate --errors`: one row per reading evaluated. The attitude in the NED convention
/// (heading clockwise from the reference frame's north), the tilt between body up and up, and
/// the errors of the calibrated readings (of the raw ones with `--raw`) and of the raw ones.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ErrorRow {
    /// The reading's line in a CSV log, its message's byte offset in a flight log.
    pub line: usize,
    /// Seconds on the log's clock; empty where the log has no times.
    pub time_s: Option<Real>,
    pub roll_deg: Real,
    pub pitch_deg: Real,
    pub heading_deg: Real,
    pub tilt_deg: Real,
    pub heading_error_deg: Real,
    pub direction_error_deg: Real,
    pub raw_heading_error_deg: Real,
    pub raw_direction_error_deg: Real,
}

impl EvaluationJson {
    /// The sets of figures in the order the report gives them, with their names: calibrated,
    /// aligned (where there is one), uncalibrated.
    pub fn sets(&self) -> Vec<(&'static str, &FiguresJson)> {
        [("calibrated", &self.calibrated), ("aligned", &self.calibrated_aligned)]
            .into_iter()
            .filter_map(|(name, f)| Some((name, f.as_ref()?)))
            .chain([("uncalibrated", &self.uncalibrated)])
            .collect()
    }
}

/// The readings a page draws and counts.
pub struct Readings<'a> {
    /// The rows of the readings drawn, evenly through the log.
    pub drawn: &'a [ErrorRow],
    /// The heading error of every reading evaluated, degrees: of the calibrated readings (of
    /// the raw ones with `--raw`).
    pub heading_error_deg: &'a [f64],
    /// The same of the raw readings, beside calibrated ones; `None` with `--raw`.
    pub raw_heading_error_deg: Option<&'a [f64]>,
}

/// A number with `decimals` decimals, its full value kept (a dash where not finite).
fn fixed(value: f64, decimals: usize) -> Cell {
    if !value.is_finite() {
        return Cell::text("-");
    }
    Cell {
        text: format!("{value:.decimals$}"),
        value: Some(value),
    }
}

/// [`fixed`] of a value that may be missing.
fn fixed_maybe(value: Option<f64>, decimals: usize) -> Cell {
    value.map_or_else(|| Cell::text("-"), |v| fixed(v, decimals))
}

/// The page of an evaluation `json` and of its `readings`.
///
/// # Errors
/// A JSON that does not serialise (a bug).
pub fn page(json: &EvaluationJson, readings: &Readings) -> Result<Page> {
    let judged = if json.calibration.is_some() {
        "calibrated"
    } else {
        "raw"
    };
    let mut page = Page::new(
        format!("Heading errors of {}", file_name(&json.log)),
        match &json.calibration {
            Some(c) => format!("{} evaluated with {c}, magcal {}", json.log, env!("CARGO_PKG_VERSION")),
            None => format!(
                "{}: raw readings, uncalibrated, magcal {}",
                json.log,
                env!("CARGO_PKG_VERSION")
            ),
        },
    );
    let r = &json.rows;
    page.text(format!(
        "{} readings with an attitude used, {} without one; {} rows skipped, {} left out by --where. Attitudes: {}. {}.",
        r.used, r.without_attitude, r.skipped, r.left_out_by_where, json.against, json.frames
    ));
    for note in &r.notes {
        page.note(format!("Note: {note}"));
    }
    figures_table(&mut page, json);
    rows_table(&mut page, r);
    let total = readings.heading_error_deg.len();
    page.heading(format!("Heading error of each reading ({judged})"));
    if let Some(note) = thinned_note("The three figures below", readings.drawn.len(), total) {
        page.note(note);
    }
    against_reading(&mut page, readings, judged);
    page.heading("Distribution of the heading error");
    histogram(&mut page, readings, judged);
    let sets = json.sets();
    let (name, main) = sets[0];
    let raw = json.calibrated.as_ref().map(|_| &json.uncalibrated);
    page.heading(format!("By heading of the body ({name})"));
    cells(
        &mut page,
        "by-heading",
        &main.by_heading,
        raw.map(|r| &r.by_heading[..]),
        "heading sector of the body, clockwise from the reference frame's north",
    );
    page.heading(format!("By tilt ({name})"));
    cells(
        &mut page,
        "by-tilt",
        &main.by_tilt,
        raw.map(|r| &r.by_tilt[..]),
        "tilt band: the angle between body up and up",
    );
    page.data(
        "evaluation",
        serde_json::to_value(json).context("the evaluation's JSON")?,
    );
    page.data("readings", json!(total));
    page.data("drawn", json!(readings.drawn.len()));
    Ok(page)
}

/// The last part of a path.
fn file_name(path: &str) -> &str {
    path.rsplit(['/', '\\']).next().unwrap_or(path)
}

/// The four error figures, `Q` and `F` of each set.
fn figures_table(page: &mut Page, json: &EvaluationJson) {
    let units = json.units.as_deref().unwrap_or("the log's units");
    let rows = json
        .sets()
        .into_iter()
        .map(|(name, f)| {
            vec![
                Cell::text(name),
                fixed(f.heading_rms_deg, 4),
                fixed(f.heading_p95_deg, 4),
                fixed(f.heading_max_deg, 4),
                fixed(f.direction_rms_deg, 4),
                fixed(f.rotation_angle_deg, 4),
                fixed(f.field_magnitude, 4),
                fixed(f.field_dip_deg, 4),
            ]
        })
        .collect();
    page.heading("Figures");
    page.table(Table {
        id: "figures".into(),
        caption: format!("Heading error rms, 95th percentile and maximum and direction error rms (degrees), the angle of the fitted rotation Q, and the fitted field F's magnitude ({units}) and dip (degrees), as evaluate --json gives them"),
        header: [
            "readings judged",
            "heading rms",
            "heading p95",
            "heading max",
            "direction rms",
            "Q angle",
            "|F|",
            "dip",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    });
    if json.calibrated_aligned.is_some() {
        page.note("aligned: the calibrated readings with Q held at the calibration's alignment, only F fitted.");
    }
}

/// What was read and what was used.
fn rows_table(page: &mut Page, r: &RowsJson) {
    let row = |what: &str, n: usize| vec![Cell::text(what), Cell::count(n)];
    page.table(Table {
        id: "rows".into(),
        caption: "Readings".into(),
        header: ["readings", "count"].map(String::from).to_vec(),
        rows: vec![
            row("read", r.readings),
            row("used (with an attitude)", r.used),
            row("without an attitude", r.without_attitude),
            row("rows skipped", r.skipped),
            row("left out by --where", r.left_out_by_where),
        ],
    });
}

/// A 2D scatter of `y` against `x`, drawn as SVG: its at most [`MAX_DRAWN`] points draw at once
/// without WebGL, which the pages' plotly.js leaves out for 2D (`scattergl` would add 0.28 MB to
/// every page).
fn scatter(x: Vec<f64>, y: Vec<f64>, name: &str, colour: &'static str) -> Box<Scatter<f64, f64>> {
    Scatter::new(x, y)
        .mode(Mode::Markers)
        .name(name)
        .marker(Marker::new().size(3).color(colour))
}

/// A layout with titled axes.
fn axes(x: &str, y: &str) -> Layout {
    Layout::new()
        .x_axis(Axis::new().title(Title::with_text(x)))
        .y_axis(Axis::new().title(Title::with_text(y)))
        .margin(plotly::layout::Margin::new().top(30))
}

/// The heading error of each reading drawn against its time, its heading and its tilt.
fn against_reading(page: &mut Page, readings: &Readings, judged: &str) {
    let rows = readings.drawn;
    let timed = rows.iter().all(|r| r.time_s.is_some());
    let pick = |f: &dyn Fn(&ErrorRow) -> f64| rows.iter().map(|r| drawn(f(r))).collect::<Vec<f64>>();
    let error = pick(&|r| r.heading_error_deg.0);
    let raw = readings
        .raw_heading_error_deg
        .map(|_| pick(&|r| r.raw_heading_error_deg.0));
    let views: [(&str, Vec<f64>, String, String); 3] = [
        (
            "error-time",
            if timed {
                pick(&|r| r.time_s.map_or(f64::NAN, |t| t.0))
            } else {
                pick(&|r| r.line as f64)
            },
            if timed {
                "time (s, the log's clock)"
            } else {
                "line of the log"
            }
            .to_string(),
            "against time".to_string(),
        ),
        (
            "error-heading",
            pick(&|r| r.heading_deg.0),
            "heading of the body (degrees clockwise from the reference frame's north)".to_string(),
            "against the body's heading".to_string(),
        ),
        (
            "error-tilt",
            pick(&|r| r.tilt_deg.0),
            "tilt (degrees between body up and up)".to_string(),
            "against the body's tilt".to_string(),
        ),
    ];
    for (id, x, x_title, what) in views {
        let mut plot = Plot::new();
        if let Some(raw) = &raw {
            plot.add_trace(scatter(x.clone(), raw.clone(), "raw readings", "#bbbbbb"));
        }
        plot.add_trace(scatter(x, error.clone(), &format!("{judged} readings"), "#1f77b4"));
        plot.set_layout(axes(&x_title, "heading error (degrees)"));
        page.plot(id, plot, 380, format!(
            "Heading error (degrees, the signed angle about up from the fitted field's horizontal part to the reading's) of the {judged} readings {what}{}; {} readings drawn. Drag to zoom, hover for a reading's values.",
            if raw.is_some() { ", the raw readings' in grey behind" } else { "" },
            rows.len()
        ));
    }
}

/// Bins of width `width` from `-k width` to `k width` holding every finite value of `values`;
/// the counts, and the values that are not finite.
fn bins(values: &[f64], width: f64, k: usize) -> (Vec<usize>, usize) {
    let mut counts = vec![0usize; 2 * k];
    let mut not_finite = 0;
    for &v in values {
        if !v.is_finite() {
            not_finite += 1;
            continue;
        }
        let i = ((v / width).floor() + k as f64).clamp(0.0, (2 * k - 1) as f64);
        counts[i as usize] += 1;
    }
    (counts, not_finite)
}

/// The width of a histogram's bins for values up to `max` in magnitude: 1, 2 or 5 times a power
/// of 10, about 30 bins each side; and the bins each side.
fn bin_width(max: f64) -> (f64, usize) {
    let rough = (max / 30.0).max(1e-6);
    let power = 10f64.powf(rough.log10().floor());
    let width = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * power)
        .find(|w| *w >= rough)
        .unwrap_or(10.0 * power);
    let k = ((max / width).floor() as usize + 1).max(1);
    (width, k)
}

/// The histogram of the heading errors of every reading.
fn histogram(page: &mut Page, readings: &Readings, judged: &str) {
    let all = readings.heading_error_deg;
    let raw = readings.raw_heading_error_deg;
    let max = all
        .iter()
        .chain(raw.unwrap_or_default())
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let (width, k) = bin_width(max);
    let centres: Vec<f64> = (0..2 * k).map(|i| drawn((i as f64 - k as f64 + 0.5) * width)).collect();
    let (counts, not_finite) = bins(all, width, k);
    let mut plot = Plot::new();
    let mut data = json!({"width": width, "centres": centres, "counts": counts, "judged": judged});
    if let Some(raw) = raw {
        let (raw_counts, _) = bins(raw, width, k);
        plot.add_trace(
            Bar::new(centres.clone(), raw_counts.clone())
                .name("raw readings")
                .opacity(0.5)
                .marker(Marker::new().color("#999999")),
        );
        data["raw"] = json!(raw_counts);
    }
    plot.add_trace(
        Bar::new(centres, counts)
            .name(format!("{judged} readings"))
            .opacity(0.75)
            .marker(Marker::new().color("#1f77b4")),
    );
    let mut layout = axes("heading error (degrees)", "readings");
    layout = layout.bar_mode(BarMode::Overlay).bar_gap(0.0);
    plot.set_layout(layout);
    page.plot(
        "histogram",
        plot,
        360,
        format!(
            "Readings per bin of {} degrees of heading error, all {} readings counted{}.",
            super::significant(width, 3),
            all.len(),
            if not_finite > 0 {
                format!("; {not_finite} readings whose error is not finite are not drawn")
            } else {
                String::new()
            }
        ),
    );
    page.data("histogram", data);
}

/// The table and the bars of the cells of one grouping (`id`), with the raw readings' heading
/// rms beside where given.
fn cells(page: &mut Page, id: &str, cells: &[CellJson], raw: Option<&[CellJson]>, what: &str) {
    let labels: Vec<String> = cells.iter().map(|c| format!("{}-{}", c.from_deg, c.to_deg)).collect();
    let mut plot = Plot::new();
    if let Some(raw) = raw {
        let y: Vec<Option<f64>> = raw.iter().map(|c| c.heading_rms_deg.map(drawn)).collect();
        plot.add_trace(
            Bar::new(labels.clone(), y)
                .name("raw readings")
                .marker(Marker::new().color("#999999")),
        );
    }
    let y: Vec<Option<f64>> = cells.iter().map(|c| c.heading_rms_deg.map(drawn)).collect();
    plot.add_trace(
        Bar::new(labels.clone(), y)
            .name("heading rms")
            .marker(Marker::new().color("#1f77b4")),
    );
    plot.set_layout(axes(&format!("{what} (degrees)"), "heading error rms (degrees)").bar_mode(BarMode::Group));
    page.plot(&format!("{id}-bars"), plot, 340, format!("Heading error rms (degrees) of the readings in each {what}; an empty cell has no bar. The table below gives the counts."));
    let mut header: Vec<String> = ["degrees", "readings", "heading rms", "heading max", "direction rms"]
        .map(String::from)
        .to_vec();
    if raw.is_some() {
        header.push("raw heading rms".into());
    }
    let rows = cells
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let mut row = vec![
                Cell::text(&labels[i]),
                Cell::count(c.readings),
                fixed_maybe(c.heading_rms_deg, 4),
                fixed_maybe(c.heading_max_deg, 4),
                fixed_maybe(c.direction_rms_deg, 4),
            ];
            if let Some(raw) = raw {
                row.push(fixed_maybe(raw[i].heading_rms_deg, 4));
            }
            row
        })
        .collect();
    page.push(Block::Table(Table {
        id: id.into(),
        caption: format!("Errors (degrees) per {what}, as evaluate --json gives them"),
        header,
        rows,
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_bins_hold_every_finite_value_once_and_count_the_others() {
        let values = [-17.39, -0.01, 0.0, 0.49, 0.5, 17.39, f64::NAN, f64::INFINITY];
        let (width, k) = bin_width(17.39);
        assert_eq!(width, 1.0);
        assert_eq!(k, 18);
        let (counts, not_finite) = bins(&values, width, k);
        assert_eq!(not_finite, 2);
        assert_eq!(counts.iter().sum::<usize>(), 6);
        assert_eq!(counts[0], 1, "-17.39 in [-18, -17)");
        assert_eq!(counts[k - 1], 1, "-0.01 in [-1, 0)");
        assert_eq!(counts[k], 3, "0, 0.49 and 0.5 in [0, 1)");
        assert_eq!(counts[2 * k - 1], 1, "17.39 in [17, 18)");
        let (tiny, one) = bin_width(0.0);
        assert!(tiny > 0.0 && one == 1, "{tiny} {one}");
        assert_eq!(bin_width(150.0).0, 5.0);
    }
}

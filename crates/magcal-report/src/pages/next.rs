//! What `next` reports: its JSON object ([`NextJson`], `next --json`) and its page (`next
//! --report`): the attitudes to add as a pilot flies them, each drawn where its field direction
//! falls on the sphere of MotionCal's regions coloured by what the log already covers, the
//! standard errors before and after, and the coverage and verdict.

use anyhow::{Context, Result};
use magcal_core::Vec3;
use plotly::Scatter3D;
use plotly::common::{Marker, Mode, Position};
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::sphere::coverage_plot;
use super::{Block, Cell, Page, Table, drawn};

/// `next --json`: every figure the text report prints.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NextJson {
    pub log: String,
    pub calibration: String,
    /// Readings of the log.
    pub readings: usize,
    /// Attitudes asked for (`--count`); the same attitude chosen again is one row of
    /// `attitudes`, with its readings.
    pub count: usize,
    /// The box searched: the scenario file, or the flags.
    pub attitude_box: String,
    /// Declination of the vehicle's field, degrees east of true north; `null` for a field
    /// without a horizontal component.
    pub declination_deg: Option<f64>,
    /// Where the field comes from.
    pub field_source: String,
    /// The attitudes to add, in the order chosen.
    pub attitudes: Vec<AttitudeJson>,
    /// The attitudes relative to what the log flew; `null` for a log without attitudes.
    pub relative_to_log: Option<RelativeJson>,
    /// The standard error of each parameter before and after, under the fitted sensor.
    pub parameters: Vec<ParameterJson>,
    /// Certified D-efficiency per reading in the box, before and after; `null` where no design
    /// in the box determines the model. Above 1 it is no efficiency: the readings hold more
    /// information per reading than any design inside the box.
    pub d_efficiency_before: Option<f64>,
    pub d_efficiency_after: Option<f64>,
    /// Why both are `null` where the certificate was not computed (`live` bounds each fit in
    /// time: `skipped: next's coverage certificate did not finish within 2 s`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub d_efficiency_why_not: Option<String>,
    /// MotionCal's gaps (percent) of the calibrated field directions, before and after.
    pub motioncal_gap_percent_before: f64,
    pub motioncal_gap_percent_after: f64,
    /// MicroStrain's spatial coverage (percent), before and after.
    pub microstrain_coverage_percent_before: f64,
    pub microstrain_coverage_percent_after: f64,
    /// The sensor the plan assumes: the calibration's where it is usable, else the sphere that
    /// best fits the log (a runaway estimate is no sensor to plan with), in words.
    pub planned_under: String,
    /// Whether the full model's calibration of the log is usable before (calibrate's verdict,
    /// its check by trials included), and on what that rests.
    pub usable_before: bool,
    pub usable_before_source: String,
    /// The passes over the table (each row's `readings` count every pass) that make the full
    /// calibration of the log with them usable, where at most [`MAX_PASSES`] do: the full fit of
    /// the log with that many readings simulated from the planning sensor at the log's noise,
    /// judged as calibrate judges a log.
    pub passes_to_usable: Option<usize>,
    /// The readings added in all at that many passes (or at the most tried).
    pub readings_added: usize,
    /// Whether the full fit of the log with the readings added is usable, and where it is not,
    /// why.
    pub usable_after: bool,
    pub usable_after_why_not: Option<String>,
    /// The heading the full fit of the log with the readings added is predicted to leave (95th
    /// percentile over the box at every heading, degrees; the median over its simulated logs),
    /// and the budget it is held to.
    #[serde(default)]
    pub heading_after_deg: Option<f64>,
    /// Logs simulated at those passes, each with the readings added drawn afresh (the first
    /// alone where it is not usable), and how many are usable; `usable_after` needs 4 of 5.
    /// `heading_after_deg` is the median of their figures.
    #[serde(default)]
    pub simulated_logs: usize,
    #[serde(default)]
    pub simulated_logs_usable: usize,
    #[serde(default)]
    pub heading_budget_deg: Option<f64>,
}

/// The most passes over the table `next` tries before it says that more readings at these
/// attitudes do not make the log usable.
pub const MAX_PASSES: usize = 32;

/// One attitude to add, degrees.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AttitudeJson {
    /// Its row, from 1.
    pub k: usize,
    pub roll_deg: f64,
    pub pitch_deg: f64,
    /// True heading of the nose, clockwise from north, in [0, 360) to 1e-9 degree.
    pub true_heading_deg: f64,
    /// Magnetic (compass) heading; `null` without a declination.
    pub magnetic_heading_deg: Option<f64>,
    /// Readings to log there.
    pub readings: usize,
    /// The variance of the linear model's prediction there, at its first choice.
    pub variance: f64,
    /// The direction of the field the sensor reads there, a unit vector in the sensor frame (the
    /// frame of the calibrated readings).
    pub field_direction: Vec3,
}

/// The attitudes to add against those the log flew.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RelativeJson {
    /// Attitudes of the log.
    pub flown: usize,
    /// Each tilt at its headings, and how near the log came, one sentence each.
    pub tilts: Vec<String>,
    /// For a log in the ENU convention, the attitudes as it gives them, in the table's order.
    pub as_logged: Option<String>,
}

/// The standard error of one parameter.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ParameterJson {
    /// `psi1_deg`..`psi3_deg` (degrees), `s1`..`s3`, `o1`..`o3` (the log's units).
    pub name: String,
    /// `null` where the information is singular.
    pub std_before: Option<f64>,
    pub std_after: Option<f64>,
}

/// The page of `next`'s report `json`, over the readings per MotionCal region of the log's
/// calibrated field directions (`counts`) and of those with the added attitudes (`after`).
///
/// # Errors
/// A JSON that does not serialise (a bug).
pub fn page(json: &NextJson, counts: &[usize; 100], after: &[usize; 100]) -> Result<Page> {
    let mut page = Page::new(
        format!("Next attitudes for {}", file_name(&json.log)),
        format!(
            "{} readings of {}, calibrated by {}; the next {} attitudes in the box of {}; magcal {}",
            json.readings,
            json.log,
            json.calibration,
            json.count,
            json.attitude_box,
            env!("CARGO_PKG_VERSION")
        ),
    );
    verdict(&mut page, json);
    page.heading("Attitudes to add");
    page.text(crate::rows::cells::declination_line(
        json.declination_deg,
        &json.field_source,
    ));
    attitudes_table(&mut page, json);
    if let Some(r) = &json.relative_to_log {
        page.text(format!(
            "Relative to the log's {} attitudes (heading clockwise from north, degrees):",
            r.flown
        ));
        for t in &r.tilts {
            page.text(t.clone());
        }
        if let Some(enu) = &r.as_logged {
            page.note(format!("As the log gives attitudes (ENU, body forward-left-up: roll, pitch, yaw counter-clockwise from east), in the table's order: {enu}"));
        }
    }
    page.heading("Where they fall on the coverage sphere");
    page.plot("coverage", coverage(json, counts), 600, format!(
        "The sphere of field directions in the sensor frame (the calibrated readings' frame), cut into MotionCal's 100 regions of equal area and coloured by the log's readings in each: red none, orange one, yellow two, green three or more. The black points, numbered as in the table, are the directions of the field the sensor reads at the attitudes to add. {} regions empty before, {} after. Drag to turn, hover for a region's count or an attitude.",
        counts.iter().filter(|&&c| c == 0).count(),
        after.iter().filter(|&&c| c == 0).count()
    ));
    parameters_table(&mut page, json);
    summary_table(&mut page, json);
    page.data("next", serde_json::to_value(json).context("next's JSON")?);
    page.data("region_counts", json!(counts.to_vec()));
    page.data("region_counts_after", json!(after.to_vec()));
    Ok(page)
}

/// The last part of a path.
fn file_name(path: &str) -> &str {
    path.rsplit(['/', '\\']).next().unwrap_or(path)
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn verdict(page: &mut Page, json: &NextJson) {
    let before = format!(
        "before: {} ({})",
        if json.usable_before { "usable" } else { "not usable" },
        json.usable_before_source
    );
    let text = match (json.passes_to_usable, &json.usable_after_why_not) {
        (Some(n), _) => format!(
            "USABLE AFTER: the full calibration of the log with {} readings at these attitudes ({n} pass{} of the table; simulated under {} at the log's noise) is usable; {before}",
            json.readings_added,
            if n == 1 { "" } else { "es" },
            json.planned_under
        ),
        (None, why) => format!(
            "NOT USABLE AFTER {MAX_PASSES} PASSES: the full calibration of the log with {} readings at these attitudes is still not usable{}; {before}",
            json.readings_added,
            why.as_ref().map_or(String::new(), |w| format!(": {w}"))
        ),
    };
    page.push(Block::Verdict {
        good: json.usable_after,
        text,
    });
}

/// The pilot's table: roll, pitch, true and compass heading, readings, variance.
fn attitudes_table(page: &mut Page, json: &NextJson) {
    let rows = json
        .attitudes
        .iter()
        .map(|a| {
            vec![
                Cell::count(a.k),
                fixed(a.roll_deg, 2),
                fixed(a.pitch_deg, 2),
                fixed(a.true_heading_deg, 2),
                a.magnetic_heading_deg.map_or_else(|| Cell::text("-"), |h| fixed(h, 2)),
                Cell::count(a.readings),
                Cell::number(a.variance, 5),
            ]
        })
        .collect();
    page.table(Table {
        id: "attitudes".into(),
        caption: "Hold each attitude and log its readings: roll (right side down positive), pitch (nose up positive), true heading and compass (magnetic) heading of the nose clockwise from north, degrees; the variance d of the linear model's prediction there when chosen".into(),
        header: ["k", "roll", "pitch", "true heading", "compass heading", "readings", "variance d"]
            .map(String::from)
            .to_vec(),
        rows,
    });
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

/// The coverage sphere with the added attitudes' field directions on it.
fn coverage(json: &NextJson, counts: &[usize; 100]) -> plotly::Plot {
    let mut plot = coverage_plot(counts);
    // Just outside the sphere, so that the patches do not hide them.
    const LIFT: f64 = 1.06;
    let col = |i: usize| {
        json.attitudes
            .iter()
            .map(|a| drawn(LIFT * a.field_direction[i]))
            .collect::<Vec<f64>>()
    };
    let labels: Vec<String> = json.attitudes.iter().map(|a| a.k.to_string()).collect();
    let hover: Vec<String> = json
        .attitudes
        .iter()
        .map(|a| {
            format!(
                "attitude {}: roll {:.2}, pitch {:.2}, true heading {:.2}, {} reading(s)",
                a.k, a.roll_deg, a.pitch_deg, a.true_heading_deg, a.readings
            )
        })
        .collect();
    let points = Scatter3D::new(col(0), col(1), col(2))
        .mode(Mode::MarkersText)
        .name("attitudes to add")
        .text_array(labels)
        .text_position(Position::TopCenter)
        .hover_text_array(hover)
        .marker(Marker::new().size(6).color("#000000"));
    plot.add_trace(points);
    plot
}

/// The standard error of each parameter before and after.
fn parameters_table(page: &mut Page, json: &NextJson) {
    let rows = json
        .parameters
        .iter()
        .map(|p| {
            vec![
                Cell::text(&p.name),
                Cell::maybe(p.std_before, 4),
                Cell::maybe(p.std_after, 4),
            ]
        })
        .collect();
    page.heading("Standard errors");
    page.table(Table {
        id: "parameters".into(),
        caption: "The standard error of each parameter under the fitted sensor ([P1] eq. (12)), before and after the added readings: psi in degrees, s relative, o (bias) in the log's units; a dash where the information is singular".into(),
        header: ["parameter", "before", "after"].map(String::from).to_vec(),
        rows,
    });
}

/// Efficiency, coverage and identifiability before and after.
fn summary_table(page: &mut Page, json: &NextJson) {
    let row = |what: &str, before: Cell, after: Cell| vec![Cell::text(what), before, after];
    let rows = vec![
        row(
            "certified D-efficiency per reading in the box",
            Cell::maybe(json.d_efficiency_before, 4),
            Cell::maybe(json.d_efficiency_after, 4),
        ),
        row(
            "MotionCal gaps (%)",
            Cell::number(json.motioncal_gap_percent_before, 4),
            Cell::number(json.motioncal_gap_percent_after, 4),
        ),
        row(
            "MicroStrain spatial coverage (%)",
            Cell::number(json.microstrain_coverage_percent_before, 4),
            Cell::number(json.microstrain_coverage_percent_after, 4),
        ),
        row(
            "usable (full model)",
            Cell::text(yes_no(json.usable_before)),
            Cell::text(yes_no(json.usable_after)),
        ),
    ];
    page.heading("Before and after");
    page.table(Table {
        id: "summary".into(),
        caption: "The log before and with the added readings. A D-efficiency above 1 is none: the readings hold more information per reading than any design inside the box; a dash: no design in the box determines the model".into(),
        header: ["figure", "before", "after"].map(String::from).to_vec(),
        rows,
    });
}

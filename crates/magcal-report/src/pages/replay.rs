//! The page of a replay set (`magcal replay`): per design and model the distribution of the
//! heading rms over the trials, as \[P1\] Figs. 1-3 draw eta per design, and of eta_psi, eta_S
//! and eta_O where the truth is known; the count of every trial outcome; the design attitudes on
//! the sphere of field directions with the angle within which the log's windows realise them;
//! and `summary.csv` and `whole_log.csv` in tables.
//!
//! Every file is read once and checked against the SHA-256 its manifest records before anything
//! is drawn, and the outcome counts of `summary.csv` against the rows of `trials.csv`: a set whose
//! files were edited or disagree has no page.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::CalibrationStatus;
use plotly::box_plot::{BoxPoints, HoverOn};
use plotly::common::{Line, Marker, Mode, Title};
use plotly::layout::{AspectMode, Axis, AxisType, BoxMode, CategoryOrder, LayoutScene, Margin};
use plotly::{BoxPlot, Layout, Mesh3D, Plot, Scatter3D};
use serde_json::json;

use super::{Cell, Page, Table, drawn, significant};
use crate::manifest::{ReplayManifest, verify};
use crate::rows::parse_csv;
use crate::rows::replay_rows::{RealisationRow, ReplaySummaryRow, ReplayTrialRow, WholeLogRow};
use magcal_logs::limits::{self, excerpt};

/// The models' colours, in the order `replay --models` lists them by default; one colour per
/// model on every figure of the page.
const MODEL_COLOURS: [(&str, &str); 5] = [
    ("full", "#1f77b4"),
    ("diagonal", "#ff7f0e"),
    ("offset", "#2ca02c"),
    ("symmetric", "#d62728"),
    ("vector", "#9467bd"),
];

/// The designs' colours on the sphere, in turn.
const DESIGN_COLOURS: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79",
];

/// The figures of the distributions: the column of `trials.csv` (the metric of `summary.csv`),
/// its name on the page, its unit, and whether it needs the truth.
const METRICS: [(&str, &str, &str, bool); 4] = [
    ("heading_rms_deg", "heading rms against the reference", "degrees", false),
    ("eta_psi", "eta_psi, [P1] eq. (21)", "%", true),
    ("eta_s", "eta_S, [P1] eq. (22)", "%", true),
    ("eta_o", "eta_O, [P1] eq. (23)", "%", true),
];

/// The statuses counted in the outcome table, in the order of its columns.
const STATUSES: [CalibrationStatus; 7] = CalibrationStatus::ALL;

/// A replay set as read: its manifest and the rows of its four CSV files, every file's bytes
/// checked against the SHA-256 the manifest records.
struct ReplaySet {
    manifest: ReplayManifest,
    summary: Vec<ReplaySummaryRow>,
    trials: Vec<ReplayTrialRow>,
    realisation: Vec<RealisationRow>,
    whole_log: Vec<WholeLogRow>,
}

impl ReplaySet {
    /// Reads the set in `dir`.
    ///
    /// # Errors
    /// A manifest that is damaged or not a replay's, a file it does not record, or a file whose
    /// bytes are not the ones it records (edited since replay wrote it).
    fn read(dir: &Path) -> Result<Self> {
        let path = limits::set_member(dir, "manifest.json")?;
        let bytes = limits::read_bounded(&path, crate::manifest::MAX_MANIFEST_BYTES)?;
        verify(&path, &bytes)?;
        let manifest: ReplayManifest = serde_json::from_slice(&bytes).map_err(|e| {
            anyhow::anyhow!(
                "{}: not a magcal replay manifest: {}",
                path.display(),
                excerpt(&e.to_string(), 160)
            )
        })?;
        let file = |name: &str| super::sealed_bytes(dir, name, manifest.file_sha256.get(name), "replay");
        let (summary, s) = file("summary.csv")?;
        let (trials, t) = file("trials.csv")?;
        let (realisation, r) = file("realisation.csv")?;
        let (whole_log, w) = file("whole_log.csv")?;
        Ok(Self {
            summary: parse_csv(&summary, &s)?,
            trials: parse_csv(&trials, &t)?,
            realisation: parse_csv(&realisation, &r)?,
            whole_log: parse_csv(&whole_log, &w)?,
            manifest,
        })
    }

    /// A setting of the manifest, or the empty string.
    fn setting(&self, key: &str) -> &str {
        self.manifest.settings.get(key).map_or("", String::as_str)
    }

    /// The designs in the order of `summary.csv`, with their attitude count.
    fn designs(&self) -> Vec<(String, usize)> {
        let mut seen: Vec<(String, usize)> = Vec::new();
        for row in &self.summary {
            if !seen.iter().any(|(d, _)| *d == row.design) {
                seen.push((row.design.clone(), row.m));
            }
        }
        seen
    }

    /// The models in the order of `summary.csv`.
    fn models(&self) -> Vec<String> {
        let mut seen: Vec<String> = Vec::new();
        for row in &self.summary {
            if !seen.contains(&row.model) {
                seen.push(row.model.clone());
            }
        }
        seen
    }

    /// Whether the set was scored against a known truth (`--truth impose` or `scenario`).
    fn truth_known(&self) -> bool {
        !matches!(self.setting("truth"), "" | "none")
    }
}

/// The outcomes of one design and model, counted from `trials.csv`.
#[derive(Debug, Clone, Default, PartialEq)]
struct Outcomes {
    /// Trials per status, in the order of [`STATUSES`].
    by_status: [usize; STATUSES.len()],
    /// `ok` trials without a heading rms (none can be drawn).
    ok_without_heading: usize,
}

impl Outcomes {
    fn trials(&self) -> usize {
        self.by_status.iter().sum()
    }

    fn of(&self, status: CalibrationStatus) -> usize {
        STATUSES
            .iter()
            .position(|&s| s == status)
            .map_or(0, |i| self.by_status[i])
    }

    /// Trials without an estimate (`failed` in `summary.csv`).
    fn failed(&self) -> usize {
        STATUSES
            .iter()
            .zip(&self.by_status)
            .filter(|(s, _)| !s.has_estimate())
            .map(|(_, n)| n)
            .sum()
    }
}

/// The outcomes of every design and model in `trials.csv`, checked against the counts of
/// `summary.csv`.
///
/// # Errors
/// A row of `trials.csv` of a design or model `summary.csv` does not have, or counts that differ.
fn outcomes(set: &ReplaySet, dir: &Path) -> Result<BTreeMap<(String, String), Outcomes>> {
    let mut counted: BTreeMap<(String, String), Outcomes> = BTreeMap::new();
    for row in &set.summary {
        counted.entry((row.design.clone(), row.model.clone())).or_default();
    }
    let trials_csv = dir.join("trials.csv");
    for (i, row) in set.trials.iter().enumerate() {
        let Some(o) = counted.get_mut(&(row.design.clone(), row.model.clone())) else {
            bail!(
                "{}: line {}: design {:?} with model {:?}, which summary.csv does not have",
                trials_csv.display(),
                i + 2,
                excerpt(&row.design, 40),
                excerpt(&row.model, 40)
            );
        };
        let k = STATUSES.iter().position(|&s| s == row.status.0).unwrap_or(0);
        o.by_status[k] += 1;
        if row.status.0 == CalibrationStatus::Ok && row.heading_rms_deg.is_none() {
            o.ok_without_heading += 1;
        }
    }
    let summary_csv = dir.join("summary.csv");
    for row in &set.summary {
        let o = &counted[&(row.design.clone(), row.model.clone())];
        let pairs = [
            ("trials", row.trials, o.trials()),
            ("ok", row.ok, o.of(CalibrationStatus::Ok)),
            (
                "not_converged",
                row.not_converged,
                o.of(CalibrationStatus::NotConverged),
            ),
            (
                "not_identifiable",
                row.not_identifiable,
                o.of(CalibrationStatus::NotIdentifiable),
            ),
            ("failed", row.failed, o.failed()),
        ];
        for (column, said, found) in pairs {
            if said != found {
                bail!(
                    "{}: design {} model {} metric {}: {column} = {said}, but trials.csv has {found}",
                    summary_csv.display(),
                    excerpt(&row.design, 40),
                    excerpt(&row.model, 40),
                    excerpt(&row.metric, 40)
                );
            }
        }
    }
    Ok(counted)
}

/// The page of the replay set in `dir`.
///
/// # Errors
/// A set that cannot be read, whose files were edited since replay wrote them, or whose files
/// disagree.
pub fn page(dir: &Path) -> Result<Page> {
    let set = ReplaySet::read(dir)?;
    let counted = outcomes(&set, dir)?;
    let m = &set.manifest;
    let mut page = Page::new(
        format!("Replay of {} on {}", m.scenario, file_name(&m.log)),
        format!(
            "{} trials per design, models {}, truth {}, magcal {}",
            m.trials,
            set.setting("models"),
            set.setting("truth"),
            m.version
        ),
    );
    page.text(format!(
        "[P1]'s Monte Carlo (IV.C) on a real log: each design attitude is realised by a window of {} consecutive readings of the log whose field direction in the body frame lies within {} degrees of the design's; every trial draws one window per attitude, calibrates each model from the same held readings and scores it on {} of the log's other readings against their reference attitudes (heading rms) and, where the truth is known, against it (eta, [P1] eq. (21)-(23)).",
        set.setting("hold"),
        set.setting("within_deg"),
        set.setting("scoring_readings"),
    ));
    settings(&mut page, &set);
    outcome_table(&mut page, &set, &counted);
    distributions(&mut page, &set);
    realisation(&mut page, &set);
    whole_log_table(&mut page, &set);
    summary_table(&mut page, &set);
    page.data("manifest", serde_json::to_value(m).context("manifest.json")?);
    Ok(page)
}

/// The last part of a path as written in the manifest.
fn file_name(log: &str) -> &str {
    log.rsplit(['/', '\\']).next().unwrap_or(log)
}

/// A setting as a number where it is one, else as text.
fn setting_cell(value: &str) -> Cell {
    // Whole numbers (counts, seeds) in full; others with 6 significant digits.
    if let Ok(n) = value.parse::<i64>() {
        return Cell {
            text: n.to_string(),
            value: Some(n as f64),
        };
    }
    match value.parse::<f64>() {
        Ok(v) if v.is_finite() && v.fract() == 0.0 && v.abs() < 1e15 => Cell {
            text: format!("{v:.0}"),
            value: Some(v),
        },
        Ok(v) if v.is_finite() && !value.is_empty() => Cell {
            text: significant(v, 6),
            value: Some(v),
        },
        _ => Cell::text(value),
    }
}

fn settings(page: &mut Page, set: &ReplaySet) {
    let m = &set.manifest;
    let mut rows = vec![
        vec![Cell::text("scenario"), Cell::text(&m.scenario_path)],
        vec![Cell::text("log"), Cell::text(&m.log)],
        vec![Cell::text("log SHA-256"), Cell::text(&m.log_sha256)],
        vec![Cell::text("seed"), Cell::text(m.seed.to_string())],
        vec![Cell::text("trials per design"), Cell::count(m.trials)],
    ];
    for (key, value) in &m.settings {
        rows.push(vec![Cell::text(key), setting_cell(value)]);
    }
    page.heading("Settings");
    page.text(format!(
        "A held attitude is the mean of {} readings: white noise would leave {} nT on it; measured against the whole log's calibration it carries {} nT; the verdicts rest on {} nT.",
        set.setting("hold"),
        short(set.setting("white_held_noise_nt")),
        short(set.setting("measured_held_error_nt")),
        short(set.setting("held_noise_nt")),
    ));
    page.table(Table {
        id: "settings".into(),
        caption: "What the set was made from and with, as manifest.json records it (nT where a name ends in _nt, degrees in _deg)".into(),
        header: ["setting", "value"].map(String::from).to_vec(),
        rows,
    });
}

/// A number of the manifest's settings with 4 significant digits, or "-".
fn short(value: &str) -> String {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map_or_else(|| "-".to_string(), |v| significant(v, 4))
}

/// Why a design has no trials: its first attitude without a window of the log.
fn not_realised(set: &ReplaySet, design: &str) -> String {
    set.realisation
        .iter()
        .find(|r| r.design == design && r.candidates == 0)
        .map_or_else(
            || "no trials".to_string(),
            |r| {
                format!(
                    "not realised: attitude {} has no window of the log within {} degrees",
                    r.point,
                    set.setting("within_deg")
                )
            },
        )
}

fn outcome_table(page: &mut Page, set: &ReplaySet, counted: &BTreeMap<(String, String), Outcomes>) {
    let mut header: Vec<String> = ["design", "m", "model", "trials"].map(String::from).to_vec();
    header.extend(STATUSES.iter().map(|s| s.as_str().replace('_', " ")));
    header.push("drawn".into());
    header.push("remark".into());
    let mut rows = Vec::new();
    for (design, m) in set.designs() {
        for model in set.models() {
            let Some(o) = counted.get(&(design.clone(), model.clone())) else {
                continue;
            };
            let mut row = vec![
                Cell::text(&design),
                Cell::count(m),
                Cell::text(&model),
                Cell::count(o.trials()),
            ];
            row.extend(o.by_status.iter().map(|&n| Cell::count(n)));
            let ok = o.of(CalibrationStatus::Ok);
            row.push(Cell::count(ok - o.ok_without_heading));
            let remark = if o.trials() == 0 {
                not_realised(set, &design)
            } else if o.ok_without_heading > 0 {
                format!("{} ok trials without a heading rms", o.ok_without_heading)
            } else {
                String::new()
            };
            row.push(Cell::text(remark));
            rows.push(row);
        }
    }
    page.heading("Outcomes of the trials");
    page.table(Table {
        id: "outcomes".into(),
        caption: "Per design and model, the trials of trials.csv by outcome: ok (a calibration to use), not converged and not identifiable (an estimate the verdict refuses), and the failures without an estimate; 'drawn' counts the ok trials with a heading rms, which the figures below draw".into(),
        header,
        rows,
    });
}

/// The colour of `model` on every figure.
fn model_colour(model: &str, index: usize) -> &'static str {
    MODEL_COLOURS
        .iter()
        .find(|(m, _)| *m == model)
        .map_or(DESIGN_COLOURS[index % DESIGN_COLOURS.len()], |(_, c)| c)
}

/// A trial row's value of `column` (a column of [`METRICS`]).
fn value_of(row: &ReplayTrialRow, column: &str) -> Option<f64> {
    let v = match column {
        "heading_rms_deg" => row.heading_rms_deg,
        "eta_psi" => row.eta_psi,
        "eta_s" => row.eta_s,
        "eta_o" => row.eta_o,
        _ => None,
    };
    v.map(|r| r.0)
}

/// The whole log's value of `column`.
fn whole_value_of(row: &WholeLogRow, column: &str) -> Option<f64> {
    let v = match column {
        "heading_rms_deg" => row.heading_rms_deg,
        "eta_psi" => row.eta_psi,
        "eta_s" => row.eta_s,
        "eta_o" => row.eta_o,
        _ => None,
    };
    v.map(|r| r.0)
}

fn distributions(page: &mut Page, set: &ReplaySet) {
    page.heading("Distributions over the trials");
    let mut drawn_counts = serde_json::Map::new();
    for (column, name, unit, needs_truth) in METRICS {
        if needs_truth && !set.truth_known() {
            page.note(format!(
                "No figure of {name}: the truth is not known (--truth {}), so the set has no eta.",
                set.setting("truth")
            ));
            continue;
        }
        let figure = distribution(set, column, name, unit);
        let id = format!("dist-{}", column.replace('_', "-"));
        page.figure(&id, figure.figure, 480, figure.caption);
        if let Some(note) = figure.note {
            page.note(note);
        }
        drawn_counts.insert(column.to_string(), json!(figure.per_trace));
    }
    page.data("drawn", serde_json::Value::Object(drawn_counts));
}

/// A distribution figure, what it says, and the values drawn per model and design.
struct Distribution {
    figure: serde_json::Value,
    caption: String,
    note: Option<String>,
    per_trace: BTreeMap<String, BTreeMap<String, usize>>,
}

fn distribution(set: &ReplaySet, column: &str, name: &str, unit: &str) -> Distribution {
    let designs = set.designs();
    let mut plot = Plot::new();
    // The category of each trace: one trace per model and design (the design its `x0`, not a
    // name per point, which was 40 % of the figure's bytes), grouped by model.
    let mut positions = Vec::new();
    let mut per_trace = BTreeMap::new();
    let (mut non_finite, mut non_positive) = (0usize, 0usize);
    let mut trial_values = 0usize;
    for (k, model) in set.models().iter().enumerate() {
        let colour = model_colour(model, k);
        let mut by_design: BTreeMap<&str, (Vec<f64>, Vec<String>)> = BTreeMap::new();
        let mut counts = BTreeMap::new();
        for row in set.trials.iter().filter(|r| r.model == *model) {
            if row.status.0 != CalibrationStatus::Ok {
                continue;
            }
            let Some(v) = value_of(row, column) else { continue };
            if !v.is_finite() {
                non_finite += 1;
                continue;
            }
            non_positive += usize::from(v <= 0.0);
            let (y, text) = by_design.entry(row.design.as_str()).or_default();
            y.push(drawn(v));
            text.push(format!("trial {}", row.trial));
            *counts.entry(row.design.clone()).or_insert(0usize) += 1;
            trial_values += 1;
        }
        let mut traces: Vec<(String, Vec<f64>, Vec<String>)> = designs
            .iter()
            .filter_map(|(d, _)| {
                let (y, text) = by_design.remove(d.as_str())?;
                Some((d.clone(), y, text))
            })
            .collect();
        // A design of trials.csv that summary.csv lacks (the page refuses such a set before) is
        // still drawn, after the others.
        traces.extend(by_design.into_iter().map(|(d, (y, text))| (d.to_string(), y, text)));
        if let Some(w) = set.whole_log.iter().find(|w| w.model == *model)
            && let Some(v) = whole_value_of(w, column).filter(|v| v.is_finite())
        {
            non_positive += usize::from(v <= 0.0);
            traces.push((
                WHOLE_LOG.to_string(),
                vec![drawn(v)],
                vec![format!(
                    "the whole log's calibration ({} readings, {})",
                    w.readings, w.status.0
                )],
            ));
        }
        per_trace.insert(model.clone(), counts);
        for (t, (design, y, text)) in traces.into_iter().enumerate() {
            let trace = BoxPlot::new(y)
                .name(model)
                .legend_group(model)
                .show_legend(t == 0)
                .alignment_group("models")
                .offset_group(model)
                .box_points(BoxPoints::All)
                .jitter(0.4)
                .point_pos(0.0)
                .hover_on(HoverOn::BoxesAndPoints)
                // The hover shows the design (the box's place) itself: the text names only the
                // trial.
                .text_array(text)
                .marker(Marker::new().size(3).color(colour).opacity(0.6))
                .line(Line::new().color(colour).width(1.2));
            plot.add_trace(trace);
            positions.push(design);
        }
    }
    let log = non_positive == 0 && trial_values > 0;
    let mut categories: Vec<String> = designs.into_iter().map(|(d, _)| d).collect();
    categories.push(WHOLE_LOG.to_string());
    plot.set_layout(distribution_layout(categories, &format!("{name} ({unit}"), log));
    let caption = format!(
        "{name} ({unit}) of every ok trial, per design (one box per model: median, quartiles and whiskers, every trial a point; hover for its trial), as [P1] Figs. 1-3 draw eta per design; at the right the whole log's own calibration by each model (its status in the table of the whole log below). Trials that are not ok are counted in the table above, not drawn; summary.csv's statistics are over the same ok trials."
    );
    let note = (non_finite > 0)
        .then(|| format!("{non_finite} ok trials have a {name} that is not a finite number; not drawn."));
    // plotly's typed box trace has no `x0`: it is set in the JSON.
    let mut figure = super::figure_json(plot);
    for (trace, design) in figure["data"].as_array_mut().into_iter().flatten().zip(positions) {
        trace["x0"] = json!(design);
    }
    Distribution {
        figure,
        caption,
        note,
        per_trace,
    }
}

/// The layout of a distribution figure: the designs and the whole log as categories in their
/// order, the boxes of the models side by side, the y axis titled `{what}` and logarithmic where
/// `log`.
fn distribution_layout(categories: Vec<String>, what: &str, log: bool) -> Layout {
    let span = vec![-0.5, categories.len() as f64 - 0.5];
    Layout::new()
        .box_mode(BoxMode::Group)
        .x_axis(
            Axis::new()
                .title(Title::with_text("design"))
                .category_order(CategoryOrder::Array)
                .category_array(categories)
                .range(span),
        )
        .y_axis(
            Axis::new()
                .title(Title::with_text(format!(
                    "{what}{})",
                    if log { ", log scale" } else { "" }
                )))
                .type_(if log { AxisType::Log } else { AxisType::Linear }),
        )
        .margin(Margin::new().top(30).bottom(60))
}

/// The category of the whole log's values on the distribution figures.
const WHOLE_LOG: &str = "whole log";

/// Points of the circle at `angle_deg` around the unit vector `u` on the unit sphere.
fn ring(u: [f64; 3], angle_deg: f64, points: usize) -> Vec<[f64; 3]> {
    let helper = if u[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let unit = |a: [f64; 3]| {
        let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        a.map(|c| c / n)
    };
    let e1 = unit(cross(u, helper));
    let e2 = cross(u, e1);
    let (s, c) = angle_deg.to_radians().sin_cos();
    (0..=points)
        .map(|k| {
            let (sp, cp) = (std::f64::consts::TAU * k as f64 / points as f64).sin_cos();
            std::array::from_fn(|i| c * u[i] + s * (cp * e1[i] + sp * e2[i]))
        })
        .collect()
}

/// A 3D line or set of points with gaps (`None`) between its pieces.
type Gapped3D = Scatter3D<Option<f64>, Option<f64>, Option<f64>>;

/// The hover text of one design attitude.
fn attitude_text(r: &RealisationRow, within: &str) -> String {
    let spread = match (r.nearest_deg, r.median_deg, r.farthest_deg) {
        (Some(a), Some(b), Some(c)) => format!(
            "{} windows within {within} deg: nearest {}, median {}, farthest {} deg",
            r.candidates,
            significant(a.0, 3),
            significant(b.0, 3),
            significant(c.0, 3)
        ),
        _ => format!("no window of the log within {within} deg"),
    };
    format!(
        "{} attitude {}: roll {}, pitch {}, yaw {} deg (before turning by {} deg), {} reading(s); {spread}",
        r.design,
        r.point,
        significant(r.roll_deg.0, 4),
        significant(r.pitch_deg.0, 4),
        significant(r.yaw_deg.0, 4),
        significant(r.turned_deg.0, 4),
        r.readings
    )
}

/// The design attitudes of one design on the sphere, and the rings inside which the log's
/// windows realise them (one line, broken between rings).
fn design_traces(rows: &[&RealisationRow], design: &str, colour: &'static str, within: &str) -> [Box<Gapped3D>; 2] {
    let pick = |i: usize| {
        rows.iter()
            .map(|r| Some(drawn([r.ux.0, r.uy.0, r.uz.0][i])))
            .collect::<Vec<_>>()
    };
    let text: Vec<String> = rows.iter().map(|r| attitude_text(r, within)).collect();
    let points = Scatter3D::new(pick(0), pick(1), pick(2))
        .mode(Mode::Markers)
        .name(design)
        .legend_group(design)
        .text_array(text)
        .hover_info(plotly::common::HoverInfo::Text)
        .marker(Marker::new().size(5).color(colour));
    let mut line: [Vec<Option<f64>>; 3] = Default::default();
    for r in rows {
        let Some(far) = r.farthest_deg else { continue };
        for p in ring([r.ux.0, r.uy.0, r.uz.0], far.0, 36) {
            for i in 0..3 {
                line[i].push(Some(drawn(p[i])));
            }
        }
        for column in &mut line {
            column.push(None);
        }
    }
    let [x, y, z] = line;
    let rings = Scatter3D::new(x, y, z)
        .mode(Mode::Lines)
        .name(format!("{design}: windows"))
        .legend_group(design)
        .show_legend(false)
        .hover_info(plotly::common::HoverInfo::Skip)
        .line(Line::new().color(colour).width(2.0));
    [points, rings]
}

fn realisation(page: &mut Page, set: &ReplaySet) {
    let within = set.setting("within_deg").to_string();
    let mut plot = Plot::new();
    let (sphere, triangles) = super::calibration::unit_sphere(18, 36);
    let col = |i: usize| sphere.iter().map(|p| drawn(0.99 * p[i])).collect::<Vec<f64>>();
    let tri = |i: usize| Some(triangles.iter().map(|t| t[i]).collect::<Vec<usize>>());
    plot.add_trace(
        Mesh3D::new(col(0), col(1), col(2), tri(0), tri(1), tri(2))
            .name("unit sphere")
            .opacity(0.12)
            .color("#888888")
            .hover_info(plotly::common::HoverInfo::Skip),
    );
    let mut missing = Vec::new();
    for (k, (design, _)) in set.designs().iter().enumerate() {
        let rows: Vec<&RealisationRow> = set.realisation.iter().filter(|r| r.design == *design).collect();
        missing.extend(rows.iter().filter(|r| r.candidates == 0).map(|r| (*r).clone()));
        for trace in design_traces(&rows, design, DESIGN_COLOURS[k % DESIGN_COLOURS.len()], &within) {
            plot.add_trace(trace);
        }
    }
    if !missing.is_empty() {
        let refs: Vec<&RealisationRow> = missing.iter().collect();
        let [points, _] = design_traces(&refs, "no window", "#000000", &within);
        plot.add_trace(
            points.marker(
                Marker::new()
                    .size(9)
                    .color("#000000")
                    .symbol(plotly::common::MarkerSymbol::DiamondOpen),
            ),
        );
    }
    let axis = |name: &str| Axis::new().title(Title::with_text(name)).range(vec![-1.1, 1.1]);
    plot.set_layout(
        Layout::new()
            .scene(
                LayoutScene::new()
                    .aspect_mode(AspectMode::Cube)
                    .x_axis(axis("forward"))
                    .y_axis(axis("right"))
                    .z_axis(axis("down")),
            )
            .margin(Margin::new().left(0).right(0).top(30).bottom(0)),
    );
    page.heading("The design attitudes and the log's windows that realise them");
    page.plot("realisation", plot, 640, format!(
        "Each design attitude as the field direction it asks for in the body frame (forward, right, down; unit vectors), after the design was turned as a whole to the log's coverage (--orient), as realisation.csv gives them; around each, the circle inside which lie all the log's windows that a trial may draw for it (at most {within} degrees away; hover a point for their count and nearest, median and farthest angle). Attitudes with no window are black crosses. The log's readings themselves are not part of the set. A design drawn at random with --random redraw (this set: {}) is drawn afresh in every trial: its points are the scenario's one draw. Click a design in the legend to hide it.",
        set.setting("random")
    ));
    page.data("realisation_points", json!(set.realisation.len()));
}

fn whole_log_table(page: &mut Page, set: &ReplaySet) {
    let header = [
        "model",
        "readings",
        "status",
        "heading rms (deg)",
        "heading p95 (deg)",
        "heading max (deg)",
        "direction rms (deg)",
        "heading rms, alignment held (deg)",
        "direction rms, alignment held (deg)",
        "eta_psi (%)",
        "eta_S (%)",
        "eta_O (%)",
        "rms residual (nT)",
    ];
    let n = |v: Option<crate::rows::Real>| Cell::maybe(v.map(|r| r.0), 4);
    let rows = set
        .whole_log
        .iter()
        .map(|w| {
            vec![
                Cell::text(&w.model),
                Cell::count(w.readings),
                Cell::text(w.status.0.as_str()),
                n(w.heading_rms_deg),
                n(w.heading_p95_deg),
                n(w.heading_max_deg),
                n(w.direction_rms_deg),
                n(w.heading_rms_held_deg),
                n(w.direction_rms_held_deg),
                n(w.eta_psi),
                n(w.eta_s),
                n(w.eta_o),
                n(w.rms_residual_nt),
            ]
        })
        .collect();
    page.heading("The whole log's own calibration");
    page.table(Table {
        id: "whole-log".into(),
        caption: "Each model's calibration of all the log's readings, scored as the trials are (whole_log.csv): heading and direction errors against the reference attitudes, eta against the truth where it is known, and the rms of |b| - R".into(),
        header: header.map(String::from).to_vec(),
        rows,
    });
}

fn summary_table(page: &mut Page, set: &ReplaySet) {
    let header = [
        "design",
        "m",
        "model",
        "trials",
        "ok",
        "not converged",
        "not identifiable",
        "failed",
        "metric",
        "mean",
        "std",
        "median",
        "p05",
        "p95",
        "se of mean",
        "rms",
    ];
    let n = |v: Option<crate::rows::Real>| Cell::maybe(v.map(|r| r.0), 4);
    let rows = set
        .summary
        .iter()
        .map(|s| {
            vec![
                Cell::text(&s.design),
                Cell::count(s.m),
                Cell::text(&s.model),
                Cell::count(s.trials),
                Cell::count(s.ok),
                Cell::count(s.not_converged),
                Cell::count(s.not_identifiable),
                Cell::count(s.failed),
                Cell::text(&s.metric),
                n(s.mean),
                n(s.std),
                n(s.median),
                n(s.p05),
                n(s.p95),
                n(s.se_mean),
                n(s.rms),
            ]
        })
        .collect();
    page.heading("summary.csv");
    page.table(Table {
        id: "summary".into(),
        caption: "Per design, model and metric, the outcome counts and the statistics over the ok trials, as summary.csv holds them (metrics ending in _deg in degrees, eta in %; p05 and p95 the 5th and 95th percentiles, se of mean the standard error of the mean)".into(),
        header: header.map(String::from).to_vec(),
        rows,
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pages::Block;
    use magcal_logs::digest::sha256_hex;

    /// A copy of the shipped `results/replay-handheld-10` in a temporary directory, with `edit`
    /// applied to its manifest and files and the manifest sealed again over the edited files.
    fn resealed(edit: impl FnOnce(&mut ReplayManifest, &mut BTreeMap<String, String>)) -> tempfile::TempDir {
        let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results/replay-handheld-10");
        let tmp = tempfile::TempDir::new().unwrap();
        let bytes = std::fs::read(from.join("manifest.json")).unwrap();
        let mut manifest: ReplayManifest = serde_json::from_slice(&bytes).unwrap();
        let mut files: BTreeMap<String, String> = manifest
            .files
            .iter()
            .map(|f| (f.clone(), std::fs::read_to_string(from.join(f)).unwrap()))
            .collect();
        edit(&mut manifest, &mut files);
        for (name, text) in &files {
            std::fs::write(tmp.path().join(name), text).unwrap();
            manifest.file_sha256.insert(name.clone(), sha256_hex(text.as_bytes()));
        }
        manifest.manifest_sha256 = None;
        std::fs::write(tmp.path().join("manifest.json"), manifest.to_bytes().unwrap()).unwrap();
        tmp
    }

    #[test]
    fn a_ring_lies_at_its_angle_around_its_direction() {
        let u = [0.6, -0.48, 0.64];
        for angle in [0.5, 10.0, 90.0] {
            for p in ring(u, angle, 36) {
                let dot = p[0] * u[0] + p[1] * u[1] + p[2] * u[2];
                let norm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                assert!((norm - 1.0).abs() < 8.0 * f64::EPSILON, "{norm}");
                assert!(
                    (dot - angle.to_radians().cos()).abs() < 8.0 * f64::EPSILON,
                    "{dot} at {angle}"
                );
            }
        }
    }

    #[test]
    fn the_shipped_set_reads_and_its_counts_agree() {
        let dir = resealed(|_, _| {});
        let page = page(dir.path()).unwrap();
        let plots: Vec<&str> = page
            .blocks
            .iter()
            .filter_map(|b| match b {
                Block::Plot { id, .. } => Some(id.as_str()),
                _ => None,
            })
            .collect();
        assert_eq!(
            plots,
            [
                "dist-heading-rms-deg",
                "dist-eta-psi",
                "dist-eta-s",
                "dist-eta-o",
                "realisation"
            ]
        );
    }

    #[test]
    fn without_the_truth_the_page_draws_no_eta_and_says_why() {
        let dir = resealed(|m, _| {
            m.settings.insert("truth".into(), "none".into());
        });
        let page = page(dir.path()).unwrap();
        let plots = page
            .blocks
            .iter()
            .filter(|b| matches!(b, Block::Plot { id, .. } if id.starts_with("dist-eta")))
            .count();
        assert_eq!(plots, 0);
        let said = page
            .blocks
            .iter()
            .filter(|b| matches!(b, Block::Note(t) if t.contains("the truth is not known (--truth none)")))
            .count();
        assert_eq!(said, 3, "one note per eta");
    }

    #[test]
    fn a_summary_that_does_not_count_what_trials_csv_holds_is_refused() {
        let dir = resealed(|_, files| {
            let summary = files.get_mut("summary.csv").unwrap();
            *summary = summary.replacen("random9,9,symmetric,200,6,", "random9,9,symmetric,200,7,", 1);
        });
        let e = format!("{:#}", page(dir.path()).unwrap_err());
        assert!(e.contains("summary.csv"), "{e}");
        assert!(
            e.contains("random9 model symmetric metric heading_rms_deg: ok = 7, but trials.csv has 6"),
            "{e}"
        );
    }
}

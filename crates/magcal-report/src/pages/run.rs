//! The page of a `design` or `run` set: the recommendation, the flight plans ([`super::plan`]),
//! the summary of the trials as `summary.csv` holds it, the noise sweep as an interactive figure
//! when the set has several noise levels, and the set's own figures (`plots/*.svg`) inlined as
//! they are.
//!
//! Every file the page reads is checked against the SHA-256 the set's manifest recorded for it,
//! so that the page shows the set as it was written or is not made.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use plotly::common::{DashType, ErrorData, ErrorType, Line, Marker, Mode, Title, Visible};
use plotly::layout::update_menu::{Button, ButtonMethod, UpdateMenu};
use plotly::layout::{Axis, AxisType, Margin};
use plotly::{Layout, Plot, Scatter, Trace};
use serde::de::DeserializeOwned;
use serde_json::json;

use super::plan::{self, Plan};
use super::{Block, Cell, Page, Table, drawn, significant};
use crate::manifest::Manifest;
use crate::rows::Metric;
use crate::rows::{CertificateRow, DesignMetricsRow, DesignPointRow, SummaryRow, parse_csv};

/// Colours of the sweep's series (plotly's own cycle).
const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
];

/// The page of the `design` or `run` set in `dir`.
///
/// # Errors
/// A set whose manifest or files cannot be read, whose files differ from the SHA-256 its manifest
/// recorded, or whose files disagree with one another; a figure that cannot be drawn.
pub fn page(dir: &Path) -> Result<Page> {
    let (manifest, _) = Manifest::read(dir)?;
    let designs_path = dir.join("designs.csv");
    let plans = plan::plans(member::<DesignPointRow>(dir, &manifest, "designs.csv")?, &designs_path)?;
    let metrics: Vec<DesignMetricsRow> = member(dir, &manifest, "design_metrics.csv")?;
    agree(dir, &plans, &metrics)?;
    let certificate: Vec<CertificateRow> = member(dir, &manifest, "certificate.csv")?;
    if certificate.len() > 1 {
        bail!(
            "{}: {} rows; a certificate has one",
            dir.join("certificate.csv").display(),
            certificate.len()
        );
    }
    let summary: Option<Vec<SummaryRow>> = if manifest.lists("summary.csv") {
        Some(member(dir, &manifest, "summary.csv")?)
    } else {
        None
    };
    let figures = figures(dir, &manifest)?;
    let trials = if summary.is_some() {
        format!("{} trials per design and noise level", manifest.trials)
    } else {
        "a design set: each design checked by its own noisy trials (the verdicts), no statistics of the scenario's trials".to_string()
    };
    let mut page = Page::new(
        format!("Designs of {}", manifest.name),
        format!(
            "{} ({}; seed {}; {}; magcal {})",
            manifest.description,
            manifest.scenario,
            manifest.seed,
            trials,
            manifest.crates.first().map_or("?", |c| c.1.as_str())
        ),
    );
    verdict(&mut page, &metrics);
    plan::section(&mut page, &plans, &metrics, certificate.first());
    if let Some(summary) = &summary {
        summary_table(&mut page, summary);
        sweep(&mut page, summary);
    }
    page.heading("The set's figures");
    page.note(format!(
        "The {} figures of the set, drawn from its sealed files as `magcal plot` draws them into {} (the set's own SVG files are not read: they are not sealed).",
        figures.len(),
        dir.join("plots").display()
    ));
    for (stem, svg) in &figures {
        use base64::Engine;
        page.push(Block::Image {
            id: format!("figure-{stem}"),
            svg: base64::engine::general_purpose::STANDARD.encode(svg),
            caption: caption(stem),
        });
    }
    page.data("manifest", serde_json::to_value(&manifest).context("manifest.json")?);
    page.data("figures", json!(figures.iter().map(|f| &f.0).collect::<Vec<_>>()));
    Ok(page)
}

/// The rows of the set's file `name`, which its manifest must list and whose SHA-256 must be the
/// one it recorded.
fn member<T: DeserializeOwned>(dir: &Path, manifest: &Manifest, name: &str) -> Result<Vec<T>> {
    if !manifest.lists(name) {
        bail!("{}: does not list {name}", dir.join("manifest.json").display());
    }
    let (bytes, shown) = super::sealed_bytes(dir, name, manifest.file_sha256.get(name), "magcal run")?;
    parse_csv(&bytes, &shown)
}

/// `designs.csv` and `design_metrics.csv` name the same designs in the same order.
fn agree(dir: &Path, plans: &[Plan], metrics: &[DesignMetricsRow]) -> Result<()> {
    let a: Vec<&str> = plans.iter().map(|p| p.design.as_str()).collect();
    let b: Vec<&str> = metrics.iter().map(|m| m.design.as_str()).collect();
    if a != b {
        bail!(
            "{}: designs {} differ from designs.csv's {}",
            dir.join("design_metrics.csv").display(),
            short_list(&b),
            short_list(&a)
        );
    }
    for (p, m) in plans.iter().zip(metrics) {
        let readings: usize = p.rows.iter().map(|r| r.readings).sum();
        if readings != m.m {
            bail!(
                "{}: design {} has m = {}, but its rows in designs.csv plan {readings} readings",
                dir.join("design_metrics.csv").display(),
                m.design.chars().take(40).collect::<String>(),
                m.m
            );
        }
    }
    Ok(())
}

/// A list of names for a message, at most 80 characters.
fn short_list(names: &[&str]) -> String {
    let text = format!("[{}]", names.join(", "));
    if text.chars().count() > 80 {
        format!("{}...", text.chars().take(77).collect::<String>())
    } else {
        text
    }
}

/// The design the set recommends flying, or that none works.
fn verdict(page: &mut Page, metrics: &[DesignMetricsRow]) {
    let text = match metrics.iter().find(|m| m.recommended) {
        Some(m) => format!(
            "RECOMMENDED: design {} ({} readings; certified D-efficiency at least {}; its check: {} of {} trials at {} nT ok)",
            m.design,
            m.m,
            m.d_efficiency_bound.map_or("-".to_string(), |b| significant(b.0, 4)),
            m.check_ok,
            m.check_trials,
            significant(m.check_sigma_nt.0, 4)
        ),
        None if metrics.iter().any(|m| m.works) => {
            let fewest = magcal_core::log_fit::min_held_out_readings(magcal_core::log_fit::FitModel::Full);
            let names: Vec<&str> = metrics.iter().filter(|m| m.works).map(|m| m.design.as_str()).collect();
            format!(
                "NONE RECOMMENDED AS IT STANDS: {} {} by the check, but a log of fewer than {fewest} readings holds no fifth out to vouch for its calibration; fly its attitudes as a plan (kind = \"plan\", readings = 100 or more)",
                names.join(", "),
                if names.len() == 1 { "works" } else { "work" }
            )
        }
        None => "NO DESIGN WORKS: no design of this set passed its check with the heading within its budget (see the designs table, and advice.csv where the set has one)".to_string(),
    };
    page.push(Block::Verdict {
        good: metrics.iter().any(|m| m.recommended),
        text,
    });
}

/// `summary.csv` as it is, one row per design, noise level and metric.
fn summary_table(page: &mut Page, summary: &[SummaryRow]) {
    let n = |v: Option<crate::rows::Real>| Cell::maybe(v.map(|r| r.0), 4);
    let rows = summary
        .iter()
        .map(|r| {
            vec![
                Cell::text(&r.design),
                Cell::number(r.sigma_nt.0, 6),
                Cell::number(r.attitude_sigma_deg.0, 6),
                Cell::text(r.metric.as_str()),
                Cell::count(r.trials),
                Cell::count(r.ok),
                Cell::count(r.not_converged),
                Cell::count(r.not_identifiable),
                Cell::count(r.failed),
                n(r.mean),
                n(r.std),
                n(r.median),
                n(r.p05),
                n(r.p95),
                n(r.se_mean),
                n(r.rms),
                n(r.crb_rms),
            ]
        })
        .collect();
    page.heading("Summary of the trials");
    page.table(Table {
        id: "summary".into(),
        caption: "summary.csv: per design, noise level (nT), execution error (degrees) and metric, the trials' outcomes and the statistics over the ok trials; crb_rms is the Cramer-Rao prediction of the rms".into(),
        header: [
            "design", "sigma (nT)", "attitude sigma (deg)", "metric", "trials", "ok", "not converged",
            "not identifiable", "failed", "mean", "std", "median", "p05", "p95", "se of mean", "rms",
            "crb rms",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    });
}

/// A series of the sweep: a design, flown with an execution error or not.
fn series_name(r: &SummaryRow) -> String {
    if r.attitude_sigma_deg.0 > 0.0 {
        format!("{} flown +-{} deg", r.design, r.attitude_sigma_deg.0)
    } else {
        r.design.clone()
    }
}

/// The traces of one metric: per series, the median with the middle 90 % of the trials, and the
/// Cramer-Rao prediction of the rms; whether its values span more than a decade; cells not drawn.
struct MetricTraces {
    traces: Vec<Box<dyn Trace>>,
    log_y: bool,
    missing: usize,
}

fn metric_traces(summary: &[SummaryRow], metric: Metric, shown: bool) -> MetricTraces {
    let mut series: BTreeMap<(usize, String), Vec<&SummaryRow>> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    let mut missing = 0;
    for r in summary.iter().filter(|r| r.metric == metric) {
        let name = series_name(r);
        if !order.contains(&name) {
            order.push(name.clone());
        }
        let finite = |v: Option<crate::rows::Real>| v.is_some_and(|x| x.0.is_finite() && x.0 > 0.0);
        if finite(r.median) && finite(r.p05) && finite(r.p95) && r.sigma_nt.0 > 0.0 {
            let k = order.iter().position(|o| *o == name).unwrap_or(0);
            series.entry((k, name)).or_default().push(r);
        } else {
            missing += 1;
        }
    }
    let visible = if shown { Visible::True } else { Visible::False };
    let mut traces = Vec::new();
    let mut values = Vec::new();
    for ((k, name), mut rows) in series {
        rows.sort_by(|a, b| a.sigma_nt.0.total_cmp(&b.sigma_nt.0));
        let colour = PALETTE[k % PALETTE.len()];
        series_traces(&name, colour, &rows, &visible, &mut traces, &mut values);
    }
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite() && **v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(*v), b.max(*v)));
    MetricTraces {
        traces,
        log_y: hi > 10.0 * lo,
        missing,
    }
}

/// The traces of one series of a metric (its rows by noise level) into `traces`, and the values
/// they draw into `values`.
fn series_traces(
    name: &str,
    colour: &'static str,
    rows: &[&SummaryRow],
    visible: &Visible,
    traces: &mut Vec<Box<dyn Trace>>,
    values: &mut Vec<f64>,
) {
    let get = |f: fn(&SummaryRow) -> Option<crate::rows::Real>| {
        rows.iter()
            .map(|r| f(r).map_or(f64::NAN, |v| v.0))
            .collect::<Vec<f64>>()
    };
    let (median, p05, p95) = (get(|r| r.median), get(|r| r.p05), get(|r| r.p95));
    values.extend(p05.iter().chain(&p95).copied());
    let x: Vec<f64> = rows.iter().map(|r| r.sigma_nt.0).collect();
    let text: Vec<String> = rows
        .iter()
        .map(|r| {
            format!(
                "{name}: {} of {} trials ok; mean {}, rms {}",
                r.ok,
                r.trials,
                r.mean.map_or("-".into(), |v| significant(v.0, 4)),
                r.rms.map_or("-".into(), |v| significant(v.0, 4))
            )
        })
        .collect();
    traces.push(
        Scatter::new(x.clone(), median.iter().map(|v| drawn(*v)).collect())
            .mode(Mode::LinesMarkers)
            .name(format!("{name}: median"))
            .text_array(text)
            .line(Line::new().color(colour))
            .marker(Marker::new().color(colour))
            .error_y(
                ErrorData::new(ErrorType::Data)
                    .array(p95.iter().zip(&median).map(|(a, m)| drawn(a - m)).collect())
                    .array_minus(median.iter().zip(&p05).map(|(m, a)| drawn(m - a)).collect())
                    .color(colour),
            )
            .visible(visible.clone()),
    );
    let crb: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|r| {
            r.crb_rms
                .map(|c| (r.sigma_nt.0, c.0))
                .filter(|c| c.1.is_finite() && c.1 > 0.0)
        })
        .collect();
    if !crb.is_empty() {
        values.extend(crb.iter().map(|c| c.1));
        traces.push(
            Scatter::new(
                crb.iter().map(|c| c.0).collect(),
                crb.iter().map(|c| drawn(c.1)).collect(),
            )
            .mode(Mode::Lines)
            .name(format!("{name}: Cramer-Rao rms"))
            .line(Line::new().color(colour).dash(DashType::Dash))
            .visible(visible.clone()),
        );
    }
}

/// The noise sweep, one metric at a time behind a dropdown, when the set has several noise levels.
fn sweep(page: &mut Page, summary: &[SummaryRow]) {
    let mut sigmas: Vec<f64> = summary.iter().map(|r| r.sigma_nt.0).filter(|s| *s > 0.0).collect();
    sigmas.sort_by(f64::total_cmp);
    sigmas.dedup();
    if sigmas.len() < 2 {
        return;
    }
    let mut plot = Plot::new();
    let mut per_metric = Vec::new();
    for (i, metric) in Metric::ALL.into_iter().enumerate() {
        let t = metric_traces(summary, metric, i == 0);
        per_metric.push((metric, t.traces.len(), t.log_y, t.missing));
        for trace in t.traces {
            plot.add_trace(trace);
        }
    }
    let y_axis = |metric: Metric, log: bool| json!({"yaxis.type": if log { "log" } else { "linear" }, "yaxis.title.text": metric.label()});
    let buttons: Vec<Button> = per_metric
        .iter()
        .enumerate()
        .map(|(i, &(metric, _, log, _))| {
            let visible: Vec<bool> = per_metric
                .iter()
                .enumerate()
                .flat_map(|(j, m)| std::iter::repeat_n(i == j, m.1))
                .collect();
            Button::new()
                .label(metric.as_str())
                .method(ButtonMethod::Update)
                .args(json!([{"visible": visible}, y_axis(metric, log)]))
        })
        .collect();
    let (first, first_log) = (per_metric[0].0, per_metric[0].2);
    plot.set_layout(
        Layout::new()
            .x_axis(
                Axis::new()
                    .type_(AxisType::Log)
                    .title(Title::with_text("sensor noise sigma (nT, log scale)")),
            )
            .y_axis(
                Axis::new()
                    .type_(if first_log { AxisType::Log } else { AxisType::Linear })
                    .title(Title::with_text(first.label())),
            )
            .update_menus(vec![UpdateMenu::new().buttons(buttons).active(0).x(0.0).y(1.15)])
            .margin(Margin::new().top(60)),
    );
    let missing: usize = per_metric.iter().map(|m| m.3).sum();
    page.heading("Noise sweep");
    page.plot("sweep", plot, 560, format!(
        "Each metric (the dropdown) against the sensor noise, per design: the median over the ok trials, the bar from the 5th to the 95th percentile, and dashed the Cramer-Rao prediction of the rms, all from summary.csv at the {} noise levels {}; an axis is logarithmic where the values span more than a decade. {}",
        sigmas.len(),
        sigmas.iter().map(|s| significant(*s, 4)).collect::<Vec<_>>().join(", "),
        if missing == 0 {
            "Every cell is drawn.".to_string()
        } else {
            format!("{missing} cells of summary.csv are not drawn: no ok trial gave them a value, or a value is zero, which a log axis cannot place (the table above has them).")
        }
    ));
    page.data(
        "sweep",
        json!(
            per_metric
                .iter()
                .map(|m| json!({"metric": m.0.as_str(), "traces": m.1, "log": m.2, "missing": m.3}))
                .collect::<Vec<_>>()
        ),
    );
}

/// The set's figures as SVG, by stem in the page's order: drawn here from the set's files as
/// `magcal plot` draws them, each file checked against its seal first (a set's `plots/` is not
/// sealed, and is never read).
fn figures(dir: &Path, manifest: &Manifest) -> Result<Vec<(String, String)>> {
    // designs.csv, design_metrics.csv and summary.csv were checked as the page read them.
    if manifest.lists("pso_runs.csv") {
        super::sealed_bytes(
            dir,
            "pso_runs.csv",
            manifest.file_sha256.get("pso_runs.csv"),
            "magcal run",
        )?;
    }
    let mut svgs = crate::figures::Svgs::default();
    crate::figures::draw(dir, manifest, &mut svgs, "").context("drawing the set's figures")?;
    let mut figures: Vec<(String, String)> = svgs
        .0
        .into_iter()
        .map(|(name, text)| (name.trim_end_matches(".svg").to_string(), text))
        .collect();
    figures.sort_by_key(|(stem, _)| (rank(stem), stem.clone()));
    Ok(figures)
}

/// Where a figure comes on the page: [P1]'s figures first, then the other metrics, the sweep,
/// the PSO runs, the designs.
fn rank(stem: &str) -> usize {
    match stem {
        "eta_psi" => 0,
        "eta_s" => 1,
        "eta_o" => 2,
        "pso_runs" => 3,
        s if s.starts_with("noise_sweep_") => 5,
        s if s.starts_with("design_") => 6,
        s if Metric::ALL.iter().any(|m| m.as_str() == s) => 4,
        _ => 7,
    }
}

/// What the figure `stem` of a set plots, from how `magcal run` names its figures.
fn caption(stem: &str) -> String {
    let paper = match stem {
        "eta_psi" => " ([P1] Fig. 1)",
        "eta_s" => " ([P1] Fig. 2)",
        "eta_o" => " ([P1] Fig. 3)",
        _ => "",
    };
    if let Some(m) = Metric::ALL.iter().find(|m| m.as_str() == stem) {
        return format!(
            "plots/{stem}.svg{paper}: {} per design over the trials at one noise level (the paper's 30 nT where the set has it): mean, spread and percentiles, with the trials' outcome counts ok / not converged / not identifiable / failed in the legend.",
            m.label()
        );
    }
    if let Some(m) = stem
        .strip_prefix("noise_sweep_")
        .and_then(|s| Metric::ALL.into_iter().find(|m| m.as_str() == s))
    {
        return format!(
            "plots/{stem}.svg: {} against the sensor noise, per design (the interactive sweep above shows the same cells).",
            m.label()
        );
    }
    if stem == "pso_runs" {
        return "plots/pso_runs.svg ([P1] Fig. 4): the final ln det M_F of each repeated PSO run, against the best design of the set.".into();
    }
    if let Some(d) = stem.strip_prefix("design_") {
        return format!(
            "plots/{stem}.svg: design {d}'s attitudes and the field's directions in the body frame they ask for."
        );
    }
    format!("plots/{stem}.svg")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_figure_of_the_shipped_sets_is_drawn_with_a_caption() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results");
        for set in ["wu2014", "noise-sweep", "ship", "criteria"] {
            let (manifest, _) = Manifest::read(&root.join(set)).unwrap();
            let figures = figures(&root.join(set), &manifest).unwrap();
            assert!(figures.len() >= 10, "{set}: {}", figures.len());
            for (stem, _) in &figures {
                assert!(caption(stem).len() > stem.len() + 20, "{set}: {stem} has no caption");
            }
            assert_eq!(figures[0].0, "eta_psi", "{set}: [P1] Fig. 1 first");
        }
    }
}

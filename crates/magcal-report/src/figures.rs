//! Figures from a result set's CSV files and manifest alone, as SVG and PNG: \[P1\] Figs. 1-3
//! (relative errors per design), Fig. 4 (final fitness of repeated PSO runs), the noise sweep, and
//! each design's attitudes and field directions.
//!
//! Every figure is rendered in memory and handed to a [`Figures`] sink (the command line's result set being written), so figures are
//! replaced with the rest of the set or not at all. Axis ranges are built from finite values only:
//! a cell with no successful trial, or a non-finite value, is drawn as absent and its label says
//! so. PNG text is drawn with a bundled DejaVu Sans through plotters' `ab_glyph` feature, so no
//! system font library is needed.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result};
use magcal_core::{Attitude, ReferenceField};
use plotters::coord::Shift;
use plotters::coord::combinators::LogCoord;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::manifest::Manifest;
use crate::rows::Metric;
use crate::rows::{DesignMetricsRow, DesignPointRow, PsoRunRow, SummaryRow, read_csv};
use magcal_logs::limits::set_member;

/// Figure size, pixels: readable at 800 px wide.
const SIZE: (u32, u32) = (960, 600);
const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// Decades a log axis spans at most; values further below its top are drawn at its bottom.
const MAX_DECADES: f64 = 12.0;

fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        register_font(FONT, FontStyle::Normal, FONT_BYTES).unwrap_or_else(|_| panic!("bundled font is valid"));
    });
}

/// One cell of `summary.csv` with its statistics, all finite, or `None` when absent.
#[derive(Debug, Clone)]
struct Stat {
    design: String,
    metric: Metric,
    sigma: f64,
    trials: usize,
    ok: usize,
    not_converged: usize,
    not_identifiable: usize,
    failed: usize,
    values: Option<Values>,
}

#[derive(Debug, Clone, Copy)]
struct Values {
    mean: f64,
    std: f64,
    median: f64,
    p05: f64,
    p95: f64,
}

impl Stat {
    fn of(row: &SummaryRow) -> Self {
        let get = |v: Option<crate::rows::Real>| v.map(|r| r.0).filter(|x| x.is_finite());
        let values = match (get(row.mean), get(row.median), get(row.p05), get(row.p95)) {
            (Some(mean), Some(median), Some(p05), Some(p95)) => Some(Values {
                mean,
                // One value has no spread.
                std: get(row.std).unwrap_or(0.0),
                median,
                p05,
                p95,
            }),
            _ => None,
        };
        // A cell with execution error is its own series.
        let design = if row.attitude_sigma_deg.0 > 0.0 {
            format!("{} flown +-{} deg", row.design, row.attitude_sigma_deg.0)
        } else {
            row.design.clone()
        };
        Self {
            design,
            metric: row.metric,
            sigma: row.sigma_nt.0,
            trials: row.trials,
            ok: row.ok,
            not_converged: row.not_converged,
            not_identifiable: row.not_identifiable,
            failed: row.failed,
            values,
        }
    }

    /// The design with its outcome counts, ok / not converged / not identifiable / failed:
    /// `pso (196/0/0/4)`, with `, no value` when no trial gave the metric.
    fn label(&self) -> String {
        let counts = format!(
            "{}/{}/{}/{}",
            self.ok, self.not_converged, self.not_identifiable, self.failed
        );
        match self.values {
            Some(_) => format!("{} ({counts})", self.design),
            None => format!("{} ({counts}, no value)", self.design),
        }
    }
}

/// A log-axis range `[lo, hi]` over the positive finite `values`, at most [`MAX_DECADES`] wide;
/// `None` when there is none.
fn log_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0_f64), |(a, b), v| (a.min(v), b.max(v)));
    if !(lo.is_finite() && hi > 0.0) {
        return None;
    }
    let lo = lo.max(hi * 10f64.powf(-MAX_DECADES)).min(hi / 10.0);
    Some((lo, hi))
}

/// Where drawn figures go: a result set's files (SVG and PNG), or a page's figures (SVG only).
pub trait Figures {
    /// Stores the file `name` (`<prefix><stem>.svg` or `.png`).
    ///
    /// # Errors
    /// One that cannot be stored.
    fn put(&mut self, name: &str, bytes: &[u8]) -> Result<()>;

    /// Whether PNG copies are drawn too.
    fn png(&self) -> bool {
        true
    }
}

/// The SVG drawings in memory, as `(name, text)` in the order drawn: what a page shows.
#[derive(Debug, Default)]
pub struct Svgs(pub Vec<(String, String)>);

impl Figures for Svgs {
    fn put(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        let text = String::from_utf8(bytes.to_vec()).with_context(|| format!("{name}: not UTF-8"))?;
        self.0.push((name.to_string(), text));
        Ok(())
    }

    fn png(&self) -> bool {
        false
    }
}

/// Renders the body (a drawing on `root`, evaluating to `Result<()>`) as `<prefix><stem>.svg`,
/// and where the figures want it as `.png`, into `set` (a [`Figures`]).
macro_rules! render {
    ($set:expr, $prefix:expr, $stem:expr, |$root:ident| $body:expr) => {{
        let stem: &str = $stem;
        let mut svg = String::new();
        {
            let $root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
            $body?;
            $root.present().map_err(|e| anyhow::anyhow!("{stem}.svg: {e}"))?;
        }
        $set.put(&format!("{}{stem}.svg", $prefix), svg.as_bytes())?;
        if $set.png() {
            let mut rgb = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
            {
                let $root = BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area();
                $body?;
                $root.present().map_err(|e| anyhow::anyhow!("{stem}.png: {e}"))?;
            }
            $set.put(&format!("{}{stem}.png", $prefix), &png(&rgb, stem)?)?;
        }
    }};
}

/// PNG bytes of an RGB image of [`SIZE`].
fn png(rgb: &[u8], stem: &str) -> Result<Vec<u8>> {
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        rgb,
        SIZE.0,
        SIZE.1,
        image::ColorType::Rgb8,
    )
    .with_context(|| format!("{stem}.png: cannot encode"))?;
    Ok(png)
}

/// Draws every figure that the result set in `src` supports (only files its manifest lists) into
/// `set`, each under `prefix` (`"plots/"` inside a result set, `""` for a set that is the plots
/// directory itself); returns the stems drawn.
///
/// # Errors
/// A missing or malformed file of the set (named in the message).
pub fn draw(src: &Path, manifest: &Manifest, set: &mut dyn Figures, prefix: &str) -> Result<Vec<String>> {
    register();
    let mut drawn = Vec::new();
    let name = manifest.name.as_str();

    let designs = read_designs(&set_member(src, "designs.csv")?)?;
    let f = manifest.field_ned_nt;
    let reference = ReferenceField::from_ned(f[0], f[1], f[2])
        .and_then(|x| x.with_yaw_offset_deg(manifest.yaw_offset_deg))
        .map_err(|e| anyhow::anyhow!("{}: field: {e}", src.join("manifest.json").display()))?;
    for (design, attitudes) in &designs {
        let stem = format!("design_{design}");
        render!(set, prefix, &stem, |root| draw_design(
            &root,
            name,
            design,
            attitudes,
            &reference,
            manifest.attitude_box_deg
        ));
        drawn.push(stem);
    }

    if manifest.lists("summary.csv") {
        let stats: Vec<Stat> = read_csv::<SummaryRow>(&set_member(src, "summary.csv")?)?
            .iter()
            .map(Stat::of)
            .collect();
        let mut sigmas: Vec<f64> = stats.iter().map(|s| s.sigma).filter(|s| s.is_finite()).collect();
        sigmas.sort_by(f64::total_cmp);
        sigmas.dedup_by(|a, b| a.to_bits() == b.to_bits());
        // [P1] Figs. 1-3 at the paper's 30 nT when present, else the first noise level.
        let sigma = sigmas
            .iter()
            .copied()
            .find(|s| (*s - 30.0).abs() < 1e-9)
            .or(sigmas.first().copied());
        let sweep = sigmas.iter().filter(|s| **s > 0.0).count() > 1;
        for metric in Metric::ALL.into_iter().filter(|_| sigma.is_some()) {
            let sigma = sigma.unwrap_or_default();
            let of_metric: Vec<&Stat> = stats.iter().filter(|s| s.metric == metric).collect();
            let rows: Vec<&Stat> = of_metric
                .iter()
                .copied()
                .filter(|s| s.sigma.to_bits() == sigma.to_bits())
                .collect();
            render!(set, prefix, metric.as_str(), |root| draw_errors(
                &root,
                name,
                metric.label(),
                sigma,
                &rows
            ));
            drawn.push(metric.as_str().to_string());
            if sweep {
                let stem = format!("noise_sweep_{}", metric.as_str());
                render!(set, prefix, &stem, |root| draw_sweep(
                    &root,
                    name,
                    metric.label(),
                    &of_metric
                ));
                drawn.push(stem);
            }
        }
    }

    if manifest.lists("pso_runs.csv") {
        let runs = read_csv::<PsoRunRow>(&set_member(src, "pso_runs.csv")?)?;
        let values: Vec<f64> = runs.iter().map(|r| r.final_ln_det.0).collect();
        // The reference line: the run's own best, over the runs and the designs of the same size.
        let m = runs.first().map_or(0, |r| r.m);
        let best_design = read_csv::<DesignMetricsRow>(&set_member(src, "design_metrics.csv")?)?
            .iter()
            .filter(|d| d.m == m && d.ln_det_mf.0.is_finite())
            .map(|d| (d.ln_det_mf.0, d.design.clone()))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        let best_run = values
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(f64::NEG_INFINITY, f64::max);
        let reference = match best_design {
            Some((v, design)) if v >= best_run => Some((v, format!("best of this run: design {design}"))),
            _ if best_run.is_finite() => Some((best_run, "best of this run: a PSO run".to_string())),
            _ => None,
        };
        render!(set, prefix, "pso_runs", |root| draw_runs(
            &root,
            name,
            &values,
            reference.as_ref()
        ));
        drawn.push("pso_runs".into());
    }
    Ok(drawn)
}

fn read_designs(path: &Path) -> Result<Vec<(String, Vec<Attitude>)>> {
    let mut designs: Vec<(String, Vec<Attitude>)> = Vec::new();
    for (i, r) in read_csv::<DesignPointRow>(path)?.into_iter().enumerate() {
        let [roll, yaw, pitch] = [r.roll_deg.0, r.yaw_deg.0, r.pitch_deg.0];
        if ![roll, yaw, pitch].iter().all(|v| v.is_finite()) {
            anyhow::bail!("{}: line {}: an attitude angle is not finite", path.display(), i + 2);
        }
        let a = Attitude::from_degrees(roll, yaw, pitch);
        match designs.last_mut() {
            Some((n, list)) if *n == r.design => list.push(a),
            _ => designs.push((r.design, vec![a])),
        }
    }
    Ok(designs)
}

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing: {e}")
}

/// The legend of a chart's labelled series, in the house style.
fn legend<'a, DB, CT>(chart: &mut ChartContext<'a, DB, CT>, position: SeriesLabelPosition) -> Result<()>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font((FONT, 16))
        .draw()
        .map_err(err)
}

fn palette(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(255, 127, 14),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
    ];
    C[i % C.len()]
}

/// \[P1\] Figs. 1-3: per design, the p05-p95 range (bar), the median (white line), and the mean with
/// +- one standard deviation (black marker and whisker). Logarithmic axis: the tails are heavy. A
/// design without values (no successful trial) keeps its place, labelled, with nothing drawn.
/// The mesh of a chart with one category per integer x (`names`) and a log y axis of `label`.
fn category_mesh<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, LogCoord<f64>>>,
    names: &[String],
    label: &str,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(names.len().max(1))
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < names.len() {
                names[i as usize].clone()
            } else {
                String::new()
            }
        })
        .y_desc(format!("{label} (log scale)"))
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()
        .map_err(err)
}

fn draw_errors<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    scenario: &str,
    label: &str,
    sigma: f64,
    rows: &[&Stat],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let values: Vec<Values> = rows.iter().filter_map(|s| s.values).collect();
    let (lo, hi) = log_range(
        values
            .iter()
            .flat_map(|v| [v.p05, v.median, v.mean, v.p95, v.mean + v.std]),
    )
    .unwrap_or((0.1, 10.0));
    let (lo, hi) = (lo / 1.5, hi * 1.5);
    let n = rows.len().max(1);
    let mut caption = format!(
        "{scenario}: {label}, sigma = {sigma} nT, {} trials per design",
        rows.first().map_or(0, |s| s.trials)
    );
    if values.len() < rows.len() {
        caption.push_str(&format!(" ({} without a value)", rows.len() - values.len()));
    }
    let mut chart = ChartBuilder::on(root)
        .caption(caption, (FONT, 20))
        .margin(16)
        .x_label_area_size(80)
        .y_label_area_size(80)
        .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), (lo..hi).log_scale())
        .map_err(err)?;
    let names: Vec<String> = rows.iter().map(|s| s.label()).collect();
    category_mesh(&mut chart, &names, label)?;
    let clip = |v: f64| v.clamp(lo, hi);
    for (i, s) in rows.iter().enumerate() {
        let Some(v) = s.values else { continue };
        let x = i as f64;
        let color = palette(i);
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x - 0.3, clip(v.p05)), (x + 0.3, clip(v.p95))],
                color.mix(0.45).filled(),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x - 0.3, clip(v.median)), (x + 0.3, clip(v.median))],
                WHITE.stroke_width(3),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x, clip(v.mean - v.std)), (x, clip(v.mean + v.std))],
                BLACK.stroke_width(2),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Circle::new((x, clip(v.mean)), 6, BLACK.filled())))
            .map_err(err)?;
    }
    // A legend drawn as text: what each mark means.
    root.draw(&Text::new(
        "bar: 5th-95th percentile   white: median   dot: mean   whisker: mean +- std   (trials: ok/not converged/not identifiable/failed)",
        (100, (SIZE.1 - 20) as i32),
        (FONT, 15).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

/// The noise sweep: median against sigma with the p05-p95 band, log-log, one line per design, over
/// the positive noise levels. A level without values is a gap; a design without any is named in
/// the legend as such.
fn draw_sweep<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    scenario: &str,
    label: &str,
    rows: &[&Stat],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let positive: Vec<&Stat> = rows
        .iter()
        .copied()
        .filter(|s| s.sigma > 0.0 && s.sigma.is_finite())
        .collect();
    let (smin, smax) = log_range(positive.iter().map(|s| s.sigma)).unwrap_or((1.0, 10.0));
    let (lo, hi) = log_range(
        positive
            .iter()
            .filter_map(|s| s.values)
            .flat_map(|v| [v.p05, v.median, v.p95]),
    )
    .unwrap_or((0.1, 10.0));
    let (lo, hi) = (lo / 1.5, hi * 1.5);
    let mut chart = ChartBuilder::on(root)
        .caption(format!("{scenario}: {label} against noise"), (FONT, 24))
        .margin(16)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((smin / 1.3..smax * 1.3).log_scale(), (lo..hi).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("sigma, noise per component (nT)")
        .y_desc(format!("{label}: median, band 5th-95th percentile"))
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()
        .map_err(err)?;
    let clip = |v: f64| v.clamp(lo, hi);
    let mut names: Vec<&str> = Vec::new();
    for s in &positive {
        if !names.contains(&s.design.as_str()) {
            names.push(&s.design);
        }
    }
    for (i, name) in names.iter().enumerate() {
        let mut pts: Vec<(f64, Values)> = positive
            .iter()
            .filter(|s| s.design == *name)
            .filter_map(|s| s.values.map(|v| (s.sigma, v)))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        let color = palette(i);
        let missing = positive.iter().filter(|s| s.design == *name).count() - pts.len();
        let label = match (pts.is_empty(), missing) {
            (true, _) => format!("{name} (no successful trial)"),
            (false, 0) => name.to_string(),
            (false, 1) => format!("{name} (1 level without a value)"),
            (false, k) => format!("{name} ({k} levels without a value)"),
        };
        let mut band: Vec<(f64, f64)> = pts.iter().map(|(s, v)| (*s, clip(v.p95))).collect();
        band.extend(pts.iter().rev().map(|(s, v)| (*s, clip(v.p05))));
        if !band.is_empty() {
            chart
                .draw_series(std::iter::once(Polygon::new(band, color.mix(0.15).filled())))
                .map_err(err)?;
        }
        chart
            .draw_series(LineSeries::new(
                pts.iter().map(|(s, v)| (*s, clip(v.median))),
                color.stroke_width(3),
            ))
            .map_err(err)?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3)));
        chart
            .draw_series(
                pts.iter()
                    .map(|(s, v)| Circle::new((*s, clip(v.median)), 4, color.filled())),
            )
            .map_err(err)?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

/// \[P1\] Fig. 4: the final `ln det M_F` of each repeated PSO run, and the best of the run (the
/// best design of the same size or the best run) as a reference line. A run that ended without a
/// finite value (a singular design) is not drawn; the caption counts it.
fn draw_runs<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    scenario: &str,
    values: &[f64],
    reference: Option<&(f64, String)>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let finite: Vec<(usize, f64)> = values
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .collect();
    let start = reference.map_or(finite.first().map_or((0.0, 1.0), |&(_, v)| (v, v)), |r| (r.0, r.0));
    let (lo, hi) = finite.iter().fold(start, |(a, b), &(_, v)| (a.min(v), b.max(v)));
    let pad = ((hi - lo) * 0.1).max(1e-3);
    let n = values.len();
    let mut caption = format!("{scenario}: final ln det M_F of {n} PSO runs");
    if finite.len() < n {
        caption.push_str(&format!(" ({} not finite, not drawn)", n - finite.len()));
    }
    let mut chart = ChartBuilder::on(root)
        .caption(caption, (FONT, 22))
        .margin(16)
        .x_label_area_size(50)
        .y_label_area_size(90)
        .build_cartesian_2d(0f64..(n as f64 + 1.0), (lo - pad)..(hi + pad))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("run")
        .y_desc("final ln det M_F (H in nT)")
        .y_label_formatter(&|y| format!("{y:.2}"))
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()
        .map_err(err)?;
    if let Some((best, what)) = reference {
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(0.0, *best), (n as f64 + 1.0, *best)],
                RED.stroke_width(2),
            )))
            .map_err(err)?
            .label(format!("{what}, {best:.5}"))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], RED.stroke_width(2)));
    }
    chart
        .draw_series(
            finite
                .iter()
                .map(|&(i, v)| Circle::new((i as f64 + 1.0, v), 4, palette(0).filled())),
        )
        .map_err(err)?
        .label("final value of a run")
        .legend(|(x, y)| Circle::new((x + 12, y), 4, palette(0).filled()));
    legend(&mut chart, SeriesLabelPosition::LowerRight)
}

/// A design: its attitudes in the (yaw, pitch) plane coloured by roll (left), and where the readings
/// fall on the unit sphere of body-frame field directions in a Lambert cylindrical equal-area
/// projection, azimuth `atan2(right, nose)` against `sin(elevation)` (right).
fn draw_design<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    scenario: &str,
    design: &str,
    attitudes: &[Attitude],
    field: &ReferenceField,
    bounds: Option<[[f64; 2]; 3]>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let degs: Vec<[f64; 3]> = attitudes.iter().map(Attitude::to_degrees).collect();
    let max_abs = |k: usize| degs.iter().map(|d| d[k].abs()).fold(0.0_f64, f64::max);
    let box_pitch = bounds.map_or(0.0, |b| b[2][0].abs().max(b[2][1].abs()));
    let pitch_span = (max_abs(2).max(box_pitch) * 1.15).max(5.0);
    let roll_span = bounds
        .map_or(max_abs(0), |b| b[0][0].abs().max(b[0][1].abs()))
        .max(1e-9);
    let title = format!(
        "{scenario}: design {design} ({} attitudes); colour = roll, blue -{roll_span:.1} to red +{roll_span:.1} deg",
        attitudes.len()
    );
    let root = root.titled(&title, (FONT, 20)).map_err(err)?;
    let (left, right) = root.split_horizontally(SIZE.0 / 2);
    let mut chart = ChartBuilder::on(&left)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(-190f64..190f64, -pitch_span..pitch_span)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("yaw (deg)")
        .y_desc("pitch (deg)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 17))
        .draw()
        .map_err(err)?;
    if let Some(b) = bounds {
        // The attitude box's yaw-pitch face, dashed grey.
        let [y0, y1] = b[1];
        let [p0, p1] = b[2];
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(y0, p0), (y1, p0), (y1, p1), (y0, p1), (y0, p0)],
                RGBColor(120, 120, 120).stroke_width(2),
            )))
            .map_err(err)?;
    }
    for d in &degs {
        // Roll from -max (blue) to +max (red).
        let t = (d[0] / roll_span + 1.0) / 2.0;
        let color = RGBColor((255.0 * t) as u8, 40, (255.0 * (1.0 - t)) as u8);
        chart
            .draw_series(std::iter::once(Circle::new((d[1], d[2]), 7, color.filled())))
            .map_err(err)?;
    }

    let mut chart = ChartBuilder::on(&right)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(-180f64..180f64, -1f64..1f64)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("field azimuth in the body frame, atan2(right, nose) (deg)")
        .y_desc("sin(field elevation above the body x-z plane)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 15))
        .draw()
        .map_err(err)?;
    let dirs: Vec<(f64, f64)> = attitudes
        .iter()
        .map(|a| {
            let b = field.body_field(a);
            let n = magcal_core::small::norm(b);
            (b[2].atan2(b[0]).to_degrees(), b[1] / n)
        })
        .collect();
    chart
        .draw_series(dirs.iter().map(|&p| Cross::new(p, 7, palette(1).stroke_width(3))))
        .map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ranges_are_finite_and_bounded() {
        assert_eq!(log_range([f64::NAN, f64::INFINITY, -1.0, 0.0]), None);
        let (lo, hi) = log_range([1e-300, 5.0, f64::INFINITY]).unwrap();
        assert!(
            (hi - 5.0).abs() < 1e-12 && (lo / (5e-12) - 1.0).abs() < 1e-12,
            "{lo} {hi}"
        );
        // One value: a decade below it.
        let (lo, hi) = log_range([2.0]).unwrap();
        assert!((lo - 0.2).abs() < 1e-15 && (hi - 2.0).abs() < 1e-15);
    }
}

/// One design and model of a replay (`replay`'s `summary.csv`) for [`draw_replay`]: the outcome
/// trials (0 where the log could not realise the design) and the 5th percentile, median and 95th
/// percentile of a metric over the `ok` trials (`None` without any).
#[derive(Debug, Clone)]
pub struct ReplayCell {
    pub design: String,
    pub model: String,
    pub trials: usize,
    pub band: Option<[f64; 3]>,
}

/// The figures of a replay set, one per metric with a value (`metrics`: file stem, axis label
/// and its cells, design-major): per design a group of bars, one per model in its colour, from
/// the 5th to the 95th percentile with the median in white, on a log axis (the tails are heavy, as
/// in \[P1\] Figs. 1-3). A design the log could not realise keeps its place, labelled. Returns the
/// stems drawn.
///
/// # Errors
/// A figure that cannot be rendered or stored.
pub fn draw_replay(
    set: &mut dyn Figures,
    prefix: &str,
    title: &str,
    metrics: &[(&str, &str, Vec<ReplayCell>)],
) -> Result<Vec<String>> {
    register();
    let mut drawn = Vec::new();
    for (stem, label, cells) in metrics {
        if cells.iter().all(|c| c.band.is_none()) {
            continue;
        }
        render!(set, prefix, stem, |root| draw_replay_metric(&root, title, label, cells));
        drawn.push((*stem).to_string());
    }
    Ok(drawn)
}

fn draw_replay_metric<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    label: &str,
    cells: &[ReplayCell],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let mut designs: Vec<&str> = Vec::new();
    let mut models: Vec<&str> = Vec::new();
    for c in cells {
        if !designs.contains(&c.design.as_str()) {
            designs.push(&c.design);
        }
        if !models.contains(&c.model.as_str()) {
            models.push(&c.model);
        }
    }
    let (lo, hi) = log_range(cells.iter().filter_map(|c| c.band).flatten()).unwrap_or((0.1, 10.0));
    let (lo, hi) = (lo / 1.5, hi * 1.5);
    let n = designs.len().max(1);
    let mut chart = ChartBuilder::on(root)
        .caption(format!("{title}: {label}"), (FONT, 20))
        .margin(16)
        .x_label_area_size(60)
        .y_label_area_size(80)
        .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), (lo..hi).log_scale())
        .map_err(err)?;
    let names: Vec<String> = designs
        .iter()
        .map(|d| {
            let replayed = cells.iter().any(|c| c.design == *d && c.trials > 0);
            if replayed {
                (*d).to_string()
            } else {
                format!("{d} (not realised)")
            }
        })
        .collect();
    category_mesh(&mut chart, &names, label)?;
    let clip = |v: f64| v.clamp(lo, hi);
    let width = 0.8 / models.len().max(1) as f64;
    for (k, model) in models.iter().enumerate() {
        let color = palette(k);
        let bars: Vec<_> = cells
            .iter()
            .filter(|c| c.model == *model)
            .filter_map(|c| {
                let i = designs.iter().position(|d| *d == c.design)?;
                let [p05, median, p95] = c.band?;
                let x = i as f64 - 0.4 + width * (k as f64 + 0.5);
                Some((x, clip(p05), clip(median), clip(p95)))
            })
            .collect();
        chart
            .draw_series(bars.iter().map(|&(x, a, _, b)| {
                Rectangle::new([(x - width * 0.4, a), (x + width * 0.4, b)], color.mix(0.6).filled())
            }))
            .map_err(err)?
            .label(model.to_string())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], color.filled()));
        chart
            .draw_series(bars.iter().map(|&(x, _, m, _)| {
                PathElement::new(vec![(x - width * 0.4, m), (x + width * 0.4, m)], WHITE.stroke_width(3))
            }))
            .map_err(err)?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    root.draw(&Text::new(
        "bar: 5th-95th percentile over the ok trials   white: median   no bar: no ok trial (see summary.csv)",
        (100, (SIZE.1 - 20) as i32),
        (FONT, 15).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

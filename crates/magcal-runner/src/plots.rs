//! Figures from a results directory's CSV files and manifest alone, as SVG and PNG under `plots/`:
//! \[P1\] Figs. 1-3 (relative errors per design), Fig. 4 (final fitness of repeated PSO runs), the
//! noise sweep, and each design's attitudes and field directions.
//!
//! PNG text is drawn with a bundled DejaVu Sans through plotters' `ab_glyph` feature, so no system
//! font library is needed. Each file is written to a temporary name and renamed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{Context, Result, bail};
use magcal_core::{Attitude, ReferenceField};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::export::write_atomic;

/// Figure size, pixels: readable at 800 px wide.
const SIZE: (u32, u32) = (960, 600);
const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        register_font(FONT, FontStyle::Normal, FONT_BYTES).unwrap_or_else(|_| panic!("bundled font is valid"));
    });
}

/// One row of `summary.csv`.
#[derive(Debug, Clone)]
struct Stat {
    design: String,
    sigma: f64,
    trials: usize,
    failed: usize,
    metric: String,
    mean: f64,
    std: f64,
    median: f64,
    p05: f64,
    p95: f64,
}

/// What the manifest says that the figures need.
#[derive(Debug, serde::Deserialize)]
struct ManifestIn {
    name: String,
    field_ned_nt: [f64; 3],
    yaw_offset_deg: f64,
    /// Roll, yaw, pitch `[min, max]`, degrees (absent in manifests of older runs: no box drawn).
    attitude_box_deg: Option<[[f64; 2]; 3]>,
}

fn read_csv(path: &Path) -> Result<Vec<BTreeMap<String, String>>> {
    let mut reader = csv::Reader::from_path(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let headers = reader
        .headers()
        .with_context(|| format!("{}: no header", path.display()))?
        .clone();
    reader
        .records()
        .enumerate()
        .map(|(i, r)| {
            let r = r.with_context(|| format!("{}: row {}", path.display(), i + 2))?;
            Ok(headers
                .iter()
                .zip(r.iter())
                .map(|(h, v)| (h.to_string(), v.to_string()))
                .collect())
        })
        .collect()
}

fn field<T: std::str::FromStr>(row: &BTreeMap<String, String>, key: &str, path: &Path, line: usize) -> Result<T> {
    let text = row
        .get(key)
        .with_context(|| format!("{}: no column {key:?}", path.display()))?;
    text.parse()
        .map_err(|_| anyhow::anyhow!("{}: row {line}: {key} = {text:?} is not a valid number", path.display()))
}

fn read_summary(path: &Path) -> Result<Vec<Stat>> {
    read_csv(path)?
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let line = i + 2;
            Ok(Stat {
                design: r
                    .get("design")
                    .with_context(|| format!("{}: no column \"design\"", path.display()))?
                    .clone(),
                sigma: field(r, "sigma_nt", path, line)?,
                trials: field(r, "trials", path, line)?,
                failed: field(r, "failed", path, line)?,
                metric: r
                    .get("metric")
                    .with_context(|| format!("{}: no column \"metric\"", path.display()))?
                    .clone(),
                mean: field(r, "mean", path, line)?,
                std: field(r, "std", path, line)?,
                median: field(r, "median", path, line)?,
                p05: field(r, "p05", path, line)?,
                p95: field(r, "p95", path, line)?,
            })
        })
        .collect()
}

/// Renders `draw` into `plots/<stem>.svg` and `plots/<stem>.png`; evaluates to the PNG's path.
macro_rules! render {
    ($dir:expr, $stem:expr, $draw:expr) => {{
        let dir: &Path = $dir;
        let stem: &str = $stem;
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
            $draw(&root)?;
            root.present().map_err(|e| anyhow::anyhow!("{stem}.svg: {e}"))?;
        }
        write_atomic(&dir.join(format!("{stem}.svg")), svg.as_bytes())?;
        let png = dir.join(format!("{stem}.png"));
        let tmp = dir.join(format!(".{stem}.{}.tmp.png", std::process::id()));
        {
            let root = BitMapBackend::new(&tmp, SIZE).into_drawing_area();
            $draw(&root)?;
            root.present().map_err(|e| anyhow::anyhow!("{stem}.png: {e}"))?;
        }
        std::fs::rename(&tmp, &png).with_context(|| format!("{}: cannot rename into place", png.display()))?;
        png
    }};
}

/// Draws every figure the results directory supports into `<dir>/plots/`; returns the PNG paths.
///
/// # Errors
/// A missing or malformed `summary.csv`, `designs.csv` or `manifest.json` (named in the message); a
/// malformed `pso_runs.csv` when it exists.
pub fn plot_dir(dir: &Path) -> Result<Vec<PathBuf>> {
    register();
    let manifest_path = dir.join("manifest.json");
    let manifest: ManifestIn = serde_json::from_slice(
        &std::fs::read(&manifest_path).with_context(|| format!("{}: cannot read", manifest_path.display()))?,
    )
    .with_context(|| format!("{}: malformed", manifest_path.display()))?;
    let out = dir.join("plots");
    std::fs::create_dir_all(&out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut written = Vec::new();
    let name = manifest.name.as_str();

    // Designs first: they exist for `magcal design` too.
    let designs_path = dir.join("designs.csv");
    let designs = read_designs(&designs_path)?;
    let f = manifest.field_ned_nt;
    let reference = ReferenceField::from_ned(f[0], f[1], f[2])
        .and_then(|x| x.with_yaw_offset_deg(manifest.yaw_offset_deg))
        .map_err(|e| anyhow::anyhow!("{}: field: {e}", manifest_path.display()))?;
    for (design, attitudes) in &designs {
        written.push(render!(&out, &format!("design_{design}"), |root: &DrawingArea<
            _,
            Shift,
        >| {
            draw_design(root, name, design, attitudes, &reference, manifest.attitude_box_deg)
        }));
    }

    let summary_path = dir.join("summary.csv");
    if summary_path.exists() {
        let stats = read_summary(&summary_path)?;
        if stats.is_empty() {
            bail!("{}: no rows", summary_path.display());
        }
        let sigmas: Vec<f64> = {
            let mut s: Vec<f64> = stats.iter().map(|s| s.sigma).collect();
            s.sort_by(f64::total_cmp);
            s.dedup_by(|a, b| a.to_bits() == b.to_bits());
            s
        };
        // [P1] Figs. 1-3 at the paper's 30 nT when present, else the first noise level.
        let sigma = sigmas
            .iter()
            .copied()
            .find(|s| (*s - 30.0).abs() < 1e-9)
            .unwrap_or(sigmas[0]);
        for (metric, label) in METRICS {
            let rows: Vec<&Stat> = stats
                .iter()
                .filter(|s| s.metric == metric && s.sigma.to_bits() == sigma.to_bits())
                .collect();
            written.push(render!(&out, metric, |root: &DrawingArea<_, Shift>| draw_errors(
                root, name, label, sigma, &rows
            )));
            if sigmas.len() > 1 {
                let rows: Vec<&Stat> = stats.iter().filter(|s| s.metric == metric).collect();
                written.push(render!(&out, &format!("noise_sweep_{metric}"), |root: &DrawingArea<
                    _,
                    Shift,
                >| {
                    draw_sweep(root, name, label, &rows)
                }));
            }
        }
    }

    let runs_path = dir.join("pso_runs.csv");
    if runs_path.exists() {
        let rows = read_csv(&runs_path)?;
        let values: Vec<f64> = rows
            .iter()
            .enumerate()
            .map(|(i, r)| field(r, "final_ln_det", &runs_path, i + 2))
            .collect::<Result<_>>()?;
        if values.is_empty() {
            bail!("{}: no rows", runs_path.display());
        }
        written.push(render!(&out, "pso_runs", |root: &DrawingArea<_, Shift>| draw_runs(
            root, name, &values
        )));
    }
    Ok(written)
}

const METRICS: [(&str, &str); 3] = [
    ("eta_psi", "eta_psi, non-orthogonality error (%)"),
    ("eta_s", "eta_S, scale factor error (%)"),
    ("eta_o", "eta_O, bias error (%)"),
];

fn read_designs(path: &Path) -> Result<Vec<(String, Vec<Attitude>)>> {
    let mut designs: Vec<(String, Vec<Attitude>)> = Vec::new();
    for (i, r) in read_csv(path)?.iter().enumerate() {
        let line = i + 2;
        let name = r
            .get("design")
            .with_context(|| format!("{}: no column \"design\"", path.display()))?;
        let a = Attitude::from_degrees(
            field(r, "roll_deg", path, line)?,
            field(r, "yaw_deg", path, line)?,
            field(r, "pitch_deg", path, line)?,
        );
        match designs.last_mut() {
            Some((n, list)) if n == name => list.push(a),
            _ => designs.push((name.clone(), vec![a])),
        }
    }
    if designs.is_empty() {
        bail!("{}: no rows", path.display());
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
/// +- one standard deviation (black marker and whisker). Logarithmic axis: the tails are heavy.
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
    let lo = rows
        .iter()
        .map(|s| s.p05.min(s.median))
        .fold(f64::INFINITY, f64::min)
        .max(1e-6);
    let hi = rows
        .iter()
        .map(|s| s.p95.max(s.mean + s.std))
        .fold(0.0_f64, f64::max)
        .max(lo * 10.0);
    let n = rows.len();
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!(
                "{scenario}: {label}, sigma = {sigma} nT, {} trials per design",
                rows.first().map_or(0, |s| s.trials)
            ),
            (FONT, 22),
        )
        .margin(16)
        .x_label_area_size(80)
        .y_label_area_size(80)
        .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), (lo / 1.5..hi * 1.5).log_scale())
        .map_err(err)?;
    let names: Vec<String> = rows
        .iter()
        .map(|s| format!("{} ({} failed)", s.design, s.failed))
        .collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
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
        .map_err(err)?;
    for (i, s) in rows.iter().enumerate() {
        let x = i as f64;
        let color = palette(i);
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(x - 0.3, s.p05.max(lo / 1.5)), (x + 0.3, s.p95)],
                color.mix(0.45).filled(),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x - 0.3, s.median), (x + 0.3, s.median)],
                WHITE.stroke_width(3),
            )))
            .map_err(err)?;
        let (a, b) = ((s.mean - s.std).max(lo / 1.5), s.mean + s.std);
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x, a), (x, b)],
                BLACK.stroke_width(2),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Circle::new((x, s.mean), 6, BLACK.filled())))
            .map_err(err)?;
    }
    // A legend drawn as text: what each mark means.
    root.draw(&Text::new(
        "bar: 5th-95th percentile   white: median   dot: mean   whisker: mean +- std",
        (100, (SIZE.1 - 20) as i32),
        (FONT, 15).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

/// The noise sweep: median against sigma with the p05-p95 band, log-log, one line per design.
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
    let positive: Vec<&&Stat> = rows.iter().filter(|s| s.sigma > 0.0).collect();
    let (smin, smax) = positive
        .iter()
        .fold((f64::INFINITY, 0.0_f64), |(a, b), s| (a.min(s.sigma), b.max(s.sigma)));
    let lo = positive
        .iter()
        .map(|s| s.p05)
        .filter(|v| *v > 0.0)
        .fold(f64::INFINITY, f64::min);
    let hi = positive.iter().map(|s| s.p95).fold(0.0_f64, f64::max);
    if !(smin < smax && lo < hi) {
        bail!("noise sweep: needs two positive noise levels and positive errors");
    }
    let mut chart = ChartBuilder::on(root)
        .caption(format!("{scenario}: {label} against noise"), (FONT, 24))
        .margin(16)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((smin / 1.3..smax * 1.3).log_scale(), (lo / 1.5..hi * 1.5).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("sigma, noise per component (nT)")
        .y_desc(format!("{label}: median, band 5th-95th percentile"))
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()
        .map_err(err)?;
    let mut names: Vec<&str> = Vec::new();
    for s in &positive {
        if !names.contains(&s.design.as_str()) {
            names.push(&s.design);
        }
    }
    for (i, name) in names.iter().enumerate() {
        let mut pts: Vec<&&&Stat> = positive.iter().filter(|s| s.design == *name).collect();
        pts.sort_by(|a, b| a.sigma.total_cmp(&b.sigma));
        let color = palette(i);
        let mut band: Vec<(f64, f64)> = pts.iter().map(|s| (s.sigma, s.p95)).collect();
        band.extend(pts.iter().rev().map(|s| (s.sigma, s.p05.max(lo / 1.5))));
        chart
            .draw_series(std::iter::once(Polygon::new(band, color.mix(0.15).filled())))
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new(
                pts.iter().map(|s| (s.sigma, s.median)),
                color.stroke_width(3),
            ))
            .map_err(err)?
            .label(name.to_string())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3)));
        chart
            .draw_series(pts.iter().map(|s| Circle::new((s.sigma, s.median), 4, color.filled())))
            .map_err(err)?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

/// \[P1\] Fig. 4: the final `ln det M_F` of each repeated PSO run, and the best known optimum.
fn draw_runs<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, scenario: &str, values: &[f64]) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    let best = magcal_core::paper::BEST_KNOWN_LN_DET;
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min).min(best);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max).max(best);
    let pad = ((hi - lo) * 0.1).max(1e-3);
    let n = values.len();
    let mut chart = ChartBuilder::on(root)
        .caption(format!("{scenario}: final ln det M_F of {n} PSO runs"), (FONT, 24))
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
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(0.0, best), (n as f64 + 1.0, best)],
            RED.stroke_width(2),
        )))
        .map_err(err)?
        .label(format!("best known optimum {best}"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], RED.stroke_width(2)));
    chart
        .draw_series(
            values
                .iter()
                .enumerate()
                .map(|(i, v)| Circle::new((i as f64 + 1.0, *v), 4, palette(0).filled())),
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
    fn malformed_summary_names_the_file_and_value() {
        let dir = tempfile::TempDir::new().unwrap();
        let p = dir.path().join("summary.csv");
        std::fs::write(
            &p,
            "design,sigma_nt,trials,failed,metric,mean,std,median,p05,p95,se_mean\nu,30,10,0,eta_psi,abc,1,1,1,1,1\n",
        )
        .unwrap();
        let e = read_summary(&p).unwrap_err().to_string();
        assert!(e.contains("summary.csv") && e.contains("mean = \"abc\""), "{e}");
    }
}

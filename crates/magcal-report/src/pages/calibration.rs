//! The page of a calibration set (`calibrate --out DIR`): the verdict and the numbers of
//! `calibration.json`, the raw readings with the fitted ellipsoid and the calibrated readings on
//! the sphere in 3D, the residual over the sphere of directions, and MotionCal's coverage
//! regions coloured by count.

use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::log_fit::motioncal_region_counts;
use plotly::common::{ColorBar, ColorScale, ColorScalePalette, Marker, Mode, Title};
use plotly::layout::{AspectMode, Axis, LayoutScene};
use plotly::{HeatMap, Layout, Plot, Scatter3D};
use serde_json::json;

use super::sphere::{coverage_plot, mesh};
use super::{Cell, Page, Table, drawn, thin, thinned_note};
use crate::manifest::{CalibrationManifest, verify};
use crate::rows::log_rows::ResidualRow;
use magcal_logs::calibration::{CalibrationJson, PassesJson, parse_calibration};

/// Readings drawn in each 3D and attitude figure at most: more add megabytes and nothing a
/// person sees (at 2,500 the page of BROAD trial 02's calibration is 1.9 MB, 1.49 MB of it
/// plotly.js).
pub const MAX_DRAWN: usize = 2500;

/// The page of the calibration set in `dir`.
///
/// # Errors
/// A set without its calibration.json or residuals.csv, or whose files disagree.
pub fn page(dir: &Path) -> Result<Page> {
    let manifest = read_manifest(dir)?;
    // A page never shows a file edited after calibrate wrote it.
    let sealed = |name: &str| super::sealed_bytes(dir, name, manifest.file_sha256.get(name), "calibrate");
    let (bytes, shown) = sealed("calibration.json")?;
    let cal = parse_calibration(&bytes, &shown)?;
    // residuals.csv (a row per reading: 1.4 GB for 10^7) is read streaming: the page keeps the
    // rows it draws and the counts over all rows, never the file.
    let mut residuals = Residuals::new(cal.samples);
    let (rows, residuals_shown) = super::sealed_rows(
        dir,
        "residuals.csv",
        manifest.file_sha256.get("residuals.csv"),
        "calibrate",
        |row| {
            residuals.add(row);
            Ok(())
        },
    )?;
    if rows != cal.samples {
        bail!(
            "{}: {} rows, but calibration.json says {} readings were fitted",
            residuals_shown,
            rows,
            cal.samples
        );
    }
    let residuals = residuals.finish();
    let units = cal.units.clone().unwrap_or_else(|| "log units".to_string());
    let mut page = Page::new(
        format!("Calibration of {}", file_name(&cal.log)),
        format!(
            "{} model, {} readings, magcal {}",
            cal.fit,
            cal.samples,
            cal.magcal_version.as_deref().unwrap_or("?")
        ),
    );
    verdict(&mut page, &cal);
    parameters(&mut page, &cal, &units);
    summary(&mut page, &cal, &units);
    let drawn = &residuals.drawn;
    if let Some(note) = thinned_note("The 3D figures", drawn.len(), rows) {
        page.note(note);
    }
    page.heading("Raw readings and the fitted ellipsoid");
    page.plot("raw", raw_plot(&cal, drawn, &units), 620, format!(
        "Raw readings ({units}) as logged, and the ellipsoid raw = K b + O on which calibrated readings b of magnitude {} lie. Drag to turn, scroll to zoom, hover for a reading's line.",
        super::significant(cal.magnitude, 5)
    ));
    page.heading("Calibrated readings on the sphere");
    page.plot("calibrated", calibrated_plot(&cal, drawn, &units), 620, "Calibrated readings b = P (raw - O), coloured by their residual |b| - R; a good calibration puts them on the sphere of radius R (drawn as a wire frame).");
    page.heading("Residual over the sphere of directions");
    page.plot("residual-map", residual_map(&residuals.cells), 460, "RMS residual |b| - R of the readings whose calibrated direction falls in each 10-degree cell of longitude (from the sensor's x axis towards y) and latitude (towards z); empty cells were never visited. All readings counted.");
    page.heading("Coverage of field directions (MotionCal's 100 regions)");
    let counts = residuals.regions;
    page.plot("coverage", coverage_plot(&counts), 560, format!(
        "The sphere of calibrated field directions cut into MotionCal's 100 regions of equal area, coloured by the readings in each: red none, orange one, yellow two, green three or more (MotionCal's gap error counts 1, 0.2, 0.01 and 0 for them). {} regions empty; MotionCal gaps {} %.",
        counts.iter().filter(|&&c| c == 0).count(),
        super::significant(cal.coverage.motioncal_gap_percent, 3)
    ));
    super::attitudes::section(
        &mut page,
        drawn,
        cal.coverage.flown.as_ref(),
        cal.coverage.box_from.as_deref(),
    );
    page.data("calibration", serde_json::to_value(&cal).context("calibration.json")?);
    page.data("readings", json!(rows));
    page.data("drawn", json!(drawn.len()));
    page.data("region_counts", json!(counts.to_vec()));
    Ok(page)
}

/// Cells of the residual map: 10 degrees of longitude by 10 of latitude.
const LON: usize = 36;
const LAT: usize = 18;

/// Calibrated directions buffered for [`motioncal_region_counts`] between calls.
const REGION_BATCH: usize = 4096;

/// What the page takes of residuals.csv, row by row: the rows it draws, and the sums and counts
/// over every row.
struct Residuals {
    /// The indices of the rows drawn ([`thin`] of the rows the calibration says it fitted), in
    /// order, and the next of them to come.
    wanted: Vec<usize>,
    next: usize,
    /// Rows read.
    read: usize,
    /// The rows drawn.
    drawn: Vec<ResidualRow>,
    /// Per cell of the residual map, the sum of squared residuals and the readings.
    cells: Cells,
    /// Readings per MotionCal region of the calibrated directions, and directions not yet counted.
    regions: [usize; 100],
    pending: Vec<[f64; 3]>,
}

/// The residual map's sums of squared residuals and counts, `[latitude][longitude]`.
struct Cells {
    sum: [[f64; LON]; LAT],
    count: [[usize; LON]; LAT],
}

impl Residuals {
    /// For a file of `samples` rows, as calibration.json says.
    fn new(samples: usize) -> Self {
        Self {
            wanted: thin(samples, MAX_DRAWN),
            next: 0,
            read: 0,
            drawn: Vec::new(),
            cells: Cells {
                sum: [[0.0; LON]; LAT],
                count: [[0; LON]; LAT],
            },
            regions: [0; 100],
            pending: Vec::with_capacity(REGION_BATCH),
        }
    }

    fn add(&mut self, row: ResidualRow) {
        if let Some((lon, lat)) = lon_lat(&row) {
            let i = (((lat + 90.0) / 10.0) as usize).min(LAT - 1);
            let j = (((lon + 180.0) / 10.0) as usize).min(LON - 1);
            self.cells.sum[i][j] += row.residual.0 * row.residual.0;
            self.cells.count[i][j] += 1;
        }
        self.pending.push([row.x.0, row.y.0, row.z.0]);
        if self.pending.len() == REGION_BATCH {
            self.count_regions();
        }
        if self.wanted.get(self.next) == Some(&self.read) {
            self.drawn.push(row);
            self.next += 1;
        }
        self.read += 1;
    }

    fn count_regions(&mut self) {
        let counts = motioncal_region_counts(&self.pending);
        self.regions.iter_mut().zip(counts).for_each(|(total, c)| *total += c);
        self.pending.clear();
    }

    /// With every direction counted.
    fn finish(mut self) -> Self {
        self.count_regions();
        self
    }
}

/// The certified D-efficiency per reading in the scenario's box, as `calibrate` says it: above 1
/// the log's attitudes lie outside the box, and the ratio is no efficiency.
fn d_efficiency_row(cal: &CalibrationJson) -> Vec<Cell> {
    let box_from = cal.coverage.box_from.as_deref().unwrap_or("the scenario");
    match cal.coverage.d_efficiency_per_reading {
        Some(e) if e > 1.0 => vec![
            Cell::text(format!("certified D-efficiency per reading in the box of {box_from}")),
            Cell::text(format!(
                "none: the log holds {} times the information per reading of the best design in the box (its attitudes lie outside it)",
                super::significant(e, 4)
            )),
        ],
        Some(e) => vec![
            Cell::text(format!("certified D-efficiency per reading in the box of {box_from}")),
            Cell::number(e, 4),
        ],
        None => match &cal.coverage.d_efficiency_why_not {
            Some(why) => vec![
                Cell::text(format!("certified D-efficiency per reading in the box of {box_from}")),
                Cell::text(format!("- ({why})")),
            ],
            None => vec![
                Cell::text("certified D-efficiency per reading"),
                Cell::text("- (no --scenario or box given to calibrate)"),
            ],
        },
    }
}

/// The set's manifest, its own hash checked.
fn read_manifest(dir: &Path) -> Result<CalibrationManifest> {
    let path = magcal_logs::limits::set_member(dir, "manifest.json")?;
    let bytes = magcal_logs::limits::read_bounded(&path, crate::manifest::MAX_MANIFEST_BYTES)?;
    verify(&path, &bytes)?;
    serde_json::from_slice(&bytes).with_context(|| format!("{}: not a magcal calibration manifest", path.display()))
}

/// The last part of a path as written in calibration.json.
fn file_name(log: &str) -> &str {
    log.rsplit(['/', '\\']).next().unwrap_or(log)
}

fn verdict(page: &mut Page, cal: &CalibrationJson) {
    let text = if cal.usable {
        let flag = cal.passes.as_ref().and_then(PassesJson::flag);
        format!(
            "USABLE: {}{}",
            cal.verdict,
            flag.map_or(String::new(), |f| format!("; {f}"))
        )
    } else {
        format!(
            "NOT USABLE: {}",
            if cal.reasons.is_empty() {
                cal.verdict.clone()
            } else {
                cal.reasons.join("; ")
            }
        )
    };
    page.push(super::Block::Verdict { good: cal.usable, text });
}

/// Estimate, standard error and 95 % interval of every parameter.
fn parameters(page: &mut Page, cal: &CalibrationJson, units: &str) {
    let se = &cal.std_error;
    let ci = cal.interval95.as_ref();
    let mut rows = Vec::new();
    let axes = ["x", "y", "z"];
    let mut add = |name: String, value: f64, se: Option<f64>, half: Option<f64>| {
        rows.push(vec![
            Cell::text(name),
            Cell::number(value, 6),
            Cell::maybe(se, 3),
            Cell::maybe(half, 3),
        ]);
    };
    for i in 0..3 {
        add(
            format!("bias O_{} ({units})", axes[i]),
            cal.bias[i],
            se.bias.map(|s| s[i]),
            ci.map(|c| c.bias[i]),
        );
    }
    for i in 0..3 {
        add(
            format!("scale factor S_{}", axes[i]),
            cal.scale[i],
            se.scale.map(|s| s[i]),
            ci.map(|c| c.scale[i]),
        );
    }
    for i in 0..3 {
        add(
            format!("non-orthogonality psi_{} (degrees)", i + 1),
            cal.psi_deg[i],
            se.psi_deg.map(|s| s[i]),
            ci.map(|c| c.psi_deg[i]),
        );
    }
    page.heading("Parameters");
    page.table(Table {
        id: "parameters".into(),
        caption:
            "The fitted sensor ([P1] eq. (5)-(7)): estimate, standard error, and the half-width of the 95 % interval"
                .into(),
        header: ["parameter", "estimate", "standard error", "95 % half-width"]
            .map(String::from)
            .to_vec(),
        rows,
    });
}

/// The fit's figures: residual, noise, coverage, verdicts.
fn summary(page: &mut Page, cal: &CalibrationJson, units: &str) {
    let mut rows = vec![
        vec![Cell::text("readings fitted"), Cell::count(cal.samples)],
        vec![
            Cell::text("rows skipped / rejected as outliers"),
            Cell::text(format!("{} / {}", cal.skipped, cal.rejected)),
        ],
        vec![
            Cell::text(format!("magnitude R ({units})")),
            Cell::number(cal.magnitude, 6),
        ],
        vec![Cell::text("magnitude from"), Cell::text(&cal.magnitude_source)],
        vec![
            Cell::text(format!("residual rms ({units})")),
            Cell::number(cal.residual_rms, 4),
        ],
        vec![
            Cell::text("residual rms (% of R)"),
            Cell::number(cal.residual_rms_percent, 4),
        ],
        vec![
            Cell::text(format!("residual max ({units})")),
            Cell::number(cal.residual_max, 4),
        ],
        vec![
            Cell::text(format!("noise per component ({units})")),
            Cell::maybe(cal.noise, 4),
        ],
        vec![
            Cell::text("identifiable"),
            Cell::text(if cal.identifiable { "yes" } else { "no" }),
        ],
        vec![Cell::text("verdict"), Cell::text(&cal.verdict)],
        vec![Cell::text("status"), Cell::text(&cal.status)],
        vec![
            Cell::text("MotionCal gaps (%)"),
            Cell::number(cal.coverage.motioncal_gap_percent, 4),
        ],
        vec![
            Cell::text("MicroStrain spatial coverage (%)"),
            Cell::number(cal.coverage.microstrain_coverage_percent, 4),
        ],
        d_efficiency_row(cal),
    ];
    if let Some(e) = &cal.ellipsoid {
        rows.push(vec![Cell::text("on an ellipsoid"), Cell::text(&e.words)]);
    }
    if let Some(l) = &cal.lack_of_fit {
        rows.push(vec![Cell::text("lack of fit"), Cell::text(&l.words)]);
    }
    page.heading("Fit");
    page.table(Table {
        id: "fit".into(),
        caption: "The fit and its verdicts, as calibration.json holds them".into(),
        header: ["figure", "value"].map(String::from).to_vec(),
        rows,
    });
}

/// A 3D scene with equal scales on its axes, labelled in `units`.
fn scene(units: &str, what: &str) -> Layout {
    let axis = |name: &str| Axis::new().title(Title::with_text(format!("{what} {name} ({units})")));
    Layout::new()
        .scene(
            LayoutScene::new()
                .aspect_mode(AspectMode::Data)
                .x_axis(axis("x"))
                .y_axis(axis("y"))
                .z_axis(axis("z")),
        )
        .margin(plotly::layout::Margin::new().left(0).right(0).top(30).bottom(0))
}

/// Points on the unit sphere, `lat` bands by `lon` sectors, and the triangles between them.
pub(super) fn unit_sphere(lat: usize, lon: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let mut points = Vec::new();
    for a in 0..=lat {
        let theta = std::f64::consts::PI * a as f64 / lat as f64;
        for b in 0..lon {
            let phi = std::f64::consts::TAU * b as f64 / lon as f64;
            points.push([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]);
        }
    }
    let mut triangles = Vec::new();
    for a in 0..lat {
        for b in 0..lon {
            let (p, q) = (a * lon + b, a * lon + (b + 1) % lon);
            triangles.push([p, q, p + lon]);
            triangles.push([q, q + lon, p + lon]);
        }
    }
    (points, triangles)
}

/// The hover of a reading drawn in 3D: its line of the log and where it is (the line per point
/// as a number, the words once).
const LINE_HOVER: &str = "line %{customdata}<br>(%{x}, %{y}, %{z})<extra></extra>";

fn raw_plot(cal: &CalibrationJson, rows: &[ResidualRow], units: &str) -> Plot {
    let pick = |f: fn(&ResidualRow) -> f64| rows.iter().map(|r| drawn(f(r))).collect::<Vec<f64>>();
    let lines: Vec<usize> = rows.iter().map(|r| r.line).collect();
    let readings = Scatter3D::new(pick(|r| r.raw_x.0), pick(|r| r.raw_y.0), pick(|r| r.raw_z.0))
        .mode(Mode::Markers)
        .name("raw readings")
        .custom_data(lines)
        .hover_template(LINE_HOVER)
        .marker(Marker::new().size(2).color("#1f77b4"));
    let (unit, triangles) = unit_sphere(16, 32);
    let ellipsoid: Vec<[f64; 3]> = unit
        .iter()
        .map(|u| {
            let b = u.map(|c| c * cal.magnitude);
            std::array::from_fn(|r| cal.k[r][0] * b[0] + cal.k[r][1] * b[1] + cal.k[r][2] * b[2] + cal.bias[r])
        })
        .collect();
    let surface = mesh(&ellipsoid, &triangles)
        .name("fitted ellipsoid")
        .opacity(0.25)
        .color("#ff7f0e");
    let mut plot = Plot::new();
    plot.add_trace(readings);
    plot.add_trace(surface);
    plot.set_layout(scene(units, "raw"));
    plot
}

fn calibrated_plot(cal: &CalibrationJson, rows: &[ResidualRow], units: &str) -> Plot {
    let pick = |f: fn(&ResidualRow) -> f64| rows.iter().map(|r| drawn(f(r))).collect::<Vec<f64>>();
    let lines: Vec<usize> = rows.iter().map(|r| r.line).collect();
    let readings = Scatter3D::new(pick(|r| r.x.0), pick(|r| r.y.0), pick(|r| r.z.0))
        .mode(Mode::Markers)
        .name("calibrated readings")
        .custom_data(lines)
        .hover_template(LINE_HOVER)
        .marker(
            Marker::new()
                .size(2)
                .color_array(pick(|r| r.residual.0))
                .color_scale(ColorScale::Palette(ColorScalePalette::RdBu))
                .cmid(0.0)
                .show_scale(true)
                .color_bar(ColorBar::new().title(format!("residual ({units})"))),
        );
    let (unit, triangles) = unit_sphere(12, 24);
    let sphere: Vec<[f64; 3]> = unit.iter().map(|u| u.map(|c| c * cal.magnitude)).collect();
    let frame = mesh(&sphere, &triangles)
        .name("sphere of radius R")
        .opacity(0.08)
        .color("#888888");
    let mut plot = Plot::new();
    plot.add_trace(readings);
    plot.add_trace(frame);
    plot.set_layout(scene(units, "calibrated"));
    plot
}

/// Longitude and latitude of a calibrated reading's direction, degrees.
fn lon_lat(r: &ResidualRow) -> Option<(f64, f64)> {
    let n = (r.x.0 * r.x.0 + r.y.0 * r.y.0 + r.z.0 * r.z.0).sqrt();
    (n > 0.0 && n.is_finite()).then(|| {
        (
            r.y.0.atan2(r.x.0).to_degrees(),
            (r.z.0 / n).clamp(-1.0, 1.0).asin().to_degrees(),
        )
    })
}

fn residual_map(cells: &Cells) -> Plot {
    let Cells { sum, count } = cells;
    let z: Vec<Vec<Option<f64>>> = (0..LAT)
        .map(|i| {
            (0..LON)
                .map(|j| (count[i][j] > 0).then(|| drawn((sum[i][j] / count[i][j] as f64).sqrt())))
                .collect()
        })
        .collect();
    let text: Vec<Vec<String>> = (0..LAT)
        .map(|i| (0..LON).map(|j| format!("{} readings", count[i][j])).collect())
        .collect();
    let x: Vec<f64> = (0..LON).map(|j| -175.0 + 10.0 * j as f64).collect();
    let y: Vec<f64> = (0..LAT).map(|i| -85.0 + 10.0 * i as f64).collect();
    let map = HeatMap::new(x, y, z)
        .hover_text_matrix(text)
        .color_scale(ColorScale::Palette(ColorScalePalette::Viridis))
        .color_bar(ColorBar::new().title("rms residual"));
    let mut plot = Plot::new();
    plot.add_trace(map);
    plot.set_layout(
        Layout::new()
            .x_axis(
                Axis::new()
                    .title(Title::with_text("longitude of the calibrated direction (degrees)"))
                    .range(vec![-180.0, 180.0]),
            )
            .y_axis(
                Axis::new()
                    .title(Title::with_text("latitude (degrees)"))
                    .range(vec![-90.0, 90.0]),
            ),
    );
    plot
}
